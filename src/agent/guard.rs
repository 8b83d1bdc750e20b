//! The guards: what a step's calls pass between the model's turn and the policy, in the
//! order `Guards::standard` lists them. A guard may narrow the tools a step offers
//! before the model is asked, and judge (or edit) the calls it made after.
//!
//! - `Grounded`: optional arguments nobody asked for (a filter, a number neither said,
//!   returned nor the default) are dropped (`strategy::ground`); a tool that computes
//!   from numbers the operator gives is not offered before one is said or returned.
//! - `SaidOrder` (`said_order`): a route (a tool's `sequence`) is put in the order the
//!   request names its places.
//! - `Signed`: a motion's amount takes the sign the request's direction words name
//!   (REP 103: backward and clockwise are negative).
//! - `NoRepeat`: a call already made this run (whether it succeeded, was refused or
//!   failed) is not made again; a turn of nothing but repeats leaves the next step only
//!   the answer; a tool whose calls failed or were refused twice is offered no more
//!   this run (a small model otherwise varies the arguments of a failing call until the
//!   step limit).
//! - `FollowError`: after a call fails with an error that names a tool ("call
//!   ros_topic_list to see the topics"), the next step offers that tool and the answer.
//! - `AskedFor`: an actuating call runs only when the operator's request points at it
//!   (`intent`); tools it cannot point at are not offered.
//! - `ActFirst`: a request (or a part of one, `plan`) that asks for an act a dedicated
//!   actuator is named for ("mueve la tortuga" and `turtle_move`) gets an actuating
//!   call before any answer: its first step offers the actuators only (of which
//!   `AskedFor` keeps those the request may ask for). A small model otherwise often
//!   answers "moving the turtle" without moving it, most of all outside English.
//! - `NoSubstitute`: once an act of a part failed or was refused, no other act is made
//!   in that part (a drive to a place the robot lacks is not replaced by a drive ahead),
//!   nor is anything recorded (the pose the drive never left taught as the place).
//!
//! The policy (`tool::Policy`: deny-list, limits, confirmation) comes after all of them.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use serde_json::Value;

use crate::reading::concepts::{acts_of, asked_acts, clauses, signs, Act};
use crate::reading::intent::{
    is_generic, name_words, names_target, targets_known, writes_name, Intent, TARGET_KEYS,
};
use crate::strategy::ground::Grounding;
use crate::strategy::Strategy;
use crate::tool::{Effect, Policy, ToolCall, ToolSpec};

/// What a guard says of one call.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// On to the policy.
    Pass,
    /// Not made, and not shown to the model as a call (a repeat).
    Skip,
    /// Not made; the reason is what the model reads.
    Refuse(String),
}

/// What came of a call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Came {
    Ran,
    /// Refused by the policy (a limit, the deny-list, the e-stop, the operator).
    Refused,
    /// Refused by a guard before the policy saw it (a call the request did not ask
    /// for): the model's mistake, not the robot's answer.
    TurnedDown,
    Failed,
}

impl Came {
    /// Asking again would get the same: it ran, or was refused.
    pub fn done(self) -> bool {
        self != Came::Failed
    }
}

/// One guard (see the module header).
pub(crate) trait Guard {
    fn name(&self) -> &'static str;

    /// Before the model's turn: the tools this step may call, of those `offered` (`None`:
    /// all of them).
    /// Whether a tool (`declared`), its arguments as this step's grammar takes them
    /// (`bound`, see `reading::bound`), may be offered: `false` when every call it could
    /// write would be refused.
    fn keeps(&self, _declared: &ToolSpec, _bound: &ToolSpec) -> bool {
        true
    }
    fn narrow(&self, _offered: &[ToolSpec]) -> Option<Vec<String>> {
        None
    }

    /// After the turn: one verdict per call (calls may be edited).
    fn check(&mut self, calls: &mut [ToolCall], _offered: &[ToolSpec]) -> Vec<Verdict> {
        vec![Verdict::Pass; calls.len()]
    }

    /// After the calls ran: what came of one, and the text the model was shown.
    fn observe(&mut self, _call: &ToolCall, _came: Came, _shown: &str) {}

    /// The run moved on to the next part of the request (`plan`): what held for the
    /// last part's steps no longer does.
    fn next_part(&mut self, _part: &str) {}

    /// The robot's names the current part asks to act on by meaning
    /// (`reading::meant`), read again for each part.
    fn by_meaning(&mut self, _meant: &[String]) {}
}

/// The guards of a run, in order.
pub(crate) struct Guards {
    guards: Vec<Box<dyn Guard>>,
}

impl Guards {
    /// The guards every run has: grounding, no repeats, and (with `asked`) actuation only
    /// when asked for. `said` is what the operator said this session (optional numbers
    /// are held to `query`'s alone).
    pub fn standard(query: &str, said: &[&str], asked: Option<Asked>) -> Guards {
        let mut guards: Vec<Box<dyn Guard>> = vec![
            Box::new(Grounded {
                grounding: Grounding::new(said.iter().copied()).with_numbers_of(query),
                numbers: !crate::lexicon::numbers(query).is_empty(),
            }),
            Box::new(super::said_order::SaidOrder::new(query)),
            Box::new(NoRepeat::default()),
            Box::new(FollowError::default()),
        ];
        guards.push(Box::new(Signed(signs(query))));
        if let Some(asked) = asked {
            let actuators = asked.actuators.clone();
            let effects = asked.effects.clone();
            let records = asked.records.clone();
            guards.push(Box::new(AskedFor {
                intent: Intent::new(query),
                asked,
                called: false,
                meant: Vec::new(),
                part: None,
                before: None,
                part_text: None,
            }));
            guards.push(Box::new(ActFirst::new(query, actuators)));
            guards.push(Box::new(NoSubstitute::new(effects, records)));
        }
        Guards { guards }
    }

    /// Their names, in order.
    pub fn names(&self) -> Vec<&'static str> {
        self.guards.iter().map(|g| g.name()).collect()
    }

    /// The tools this step may call: those every guard allows.
    pub fn narrow(&self, offered: &[ToolSpec]) -> Option<Vec<String>> {
        self.narrow_without(offered, "")
    }

    /// `narrow` with every guard but the one called `skip`.
    pub(crate) fn narrow_without(&self, offered: &[ToolSpec], skip: &str) -> Option<Vec<String>> {
        let mut allowed: Option<Vec<String>> = None;
        for g in self.guards.iter().filter(|g| g.name() != skip) {
            if let Some(names) = g.narrow(offered) {
                let kept: Vec<String> = match &allowed {
                    None => names,
                    Some(prev) => prev.iter().filter(|n| names.contains(n)).cloned().collect(),
                };
                // A guard that would leave nothing to write is passed over (the guards
                // that judge calls after the turn still do).
                if !kept.is_empty() {
                    allowed = Some(kept);
                }
            }
        }
        allowed
    }

    /// Whether every guard keeps a tool with its arguments as bound (`Guard::keeps`).
    pub fn keeps(&self, declared: &ToolSpec, bound: &ToolSpec) -> bool {
        self.guards.iter().all(|g| g.keeps(declared, bound))
    }

    /// Each call's verdict: the first guard that does not pass it decides.
    pub fn check(&mut self, calls: &mut [ToolCall], offered: &[ToolSpec]) -> Vec<Verdict> {
        let mut verdicts = vec![Verdict::Pass; calls.len()];
        for g in &mut self.guards {
            let said = g.check(calls, offered);
            for (v, s) in verdicts.iter_mut().zip(said) {
                if *v == Verdict::Pass {
                    *v = s;
                }
            }
        }
        verdicts
    }

    pub fn observe(&mut self, call: &ToolCall, came: Came, shown: &str) {
        for g in &mut self.guards {
            g.observe(call, came, shown);
        }
    }

    pub(crate) fn next_part(&mut self, part: &str) {
        for g in &mut self.guards {
            g.next_part(part);
        }
    }

    pub(crate) fn by_meaning(&mut self, meant: &[String]) {
        for g in &mut self.guards {
            g.by_meaning(meant);
        }
    }
}

