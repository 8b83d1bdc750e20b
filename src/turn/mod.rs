//! One assistant turn, from the conversation to parsed calls: the prompt is rendered
//! (`decode::request`), the turn decoded token by token under the tool-call grammar
//! (`decoder::TurnDecoder`) with the strategies of a `strategy::Pipeline` plugged in, or
//! written by a model on a server (`remote`), and the text parsed back into calls.
//!
//! Without a strategy that decides (`Strategy::decides`), or when the turn may answer in
//! prose, the turn is decoded to its end with the pipeline as the logits hook. Otherwise,
//! and only when every candidate tool name can be written as the envelope spells it
//! (checked before anything is shown), the pipeline picks the tool, and for a turn that
//! may make a list, each call is written before it is shown: reviewed when it closes
//! (kept, written again more strictly, or dropped), and the list goes on or closes as the
//! pipeline decides. A turned-down first call gives way to the fallback tool (the one
//! that answers in words). Text the grammar forced (a call's opening) is shown once the
//! model has read it: after the pick, or with the first token plain decoding writes.

use std::ops::ControlFlow;

use crate::backend::{Backend, TokenId};
use crate::chat::Role;
use crate::decode::request::{render_prompt, with_tools, TurnRequest, TurnResult};
use crate::decode::{DecodeError, Draft, Finish, Grammars, Sampler, Session, ToolChoice};
use crate::remote::Remote;
use crate::strategy::choice::CONTENT_FREE;
use crate::strategy::{Pipeline, Review, Scorer};
use crate::tool::ToolCall;

mod decoder;

pub use decoder::{assistant_turn, Mark, TurnDecoder, Until};

/// The model and what decoding it needs.
pub struct Engine<'a> {
    /// The model, or with `remote` its vocabulary and template only.
    pub backend: &'a mut dyn Backend,
    pub session: &'a mut Session,
    pub grammars: &'a Grammars,
    pub sampler: &'a mut Sampler,
    /// A server that writes the turns instead (`remote`): the pipeline, which reads the
    /// model's log-probabilities, is not applied.
    pub remote: Option<&'a mut Remote>,
    /// How far local decoding guesses ahead (the text is the same either way).
    pub draft: Draft,
}

/// Run `req` through `pipeline`; `fallback` names the tool that answers in words (if it
/// is offered). `on_text` gets the text once it is final, and may break to stop.
pub fn run(
    engine: &mut Engine,
    req: &TurnRequest,
    pipeline: &mut Pipeline,
    fallback: Option<&str>,
    on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
) -> Result<TurnResult, DecodeError> {
    if let Some(remote) = engine.remote.as_deref_mut() {
        return remote.turn(engine.backend, req, on_text);
    }
    let mut turn = TurnDecoder::new(engine.backend, engine.grammars, req)?;
    turn.set_draft(engine.draft);
    engine.session.set_stable(turn.stable_prefix());
    let gate = if pipeline.decides() {
        Gate::prepare(engine.backend, &mut turn, req, fallback)?
    } else {
        None
    };
    match gate {
        Some(gate) => gate.run(engine, &mut turn, req, pipeline, on_text)?,
        None => decode_rest(engine, &mut turn, pipeline, on_text)?,
    }
    Ok(turn.finish(req))
}

/// A turn the pipeline decides: the candidate names and the content-free prompt.
struct Gate {
    /// Each allowed tool's name as tokens after what the grammar forces first.
    names: Vec<Vec<TokenId>>,
    fallback: Option<usize>,
    /// The prompt with a content-free request in place of the last one.
    base_prompt: Vec<TokenId>,
}

/// A call written after a list decided to go on, not yet kept.
struct Proposal {
    /// Before the separator, and the tokens that close the list instead.
    before: Mark,
    close: Vec<TokenId>,
    /// After the separator (where a second attempt starts).
    after: Mark,
}

