//! Name arguments held to names that exist. In a turn's grammar, a required string
//! argument that takes one of the robot's names (`node`, `topic`, `service`, `action`,
//! `type`: the keys a `NameSource` gives) may be only a name the robot holds now under
//! that key, or a name the operator wrote; and of the robot's names, only those the
//! operator's words point at most (`pointed`), when they point at any.
//!
//! A small model writes a name it has not seen as often as one it has ("turtle1" for the
//! node, "object" for the type, "topic_echo_topic_name"), and of real names the one it
//! always likes (`/turtle1/teleport_absolute` for "clear the canvas"). Once the value
//! must be a real name the words point at, it chooses among a few, or none. What the
//! operator wrote stays open, so a name the robot lacks is still asked for and still
//! reported missing ("no topic /chatter"); when the words point at none of the robot's
//! names of that key, a ROS name written (`/odom`) is the only one. A key the robot has
//! no names for is left free.
//!
//! A field the operator gives a value ("at x 2 y 3") is required in the objects that
//! have it (`require_given`), so it is written and the copy bias fills in the number.
//!
//! Only the grammar changes: the prompt shows the tools as before, so its cache holds.

use std::collections::{BTreeMap, BTreeSet};

use serde_json::{json, Value};

use crate::lexicon::{folded_words, is_number};
use crate::reading::concepts::with_name_words;
use crate::tool::schema::{QUOTE, UNIT};
use crate::tool::ToolSpec;
use crate::units::{unit_tokens, units_written, WrittenUnit};

/// `specs` with each name argument held to the `names` (key, name) of its key that
/// `request`'s words point at (`pointed`) and the names `request` writes
/// (`written_names`). A schema that is a choice of branches, one per name
/// (`Tool::live_parameters`), keeps the branches of names it may take. Tools with no
/// such argument are unchanged. `near`, a name's nearness to the request by meaning
/// (`meaning::Meaning::name_similarity`), narrows the names the words point at
/// equally, or at none of (`NEAR_MARGIN`).
pub fn bind(
    specs: &[ToolSpec],
    names: &[(String, String)],
    request: &str,
    near: Option<&dyn Fn(&str) -> f64>,
) -> Vec<ToolSpec> {
    let written = written_names(request);
    let given = given_fields(request);
    // Every name the robot has, by key: those given and those the tools' arguments
    // suggest (a node's parameters).
    let mut every: Vec<(String, String)> = names.to_vec();
    for spec in specs {
        suggested_names(&spec.parameters, &mut every);
    }
    // A node's own parameter and type-description services are the parameter tools'
    // way in (`meant::every_node`): no service argument is held to one the request does
    // not write (a change of a gripper setting went to a hand-built
    // `set_parameters_atomically`).
    let names: Vec<(String, String)> = names
        .iter()
        .filter(|(k, n)| {
            k != "service"
                || !super::meant::every_node(n)
                || written
                    .iter()
                    .any(|w| w.trim_start_matches('/') == n.trim_start_matches('/'))
        })
        .cloned()
        .collect();
    let (names, met) = pointing(&names, &[request], &written, near);
    let amounts = crate::units::amounts(request);
    let held = Held {
        names: &names,
        every: &every,
        met: &met,
        written: &written,
        request,
        near,
    };
    specs
        .iter()
        .map(|spec| {
            let mut spec = spec.clone();
            bind_schema(&mut spec.parameters, &held);
            require_given(&mut spec.parameters, &given, 0);
            quote(&mut spec.parameters, request);
            hold_units(&mut spec.parameters, request);
            if spec.computes {
                hold_arithmetic(&mut spec.parameters, request);
            }
            let _ = super::amount::hold(&mut spec.parameters, &amounts);
            hold_number_list(&mut spec.parameters, request);
            cap_free(&mut spec.parameters, request);
            spec
        })
        .collect()
}

/// Fewest numbers written one after another that are a list ("0, -1.2, 1.5"): two may
/// be a joint's index and its angle.
const LIST_NUMBERS: usize = 3;

/// The one argument of `schema` (in each of its branches) that takes a list of numbers
/// held to the list `request` writes, in its order, when it writes `LIST_NUMBERS` or
/// more: "move the joints to 0, -1.2, 1.5, -1.9, -1.57 and 0" is that list of six
/// targets, which the model had written as five numbers of its own. A schema with two
/// such arguments (two points) is left to the model, as is a list the argument's bounds
/// or item type do not allow.
fn hold_number_list(schema: &mut Value, request: &str) {
    let numbers = crate::lexicon::digit_list(request);
    if numbers.len() >= LIST_NUMBERS {
        hold_list_in(schema, &numbers);
    }
}

fn hold_list_in(schema: &mut Value, numbers: &[f64]) {
    if let Some(branches) = schema.get_mut("anyOf").and_then(Value::as_array_mut) {
        for b in branches {
            hold_list_in(b, numbers);
        }
        return;
    }
    if number_lists(schema) == 1 {
        set_list(schema, numbers);
    }
}

/// Whether `prop` is an open list of numbers.
fn is_number_list(prop: &Value) -> bool {
    crate::tool::schema::is_open(prop, &["array"])
        && crate::tool::schema::is_open(&prop["items"], &["number", "integer"])
}

/// How many open lists of numbers `schema` takes (a branch counted at its most).
fn number_lists(schema: &Value) -> usize {
    if is_number_list(schema) {
        return 1;
    }
    let within = schema["properties"]
        .as_object()
        .map_or(0, |p| p.values().map(number_lists).sum());
    let branches = schema["anyOf"]
        .as_array()
        .map_or(0, |b| b.iter().map(number_lists).max().unwrap_or(0));
    within + branches
}

fn set_list(schema: &mut Value, numbers: &[f64]) {
    if is_number_list(schema) {
        let whole = schema["items"]["type"] == "integer";
        let fits = |k: &str, ok: &dyn Fn(u64) -> bool| schema[k].as_u64().is_none_or(ok);
        let n = numbers.len() as u64;
        if (!whole || numbers.iter().all(|v| v.fract() == 0.0))
            && fits("minItems", &|m| n >= m)
            && fits("maxItems", &|m| n <= m)
        {
            schema["enum"] = json!([numbers]);
        }
        return;
    }
    if let Some(props) = schema.get_mut("properties").and_then(Value::as_object_mut) {
        for p in props.values_mut() {
            set_list(p, numbers);
        }
    }
    if let Some(branches) = schema.get_mut("anyOf").and_then(Value::as_array_mut) {
        for b in branches {
            set_list(b, numbers);
        }
    }
}

/// Whether every call of `spec` would name a thing of a kind (`topic`, `service`,
/// `action`) of which the robot has none and `request` writes none: a goal for a robot
/// with no action server ("move the joints to …" on an arm with none went to
/// `ros_action_send_goal`, its action named "ros_action_send_goal"). Then the tool
/// reaches nothing, and is not written. With no names at all (a graph that did not
/// answer), nothing is ruled out.
pub(crate) fn reaches_nothing(spec: &ToolSpec, names: &[(String, String)], request: &str) -> bool {
    if names.is_empty() || !written_names(request).is_empty() {
        return false;
    }
    let props = spec.parameters["properties"].as_object();
    crate::tool::schema::required(&spec.parameters)
        .iter()
        .filter(|k| super::meant::ACTED_ON.contains(&k.as_str()))
        .filter(|k| props.is_some_and(|p| p.get(k.as_str()).is_some()))
        .any(|k| !names.iter().any(|(kind, _)| kind == k))
}