/// Grounding of optional arguments against what the operator said and tools returned,
/// and of the numbers a tool computes from.
struct Grounded {
    grounding: Grounding,
    /// Whether the request or a result of this run spells a number.
    numbers: bool,
}

impl Guard for Grounded {
    fn name(&self) -> &'static str {
        "grounded"
    }

    /// A tool that computes from numbers the operator gives
    /// (`ToolSpec::waits_for_numbers`) is not offered while nothing said or returned
    /// spells one: a small model calls it on a greeting with numbers of its own
    /// ("1, 2, 3, … 32"), and its result is about nothing anyone asked; asked a joint's
    /// angle in degrees, it wrote an expression of letters.
    fn narrow(&self, offered: &[ToolSpec]) -> Option<Vec<String>> {
        if self.numbers {
            return None;
        }
        let kept: Vec<String> = offered
            .iter()
            .filter(|s| !s.waits_for_numbers())
            .map(|s| s.name.clone())
            .collect();
        (kept.len() < offered.len()).then_some(kept)
    }

    fn check(&mut self, calls: &mut [ToolCall], offered: &[ToolSpec]) -> Vec<Verdict> {
        for c in calls.iter_mut() {
            if let Some(spec) = offered.iter().find(|s| s.name == c.name) {
                let dropped = self.grounding.settle(c, spec);
                if !dropped.is_empty() {
                    tracing::debug!(tool = %c.name, ?dropped, "ungrounded arguments dropped");
                }
            }
        }
        vec![Verdict::Pass; calls.len()]
    }

    fn observe(&mut self, _: &ToolCall, _: Came, shown: &str) {
        self.grounding.add(shown);
        self.numbers |= !crate::lexicon::numbers(shown).is_empty();
    }
}

/// The sign of a motion's amount, from the request's direction words (`concepts::signs`,
/// REP 103): a small model writes "turn right 90 degrees" as +90 (to the left) and
/// "backward 1 meter" as +1. An amount is signed when its parameter says what a
/// negative value means ("negative drives backward", "positive is counter-clockwise")
/// or it is a twist's `linear/x` or `angular/z`; it is given the sign the words name.
struct Signed((Option<bool>, Option<bool>));

impl Guard for Signed {
    fn name(&self) -> &'static str {
        "signed"
    }

    fn check(&mut self, calls: &mut [ToolCall], offered: &[ToolSpec]) -> Vec<Verdict> {
        let (linear, angular) = self.0;
        if linear.is_some() || angular.is_some() {
            for c in calls.iter_mut() {
                let schema = offered
                    .iter()
                    .find(|s| s.name == c.name)
                    .map(|s| &s.parameters);
                let before = c.arguments.clone();
                sign_amounts(&mut c.arguments, schema, "", self.0);
                if c.arguments != before {
                    tracing::debug!(tool = %c.name, from = %before, to = %c.arguments, "signed by the request's direction");
                }
            }
        }
        vec![Verdict::Pass; calls.len()]
    }

    fn next_part(&mut self, part: &str) {
        self.0 = signs(part);
    }
}

/// Give each signed amount in `value` (at `path`, its schema `schema` when known) the
/// sign `negative` names, (linear, angular).
fn sign_amounts(
    value: &mut Value,
    schema: Option<&Value>,
    path: &str,
    negative: (Option<bool>, Option<bool>),
) {
    match value {
        Value::Object(map) => {
            for (k, v) in map.iter_mut() {
                let sub = schema
                    .and_then(|s| s.get("properties"))
                    .and_then(|p| p.get(k));
                sign_amounts(v, sub, &format!("{path}/{k}"), negative);
            }
        }
        Value::Number(n) => {
            let about = schema
                .and_then(|s| s.get("description"))
                .and_then(Value::as_str)
                .unwrap_or_default()
                .to_lowercase();
            let which = if about.contains("backward") || path.ends_with("linear/x") {
                negative.0
            } else if about.contains("counter-clockwise")
                || about.contains("counterclockwise")
                || path.ends_with("angular/z")
            {
                negative.1
            } else {
                None
            };
            if let (Some(neg), Some(x)) = (which, n.as_f64()) {
                if x != 0.0 && (x < 0.0) != neg {
                    let flipped = if neg { -x.abs() } else { x.abs() };
                    if let Some(f) = serde_json::Number::from_f64(flipped) {
                        *n = if n.is_f64() || flipped.fract() != 0.0 {
                            f
                        } else {
                            serde_json::Number::from(flipped as i64)
                        };
                    }
                }
            }
        }
        _ => {}
    }
}

/// Calls already made this run (name and arguments). Small models repeat a call after it
/// succeeded (or was refused); a repeat gets the same result, so the next step offers
/// only the answer.
#[derive(Default)]
struct NoRepeat {
    done: Vec<(String, Value)>,
    answer_only: bool,
    /// Calls of each tool that failed or were refused.
    misses: BTreeMap<String, usize>,
}

/// Misses after which a tool is offered no more.
const MAX_MISSES: usize = 2;

impl Guard for NoRepeat {
    fn name(&self) -> &'static str {
        "no-repeat"
    }

    fn narrow(&self, offered: &[ToolSpec]) -> Option<Vec<String>> {
        if self.answer_only {
            return Some(vec![super::answer::ANSWER_TOOL.to_string()]);
        }
        let spent = |n: &String| self.misses.get(n).is_some_and(|m| *m >= MAX_MISSES);
        let left: Vec<String> = offered
            .iter()
            .map(|s| s.name.clone())
            .filter(|n| !spent(n))
            .collect();
        (left.len() < offered.len()).then_some(left)
    }

    fn check(&mut self, calls: &mut [ToolCall], _: &[ToolSpec]) -> Vec<Verdict> {
        let verdicts: Vec<Verdict> = calls
            .iter()
            .map(|c| {
                let repeat = self
                    .done
                    .iter()
                    .any(|(n, a)| *n == c.name && same_value(a, &c.arguments));
                if repeat {
                    Verdict::Skip
                } else {
                    Verdict::Pass
                }
            })
            .collect();
        if !verdicts.is_empty() && verdicts.iter().all(|v| *v == Verdict::Skip) {
            self.answer_only = true;
        }
        verdicts
    }

    fn observe(&mut self, call: &ToolCall, came: Came, _: &str) {
        // A failed call fails the same way again: it is as done as one that ran.
        self.done.push((call.name.clone(), call.arguments.clone()));
        if came != Came::Ran {
            *self.misses.entry(call.name.clone()).or_default() += 1;
        }
    }

    fn next_part(&mut self, _: &str) {
        self.answer_only = false;
    }
}

