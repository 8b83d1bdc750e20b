//! Policy: enforced in code on every call, never left to the prompt.
//!
//! A call actuates when its tool does, unless an `observes` rule of the policy file says
//! this call only reads (a service known to be a query, say).
//!
//! In order, a call is refused if: the tool is unknown; it actuates in read-only mode;
//! its arguments do not match the schema; any string in them names something on the
//! operator's deny-list (or a pattern the model added; it can add, never remove); a limit
//! from the policy file is exceeded; or it actuates and the operator does not confirm.
//! Listings pass through `redact`, so denied names are not shown either.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use regex::Regex;
use serde::Deserialize;
use serde_json::Value;

use super::{DynTool, Effect, ToolCall};

#[derive(Debug, thiserror::Error)]
pub enum PolicyError {
    #[error("cannot read policy file {path}: {message}")]
    Read { path: String, message: String },
    #[error("policy: invalid pattern {pattern:?}: {message}")]
    Pattern { pattern: String, message: String },
}

/// The outcome of checking one call.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "decision", content = "reason", rename_all = "lowercase")]
pub enum Decision {
    /// Observes, or actuates under auto-approval.
    Allowed,
    /// Actuates, and the operator said yes.
    Confirmed,
    /// Not run; the reason is what the model reads.
    Refused(String),
}

/// Asks the operator about an actuating call.
pub trait Confirm: Send + Sync {
    fn confirm(&self, call: &ToolCall) -> bool;
}

/// Never confirms: the default when no operator is present and `--yes` was not given.
pub struct NoOperator;

impl Confirm for NoOperator {
    fn confirm(&self, _: &ToolCall) -> bool {
        false
    }
}

/// A bound on argument values, from the policy file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Limit {
    /// Regex on tool names this limit applies to.
    pub tool: String,
    /// Only when these arguments have these values (e.g. `message_type`).
    #[serde(default)]
    pub when: serde_json::Map<String, Value>,
    /// JSON pointers into the arguments (e.g. "/message/linear/x").
    pub paths: Vec<String>,
    #[serde(default)]
    pub min: Option<f64>,
    #[serde(default)]
    pub max: Option<f64>,
    /// Bound on the Euclidean norm of the values at `paths` (absent ones count as 0).
    #[serde(default)]
    pub max_norm: Option<f64>,
}

/// Calls of a tool allowed only with listed arguments ("this service only with these").
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Only {
    pub tool: String,
    #[serde(default)]
    pub when: serde_json::Map<String, Value>,
    /// Each entry's fields must all equal the call's for the call to pass.
    pub arguments: Vec<serde_json::Map<String, Value>>,
}

/// Calls of an actuating tool that only read: `argument` matching `pattern`, e.g. tool
/// `ros_service_call`, argument `service`, pattern `^/robot/get_`. Such calls need no
/// confirmation and are allowed in read-only mode.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Observes {
    /// Regex on tool names.
    pub tool: String,
    /// The string argument the pattern is tried on.
    pub argument: String,
    /// Regex the argument's whole value must match.
    pub pattern: String,
}

/// The policy file (TOML).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PolicyFile {
    #[serde(default)]
    pub deny: Vec<String>,
    #[serde(default)]
    pub read_only: bool,
    /// Approve actuating calls without asking (what `--yes` does).
    #[serde(default)]
    pub auto_approve: bool,
    #[serde(default)]
    pub timeout_s: Option<f64>,
    #[serde(default)]
    pub limit: Vec<Limit>,
    #[serde(default)]
    pub only: Vec<Only>,
    #[serde(default)]
    pub observes: Vec<Observes>,
}

pub struct Policy {
    deny: Vec<Regex>,
    model_deny: Mutex<Vec<Regex>>,
    pub read_only: bool,
    pub auto_approve: bool,
    pub timeout: Duration,
    limits: Vec<(Regex, Limit)>,
    only: Vec<(Regex, Only)>,
    /// (tool, argument, anchored value pattern)
    observes: Vec<(Regex, String, Regex)>,
    confirm: Arc<dyn Confirm>,
}

impl std::fmt::Debug for Policy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Policy")
            .field("deny", &self.deny)
            .field("read_only", &self.read_only)
            .field("auto_approve", &self.auto_approve)
            .finish_non_exhaustive()
    }
}

