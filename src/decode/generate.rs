//! The generation loop: evaluate a prompt (reusing what the KV cache already holds), then
//! sample token by token, with an optional grammar and a logits hook, until end of
//! generation, the token limit or the caller's stop. `Session` remembers what the
//! backend's cache holds, so a prompt sharing a prefix evaluates only its tail.
//!
//! Per token: the hook adjusts the logits, the grammar checks the sampled token (the full
//! mask only when it is refused), and the tokens the grammar then forces are evaluated
//! in one batch with the next forward pass. Near the budget a constrained turn steers to
//! a close (`close`), so a started call always ends complete. With drafting on, a guess
//! at the next tokens (`draft`), cut to what the grammar allows, rides in that batch too,
//! and each step chooses from the batch's logits as long as the turn keeps to the guess:
//! the same tokens, fewer forward passes. The loop allocates nothing per token.

use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use super::close;
use super::draft::Draft;
use super::hook::{LogitsHook, TokenContext};
use super::{Constraint, DecodeError, Finish, Sampler};
use crate::backend::{Backend, BackendError, Session, TokenId, Vocab};
use crate::json::JsonScan;

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
    /// Tokens guessed by drafting and evaluated ahead of being chosen.
    pub drafted_tokens: usize,
    /// Of those, the ones the turn then chose (each saved a forward pass).
    pub draft_accepted: usize,
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

/// What steers a generation besides the model: the sampler, the grammar (if any), the
/// logits hook, and the reader of the turn's text (every emitted token's bytes are pushed
/// to it; it may already hold the turn's earlier text).
pub struct Steering<'a> {
    pub sampler: &'a mut Sampler,
    pub constraint: Option<&'a mut Constraint>,
    pub hook: &'a mut dyn LogitsHook,
    pub scan: &'a mut JsonScan,
    /// How far to guess ahead (`Draft::OFF`: one forward pass per step).
    pub draft: Draft,
}

/// Generate after `prompt`, calling `on_token` with each emitted token, sampled or
/// forced by the grammar, and the turn's text after it (the stop token included, so a
/// caller can see why it ended); `on_token` may break to stop early. With a constraint,
/// every token obeys its grammar, and a call started before `max_tokens` is closed (up
/// to `close::OVERRUN` tokens past it).
pub fn generate(
    backend: &mut dyn Backend,
    session: &mut Session,
    prompt: &[TokenId],
    max_tokens: usize,
    steer: Steering,
    mut on_token: impl FnMut(TokenId, &JsonScan) -> ControlFlow<()>,
) -> Result<(Finish, GenerationStats), DecodeError> {
    let Steering {
        sampler,
        mut constraint,
        hook,
        scan,
        draft,
    } = steer;
    let start = Instant::now();
    let hard_limit = max_tokens + constraint.as_ref().map_or(0, |_| close::OVERRUN);
    let vocab = backend.vocab().clone();
    let (mut logits, forced, mut stats) = prefill(
        backend,
        session,
        prompt,
        hard_limit,
        constraint.as_deref_mut(),
    )?;
    // Tokens forced at the start were evaluated with the prompt; they reach the caller
    // now, once the model has actually seen them.
    if !deliver_forced_at_start(
        &forced,
        &vocab,
        &mut stats,
        start,
        scan,
        constraint.as_deref_mut(),
        &mut on_token,
    )? {
        return Ok((Finish::Stopped, stats));
    }
    let gen_start = Instant::now();
    let mut pending: Vec<TokenId> = Vec::with_capacity(64);
    let mut rows = Rows::new(draft, vocab.len());
    let finish = 'gen: loop {
        // A grammar finished by forced tokens alone allows only end-of-generation.
        if constraint.as_deref().is_some_and(Constraint::is_stopped) {
            break Finish::EndOfGeneration;
        }
        let remaining = max_tokens.saturating_sub(stats.generated_tokens);
        let chosen = Step::new(&vocab, scan, remaining).choose(
            hook,
            constraint.as_deref_mut(),
            sampler,
            logits,
            &mut stats,
        )?;
        let Some(tok) = chosen else {
            break Finish::NoCandidate;
        };
        if stats.time_to_first_token.is_zero() {
            stats.time_to_first_token = start.elapsed();
        }
        stats.generated_tokens += 1;
        push_text(scan, &vocab, tok);
        let flow = on_token(tok, scan);
        if let Some(finish) = ends_at(tok, flow, &vocab, constraint.as_deref_mut())? {
            break finish;
        }
        pending.clear();
        pending.push(tok);
        let forcing = ForcedStep {
            hard_limit,
            vocab: &vocab,
        };
        let c = constraint.as_deref_mut();
        if let Some(finish) =
            forcing.commit(c, tok, &mut stats, &mut pending, scan, &mut on_token)?
        {
            break 'gen finish;
        }
        let open = constraint.is_some() && scan.open_count() > 0;
        let n = stats.generated_tokens;
        let held = session.tokens().len() + pending.len();
        if let Some(finish) = out_of_room(n, (max_tokens, hard_limit), open, held, backend) {
            break finish;
        }
        let c = constraint.as_deref_mut();
        logits = rows.evaluate(backend, session, &pending, hard_limit - n, c, &mut stats)?;
    };
    if let Some(c) = constraint {
        stats.masks_computed = c.masks_computed;
    }
    stats.gen_time = gen_start.elapsed();
    Ok((finish, stats))
}