/// The next step an error names. A small model that reads "no topic /x; call
/// ros_topic_list to see the topics" tends to try /x again or give up; the step after a
/// failure offers the tools the error names (with the answer), once.
#[derive(Default)]
struct FollowError {
    /// The text of the last failure, until the step after it.
    error: Option<String>,
}

impl Guard for FollowError {
    fn name(&self) -> &'static str {
        "follow-error"
    }

    fn narrow(&self, offered: &[ToolSpec]) -> Option<Vec<String>> {
        let error = self.error.as_deref()?;
        let named: Vec<String> = offered
            .iter()
            .filter(|s| s.name != super::answer::ANSWER_TOOL && names_tool(error, &s.name))
            .map(|s| s.name.clone())
            .collect();
        if named.is_empty() {
            return None;
        }
        Some(
            named
                .into_iter()
                .chain([super::answer::ANSWER_TOOL.to_string()])
                .collect(),
        )
    }

    fn check(&mut self, calls: &mut [ToolCall], _: &[ToolSpec]) -> Vec<Verdict> {
        self.error = None;
        vec![Verdict::Pass; calls.len()]
    }

    fn observe(&mut self, _: &ToolCall, came: Came, shown: &str) {
        if !came.done() {
            self.error = Some(shown.to_string());
        }
    }

    fn next_part(&mut self, _: &str) {
        self.error = None;
    }
}

/// `text` names `tool` as a word of its own.
fn names_tool(text: &str, tool: &str) -> bool {
    text.match_indices(tool).any(|(i, _)| {
        let word = |c: char| c.is_alphanumeric() || c == '_';
        let before = text[..i].chars().next_back().is_none_or(|c| !word(c));
        let after = text[i + tool.len()..]
            .chars()
            .next()
            .is_none_or(|c| !word(c));
        before && after
    })
}

/// What the actuation guard needs to know of the tools.
#[derive(Clone)]
pub struct Asked {
    pub policy: Arc<Policy>,
    /// Each tool's declared effect.
    pub effects: BTreeMap<String, Effect>,
    /// Tools whose calls record what the agent keeps (`ToolSpec::records`).
    pub records: BTreeSet<String>,
    /// Tools whose every call actuates (no `observes` rule covers one).
    pub actuators: BTreeSet<String>,
    /// The words of all the other tools.
    pub observing: BTreeSet<String>,
    /// The names each actuator's targets take now, where its live schema lists them
    /// (a place's names and aliases): filled in per run (`with_known`).
    pub known: BTreeMap<String, Vec<String>>,
}

impl Asked {
    /// These, with the names the actuators' targets take now, read from `live` (each
    /// actuator's arguments as the robot can take them: `Tool::live_parameters`).
    pub(crate) fn with_known(mut self, live: impl Fn(&str) -> Option<Value>) -> Asked {
        self.known = self
            .actuators
            .iter()
            .filter_map(|name| {
                let names = offered_names(&live(name)?);
                (!names.is_empty()).then(|| (name.clone(), names))
            })
            .collect();
        self
    }
}

/// The names a schema's target properties suggest (`bound::suggested`: a choice of
/// known names beside any other).
fn offered_names(schema: &Value) -> Vec<String> {
    let Some(props) = schema.get("properties").and_then(Value::as_object) else {
        return Vec::new();
    };
    props
        .iter()
        .filter(|(k, _)| TARGET_KEYS.contains(&k.as_str()))
        .filter_map(|(_, p)| crate::reading::bound::suggested(p))
        .flatten()
        .collect()
}

/// Actuation the operator asked for (see `intent`).
struct AskedFor {
    intent: Intent,
    asked: Asked,
    /// A call of this part was written: a name the robot lacks, said in words, is
    /// asked for on the part's first step only (a request to drive two metres ahead
    /// drove, then tried a place called "ahead").
    called: bool,
    /// The names the current part asks to act on by meaning (`reading::meant`).
    meant: Vec<String>,
    /// The current part, read on its own, of a request of several: a call is asked for
    /// by its words too ("shut the gripper, then say how wide it is open" asks to
    /// open nothing, though "gripper" and "open" are both said).
    part: Option<Intent>,
    /// The part before the current one, for a part that asks for an act on what that
    /// part named (`Intent::acts_on_unnamed`).
    before: Option<String>,
    /// The current part's text.
    part_text: Option<String>,
}

impl AskedFor {
    fn known(&self, tool: &str) -> &[String] {
        self.asked.known.get(tool).map_or(&[], Vec::as_slice)
    }

    /// Whether the request asks for `call` of `spec` (see `intent`), this step.
    /// `later`: another call of the part was written before this one.
    fn asks(&self, call: &ToolCall, spec: &ToolSpec, later: bool) -> bool {
        let known = self.known(&call.name);
        if (self.called || later) && !known.is_empty() && !targets_known(call, known) {
            return false;
        }
        self.meant_for(call, spec) || self.by_words(call, spec)
    }

    /// Whether the request's words ask for `call` (`intent`), the current part's too.
    fn by_words(&self, call: &ToolCall, spec: &ToolSpec) -> bool {
        let known = self.known(&call.name);
        let asks =
            |intent: &Intent| intent.asks_for_known(call, spec, &self.asked.observing, known);
        // A part that points back and writes no name of its own acts on a target the
        // part before wrote whole ("read lamp_level, then change it to 20"); the whole
        // request must still ask for the call.
        let refers_back = |part: &Intent| {
            part.acts_on_unnamed(call, spec)
                && self.part_text.as_deref().is_some_and(|p| !writes_name(p))
                && self
                    .before
                    .as_deref()
                    .is_some_and(|b| names_target(b, call))
        };
        let part_asks = |part: &Intent| asks(part) || refers_back(part);
        // The part's own words hold a generic actuator only: a tool that names its act
        // ("turn left, then right 45") is read with the whole request.
        asks(&self.intent)
            && (!is_generic(spec) || self.part.as_ref().is_none_or(part_asks))
            && !self.meant_otherwise(call, spec)
    }