impl Gate {
    /// Everything the gate needs, or `None` when it does not apply: the turn may answer in
    /// prose, there is nothing to decide, or the grammar spells the names otherwise.
    fn prepare(
        backend: &dyn Backend,
        turn: &mut TurnDecoder,
        req: &TurnRequest,
        fallback: Option<&str>,
    ) -> Result<Option<Gate>, DecodeError> {
        let names: Vec<&str> = req
            .allowed_specs()
            .iter()
            .map(|s| s.name.as_str())
            .collect();
        let fallback = names.iter().position(|n| Some(*n) == fallback);
        let last_user = req.messages.iter().rposition(|m| m.role == Role::User);
        let nothing_to_decide = names.len() < 2 && (!req.parallel || fallback.is_some());
        let Some(last_user) = last_user else {
            return Ok(None);
        };
        if req.choice != ToolChoice::Required || nothing_to_decide || turn.written().is_empty() {
            return Ok(None);
        }
        let forced = turn.text();
        let mut tokens = Vec::with_capacity(names.len());
        for name in &names {
            let opening = req.envelope.call_opening(name);
            let Some(rest) = opening.strip_prefix(forced.as_str()) else {
                tracing::debug!(%opening, "gate skipped: the grammar forces something else");
                return Ok(None);
            };
            let toks = backend.tokenize(rest, false)?;
            if !turn.allows(&toks) {
                tracing::debug!(%opening, "gate skipped: the grammar refuses this spelling");
                return Ok(None);
            }
            tokens.push(toks);
        }
        tracing::debug!(target: "ferrosa::gate", ?names, ?fallback, "candidates");
        let mut messages = req.messages.to_vec();
        messages[last_user].content = CONTENT_FREE.into();
        let baseline = TurnRequest {
            messages: &messages,
            ..req.clone()
        };
        let base_prompt = render_prompt(backend, &with_tools(&baseline), req.envelope)?;
        Ok(Some(Gate {
            names: tokens,
            fallback,
            base_prompt,
        }))
    }

