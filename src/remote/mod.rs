//! The remote engine: a model served elsewhere (llama-server, vLLM, Ollama: any server
//! with OpenAI's `/v1/completions`) writes the turns; everything else stays here. The
//! prompt is rendered and tokenized by ferrosa exactly as for a local model (the model's
//! vocabulary and chat template are read from its GGUF file, without its weights) and
//! sent as token ids, so nothing a tool returned can become a role marker on the server
//! either. The agent, its guards, the policy and the tools do not know where the model
//! runs.
//!
//! Every turn goes out with a grammar the server enforces:
//! - `Lark`: the envelope's own grammar, for servers built with llguidance (llama-server
//!   with `LLAMA_LLGUIDANCE`): the turn is exactly what a local one could be.
//! - `JsonSchema`: the call list's JSON schema between markers ferrosa writes itself
//!   (`frame`), for every other server.
//!
//! Which one a server takes is found when connecting (`GrammarMode::Auto`) and said in
//! every trace (`Remote::describe`). Whatever the server answers is parsed and checked
//! against the tools' schemas before the agent sees it: a server that ignores the grammar,
//! answers with something that is not the API's JSON, fails or times out is an error that
//! says so, never a call. The strategies that read the model's log-probabilities (the
//! weighed pick, the copy bias, call review) need a local model and are not applied.
//!
//! Layout: `client` (the HTTP client), `frame` (turns as JSON schemas), `error`.

pub mod client;
mod error;
pub mod frame;

pub use error::RemoteError;

use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use serde_json::{json, Value};

use crate::backend::{Backend, TokenId};
use crate::decode::envelope::{EnvelopeError, MAX_PARALLEL};
use crate::decode::request::{render_prompt_split, with_tools, TurnRequest, TurnResult};
use crate::decode::{
    DecodeError, Decoding, Finish, GenerationStats, SamplerConfig, ToolChoice, Turn,
};
use client::{Client, Events};
use frame::Frame;

/// Which grammar form to send (`--grammar`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GrammarMode {
    /// Lark if the server takes it (a probe when connecting), else JSON schema.
    #[default]
    Auto,
    Lark,
    JsonSchema,
}

/// The grammar form a connected server is sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Grammar {
    Lark,
    JsonSchema,
}

/// How to reach a server (`--engine openai`).
#[derive(Debug, Clone)]
pub struct RemoteOptions {
    /// `http://HOST:PORT` (what precedes `/v1`).
    pub url: String,
    /// The environment variable that holds the API key, if the server wants one.
    pub api_key_env: Option<String>,
    /// The model name sent with each request (default: the first the server lists).
    pub model: Option<String>,
    pub grammar: GrammarMode,
    pub timeout: Duration,
}

/// A connected server.
pub struct Remote {
    client: Client,
    model: String,
    grammar: Grammar,
    sampler: SamplerConfig,
    /// Every completion's time so far (`times`).
    times: Vec<CompletionTime>,
}

/// A tokenization both sides must agree on before ids are sent.
const PROBE: &str = "Move the turtle 2.5 m forward, then ¿dónde está? /turtle1/cmd_vel {\"x\": 1}";

/// One completion's text and how it ended.
struct Completion {
    text: String,
    /// `None` until the server says.
    finish: Option<Finish>,
    generated: Option<usize>,
    first_piece: Option<Duration>,
    cached: Option<usize>,
    /// From sending the request to the end of the answer.
    wall: Duration,
    /// What the server says it spent evaluating and generating (llama-server's
    /// `timings`), when it says.
    server: Option<Duration>,
}

/// One completion's time here and on the server: the difference is what running the
/// model remotely adds (HTTP, JSON, streaming, the server's queue).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompletionTime {
    pub wall: Duration,
    pub server: Option<Duration>,
}

impl Completion {
    fn finish(&self) -> Finish {
        self.finish.unwrap_or(Finish::Length)
    }
}