    /// Whether the part, by meaning, asks to act on a name that shares words with
    /// `call`'s target while none of the words only the target has are said: "close the
    /// gripper" shares "gripper" with `/gripper/open`, which is no reason to open it;
    /// "open" said would be. A target sharing no word with a meant name is not judged.
    fn meant_otherwise(&self, call: &ToolCall, spec: &ToolSpec) -> bool {
        if self.meant.is_empty() || !is_generic(spec) {
            return false;
        }
        let words = |n: &str| crate::lexicon::folded_words(&n.replace(['_', '/'], " "));
        let meant: BTreeSet<String> = self.meant.iter().flat_map(|m| words(m)).collect();
        acted_on(call)
            .filter(|t| !self.meant.iter().any(|m| same_name(m, t)))
            .any(|t| {
                let (shared, own): (Vec<String>, Vec<String>) =
                    words(t).into_iter().partition(|w| meant.contains(w));
                !shared.is_empty() && !own.is_empty() && !self.intent.says(&own)
            })
    }

    /// Whether `call` of the generic actuator `spec` acts only on names the part asks
    /// to act on by meaning (a setting is still changed only when asked, as `intent`
    /// holds it).
    fn meant_for(&self, call: &ToolCall, spec: &ToolSpec) -> bool {
        if self.meant.is_empty()
            || !is_generic(spec)
            || !self.intent.may_ask_for(spec, &self.asked.observing)
        {
            return false;
        }
        let targets: Vec<&str> = acted_on(call).collect();
        !targets.is_empty()
            && targets
                .iter()
                .all(|t| self.meant.iter().any(|m| same_name(m, t)))
            && call
                .arguments
                .as_object()
                .into_iter()
                .flatten()
                .filter(|(k, _)| !MEANT_KEYS.contains(&k.as_str()))
                .all(|(_, v)| self.said_values(v))
    }

    /// Whether every value in `v` is one the request says, or none at all: a number it
    /// writes (zero beside numbers it writes), a text whose words it says side by side;
    /// never a yes or no. Meaning
    /// points at a name, not at values: "take the turtle up to the stars" is near a teleport,
    /// and the numbers of one were the model's own.
    fn said_values(&self, v: &Value) -> bool {
        match v {
            Value::Number(n) => n.as_f64().is_some_and(|n| {
                self.intent.says_number(n) || (n == 0.0 && self.intent.says_numbers())
            }),
            Value::String(s) => s.trim().is_empty() || self.intent.says_name(s),
            Value::Array(items) => items.iter().all(|i| self.said_values(i)),
            Value::Object(fields) => fields.values().all(|f| self.said_values(f)),
            // On or off is the act itself ("std_srvs/SetBool"): meaning does not say
            // which.
            Value::Bool(_) => false,
            Value::Null => true,
        }
    }
}

/// The branch of a choice of objects (`Tool::live_parameters`) whose `key` is `target`.
fn branch_of<'a>(schema: &'a Value, key: &str, target: &str) -> Option<&'a Value> {
    schema
        .get("anyOf")?
        .as_array()?
        .iter()
        .find(|b| b["properties"][key]["const"].as_str() == Some(target))
}

/// Whether two ROS names are one, written with or without the leading slash.
fn same_name(a: &str, b: &str) -> bool {
    a.trim_start_matches('/') == b.trim_start_matches('/')
}

/// The arguments that name what a generic actuator acts on, as `reading::meant` reads it.
const MEANT_KEYS: &[&str] = &["service", "topic", "action"];

/// The names `call` acts on (`MEANT_KEYS`).
fn acted_on(call: &ToolCall) -> impl Iterator<Item = &str> {
    MEANT_KEYS
        .iter()
        .filter_map(|k| call.arguments.get(*k).and_then(Value::as_str))
}

impl Guard for AskedFor {
    fn name(&self) -> &'static str {
        "asked-for"
    }

    fn narrow(&self, offered: &[ToolSpec]) -> Option<Vec<String>> {
        let askable: Vec<String> = offered
            .iter()
            .filter(|s| {
                !self.asked.actuators.contains(&s.name)
                    || self.intent.may_ask_for(s, &self.asked.observing)
            })
            .map(|s| s.name.clone())
            .collect();
        (askable.len() < offered.len()).then_some(askable)
    }

    /// A generic actuator whose grammar holds its targets to names (`reading::bound`) is
    /// kept only when the request asks for one of them: "upload the map to a server" asks
    /// nothing of `/clear`, `/kill` or `/spawn`, so the service call is not written (and
    /// refused).
    ///
    /// An actuator that names its act (`place_forget`) and takes one of the robot's
    /// names is kept only when the request says one of them: "delete all files" names
    /// no place to forget.
    fn keeps(&self, declared: &ToolSpec, bound: &ToolSpec) -> bool {
        if !self.asked.actuators.contains(&bound.name) {
            return true;
        }
        if !is_generic(declared) {
            let known = self.known(&bound.name);
            return known.is_empty() || known.iter().any(|k| self.intent.says_name(k));
        }
        let Some(targets) = bound_targets(&bound.parameters) else {
            return true;
        };
        targets.into_iter().any(|(key, target)| {
            let call = ToolCall {
                name: bound.name.clone(),
                arguments: serde_json::json!({ key.clone(): target.clone() }),
            };
            // Asked for by meaning alone, a target whose payload takes numbers is
            // written only when the request gives some, and one that takes a yes or no
            // never: else each would be the model's.
            let invents = || {
                let branch = branch_of(&bound.parameters, &key, &target);
                let numbers = !self.intent.says_numbers()
                    && branch
                        .is_some_and(|b| crate::tool::schema::takes(b, &["number", "integer"]));
                (numbers || branch.is_some_and(|b| crate::tool::schema::takes(b, &["boolean"])))
                    && !self.by_words(&call, declared)
            };
            self.asks(&call, declared, false) && !invents()
        })
    }

    fn next_part(&mut self, part: &str) {
        self.called = false;
        self.part = Some(Intent::new(part));
        self.before = self.part_text.replace(part.to_string());
    }

    fn by_meaning(&mut self, meant: &[String]) {
        self.meant = meant.to_vec();
    }

    fn check(&mut self, calls: &mut [ToolCall], offered: &[ToolSpec]) -> Vec<Verdict> {
        let verdicts = self.verdicts(calls, offered);
        self.called |= !calls.is_empty();
        verdicts
    }
}

impl AskedFor {
    fn verdicts(&self, calls: &[ToolCall], offered: &[ToolSpec]) -> Vec<Verdict> {
        calls
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let spec = offered.iter().find(|s| s.name == c.name);
                let effect = self.asked.effects.get(&c.name).copied();
                let actuates = effect.is_some_and(|e| self.asked.policy.actuates(e, c));
                let unasked = actuates && spec.is_some_and(|s| !self.asks(c, s, i > 0));
                if unasked {
                    Verdict::Refuse(format!(
                        "the operator did not ask for {}: no word of the request points at it or at its target; do not act, answer instead",
                        c.name
                    ))
                } else {
                    Verdict::Pass
                }
            })
            .collect()
    }
}

