//! Policy: enforced in code on every call, never left to the prompt.
//!
//! A call actuates when its tool does, unless an `observes` rule of the policy file says
//! this call only reads (a service known to be a query, say). A tool that stops
//! (`Effect::Stops`) passes every rule: stopping needs no confirmation, is allowed
//! read-only and behind the e-stop, and no deny pattern can forbid it.
//!
//! In order, a call is refused if: the tool is unknown; it actuates while the e-stop is
//! engaged; it actuates in read-only mode; its arguments do not match the schema; any
//! string in them names something behind the fence (the operator's deny-list, or a
//! pattern the model added; it can add, never remove; in any spelling of the name, hidden
//! characters and case aside), or a `node` and a `name` (or `parameter`) argument
//! together name a denied parameter (`/turtlesim` + `background_r`); a
//! limit from the policy file is exceeded (a null where a limited number belongs is
//! refused too); it breaks an `only` rule; or it actuates and the operator does not
//! confirm. Refusals never quote a deny pattern or a denied name.
//!
//! The same fence and e-stop guard the ROS boundary (`ros::boundary`), which also holds the
//! motion limits of the `[motion]` table (`limits`) on every encoded message.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use regex::Regex;
use serde::Deserialize;
use serde_json::Value;

use super::{DynTool, Effect, ToolCall};
use crate::estop::EStop;
use crate::fence::{canonical, Fence, FenceError};
use crate::limits::Motion;

#[derive(Debug, thiserror::Error)]
pub enum PolicyError {
    #[error("cannot read policy file {path}: {message}")]
    Read { path: String, message: String },
    #[error("policy: invalid pattern {pattern:?}: {message}")]
    Pattern { pattern: String, message: String },
    #[error("policy: {0}")]
    Motion(String),
}

impl From<FenceError> for PolicyError {
    fn from(e: FenceError) -> PolicyError {
        match e {
            FenceError::Pattern { pattern, message } => PolicyError::Pattern { pattern, message },
            other => PolicyError::Pattern {
                pattern: String::new(),
                message: other.to_string(),
            },
        }
    }
}

/// The outcome of checking one call.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "decision", content = "reason", rename_all = "lowercase")]
pub enum Decision {
    /// Observes, or actuates under auto-approval.
    Allowed,
    /// Actuates, and the operator said yes.
    Confirmed,
    /// Ran, but the ROS boundary clamped what it sent to the limits (what it changed).
    Clamped(String),
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
    /// Motion limits, enforced at the ROS boundary (defaults apply when absent).
    #[serde(default)]
    pub motion: Motion,
}

pub struct Policy {
    fence: Arc<Fence>,
    estop: Arc<EStop>,
    pub motion: Motion,
    pub read_only: bool,
    pub auto_approve: bool,
    pub timeout: Duration,
    /// Whether the policy file set the time limit (then it holds for every tool).
    timeout_given: bool,
    limits: Vec<(Regex, Limit)>,
    only: Vec<(Regex, Only)>,
    /// (tool, argument, anchored value pattern)
    observes: Vec<(Regex, String, Regex)>,
    confirm: Arc<dyn Confirm>,
}

impl std::fmt::Debug for Policy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Policy")
            .field("fence", &self.fence)
            .field("read_only", &self.read_only)
            .field("auto_approve", &self.auto_approve)
            .finish_non_exhaustive()
    }
}

