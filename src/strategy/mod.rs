//! Tool-calling strategies: what shapes a turn's calls beyond what the grammar enforces.
//! The grammar makes every call valid; a strategy makes it more likely to be the right
//! call, with the right values, for what was asked.
//!
//! Every strategy implements `Strategy`, whose methods are the points of a turn where it
//! may act; each has a default that does nothing, and each implementation documents its
//! cost per token and per turn. A `Pipeline` runs several in order, and `crate::turn::run`
//! drives a turn through them. Strategies are tested with scripted logits and texts, never with a
//! model's output.
//!
//! Layout:
//! - `choice`: which tool a turn calls, calibrated (against a content-free request, list
//!   length too) or weighed with a prior (the agent's tool retrieval)
//! - `copy`: the copy bias (values lean towards spans of the request or a tool result)
//! - `repeats`: guards on what a turn writes (no looping arrays, no repeated call)
//! - `verify`: call verification (a call's values must come from the request)
//! - `ground`: grounding (optional arguments nobody asked for are dropped)
//! - `default`: what a parameter's schema declares as its default (shared knowledge)
//! - `likelihood`: the model's log-probabilities of continuations (for calibrated choices)

pub mod choice;
pub mod copy;
pub mod default;
pub mod ground;
pub mod likelihood;
pub mod repeats;
pub mod verify;

use crate::backend::{Backend, BackendError, TokenId};
use crate::decode::{DecodeError, LogitsHook, Session, TokenContext};
use crate::tool::{ToolCall, ToolSpec};
use likelihood::{chooser_logprobs, continuation_logprobs};

/// What to do with a call a turn just wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Review {
    Keep,
    /// Write it again, more strictly (`Strategy::strict`); if it fails again, reject it.
    Redo,
    /// Do not make it: a further call is dropped, a first call gives way to answering.
    Reject,
}

/// One strategy (see the module header). `&mut self` methods may keep per-turn state; a
/// strategy is built for one turn or reset by `strict(false)` between calls.
pub trait Strategy {
    /// Short name, for traces.
    fn name(&self) -> &'static str;

    /// Whether this strategy decides which tool a turn calls (so the driver prepares the
    /// scores `choose` needs).
    fn decides(&self) -> bool {
        false
    }

    /// Once per turn, before decoding: which of the candidate tool names (their tokens,
    /// after what the turn has `written`: the call's opening) the turn calls; `fallback`
    /// is the one that answers in words. `None`: the model decides.
    fn choose(
        &mut self,
        _scorer: &mut Scorer,
        _written: &[TokenId],
        _names: &[Vec<TokenId>],
        _fallback: Option<usize>,
    ) -> Result<Option<usize>, DecodeError> {
        Ok(None)
    }

    /// Per closed call of a list that may go on: whether another call follows (`options`
    /// are the tokens that go on and those that close, after `written`). `None`: no view.
    fn go_on(
        &mut self,
        _scorer: &mut Scorer,
        _written: &[TokenId],
        _options: &[Vec<TokenId>; 2],
    ) -> Result<Option<bool>, DecodeError> {
        Ok(None)
    }

    /// Per token: shift the logits (the decode loop's hook).
    fn adjust(&mut self, _cx: &TokenContext, _logits: &mut [f32]) {}

    /// Per closed call: keep it or not. `first` is the turn's first call.
    fn review(&mut self, _call: &ToolCall, _earlier: &[ToolCall], _first: bool) -> Review {
        Review::Keep
    }

    /// Be stricter while a call is written again after `Review::Redo` (`on`), or as
    /// usual again. Returns whether it changes anything.
    fn strict(&mut self, _on: bool) -> bool {
        false
    }

    /// Per call, after the turn and before it runs: drop arguments nobody asked for;
    /// returns their names.
    fn settle(&self, _call: &mut ToolCall, _spec: &ToolSpec) -> Vec<String> {
        Vec::new()
    }
}

/// Strategies applied in order.
#[derive(Default)]
pub struct Pipeline {
    strategies: Vec<Box<dyn Strategy>>,
}

impl Pipeline {
    pub fn new() -> Pipeline {
        Pipeline::default()
    }

    pub fn with(mut self, s: impl Strategy + 'static) -> Pipeline {
        self.strategies.push(Box::new(s));
        self
    }

