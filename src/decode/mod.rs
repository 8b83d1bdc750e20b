//! Decoding: the grammar and sampling layer. Turns logits into tokens, one step at a
//! time, over a `Backend`: the generation loop, the sampler, grammar-constrained
//! decoding (llguidance), the tool-call envelopes, what a turn asks for and returns, and
//! the one seam through which anything else shapes a token (`hook::LogitsHook`). It knows
//! tool specs (to build grammars) but nothing of tool execution, strategies or ROS.
//!
//! Layout:
//! - `generate`: the loop (prefill, hook, grammar, sample, forced tokens, drafts)
//! - `draft`: prompt-lookup drafting, a guess at the next tokens copied from the context
//! - `hook`: the logits-hook seam
//! - `close`: the steer to a complete call at the token limit
//! - `sample`: greedy / temperature, top-k, top-p sampling with a seeded generator
//! - `trie`: llguidance's token environment built from a backend's vocabulary
//! - `constraint`: per-model grammars, per-turn constraint (mask, commit, force, rollback)
//! - `envelope`: tool-call formats per model family: grammar, prompt text, parser
//! - `request`: what a turn asks for (`TurnRequest`), the prompt it renders, what it
//!   returns (`TurnResult`); the turn itself is decoded by `crate::turn`

mod close;
pub mod constraint;
pub mod draft;
pub mod envelope;
pub mod generate;
pub mod hook;
pub mod request;
pub mod sample;
mod trie;

pub use crate::backend::{PromptCache, Session};
pub use crate::json::JsonScan;
pub use constraint::{Constraint, ConstraintError, Grammars};
pub use draft::Draft;
pub use envelope::{Envelope, ToolChoice, Turn};
pub use generate::{generate, prompt_tokens, GenerationStats, Steering};
pub use hook::{LogitsHook, NoHook, TokenContext};
pub use sample::{Sampler, SamplerConfig};

use crate::backend::BackendError;

/// With or without the grammar: the switch that lets one run compare both.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Decoding {
    /// Every token is checked against the turn's grammar.
    #[default]
    Constrained,
    /// The model writes freely; calls are parsed afterwards and may be invalid.
    Free,
}

#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    #[error(transparent)]
    Backend(#[from] BackendError),
    #[error(transparent)]
    Template(#[from] crate::backend::TemplateError),
    #[error(transparent)]
    Constraint(#[from] ConstraintError),
    /// An engine that runs the model elsewhere failed (`remote`).
    #[error(transparent)]
    Engine(Box<dyn std::error::Error + Send + Sync>),
}

/// Why a generation stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Finish {
    /// The model emitted an end-of-generation token.
    EndOfGeneration,
    /// The token limit was reached.
    Length,
    /// The context window is full.
    ContextFull,
    /// The caller asked to stop (e.g. a stop string was seen).
    Stopped,
    /// Every token was masked out (only possible with a constraint that dead-ends).
    NoCandidate,
}