/// Why the turn ends before evaluating what it wrote, if it does: `n` tokens written
/// against its `(budget, hard limit)` (past the budget only to close a call that is
/// `open`), or `held` tokens not fitting the context.
fn out_of_room(
    n: usize,
    (budget, hard_limit): (usize, usize),
    open: bool,
    held: usize,
    backend: &dyn Backend,
) -> Option<Finish> {
    if n >= hard_limit || (n >= budget && !open) {
        return Some(Finish::Length);
    }
    (held > backend.context_len()).then_some(Finish::ContextFull)
}

/// Whether the turn ends at the emitted `tok`: at end-of-generation, or when the caller
/// broke. The grammar takes every emitted token, so a turn that stops here can be
/// rewound token for token (`TurnDecoder::rewind`).
fn ends_at(
    tok: TokenId,
    flow: ControlFlow<()>,
    vocab: &Vocab,
    constraint: Option<&mut Constraint>,
) -> Result<Option<Finish>, DecodeError> {
    let eog = vocab.is_eog(tok);
    if !eog && flow.is_continue() {
        return Ok(None);
    }
    if let Some(c) = constraint {
        c.advance(tok)?;
    }
    Ok(Some(if eog {
        Finish::EndOfGeneration
    } else {
        Finish::Stopped
    }))
}

/// Where a step of the loop stands: the vocabulary, the turn's text so far, the tokens
/// left in the budget.
struct Step<'a> {
    vocab: &'a Vocab,
    scan: &'a JsonScan,
    remaining: usize,
}

impl<'a> Step<'a> {
    fn new(vocab: &'a Vocab, scan: &'a JsonScan, remaining: usize) -> Step<'a> {
        Step {
            vocab,
            scan,
            remaining,
        }
    }

    /// The step's token: the hook adjusts the logits, then the sampler chooses, or with a
    /// grammar, the grammar checks the sampled token (or near the budget steers to a
    /// close), its time counted as the grammar's.
    fn choose(
        &self,
        hook: &mut dyn LogitsHook,
        constraint: Option<&mut Constraint>,
        sampler: &mut Sampler,
        logits: &mut [f32],
        stats: &mut GenerationStats,
    ) -> Result<Option<TokenId>, DecodeError> {
        let context = TokenContext {
            vocab: self.vocab,
            scan: self.scan,
            remaining: self.remaining,
        };
        hook.adjust(&context, logits);
        let Some(c) = constraint else {
            return Ok(sampler.sample(logits));
        };
        let t = Instant::now();
        let tok = if close::should_close(self.remaining, self.scan) {
            close::closing_choice(c, self.vocab, self.scan, logits)?
        } else {
            c.choose(logits, sampler)?
        };
        stats.constraint_time += t.elapsed();
        Ok(tok)
    }
}

