//! Tools as the model sees them and as the agent runs them: a `Tool` trait with typed
//! arguments (one JSON schema, generated from the Rust type, serves the prompt, the
//! grammar and validation), a declared `Effect`, a registry of named packages, and the
//! policy every call passes through.
//!
//! Tools know nothing of the model; the agent knows tools only through this module.
//!
//! Layout:
//! - `spec`: `ToolSpec` (name, description, schema), `ToolCall`, schema normalisation
//! - `examples`: the shipped tools' example requests (data files, one per language)
//! - `schema`: JSON schemas from Rust types (schemars), cleaned for grammars
//! - `registry`: the type-erased `DynTool`, named packages, lookup
//! - `policy`: the fence, the e-stop, read-only, confirmation, argument limits, time limits
//! - `exec`: running calls after the policy (concurrent, time-limited, aborted on the
//!   e-stop, outputs redacted)

pub mod examples;
pub mod exec;
pub mod policy;
pub mod registry;
pub mod schema;
pub mod spec;

use std::future::Future;
use std::time::Duration;

pub use policy::{Confirm, Decision, Policy, PolicyError};
pub use registry::{DynTool, Package, Registry};
pub use spec::{specs_from_json, SpecError, ToolCall, ToolSpec};

/// The name of the tool that stops the robot (`Effect::Stops`; `tools::stop`), which
/// every robot's tools include and every request is offered.
pub const STOP_TOOL: &str = "robot_stop";

/// What a tool does to the world: the policy confirms every `Actuates` call.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Effect {
    /// Reads state (downlink): listing, echoing, computing.
    Observes,
    /// Changes the robot or its world (uplink): publishing, calling, setting.
    Actuates,
    /// Stops the robot (the e-stop): always allowed, never confirmed, never fenced.
    Stops,
}

/// A failed call, as the model will read it: short, and saying what to do next.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ToolError {
    #[error("invalid arguments: {0}")]
    InvalidArguments(String),
    #[error("{0}")]
    Failed(String),
    #[error("timed out after {0:?}")]
    Timeout(Duration),
    #[error("refused: {0}")]
    Refused(String),
}

/// What a running call may consult.
#[derive(Debug, Clone)]
pub struct ToolContext {
    /// The call's time limit (tools that wait, like `system_wait`, respect it).
    pub timeout: Duration,
    /// Where a long call says how it is going, for the operator to see while it runs.
    pub progress: Progress,
}

impl ToolContext {
    /// A context whose progress reports go nowhere.
    pub fn new(timeout: Duration) -> ToolContext {
        ToolContext {
            timeout,
            progress: Progress::default(),
        }
    }
}

/// A long call's reports of how it is going ("0.6 of 1.0 m driven", "waiting for a
/// message, 2 s of 5"), shown to the operator while it runs; they reach the front end
/// through the fence like everything else, and never the model (it reads the result).
/// A report is a line of text, or a message (an action's feedback) that the agent words
/// in one line as it words results. The default goes nowhere.
#[derive(Clone, Default)]
pub struct Progress(
    Option<(
        usize,
        tokio::sync::mpsc::UnboundedSender<(usize, serde_json::Value)>,
    )>,
);

impl Progress {
    /// Reports of the call at `index` of a turn, sent into `to`.
    pub fn to(
        index: usize,
        to: tokio::sync::mpsc::UnboundedSender<(usize, serde_json::Value)>,
    ) -> Progress {
        Progress(Some((index, to)))
    }

    /// Say how the call is going (one short line, or a message; each replaces the one
    /// before).
    pub fn report(&self, what: impl Into<serde_json::Value>) {
        if let Some((index, to)) = &self.0 {
            // Nobody listening any more (the turn ended) is no error of the tool's.
            let _ = to.send((*index, what.into()));
        }
    }
}

impl std::fmt::Debug for Progress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "Progress(on)"
        } else {
            "Progress(off)"
        })
    }
}

/// A tool with typed arguments. Implement this for a robot-specific tool; the registry
/// erases the type.
pub trait Tool: Send + Sync + 'static {
    type Args: serde::de::DeserializeOwned + schemars::JsonSchema + Send;
    const NAME: &'static str;
    const EFFECT: Effect;
    /// Arguments that list things in the order they are done (`ToolSpec::sequence`).
    const SEQUENCE: &'static [&'static str] = &[];
    /// Whether a call writes down what the agent keeps for later (a place taught at the
    /// robot's pose, a note): it reads the robot, but what it records must be true, so
    /// it is not made once an act of the request came to nothing (`ToolSpec::records`).
    const RECORDS: bool = false;
    /// Whether it computes from numbers the operator or a result gives, in an argument
    /// its schema cannot show as a number (an arithmetic expression): it is not offered
    /// while nothing said or returned spells one (`ToolSpec::computes`).
    const COMPUTES: bool = false;
    /// The kind of the robot's names a call lists, all of them (`ToolSpec::lists`).
    const LISTS: Option<&'static str> = None;
    /// The contract the model reads: one or two sentences with ranges, side effects and
    /// time bounds.
    fn description(&self) -> String;
    fn call(
        &self,
        args: Self::Args,
        cx: &ToolContext,
    ) -> impl Future<Output = Result<serde_json::Value, ToolError>> + Send;
    /// The arguments as the robot can take them now, when that is narrower than
    /// `Args` says (a service's request typed by that service's type): a JSON schema
    /// every value of which `Args` also takes. The grammar holds calls to it; the
    /// prompt shows `Args`, so it stays the same while the robot changes. `None` (the
    /// default): `Args` as it is.
    fn live_parameters(&self) -> Option<serde_json::Value> {
        None
    }
    /// How long a call may take when the policy file sets no time limit, if longer than
    /// the default's 30 s (a drive through several places). A policy file's limit holds
    /// for every tool.
    fn time_limit(&self) -> Option<std::time::Duration> {
        None
    }
}
