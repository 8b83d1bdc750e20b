//! Declarative tools: an integrator adds a robot-specific tool in a TOML file, without
//! recompiling (`--tools FILE.toml`, or `tools = [...]` in the robot's prompt file). A
//! tool is a name, a description, an argument schema, an effect, and one ROS action:
//! publish this message on this topic, call this service with this request, or read one
//! message from this topic. The message and the request may place arguments with
//! `"{{name}}"` (a string that is exactly a placeholder takes the argument's JSON value,
//! or the parameter's `default` when the call leaves it out; inside longer text it is
//! spliced in).
//!
//! A file is checked whole when it loads, and every mistake is reported with its line
//! and the fix: a name a built-in tool (or an earlier file) has, a parameter without a
//! type, a placeholder that names no parameter, an optional parameter placed without a
//! default, a ROS name that is not absolute, a type that is not `pkg/msg/Name` (or
//! `pkg/srv/Name` for a call), a publishing tool declared as observing (a message sent
//! acts on the robot). An actuating tool's parameters must be bounded: numbers
//! with `minimum` and `maximum`, strings with `enum` or `maxLength`, so the grammar and
//! the policy hold the model to the range the integrator allows. The same policy applies
//! as to every tool: the deny-list, read-only, the e-stop, the operator's confirmation,
//! the velocity limits on what is published.
//!
//! ```toml
//! [[tool]]
//! name = "spot_stand_up"
//! description = "Make Spot stand up. Moves the robot."
//! effect = "actuates"
//! [tool.call]
//! service = "/spot/stand_up"
//! type = "std_srvs/srv/Trigger"
//! request = {}
//!
//! [[tool]]
//! name = "eels_raise_head"
//! description = "Raise EELS's head by angle degrees (0-45). Moves the robot."
//! effect = "actuates"
//! parameters = { type = "object", properties = { angle = { type = "number", minimum = 0, maximum = 45 } }, required = ["angle"] }
//! [tool.publish]
//! topic = "/eels/head/cmd"
//! type = "std_msgs/msg/Float64"
//! message = { data = "{{angle}}" }
//! ```

use std::collections::BTreeSet;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use serde::Deserialize;
use serde_json::{json, Value};

use crate::ros::RosGraph;
use crate::tool::registry::BoxFuture;
use crate::tool::{DynTool, Effect, Package, SpecError, ToolContext, ToolError, ToolSpec};

