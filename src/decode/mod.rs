//! Decoding: turning logits into tokens, one step at a time, over a `Backend`.
//!
//! Owns the generation loop (prefill, sample, stop), the sampler, grammar-constrained
//! decoding, and the session that remembers what the backend's KV cache holds so a new
//! prompt sharing a prefix evaluates only its tail. It knows tool specs (to build
//! grammars) but nothing of tool execution or ROS.
//!
//! Layout:
//! - `sample`: greedy / temperature, top-k, top-p sampling with a seeded generator
//! - `trie`: llguidance's token environment built from a backend's vocabulary
//! - `constraint`: per-model grammar factory and per-turn constraint (mask, commit, forced tokens)
//! - `copy`: the copy bias: argument values lean towards spans of the request
//! - `envelope`: tool-call formats per model family: grammar, prompt text, parser
//! - `turn`: one assistant turn with tools: prompt, constrained generation, parse
//! - `gate`: the relevance gate: which tool, and whether another call follows, decided
//!   by what the request changed in the model's likelihoods
//! - `verify`: whether a proposed extra call brings values the request asked for

pub mod constraint;
pub mod copy;
pub mod envelope;
pub mod gate;
pub mod sample;
pub mod trie;
pub mod turn;
pub mod verify;

use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use crate::backend::{Backend, BackendError, TokenId};
pub use constraint::{Constraint, ConstraintError, Grammars};
pub use envelope::{Envelope, ToolChoice, Turn};
pub use sample::{Sampler, SamplerConfig};

/// With or without the grammar: the switch that lets one run compare both.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
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

#[derive(Debug, Clone, Default)]
pub struct GenerationStats {
    pub prompt_tokens: usize,
    /// Prompt tokens found already in the KV cache and not evaluated again.
    pub reused_tokens: usize,
    pub prompt_time: Duration,
    pub generated_tokens: usize,
    /// From the first sampled token to the last: sampling plus single-token forwards.
    pub gen_time: Duration,
    /// Forward passes during generation (each evaluates a sampled token and the tokens
    /// the grammar forced after it).
    pub gen_forwards: usize,
    /// Tokens appended because the grammar forced them, without sampling.
    pub forced_tokens: usize,
    /// Of those, the ones forced before the first sample (evaluated with the prompt).
    pub forced_at_start: usize,
    /// Steps where the sampled token was refused and the full mask was computed.
    pub masks_computed: usize,
    /// Time spent in the grammar (checking, masking, committing, forcing).
    pub constraint_time: Duration,
    pub time_to_first_token: Duration,
}

impl GenerationStats {
    pub fn prompt_tok_per_s(&self) -> f64 {
        let evaluated = self.prompt_tokens - self.reused_tokens;
        evaluated as f64 / self.prompt_time.as_secs_f64().max(1e-9)
    }

    /// Forward passes per second: the model's decode speed.
    pub fn gen_tok_per_s(&self) -> f64 {
        self.gen_forwards as f64 / self.gen_time.as_secs_f64().max(1e-9)
    }

    /// Tokens emitted per second after the prompt, forced ones included: the output
    /// rate an operator sees. (Tokens forced before the first sample ride in the
    /// prompt's batch and are left out.)
    pub fn output_tok_per_s(&self) -> f64 {
        let n = self
            .generated_tokens
            .saturating_sub(self.forced_at_start + 1);
        n as f64 / self.gen_time.as_secs_f64().max(1e-9)
    }
}

/// The tokens of a prompt as a fresh context needs them: BOS when the model wants one
/// (once, even if a template writes it too), then `text`. With `special`, special-token
/// texts (from a rendered chat template) become their ids; without, the text is literal.
pub fn prompt_tokens(
    backend: &dyn Backend,
    text: &str,
    special: bool,
) -> Result<Vec<TokenId>, BackendError> {
    let mut prompt: Vec<TokenId> = backend.vocab().bos().into_iter().collect();
    let body = backend.tokenize(text, special)?;
    let skip = usize::from(!prompt.is_empty() && body.first() == prompt.first());
    prompt.extend_from_slice(&body[skip..]);
    Ok(prompt)
}

/// The token sequence the backend's KV cache holds.
#[derive(Debug, Default, Clone)]
pub struct Session {
    tokens: Vec<TokenId>,
}

impl Session {
    pub fn new() -> Session {
        Session::default()
    }

    pub fn tokens(&self) -> &[TokenId] {
        &self.tokens
    }

    /// Forget the cache contents (the next prompt is evaluated in full).
    pub fn clear(&mut self) {
        self.tokens.clear();
    }

    /// How many leading tokens of `prompt` are cached, leaving at least one to evaluate
    /// (the backend returns logits only for tokens it evaluates).
    pub fn reusable(&self, prompt: &[TokenId]) -> usize {
        let common = self
            .tokens
            .iter()
            .zip(prompt)
            .take_while(|(a, b)| a == b)
            .count();
        common.min(prompt.len().saturating_sub(1))
    }
}