fn compile(p: &str) -> Result<Regex, PolicyError> {
    Regex::new(p).map_err(|e| PolicyError::Pattern {
        pattern: p.to_string(),
        // The regex crate draws a multi-line caret diagram; its last line says what.
        message: e
            .to_string()
            .lines()
            .rfind(|l| !l.trim().is_empty())
            .unwrap_or("invalid regex")
            .trim_start_matches("error: ")
            .to_string(),
    })
}

impl Default for Policy {
    fn default() -> Policy {
        Policy::from_file(PolicyFile::default(), Arc::new(NoOperator))
            .expect("empty policy compiles")
    }
}

impl Policy {
    pub fn from_file(file: PolicyFile, confirm: Arc<dyn Confirm>) -> Result<Policy, PolicyError> {
        Ok(Policy {
            deny: file
                .deny
                .iter()
                .map(|p| compile(p))
                .collect::<Result<_, _>>()?,
            model_deny: Mutex::new(Vec::new()),
            read_only: file.read_only,
            auto_approve: file.auto_approve,
            timeout: Duration::from_secs_f64(file.timeout_s.unwrap_or(30.0).max(0.001)),
            limits: file
                .limit
                .into_iter()
                .map(|l| Ok((compile(&l.tool)?, l)))
                .collect::<Result<_, PolicyError>>()?,
            only: file
                .only
                .into_iter()
                .map(|o| Ok((compile(&o.tool)?, o)))
                .collect::<Result<_, PolicyError>>()?,
            observes: file
                .observes
                .iter()
                .map(|o| {
                    Ok((
                        compile(&o.tool)?,
                        o.argument.clone(),
                        compile(&format!("^(?:{})$", o.pattern))?,
                    ))
                })
                .collect::<Result<_, PolicyError>>()?,
            confirm,
        })
    }

    /// Whether some calls of `tool` count as observing (an `observes` rule names it).
    pub fn may_observe(&self, tool: &str) -> bool {
        self.observes.iter().any(|(re, _, _)| re.is_match(tool))
    }

    /// Whether an `observes` rule covers this call.
    fn observes_call(&self, call: &ToolCall) -> bool {
        self.observes.iter().any(|(re, arg, pattern)| {
            re.is_match(&call.name)
                && call
                    .arguments
                    .get(arg)
                    .and_then(Value::as_str)
                    .is_some_and(|v| pattern.is_match(v))
        })
    }