/// Hand the tokens forced before the first sample to the caller; false when it broke
/// (the grammar is rolled back to the token it broke at).
fn deliver_forced_at_start(
    forced: &[TokenId],
    vocab: &Vocab,
    stats: &mut GenerationStats,
    start: Instant,
    scan: &mut JsonScan,
    constraint: Option<&mut Constraint>,
    on_token: &mut impl FnMut(TokenId, &JsonScan) -> ControlFlow<()>,
) -> Result<bool, DecodeError> {
    for (i, &f) in forced.iter().enumerate() {
        if stats.time_to_first_token.is_zero() {
            stats.time_to_first_token = start.elapsed();
        }
        push_text(scan, vocab, f);
        if on_token(f, scan).is_break() {
            // The caller has what it waited for: the rest is not the turn's.
            if let Some(c) = constraint {
                c.rollback(forced.len() - i - 1)?;
            }
            return Ok(false);
        }
    }
    Ok(true)
}

/// What committing a sampled token to the grammar needs besides the turn's state.
struct ForcedStep<'v> {
    hard_limit: usize,
    vocab: &'v Vocab,
}

impl ForcedStep<'_> {
    /// Commit `tok` to the grammar (if any) and pass on the tokens it then forces: the
    /// turn's end when the caller stopped or the grammar finished, else `None`.
    fn commit(
        &self,
        c: Option<&mut Constraint>,
        tok: TokenId,
        stats: &mut GenerationStats,
        pending: &mut Vec<TokenId>,
        scan: &mut JsonScan,
        on_token: &mut impl FnMut(TokenId, &JsonScan) -> ControlFlow<()>,
    ) -> Result<Option<Finish>, DecodeError> {
        let Some(c) = c else { return Ok(None) };
        let t = Instant::now();
        let forced = c.commit(tok)?.to_vec();
        stats.constraint_time += t.elapsed();
        let (kept, stopped) = emit_forced(
            &forced,
            self.hard_limit,
            stats,
            pending,
            scan,
            self.vocab,
            on_token,
        );
        // The grammar has taken every forced token; those the turn does not keep are
        // rolled back, so grammar and text stay token for token the same (a rewind
        // relies on it).
        if kept < forced.len() {
            tracing::debug!(
                kept,
                forced = forced.len(),
                stopped,
                "forced tokens past the turn's end rolled back"
            );
        }
        c.rollback(forced.len() - kept)?;
        if stopped {
            return Ok(Some(Finish::Stopped));
        }
        // A finished grammar allows only end-of-generation: no need to ask the model.
        Ok(c.is_stopped().then_some(Finish::EndOfGeneration))
    }
}

/// Pass the tokens the grammar forced after a sampled one to the turn, up to the hard
/// limit or until the caller breaks: how many the turn kept, and whether it stopped.
fn emit_forced(
    forced: &[TokenId],
    hard_limit: usize,
    stats: &mut GenerationStats,
    pending: &mut Vec<TokenId>,
    scan: &mut JsonScan,
    vocab: &Vocab,
    on_token: &mut impl FnMut(TokenId, &JsonScan) -> ControlFlow<()>,
) -> (usize, bool) {
    let mut kept = 0;
    for &f in forced {
        if stats.generated_tokens >= hard_limit {
            break;
        }
        kept += 1;
        stats.generated_tokens += 1;
        stats.forced_tokens += 1;
        pending.push(f);
        push_text(scan, vocab, f);
        if on_token(f, scan).is_break() {
            return (kept, true);
        }
    }
    (kept, false)
}

