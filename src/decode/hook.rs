//! The logits-hook seam: the one place where anything outside the grammar shapes which
//! token a turn writes. The decode loop calls the hook once per sampled token, after the
//! forward pass and before the grammar and the sampler see the logits, with where the
//! turn stands. Biases and guards (the copy bias, the repeat guards in `strategy`) act
//! only through it; nothing wraps a `Backend` to change logits.
//!
//! A hook may raise or lower logits; it may not set −∞ (that is the grammar's job, and a
//! hook that removed every token the grammar allows would leave nothing to sample).

use crate::backend::Vocab;
use crate::json::JsonScan;

/// Where a turn stands when the decoder asks for the next token.
pub struct TokenContext<'a> {
    pub vocab: &'a Vocab,
    /// The turn's text so far, as JSON (`scan.text()` is the text itself).
    pub scan: &'a JsonScan,
    /// Tokens the turn may still write.
    pub remaining: usize,
}

/// Something that shifts next-token logits.
pub trait LogitsHook {
    /// Adjust `logits` (one per vocabulary entry) for the token after `cx`.
    fn adjust(&mut self, cx: &TokenContext, logits: &mut [f32]);
}

/// The hook that changes nothing.
pub struct NoHook;

impl LogitsHook for NoHook {
    fn adjust(&mut self, _: &TokenContext, _: &mut [f32]) {}
}