    pub fn load(path: &Path, confirm: Arc<dyn Confirm>) -> Result<Policy, PolicyError> {
        let err = |message: String| PolicyError::Read {
            path: path.display().to_string(),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
        let file: PolicyFile = toml::from_str(&text).map_err(|e| err(e.message().to_string()))?;
        Policy::from_file(file, confirm)
    }

    /// Add a deny pattern on the model's behalf (it can never remove one).
    pub fn add_model_pattern(&self, pattern: &str) -> Result<(), PolicyError> {
        let re = compile(pattern)?;
        self.model_deny.lock().expect("policy lock").push(re);
        Ok(())
    }

    /// The first deny pattern matching `name`, if any.
    pub fn denied(&self, name: &str) -> Option<String> {
        if let Some(re) = self.deny.iter().find(|re| re.is_match(name)) {
            return Some(re.as_str().to_string());
        }
        let model = self.model_deny.lock().expect("policy lock");
        model
            .iter()
            .find(|re| re.is_match(name))
            .map(|re| re.as_str().to_string())
    }

    /// Whether this call changes the robot: its tool actuates and no `observes` rule
    /// covers it.
    pub fn actuates(&self, effect: Effect, call: &ToolCall) -> bool {
        effect == Effect::Actuates && !self.observes_call(call)
    }

    /// Check one call; only `Allowed`/`Confirmed` calls may run.
    pub fn check(&self, tool: Option<&dyn DynTool>, call: &ToolCall) -> Decision {
        let Some(tool) = tool else {
            return Decision::Refused(format!("there is no tool named {}", call.name));
        };
        let actuates = self.actuates(tool.effect(), call);
        if actuates && self.read_only {
            return Decision::Refused(format!(
                "{} changes the robot and the agent is read-only; tell the operator it cannot be done",
                call.name
            ));
        }
        if let Err(e) = tool.spec().validate(&call.arguments) {
            return Decision::Refused(format!("invalid arguments for {}: {e}", call.name));
        }
        let mut strings = Vec::new();
        collect_strings(&call.arguments, &mut strings);
        for s in strings {
            if let Some(p) = self.denied(s) {
                return Decision::Refused(format!(
                    "{s} is off limits (operator deny-list pattern {p:?}); do not try it again"
                ));
            }
        }
        for (re, limit) in &self.limits {
            if re.is_match(&call.name) && matches_when(&limit.when, &call.arguments) {
                if let Some(why) = violates(limit, &call.arguments) {
                    return Decision::Refused(format!("{why}; retry within the limit"));
                }
            }
        }
        for (re, only) in &self.only {
            if re.is_match(&call.name) && matches_when(&only.when, &call.arguments) {
                let ok = only.arguments.iter().any(|allowed| {
                    allowed
                        .iter()
                        .all(|(k, v)| call.arguments.get(k).is_some_and(|x| json_eq(x, v)))
                });
                if !ok {
                    return Decision::Refused(format!(
                        "{} is allowed only with these arguments: {}",
                        call.name,
                        serde_json::to_string(&only.arguments).unwrap_or_default()
                    ));
                }
            }
        }
        if !actuates || self.auto_approve {
            return Decision::Allowed;
        }
        if self.confirm.confirm(call) {
            Decision::Confirmed
        } else {
            Decision::Refused(format!(
                "the operator did not approve {}; do not retry it unless asked",
                call.name
            ))
        }
    }

    /// Remove denied names from a tool's output: array items that are denied strings, or
    /// objects whose name-like fields are denied. Returns how many were removed.
    pub fn redact(&self, output: &mut Value) -> usize {
        let mut removed = 0;
        match output {
            Value::Array(items) => {
                let before = items.len();
                items.retain(|item| !self.item_denied(item));
                removed += before - items.len();
                for item in items.iter_mut() {
                    removed += self.redact(item);
                }
            }
            Value::Object(map) => {
                for v in map.values_mut() {
                    removed += self.redact(v);
                }
            }
            _ => {}
        }
        removed
    }

    fn item_denied(&self, item: &Value) -> bool {
        match item {
            Value::String(s) => self.denied(s).is_some(),
            Value::Object(map) => ["name", "topic", "node", "service", "action", "parameter"]
                .iter()
                .filter_map(|k| map.get(*k).and_then(Value::as_str))
                .any(|s| self.denied(s).is_some()),
            _ => false,
        }
    }
}

fn collect_strings<'a>(v: &'a Value, out: &mut Vec<&'a str>) {
    match v {
        Value::String(s) => out.push(s),
        Value::Array(a) => a.iter().for_each(|x| collect_strings(x, out)),
        Value::Object(m) => m.values().for_each(|x| collect_strings(x, out)),
        _ => {}
    }
}

fn json_eq(a: &Value, b: &Value) -> bool {
    match (a.as_f64(), b.as_f64()) {
        (Some(x), Some(y)) => (x - y).abs() < 1e-9,
        _ => a == b,
    }
}

fn matches_when(when: &serde_json::Map<String, Value>, args: &Value) -> bool {
    when.iter()
        .all(|(k, v)| args.get(k).is_some_and(|x| json_eq(x, v)))
}

fn violates(limit: &Limit, args: &Value) -> Option<String> {
    let mut sq = 0.0;
    for p in &limit.paths {
        let Some(x) = args.pointer(p).and_then(Value::as_f64) else {
            continue;
        };
        if let Some(min) = limit.min {
            if x < min {
                return Some(format!("{p} = {x} is below the limit {min}"));
            }
        }
        if let Some(max) = limit.max {
            if x > max {
                return Some(format!("{p} = {x} is above the limit {max}"));
            }
        }
        sq += x * x;
    }
    match limit.max_norm {
        Some(n) if sq.sqrt() > n + 1e-9 => Some(format!(
            "|{}| = {:.3} exceeds the limit {n}",
            limit.paths.join(", "),
            sq.sqrt()
        )),
        _ => None,
    }
}