/// What a completion is held to.
enum Constraint<'a> {
    None,
    Lark(&'a str),
    Schema(&'a Value),
}

impl Remote {
    /// Reach the server, name the model, check that it tokenizes as `backend` does (where
    /// the server can tokenize on request), and find the grammar form it takes.
    /// `local`: the model file's name, for messages.
    pub fn connect(
        opts: &RemoteOptions,
        backend: &dyn Backend,
        local: &str,
    ) -> Result<Remote, RemoteError> {
        let api_key = match &opts.api_key_env {
            Some(var) => {
                Some(std::env::var(var).map_err(|_| RemoteError::NoKey { var: var.clone() })?)
            }
            None => None,
        };
        let client = Client::new(&opts.url, api_key, opts.timeout)?;
        let listed = client.get_json("/v1/models")?;
        let model = match &opts.model {
            Some(m) => m.clone(),
            None => listed["data"][0]["id"]
                .as_str()
                .map(str::to_string)
                .ok_or_else(|| RemoteError::BadAnswer {
                    path: "/v1/models".into(),
                    reason: format!("no model is listed ({listed}); name one with --remote-model"),
                })?,
        };
        let mut remote = Remote {
            client,
            model,
            grammar: Grammar::JsonSchema,
            sampler: SamplerConfig::default(),
            times: Vec::new(),
        };
        remote.check_vocabulary(backend, local)?;
        remote.grammar = match opts.grammar {
            GrammarMode::JsonSchema => Grammar::JsonSchema,
            mode => match remote.takes_lark(backend)? {
                Ok(()) => Grammar::Lark,
                Err(message) if mode == GrammarMode::Lark => {
                    return Err(RemoteError::NoLark { message })
                }
                Err(message) => {
                    tracing::info!(%message, "the model server takes no Lark grammar: JSON schemas it is");
                    Grammar::JsonSchema
                }
            },
        };
        tracing::info!(engine = %remote.describe(), "remote engine connected");
        Ok(remote)
    }

    /// Sample as `config` says (greedy by default).
    pub(crate) fn with_sampler(mut self, config: SamplerConfig) -> Remote {
        self.sampler = config;
        self
    }

    pub fn grammar(&self) -> Grammar {
        self.grammar
    }

    /// The time of every completion of this engine's turns, in order.
    pub fn times(&self) -> &[CompletionTime] {
        &self.times
    }

    /// The engine in a line, for traces and reports.
    pub fn describe(&self) -> String {
        let grammar = match self.grammar {
            Grammar::Lark => "Lark grammar (llguidance on the server)",
            Grammar::JsonSchema => "JSON schema (markers written by ferrosa)",
        };
        format!(
            "openai-compatible server {} model {} | {grammar}",
            self.client.url(),
            self.model
        )
    }

    /// Where a model runs, in a line: `remote`'s server, or in this process on `backend`.
    pub(crate) fn describe_engine(remote: Option<&Remote>, backend: &dyn Backend) -> String {
        remote.map_or_else(
            || format!("in-process {}", backend.name()),
            Remote::describe,
        )
    }

    /// A server that tokenizes on request (llama-server's `/tokenize`) must agree with
    /// the local vocabulary, or the ids ferrosa sends would mean other text.
    fn check_vocabulary(&self, backend: &dyn Backend, local: &str) -> Result<(), RemoteError> {
        let body = json!({"content": PROBE, "add_special": false, "parse_special": false});
        let theirs = match self.client.post_json("/tokenize", &body) {
            Ok(v) => v,
            Err(e @ (RemoteError::Connect { .. } | RemoteError::Timeout { .. })) => return Err(e),
            Err(e) => {
                tracing::info!("cannot check the server's tokenizer ({e}); its model is trusted to be the local one");
                return Ok(());
            }
        };
        let theirs: Vec<TokenId> = theirs["tokens"]
            .as_array()
            .map(|a| {
                a.iter()
                    .filter_map(|t| t.as_u64().map(|t| t as TokenId))
                    .collect()
            })
            .unwrap_or_default();
        let ours = backend
            .tokenize(PROBE, false)
            .map_err(|e| RemoteError::BadAnswer {
                path: "/tokenize".into(),
                reason: format!("cannot tokenize the probe locally: {e}"),
            })?;
        if theirs != ours {
            return Err(RemoteError::OtherModel {
                local: local.to_string(),
                probe: PROBE.to_string(),
                ours,
                theirs,
            });
        }
        Ok(())
    }

    /// Does the server hold a completion to a Lark grammar? `Err` says why not.
    fn takes_lark(&self, backend: &dyn Backend) -> Result<Result<(), String>, RemoteError> {
        let prompt = backend
            .tokenize("Reply with one word:", false)
            .unwrap_or_default();
        let grammar = "%llguidance {}\nstart: \"ok\"";
        let mut body = self.body(&prompt, &Constraint::Lark(grammar), 4);
        body["stream"] = json!(false);
        match self.client.post_json("/v1/completions", &body) {
            Ok(v) => {
                let text = v["choices"][0]["text"].as_str().unwrap_or_default();
                Ok(if text == "ok" {
                    Ok(())
                } else {
                    Err(format!(
                        "a completion under the grammar `start: \"ok\"` came back as {text:?}"
                    ))
                })
            }
            Err(RemoteError::Status { message, .. }) => Ok(Err(message)),
            Err(e) => Err(e),
        }
    }

    /// A completion request's body.
    fn body(&self, prompt: &[TokenId], constraint: &Constraint, max_tokens: usize) -> Value {
        let s = &self.sampler;
        let mut body = json!({
            "model": self.model,
            "prompt": prompt,
            "max_tokens": max_tokens.max(1),
            "temperature": s.temperature,
            "top_p": s.top_p,
            "seed": s.seed,
            "stream": true,
            "stream_options": {"include_usage": true},
            // llama-server: keep the prompt's KV cache for the next turn.
            "cache_prompt": true,
        });
        if s.temperature > 0.0 && s.top_k > 0 {
            body["top_k"] = json!(s.top_k);
        }
        match constraint {
            Constraint::None => {}
            Constraint::Lark(g) => body["grammar"] = json!(g),
            // `json_schema` is llama-server's field; `response_format` OpenAI's (vLLM).
            Constraint::Schema(schema) => {
                body["json_schema"] = (*schema).clone();
                body["response_format"] = json!({
                    "type": "json_schema",
                    "json_schema": {"name": "turn", "schema": schema, "strict": true},
                });
            }
        }
        body
    }

    /// One streamed completion; each piece goes to `on_text`, which may break to stop it.
    fn complete(
        &self,
        prompt: &[TokenId],
        constraint: &Constraint,
        max_tokens: usize,
        on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
    ) -> Result<Completion, RemoteError> {
        const PATH: &str = "/v1/completions";
        let start = Instant::now();
        let mut body = self.body(prompt, constraint, max_tokens);
        tracing::trace!(target: "ferrosa::remote", %body, "completion request");
        let tokens = body["prompt"].take();
        tracing::debug!(target: "ferrosa::remote", %body, "completion request (prompt ids left out)");
        body["prompt"] = tokens;
        let mut resp = self.client.post(PATH, &body)?;
        if !(200..300).contains(&resp.status) {
            let status = resp.status;
            let bytes = self.client.read_all(resp)?;
            return Err(RemoteError::Status {
                path: PATH.into(),
                status,
                message: client::server_message(&bytes),
            });
        }
        let c = self.read_stream(&mut resp, start, max_tokens, on_text);
        // Closing the connection at once, however the reading ended: a server stops a
        // completion its client left.
        self.client.close(resp);
        let mut c = c?;
        c.wall = start.elapsed();
        if c.finish.is_none() {
            return Err(RemoteError::BadAnswer {
                path: PATH.into(),
                reason: format!(
                    "the stream ended without saying why the completion stopped, after {:?}",
                    client::preview(c.text.as_bytes())
                ),
            });
        }
        Ok(c)
    }

    /// A completion's streamed answer, read up to its end, its `[DONE]` or `on_text`'s
    /// break, within bounds on what a server may send: text for the token limit (at a
    /// generous 128 bytes a token), a line and an event (`client::Events`), and a time-out
    /// between pieces of new text (keep-alive comments and empty pieces do not count).
    fn read_stream(
        &self,
        resp: &mut client::Response,
        start: Instant,
        max_tokens: usize,
        on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
    ) -> Result<Completion, RemoteError> {
        const PATH: &str = "/v1/completions";
        let mut c = Completion {
            text: String::new(),
            finish: None,
            generated: None,
            first_piece: None,
            cached: None,
            wall: Duration::ZERO,
            server: None,
        };
        let mut events = Events::default();
        let max_bytes = max_tokens.saturating_mul(128).saturating_add(4096);
        let mut progress = (Instant::now(), 0);
        loop {
            let chunk = self.client.next_chunk(resp)?;
            let batch = match &chunk {
                Some(bytes) => events.push(bytes),
                None => events.finish().map(|e| e.into_iter().collect()),
            };
            let batch = batch.map_err(|limit| RemoteError::BadAnswer {
                path: PATH.into(),
                reason: limit.to_string(),
            })?;
            for event in batch {
                if event.trim() == "[DONE]" {
                    return Ok(c);
                }
                if let Some(piece) = read_event(&event, &mut c, start, max_bytes)? {
                    if on_text(&piece).is_break() {
                        c.finish = Some(Finish::Stopped);
                        return Ok(c);
                    }
                }
            }
            if chunk.is_none() {
                return Ok(c);
            }
            if c.text.len() > progress.1 {
                progress = (Instant::now(), c.text.len());
            } else if progress.0.elapsed() > self.client.timeout {
                return Err(RemoteError::Timeout {
                    url: self.client.url(),
                    after: self.client.timeout,
                    waiting: "new text (the stream goes on without any)",
                });
            }
        }
    }

    /// Run one turn on the server (see the module header).
    pub fn turn(
        &mut self,
        backend: &dyn Backend,
        req: &TurnRequest,
        on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
    ) -> Result<TurnResult, DecodeError> {
        let start = Instant::now();
        let (prompt, _) = render_prompt_split(backend, &with_tools(req), req.envelope)?;
        let frame = match (req.decoding, self.grammar) {
            (Decoding::Free, _) => Frame::Free,
            (Decoding::Constrained, _) => {
                frame::for_turn(req.envelope, req.allowed_specs(), req.choice, req.parallel)
            }
        };
        let lark = (self.grammar == Grammar::Lark)
            .then(|| req.grammar())
            .flatten()
            .map(|g| lark_for_server(&g));
        let mut parts = Vec::new();
        let (text, finish) = match (&lark, frame) {
            (Some(g), _) => self.one(
                &prompt,
                &Constraint::Lark(g),
                req.max_tokens,
                on_text,
                &mut parts,
            )?,
            (None, frame) => self.framed(
                backend,
                &prompt,
                &frame,
                req.max_tokens,
                on_text,
                &mut parts,
            )?,
        };
        let turn = match req.decoding {
            Decoding::Free => req.envelope.parse(&text, req.specs),
            // What the grammar allowed: the allowed tools with their arguments as narrowed,
            // in a list of the allowed shape, whatever the server says of how it ended.
            Decoding::Constrained => {
                let cut = finish != Finish::EndOfGeneration;
                let turn = req
                    .envelope
                    .parse(&text, req.allowed_specs())
                    .and_then(|t| check_shape(req, t, cut));
                match turn {
                    // A call cut off at the token limit or by a stop is not a breach: the
                    // agent hears that it was cut off, and nothing runs.
                    Err(EnvelopeError::Json(_)) if cut => turn,
                    Err(e) => {
                        return Err(RemoteError::IgnoredGrammar {
                            reason: e.to_string(),
                            text: client::preview(text.as_bytes()),
                        }
                        .into())
                    }
                    Ok(t) => Ok(t),
                }
            }
        };
        let mut stats = GenerationStats {
            prompt_tokens: prompt.len(),
            ..GenerationStats::default()
        };
        for c in &parts {
            self.times.push(CompletionTime {
                wall: c.wall,
                server: c.server,
            });
            let n = c
                .generated
                .unwrap_or_else(|| backend.tokenize(&c.text, false).map_or(0, |t| t.len()));
            stats.generated_tokens = stats.generated_tokens.saturating_add(n);
            stats.gen_forwards = stats.gen_forwards.saturating_add(n);
        }
        stats.reused_tokens = parts
            .first()
            .and_then(|c| c.cached)
            .unwrap_or(0)
            .min(prompt.len());
        let first = parts
            .iter()
            .find_map(|c| c.first_piece)
            .unwrap_or_else(|| start.elapsed());
        stats.time_to_first_token = first;
        stats.prompt_time = first;
        stats.gen_time = start.elapsed().saturating_sub(first);
        Ok(TurnResult {
            text,
            turn,
            finish,
            stats,
        })
    }

    /// One completion as the whole turn: its text and how it ended; its figures go to
    /// `parts`.
    fn one(
        &self,
        prompt: &[TokenId],
        constraint: &Constraint,
        max_tokens: usize,
        on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
        parts: &mut Vec<Completion>,
    ) -> Result<(String, Finish), RemoteError> {
        let c = self.complete(prompt, constraint, max_tokens, on_text)?;
        let out = (c.text.clone(), c.finish());
        parts.push(c);
        Ok(out)
    }

    /// A turn as JSON-schema frames: the text and how it ended; each completion's figures
    /// go to `parts`.
    fn framed(
        &self,
        backend: &dyn Backend,
        prompt: &[TokenId],
        frame: &Frame,
        max_tokens: usize,
        on_text: &mut dyn FnMut(&str) -> ControlFlow<()>,
        parts: &mut Vec<Completion>,
    ) -> Result<(String, Finish), DecodeError> {
        match frame {
            Frame::Free => Ok(self.one(prompt, &Constraint::None, max_tokens, on_text, parts)?),
            Frame::Whole { schema } => {
                let schema = Constraint::Schema(schema);
                Ok(self.one(prompt, &schema, max_tokens, on_text, parts)?)
            }
            Frame::Marked {
                opening,
                schema,
                closing,
            } => {
                let mut full = prompt.to_vec();
                full.extend(backend.tokenize(opening, true)?);
                // The opening is shown with the server's first piece, as if it wrote it.
                let mut opened = false;
                let mut with_opening = |piece: &str| {
                    if std::mem::replace(&mut opened, true) {
                        on_text(piece)
                    } else {
                        on_text(&format!("{opening}{piece}"))
                    }
                };
                let c = self.complete(
                    &full,
                    &Constraint::Schema(schema),
                    max_tokens,
                    &mut with_opening,
                )?;
                let mut text = format!("{opening}{}", c.text);
                let finish = c.finish();
                parts.push(c);
                if finish == Finish::EndOfGeneration {
                    text.push_str(closing);
                    let _ = on_text(closing);
                }
                Ok((text, finish))
            }
            Frame::Either { marker, then } => {
                // Written whole before any of it is shown: a call's opening is not prose.
                let c = self.complete(prompt, &Constraint::None, max_tokens, &mut |_| {
                    ControlFlow::Continue(())
                })?;
                let Some(at) = marker.find(&c.text) else {
                    let _ = on_text(&c.text);
                    let out = (c.text.clone(), c.finish());
                    parts.push(c);
                    return Ok(out);
                };
                let prose = c.text[..at].to_string();
                parts.push(c);
                if !prose.is_empty() && on_text(&prose).is_break() {
                    return Ok((prose, Finish::Stopped));
                }
                let mut full = prompt.to_vec();
                full.extend(backend.tokenize(&prose, false)?);
                let (call, finish) =
                    self.framed(backend, &full, then, max_tokens, on_text, parts)?;
                Ok((format!("{prose}{call}"), finish))
            }
        }
    }
}

/// A parsed turn held to the list's shape the grammar allows (`parse` checks each call's
/// tool and arguments, not the list): a turn that must call does, no more calls than
/// allowed, and a tool called alone comes alone. A turn `cut` short may have no call yet.
fn check_shape(req: &TurnRequest, turn: Turn, cut: bool) -> Result<Turn, EnvelopeError> {
    let allowed = req.allowed_specs();
    let n = turn.calls.len();
    let max = if req.parallel { MAX_PARALLEL } else { 1 };
    let alone = turn
        .calls
        .iter()
        .any(|c| allowed.iter().any(|s| s.name == c.name && s.alone));
    let breach = match req.choice {
        ToolChoice::Required if n == 0 && !cut => {
            Some("no call, where one was required".to_string())
        }
        _ if n > max => Some(format!("{n} calls, where at most {max} were allowed")),
        _ if alone && n > 1 => Some("a tool called alone came with other calls".to_string()),
        _ => None,
    };
    match breach {
        Some(why) => Err(EnvelopeError::Shape(why)),
        None => Ok(turn),
    }
}

/// A Lark grammar as llama-server hands it to llguidance: only a grammar whose text
/// starts with `%llguidance` is (anything else is read as GBNF), so the leading comment
/// lines go.
fn lark_for_server(grammar: &str) -> String {
    let mut rest = grammar;
    while let Some(line) = rest.lines().next() {
        let t = line.trim();
        if !(t.is_empty() || t.starts_with("//")) {
            break;
        }
        rest = rest[line.len()..].trim_start_matches(['\r', '\n']);
    }
    if rest.starts_with("%llguidance") {
        rest.to_string()
    } else {
        format!("%llguidance {{}}\n{rest}")
    }
}

/// One streamed event: its text piece, if any; the completion's end, usage and cache
/// figures are noted in `c`.
fn read_event(
    event: &str,
    c: &mut Completion,
    start: Instant,
    max_bytes: usize,
) -> Result<Option<String>, RemoteError> {
    const PATH: &str = "/v1/completions";
    let v: Value = serde_json::from_str(event).map_err(|e| RemoteError::BadAnswer {
        path: PATH.into(),
        reason: format!(
            "a streamed event is not JSON ({e}): {}",
            client::preview(event.as_bytes())
        ),
    })?;
    if let Some(err) = v.get("error") {
        return Err(RemoteError::Status {
            path: PATH.into(),
            status: err["code"].as_u64().unwrap_or(0) as u16,
            message: err["message"]
                .as_str()
                .map_or_else(|| err.to_string(), str::to_string),
        });
    }
    if let Some(n) = v["usage"]["completion_tokens"].as_u64() {
        c.generated = Some(usize::try_from(n).unwrap_or(usize::MAX));
    }
    if let Some(n) = v["timings"]["cache_n"]
        .as_u64()
        .or_else(|| v["usage"]["prompt_tokens_details"]["cached_tokens"].as_u64())
    {
        c.cached = Some(n as usize);
    }
    let t = &v["timings"];
    if let (Some(p), Some(g)) = (t["prompt_ms"].as_f64(), t["predicted_ms"].as_f64()) {
        c.server = Duration::try_from_secs_f64((p + g) / 1e3).ok();
    }
    let Some(choice) = v["choices"].get(0) else {
        if v.get("usage").is_some() {
            return Ok(None);
        }
        return Err(RemoteError::BadAnswer {
            path: PATH.into(),
            reason: format!(
                "an event without choices: {}",
                client::preview(event.as_bytes())
            ),
        });
    };
    match choice["finish_reason"].as_str() {
        Some("length") => c.finish = Some(Finish::Length),
        Some(_) => c.finish = Some(Finish::EndOfGeneration),
        None => {}
    }
    let piece = choice["text"].as_str().unwrap_or_default();
    if piece.is_empty() {
        return Ok(None);
    }
    c.first_piece.get_or_insert_with(|| start.elapsed());
    c.text.push_str(piece);
    if c.text.len() > max_bytes {
        return Err(RemoteError::BadAnswer {
            path: PATH.into(),
            reason: format!(
                "the completion ran past its token limit ({} bytes and going)",
                c.text.len()
            ),
        });
    }
    Ok(Some(piece.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lark_grammar_reaches_llguidance_on_the_server() {
        let g = "// a comment\n//\n\n%llguidance {}\n\nstart: \"a\"\n// kept\n";
        assert_eq!(
            lark_for_server(g),
            "%llguidance {}\n\nstart: \"a\"\n// kept\n"
        );
        assert_eq!(
            lark_for_server("start: \"a\""),
            "%llguidance {}\nstart: \"a\""
        );
        let envelope =
            crate::decode::Envelope::Smollm2.grammar(&[], crate::decode::ToolChoice::Auto, true);
        assert!(lark_for_server(&envelope).starts_with("%llguidance {}"));
    }
}