/// Generate after `prompt`, calling `on_token` with each emitted token, sampled or
/// forced by the grammar (the stop token included, so a caller can see why it ended);
/// `on_token` may break to stop early. With a constraint, every token obeys its grammar.
pub fn generate(
    backend: &mut dyn Backend,
    session: &mut Session,
    prompt: &[TokenId],
    max_tokens: usize,
    sampler: &mut Sampler,
    mut constraint: Option<&mut Constraint>,
    mut on_token: impl FnMut(TokenId) -> ControlFlow<()>,
) -> Result<(Finish, GenerationStats), DecodeError> {
    let mut stats = GenerationStats {
        prompt_tokens: prompt.len(),
        ..Default::default()
    };
    if prompt.is_empty() {
        return Err(DecodeError::Backend(BackendError::Eval {
            backend: backend.name(),
            reason: "empty prompt".into(),
        }));
    }
    let start = Instant::now();
    let keep = session.reusable(prompt);
    stats.reused_tokens = keep;
    session.tokens.truncate(keep);
    let n_ctx = backend.context_len();
    // Room for every token this call can add, so the per-token loop never reallocates.
    session
        .tokens
        .reserve((prompt.len() - keep + max_tokens).min(n_ctx));
    let mut pending: Vec<TokenId> = Vec::with_capacity(64);
    // What the grammar forces before any sampling joins the prompt's batch.
    let mut first: Vec<TokenId> = prompt[keep..].to_vec();
    if let Some(c) = constraint.as_deref_mut() {
        let t = Instant::now();
        let forced = c.forced_at_start()?;
        stats.constraint_time += t.elapsed();
        first.extend(forced.iter().take(max_tokens));
        stats.forced_at_start = first.len() - (prompt.len() - keep);
        stats.forced_tokens += stats.forced_at_start;
        stats.generated_tokens += stats.forced_at_start;
    }
    let mut logits = match backend.forward(keep, &first) {
        Ok(l) => l,
        Err(e) => {
            // What the cache holds past `keep` is unknown now; start clean next time.
            session.clear();
            return Err(e.into());
        }
    };
    session.tokens.extend_from_slice(&first);
    stats.prompt_time = start.elapsed();
    // Tokens forced at the start were evaluated with the prompt; they reach the caller
    // now, once the model has actually seen them.
    for &f in &first[prompt.len() - keep..] {
        if stats.time_to_first_token.is_zero() {
            stats.time_to_first_token = start.elapsed();
        }
        let _ = on_token(f);
    }
    let gen_start = Instant::now();

    let finish = 'gen: loop {
        // A grammar finished by forced tokens alone allows only end-of-generation.
        if constraint.as_deref().is_some_and(Constraint::is_stopped) {
            break Finish::EndOfGeneration;
        }
        let chosen = match constraint.as_deref_mut() {
            Some(c) => {
                let t = Instant::now();
                let tok = c.choose(logits, sampler)?;
                stats.constraint_time += t.elapsed();
                tok
            }
            None => sampler.sample(logits),
        };
        let Some(tok) = chosen else {
            break Finish::NoCandidate;
        };
        if stats.time_to_first_token.is_zero() {
            stats.time_to_first_token = start.elapsed();
        }
        stats.generated_tokens += 1;
        let flow = on_token(tok);
        if backend.vocab().is_eog(tok) {
            break Finish::EndOfGeneration;
        }
        if flow.is_break() {
            break Finish::Stopped;
        }
        pending.clear();
        pending.push(tok);
        if let Some(c) = constraint.as_deref_mut() {
            let t = Instant::now();
            let forced = c.commit(tok)?;
            stats.constraint_time += t.elapsed();
            for &f in forced {
                if stats.generated_tokens >= max_tokens {
                    break;
                }
                stats.generated_tokens += 1;
                stats.forced_tokens += 1;
                pending.push(f);
                if on_token(f).is_break() {
                    break 'gen Finish::Stopped;
                }
            }
            // A finished grammar allows only end-of-generation: no need to ask the model.
            if c.is_stopped() {
                break Finish::EndOfGeneration;
            }
        }
        if stats.generated_tokens >= max_tokens {
            break Finish::Length;
        }
        if session.tokens.len() + pending.len() > n_ctx {
            break Finish::ContextFull;
        }
        logits = match backend.forward(session.tokens.len(), &pending) {
            Ok(l) => l,
            Err(e) => {
                session.clear();
                return Err(e.into());
            }
        };
        session.tokens.extend_from_slice(&pending);
        stats.gen_forwards += 1;
    };
    if let Some(c) = constraint {
        stats.masks_computed = c.masks_computed;
    }
    stats.gen_time = gen_start.elapsed();
    Ok((finish, stats))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reusable_prefix_leaves_one_token_to_evaluate() {
        let s = Session {
            tokens: vec![1, 2, 3, 4],
        };
        assert_eq!(s.reusable(&[1, 2, 3, 4, 5]), 4);
        assert_eq!(s.reusable(&[1, 2, 3, 4]), 3);
        assert_eq!(s.reusable(&[1, 9]), 1);
        assert_eq!(s.reusable(&[7]), 0);
    }
}
