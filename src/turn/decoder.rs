//! A turn in progress, as something a strategy can drive: write tokens it chose
//! (`force`), decode until a call closes (`run` with `Until::CallClosed`), go back to an
//! earlier point (`mark`, `rewind`), and show the text only once it is final (`flush`).
//! `assistant_turn` is the plain case: decode to the end, streaming as it goes.

use std::ops::ControlFlow;

use crate::backend::{Backend, TokenId};
use crate::decode::request::{render_prompt_split, with_tools, TurnRequest, TurnResult};
use crate::decode::{
    generate, Constraint, DecodeError, Draft, Finish, GenerationStats, Grammars, JsonScan,
    LogitsHook, Sampler, Session, Steering,
};

/// Where to stop decoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Until {
    /// The end of the turn (or the budget).
    End,
    /// The moment a call closes (its `}` is written).
    CallClosed,
}

/// A point of a turn to come back to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Mark {
    tokens: usize,
    bytes: usize,
}

impl Mark {
    /// The length of the turn's text at this point.
    pub fn bytes(&self) -> usize {
        self.bytes
    }
}

/// A turn in progress (see the module header).
pub struct TurnDecoder {
    prompt: Vec<TokenId>,
    /// Leading tokens of the prompt that do not depend on the conversation.
    stable: usize,
    constraint: Option<Constraint>,
    written: Vec<TokenId>,
    scan: JsonScan,
    max_tokens: usize,
    stats: GenerationStats,
    /// Bytes of the text already handed to the caller.
    shown: usize,
    finish: Finish,
    /// How far generation guesses ahead (`Draft::OFF` unless `set_draft`).
    draft: Draft,
}

impl TurnDecoder {
    /// Render `req`'s prompt and start its grammar: the tokens the grammar forces first
    /// (e.g. a required call's opening) are written already.
    pub fn new(
        backend: &dyn Backend,
        grammars: &Grammars,
        req: &TurnRequest,
    ) -> Result<TurnDecoder, DecodeError> {
        let (prompt, stable) = render_prompt_split(backend, &with_tools(req), req.envelope)?;
        let mut constraint = match req.grammar() {
            Some(lark) => Some(grammars.compile(&lark)?),
            None => None,
        };
        let mut d = TurnDecoder {
            stats: GenerationStats {
                prompt_tokens: prompt.len(),
                ..GenerationStats::default()
            },
            prompt,
            stable,
            constraint: None,
            written: Vec::new(),
            scan: JsonScan::new(),
            max_tokens: req.max_tokens,
            shown: 0,
            finish: Finish::Length,
            draft: Draft::OFF,
        };
        if let Some(c) = constraint.as_mut() {
            let forced = c.forced_at_start()?.to_vec();
            d.stats.forced_at_start = forced.len();
            d.append(backend, &forced);
        }
        d.constraint = constraint;
        Ok(d)
    }

    /// Guess ahead as `draft` says from now on (the text written is the same).
    pub fn set_draft(&mut self, draft: Draft) {
        self.draft = draft;
    }

    pub fn prompt(&self) -> &[TokenId] {
        &self.prompt
    }

    /// The prompt's leading tokens that do not depend on the conversation.
    pub(crate) fn stable_prefix(&self) -> &[TokenId] {
        &self.prompt[..self.stable]
    }

    /// The turn's tokens so far.
    pub fn written(&self) -> &[TokenId] {
        &self.written
    }

    /// The turn's text so far, as JSON.
    pub fn scan(&self) -> &JsonScan {
        &self.scan
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(self.scan.text()).into_owned()
    }

    /// Nothing but end-of-generation may follow.
    pub(crate) fn is_done(&self) -> bool {
        self.constraint.as_ref().is_some_and(Constraint::is_stopped)
    }

    fn append(&mut self, backend: &dyn Backend, tokens: &[TokenId]) {
        let vocab = backend.vocab();
        for &t in tokens {
            if vocab.kind(t) != crate::backend::vocab::TokenKind::Control {
                self.scan.push(vocab.piece(t));
            }
        }
        self.written.extend_from_slice(tokens);
    }

    /// Does the grammar allow `tokens` from here?
    pub fn allows(&mut self, tokens: &[TokenId]) -> bool {
        self.constraint.as_mut().is_none_or(|c| c.allows(tokens))
    }

    /// Write `tokens` as if the model had (the grammar must allow them: see `allows`),
    /// and what the grammar forces after them.
    pub fn force(&mut self, backend: &dyn Backend, tokens: &[TokenId]) -> Result<(), DecodeError> {
        self.force_then(backend, tokens, true)
    }

    /// Write `tokens` and nothing after them, even what the grammar forces: a shared
    /// prefix of several continuations, one of which follows.
    pub(crate) fn force_prefix(
        &mut self,
        backend: &dyn Backend,
        tokens: &[TokenId],
    ) -> Result<(), DecodeError> {
        self.force_then(backend, tokens, false)
    }

    fn force_then(
        &mut self,
        backend: &dyn Backend,
        tokens: &[TokenId],
        then: bool,
    ) -> Result<(), DecodeError> {
        let mut all = tokens.to_vec();
        if let Some(c) = self.constraint.as_mut() {
            for &t in tokens {
                c.advance(t)?;
            }
            if then {
                all.extend_from_slice(c.take_forced()?);
            }
        }
        self.stats.forced_tokens += all.len();
        self.append(backend, &all);
        Ok(())
    }

    pub fn mark(&self) -> Mark {
        Mark {
            tokens: self.written.len(),
            bytes: self.scan.text().len(),
        }
    }