/// Most characters of an optional free-text argument in a turn's grammar, unless the
/// request is longer (`cap_free`).
const FREE_CHARS: usize = 64;

/// Each optional string argument of `schema` a model writes freely (no enum, no const,
/// no length bound of its own; a pattern still lets it run on) may be at most `FREE_CHARS` characters long, or as long as
/// `request`. Such arguments are filters, labels and ids (a listing's `namespace`, a
/// log's `node`, a recall's subject, a goal id), and the grounding guard keeps one only
/// when its words were said or returned. A small model asked to list the nodes wrote
/// a `namespace` of about 240 tokens of junk, token by token (6 to 8 s on 2 cores),
/// which the guard then dropped; the bound ends it after a few.
fn cap_free(schema: &mut Value, request: &str) {
    let required = crate::tool::schema::required(schema);
    let Some(props) = schema.get_mut("properties").and_then(Value::as_object_mut) else {
        return;
    };
    let most = FREE_CHARS.max(request.chars().count());
    let free =
        |p: &Value| crate::tool::schema::is_open(p, &["string"]) && p.get("maxLength").is_none();
    for (name, prop) in props.iter_mut() {
        if !required.contains(name) && free(prop) {
            prop["maxLength"] = json!(most);
        }
    }
}

/// A computing tool's expression (its one required argument of free text, `schema`)
/// held to the expression `request` says in words (`arithmetic::said`: "what is 17
/// times 23?" is `17 * 23`), when it says one: a small model wrote "17" and stopped.
fn hold_arithmetic(schema: &mut Value, request: &str) {
    let Some(expression) = super::arithmetic::said(request) else {
        return;
    };
    let required = crate::tool::schema::required(schema);
    let Some(props) = schema.get_mut("properties").and_then(Value::as_object_mut) else {
        return;
    };
    let free: Vec<String> = props
        .iter()
        .filter(|(k, p)| required.contains(k) && crate::tool::schema::is_open(p, &["string"]))
        .map(|(k, _)| k.clone())
        .collect();
    if let [key] = &free[..] {
        props[key] = json!({"type": "string", "enum": [expression]});
    }
}

/// Fewest words a quote has: a subject and what is said of it.
const QUOTE_WORDS: usize = 3;

/// Each string argument of `schema` marked `QUOTE` may be only words `request` ends
/// with, three or more of them (all of a shorter request): what the operator said, not
/// what a model makes of it. Asked to keep a fact about spare fuses in a drawer, a small
/// model wrote a list of fuses of its own; held to the request's own words, it chooses
/// where the fact begins.
fn quote(schema: &mut Value, request: &str) {
    let Some(props) = schema.get_mut("properties").and_then(Value::as_object_mut) else {
        return;
    };
    let quoted = |p: &Value| p.get(QUOTE).and_then(Value::as_bool) == Some(true);
    if !props.values().any(quoted) {
        return;
    }
    let mut words: Vec<&str> = request.split_whitespace().collect();
    if let Some(last) = words.last_mut() {
        *last = last.trim_end_matches(['.', '!', '?', '。', '¡', '¿']);
    }
    words.retain(|w| !w.is_empty());
    let fewest = QUOTE_WORDS.min(words.len()).max(1);
    let phrases: Vec<String> = (fewest..=words.len())
        .map(|n| words[words.len() - n..].join(" "))
        .collect();
    if phrases.is_empty() {
        return;
    }
    for prop in props.values_mut() {
        if quoted(prop) {
            *prop = json!({"type": "string", "enum": phrases});
        }
    }
}

/// The unit arguments of `schema` (marked `UNIT`) held to the units `request` writes:
/// `from` to the unit written right after a number ("3 feet", "10km/h", "20 Grad
/// Celsius"), `to` to the other units of that kind it writes. Of a schema with a branch
/// a kind of quantity, only the kind written after a number stays. A small model
/// reverses the two at times (10 km/h asked in m/s went m/s → km/h). A request that
/// writes units of a kind after no number asks for a returned amount in them: `to` is
/// held to those, `from` to the others of the kind. A request with no unit leaves them
/// as they are; the marks go either way.
fn hold_units(schema: &mut Value, request: &str) {
    let spellings = unit_kinds(schema).concat();
    if spellings.is_empty() {
        return;
    }
    let tokens = unit_tokens(request);
    let written = units_written(&tokens, &spellings);
    let Some(branches) = schema.get_mut("anyOf").and_then(Value::as_array_mut) else {
        hold_branch_units(schema, &tokens, &written);
        return;
    };
    let held: Vec<Option<bool>> = branches
        .iter_mut()
        .map(|b| hold_branch_units(b, &tokens, &written))
        .collect();
    if held.contains(&Some(true)) {
        let mut held = held.into_iter();
        branches.retain(|_| held.next().flatten() != Some(false));
    }
}

/// The units each `from` argument (marked `UNIT`) of `schema` takes, a list a branch:
/// one kind of quantity each.
fn unit_kinds(schema: &Value) -> Vec<Vec<String>> {
    let branches: Vec<&Value> = match schema.get("anyOf").and_then(Value::as_array) {
        Some(b) => b.iter().collect(),
        None => vec![schema],
    };
    branches
        .iter()
        .filter_map(|b| b["properties"].as_object())
        .flat_map(|props| props.values())
        .filter(|p| p.get(UNIT).and_then(Value::as_str) == Some("from"))
        .filter_map(|p| p["enum"].as_array())
        .map(|kind| {
            kind.iter()
                .filter_map(|s| Some(s.as_str()?.to_string()))
                .collect()
        })
        .collect()
}

/// Whether `schema` converts between units: it has a `from` unit argument (`UNIT`).
pub(crate) fn converts_units(schema: &Value) -> bool {
    !unit_kinds(schema).is_empty()
}

/// Whether `request` asks to convert an amount in one unit of `schema`'s (a `from`
/// argument marked `UNIT`) into another of its kind: it writes the one right after a
/// number and the other apart ("how many meters are 5 Meilen?"). An amount in a unit
/// alone is no such request: it says how far to drive or turn as often.
pub(crate) fn asks_a_conversion(schema: &Value, request: &str) -> bool {
    let kinds = unit_kinds(schema);
    if kinds.is_empty() {
        return false;
    }
    let tokens = unit_tokens(request);
    let written = units_written(&tokens, &kinds.concat());
    kinds.iter().any(|kind| {
        let (from, to) = units_asked(kind, &tokens, &written);
        !from.is_empty() && !to.is_empty()
    })
}

/// `hold_units` in one object, given the units the request writes: `None` when it has
/// no unit argument, else whether the request writes one of its units after a number.
fn hold_branch_units(
    object: &mut Value,
    tokens: &[String],
    written: &[WrittenUnit],
) -> Option<bool> {
    let props = object.get_mut("properties")?.as_object_mut()?;
    let role = |p: &Value, r: &str| p.get(UNIT).and_then(Value::as_str) == Some(r);
    let from_key = props.iter().find(|(_, p)| role(p, "from"))?.0.clone();
    let to_key = props
        .iter()
        .find(|(_, p)| role(p, "to"))
        .map(|(k, _)| k.clone());
    for p in props.values_mut() {
        if let Some(p) = p.as_object_mut() {
            p.remove(UNIT);
        }
    }
    let spellings: Vec<String> = props[&from_key]["enum"]
        .as_array()?
        .iter()
        .filter_map(|s| Some(s.as_str()?.to_string()))
        .collect();
    let (mut from, mut to) = units_asked(&spellings, tokens, written);
    // One unit written with no number before it, and none after one: the amount is one
    // a tool returns ("the elbow's angle, in degrees"), and it is asked in that unit.
    // Only a unit no everyday word spells counts so ("in", "s" or "second" may be no
    // unit); of two ("convert meters to yards") either may be the one it is in.
    if from.is_empty() {
        let one = to.iter().all(|t| crate::units::same_unit(t, &to[0]));
        to.retain(|s| crate::units::unmistakable_spelling(s));
        if to.is_empty() || !one {
            return Some(false);
        }
        // Each unit once, by the symbol the tool's prompt shows ("degrés" is `deg`).
        let symbols = |units: Vec<String>| {
            let mut out: Vec<String> = Vec::new();
            for u in units.iter().map(|u| crate::units::symbol(u)) {
                if !out.contains(&u) {
                    out.push(u);
                }
            }
            out
        };
        from = symbols(others(&spellings, &to));
        to = symbols(to);
    } else if to.is_empty() {
        to = others(&spellings, &from);
    }
    props[&from_key]["enum"] = json!(from);
    if let Some(k) = to_key.filter(|_| !to.is_empty()) {
        props[&k]["enum"] = json!(to);
    }
    Some(true)
}