/// Evaluate what of `prompt` the cache lacks, with the tokens the grammar forces before
/// any sampling in the same batch: the logits after them, those forced tokens, and the
/// statistics so far.
fn prefill<'b>(
    backend: &'b mut dyn Backend,
    session: &mut Session,
    prompt: &[TokenId],
    limit: usize,
    constraint: Option<&mut Constraint>,
) -> Result<(&'b mut [f32], Vec<TokenId>, GenerationStats), DecodeError> {
    if prompt.is_empty() {
        return Err(DecodeError::Backend(BackendError::Eval {
            backend: backend.name(),
            reason: "empty prompt".into(),
        }));
    }
    let start = Instant::now();
    let (reused, keep) = session.prepare(backend, prompt)?;
    let mut stats = GenerationStats {
        prompt_tokens: prompt.len(),
        reused_tokens: reused,
        ..Default::default()
    };
    session.truncate(keep);
    // Room for every token this call can add, so the per-token loop never reallocates.
    session.reserve((prompt.len() - keep + limit).min(backend.context_len()));
    let mut batch: Vec<TokenId> = prompt[keep..].to_vec();
    let mut forced = Vec::new();
    if let Some(c) = constraint {
        let t = Instant::now();
        let all = c.forced_at_start()?.to_vec();
        let kept = all.len().min(limit);
        forced.extend_from_slice(&all[..kept]);
        c.rollback(all.len() - kept)?;
        stats.constraint_time += t.elapsed();
        stats.forced_at_start = forced.len();
        stats.forced_tokens += forced.len();
        stats.generated_tokens += forced.len();
        batch.extend_from_slice(&forced);
    }
    session.truncate(keep);
    let logits = forward(backend, session, &batch)?;
    stats.prompt_time = start.elapsed();
    Ok((logits, forced, stats))
}

/// A drafted guess evaluated in one batch: the guessed tokens, the logits after the token
/// before them and after each of them (one row per token), and how many of them the turn
/// has chosen so far. Buffers sized once per generation, at its first guess.
struct Rows {
    draft: Draft,
    guess: Vec<TokenId>,
    /// Whether `guess` was evaluated and the turn has kept to it so far.
    live: bool,
    chosen: usize,
    logits: Vec<f32>,
    n_vocab: usize,
    batch: Vec<TokenId>,
}

impl Rows {
    fn new(draft: Draft, n_vocab: usize) -> Rows {
        Rows {
            draft,
            guess: Vec::with_capacity(draft.max_tokens),
            live: false,
            chosen: 0,
            // Sized at the first guess: a turn that never guesses costs nothing.
            logits: Vec::new(),
            n_vocab,
            batch: Vec::with_capacity(64 + draft.max_tokens),
        }
    }

    /// Room for the rows of a guess of `max_tokens` (once per generation).
    fn make_room(&mut self) {
        let len = (self.draft.max_tokens + 1) * self.n_vocab;
        if self.logits.len() < len {
            self.logits.resize(len, 0.0);
        }
    }

    /// How many leading tokens of `pending` the evaluated guess holds next; the guess
    /// stays live only if it holds them all.
    fn keep_to(&mut self, pending: &[TokenId]) -> usize {
        if !self.live {
            return 0;
        }
        let next = &self.guess[self.chosen..];
        let same = pending.iter().zip(next).take_while(|(a, b)| a == b).count();
        self.chosen += same;
        self.live = same == pending.len();
        same
    }

    /// The logits after the guess's first `k` tokens (row 0: before the guess).
    fn row(&mut self, k: usize) -> &mut [f32] {
        &mut self.logits[k * self.n_vocab..(k + 1) * self.n_vocab]
    }

