//! The command line's names for the library's choices. The core enums (`Decoding`,
//! `Envelope`, `ToolChoice`, `AnswerMode`, `BackendKind`) know nothing of clap; these
//! mirrors give them their flag values and help text, and convert.

use clap::ValueEnum;

use crate::agent::config::Pick;
use crate::agent::AnswerMode;
use crate::backend::BackendKind;
use crate::decode::{Decoding, Envelope, ToolChoice};

/// With or without the grammar.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum DecodingArg {
    /// Every token is checked against the turn's grammar.
    Constrained,
    /// The model writes freely; calls are parsed afterwards and may be invalid.
    Free,
}

/// A tool-call format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum EnvelopeArg {
    /// `<tool_call>[{...}, ...]</tool_call>` in plain text (SmolLM2-Instruct family).
    Smollm2,
    /// `<tool_call>\n{...}\n</tool_call>` per call, markers are special tokens (Qwen).
    Qwen,
    /// `{"tool_calls": [...]}` as the whole turn.
    Json,
}

/// Whether a turn may, must or must not call a tool.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum ToolChoiceArg {
    /// Prose, or a call once the envelope's opening marker appears.
    Auto,
    /// One or more calls, nothing else.
    Required,
    /// Calls, or an empty call list that declines.
    Decline,
    /// Prose only.
    None,
}

/// How the model ends a turn without acting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum AnswerModeArg {
    /// By calling the `reply` tool.
    Tool,
    /// In prose.
    Prose,
    /// With an empty call list.
    Decline,
}

/// The model runtime.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum BackendArg {
    /// llama.cpp (llama-cpp-2)
    Llama,
    /// candle, pure Rust
    Candle,
}

impl From<DecodingArg> for Decoding {
    fn from(a: DecodingArg) -> Decoding {
        match a {
            DecodingArg::Constrained => Decoding::Constrained,
            DecodingArg::Free => Decoding::Free,
        }
    }
}

impl From<EnvelopeArg> for Envelope {
    fn from(a: EnvelopeArg) -> Envelope {
        match a {
            EnvelopeArg::Smollm2 => Envelope::Smollm2,
            EnvelopeArg::Qwen => Envelope::Qwen,
            EnvelopeArg::Json => Envelope::Json,
        }
    }
}

/// How an agent step picks its tool.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum PickArg {
    /// The model's likeliest name weighed with the tool retrieval's score.
    Weighed,
    /// The tool the request raised most over a content-free request.
    Calibrated,
    /// The model's likeliest tool name.
    Likeliest,
}

impl From<PickArg> for Pick {
    fn from(a: PickArg) -> Pick {
        match a {
            PickArg::Weighed => Pick::Weighed,
            PickArg::Calibrated => Pick::Calibrated,
            PickArg::Likeliest => Pick::Likeliest,
        }
    }
}

impl From<ToolChoiceArg> for ToolChoice {
    fn from(a: ToolChoiceArg) -> ToolChoice {
        match a {
            ToolChoiceArg::Auto => ToolChoice::Auto,
            ToolChoiceArg::Required => ToolChoice::Required,
            ToolChoiceArg::Decline => ToolChoice::Decline,
            ToolChoiceArg::None => ToolChoice::None,
        }
    }
}

impl From<AnswerModeArg> for AnswerMode {
    fn from(a: AnswerModeArg) -> AnswerMode {
        match a {
            AnswerModeArg::Tool => AnswerMode::Tool,
            AnswerModeArg::Prose => AnswerMode::Prose,
            AnswerModeArg::Decline => AnswerMode::Decline,
        }
    }
}

impl From<BackendArg> for BackendKind {
    fn from(a: BackendArg) -> BackendKind {
        match a {
            BackendArg::Llama => BackendKind::Llama,
            BackendArg::Candle => BackendKind::Candle,
        }
    }
}