/// The spellings of `spellings` of no unit `of` spells (a conversion goes between two
/// units, not between two spellings of one).
fn others(spellings: &[String], of: &[String]) -> Vec<String> {
    spellings
        .iter()
        .filter(|s| !of.iter().any(|o| o == *s || crate::units::same_unit(o, s)))
        .cloned()
        .collect()
}

/// Of the units `written` in `tokens`, those of `spellings` (one kind's) that the
/// request converts from (written right after a number) and to (the others, but a
/// unit word between another unit and a number or a unit, which joins them: the "in"
/// of "3 feet in meters", "meters in 3 feet").
fn units_asked(
    spellings: &[String],
    tokens: &[String],
    written: &[WrittenUnit],
) -> (Vec<String>, Vec<String>) {
    let after_number = |w: &WrittenUnit| w.at > 0 && is_number(&tokens[w.at - 1]);
    let joins = |i: usize| {
        let w = &written[i];
        let after_unit = i > 0 && written[i - 1].at + written[i - 1].len == w.at;
        let next = w.at + w.len;
        let before = tokens.get(next).is_some_and(|t| is_number(t))
            || written.get(i + 1).is_some_and(|n| n.at == next);
        after_unit && before
    };
    let mut from: Vec<String> = Vec::new();
    let mut to: Vec<String> = Vec::new();
    for (i, w) in written.iter().enumerate() {
        if !spellings.contains(&w.spelling) {
            continue;
        }
        if after_number(w) {
            if !from.contains(&w.spelling) {
                from.push(w.spelling.clone());
            }
        } else if !joins(i) && !to.contains(&w.spelling) {
            to.push(w.spelling.clone());
        }
    }
    to.retain(|s| !from.contains(s));
    (from, to)
}

/// The fields `request` gives a value: a word followed by a number ("at x 2 y 3",
/// "theta=90", "width: 3", "x tres").
pub(crate) fn given_fields(request: &str) -> BTreeSet<String> {
    let words = folded_words(request);
    words
        .windows(2)
        .filter(|p| is_number(&p[1]) && !is_number(&p[0]))
        .map(|p| p[0].clone())
        .collect()
}

/// Deepest object whose fields `require_given` looks at: the arguments and the objects
/// they hold (a service's request), not the objects inside those. "linear x 1" would
/// otherwise require `x` of a twist's `angular` too, and a value would be made up for it.
const GIVEN_DEPTH: usize = 1;

/// Each field of an object of `schema` that `given` names becomes required, and so does
/// the object holding it, so the value the operator gave is written: a small model
/// fills an object of optional fields with the ones it likes ("spawn a turtle at x 2 y
/// 3": only `name`), or leaves the object out. Whether `schema` names any.
fn require_given(schema: &mut Value, given: &BTreeSet<String>, depth: usize) -> bool {
    if depth > GIVEN_DEPTH || given.is_empty() {
        return false;
    }
    let mut any = false;
    if let Some(branches) = schema.get_mut("anyOf").and_then(Value::as_array_mut) {
        for b in branches {
            any |= require_given(b, given, depth);
        }
    }
    let Some(props) = schema.get_mut("properties").and_then(Value::as_object_mut) else {
        return any;
    };
    let mut named: Vec<String> = Vec::new();
    for (k, p) in props.iter_mut() {
        if given.contains(&crate::lexicon::fold(k)) | require_given(p, given, depth + 1) {
            named.push(k.clone());
        }
    }
    if named.is_empty() {
        return any;
    }
    let required = schema
        .as_object_mut()
        .map(|o| o.entry("required").or_insert_with(|| json!([])));
    if let Some(Value::Array(required)) = required {
        for k in named {
            if !required.iter().any(|r| r == k.as_str()) {
                required.push(json!(k));
            }
        }
    }
    true
}

/// What a turn's name arguments are held to.
struct Held<'a> {
    /// The robot's names the words point at (all of a key's when they point at none).
    names: &'a [(String, String)],
    /// Every name the robot has (key, name), pointed at or not.
    every: &'a [(String, String)],
    /// The keys of which the words point at some name.
    met: &'a BTreeSet<String>,
    /// The names the request writes.
    written: &'a [String],
    request: &'a str,
    near: Option<&'a dyn Fn(&str) -> f64>,
}

fn bind_schema(schema: &mut Value, held: &Held) {
    let Some(branches) = schema.get("anyOf").and_then(Value::as_array) else {
        bind_object(schema, held, &[]);
        return;
    };
    // The names the branches spell out: the open branch is for the others.
    let taken: Vec<(String, String)> = branches
        .iter()
        .flat_map(|b| b["properties"].as_object().into_iter().flatten())
        .filter_map(|(k, p)| Some((k.clone(), p.get("const")?.as_str()?.to_string())))
        .collect();
    let kept: Vec<Value> = branches
        .iter()
        .cloned()
        .filter_map(|mut b| bind_object(&mut b, held, &taken).then_some(b))
        .collect();
    // A robot whose every such name is fenced off, with none written: the call stays as
    // declared, for the policy to refuse.
    if !kept.is_empty() {
        schema["anyOf"] = Value::Array(kept);
    }
}

/// Hold each required string name property of `object` (`taken`: names other branches
/// spell out), and each required property that suggests names (`suggested`); `false`
/// when it can take no name at all.
fn bind_object(object: &mut Value, h: &Held, taken: &[(String, String)]) -> bool {
    let (names, written, request) = (h.names, h.written, h.request);
    let required = crate::tool::schema::required(object);
    let Some(props) = object["properties"].as_object_mut() else {
        return true;
    };
    for (key, prop) in props.iter_mut() {
        if !required.contains(key) {
            continue;
        }
        if let Some(known) = suggested(prop) {
            let open = held_to(&known, key, names, request, written, h.near);
            *prop = json!({"type": "string", "enum": open});
            continue;
        }
        if prop["type"] != "string" {
            continue;
        }
        let held: Vec<&str> = names
            .iter()
            .filter(|(k, _)| k == key)
            .map(|(_, n)| n.as_str())
            .collect();
        if held.is_empty() {
            continue;
        }
        // A written name the robot holds under a longer spelling ("teleport_absolute",
        // "turtle1/pose") is that name, not a missing one; nor is one the robot has
        // under another key ("background_r", a parameter, is no missing service).
        let missing: Vec<&str> = written
            .iter()
            .map(String::as_str)
            .filter(|w| {
                let w = w.trim_start_matches('/');
                !held
                    .iter()
                    .any(|h| h.trim_start_matches('/') == w || h.ends_with(&format!("/{w}")))
                    && !h
                        .every
                        .iter()
                        .any(|(k, n)| k != key && n.trim_start_matches('/') == w)
            })
            .collect();
        // A ROS name written (with its slash) that the robot lacks, under no other key
        // either, and words that point at none of the key's names ("print what
        // /odom says"): what is asked for is the name written, which the tool reports
        // missing, not any of the robot's.
        let bare = |n: &str| n.trim_start_matches('/').to_string();
        let asked: Vec<&str> = missing
            .iter()
            .copied()
            .filter(|w| w.starts_with('/'))
            .filter(|w| !names.iter().any(|(k, n)| k != key && bare(n) == bare(w)))
            .collect();
        let mut open: Vec<&str> = if asked.is_empty() || h.met.contains(key) {
            held.iter().copied().chain(missing).collect()
        } else {
            asked
        };
        if let Some(c) = prop.get("const").and_then(Value::as_str) {
            if !open.contains(&c) {
                return false;
            }
            continue;
        }
        open.retain(|n| !taken.iter().any(|(k, t)| k == key && t == n));
        if open.is_empty() {
            return false;
        }
        open.sort_unstable();
        open.dedup();
        prop["enum"] = json!(open);
    }
    true
}