/// The names the target arguments (`intent::TARGET_KEYS`) of `schema` (an object, or a
/// choice of objects) may take, each with its key; `None` when one of them may be any
/// string, or when there is none.
pub(super) fn bound_targets(schema: &Value) -> Option<Vec<(String, String)>> {
    let objects: Vec<&Value> = match schema.get("anyOf").and_then(Value::as_array) {
        Some(branches) => branches.iter().collect(),
        None => vec![schema],
    };
    let mut out = Vec::new();
    for object in objects {
        let props = object.get("properties")?.as_object()?;
        let mut any = false;
        for (key, prop) in props
            .iter()
            .filter(|(k, _)| TARGET_KEYS.contains(&k.as_str()))
        {
            let values: Vec<&str> = match (prop.get("const"), prop.get("enum")) {
                (Some(c), _) => vec![c.as_str()?],
                (None, Some(Value::Array(e))) => e.iter().filter_map(Value::as_str).collect(),
                _ => return None,
            };
            out.extend(values.into_iter().map(|v| (key.clone(), v.to_string())));
            any = true;
        }
        if !any {
            return None;
        }
    }
    (!out.is_empty()).then_some(out)
}

/// The acts a request (part) asks for, until a step has called.
struct ActFirst {
    acts: Vec<Act>,
    actuators: BTreeSet<String>,
    tried: bool,
}

impl ActFirst {
    fn new(request: &str, actuators: BTreeSet<String>) -> ActFirst {
        // Words of names ("cmd_vel", "/turtle1/pose") are what a call acts on, not acts.
        let plain: Vec<&str> = request
            .split_whitespace()
            .filter(|w| !w.contains(['_', '/']))
            .collect();
        let acts = asked_acts(&clauses(&plain.join(" ")))
            .into_iter()
            .filter(|a| !matches!(a, Act::Stop | Act::Fence))
            .collect();
        ActFirst {
            acts,
            actuators,
            tried: false,
        }
    }
}

impl Guard for ActFirst {
    fn name(&self) -> &'static str {
        "act-first"
    }

    fn narrow(&self, offered: &[ToolSpec]) -> Option<Vec<String>> {
        if self.tried || self.acts.is_empty() {
            return None;
        }
        let actuators = || offered.iter().filter(|s| self.actuators.contains(&s.name));
        let named = actuators().any(|s| {
            !is_generic(s)
                && acts_of(&name_words(&s.name))
                    .iter()
                    .any(|a| self.acts.contains(a))
        });
        named.then(|| actuators().map(|s| s.name.clone()).collect())
    }

    fn check(&mut self, calls: &mut [ToolCall], _: &[ToolSpec]) -> Vec<Verdict> {
        self.tried = true;
        vec![Verdict::Pass; calls.len()]
    }

    fn next_part(&mut self, part: &str) {
        let actuators = std::mem::take(&mut self.actuators);
        *self = ActFirst::new(part, actuators);
    }
}

/// An act that failed or was refused is not replaced by another: once a call of a
/// tool that actuates failed or was refused by the policy, the part's later steps
/// offer no other such tool (the same one may be tried again; reads, stopping and the
/// answer stay). Asked to
/// drive to a place the robot does not know, a small model drove a metre ahead
/// instead; refused a drive by the fence, it reaches for a teleport.
struct NoSubstitute {
    effects: BTreeMap<String, Effect>,
    /// Tools that record what the agent keeps (a place taught at the robot's pose, a
    /// note): after a failed act, what they would record is not so ("drive to the
    /// library" failed, then the robot's pose was taught as the library); beside an act
    /// in one step, they would record the robot before the act is done.
    records: BTreeSet<String>,
    /// The act of this part that failed or was refused.
    failed: Option<String>,
    /// The first act of the run that failed or was refused: kept across parts, since a
    /// later part's "then save this spot as the library" is as untrue.
    run_failed: Option<String>,
}

impl NoSubstitute {
    fn new(effects: BTreeMap<String, Effect>, records: BTreeSet<String>) -> NoSubstitute {
        NoSubstitute {
            effects,
            records,
            failed: None,
            run_failed: None,
        }
    }

    /// Whether `tool` moves or changes the robot: stopping (`robot_stop`, a goal's
    /// cancel) is never held back.
    fn actuates(&self, tool: &str) -> bool {
        self.effects.get(tool) == Some(&Effect::Actuates)
    }

    fn other_act(&self, tool: &str) -> bool {
        self.failed
            .as_deref()
            .is_some_and(|failed| tool != failed && self.actuates(tool))
    }

    /// Whether `tool` would record after an act of the run came to nothing.
    fn untrue(&self, tool: &str) -> bool {
        self.run_failed.is_some() && self.records.contains(tool)
    }
}

impl Guard for NoSubstitute {
    fn name(&self) -> &'static str {
        "no-substitute"
    }

    fn narrow(&self, offered: &[ToolSpec]) -> Option<Vec<String>> {
        if self.failed.is_none() && self.run_failed.is_none() {
            return None;
        }
        Some(
            offered
                .iter()
                .filter(|s| !self.other_act(&s.name) && !self.untrue(&s.name))
                .map(|s| s.name.clone())
                .collect(),
        )
    }

    fn check(&mut self, calls: &mut [ToolCall], _: &[ToolSpec]) -> Vec<Verdict> {
        let acting = calls.iter().any(|c| self.actuates(&c.name));
        calls
            .iter()
            .map(|c| match (&self.failed, &self.run_failed) {
                (Some(failed), _) if self.other_act(&c.name) => Verdict::Refuse(format!(
                    "not made: {failed} came to nothing, and {} is not what the operator asked for; answer with what went wrong",
                    c.name
                )),
                (_, Some(failed)) if self.untrue(&c.name) => Verdict::Refuse(format!(
                    "not made: {failed} came to nothing, so what {} would record is not so; answer with what went wrong",
                    c.name
                )),
                _ if acting && self.records.contains(&c.name) => Verdict::Refuse(format!(
                    "not made: {} records the robot as it is, and the act beside it has not run yet; call it once the act is done",
                    c.name
                )),
                _ => Verdict::Pass,
            })
            .collect()
    }

    fn observe(&mut self, call: &ToolCall, came: Came, _: &str) {
        // A call a guard turned down was the model's mistake: the act the operator asked
        // for may still come.
        let came_to_nothing = matches!(came, Came::Refused | Came::Failed);
        if came_to_nothing && self.actuates(&call.name) {
            self.failed.get_or_insert_with(|| call.name.clone());
            self.run_failed.get_or_insert_with(|| call.name.clone());
        }
    }

    fn next_part(&mut self, _: &str) {
        self.failed = None;
    }
}

