//! The typed events a run produces, in order. Every front end (one-shot, REPL, JSON,
//! trace file) consumes the same stream.

use serde::Serialize;
use serde_json::Value;

use crate::tool::Decision;

#[derive(Debug, Clone, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    /// A reasoning step begins; `tools` are the ones offered to the model this step.
    Step {
        step: usize,
        prompt_tokens: usize,
        reused_tokens: usize,
        tools: Vec<String>,
    },
    /// Text as the model writes it.
    Token {
        text: String,
    },
    /// A call the model made, with the policy's decision.
    ToolCall {
        step: usize,
        index: usize,
        name: String,
        arguments: Value,
        decision: Decision,
    },
    /// What a call returned (or the error the model reads), and how long it took.
    ToolResult {
        step: usize,
        index: usize,
        name: String,
        output: Value,
        ok: bool,
        ms: f64,
    },
    /// The final answer.
    Answer {
        text: String,
        finish: String,
    },
    Error {
        message: String,
    },
}
