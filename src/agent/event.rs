//! The typed events a run produces, in order. Every front end (one-shot, REPL, JSON,
//! trace file) consumes the same stream, and nothing behind the fence reaches it: call
//! arguments, results, errors and answers are redacted, and streamed text is released a
//! whole word at a time so a denied name split across tokens is caught too.

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
    /// How a running call is going, in its own words ("0.6 of 1.0 m driven"); each
    /// replaces the one before, until the call's result.
    ToolProgress {
        step: usize,
        index: usize,
        name: String,
        text: String,
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

/// Streamed text, redacted a word at a time: a name-like word is held back until the
/// character after it shows it is complete.
pub struct WordStream {
    fence: std::sync::Arc<crate::fence::Fence>,
    pending: String,
}

impl WordStream {
    pub fn new(fence: std::sync::Arc<crate::fence::Fence>) -> WordStream {
        WordStream {
            fence,
            pending: String::new(),
        }
    }

    /// Add a piece; returns the text that can be shown now (possibly empty).
    pub fn push(&mut self, piece: &str) -> String {
        self.pending.push_str(piece);
        let name_char = crate::fence::name_char;
        let cut = self
            .pending
            .char_indices()
            .rev()
            .find(|&(_, c)| !name_char(c))
            .map_or(0, |(i, c)| i + c.len_utf8());
        let ready: String = self.pending.drain(..cut).collect();
        self.fence.redact(&ready).into_owned()
    }

    /// The rest, at the end of the stream.
    pub fn finish(&mut self) -> String {
        let rest = std::mem::take(&mut self.pending);
        self.fence.redact(&rest).into_owned()
    }
}