fn compile(p: &str) -> Result<Regex, PolicyError> {
    Regex::new(p).map_err(|e| PolicyError::Pattern {
        pattern: p.to_string(),
        message: crate::fence::regex_error(&e),
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
        file.motion.validate().map_err(PolicyError::Motion)?;
        Ok(Policy {
            fence: Arc::new(Fence::new(&file.deny)?),
            estop: EStop::new(),
            motion: file.motion,
            read_only: file.read_only,
            auto_approve: file.auto_approve,
            timeout: Duration::from_secs_f64(file.timeout_s.unwrap_or(30.0).max(0.001)),
            timeout_given: file.timeout_s.is_some(),
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

    /// Share `estop` (the process's one latch) instead of a latch of its own.
    pub(crate) fn with_estop(mut self, estop: Arc<EStop>) -> Policy {
        self.estop = estop;
        self
    }

    /// The names off limits, shared with the ROS boundary.
    pub fn fence(&self) -> &Arc<Fence> {
        &self.fence
    }

    pub fn estop(&self) -> &Arc<EStop> {
        &self.estop
    }

    /// The tools a caller is offered under this policy: read-only drops every tool
    /// that only acts (those some of whose calls count as observing stay).
    pub fn offered(&self, registry: super::registry::Registry) -> super::registry::Registry {
        if self.read_only {
            registry.without_actuators(|name| self.may_observe(name))
        } else {
            registry
        }
    }

    /// Whether some calls of `tool` count as observing (an `observes` rule names it).
    pub(crate) fn may_observe(&self, tool: &str) -> bool {
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

    /// Add a deny pattern on the model's behalf (it can never remove one, and one that
    /// would fence off names in general is refused).
    pub fn add_model_pattern(&self, pattern: &str) -> Result<(), FenceError> {
        self.fence.add_model_pattern(pattern)
    }

    /// Whether `name` is behind the fence, in any spelling.
    pub fn denied(&self, name: &str) -> bool {
        self.fence.denies(name)
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
        if tool.effect() == Effect::Stops {
            return Decision::Allowed;
        }
        let actuates = self.actuates(tool.effect(), call);
        if let (true, Some(e)) = (actuates, self.estop.engaged_by()) {
            return Decision::Refused(format!(
                "the e-stop is engaged ({}): {} is refused until the operator resets it; tell the operator",
                e.source, call.name
            ));
        }
        if actuates && self.read_only {
            return Decision::Refused(format!(
                "{} changes the robot and the agent is read-only; tell the operator it cannot be done",
                call.name
            ));
        }
        if let Err(e) = tool.spec().validate(&call.arguments) {
            return Decision::Refused(format!("invalid arguments for {}: {e}", call.name));
        }
        if let Some(why) = self.rule_breach(call) {
            return Decision::Refused(why);
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

    /// Why `call` is refused when it names a name off limits (the deny-list), as the
    /// model reads it. That reason comes before any other: the model is told the name is
    /// out of reach, not that the operator did not ask for it.
    pub(crate) fn off_limits(&self, call: &ToolCall) -> Option<String> {
        let mut strings = Vec::new();
        collect_strings(&call.arguments, &mut strings);
        (strings.iter().any(|s| self.fence.denies(s)) || self.names_denied_parameter(call))
            .then(|| {
                "that name is off limits (the operator's deny-list); do not try it or anything like it again".into()
            })
    }

    /// The first of the fence, `limit` and `only` rules the call breaks, as the model
    /// reads it.
    fn rule_breach(&self, call: &ToolCall) -> Option<String> {
        if let Some(why) = self.off_limits(call) {
            return Some(why);
        }
        for (re, limit) in &self.limits {
            if re.is_match(&call.name) && matches_when(&limit.when, &call.arguments) {
                if let Some(why) = violates(limit, &call.arguments) {
                    return Some(format!("{why}; retry within the limit"));
                }
            }
        }
        for (re, only) in &self.only {
            if re.is_match(&call.name) && matches_when(&only.when, &call.arguments) {
                let ok = only.arguments.iter().any(|allowed| {
                    allowed
                        .iter()
                        .all(|(k, v)| call.arguments.get(k).is_some_and(|x| same(x, v)))
                });
                if !ok {
                    return Some(format!(
                        "{} is allowed only with these arguments: {}",
                        call.name,
                        serde_json::to_string(&only.arguments).unwrap_or_default()
                    ));
                }
            }
        }
        None
    }

    /// Whether the call names a denied parameter by its node and its name, as the
    /// parameter tools take them. (The ROS boundary judges every parameter request
    /// again, whatever tool built it; this refuses before the operator is asked.)
    fn names_denied_parameter(&self, call: &ToolCall) -> bool {
        let arg = |k: &str| call.arguments.get(k).and_then(Value::as_str);
        match (arg("node"), arg("name").or_else(|| arg("parameter"))) {
            (Some(node), Some(param)) => self.fence.denies_parameter(node, param),
            _ => false,
        }
    }

    /// Hide what the fence covers in a tool's output: array items that are denied
    /// names are dropped and every string is redacted. Returns how many were hidden.
    pub(crate) fn redact(&self, output: &mut Value) -> usize {
        self.fence.redact_json(output)
    }

    /// The time limit of a call of a tool that asks for `own` (`Tool::time_limit`): the
    /// policy file's when it sets one, else the tool's own, else the default.
    pub(crate) fn time_limit(&self, own: Option<Duration>) -> Duration {
        match own {
            Some(own) if !self.timeout_given => own,
            _ => self.timeout,
        }
    }

    /// `text` with denied names redacted (answers, errors, anything shown).
    pub(crate) fn redact_text<'a>(&self, text: &'a str) -> std::borrow::Cow<'a, str> {
        self.fence.redact(text)
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

/// Two argument values are the same: numbers by value, ROS names and type names in any
/// spelling (`reset` and `/reset `, `geometry_msgs/Twist` and `geometry_msgs/msg/Twist`).
fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::String(x), Value::String(y)) => {
            x == y
                || type_key(x) == type_key(y)
                || matches!((canonical(x), canonical(y)), (Ok(p), Ok(q)) if p == q)
        }
        _ => match (a.as_f64(), b.as_f64()) {
            (Some(x), Some(y)) => (x - y).abs() < 1e-9,
            _ => a == b,
        },
    }
}

/// A ROS type name with its spelling taken out: `pkg/Name`, `pkg/msg/Name` and
/// `pkg::msg::dds_::Name_` all give `pkg/Name`.
fn type_key(t: &str) -> String {
    let t = t.trim().trim_end_matches('_');
    let parts: Vec<&str> = t
        .split(['/', ':'])
        .filter(|p| !p.is_empty() && !matches!(*p, "msg" | "srv" | "action" | "dds_"))
        .collect();
    parts.join("/")
}

/// A `when` table holds: every key given and the same (`same`). A limit whose `when`
/// names `message_type` also holds when the call leaves the type out (the boundary
/// reads it from the topic): leaving a field out must not dodge a limit.
fn matches_when(when: &serde_json::Map<String, Value>, args: &Value) -> bool {
    when.iter().all(|(k, v)| match args.get(k) {
        Some(x) => same(x, v),
        None => k == "message_type",
    })
}

fn violates(limit: &Limit, args: &Value) -> Option<String> {
    let mut sq = 0.0;
    for p in &limit.paths {
        let x = match args.pointer(p) {
            // Absent fields are encoded as zero.
            None => continue,
            Some(v) => match v.as_f64() {
                Some(x) if x.is_finite() => x,
                _ => return Some(format!("{p} must be a finite number")),
            },
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
