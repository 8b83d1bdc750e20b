//! Grammar-constrained decoding with llguidance: one `Grammars` per model (the token
//! trie and the slicer, built once), one `Constraint` per turn (a compiled grammar and
//! its matcher state).
//!
//! Per step the sampled token is checked first (≈ 1.5 µs) and the full mask (tens of µs)
//! is computed only when that token is not allowed; sampling again from the masked logits
//! gives exactly the masked distribution. After each commit the tokens the grammar forces
//! are returned, to be evaluated in one batch with the next forward pass.

use std::sync::Arc;

use llguidance::api::TopLevelGrammar;
use llguidance::toktrie::SimpleVob;
use llguidance::{Matcher, ParserFactory};

use super::sample::Sampler;
use super::trie::TokenEnv;
use crate::backend::{TokenId, Tokenize, Vocab};

#[derive(Debug, thiserror::Error)]
pub enum ConstraintError {
    #[error("grammar does not compile: {0}")]
    Compile(String),
    #[error("constrained decoder failed: {0}")]
    Matcher(String),
}

/// The token sets llguidance's slicer precomputes, so that a mask inside a JSON string
/// (most of a call's free text) is one set lookup, not a walk of the whole vocabulary:
/// a string's characters up to 30 at a time (a bounded string accepts any such run until
/// it is within 30 of its cap: `tool::spec` caps free strings at 160) and without bound.
/// Each costs 2.5–3 MiB at a 49k vocabulary. They are two of llguidance's default four
/// (`json_slices`), which add runs of whitespace (the grammars write none of their own:
/// separators are fixed) and strings up to 10 characters (contained in the first). A
/// slice changes only the speed of a mask, never which tokens it allows.
const SLICES: [&str; 2] = [r#"[^"\\\x00-\x1F\x7F]{1,30}"#, r#"[^"\\\x00-\x1F\x7F]+"#];

/// The per-model half of constrained decoding.
pub struct Grammars {
    factory: ParserFactory,
}

impl Grammars {
    pub fn new(vocab: &Vocab, tokenizer: Arc<dyn Tokenize>) -> Result<Grammars, ConstraintError> {
        let env = TokenEnv::shared(vocab, tokenizer);
        let slices: Vec<String> = SLICES.iter().map(|s| s.to_string()).collect();
        let mut factory = ParserFactory::new(&env, Default::default(), &slices)
            .map_err(|e| ConstraintError::Compile(e.to_string()))?;
        // llguidance writes grammar warnings to stderr by default; ours go to tracing.
        factory.quiet();
        Ok(Grammars { factory })
    }

    /// Compile a Lark grammar (≈ 1 ms) into a fresh constraint.
    pub fn compile(&self, lark: &str) -> Result<Constraint, ConstraintError> {
        let _span = tracing::debug_span!("grammar_compile").entered();
        let parser = self
            .factory
            .create_parser(TopLevelGrammar::from_lark(lark.to_string()))
            .map_err(|e| ConstraintError::Compile(e.to_string()))?;
        let matcher = Matcher::new(Ok(parser));
        if let Some(e) = matcher.get_error() {
            return Err(ConstraintError::Compile(e));
        }
        Ok(Constraint {
            matcher,
            forced: Vec::with_capacity(64),
            masks_computed: 0,
            fast_forward: true,
        })
    }
}

/// One turn's grammar state.
pub struct Constraint {
    matcher: Matcher,
    forced: Vec<TokenId>,
    /// Steps where the sampled token was refused and the full mask was needed.
    pub masks_computed: usize,
    fast_forward: bool,
}

impl Constraint {
    fn err(&self, e: impl std::fmt::Display) -> ConstraintError {
        ConstraintError::Matcher(self.matcher.get_error().unwrap_or_else(|| e.to_string()))
    }

    /// Sample a token the grammar allows. `None` when nothing is allowed.
    pub fn choose(
        &mut self,
        logits: &mut [f32],
        sampler: &mut Sampler,
    ) -> Result<Option<TokenId>, ConstraintError> {
        if let Some(tok) = sampler.sample(logits) {
            let _span = tracing::trace_span!("validate").entered();
            let ok = self
                .matcher
                .validate_tokens(&[tok])
                .map_err(|e| self.err(e))?;
            if ok == 1 {
                return Ok(Some(tok));
            }
        }
        let mask = self.compute_mask()?;
        self.masks_computed += 1;
        for (i, l) in logits.iter_mut().enumerate() {
            if !mask.is_allowed(i as TokenId) {
                *l = f32::NEG_INFINITY;
            }
        }
        Ok(sampler.sample(logits))
    }

    /// With fast-forward off, forced tokens are sampled one by one like any other (to
    /// measure what the grammar alone costs).
    pub fn set_fast_forward(&mut self, on: bool) {
        self.fast_forward = on;
    }

    /// Tokens the grammar forces before anything is sampled (e.g. the whole opening of a
    /// required call), already committed: they can join the prompt's batch.
    pub(crate) fn forced_at_start(&mut self) -> Result<&[TokenId], ConstraintError> {
        self.take_forced()
    }

    /// The tokens the grammar forces from here (after tokens committed with `advance`),
    /// already committed.
    pub(crate) fn take_forced(&mut self) -> Result<&[TokenId], ConstraintError> {
        self.forced.clear();
        if self.fast_forward && !self.matcher.is_stopped() {
            let ff = self.matcher.compute_ff_tokens();
            if !ff.is_empty() {
                self.matcher.consume_tokens(&ff).map_err(|e| self.err(e))?;
                self.forced.extend_from_slice(&ff);
            }
        }
        Ok(&self.forced)
    }

    /// Commit a sampled token; returns the tokens the grammar now forces (already
    /// committed), to be appended without sampling.
    pub fn commit(&mut self, tok: TokenId) -> Result<&[TokenId], ConstraintError> {
        self.matcher.consume_token(tok).map_err(|e| self.err(e))?;
        self.take_forced()
    }

    /// Nothing but end-of-generation can follow.
    pub fn is_stopped(&self) -> bool {
        self.matcher.is_stopped()
    }

    /// The output so far is a complete sentence of the grammar.
    pub fn is_accepting(&mut self) -> bool {
        self.matcher.is_accepting().unwrap_or(false)
    }

    /// Does the grammar allow `tokens` from here (without committing them)?
    pub fn allows(&mut self, tokens: &[TokenId]) -> bool {
        self.matcher
            .validate_tokens(tokens)
            .is_ok_and(|n| n == tokens.len())
    }

    /// How many leading tokens of `tokens` the grammar allows from here, without
    /// committing any (a refused or failed check allows none past it).
    pub(crate) fn allowed_prefix(&mut self, tokens: &[TokenId]) -> usize {
        self.matcher.validate_tokens(tokens).unwrap_or(0)
    }

    /// The full allowed-token mask, as llguidance computes it on a refused token.
    pub fn compute_mask(&mut self) -> Result<SimpleVob, ConstraintError> {
        let _span = tracing::trace_span!("mask").entered();
        self.matcher.compute_mask().map_err(|e| self.err(e))
    }

    /// Undo the last `n` committed tokens (forced ones included): the grammar state is
    /// as it was before them.
    pub(crate) fn rollback(&mut self, n: usize) -> Result<(), ConstraintError> {
        if n == 0 {
            return Ok(());
        }
        self.matcher.rollback(n).map_err(|e| self.err(e))
    }

    /// Commit `tok` without taking the forced tokens that follow (to replay a known
    /// token sequence, as benchmarks and tests do).
    pub fn advance(&mut self, tok: TokenId) -> Result<(), ConstraintError> {
        self.matcher.consume_token(tok).map_err(|e| self.err(e))
    }
}