    /// Go back to `mark`: the grammar, the tokens and the text are as they were. Text
    /// already shown (`flush`) cannot be taken back: a caller that rewinds before it
    /// must write the same text again.
    pub(crate) fn rewind(&mut self, mark: Mark) -> Result<(), DecodeError> {
        let n = self.written.len().saturating_sub(mark.tokens);
        if let Some(c) = self.constraint.as_mut() {
            c.rollback(n)?;
        }
        self.written.truncate(mark.tokens);
        self.scan.truncate(mark.bytes);
        Ok(())
    }

    /// Hand the caller the text not yet shown; `false` if it asked to stop.
    pub fn flush(&mut self, on_text: &mut dyn FnMut(&str) -> ControlFlow<()>) -> bool {
        self.flush_to(usize::MAX, on_text)
    }

    /// Hand the caller the text not yet shown up to byte `upto`; `false` if it asked to
    /// stop.
    pub(crate) fn flush_to(
        &mut self,
        upto: usize,
        on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
    ) -> bool {
        let text = self.scan.text();
        let end = whole_chars_end(text, self.shown, upto);
        if end <= self.shown {
            return true;
        }
        let piece = String::from_utf8_lossy(&text[self.shown..end]).into_owned();
        self.shown = end;
        on_text(&piece).is_continue()
    }

    /// Decode from here until `until` or the end of the turn, shifting logits with
    /// `hook`; with `stream`, text goes to `on_text` as it comes, with any not shown
    /// before it (which the model has read once it writes a token), and `on_text` may
    /// break to stop the turn. Returns why it stopped: `Finish::Stopped` when `until` was met
    /// (or `on_text` broke).
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        &mut self,
        backend: &mut dyn Backend,
        session: &mut Session,
        sampler: &mut Sampler,
        hook: &mut dyn LogitsHook,
        until: Until,
        stream: bool,
        on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
    ) -> Result<Finish, DecodeError> {
        let budget = self.max_tokens.saturating_sub(self.written.len());
        let mut full = self.prompt.clone();
        full.extend_from_slice(&self.written);
        session.set_stable(self.stable_prefix());
        let calls_before = self.scan.closed_call_spans().len();
        let mut new_tokens = Vec::new();
        let mut shown = self.shown;
        let steer = Steering {
            sampler,
            constraint: self.constraint.as_mut(),
            hook,
            scan: &mut self.scan,
            draft: self.draft,
        };
        let (finish, stats) = generate(
            backend,
            session,
            &full,
            budget.max(1),
            steer,
            |tok, scan| {
                new_tokens.push(tok);
                let mut flow = ControlFlow::Continue(());
                if stream {
                    let text = scan.text();
                    let end = whole_chars_end(text, shown, usize::MAX);
                    if end > shown {
                        flow = on_text(&String::from_utf8_lossy(&text[shown..end]));
                        shown = end;
                    }
                }
                if until == Until::CallClosed && scan.closed_call_spans().len() > calls_before {
                    flow = ControlFlow::Break(());
                }
                flow
            },
        )?;
        // Unchanged unless streaming.
        self.shown = shown;
        self.written.extend_from_slice(&new_tokens);
        add_stats(&mut self.stats, &stats);
        self.finish = finish;
        Ok(finish)
    }

    /// The finished turn, parsed against `req`'s tools.
    pub fn finish(self, req: &TurnRequest) -> TurnResult {
        let text = self.text();
        let mut stats = self.stats;
        stats.generated_tokens = self.written.len();
        TurnResult::parse(req, text, self.finish, stats)
    }
}

/// Where the text from `from` to `upto` (at most) ends without cutting a character.
fn whole_chars_end(text: &[u8], from: usize, upto: usize) -> usize {
    let mut end = text.len().min(upto);
    while end > from && std::str::from_utf8(&text[from..end]).is_err() {
        end -= 1;
    }
    end
}

/// Adds a segment's figures to the turn's (the generated count is the turn's length,
/// set when it finishes: tokens dropped by a rewind do not count).
fn add_stats(total: &mut GenerationStats, s: &GenerationStats) {
    if total.gen_forwards == 0 && total.prompt_time.is_zero() {
        total.reused_tokens = s.reused_tokens;
        total.prompt_time = s.prompt_time;
    } else {
        total.gen_time += s.prompt_time;
    }
    total.gen_forwards += s.gen_forwards;
    total.drafted_tokens += s.drafted_tokens;
    total.draft_accepted += s.draft_accepted;
    total.forced_tokens += s.forced_tokens;
    total.masks_computed += s.masks_computed;
    total.constraint_time += s.constraint_time;
    total.gen_time += s.gen_time;
    if total.time_to_first_token.is_zero() {
        total.time_to_first_token = s.time_to_first_token;
    }
}

/// Run one assistant turn to its end; `on_text` receives the text as it is produced
/// and may break to stop the turn (cancellation). `hook` shifts the logits.
pub fn assistant_turn(
    backend: &mut dyn Backend,
    session: &mut Session,
    grammars: &Grammars,
    sampler: &mut Sampler,
    req: &TurnRequest,
    hook: &mut dyn LogitsHook,
    mut on_text: impl FnMut(&str) -> ControlFlow<()>,
) -> Result<TurnResult, DecodeError> {
    let mut turn = TurnDecoder::new(backend, grammars, req)?;
    turn.run(
        backend,
        session,
        sampler,
        hook,
        Until::End,
        true,
        &mut on_text,
    )?;
    turn.flush(&mut on_text);
    Ok(turn.finish(req))
}