#[derive(Debug, thiserror::Error)]
pub enum DeclaredError {
    #[error("cannot read tools file {path}: {message}")]
    Read { path: String, message: String },
    /// A mistake at a line of the file, with what to do about it.
    #[error("tools file {path}, line {line}: {message}")]
    At {
        path: String,
        line: usize,
        message: String,
    },
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct PublishAction {
    topic: String,
    #[serde(rename = "type")]
    type_name: String,
    message: Value,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct CallAction {
    service: String,
    #[serde(rename = "type")]
    type_name: String,
    #[serde(default = "empty_object")]
    request: Value,
}

/// Read one message from a topic (a sensor's reading, a status).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct ReadAction {
    topic: String,
    /// The message type; the graph's when left out.
    #[serde(rename = "type", default)]
    type_name: Option<String>,
    /// How long to wait for a message, in seconds (default 2, at most `MAX_WAIT_S`).
    #[serde(default)]
    timeout_s: Option<f64>,
}

/// Longest wait a read may declare, in seconds.
const MAX_WAIT_S: f64 = 30.0;
/// A read's wait when it declares none, in seconds.
const DEFAULT_WAIT_S: f64 = 2.0;

fn empty_object() -> Value {
    json!({})
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct ToolDecl {
    name: String,
    description: String,
    #[serde(default)]
    parameters: Option<Value>,
    /// Requests an operator makes when this tool is the one to call: tool choice
    /// compares requests with them by meaning (`reading::meaning`).
    #[serde(default)]
    examples: Vec<String>,
    effect: EffectDecl,
    #[serde(default)]
    publish: Option<PublishAction>,
    #[serde(default)]
    call: Option<CallAction>,
    #[serde(default)]
    read: Option<ReadAction>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(rename_all = "lowercase")]
enum EffectDecl {
    Observes,
    Actuates,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ToolsFile {
    #[serde(default)]
    tool: Vec<ToolDecl>,
}

#[derive(Debug, Clone)]
enum Action {
    Publish(PublishAction),
    Call(CallAction),
    Read(ReadAction),
}

/// A tool defined in a tools file.
pub struct Declared {
    spec: ToolSpec,
    effect: Effect,
    action: Action,
    ros: Arc<dyn RosGraph>,
}

/// The `{{name}}` placeholders of a template string: byte start, byte end and name of
/// each, in order.
fn slots(s: &str) -> Result<Vec<(usize, usize, String)>, String> {
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(start) = s[from..].find("{{").map(|i| i + from) {
        let end = s[start..]
            .find("}}")
            .ok_or_else(|| format!("unclosed {{{{ in {s:?}"))?
            + start
            + 2;
        out.push((start, end, s[start + 2..end - 2].trim().to_string()));
        from = end;
    }
    Ok(out)
}

/// Replace `"{{name}}"` placeholders in `template` with values from `args`. Only the
/// template is read for placeholders: a value that holds `{{…}}` is placed as it is.
fn fill(template: &Value, args: &Value) -> Result<Value, String> {
    let arg = |name: &str| {
        args.get(name)
            .ok_or_else(|| format!("argument {name} is missing"))
    };
    Ok(match template {
        Value::String(s) => {
            let slots = slots(s)?;
            if let [(start, end, name)] = &slots[..] {
                if s[..*start].trim().is_empty() && s[*end..].trim().is_empty() {
                    return arg(name).cloned();
                }
            }
            let mut out = String::with_capacity(s.len());
            let mut at = 0;
            for (start, end, name) in &slots {
                out.push_str(&s[at..*start]);
                match arg(name)? {
                    Value::String(x) => out.push_str(x),
                    other => out.push_str(&other.to_string()),
                }
                at = *end;
            }
            out.push_str(&s[at..]);
            Value::String(out)
        }
        Value::Array(a) => Value::Array(a.iter().map(|x| fill(x, args)).collect::<Result<_, _>>()?),
        Value::Object(m) => Value::Object(
            m.iter()
                .map(|(k, v)| Ok((k.clone(), fill(v, args)?)))
                .collect::<Result<_, String>>()?,
        ),
        other => other.clone(),
    })
}

/// The names `"{{name}}"` placeholders in `template` place, in order.
fn placeholders(template: &Value, out: &mut Vec<String>) -> Result<(), String> {
    match template {
        Value::String(s) => out.extend(slots(s)?.into_iter().map(|(_, _, name)| name)),
        Value::Array(a) => a.iter().try_for_each(|x| placeholders(x, out))?,
        Value::Object(m) => m.values().try_for_each(|x| placeholders(x, out))?,
        _ => {}
    }
    Ok(())
}

/// `args` with each parameter the call left out that declares a `default` set to it.
fn with_defaults(spec: &ToolSpec, args: Value) -> Value {
    let mut args = match args {
        Value::Object(m) => m,
        other => return other,
    };
    if let Some(props) = spec.parameters["properties"].as_object() {
        for (k, p) in props {
            if let Some(d) = p.get("default") {
                args.entry(k.clone()).or_insert_with(|| d.clone());
            }
        }
    }
    Value::Object(args)
}

/// Lines of a tools file: where each `[[tool]]` starts, so a mistake in a tool can name
/// the line of the key it is about.
struct Lines<'a> {
    text: &'a str,
    /// The 0-based line of each `[[tool]]` header, in order.
    headers: Vec<usize>,
}

impl<'a> Lines<'a> {
    fn new(text: &'a str) -> Lines<'a> {
        let headers = text
            .lines()
            .enumerate()
            .filter(|(_, l)| l.trim() == "[[tool]]")
            .map(|(i, _)| i)
            .collect();
        Lines { text, headers }
    }

    /// The 1-based line of byte `offset`.
    fn of_offset(&self, offset: usize) -> usize {
        self.text[..offset.min(self.text.len())]
            .matches('\n')
            .count()
            + 1
    }

    /// The 1-based line where tool `index` writes `key` (`key = …` or `[tool.key]`),
    /// else its `[[tool]]` header's.
    fn of(&self, index: usize, key: &str) -> usize {
        let Some(&first) = self.headers.get(index) else {
            return 1;
        };
        let end = self.headers.get(index + 1).copied().unwrap_or(usize::MAX);
        let found = self
            .text
            .lines()
            .enumerate()
            .skip(first)
            .take_while(|(i, _)| *i < end)
            .find(|(_, l)| {
                let l = l.trim_start();
                l == format!("[tool.{key}]")
                    || l.strip_prefix(key)
                        .is_some_and(|r| r.trim_start().starts_with('='))
            });
        found.map_or(first, |(i, _)| i) + 1
    }
}

/// Parse a tools file into tools acting on `ros`. `taken` holds the names of the tools
/// already registered (built-in ones and those of files loaded before): a declared tool
/// may not replace one.
pub fn parse(
    text: &str,
    origin: &str,
    ros: Arc<dyn RosGraph>,
    taken: &BTreeSet<String>,
) -> Result<Package, DeclaredError> {
    let lines = Lines::new(text);
    let at = |line: usize, message: String| DeclaredError::At {
        path: origin.to_string(),
        line,
        message,
    };
    let file: ToolsFile = toml::from_str(text).map_err(|e| {
        let line = e.span().map_or(1, |s| lines.of_offset(s.start));
        at(
            line,
            format!(
                "{}; see the reference in the README (Robot tools)",
                e.message().trim()
            ),
        )
    })?;
    if file.tool.is_empty() {
        return Err(at(
            1,
            "the file declares no tool: add a [[tool]] table with name, description, effect and one action ([tool.publish], [tool.call] or [tool.read])".into(),
        ));
    }
    let mut pkg = Package::new("declared");
    let mut names: Vec<String> = Vec::new();
    for (i, d) in file.tool.into_iter().enumerate() {
        let tool = build(d, &names, taken, ros.clone())
            .map_err(|(key, message)| at(lines.of(i, key), message))?;
        names.push(tool.spec.name.clone());
        pkg = pkg.with_dyn(Arc::new(tool));
    }
    Ok(pkg)
}

/// A mistake in a tool: the key it is about (for its line) and what to do.
type Mistake = (&'static str, String);

/// One declared tool, checked (see the module header).
fn build(
    d: ToolDecl,
    earlier: &[String],
    taken: &BTreeSet<String>,
    ros: Arc<dyn RosGraph>,
) -> Result<Declared, Mistake> {
    let name = d.name.clone();
    if earlier.contains(&name) {
        return Err((
            "name",
            format!("tool {name} is declared twice in this file: rename one"),
        ));
    }
    if taken.contains(&name) {
        return Err((
            "name",
            format!("tool {name}: a built-in tool (or one of a file loaded before) has this name; choose another, e.g. myrobot_{name}"),
        ));
    }
    if d.description.trim().is_empty() {
        return Err((
            "description",
            format!("tool {name}: the description is empty; say what the tool does (the model chooses tools by it), and for an actuating tool that it moves the robot"),
        ));
    }
    let mut spec = ToolSpec::new(&name, &d.description, d.parameters.clone().unwrap_or(Value::Null))
        .map_err(|e| match e {
            SpecError::Name(_) => ("name", e.to_string()),
            other => ("parameters", format!("{other}; write parameters = {{ type = \"object\", properties = {{ … }}, required = [ … ] }}")),
        })?;
    spec.examples
        .extend(d.examples.iter().filter(|e| !e.trim().is_empty()).cloned());
    let effect = match d.effect {
        EffectDecl::Observes => Effect::Observes,
        EffectDecl::Actuates => Effect::Actuates,
    };
    check_parameters(&spec, effect)?;
    let action = match (d.publish, d.call, d.read) {
        (Some(p), None, None) => Action::Publish(p),
        (None, Some(c), None) => Action::Call(c),
        (None, None, Some(r)) => Action::Read(r),
        _ => {
            return Err((
                "name",
                format!(
                "tool {name}: give exactly one action: [tool.publish], [tool.call] or [tool.read]"
            ),
            ))
        }
    };
    if matches!(action, Action::Publish(_)) && effect != Effect::Actuates {
        // A message published is an act on the robot: declared as observing, it would
        // skip confirmation and survive --read-only.
        return Err((
            "effect",
            format!("tool {name} publishes, which acts on the robot: write effect = \"actuates\""),
        ));
    }
    check_action(&spec, &action)?;
    Ok(Declared {
        spec,
        effect,
        action,
        ros,
    })
}

/// Every parameter typed; an actuating tool's bounded.
fn check_parameters(spec: &ToolSpec, effect: Effect) -> Result<(), Mistake> {
    let name = &spec.name;
    let Some(props) = spec.parameters["properties"].as_object() else {
        return Ok(());
    };
    for (p, schema) in props {
        let Some(ty) = schema.get("type").and_then(Value::as_str) else {
            if schema.get("enum").is_some() {
                continue;
            }
            return Err((
                "parameters",
                format!("tool {name}: parameter {p} has no type; give it type = \"number\", \"integer\", \"string\" or \"boolean\""),
            ));
        };
        if effect != Effect::Actuates {
            continue;
        }
        let has = |k: &str| schema.get(k).is_some();
        let bounded = match ty {
            "number" | "integer" => has("minimum") && has("maximum"),
            "string" => has("enum") || has("maxLength"),
            "boolean" => true,
            _ => false,
        };
        if !bounded {
            let fix = match ty {
                "number" | "integer" => {
                    "give it minimum and maximum (e.g. minimum = 0, maximum = 45)"
                }
                "string" => "give it enum = [ … ] or maxLength",
                _ => "use a number, integer, string or boolean parameter",
            };
            return Err((
                "parameters",
                format!("tool {name} actuates, and its parameter {p} ({ty}) is unbounded: {fix}"),
            ));
        }
    }
    Ok(())
}

/// The action's ROS name and type well formed, and each placeholder a parameter the
/// call always has (required, or with a default).
fn check_action(spec: &ToolSpec, action: &Action) -> Result<(), Mistake> {
    let name = &spec.name;
    let (key, ros_name, type_name, kind, template) = match action {
        Action::Publish(p) => (
            "publish",
            &p.topic,
            Some(&p.type_name),
            "msg",
            Some(&p.message),
        ),
        Action::Call(c) => (
            "call",
            &c.service,
            Some(&c.type_name),
            "srv",
            Some(&c.request),
        ),
        Action::Read(r) => ("read", &r.topic, r.type_name.as_ref(), "msg", None),
    };
    // The fence's reading of a ROS name, which every call's name goes through: written
    // already in that form.
    if crate::fence::canonical(ros_name).ok().as_ref() != Some(ros_name) {
        return Err((
            key,
            format!("tool {name}: {ros_name:?} is not an absolute ROS name; write it like /robot/cmd (letters, digits, _ and /, no segment starting with a digit)"),
        ));
    }
    if let Some(t) = type_name {
        // As the graph reads types (`pkg/Name` is `pkg/msg/Name`).
        let full = crate::ros::msg::normalize_type(t);
        let parts: Vec<&str> = full.split('/').collect();
        let ok = parts.len() == 3
            && parts[1] == kind
            && parts
                .iter()
                .all(|p| !p.is_empty() && p.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'));
        if !ok {
            let example = if kind == "srv" {
                "std_srvs/srv/Trigger"
            } else {
                "std_msgs/msg/Float64"
            };
            return Err((
                key,
                format!("tool {name}: type {t:?} is not a {kind} type; write it like {example}"),
            ));
        }
    }
    if let Action::Read(r) = action {
        if r.timeout_s.is_some_and(|t| !(t > 0.0 && t <= MAX_WAIT_S)) {
            return Err((
                key,
                format!("tool {name}: timeout_s must be above 0 and at most {MAX_WAIT_S}"),
            ));
        }
    }
    let mut placed = Vec::new();
    if let Some(t) = template {
        placeholders(t, &mut placed)
            .map_err(|e| (key, format!("tool {name}: {e}; close it with }}}}")))?;
    }
    let props = spec.parameters["properties"].as_object();
    let required: Vec<&str> = spec.parameters["required"]
        .as_array()
        .map(|r| r.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    for p in placed {
        let Some(schema) = props.and_then(|m| m.get(&p)) else {
            return Err((key, format!("tool {name}: placeholder {{{{{p}}}}} names no parameter; declare {p} under parameters.properties, or remove the placeholder")));
        };
        if !required.contains(&p.as_str()) && schema.get("default").is_none() {
            return Err((key, format!("tool {name}: placeholder {{{{{p}}}}} places an optional parameter with no default; add {p} to required, or give it a default")));
        }
    }
    Ok(())
}

pub fn load(
    path: &Path,
    ros: Arc<dyn RosGraph>,
    taken: &BTreeSet<String>,
) -> Result<Package, DeclaredError> {
    let text = std::fs::read_to_string(path).map_err(|e| DeclaredError::Read {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    parse(&text, &path.display().to_string(), ros, taken)
}

impl DynTool for Declared {
    fn spec(&self) -> &ToolSpec {
        &self.spec
    }

    fn effect(&self) -> Effect {
        self.effect
    }

    fn call<'a>(
        &'a self,
        args: Value,
        cx: &'a ToolContext,
    ) -> BoxFuture<'a, Result<Value, ToolError>> {
        Box::pin(async move {
            let args = with_defaults(&self.spec, args);
            match &self.action {
                Action::Read(r) => {
                    let wait = Duration::from_secs_f64(r.timeout_s.unwrap_or(DEFAULT_WAIT_S))
                        .min(cx.timeout);
                    let got = self
                        .ros
                        .subscribe(&r.topic, r.type_name.as_deref(), 1, wait)
                        .await
                        .map_err(|e| ToolError::Failed(e.to_string()))?;
                    let Some(sample) = got.into_iter().next() else {
                        return Err(ToolError::Failed(format!(
                            "no message on {} within {:.1} s; call ros_topic_list to see whether it is published",
                            r.topic,
                            wait.as_secs_f64()
                        )));
                    };
                    Ok(json!({"topic": r.topic, "message": sample.message}))
                }
                Action::Publish(p) => {
                    let message = fill(&p.message, &args).map_err(ToolError::InvalidArguments)?;
                    let sent = self
                        .ros
                        .publish(&p.topic, &p.type_name, message.clone())
                        .await
                        .map_err(|e| ToolError::Failed(e.to_string()))?;
                    let mut out = json!({"published": true, "topic": sent.topic, "type": p.type_name,
                                         "message": sent.sent.unwrap_or(message)});
                    if let Some(n) = sent.note {
                        out["limited"] = json!(n);
                    }
                    Ok(out)
                }
                Action::Call(c) => {
                    let request = fill(&c.request, &args).map_err(ToolError::InvalidArguments)?;
                    let timeout = cx.timeout.min(Duration::from_secs(30));
                    let reply = self
                        .ros
                        .call_service(&c.service, &c.type_name, request, timeout)
                        .await
                        .map_err(|e| ToolError::Failed(e.to_string()))?;
                    let mut out = json!({"service": c.service, "response": reply.response});
                    if let Some(n) = reply.note {
                        out["limited"] = json!(n);
                    }
                    Ok(out)
                }
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::fake::{FakeGraph, Sent};

    const FILE: &str = r#"
[[tool]]
name = "spot_stand_up"
description = "Make Spot stand up. Moves the robot."
effect = "actuates"
[tool.call]
service = "/spot/stand_up"
type = "std_srvs/srv/Trigger"

[[tool]]
name = "eels_raise_head"
description = "Raise the head by angle degrees (0-45)."
effect = "actuates"
parameters = { type = "object", properties = { angle = { type = "number", minimum = 0, maximum = 45 } }, required = ["angle"] }
[tool.publish]
topic = "/eels/head/cmd"
type = "std_msgs/msg/Float64"
message = { data = "{{angle}}", note = "raise by {{angle}} deg" }
"#;

    fn run(t: &dyn DynTool, args: Value) -> Result<Value, ToolError> {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(t.call(args, &ToolContext::new(Duration::from_secs(1))))
    }

    #[test]
    fn publish_and_call_actions_fill_arguments() {
        let graph = Arc::new(
            FakeGraph::new()
                .with_service("/spot/stand_up", json!({"success": true, "message": ""})),
        );
        let pkg = parse(FILE, "test", graph.clone(), &BTreeSet::new()).unwrap();
        assert_eq!(pkg.tools.len(), 2);
        assert_eq!(pkg.tools[0].effect(), Effect::Actuates);
        let out = run(pkg.tools[0].as_ref(), json!({})).unwrap();
        assert_eq!(out["response"]["success"], json!(true));
        run(pkg.tools[1].as_ref(), json!({"angle": 30})).unwrap();
        assert_eq!(
            graph.sent()[1],
            Sent::Publish {
                topic: "/eels/head/cmd".into(),
                type_name: "std_msgs/msg/Float64".into(),
                message: json!({"data": 30, "note": "raise by 30 deg"}),
            }
        );
        // The schema is the contract: the policy validates against it before a call.
        assert!(pkg.tools[1].spec().validate(&json!({"angle": 90})).is_err());
    }

    /// The error a tools file gives.
    fn mistake(text: &str) -> String {
        let taken: BTreeSet<String> = ["ros_node_list".to_string()].into();
        match parse(text, "robot.toml", Arc::new(FakeGraph::new()), &taken) {
            Ok(_) => panic!("loaded: {text}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn mistakes_name_their_line_and_the_fix() {
        let one = |body: &str| {
            format!("[[tool]]\nname = \"ok\"\ndescription = \"d\"\neffect = \"observes\"\n[tool.read]\ntopic = \"/a\"\n\n[[tool]]\n{body}")
        };
        let cases: &[(&str, usize, &str)] = &[
            // A field the format lacks: the parser's own line.
            ("name = \"x\"\ndescription = \"d\"\neffekt = \"observes\"\n", 11, "unknown field"),
            ("name = \"x\"\ndescription = \"d\"\neffect = \"observes\"\n", 9, "exactly one action"),
            ("name = \"ros_node_list\"\ndescription = \"d\"\neffect = \"observes\"\n[tool.read]\ntopic = \"/a\"\n", 9, "choose another"),
            ("name = \"ok\"\ndescription = \"d\"\neffect = \"observes\"\n[tool.read]\ntopic = \"/a\"\n", 9, "declared twice"),
            ("name = \"x\"\ndescription = \"d\"\neffect = \"actuates\"\nparameters = { type = \"object\", properties = { v = { type = \"number\" } } }\n[tool.publish]\ntopic = \"/cmd\"\ntype = \"std_msgs/msg/Float64\"\nmessage = { data = \"{{v}}\" }\n", 12, "minimum and maximum"),
            ("name = \"x\"\ndescription = \"d\"\neffect = \"observes\"\n[tool.call]\nservice = \"/s\"\ntype = \"std_srvs/msg/Trigger\"\n", 12, "std_srvs/srv/Trigger"),
            ("name = \"x\"\ndescription = \"d\"\neffect = \"observes\"\n[tool.read]\ntopic = \"battery\"\n", 12, "absolute ROS name"),
            ("name = \"x\"\ndescription = \"d\"\neffect = \"actuates\"\n[tool.publish]\ntopic = \"/cmd\"\ntype = \"std_msgs/msg/Float64\"\nmessage = { data = \"{{speed}}\" }\n", 12, "declare speed under parameters.properties"),
            ("name = \"x\"\ndescription = \"d\"\neffect = \"actuates\"\nparameters = { type = \"object\", properties = { v = { type = \"number\", minimum = 0, maximum = 1 } } }\n[tool.publish]\ntopic = \"/cmd\"\ntype = \"std_msgs/msg/Float64\"\nmessage = { data = \"{{v}}\" }\n", 13, "add v to required"),
            ("name = \"x\"\ndescription = \"\"\neffect = \"observes\"\n[tool.read]\ntopic = \"/a\"\n", 10, "description is empty"),
            ("name = \"x\"\ndescription = \"d\"\neffect = \"observes\"\n[tool.publish]\ntopic = \"/cmd\"\ntype = \"std_msgs/msg/Float64\"\nmessage = { data = 1.0 }\n", 11, "write effect = \"actuates\""),
        ];
        for (body, line, fix) in cases {
            let e = mistake(&one(body));
            assert!(
                e.starts_with(&format!("tools file robot.toml, line {line}:")),
                "{e}\n{body}"
            );
            assert!(e.contains(fix), "{e}\n{body}");
        }
        let e = mistake("# nothing here\n");
        assert!(e.contains("declares no tool"), "{e}");
    }

    #[test]
    fn only_the_template_is_read_for_placeholders() {
        // A value holding a placeholder is placed as it is (it was expanded again, and
        // one naming itself never ended).
        let args = json!({"text": "{{text}}", "n": 2});
        assert_eq!(
            fill(
                &json!({"a": "say {{ text }} {{n}} times", "b": "{{n}}"}),
                &args
            ),
            Ok(json!({"a": "say {{text}} 2 times", "b": 2}))
        );
        assert!(fill(&json!("{{open"), &args)
            .unwrap_err()
            .contains("unclosed"));
    }

    #[test]
    fn a_read_takes_one_message_and_defaults_fill_left_out_arguments() {
        let graph = Arc::new(
            FakeGraph::new()
                .with_messages("/color", vec![json!({"r": 1, "g": 2, "b": 3})])
                .with_service("/pen", json!({})),
        );
        let file = r#"
[[tool]]
name = "take_reading"
description = "Read the color sensor."
effect = "observes"
[tool.read]
topic = "/color"
timeout_s = 1.0

[[tool]]
name = "mark"
description = "Set the marker width. Moves nothing."
effect = "actuates"
parameters = { type = "object", properties = { width = { type = "integer", minimum = 1, maximum = 10, default = 3 } } }
[tool.call]
service = "/pen"
type = "turtlesim/srv/SetPen"
request = { width = "{{width}}", off = 0 }
"#;
        let pkg = parse(file, "t", graph.clone(), &BTreeSet::new()).unwrap();
        let out = run(pkg.tools[0].as_ref(), json!({})).unwrap();
        assert_eq!(out["message"], json!({"r": 1, "g": 2, "b": 3}));
        run(pkg.tools[1].as_ref(), json!({})).unwrap();
        assert_eq!(
            graph.sent().last(),
            Some(&Sent::Call {
                service: "/pen".into(),
                type_name: "turtlesim/srv/SetPen".into(),
                request: json!({"width": 3, "off": 0}),
            })
        );
        // Nothing on a topic is a failure that says what to do.
        let silent = parse(file, "t", Arc::new(FakeGraph::new()), &BTreeSet::new()).unwrap();
        let e = run(silent.tools[0].as_ref(), json!({})).unwrap_err();
        assert!(e.to_string().contains("/color"), "{e}");
    }
}
