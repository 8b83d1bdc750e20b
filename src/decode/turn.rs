//! One assistant turn with tools: describe the tools in the system prompt in the
//! envelope's format, render the conversation with the chat template, generate under the
//! envelope's grammar (or freely, to compare), and parse the text back into a `Turn`.
//!
//! This is the decode-level entry point the agent loop and the CLI both call.

use std::ops::ControlFlow;

use super::copy::{CopyIndex, Copying};
use super::envelope::{Envelope, EnvelopeError, ToolChoice, Turn};
use super::gate;
use super::{generate, DecodeError, Decoding, Finish, GenerationStats, Grammars, Sampler, Session};
use crate::backend::{Backend, ChatMessage, Detokenizer, Role};
use crate::tool::ToolSpec;

#[derive(Debug, Clone)]
pub struct TurnRequest<'a> {
    pub messages: &'a [ChatMessage],
    /// The tools described in the prompt.
    pub specs: &'a [ToolSpec],
    /// The tools the grammar allows this turn, when fewer than those described (keeping
    /// the prompt, and so the KV cache, unchanged while narrowing the choice).
    pub allowed: Option<&'a [ToolSpec]>,
    pub envelope: Envelope,
    pub choice: ToolChoice,
    /// Several calls in one turn.
    pub parallel: bool,
    pub decoding: Decoding,
    pub max_tokens: usize,
    /// The relevance gate (see `decode::gate`): the tool to call when the request made no
    /// tool likelier than a content-free request did. Applies to constrained turns that
    /// must call; when this tool is not among those allowed, the gate still picks the
    /// tool and the number of calls.
    pub relevance_gate: Option<&'a str>,
    /// Lean argument values towards spans of these texts (see `decode::copy`);
    /// constrained turns only.
    pub copy: Option<CopyFrom<'a>>,
}

/// Where argument values are copied from, and how hard.
#[derive(Debug, Clone, Copy)]
pub struct CopyFrom<'a> {
    pub sources: &'a [&'a str],
    /// Added to the logit of each token that goes on copying.
    pub bonus: f32,
    /// Calls of this tool (the one that answers in words) are left alone.
    pub exempt: Option<&'a str>,
}

impl CopyFrom<'_> {
    /// The index for a turn offering `specs`: the sources, and each required
    /// parameter's declared default for that parameter alone.
    pub fn index(&self, vocab: &crate::backend::Vocab, specs: &[ToolSpec]) -> CopyIndex {
        let defaults = super::copy::defaults(specs);
        CopyIndex::new(vocab, self.sources, &defaults, self.bonus, self.exempt)
    }
}

#[derive(Debug)]
pub struct TurnResult {
    /// Everything the model wrote (control tokens left out).
    pub text: String,
    /// The parsed turn; with constrained decoding an error here is a bug, and is logged
    /// as one.
    pub turn: Result<Turn, EnvelopeError>,
    pub finish: Finish,
    pub stats: GenerationStats,
}

/// The messages as the model will see them: the tool description appended to the system
/// message (one is added if there is none).
pub fn with_tools(req: &TurnRequest) -> Vec<ChatMessage> {
    let mut messages = req.messages.to_vec();
    if req.specs.is_empty() || req.choice == ToolChoice::None {
        return messages;
    }
    let tools = req.envelope.describe_tools(req.specs, req.choice);
    match messages.first_mut() {
        Some(m) if m.role == Role::System => {
            m.content = format!("{}\n\n{tools}", m.content.trim_end());
        }
        _ => messages.insert(0, ChatMessage::new(Role::System, tools)),
    }
    messages
}

/// Run one assistant turn; `on_text` receives the text as it is produced and may break
/// to stop the turn (cancellation).
pub fn assistant_turn(
    backend: &mut dyn Backend,
    session: &mut Session,
    grammars: &Grammars,
    sampler: &mut Sampler,
    req: &TurnRequest,
    mut on_text: impl FnMut(&str) -> ControlFlow<()>,
) -> Result<TurnResult, DecodeError> {
    let messages = with_tools(req);
    let rendered = backend.chat_template().render(&messages, None, true)?;
    tracing::debug!(target: "ferrosa::prompt", "{rendered}");
    let prompt = super::prompt_tokens(backend, &rendered, true)?;

    let lark = (req.decoding == Decoding::Constrained).then(|| {
        req.envelope
            .grammar(req.allowed.unwrap_or(req.specs), req.choice, req.parallel)
    });
    if let (Some(lark), Some(fallback)) = (&lark, req.relevance_gate) {
        let gated = gate::gated_turn(
            backend,
            session,
            grammars,
            sampler,
            req,
            fallback,
            &prompt,
            lark,
            &mut on_text,
        )?;
        if let Some(g) = gated {
            return Ok(finish_turn(req, g.text, g.finish, g.stats));
        }
    }
    let mut constraint = match &lark {
        Some(lark) => Some(grammars.compile(lark)?),
        None => None,
    };
    let vocab = backend.vocab().clone();
    let index = req
        .copy
        .filter(|_| constraint.is_some())
        .map(|c| c.index(&vocab, req.specs));
    let mut copying;
    let backend: &mut dyn Backend = match &index {
        Some(index) => {
            let seq = session.tokens().to_vec();
            copying = Copying::new(backend, index, seq, prompt.len());
            &mut copying
        }
        None => backend,
    };
    let mut detok = Detokenizer::new(false);
    let mut text = String::new();
    let mut piece = String::with_capacity(32);
    let (finish, stats) = generate(
        backend,
        session,
        &prompt,
        req.max_tokens,
        sampler,
        constraint.as_mut(),
        |tok| {
            piece.clear();
            detok.push(&vocab, tok, &mut piece);
            text.push_str(&piece);
            on_text(&piece)
        },
    )?;
    piece.clear();
    detok.finish(&mut piece);
    text.push_str(&piece);
    Ok(finish_turn(req, text, finish, stats))
}

/// Parse a finished turn's text.
fn finish_turn(
    req: &TurnRequest,
    text: String,
    finish: Finish,
    stats: GenerationStats,
) -> TurnResult {
    let turn = req.envelope.parse(&text, req.specs);
    if let (Decoding::Constrained, Err(e), Finish::EndOfGeneration) = (req.decoding, &turn, finish)
    {
        // The grammar guarantees a parseable, schema-valid turn when generation ends
        // normally; anything else is a defect in the grammar or the parser.
        tracing::error!(error = %e, %text, "constrained output failed to parse: this is a bug");
    }
    TurnResult {
        text,
        turn,
        finish,
        stats,
    }
}