/// JSON equality with numbers compared by value (3 and 3.0 are the same argument).
pub(crate) fn same_value(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => x.as_f64() == y.as_f64(),
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| same_value(p, q))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| same_value(v, w)))
        }
        _ => a == b,
    }
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    fn spec(name: &str) -> ToolSpec {
        ToolSpec::new(name, "", json!({"type": "object", "properties": {}})).unwrap()
    }

    fn call(name: &str, arguments: Value) -> ToolCall {
        ToolCall {
            name: name.into(),
            arguments,
        }
    }

    #[test]
    fn a_failed_call_is_not_made_again() {
        let mut g = Guards::standard("read the battery", &[], None);
        let offered = [spec("ros_topic_echo"), spec("reply")];
        let c = call("ros_topic_echo", json!({"topic": "/Battery_Level"}));
        assert_eq!(
            g.check(&mut [c.clone()], &offered),
            [Verdict::Pass],
            "first time"
        );
        g.observe(&c, Came::Failed, "{\"error\": \"no topic /Battery_Level\"}");
        assert_eq!(g.check(&mut [c], &offered), [Verdict::Skip]);
        // A turn of nothing but repeats: only the answer is left.
        assert_eq!(g.narrow(&offered), Some(vec!["reply".to_string()]));
    }

    #[test]
    fn a_tool_that_missed_twice_is_offered_no_more() {
        let mut g = Guards::standard("publish on cmd_vel", &[], None);
        let offered = [
            spec("ros_topic_publish"),
            spec("turtle_pose"),
            spec("reply"),
        ];
        for (topic, came) in [("/a", Came::Refused), ("/b", Came::Failed)] {
            assert_eq!(g.narrow(&offered), None);
            let c = call("ros_topic_publish", json!({ "topic": topic }));
            g.check(&mut [c.clone()], &offered);
            g.observe(&c, came, "{\"error\": \"invalid arguments\"}");
        }
        g.check(&mut [call("turtle_pose", json!({}))], &offered);
        assert_eq!(
            g.narrow(&offered),
            Some(vec!["turtle_pose".to_string(), "reply".to_string()])
        );
    }

    #[test]
    fn the_step_after_an_error_offers_the_tools_it_names() {
        let mut g = Guards::standard("read the battery", &[], None);
        let offered = [
            spec("ros_topic_echo"),
            spec("ros_topic_list"),
            spec("ros_topic_list_all"),
            spec("reply"),
        ];
        let c = call("ros_topic_echo", json!({"topic": "/x"}));
        g.check(&mut [c.clone()], &offered);
        g.observe(
            &c,
            Came::Failed,
            "no topic /x; call ros_topic_list to see the topics",
        );
        assert_eq!(
            g.narrow(&offered),
            Some(vec!["ros_topic_list".to_string(), "reply".to_string()])
        );
        // Once: the step after that is free again.
        g.check(&mut [call("ros_topic_list", json!({}))], &offered);
        assert_eq!(g.narrow(&offered), None);
        // A call that ran (or was refused) names no next step.
        g.observe(&c, Came::Ran, "see ros_topic_list");
        assert_eq!(g.narrow(&offered), None);
    }

    #[test]
    fn a_tool_that_computes_from_given_numbers_waits_for_one() {
        let with = |name: &str, parameters: Value| ToolSpec::new(name, "", parameters).unwrap();
        let offered = [
            with(
                "fit_line",
                json!({"type": "object", "required": ["xs"],
                    "properties": {"xs": {"type": "array", "items": {"type": "number"}}}}),
            ),
            with(
                "scale",
                json!({"type": "object", "required": ["factor"],
                    "properties": {"factor": {"type": "number"}}}),
            ),
            // An amount the tool bounds (a guess within its range is a choice) and a
            // number with a default are not data.
            with(
                "lift",
                json!({"type": "object", "required": ["mm"],
                    "properties": {"mm": {"type": "number", "minimum": 0, "maximum": 80}}}),
            ),
            with(
                "sample",
                json!({"type": "object", "required": ["n"],
                    "properties": {"n": {"type": "integer", "default": 3}}}),
            ),
            spec("reply"),
        ];
        let names = |v: &[&str]| Some(v.iter().map(|s| s.to_string()).collect::<Vec<_>>());
        let g = Guards::standard("good evening, anyone home?", &[], None);
        assert_eq!(g.narrow(&offered), names(&["lift", "sample", "reply"]));
        for q in ["fit a line through 4 and 9", "double eleven"] {
            assert_eq!(Guards::standard(q, &[], None).narrow(&offered), None, "{q}");
        }
        // A number a tool returned is given too.
        let mut g = Guards::standard("scale what the sensor reads", &[], None);
        g.observe(&call("sample", json!({})), Came::Ran, "{\"reading\": 0.25}");
        assert_eq!(g.narrow(&offered), None);
    }

    #[test]
    fn a_motion_takes_the_sign_its_direction_words_name() {
        let with = |name: &str, parameters: Value| ToolSpec::new(name, "", parameters).unwrap();
        let offered = [
            with(
                "base_drive",
                json!({"type": "object", "properties": {
                    "meters": {"type": "number", "description": "How far; negative drives backward."}}}),
            ),
            with(
                "base_turn",
                json!({"type": "object", "properties": {
                    "deg": {"type": "number", "description": "Positive is counter-clockwise."}}}),
            ),
            with("publish", json!({"type": "object", "properties": {}})),
        ];
        let signed = |q: &str, name: &str, args: Value| {
            let mut calls = [call(name, args)];
            Guards::standard(q, &[q], None).check(&mut calls, &offered);
            calls[0].arguments.clone()
        };
        assert_eq!(
            signed(
                "reverse the base by two meters",
                "base_drive",
                json!({"meters": 2})
            ),
            json!({"meters": -2})
        );
        assert_eq!(
            signed("drive ahead 2.5 m", "base_drive", json!({"meters": -2.5})),
            json!({"meters": 2.5})
        );
        assert_eq!(
            signed("spin 45 degrees clockwise", "base_turn", json!({"deg": 45})),
            json!({"deg": -45})
        );
        assert_eq!(
            signed(
                "spin 45 degrees counter-clockwise",
                "base_turn",
                json!({"deg": -45})
            ),
            json!({"deg": 45})
        );
        assert_eq!(
            signed(
                "gira a la derecha 30 grados",
                "base_turn",
                json!({"deg": 30})
            ),
            json!({"deg": -30})
        );
        // A twist by its fields; words that name no direction, or both, leave it.
        let twist = json!({"message": {"linear": {"x": 0.3}, "angular": {"z": 0.5}}});
        assert_eq!(
            signed("back up and veer right", "publish", twist.clone()),
            json!({"message": {"linear": {"x": -0.3}, "angular": {"z": -0.5}}})
        );
        assert_eq!(
            signed("spin 45 degrees", "base_turn", json!({"deg": -45})),
            json!({"deg": -45})
        );
        assert_eq!(
            signed("45 left, then right", "base_turn", json!({"deg": 45})),
            json!({"deg": 45})
        );
    }

    #[test]
    fn an_act_that_came_to_nothing_is_not_replaced_by_another() {
        let effects = [
            ("place_go", Effect::Actuates),
            ("turtle_move", Effect::Actuates),
            ("place_list", Effect::Observes),
            ("place_remember", Effect::Observes),
            ("robot_stop", Effect::Stops),
        ]
        .map(|(n, e)| (n.to_string(), e))
        .into();
        let mut g = NoSubstitute::new(effects, ["place_remember".to_string()].into());
        let offered = [
            spec("place_go"),
            spec("turtle_move"),
            spec("place_list"),
            spec("place_remember"),
            spec("robot_stop"),
            spec("reply"),
        ];
        assert_eq!(g.narrow(&offered), None);
        // A read that failed, or an act that ran, leaves every act offered.
        g.observe(&call("place_list", json!({})), Came::Failed, "");
        g.observe(&call("turtle_move", json!({})), Came::Ran, "");
        assert_eq!(g.narrow(&offered), None);
        g.observe(
            &call("place_go", json!({"place": "greenhouse"})),
            Came::Failed,
            "no place called greenhouse",
        );
        assert_eq!(
            g.narrow(&offered),
            Some(vec![
                "place_go".into(),
                "place_list".into(),
                "robot_stop".into(),
                "reply".into()
            ])
        );
        // Nor is the pose the drive never reached recorded as the place.
        let verdicts = g.check(
            &mut [
                call("turtle_move", json!({"distance": 1.0})),
                call("place_remember", json!({"name": "greenhouse"})),
                call("place_go", json!({"place": "dock"})),
                call("place_list", json!({})),
            ],
            &offered,
        );
        assert!(matches!(verdicts[0], Verdict::Refuse(_)), "{verdicts:?}");
        assert!(matches!(verdicts[1], Verdict::Refuse(_)), "{verdicts:?}");
        assert_eq!(verdicts[2..], [Verdict::Pass, Verdict::Pass]);
        // The next part starts afresh for acts; what the run would record after the
        // failed drive stays untrue.
        g.next_part("then save this spot as the greenhouse");
        let names = |n: &[&str]| Some(n.iter().map(|s| s.to_string()).collect::<Vec<_>>());
        let but_recording = names(&[
            "place_go",
            "turtle_move",
            "place_list",
            "robot_stop",
            "reply",
        ]);
        assert_eq!(g.narrow(&offered), but_recording);
        let verdicts = g.check(
            &mut [call("place_remember", json!({"name": "greenhouse"}))],
            &offered,
        );
        assert!(matches!(verdicts[0], Verdict::Refuse(_)), "{verdicts:?}");
        // A call a guard turned down is the model's mistake: nothing more is held back.
        g.observe(&call("place_go", json!({})), Came::TurnedDown, "not asked");
        assert_eq!(g.narrow(&offered), but_recording);
        // A refused act counts too.
        g.observe(&call("turtle_move", json!({})), Came::Refused, "refused");
        assert_eq!(
            g.narrow(&offered),
            names(&["turtle_move", "place_list", "robot_stop", "reply"])
        );
    }

    #[test]
    fn nothing_is_recorded_beside_an_act_in_one_step() {
        let effects = [
            ("place_go", Effect::Actuates),
            ("place_remember", Effect::Observes),
        ]
        .map(|(n, e)| (n.to_string(), e))
        .into();
        let mut g = NoSubstitute::new(effects, ["place_remember".to_string()].into());
        let offered = [spec("place_go"), spec("place_remember")];
        let remember = || call("place_remember", json!({"name": "lab"}));
        let verdicts = g.check(
            &mut [call("place_go", json!({"place": "dock"})), remember()],
            &offered,
        );
        assert_eq!(verdicts[0], Verdict::Pass);
        assert!(matches!(verdicts[1], Verdict::Refuse(_)), "{verdicts:?}");
        // Alone, or after the act ran, it is made.
        assert_eq!(g.check(&mut [remember()], &offered), [Verdict::Pass]);
        assert_eq!(g.narrow(&offered), None);
    }

    fn asked(actuators: &[&str]) -> Asked {
        Asked {
            policy: Arc::new(Policy::default()),
            effects: actuators
                .iter()
                .map(|a| (a.to_string(), Effect::Actuates))
                .collect(),
            actuators: actuators.iter().map(|a| a.to_string()).collect(),
            observing: ["turtle", "pose", "ros", "topic", "publish"]
                .iter()
                .map(|w| w.to_string())
                .collect(),
            records: BTreeSet::new(),
            known: BTreeMap::new(),
        }
    }

    #[test]
    fn a_request_for_an_act_gets_an_actuating_call_before_an_answer() {
        let publish = ToolSpec::new(
            "ros_topic_publish",
            "",
            json!({"type": "object", "properties": {"topic": {"type": "string"}}}),
        )
        .unwrap();
        let offered = [
            spec("turtle_move"),
            spec("turtle_rotate"),
            spec("turtle_pose"),
            publish,
            spec("reply"),
        ];
        let actuators = ["turtle_move", "turtle_rotate", "ros_topic_publish"];
        let narrowed = |q: &str| {
            let mut g = Guards::standard(q, &[q], Some(asked(&actuators)));
            let first = g.narrow(&offered);
            g.check(&mut [call("turtle_pose", json!({}))], &offered);
            (first, g.narrow(&offered))
        };
        // The actuators the request may ask for, without the answer; once.
        for q in ["mueve la tortuga 1 metro", "Bewege die Schildkröte 1 Meter"] {
            let want: Vec<String> = vec!["turtle_move".into(), "ros_topic_publish".into()];
            assert_eq!(narrowed(q).0, Some(want), "{q}");
            assert!(narrowed(q).1.unwrap().contains(&"reply".to_string()), "{q}");
        }
        // Questions, negations and acts named only inside names force nothing.
        for q in [
            "where does the turtle stand?",
            "how do I move the turtle?",
            "don't move the turtle",
            "echo /turtle1/cmd_vel",
            "list the publishers of /turtle1/pose",
        ] {
            let first = narrowed(q).0;
            assert!(
                first
                    .as_ref()
                    .is_none_or(|n| n.contains(&"reply".to_string())),
                "{q}: {first:?}"
            );
        }
    }

    #[test]
    fn a_generic_actuator_is_written_only_toward_a_target_the_request_asks_for() {
        let declared = ToolSpec::new(
            "ros_service_call",
            "",
            json!({"type": "object", "properties": {"service": {"type": "string"}}}),
        )
        .unwrap();
        let bound = |services: &[&str]| {
            let branches: Vec<Value> = services
                .iter()
                .map(|s| json!({"type": "object", "properties": {"service": {"const": s}}}))
                .collect();
            ToolSpec {
                parameters: json!({ "anyOf": branches }),
                ..declared.clone()
            }
        };
        let keeps = |q: &str, b: &ToolSpec| {
            Guards::standard(q, &[q], Some(asked(&["ros_service_call"]))).keeps(&declared, b)
        };
        let services = bound(&["/clear", "/kill", "/spawn"]);
        assert!(keeps("clear the canvas", &services));
        assert!(keeps("spawn a turtle at x 2 y 3", &services));
        assert!(!keeps("upload the map to a server", &services));
        assert!(!keeps("what is the weather in Paris?", &services));
        // A target that may be any name: the call is judged once written.
        let open = ToolSpec {
            parameters: json!({"anyOf": [{"type": "object", "properties": {"service": {"type": "string"}}}]}),
            ..declared.clone()
        };
        assert!(keeps("upload the map to a server", &open));
        // By meaning alone, a target whose request takes numbers needs numbers said.
        let typed = ToolSpec {
            parameters: json!({"anyOf": [
                {"type": "object", "properties": {"service": {"const": "/hatch/tilt"},
                 "request": {"type": "object", "properties": {"angle": {"type": "number"}}}}},
                {"type": "object", "properties": {"service": {"const": "/hatch/shut"},
                 "request": {"type": "object", "properties": {}}}},
                {"type": "object", "properties": {"service": {"const": "/hatch/power"},
                 "request": {"type": "object", "properties": {"data": {"type": "boolean"}}}}}]}),
            ..declared.clone()
        };
        let keeps_meant = |q: &str, meant: &str| {
            let mut g = Guards::standard(q, &[q], Some(asked(&["ros_service_call"])));
            g.by_meaning(&[meant.to_string()]);
            g.keeps(&declared, &typed)
        };
        assert!(keeps_meant("ferme la trappe", "/hatch/shut"));
        assert!(!keeps_meant("penche la trappe", "/hatch/tilt"));
        assert!(keeps_meant("penche la trappe de 20", "/hatch/tilt"));
        // On or off is the act: meaning alone never writes it.
        assert!(!keeps_meant(
            "coupe le courant de la trappe",
            "/hatch/power"
        ));
    }

    #[test]
    fn a_target_meant_by_meaning_is_asked_for_and_its_neighbours_are_not() {
        let declared = ToolSpec::new(
            "ros_service_call",
            "",
            json!({"type": "object", "properties": {"service": {"type": "string"}}, "required": ["service"]}),
        )
        .unwrap();
        let call = |service: &str| ToolCall {
            name: "ros_service_call".into(),
            arguments: json!({ "service": service }),
        };
        let judged = |q: &str, meant: &[&str], service: &str| {
            let mut g = Guards::standard(q, &[q], Some(asked(&["ros_service_call"])));
            let meant: Vec<String> = meant.iter().map(|m| m.to_string()).collect();
            g.by_meaning(&meant);
            let mut calls = [call(service)];
            g.check(&mut calls, std::slice::from_ref(&declared))
                .into_iter()
                .all(|v| v == Verdict::Pass)
        };
        // Words the lexicon does not read: asked for only when meaning points there.
        assert!(!judged("ferme la trappe", &[], "/hatch/shut"));
        assert!(judged("ferme la trappe", &["/hatch/shut"], "hatch/shut"));
        assert!(!judged("ferme la trappe", &["/hatch/shut"], "/hatch/open"));
        // Meaning points at a name, not at values: those the request does not say are
        // the model's own.
        let with = |q: &str, request: Value| {
            let mut g = Guards::standard(q, &[q], Some(asked(&["ros_service_call"])));
            g.by_meaning(&["/hatch/shut".to_string()]);
            let mut calls = [ToolCall {
                name: "ros_service_call".into(),
                arguments: json!({"service": "/hatch/shut", "request": request}),
            }];
            g.check(&mut calls, std::slice::from_ref(&declared))
                .into_iter()
                .all(|v| v == Verdict::Pass)
        };
        assert!(with("ferme la trappe à 40", json!({"angle": 40, "z": 0})));
        assert!(!with(
            "ferme la trappe à 40",
            json!({"angle": 40, "slow": true})
        ));
        assert!(!with("ferme la trappe", json!({"angle": 0})));
        assert!(with("ferme la trappe, mode doux", json!({"mode": "doux"})));
        assert!(!with("ferme la trappe", json!({"angle": 1.0})));
        assert!(!with("ferme la trappe", json!({"mode": "fast"})));
        // A word shared with the meant one's neighbour is no reason to call it; a word
        // only the neighbour has, said, is.
        assert!(judged("shut the hatch", &[], "/hatch/open"));
        assert!(!judged("shut the hatch", &["/hatch/shut"], "/hatch/open"));
        assert!(judged(
            "shut the hatch and open it",
            &["/hatch/shut"],
            "/hatch/open"
        ));
        // A target sharing no word with the meant one is not judged by it.
        assert!(judged(
            "shut the hatch and open the valve",
            &["/hatch/shut"],
            "/valve/open"
        ));
        // In a request of several parts, the part asks too.
        let q = "shut the hatch, then say how wide it stands open";
        let mut g = Guards::standard(q, &[q], Some(asked(&["ros_service_call"])));
        g.next_part("say how wide it stands open");
        let verdicts = g.check(&mut [call("/hatch/open")], std::slice::from_ref(&declared));
        assert!(matches!(verdicts[..], [Verdict::Refuse(_)]), "{verdicts:?}");
    }

    #[test]
    fn a_later_part_that_names_no_target_acts_on_what_the_part_before_named() {
        let set = ToolSpec::new(
            "ros_param_set",
            "",
            json!({"type": "object", "properties": {"node": {"type": "string"},
                   "name": {"type": "string"}, "value": {"type": "number"}}}),
        )
        .unwrap();
        let judged = |parts: &[&str], value: f64| {
            let q = parts.join(" and then ");
            // The setting's name was said earlier in the session: grounding keeps it.
            let said = [q.as_str(), "lamp_level"];
            let mut g = Guards::standard(&q, &said, Some(asked(&["ros_param_set"])));
            for p in parts {
                g.next_part(p);
            }
            let mut calls = [ToolCall {
                name: "ros_param_set".into(),
                arguments: json!({"node": "/lamp", "name": "lamp_level", "value": value}),
            }];
            g.check(&mut calls, std::slice::from_ref(&set))
                .into_iter()
                .all(|v| v == Verdict::Pass)
        };
        assert!(judged(&["read lamp_level", "change it to 20"], 20.0));
        // The part asks for no change, or names another target of its own.
        assert!(!judged(&["read lamp_level", "tell me the time"], 20.0));
        assert!(!judged(
            &["read lamp_level", "change fan_speed to 20"],
            20.0
        ));
        assert!(!judged(
            &["read lamp_level", "change fan_speed to 20 like it"],
            20.0
        ));
        // Nothing before it to refer to, or the part before never wrote the target.
        assert!(!judged(&["change it to 20"], 20.0));
        assert!(!judged(&["read the lamp", "change it to 20"], 20.0));

        // A generic act and a pointing word reach no target the part before did not
        // write whole.
        let service = ToolSpec::new(
            "ros_service_call",
            "",
            json!({"type": "object", "properties": {"service": {"type": "string"}}}),
        )
        .unwrap();
        let calls = |parts: &[&str], target: &str| {
            let q = parts.join(", then ");
            let mut g = Guards::standard(&q, &[&q], Some(asked(&["ros_service_call"])));
            for p in parts {
                g.next_part(p);
            }
            let mut calls = [ToolCall {
                name: "ros_service_call".into(),
                arguments: json!({ "service": target }),
            }];
            g.check(&mut calls, std::slice::from_ref(&service))
                .into_iter()
                .all(|v| v == Verdict::Pass)
        };
        assert!(!calls(
            &["check the crane state", "run it again"],
            "/crane/go_home"
        ));
        assert!(!calls(
            &["open the hatch", "trigger it once more"],
            "/hatch/close"
        ));
        assert!(calls(
            &["look up /crane/go_home", "call it"],
            "/crane/go_home"
        ));
    }
}