/// Each (key, name) a property of `schema` suggests (`suggested`), at any depth.
pub(crate) fn suggested_names(schema: &Value, out: &mut Vec<(String, String)>) {
    match schema {
        Value::Object(map) => {
            if let Some(Value::Object(props)) = map.get("properties") {
                for (key, prop) in props {
                    for n in suggested(prop).unwrap_or_default() {
                        out.push((key.clone(), n));
                    }
                }
            }
            map.values().for_each(|v| suggested_names(v, out));
        }
        Value::Array(items) => items.iter().for_each(|v| suggested_names(v, out)),
        _ => {}
    }
}

/// The names a property suggests, when it is a choice of known names or any other
/// (`{"anyOf": [{"enum": [...]}, {"type": "string"}]}`: a node's parameters, which the
/// node may lack one of).
pub(crate) fn suggested(prop: &Value) -> Option<Vec<String>> {
    let [known, other] = prop.get("anyOf")?.as_array()?.as_slice() else {
        return None;
    };
    if other.get("type")? != "string" || other.get("enum").is_some() {
        return None;
    }
    known
        .get("enum")?
        .as_array()?
        .iter()
        .map(|v| v.as_str().map(str::to_string))
        .collect()
}

/// Of the `known` names, those `request`'s words point at (all when they point at none),
/// with the names `written` that are neither among them nor one of the robot's names
/// of another key than `key` ("/turtlesim" is a node, not a missing parameter): what
/// the operator wrote stays possible (a topic nobody publishes, which reading then
/// says), and the tool reports what is missing.
fn held_to(
    known: &[String],
    key: &str,
    names: &[(String, String)],
    request: &str,
    written: &[String],
    near: Option<&dyn Fn(&str) -> f64>,
) -> Vec<String> {
    let bare = |n: &str| n.trim_start_matches('/').to_string();
    // A name of this key written whole is the one asked for, offered or not.
    let mut whole: Vec<String> = names
        .iter()
        .filter(|(k, n)| k == key && written.iter().any(|w| bare(w) == bare(n)))
        .map(|(_, n)| n.clone())
        .collect();
    if !whole.is_empty() {
        whole.sort_unstable();
        whole.dedup();
        return whole;
    }
    let entries: Vec<(String, String)> = known.iter().map(|n| (String::new(), n.clone())).collect();
    let (pointed_known, met) = pointing(&entries, &[request], written, near);
    let missing: Vec<String> = written
        .iter()
        .filter(|w| {
            let mut held = known
                .iter()
                .chain(names.iter().filter(|(k, _)| k != key).map(|(_, n)| n));
            !held.any(|k| bare(k) == bare(w))
        })
        .cloned()
        .collect();
    // A ROS name written that the robot lacks, and words that point at none of the
    // known names ("echo /odom"): what is asked for is the name written, which the
    // tool reports missing.
    let asked: Vec<String> = missing
        .iter()
        .filter(|w| w.starts_with('/'))
        .cloned()
        .collect();
    let mut out: Vec<String> = if met.is_empty() && !asked.is_empty() {
        asked
    } else {
        let mut out: Vec<String> = pointed_known.into_iter().map(|(_, n)| n).collect();
        out.extend(missing);
        out
    };
    // Names that are words ("loading area", not `max_speed` or `/odom`) are said as
    // words: when the request's point at none of them, what it says may be a name the
    // robot lacks ("the kitchen"), so its words stay possible and the tool reports the
    // name missing, rather than the grammar forcing one of the known names.
    let worded = known.iter().all(|n| !n.contains(['/', '_']));
    let said = said_phrases(request);
    if met.is_empty() && worded && !said.is_empty() {
        // Nor is one of the known names the request does not say a name it gives:
        // the value is one it says.
        out.retain(|n| !known.contains(n));
        out.extend(said);
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// Most words of a name the request may say.
const PHRASE_WORDS: usize = 3;

/// Shortest word a name may start with: shorter ones are the little words of a
/// sentence ("the", "as", "als", "la"), which come before a name, not in it.
const NAME_WORD: usize = 4;

/// The names a request may say in words: the phrases that end it, of one to three
/// words, numbers left out. A name comes last in a request that gives one, in each of
/// the six languages ("save this spot as the workbench", "guarda este sitio como
/// taller", "fahr zur Ladestation"); the words before it say what to do with it.
fn said_phrases(request: &str) -> Vec<String> {
    let words: Vec<String> = folded_words(request)
        .into_iter()
        .filter(|w| w.parse::<f64>().is_err())
        .collect();
    (1..=PHRASE_WORDS.min(words.len()))
        .filter_map(|n| {
            let phrase = &words[words.len() - n..];
            let least = if n == 1 { LAST_WORD } else { NAME_WORD };
            (phrase[0].chars().count() >= least).then(|| phrase.join(" "))
        })
        .collect()
}

/// Shortest a name of one word, the request's last, may be: a request that gives a
/// name ends with it, not with a little word ("remember this spot as the lab": "lab";
/// before, no phrase was left, and the grammar wrote a known place, moving it here),
/// though "it", "on" and "up" end some.
const LAST_WORD: usize = 3;

/// Of the robot's `names` (key, name), per key, those the words of `sources` point at
/// most: each word a name shares with them weighs more the fewer of the key's names have
/// it ("spawn a turtle at x 2": `/spawn`, not `/turtle1/teleport_absolute`; "kill
/// turtle1": `/kill`, which alone has "kill", over the three services under
/// `/turtle1`). A name `written` whole ("/turtle1/cmd_vel", not the longer names that
/// share its words) is the only one of its key. A key whose names the words meet not
/// at all keeps them all. The copy bias favours these; the grammar allows only these
/// (and the names written).
pub(crate) fn pointed(
    names: &[(String, String)],
    sources: &[&str],
    written: &[String],
) -> Vec<(String, String)> {
    pointing(names, sources, written, None).0
}

/// `pointed`, and the keys of which the words point at some name (or a name is
/// written whole).
fn pointing(
    names: &[(String, String)],
    sources: &[&str],
    written: &[String],
    near: Option<&dyn Fn(&str) -> f64>,
) -> (Vec<(String, String)>, BTreeSet<String>) {
    // A word in another language counts as the English word of names it says
    // ("pinza" as `gripper`).
    let said: BTreeSet<String> = sources
        .iter()
        .flat_map(|s| with_name_words(&folded_words(s)))
        .collect();
    let mut by_key: BTreeMap<&str, Vec<(&str, BTreeSet<String>)>> = BTreeMap::new();
    for (key, name) in names {
        let words = folded_words(name).into_iter().collect();
        by_key.entry(key).or_default().push((name, words));
    }
    let whole = |name: &str| {
        written
            .iter()
            .any(|w| w.trim_start_matches('/') == name.trim_start_matches('/'))
    };
    let mut out = Vec::new();
    let mut met = BTreeSet::new();
    for (key, entries) in by_key {
        if entries.iter().any(|(n, _)| whole(n)) {
            met.insert(key.to_string());
            out.extend(
                entries
                    .iter()
                    .filter(|(n, _)| whole(n))
                    .map(|(n, _)| (key.to_string(), n.to_string())),
            );
            continue;
        }
        let df = |w: &String| entries.iter().filter(|(_, ws)| ws.contains(w)).count();
        let n = entries.len() as f64;
        let scores: Vec<f64> = entries
            .iter()
            .map(|(_, ws)| {
                // A shortened word counts only beside one said whole (or said with
                // an ending: "joints" for `joint`).
                if !ws.iter().any(|w| said_whole(w, &said)) {
                    return 0.0;
                }
                ws.iter()
                    .filter(|w| meets(w, ws, &said))
                    .map(|w| (1.0 + n / df(w) as f64).ln())
                    .sum()
            })
            .collect();
        let best = scores.iter().copied().fold(0.0, f64::max);
        if best > 0.0 {
            met.insert(key.to_string());
        }
        let tied: Vec<&str> = entries
            .iter()
            .zip(&scores)
            .filter(|(_, score)| best == 0.0 || **score >= best - 1e-9)
            .map(|((name, _), _)| *name)
            .collect();
        out.extend(
            nearest(tied, near)
                .into_iter()
                .map(|name| (key.to_string(), name.to_string())),
        );
    }
    (out, met)
}

/// How much nearer by meaning than the nearest a name may be and still be offered: the
/// request's words point at `/arm/state` and `/arm/tcp_pose` alike ("what is the arm
/// doing?"), its meaning at the first (chosen on the tune halves of both robots' suites).
const NEAR_MARGIN: f64 = 0.03;

/// Of `names`, those within `NEAR_MARGIN` of the nearest to the request by meaning
/// (`near`); all of them without it.
fn nearest<'a>(names: Vec<&'a str>, near: Option<&dyn Fn(&str) -> f64>) -> Vec<&'a str> {
    let Some(near) = near.filter(|_| names.len() > 1) else {
        return names;
    };
    let sims: Vec<f64> = names.iter().map(|n| near(n)).collect();
    let top = sims.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    names
        .into_iter()
        .zip(sims)
        .filter(|(_, s)| *s >= top - NEAR_MARGIN)
        .map(|(n, _)| n)
        .collect()
}