    fn scorer<'a>(&'a self, engine: &'a mut Engine, turn: &'a TurnDecoder) -> Scorer<'a> {
        Scorer {
            backend: &mut *engine.backend,
            session: &mut *engine.session,
            base: &self.base_prompt,
            real: turn.prompt(),
        }
    }

    fn run(
        self,
        engine: &mut Engine,
        turn: &mut TurnDecoder,
        req: &TurnRequest,
        pipeline: &mut Pipeline,
        on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
    ) -> Result<(), DecodeError> {
        let written = turn.written().to_vec();
        let chosen = pipeline.choose(
            &mut self.scorer(engine, turn),
            &written,
            &self.names,
            self.fallback,
        )?;
        let Some(chosen) = chosen else {
            return decode_rest(engine, turn, pipeline, on_text);
        };
        // The model has read the call's opening (the grammar forced it) with the names
        // after it: it is the turn's, whichever call follows, and is shown now.
        if !turn.flush(on_text) {
            return Ok(());
        }
        let before_name = turn.mark();
        turn.force(engine.backend, &self.names[chosen])?;
        let opening = turn.mark();
        let separators = req
            .envelope
            .list_separators()
            .filter(|_| req.parallel && Some(chosen) != self.fallback);
        let Some((more, close)) = separators else {
            return decode_rest(engine, turn, pipeline, on_text);
        };
        let until = Until::CallClosed;
        let mut calls: Vec<ToolCall> = Vec::new();
        let mut check_first = self.fallback.is_some();
        let mut retried = false;
        let mut proposal: Option<Proposal> = None;
        loop {
            let e = &mut *engine;
            let finish = turn.run(
                e.backend, e.session, e.sampler, pipeline, until, false, on_text,
            )?;
            let Some(call) = closed_call(turn).filter(|_| finish == Finish::Stopped) else {
                // The turn ended with no call closing (the grammar had no more to say).
                if let Some(p) = proposal.take() {
                    turn.rewind(p.before)?;
                    turn.force(engine.backend, &p.close)?;
                }
                turn.flush(on_text);
                return Ok(());
            };
            let (call, call_end) = call;
            let review = if proposal.is_some() {
                pipeline.review(&call, &calls, false)
            } else if check_first {
                pipeline.review(&call, &[], true)
            } else {
                Review::Keep
            };
            let again = review == Review::Redo && !retried && pipeline.strict(true);
            retried = again;
            if again {
                let to = proposal.as_ref().map_or(opening, |p| p.after);
                turn.rewind(to)?;
                continue;
            }
            pipeline.strict(false);
            if review != Review::Keep {
                match proposal.take() {
                    // A further call that does not earn its place: the list closes before it.
                    Some(p) => {
                        turn.rewind(p.before)?;
                        turn.force(engine.backend, &p.close)?;
                    }
                    // A first call the request did not ask for: answer instead.
                    None => {
                        turn.rewind(before_name)?;
                        turn.force(engine.backend, &self.names[self.fallback.unwrap_or(chosen)])?;
                    }
                }
                return decode_rest(engine, turn, pipeline, on_text);
            }
            check_first = false;
            calls.push(call);
            match self.after_call(
                engine,
                turn,
                pipeline,
                on_text,
                opening,
                call_end,
                (more, close),
            )? {
                After::Done => return Ok(()),
                After::Rest => return decode_rest(engine, turn, pipeline, on_text),
                After::Another(p) => proposal = Some(p),
            }
        }
    }

    /// After a call kept in a list: does the list go on? The endings are scored as the
    /// model would spell them: what was written since the `opening` plus each ending,
    /// tokenized whole (the brace that closed the call often shares a token with what
    /// follows it).
    #[allow(clippy::too_many_arguments)]
    fn after_call(
        &self,
        engine: &mut Engine,
        turn: &mut TurnDecoder,
        pipeline: &mut Pipeline,
        on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
        opening: Mark,
        call_end: usize,
        (more, close): (&str, &str),
    ) -> Result<After, DecodeError> {
        let since = &turn.scan().text()[opening.bytes()..call_end];
        let since = String::from_utf8_lossy(since).into_owned();
        let with = |ending: &str| engine.backend.tokenize(&format!("{since}{ending}"), false);
        let options = [with(more)?, with(close)?];
        let common = options[0]
            .iter()
            .zip(&options[1])
            .take_while(|(a, b)| a == b)
            .count();
        turn.rewind(opening)?;
        let tails = [options[0][common..].to_vec(), options[1][common..].to_vec()];
        let both = [&options[0], &options[1]].map(|o| turn.allows(o));
        turn.force_prefix(engine.backend, &options[0][..common])?;
        if !turn.flush_to(call_end, on_text) {
            return Ok(After::Done);
        }
        if !both.iter().all(|&ok| ok) {
            // The list is full (or cannot end here): the grammar decides.
            return Ok(After::Rest);
        }
        let written = turn.written().to_vec();
        let go_on = pipeline.go_on(&mut self.scorer(engine, turn), &written, &tails)?;
        Ok(match go_on {
            Some(true) => {
                let before = turn.mark();
                turn.force(engine.backend, &tails[0])?;
                After::Another(Proposal {
                    before,
                    close: tails[1].clone(),
                    after: turn.mark(),
                })
            }
            Some(false) => {
                turn.force(engine.backend, &tails[1])?;
                After::Rest
            }
            None => After::Rest,
        })
    }
}

/// What follows a call kept in a list.
enum After {
    /// The caller broke: the turn is over.
    Done,
    /// The grammar (and the model) write the rest.
    Rest,
    /// A further call, proposed.
    Another(Proposal),
}

/// The call that just closed, parsed, and where its text ends.
fn closed_call(turn: &TurnDecoder) -> Option<(ToolCall, usize)> {
    let scan = turn.scan();
    let &(start, end) = scan.closed_call_spans().last()?;
    let v: serde_json::Value = serde_json::from_slice(&scan.text()[start..end]).ok()?;
    Some((
        ToolCall {
            name: v["name"].as_str()?.to_string(),
            arguments: v["arguments"].clone(),
        },
        end,
    ))
}

/// Decode the rest of the turn as usual, streaming: text not shown yet goes out with
/// the first token the model writes, once it has read that text.
fn decode_rest(
    engine: &mut Engine,
    turn: &mut TurnDecoder,
    pipeline: &mut Pipeline,
    on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
) -> Result<(), DecodeError> {
    if !turn.is_done() {
        let e = &mut *engine;
        turn.run(
            e.backend,
            e.session,
            e.sampler,
            pipeline,
            Until::End,
            true,
            on_text,
        )?;
    }
    turn.flush(on_text);
    Ok(())
}