    /// Bring the model past `pending`, the tokens the turn added since the model last
    /// read it (at most `limit` more may follow), and return the logits after them.
    /// Tokens an earlier batch evaluated as a guess are taken as they are; the rest are
    /// evaluated, with a new guess (cut to what the grammar allows from here) in the same
    /// batch when drafting finds one.
    fn evaluate<'b>(
        &'b mut self,
        backend: &'b mut dyn Backend,
        session: &mut Session,
        pending: &[TokenId],
        limit: usize,
        constraint: Option<&mut Constraint>,
        stats: &mut GenerationStats,
    ) -> Result<&'b mut [f32], DecodeError> {
        let held = self.keep_to(pending);
        session.extend(&pending[..held]);
        stats.draft_accepted += held;
        if held == pending.len() {
            let k = self.chosen;
            return Ok(self.row(k));
        }
        let rest = &pending[held..];
        let room = backend
            .context_len()
            .saturating_sub(session.tokens().len() + rest.len());
        // What the turn copies is the conversation's (a request's words, a result's
        // values); the stable prefix (instructions, tool specs) is mostly what the
        // grammar forces anyway, and guesses from it are rarely kept.
        let held_tokens = session.tokens();
        let head = &held_tokens[session.stable_len().min(held_tokens.len())..];
        // Where the runtime's rows are exact only in batches below a size, the guess
        // keeps the batch below it (none when the step's own tokens reach it).
        let exact = backend
            .exact_rows_below()
            .map_or(usize::MAX, |n| n.saturating_sub(rest.len() + 1));
        let mut guess = std::mem::take(&mut self.guess);
        self.draft
            .guess(head, rest, limit.min(room).min(exact), &mut guess);
        if let (Some(c), false) = (constraint, guess.is_empty()) {
            let t = Instant::now();
            guess.truncate(c.allowed_prefix(&guess));
            stats.constraint_time += t.elapsed();
        }
        self.guess = guess;
        stats.gen_forwards += 1;
        if self.guess.is_empty() {
            // In pieces the runtime evaluates as one-token steps, so that every token
            // a turn writes is read alike, drafted or not.
            let piece = backend
                .exact_rows_below()
                .map_or(rest.len(), |n| n.max(2) - 1);
            let (head, last) = rest.split_at(rest.len() - rest.len().min(piece));
            for chunk in head.chunks(piece) {
                forward(backend, session, chunk)?;
            }
            return forward(backend, session, last);
        }
        self.make_room();
        self.batch.clear();
        self.batch.extend_from_slice(rest);
        self.batch.extend_from_slice(&self.guess);
        let from = rest.len() - 1;
        let (n_vocab, logits) = (self.n_vocab, &mut self.logits);
        let done =
            backend.forward_each(session.tokens().len(), &self.batch, from, &mut |i, row| {
                let k = i - from;
                logits[k * n_vocab..(k + 1) * n_vocab].copy_from_slice(row);
            });
        if let Err(e) = done {
            session.clear();
            return Err(e.into());
        }
        session.extend(rest);
        stats.drafted_tokens += self.guess.len();
        (self.live, self.chosen) = (true, 0);
        Ok(self.row(0))
    }
}

/// Evaluate `tokens` after what the session holds, and record them; on failure the
/// session is cleared (what the cache holds is unknown then: start clean next time).
fn forward<'b>(
    backend: &'b mut dyn Backend,
    session: &mut Session,
    tokens: &[TokenId],
) -> Result<&'b mut [f32], DecodeError> {
    match backend.forward(session.tokens().len(), tokens) {
        Ok(l) => {
            session.extend(tokens);
            Ok(l)
        }
        Err(e) => {
            session.clear();
            Err(e.into())
        }
    }
}

/// The turn's text grows by `tok`'s bytes (control tokens write none).
fn push_text(scan: &mut JsonScan, vocab: &Vocab, tok: TokenId) {
    if vocab.kind(tok) != crate::backend::vocab::TokenKind::Control {
        scan.push(vocab.piece(tok));
    }
}