/// Whether a name's word `w` is said whole, or said with an ending: a word said that
/// starts with it, when it has four letters or more ("joints", "nodos" for `joint`,
/// `nodo`).
fn said_whole(w: &str, said: &BTreeSet<String>) -> bool {
    said.contains(w) || (w.chars().count() >= 4 && said.iter().any(|s| s.starts_with(w)))
}

/// Whether the word `w` of a name (whose words are `own`) is one of the words `said`, or
/// the start of one that is not itself a word of the name: names shorten what the
/// operator says in full ("b" in `background_b` for "blue", "vel" in `cmd_vel` for
/// "velocity"), but the "b" of `background_b` does not meet "background", which the
/// name has whole. (`pointed` counts a shortened word only beside a whole one: "get"
/// alone does not point at `background_g`.)
fn meets(w: &str, own: &BTreeSet<String>, said: &BTreeSet<String>) -> bool {
    said.contains(w)
        || said
            .iter()
            .any(|s| s.len() > w.len() && s.starts_with(w) && !own.contains(s))
}

/// The words of `request` shaped like a ROS name or type: with a `/` or an `_` inside
/// ("/chatter", "turtle1/pose", "battery_level", "std_msgs/msg/String"), the quotes and
/// stops around them left off. A bare word is not a name the operator gave: it may be
/// any word of any language.
pub(crate) fn written_names(request: &str) -> Vec<String> {
    request
        .split_whitespace()
        .map(|w| w.trim_matches(|c: char| !(c.is_alphanumeric() || c == '/' || c == '_')))
        .map(|w| w.trim_end_matches('/'))
        .filter(|w| {
            let body = w.trim_start_matches('/');
            body.chars().any(char::is_alphanumeric)
                && body
                    .chars()
                    .all(|c| c.is_alphanumeric() || c == '/' || c == '_')
                && (w.starts_with('/') || body.contains(['/', '_']))
        })
        .map(str::to_string)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(name: &str, parameters: Value) -> ToolSpec {
        ToolSpec {
            name: name.into(),
            description: String::new(),
            parameters,
            alone: false,
            examples: Vec::new(),
            sequence: Vec::new(),
            records: false,
            computes: false,
            lists: None,
        }
    }

    fn names() -> Vec<(String, String)> {
        [
            ("node", "/turtlesim"),
            ("topic", "/turtle1/pose"),
            ("topic", "/battery_state"),
            ("type", "turtlesim/msg/Pose"),
        ]
        .iter()
        .map(|(k, n)| (k.to_string(), n.to_string()))
        .collect()
    }

    #[test]
    fn optional_free_text_is_bounded_in_the_grammar_and_nothing_else_is() {
        let specs = [spec(
            "ros_node_list",
            json!({"type": "object", "properties": {
                "namespace": {"type": ["string", "null"], "pattern": "^/[a-z_/]*$"},
                "label": {"type": "string", "maxLength": 8},
                "level": {"type": "string", "enum": ["info", "warn"]},
                "note": {"type": "string"},
                "count": {"type": "integer"}
            }, "required": ["note"]}),
        )];
        let short = bind(&specs, &names(), "which nodes run here", None);
        let p = &short[0].parameters["properties"];
        assert_eq!(p["namespace"]["maxLength"], json!(FREE_CHARS));
        // Its own bound, a choice, a required value and a number are left as they are.
        assert_eq!(p["label"]["maxLength"], json!(8));
        assert!(p["level"].get("maxLength").is_none());
        assert!(p["note"].get("maxLength").is_none());
        assert!(p["count"].get("maxLength").is_none());
        // A request longer than the bound may be copied whole.
        let long = "list the nodes whose names mention the left front wheel's steering controller";
        let p = &bind(&specs, &names(), long, None)[0].parameters["properties"];
        assert_eq!(p["namespace"]["maxLength"], json!(long.chars().count()));
    }

    #[test]
    fn a_required_name_argument_takes_the_robots_names_and_the_operators() {
        let specs = [spec(
            "ros_topic_echo",
            json!({"type": "object", "properties": {
                "topic": {"type": "string", "description": "Topic name"},
                "count": {"type": "integer"}},
              "required": ["topic"]}),
        )];
        // A name the robot lacks, and words that point at none it holds: that name.
        let bound = bind(&specs, &names(), "echo /chatter, please", None);
        assert_eq!(
            bound[0].parameters["properties"]["topic"]["enum"],
            json!(["/chatter"])
        );
        // Words that point at one it holds too: both.
        let either = bind(&specs, &names(), "echo /chatter or the pose", None);
        assert_eq!(
            either[0].parameters["properties"]["topic"]["enum"],
            json!(["/chatter", "/turtle1/pose"])
        );
        // A name the robot holds, written without its slash, is that name, and the one
        // the words point at.
        let bound_again = bind(&specs, &names(), "echo turtle1/pose", None);
        assert_eq!(
            bound_again[0].parameters["properties"]["topic"]["enum"],
            json!(["/turtle1/pose"])
        );
        assert_eq!(
            bound[0].parameters["properties"]["topic"]["description"],
            "Topic name"
        );
        assert!(bound[0].parameters["properties"]["count"]
            .get("enum")
            .is_none());
    }

    #[test]
    fn a_list_of_numbers_written_is_the_list_a_tool_takes() {
        let schema = || {
            json!({"type": "object", "properties": {
                "topic": {"type": "string"},
                "message": {"type": "object", "properties": {
                    "data": {"type": "array", "items": {"type": "number"}}}}}})
        };
        let mut s = schema();
        hold_number_list(&mut s, "set the three valves to 0.5, -1 and 2 please");
        assert_eq!(
            s["properties"]["message"]["properties"]["data"]["enum"],
            json!([[0.5, -1.0, 2.0]])
        );
        // Two numbers, or number words, are no list.
        let mut s = schema();
        hold_number_list(&mut s, "set valve 2 to 0.5, all three of them");
        assert_eq!(s, schema());
        // Two lists to fill (two points) are the model's.
        let points = json!({"type": "object", "properties": {
            "a": {"type": "array", "items": {"type": "number"}},
            "b": {"type": "array", "items": {"type": "number"}}}});
        let mut s = points.clone();
        hold_number_list(&mut s, "from 1 2 to 4 6");
        assert_eq!(s, points);
    }

    #[test]
    fn a_tool_that_takes_a_kind_the_robot_has_none_of_reaches_nothing() {
        let goal = spec(
            "ros_action_send_goal",
            json!({"type": "object", "required": ["action"],
                   "properties": {"action": {"type": "string"}, "goal": {"type": "object"}}}),
        );
        let topics = vec![("topic".to_string(), "/lamp/level".to_string())];
        assert!(reaches_nothing(
            &goal,
            &topics,
            "send the lamp to full brightness"
        ));
        // An action written is asked for, to be reported missing if need be.
        assert!(!reaches_nothing(
            &goal,
            &topics,
            "send a goal to /lamp/fade"
        ));
        let mut with_action = topics.clone();
        with_action.push(("action".into(), "/lamp/fade".into()));
        assert!(!reaches_nothing(&goal, &with_action, "fade the lamp out"));
        // A graph that gave no names rules nothing out.
        assert!(!reaches_nothing(&goal, &[], "fade the lamp out"));
    }

    #[test]
    fn words_in_another_language_point_at_the_english_names_they_say() {
        let names: Vec<(String, String)> = ["/valve/open", "/valve/close", "/pump/start"]
            .iter()
            .map(|n| ("service".to_string(), n.to_string()))
            .collect();
        let at = |request: &str| -> Vec<String> {
            pointed(&names, &[request], &[])
                .into_iter()
                .map(|(_, n)| n)
                .collect()
        };
        assert_eq!(at("ferme la vanne, s'il te plaît"), ["/valve/close"]);
        assert_eq!(at("apri la valvola"), ["/valve/open"]);
        // "shut" is no word of the names: both valve services stay.
        assert_eq!(at("shut the valve"), ["/valve/open", "/valve/close"]);
    }

    #[test]
    fn a_nodes_own_parameter_services_are_held_to_only_when_written() {
        let specs = [spec(
            "ros_service_call",
            json!({"type": "object", "properties": {"service": {"type": "string"}},
                   "required": ["service"]}),
        )];
        let names: Vec<(String, String)> =
            ["/lamp/on", "/lamp/set_parameters", "/lamp/get_parameters"]
                .iter()
                .map(|n| ("service".to_string(), n.to_string()))
                .collect();
        let held = |request: &str| {
            bind(&specs, &names, request, None)[0].parameters["properties"]["service"]["enum"]
                .clone()
        };
        // Words that point at the parameter services ("set", "parameters") hold the
        // call to the robot's own service.
        assert_eq!(
            held("set the lamp parameters to bright"),
            json!(["/lamp/on"])
        );
        assert_eq!(
            held("call /lamp/get_parameters"),
            json!(["/lamp/get_parameters"])
        );
    }

    #[test]
    fn optional_arguments_and_keys_without_names_stay_free() {
        let specs = [
            spec(
                "ros_log_read",
                json!({"type": "object", "properties": {
                    "node": {"type": ["string", "null"]}}, "required": []}),
            ),
            spec(
                "ros_service_info",
                json!({"type": "object", "properties": {
                    "service": {"type": "string"}}, "required": ["service"]}),
            ),
        ];
        let mut bound = bind(&specs, &names(), "what does /spawn take?", None);
        // Not held to names: only bounded in length (`cap_free`).
        let node = bound[0].parameters["properties"]["node"]
            .as_object_mut()
            .unwrap();
        assert_eq!(node.remove("maxLength"), Some(json!(FREE_CHARS)));
        assert_eq!(bound[0].parameters, specs[0].parameters);
        // The robot gave no services: nothing to hold the argument to.
        assert_eq!(bound[1].parameters, specs[1].parameters);
    }

    #[test]
    fn names_said_in_words_may_be_ones_the_robot_lacks() {
        let known: Vec<String> = ["dock", "loading area", "Ladestation"]
            .map(String::from)
            .to_vec();
        let held = |request: &str| held_to(&known, "place", &[], request, &[], None);
        assert_eq!(held("back to the loading area"), ["loading area"]);
        // A name the robot lacks is one the request ends with, never a known one.
        assert_eq!(held("take me to the greenhouse"), ["greenhouse"]);
        assert_eq!(
            held("save this spot as checkpoint alpha"),
            ["alpha", "checkpoint alpha"]
        );
        // A short last word is a name too; a little word that ends a request is not.
        assert_eq!(held("mark where we are as the lab"), ["lab"]);
        let mut all = held("go to it");
        all.sort_unstable();
        assert_eq!(all, ["Ladestation", "dock", "loading area"]);
        // Identifiers are not said in words: the known ones only.
        let params: Vec<String> = ["gain_p", "max_speed"].map(String::from).to_vec();
        let held = held_to(&params, "name", &[], "what is the greenhouse", &[], None);
        assert_eq!(held, params);
    }

    #[test]
    fn written_names_are_the_words_shaped_like_ros_names() {
        assert_eq!(
            written_names("show \"turtle1/pose\", the battery_level and /clear. Then geometry_msgs/msg/Twist?"),
            ["turtle1/pose", "battery_level", "/clear", "geometry_msgs/msg/Twist"]
        );
        assert!(written_names("list the nodes / topics, por favor").is_empty());
        // Shape alone decides: "and/or" is written like a name; the grammar then
        // allows it, and the tool reports it missing.
        assert_eq!(written_names("and/or ___ /"), ["and/or"]);
    }

    #[test]
    fn branches_keep_the_names_they_may_take() {
        let branch = |service: Value| {
            json!({"type": "object", "properties": {"service": service,
                   "request": {"type": "object"}}, "required": ["service"]})
        };
        let names: Vec<(String, String)> = ["/clear", "/spawn"]
            .iter()
            .map(|n| ("service".to_string(), n.to_string()))
            .collect();
        let specs = [spec(
            "ros_service_call",
            json!({"anyOf": [
                branch(json!({"type": "string", "const": "/clear"})),
                branch(json!({"type": "string", "const": "/spawn"})),
                // Fenced off: the robot's names leave it out.
                branch(json!({"type": "string", "const": "/kill"})),
                branch(json!({"type": "string"}))]}),
        )];
        let free = |request: &str| {
            let bound = bind(&specs, &names, request, None);
            let branches = bound[0].parameters["anyOf"].as_array().unwrap().clone();
            let consts: Vec<Value> = branches
                .iter()
                .map(|b| {
                    let s = &b["properties"]["service"];
                    s.get("const").or(s.get("enum")).cloned().unwrap()
                })
                .collect();
            consts
        };
        // The words point at one service: its branch alone is left.
        assert_eq!(free("please clear the canvas"), [json!("/clear")]);
        // At none: every service the robot holds, but not the fenced one, nor the open
        // branch (nothing written).
        assert_eq!(free("call a service"), [json!("/clear"), json!("/spawn")]);
        // A missing name the operator wrote is open; one the robot holds is its branch.
        assert_eq!(
            free("call /self_destruct, then /spawn"),
            [json!("/spawn"), json!(["/self_destruct"])]
        );
        // A bare word is no name: nothing to open the branch for.
        assert_eq!(free("use clear/"), [json!("/clear")]);
    }

    #[test]
    fn the_names_the_words_point_at_most_are_favoured() {
        let services: Vec<(String, String)> = [
            "/clear",
            "/kill",
            "/spawn",
            "/turtle1/set_pen",
            "/turtle1/teleport_absolute",
            "/turtle1/teleport_relative",
        ]
        .iter()
        .map(|n| ("service".to_string(), n.to_string()))
        .chain([("node".to_string(), "/turtlesim".to_string())])
        .collect();
        let favoured = |q: &str| -> Vec<String> {
            pointed(&services, &[q], &written_names(q))
                .into_iter()
                .filter(|(k, _)| k == "service")
                .map(|(_, n)| n)
                .collect()
        };
        assert_eq!(favoured("spawn another turtle at x 4 y 1"), ["/spawn"]);
        assert_eq!(favoured("please kill turtle1 for me"), ["/kill"]);
        assert_eq!(favoured("Borra la pantalla con CLEAR"), ["/clear"]);
        assert_eq!(
            favoured("teleport turtle1 to 3 4"),
            ["/turtle1/teleport_absolute", "/turtle1/teleport_relative"]
        );
        // Words that meet no name: every name stays.
        assert_eq!(favoured("do the thing").len(), 6);
        // Keys are weighed apart: the node is kept though no word meets it.
        assert!(pointed(&services, &["spawn"], &[]).contains(&("node".into(), "/turtlesim".into())));
        // A name written whole is the one, not the longer names sharing its words.
        let topics: Vec<(String, String)> = ["/turtle1/cmd_vel", "/turtle1/cmd_vel_mux/active"]
            .iter()
            .map(|n| ("topic".to_string(), n.to_string()))
            .collect();
        let q = "publish on /turtle1/cmd_vel";
        assert_eq!(
            pointed(&topics, &[q], &written_names(q)),
            [("topic".to_string(), "/turtle1/cmd_vel".to_string())]
        );
        let q = "publish on the turtle1 cmd vel topic";
        assert_eq!(pointed(&topics, &[q], &written_names(q)).len(), 2);
    }

    #[test]
    fn fields_the_request_gives_a_value_are_written() {
        assert_eq!(
            given_fields("spawn a turtle at x 2 y 3.5, theta=90 and width: tres"),
            ["theta", "width", "x", "y"].map(String::from).into()
        );
        // Any word before a number counts; one that names no field changes nothing.
        assert_eq!(
            given_fields("move 2 m then 3 more"),
            ["move", "then"].map(String::from).into()
        );
        let specs = [spec(
            "ros_service_call",
            json!({"anyOf": [{"type": "object", "properties": {
                "service": {"type": "string", "const": "/spawn"},
                "request": {"type": "object", "properties": {
                    "x": {"type": "number"}, "y": {"type": "number"},
                    "name": {"type": "string"}}}},
              "required": ["service"]}]}),
        )];
        let bound = bind(&specs, &[], "spawn a turtle at x 2 y 3", None);
        let branch = &bound[0].parameters["anyOf"][0];
        assert_eq!(
            branch["properties"]["request"]["required"],
            json!(["x", "y"])
        );
        assert_eq!(branch["required"], json!(["service", "request"]));
        // Nothing given: nothing required beyond the declared.
        let bound = bind(&specs, &[], "spawn a turtle", None);
        assert_eq!(bound[0].parameters, specs[0].parameters);
    }

    #[test]
    fn a_computing_tools_expression_is_the_one_said_in_words() {
        let mut eval = spec(
            "evaluate",
            json!({"type": "object", "properties": {"expression": {"type": "string"}},
              "required": ["expression"]}),
        );
        eval.computes = true;
        let held = |request: &str| {
            bind(&[eval.clone()], &[], request, None)[0]
                .parameters
                .clone()
        };
        assert_eq!(
            held("und wie viel sind 14 mal 3?")["properties"]["expression"],
            json!({"type": "string", "enum": ["14 * 3"]})
        );
        // Nothing said in words, or a tool that computes nothing: as declared.
        assert_eq!(held("what is 14*3?"), eval.parameters);
        let mut plain = eval.clone();
        plain.computes = false;
        assert_eq!(
            bind(&[plain.clone()], &[], "14 times 3", None)[0].parameters,
            plain.parameters
        );
    }

    #[test]
    fn the_unit_after_the_number_is_the_one_converted_from() {
        let kind = |units: &[&str]| {
            let unit = |role: &str| json!({"type": "string", "enum": units, UNIT: role});
            json!({"type": "object", "properties": {
                "value": {"type": "number"}, "from": unit("from"), "to": unit("to")},
              "required": ["value", "from", "to"]})
        };
        let specs = [spec(
            "convert",
            json!({"anyOf": [
                kind(&["m", "meters", "in", "inches", "yd", "yards"]),
                kind(&["deg", "grad", "rad", "degrees"]),
                kind(&["C", "grad celsius", "K", "kelvin"]),
            ]}),
        )];
        let held = |request: &str| {
            let bound = bind(&specs, &[], request, None);
            let branches = bound[0].parameters["anyOf"].as_array().unwrap().clone();
            assert!(!branches.iter().any(|b| b.to_string().contains(UNIT)));
            branches
                .iter()
                .map(|b| {
                    let p = &b["properties"];
                    (p["from"]["enum"].clone(), p["to"]["enum"].clone())
                })
                .collect::<Vec<_>>()
        };
        // The unit after the number is `from`, whichever is said first; the "in" that
        // joins two units is not the one asked for, the "in" at the end is.
        assert_eq!(
            held("how many meters is 12 yards?"),
            [(json!(["yards"]), json!(["meters"]))]
        );
        assert_eq!(
            held("12 yards in meters please"),
            [(json!(["yards"]), json!(["meters"]))]
        );
        assert_eq!(
            held("and meters in 4 yd?"),
            [(json!(["yd"]), json!(["meters"]))]
        );
        assert_eq!(held("put 2 m in in"), [(json!(["m"]), json!(["in"]))]);
        // Written against the number, in another language, of several words.
        assert_eq!(
            held("wie viel Kelvin sind 30 Grad Celsius?"),
            [(json!(["grad celsius"]), json!(["kelvin"]))]
        );
        assert_eq!(
            held("90grad sind wie viel rad"),
            [(json!(["grad"]), json!(["rad"]))]
        );
        // No number: a returned amount asked in the unit written, from any other; a
        // unit an everyday word spells is not read so.
        assert_eq!(
            held("what is the elbow at, in degrees?"),
            [(json!(["rad"]), json!(["deg"]))]
        );
        assert_eq!(held("put the arm in the box").len(), 3);
        // Asked of no other unit: any other of the kind.
        assert_eq!(
            held("say 3 inches another way"),
            [(json!(["inches"]), json!(["m", "meters", "yd", "yards"]))]
        );
        // Asked to convert: an amount in one unit and another of its kind; an amount in
        // one unit alone says how far to go.
        let schema = &specs[0].parameters;
        assert!(asks_a_conversion(schema, "how many meters is 12 yards?"));
        assert!(asks_a_conversion(schema, "30 Grad Celsius in Kelvin"));
        for request in [
            "drive 12 yards",
            "convert meters to yards",
            "12 yards and 3 m",
        ] {
            assert!(!asks_a_conversion(schema, request), "{request}");
        }
        // No unit after a number: as declared, less the marks.
        assert_eq!(held("convert meters to yards").len(), 3);
        assert_eq!(
            held("how far is it")[0].0,
            json!(["m", "meters", "in", "inches", "yd", "yards"])
        );
    }

    #[test]
    fn a_choice_of_known_names_is_held_to_those_the_words_point_at() {
        let params = [
            "background_b",
            "background_g",
            "background_r",
            "use_sim_time",
        ];
        let specs = [spec(
            "ros_param_get",
            json!({"anyOf": [{"type": "object", "properties": {
                "node": {"type": "string", "const": "/turtlesim"},
                "name": {"anyOf": [{"type": "string", "enum": params}, {"type": "string"}]}},
              "required": ["node", "name"]}]}),
        )];
        let names = [("node".to_string(), "/turtlesim".to_string())];
        let held = |request: &str| {
            let bound = bind(&specs, &names, request, None);
            bound[0].parameters["anyOf"][0]["properties"]["name"]["enum"].clone()
        };
        // A name's short word meets the word it shortens, not one the name has whole.
        assert_eq!(
            held("change the blue of the background to 10"),
            json!(["background_b"])
        );
        assert_eq!(
            held("how much red is in the background?"),
            json!(["background_r"])
        );
        // A name written whole is the only one; one the node lacks stays possible (but
        // not a name the robot has for something else).
        assert_eq!(
            held("what value does background_g hold?"),
            json!(["background_g"])
        );
        let mut lacked = params.to_vec();
        lacked.insert(3, "max_speed");
        assert_eq!(held("what is max_speed on /turtlesim?"), json!(lacked));
        // Words that point at none leave them all.
        assert_eq!(held("show me a parameter"), json!(params));
    }

    #[test]
    fn a_reading_tool_takes_the_heard_topics_and_a_silent_one_written() {
        // The tool offers the topics some node publishes; the robot also has a command
        // topic nobody publishes on.
        let heard = ["/arm/state", "/wrist/force"];
        let specs = [spec(
            "ros_topic_echo",
            json!({"type": "object", "properties": {
                "topic": {"anyOf": [{"type": "string", "enum": heard}, {"type": "string"}]}},
              "required": ["topic"]}),
        )];
        let names: Vec<(String, String)> = ["/arm/state", "/wrist/force", "/arm/command"]
            .iter()
            .map(|n| ("topic".to_string(), n.to_string()))
            .collect();
        let held = |request: &str| {
            let bound = bind(&specs, &names, request, None);
            bound[0].parameters["properties"]["topic"]["enum"].clone()
        };
        // "arm" meets a heard topic and a silent one: only the heard one is offered.
        assert_eq!(held("what is the arm doing?"), json!(["/arm/state"]));
        // A silent topic the operator writes stays possible: reading it says so.
        assert_eq!(held("echo /arm/command"), json!(["/arm/command"]));
        // A topic the robot lacks, with words that point at none it has: that one.
        assert_eq!(held("print what /odom says"), json!(["/odom"]));
        // A name of another kind written is not taken for a topic.
        let mut with_node = names.clone();
        with_node.push(("node".to_string(), "/wrist".to_string()));
        let bound = bind(&specs, &with_node, "what does /wrist feel?", None);
        assert_eq!(
            bound[0].parameters["properties"]["topic"]["enum"],
            json!(["/wrist/force"])
        );
    }

    #[test]
    fn a_name_the_robot_has_as_a_parameter_is_no_missing_service() {
        let specs = [
            spec(
                "param_get",
                json!({"type": "object", "properties": {
                    "name": {"anyOf": [{"type": "string", "enum": ["max_grip", "speed_scale"]},
                                       {"type": "string"}]}},
                  "required": ["name"]}),
            ),
            spec(
                "service_info",
                json!({"type": "object", "properties": {"service": {"type": "string"}},
                  "required": ["service"]}),
            ),
        ];
        let names = [("service".to_string(), "/gripper/calibrate".to_string())];
        let bound = bind(&specs, &names, "what is speed_scale now?", None);
        assert_eq!(
            bound[1].parameters["properties"]["service"]["enum"],
            json!(["/gripper/calibrate"])
        );
        // A name the robot has under no key stays possible for a service.
        let bound = bind(&specs, &names, "describe gripper/home", None);
        assert_eq!(
            bound[1].parameters["properties"]["service"]["enum"],
            json!(["/gripper/calibrate", "gripper/home"])
        );
    }

    #[test]
    fn meaning_narrows_the_names_the_words_point_at_alike() {
        let specs = [spec(
            "ros_topic_echo",
            json!({"type": "object", "properties": {"topic": {"type": "string"}},
              "required": ["topic"]}),
        )];
        let names: Vec<(String, String)> = ["/arm/state", "/arm/pose", "/wrist/force"]
            .iter()
            .map(|n| ("topic".to_string(), n.to_string()))
            .collect();
        let near = |n: &str| match n {
            "/arm/state" => 0.40,
            "/arm/pose" => 0.35,
            _ => 0.38,
        };
        let held = |request: &str, near: Option<&dyn Fn(&str) -> f64>| {
            let bound = bind(&specs, &names, request, near);
            bound[0].parameters["properties"]["topic"]["enum"].clone()
        };
        // The words point at both arm topics; meaning at one.
        assert_eq!(
            held("what is the arm doing?", None),
            json!(["/arm/pose", "/arm/state"])
        );
        assert_eq!(
            held("what is the arm doing?", Some(&near)),
            json!(["/arm/state"])
        );
        // Words that point at none: the nearest and those within the margin.
        assert_eq!(
            held("anything new?", Some(&near)),
            json!(["/arm/state", "/wrist/force"])
        );
        // A name the words point at alone stays, however far by meaning.
        assert_eq!(
            held("what does the wrist feel?", Some(&near)),
            json!(["/wrist/force"])
        );
        // A word said with an ending points at the name that has it bare.
        assert_eq!(held("show the forces", None), json!(["/wrist/force"]));
    }

    #[test]
    fn a_quote_is_words_the_request_ends_with() {
        let mut schema = json!({"type": "object", "properties": {
            "fact": {"type": "string", "x-quote": true},
            "other": {"type": "string"}}});
        quote(&mut schema, "keep in mind: the red valve leaks!");
        assert_eq!(
            schema["properties"]["fact"]["enum"],
            json!([
                "red valve leaks",
                "the red valve leaks",
                "mind: the red valve leaks",
                "in mind: the red valve leaks",
                "keep in mind: the red valve leaks"
            ])
        );
        assert_eq!(schema["properties"]["other"], json!({"type": "string"}));
    }
}
