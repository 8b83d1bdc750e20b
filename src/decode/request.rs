//! What one assistant turn with tools asks for and what it returns: the request (the
//! conversation, the tools described and those the grammar allows, the envelope, the
//! decoding), the prompt it renders (the tools described in the system message in the
//! envelope's format, the conversation through the chat template with message contents
//! tokenized as plain text, so nothing a tool returned can become a role marker), and the
//! result parsed back into a `Turn`. The turn itself is decoded by `crate::turn`.

use super::envelope::{Envelope, EnvelopeError, ToolChoice, Turn};
use super::{DecodeError, Decoding, Finish, GenerationStats};
use crate::backend::{Backend, Part, TokenId};
use crate::chat::{ChatMessage, Role};
use crate::tool::ToolSpec;

#[derive(Debug, Clone)]
pub struct TurnRequest<'a> {
    pub messages: &'a [ChatMessage],
    /// The tools described in the prompt.
    pub specs: &'a [ToolSpec],
    /// The tools the grammar allows this turn, when fewer than those described or with
    /// arguments held narrower than described (keeping the prompt, and so the KV cache,
    /// unchanged while narrowing the choice).
    pub allowed: Option<&'a [ToolSpec]>,
    pub envelope: Envelope,
    pub choice: ToolChoice,
    /// Several calls in one turn.
    pub parallel: bool,
    pub decoding: Decoding,
    /// Tokens the turn may write (a call open at the limit is still closed).
    pub max_tokens: usize,
}

impl TurnRequest<'_> {
    /// The tools the grammar allows.
    pub(crate) fn allowed_specs(&self) -> &[ToolSpec] {
        self.allowed.unwrap_or(self.specs)
    }

    /// The turn's grammar, when decoding is constrained.
    pub fn grammar(&self) -> Option<String> {
        (self.decoding == Decoding::Constrained).then(|| {
            self.envelope
                .grammar(self.allowed_specs(), self.choice, self.parallel)
        })
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

/// The prompt tokens of `messages` ending in the assistant's opening: BOS when the
/// model wants one, the template's text with its special tokens, and each message's
/// content as plain text (the envelope's own markers in assistant and system messages
/// stay markers, as the grammar wrote them).
pub fn render_prompt(
    backend: &dyn Backend,
    messages: &[ChatMessage],
    envelope: Envelope,
) -> Result<Vec<TokenId>, DecodeError> {
    Ok(render_prompt_split(backend, messages, envelope)?.0)
}

/// As `render_prompt`, with how many leading tokens come before any content but the
/// system message's (the prefix a prompt cache may keep: it does not depend on the
/// conversation).
pub fn render_prompt_split(
    backend: &dyn Backend,
    messages: &[ChatMessage],
    envelope: Envelope,
) -> Result<(Vec<TokenId>, usize), DecodeError> {
    let rendered = backend.chat_template().render_parts(messages, true)?;
    let mut tokens: Vec<TokenId> = backend.vocab().bos().into_iter().collect();
    let bos_len = tokens.len();
    let mut stable = None;
    for part in &rendered.parts {
        if matches!(part, Part::Content { role, .. } if *role != Role::System) {
            stable.get_or_insert(tokens.len());
        }
        match part {
            Part::Markup(text) => tokens.extend(backend.tokenize(text, true)?),
            Part::Content { role, text } => match role {
                Role::Assistant | Role::System => {
                    // The markers the envelope writes are trusted text; so is nothing else.
                    let mut rest = text.as_str();
                    while let Some((at, marker)) = envelope.next_marker(rest) {
                        tokens.extend(backend.tokenize(&rest[..at], false)?);
                        tokens.extend(backend.tokenize(marker, true)?);
                        rest = &rest[at + marker.len()..];
                    }
                    tokens.extend(backend.tokenize(rest, false)?);
                }
                Role::User | Role::Tool => tokens.extend(backend.tokenize(text, false)?),
            },
        }
    }
    // A template that writes BOS itself: keep one.
    let mut stable = stable.unwrap_or(0);
    if bos_len == 1 && tokens.get(1) == tokens.first() {
        tokens.remove(1);
        if stable > 1 {
            stable -= 1;
        }
    }
    tracing::debug!(target: "ferrosa::prompt", "{}", rendered.text());
    Ok((tokens, stable))
}

impl TurnResult {
    /// Parse a finished turn's text.
    pub fn parse(
        req: &TurnRequest,
        text: String,
        finish: Finish,
        stats: GenerationStats,
    ) -> TurnResult {
        let turn = req.envelope.parse(&text, req.specs);
        if let (Decoding::Constrained, Err(e), Finish::EndOfGeneration) =
            (req.decoding, &turn, finish)
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
}
