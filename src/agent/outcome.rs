//! What a run comes to: its answer, why it ended, every call with its decision and
//! result, and its timings; and the one way it fails (a broken model runtime).

use serde::Serialize;
use serde_json::Value;

use crate::decode::DecodeError;
use crate::tool::Decision;

#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    #[error(transparent)]
    Decode(#[from] DecodeError),
    #[error("cannot start the tool runtime: {0}")]
    Runtime(String),
}

/// Why a run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Finish {
    Answer,
    MaxSteps,
    Cancelled,
}

/// One executed (or refused) call.
#[derive(Debug, Clone, Serialize)]
pub struct StepRecord {
    pub step: usize,
    pub name: String,
    pub arguments: Value,
    pub output: Value,
    pub ok: bool,
    pub ms: f64,
    pub decision: Decision,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct Timings {
    pub total_ms: f64,
    pub model_ms: f64,
    pub tools_ms: f64,
    /// Tokens the model wrote (forced ones included), over every step.
    pub generated_tokens: usize,
    /// Prompt tokens of each step, and how many of them came from the KV cache.
    pub prompt_tokens: Vec<usize>,
    pub reused_tokens: Vec<usize>,
    /// Query to the first token the model emitted.
    pub first_token_ms: Option<f64>,
    /// Query to the first token of the first tool call.
    pub first_call_token_ms: Option<f64>,
    /// Query to the first tool call written whole (the turn that made it ended), before
    /// the guards and the policy: when the robot could first act.
    pub first_call_ms: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct RunResult {
    pub answer: String,
    pub finish: Finish,
    pub steps: Vec<StepRecord>,
    pub timings: Timings,
    /// Tools offered to the model for this query.
    pub tools_offered: Vec<String>,
}