    pub fn push(&mut self, s: Box<dyn Strategy>) {
        self.strategies.push(s);
    }

    pub fn is_empty(&self) -> bool {
        self.strategies.is_empty()
    }

    /// The strategies' names, in order (for traces and reports).
    pub fn names(&self) -> Vec<&'static str> {
        self.strategies.iter().map(|s| s.name()).collect()
    }

    pub fn decides(&self) -> bool {
        self.strategies.iter().any(|s| s.decides())
    }

    /// The first strategy's choice that has one.
    pub fn choose(
        &mut self,
        scorer: &mut Scorer,
        written: &[TokenId],
        names: &[Vec<TokenId>],
        fallback: Option<usize>,
    ) -> Result<Option<usize>, DecodeError> {
        for s in &mut self.strategies {
            if let Some(c) = s.choose(scorer, written, names, fallback)? {
                return Ok(Some(c));
            }
        }
        Ok(None)
    }

    /// The first strategy's view on going on that has one.
    pub(crate) fn go_on(
        &mut self,
        scorer: &mut Scorer,
        written: &[TokenId],
        options: &[Vec<TokenId>; 2],
    ) -> Result<Option<bool>, DecodeError> {
        for s in &mut self.strategies {
            if let Some(g) = s.go_on(scorer, written, options)? {
                return Ok(Some(g));
            }
        }
        Ok(None)
    }

    /// The sternest review.
    pub(crate) fn review(&mut self, call: &ToolCall, earlier: &[ToolCall], first: bool) -> Review {
        self.strategies
            .iter_mut()
            .map(|s| s.review(call, earlier, first))
            .max()
            .unwrap_or(Review::Keep)
    }

    /// Whether any strategy could be stricter.
    pub(crate) fn strict(&mut self, on: bool) -> bool {
        let mut any = false;
        for s in &mut self.strategies {
            any |= s.strict(on);
        }
        any
    }

    /// Every strategy's settling, in order; the names of the arguments dropped.
    pub fn settle(&self, call: &mut ToolCall, spec: &ToolSpec) -> Vec<String> {
        self.strategies
            .iter()
            .flat_map(|s| s.settle(call, spec))
            .collect()
    }
}

impl LogitsHook for Pipeline {
    fn adjust(&mut self, cx: &TokenContext, logits: &mut [f32]) {
        for s in &mut self.strategies {
            s.adjust(cx, logits);
        }
    }
}

/// The model's log-probabilities of continuations after what a turn has written, once
/// with the request (`real`) and once with a content-free request in its place (`base`).
pub struct Scorer<'a> {
    pub backend: &'a mut dyn Backend,
    pub session: &'a mut Session,
    /// The prompt with the content-free request.
    pub base: &'a [TokenId],
    /// The prompt with the request.
    pub real: &'a [TokenId],
}

/// A candidate set scored with the request and without.
#[derive(Debug, Clone, PartialEq)]
pub struct Scores {
    pub real: Vec<f64>,
    pub base: Vec<f64>,
}

impl Scorer<'_> {
    /// Each candidate's log-probability after `written`, with the request only, read by
    /// the tool chooser's adapter where the runtime has one (`likelihood::chooser_logprobs`).
    pub fn real(
        &mut self,
        written: &[TokenId],
        candidates: &[Vec<TokenId>],
    ) -> Result<Vec<f64>, BackendError> {
        let mut ctx = self.real.to_vec();
        ctx.extend_from_slice(written);
        chooser_logprobs(self.backend, self.session, &ctx, candidates)
    }

    /// Both scores of each candidate after `written`. The baseline goes first so the
    /// cache ends on the real prompt, which the turn continues from.
    pub fn scores(
        &mut self,
        written: &[TokenId],
        candidates: &[Vec<TokenId>],
    ) -> Result<Scores, BackendError> {
        let mut ctx = self.base.to_vec();
        ctx.extend_from_slice(written);
        let base = continuation_logprobs(self.backend, self.session, &ctx, candidates)?;
        let mut ctx = self.real.to_vec();
        ctx.extend_from_slice(written);
        let real = continuation_logprobs(self.backend, self.session, &ctx, candidates)?;
        Ok(Scores { real, base })
    }
}
