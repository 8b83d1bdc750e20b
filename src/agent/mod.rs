//! The ReAct agent: reason (one constrained assistant turn), act (run the calls, in
//! parallel, through the policy), observe (results appended as tool messages), repeated
//! until the model answers, the step limit, or cancellation.
//!
//! It sees the model only through `Backend` and the world only through `tool`: it never
//! imports `ros` or a concrete tool.
//!
//! Context, in the order the model reads it: the robot system prompt with the tool specs
//! (one system message, stable across steps and turns so the KV cache keeps it), the chat
//! history (trimmed oldest pair first to the budget), the new query, then this run's
//! scratchpad (the calls made and what they returned).
//!
//! Layout:
//! - `prompt`: robot system prompts (ROSA's fields) from TOML
//! - `memory`: chat history, trimming, output truncation
//! - `select`: choosing tools when their specs exceed the budget
//! - `event`: the typed event stream every front end consumes
//! - `ground`: dropping optional arguments nobody asked for
//! - `trace`: JSONL session traces

pub mod event;
pub mod ground;
pub mod intent;
pub mod memory;
pub mod prompt;
pub mod select;
pub mod trace;

use std::collections::BTreeSet;
use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::Serialize;
use serde_json::{json, Value};

use crate::backend::{Backend, ChatMessage, Role};
use crate::decode::envelope::{to_json_spaced, Envelope, ToolChoice};
use crate::decode::turn::{assistant_turn, with_tools, CopyFrom, TurnRequest};
use crate::decode::{
    DecodeError, Decoding, Finish as DecodeFinish, Grammars, Sampler, SamplerConfig, Session,
};
use crate::tool::{Decision, Effect, Policy, Registry, ToolCall, ToolContext, ToolError, ToolSpec};
pub use event::Event;
use memory::{truncate_output, Memory};
use trace::Trace;

/// Name of the pseudo-tool the model calls to give its final answer.
pub const ANSWER_TOOL: &str = "reply";
/// Longest answer text the grammar allows.
const ANSWER_CHARS: usize = 240;

#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    #[error(transparent)]
    Decode(#[from] DecodeError),
    #[error("cannot start the tool runtime: {0}")]
    Runtime(String),
}

/// How the model ends a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum AnswerMode {
    /// Every turn is a call; answering is the `answer` tool. Small models follow a
    /// forced structure far better than they decide between prose and a call.
    #[default]
    Tool,
    /// The model may answer in prose (tool choice `auto`).
    Prose,
    /// Calls only, or an empty call list when no tool fits (tool choice `decline`).
    Decline,
}

#[derive(Debug, Clone)]
pub struct AgentConfig {
    pub max_steps: usize,
    pub envelope: Envelope,
    pub decoding: Decoding,
    pub answer_mode: AnswerMode,
    /// Tokens per assistant turn at most.
    pub max_turn_tokens: usize,
    /// Context kept free for the model's reply and the scratchpad.
    pub reserve_tokens: usize,
    /// Run an actuating call only when the operator's request points at it (see
    /// `intent`); off, the policy and the operator's confirmation are the only gate.
    pub asked_actuation_only: bool,
    /// Tokens the conversation history may take: a longer history makes every turn that
    /// changes the offered tools evaluate more, and a small model gains little from it.
    pub history_tokens: usize,
    /// Tokens the tool specs may take before tools are selected per query.
    pub tool_budget_tokens: usize,
    /// Tools always offered when selecting.
    pub always_on: Vec<String>,
    /// Characters of a tool's output shown to the model.
    pub output_chars: usize,
    /// Logit bonus for argument values that copy what the operator said or a tool
    /// returned this run (see `decode::copy`); 0 turns it off.
    pub copy_bias: f32,
    pub sampler: SamplerConfig,
}

impl AgentConfig {
    pub fn for_family(family: &str) -> AgentConfig {
        AgentConfig {
            max_steps: 10,
            envelope: Envelope::for_family(family),
            decoding: Decoding::Constrained,
            answer_mode: AnswerMode::Tool,
            max_turn_tokens: 256,
            reserve_tokens: 1024,
            history_tokens: 768,
            asked_actuation_only: true,
            tool_budget_tokens: 1500,
            always_on: vec![ANSWER_TOOL.to_string()],
            output_chars: 1500,
            copy_bias: 0.0,
            sampler: SamplerConfig::default(),
        }
    }
}

/// Why a run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Finish {
    Answer,
    MaxSteps,
    Cancelled,
}

/// One executed (or refused) call.
#[derive(Debug, Clone, Serialize)]
pub struct StepRecord {
    pub step: usize,
    pub name: String,
    pub arguments: Value,
    pub output: Value,
    pub ok: bool,
    pub ms: f64,
    pub decision: Decision,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct Timings {
    pub total_ms: f64,
    pub model_ms: f64,
    pub tools_ms: f64,
    /// Prompt tokens of each step, and how many of them came from the KV cache.
    pub prompt_tokens: Vec<usize>,
    pub reused_tokens: Vec<usize>,
    /// Query to the first token the model emitted.
    pub first_token_ms: Option<f64>,
    /// Query to the first token of the first tool call.
    pub first_call_token_ms: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct RunResult {
    pub answer: String,
    pub finish: Finish,
    pub steps: Vec<StepRecord>,
    pub timings: Timings,
    /// Tools offered to the model for this query.
    pub tools_offered: Vec<String>,
}

pub struct Agent {
    backend: Box<dyn Backend>,
    /// Names of the tools that always actuate, and the vocabulary of the others (`intent`).
    actuators: BTreeSet<String>,
    observing: BTreeSet<String>,
    grammars: Grammars,
    registry: Registry,
    policy: Arc<Policy>,
    system: String,
    pub config: AgentConfig,
    session: Session,
    memory: Memory,
    runtime: tokio::runtime::Runtime,
    trace: Option<Trace>,
    cancel: Arc<AtomicBool>,
}

/// The `answer` pseudo-tool: how the model gives its final answer in `AnswerMode::Tool`.
pub fn answer_spec() -> ToolSpec {
    ToolSpec::new(
        ANSWER_TOOL,
        "Reply to the operator in one sentence, using the summary or the values the last tool returned.",
        // Bounded, so a model that rambles still ends its answer (see `tidy_answer`).
        // No braces or angle brackets: a small model that "closes" the call inside the
        // string (`}}]</tool_call>`) is steered to close the string instead.
        json!({"type": "object", "properties": {"text": {"type": "string", "maxLength": ANSWER_CHARS, "pattern": "^[^{}<>]*[^{}<>:\\s]$"}}, "required": ["text"]}),
    )
    .expect("static spec is valid")
    .called_alone()
}

/// Tokens `text` takes in a prompt (a guess from its length if it cannot be tokenized).
fn token_count(backend: &dyn Backend, text: &str) -> usize {
    backend
        .tokenize(text, true)
        .map_or(text.len() / 3, |t| t.len())
}

impl Agent {
    pub fn new(
        backend: Box<dyn Backend>,
        registry: Registry,
        policy: Arc<Policy>,
        system: String,
        config: AgentConfig,
    ) -> Result<Agent, AgentError> {
        let grammars = Grammars::new(backend.vocab(), backend.tokenizer())
            .map_err(|e| AgentError::Decode(e.into()))?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .map_err(|e| AgentError::Runtime(e.to_string()))?;
        let registry = if policy.read_only {
            registry.without_actuators(|name| policy.may_observe(name))
        } else {
            registry
        };
        // Tools whose every call changes the robot (no `observes` rule may cover one),
        // and the words of all the others, for telling which actuation a request asks for.
        let actuators: BTreeSet<String> = registry
            .tools()
            .filter(|t| t.effect() == Effect::Actuates && !policy.may_observe(&t.spec().name))
            .map(|t| t.spec().name.clone())
            .collect();
        let observing = intent::vocabulary(
            registry
                .tools()
                .filter(|t| !actuators.contains(&t.spec().name))
                .map(|t| t.spec()),
        );
        Ok(Agent {
            actuators,
            observing,
            backend,
            grammars,
            registry,
            policy,
            system,
            config,
            session: Session::new(),
            memory: Memory::default(),
            runtime,
            trace: None,
            cancel: Arc::new(AtomicBool::new(false)),
        })
    }

    pub fn with_trace(mut self, trace: Trace) -> Agent {
        self.trace = Some(trace);
        self
    }

    pub fn trace_path(&self) -> Option<&std::path::Path> {
        self.trace.as_ref().map(|t| t.path())
    }

    /// Set this flag (e.g. from a Ctrl-C handler) to end the current run cleanly.
    pub fn cancel_flag(&self) -> Arc<AtomicBool> {
        self.cancel.clone()
    }

    pub fn registry(&self) -> &Registry {
        &self.registry
    }

    /// Exchanges the agent remembers (what the next prompt may include).
    pub fn history_len(&self) -> usize {
        self.memory.len()
    }

    pub fn backend(&self) -> &dyn Backend {
        self.backend.as_ref()
    }

    /// Forget the conversation (the KV cache keeps the system prompt).
    pub fn clear(&mut self) {
        self.memory.clear();
    }

    fn tokens(&self, text: &str) -> usize {
        token_count(self.backend.as_ref(), text)
    }

    /// Which tools to offer for `query`, by the token cost of their specs.
    pub fn offered_tools(&self, query: &str) -> Vec<ToolSpec> {
        let mut specs = self.registry.specs();
        if self.config.answer_mode == AnswerMode::Tool {
            specs.push(answer_spec());
        }
        let chosen = select::select(
            query,
            &specs,
            &self.config.always_on,
            self.config.tool_budget_tokens,
            |s| self.tokens(&Envelope::describe_tool(s)),
        );
        chosen.into_iter().map(|i| specs[i].clone()).collect()
    }

    /// Prompt tokens of the first step of `query` with these tools and no history.
    pub fn prompt_tokens_with(&self, query: &str, specs: &[ToolSpec]) -> usize {
        let messages = [
            ChatMessage::new(Role::System, self.system.clone()),
            ChatMessage::new(Role::User, query),
        ];
        let req = self.request(&messages, specs, ToolChoice::Required);
        let text = self
            .backend
            .chat_template()
            .render(&with_tools(&req), None, true)
            .unwrap_or_default();
        self.tokens(&text)
    }

    fn request<'a>(
        &self,
        messages: &'a [ChatMessage],
        specs: &'a [ToolSpec],
        choice: ToolChoice,
    ) -> TurnRequest<'a> {
        TurnRequest {
            messages,
            specs,
            allowed: None,
            envelope: self.config.envelope,
            choice,
            parallel: true,
            decoding: self.config.decoding,
            max_tokens: self.config.max_turn_tokens,
            relevance_gate: None,
            copy: None,
        }
    }

    /// Answer `query`: reason, act and observe until an answer, the step limit or
    /// cancellation. Tool failures are observations; only a broken model runtime is an
    /// error.
    pub fn ask(
        &mut self,
        query: &str,
        events: &mut dyn FnMut(&Event),
    ) -> Result<RunResult, AgentError> {
        self.cancel.store(false, Ordering::SeqCst);
        let start = Instant::now();
        let offered = self.offered_tools(query);
        let names: Vec<String> = offered.iter().map(|s| s.name.clone()).collect();
        let choice = match self.config.answer_mode {
            AnswerMode::Tool => ToolChoice::Required,
            AnswerMode::Prose => ToolChoice::Auto,
            AnswerMode::Decline => ToolChoice::Decline,
        };
        if let Some(t) = &mut self.trace {
            t.record(
                "query",
                json!({"query": query, "tools_offered": names, "tools_total": self.registry.len()}),
            );
        }
        let mut emit = |agent: &mut Agent, e: Event| {
            if let Some(t) = &mut agent.trace {
                t.event(&e);
            }
            events(&e);
        };
        let mut timings = Timings::default();
        let mut records: Vec<StepRecord> = Vec::new();
        let mut scratch: Vec<ChatMessage> = Vec::new();
        let mut last_observation = String::new();
        let mut finish = Finish::MaxSteps;
        let mut answer = String::new();
        // Calls already run this query (name and arguments). Small models tend to repeat
        // a call after it succeeded (or was refused); a repeat gets the same result, so
        // instead the next step offers only the answer tool.
        let mut done_calls: Vec<(String, Value)> = Vec::new();
        let mut answer_only = false;
        // What optional arguments may draw on: the operator's words (this query and the
        // earlier ones) and what tools returned this run.
        let mut grounding =
            ground::Grounding::new(self.memory.queries().into_iter().chain([query]));
        // What argument values may be copied from: the same, in the original case.
        let mut copy_from: Vec<String> = self
            .memory
            .queries()
            .into_iter()
            .chain([query])
            .map(str::to_string)
            .collect();
        let answer_only_specs: Vec<ToolSpec> = offered
            .iter()
            .filter(|s| s.name == ANSWER_TOOL)
            .cloned()
            .collect();
        // Actuation the request points at; tools it cannot point at leave the grammar.
        let intent = intent::Intent::new(query);
        let askable: Vec<ToolSpec> = offered
            .iter()
            .filter(|s| {
                !self.config.asked_actuation_only
                    || !self.actuators.contains(&s.name)
                    || intent.may_ask_for(s, &self.observing)
            })
            .cloned()
            .collect();

        for step in 0..self.config.max_steps {
            if self.cancel.load(Ordering::SeqCst) {
                finish = Finish::Cancelled;
                break;
            }
            // Budget the history against everything else this step needs.
            let mut base = vec![ChatMessage::new(Role::System, self.system.clone())];
            base.push(ChatMessage::new(Role::User, query));
            base.extend(scratch.iter().cloned());
            let fixed = {
                let req = self.request(&base, &offered, choice);
                let text = self
                    .backend
                    .chat_template()
                    .render(&with_tools(&req), None, true)
                    .map_err(|e| AgentError::Decode(e.into()))?;
                self.tokens(&text)
            };
            let room = self
                .backend
                .context_len()
                .saturating_sub(fixed + self.config.reserve_tokens)
                .min(self.config.history_tokens);
            let backend = self.backend.as_ref();
            let dropped = self.memory.trim(room, |s| token_count(backend, s));
            let history = self.memory.messages();
            if dropped > 0 {
                if let Some(t) = &mut self.trace {
                    t.record(
                        "history_trimmed",
                        json!({"dropped_exchanges": dropped, "room_tokens": room}),
                    );
                }
            }
            let mut messages = vec![base[0].clone()];
            messages.extend(history);
            messages.extend(base[1..].iter().cloned());

            let copy_sources: Vec<&str> = copy_from.iter().map(String::as_str).collect();
            let mut req = self.request(&messages, &offered, choice);
            if self.config.copy_bias > 0.0 {
                req.copy = Some(CopyFrom {
                    sources: &copy_sources,
                    bonus: self.config.copy_bias,
                    exempt: Some(ANSWER_TOOL),
                });
            }
            if answer_only && !answer_only_specs.is_empty() {
                req.allowed = Some(&answer_only_specs);
            } else if askable.len() < offered.len() {
                req.allowed = Some(&askable);
            }
            let mut sampler = Sampler::new(self.config.sampler, self.backend.vocab().len());
            let cancel = self.cancel.clone();
            let t_model = Instant::now();
            let mut pieces: Vec<String> = Vec::new();
            let mut first_token = None;
            let result = assistant_turn(
                self.backend.as_mut(),
                &mut self.session,
                &self.grammars,
                &mut sampler,
                &req,
                |piece| {
                    if first_token.is_none() {
                        first_token = Some(start.elapsed());
                    }
                    pieces.push(piece.to_string());
                    if cancel.load(Ordering::SeqCst) {
                        ControlFlow::Break(())
                    } else {
                        ControlFlow::Continue(())
                    }
                },
            );
            timings.model_ms += t_model.elapsed().as_secs_f64() * 1e3;
            for p in pieces {
                emit(self, Event::Token { text: p });
            }
            let r = match result {
                Ok(r) => r,
                Err(DecodeError::Backend(crate::backend::BackendError::ContextFull {
                    needed,
                    limit,
                })) => {
                    answer = format!(
                        "I ran out of context ({needed} tokens needed, {limit} available) before finishing. {}",
                        summary(&last_observation)
                    );
                    emit(
                        self,
                        Event::Error {
                            message: answer.clone(),
                        },
                    );
                    finish = Finish::MaxSteps;
                    break;
                }
                Err(e) => return Err(e.into()),
            };
            timings.prompt_tokens.push(r.stats.prompt_tokens);
            timings.reused_tokens.push(r.stats.reused_tokens);
            if step == 0 {
                timings.first_token_ms = first_token.map(|d| d.as_secs_f64() * 1e3);
            }
            emit(
                self,
                Event::Step {
                    step,
                    prompt_tokens: r.stats.prompt_tokens,
                    reused_tokens: r.stats.reused_tokens,
                    tools: names.clone(),
                },
            );
            if r.finish == DecodeFinish::Stopped && self.cancel.load(Ordering::SeqCst) {
                finish = Finish::Cancelled;
                break;
            }
            let mut turn = match r.turn {
                Ok(t) => t,
                Err(e)
                    if r.finish == DecodeFinish::Length
                        && self.config.decoding == Decoding::Constrained =>
                {
                    // Cut off mid-call: tell the model, as a failed step, and go on.
                    let msg = format!(
                        "your reply was cut off after {} tokens before the call was complete ({e}); make a shorter call or answer",
                        self.config.max_turn_tokens
                    );
                    emit(
                        self,
                        Event::Error {
                            message: msg.clone(),
                        },
                    );
                    scratch.push(ChatMessage::new(Role::Assistant, r.text.clone()));
                    let mut m =
                        ChatMessage::new(Role::Tool, to_json_spaced(&json!({"error": msg})));
                    m.name = Some("system".into());
                    scratch.push(m);
                    // A model that ran out of room once will again: let it only answer.
                    answer_only = true;
                    continue;
                }
                Err(e) => {
                    // Free decoding (or a truncated turn): what the model wrote is all
                    // there is; show it as the answer rather than inventing one.
                    emit(
                        self,
                        Event::Error {
                            message: format!("the model's turn did not parse: {e}"),
                        },
                    );
                    answer = r.text.trim().to_string();
                    finish = Finish::Answer;
                    break;
                }
            };
            if let Some(a) = turn.calls.iter().find(|c| c.name == ANSWER_TOOL) {
                answer = tidy_answer(
                    a.arguments["text"].as_str().unwrap_or_default(),
                    ANSWER_CHARS,
                );
                finish = Finish::Answer;
                break;
            }
            if turn.calls.is_empty() {
                answer = turn.prose;
                finish = Finish::Answer;
                break;
            }
            for c in &mut turn.calls {
                let Some(spec) = offered.iter().find(|s| s.name == c.name) else {
                    continue;
                };
                let dropped = grounding.drop_ungrounded(c, spec);
                if !dropped.is_empty() {
                    if let Some(t) = &mut self.trace {
                        t.record(
                            "ungrounded",
                            json!({"step": step, "tool": c.name, "dropped": dropped}),
                        );
                    }
                }
            }
            if timings.first_call_token_ms.is_none() {
                timings.first_call_token_ms = first_token.map(|d| d.as_secs_f64() * 1e3);
            }
            let repeats = turn.calls.iter().all(|c| {
                done_calls
                    .iter()
                    .any(|(n, a)| *n == c.name && same_value(a, &c.arguments))
            });
            if repeats {
                if let Some(t) = &mut self.trace {
                    t.record("repeat", json!({"step": step, "calls": turn.calls}));
                }
                answer_only = true;
                continue;
            }
            // Act: policy first (in call order, so confirmations are asked in order),
            // then every allowed call concurrently.
            let decisions: Vec<Decision> = turn
                .calls
                .iter()
                .map(|c| {
                    let tool = self.registry.get(&c.name).map(|t| t.as_ref());
                    let unasked = self.config.asked_actuation_only
                        && tool.is_some_and(|t| {
                            self.policy.actuates(t, c) && !intent.asks_for(c, t.spec(), &self.observing)
                        });
                    if unasked {
                        return Decision::Refused(format!(
                            "the operator did not ask for {}: no word of the request points at it or at its target; do not act, answer instead",
                            c.name
                        ));
                    }
                    self.policy.check(tool, c)
                })
                .collect();
            for (i, (c, d)) in turn.calls.iter().zip(&decisions).enumerate() {
                emit(
                    self,
                    Event::ToolCall {
                        step,
                        index: i,
                        name: c.name.clone(),
                        arguments: c.arguments.clone(),
                        decision: d.clone(),
                    },
                );
            }
            let t_tools = Instant::now();
            let outcomes = self.run_calls(&turn.calls, &decisions);
            timings.tools_ms += t_tools.elapsed().as_secs_f64() * 1e3;
            scratch.push(ChatMessage::new(
                Role::Assistant,
                self.config.envelope.render_calls(&turn.calls),
            ));
            for (i, ((call, decision), (output, ok, ms))) in
                turn.calls.iter().zip(decisions).zip(outcomes).enumerate()
            {
                emit(
                    self,
                    Event::ToolResult {
                        step,
                        index: i,
                        name: call.name.clone(),
                        output: output.clone(),
                        ok,
                        ms,
                    },
                );
                // A refused call is as done as a successful one: asking again gets the
                // same refusal.
                if ok || matches!(decision, Decision::Refused(_)) {
                    done_calls.push((call.name.clone(), call.arguments.clone()));
                }
                let shown = truncate_output(&to_json_spaced(&output), self.config.output_chars);
                grounding.add(&shown);
                copy_from.push(shown.clone());
                last_observation = shown.clone();
                let mut m = ChatMessage::new(Role::Tool, shown);
                m.name = Some(call.name.clone());
                scratch.push(m);
                records.push(StepRecord {
                    step,
                    name: call.name.clone(),
                    arguments: call.arguments.clone(),
                    output,
                    ok,
                    ms,
                    decision,
                });
            }
        }
        match finish {
            Finish::MaxSteps if answer.is_empty() => {
                answer = format!(
                    "I stopped after {} steps without a final answer. {}",
                    self.config.max_steps,
                    summary(&last_observation)
                );
            }
            Finish::Cancelled => {
                answer = format!("Cancelled. {}", summary(&last_observation));
            }
            _ => {}
        }
        timings.total_ms = start.elapsed().as_secs_f64() * 1e3;
        emit(
            self,
            Event::Answer {
                text: answer.clone(),
                finish: format!("{finish:?}").to_lowercase(),
            },
        );
        if finish == Finish::Answer {
            self.memory.push(query, answer.clone());
        }
        if let Some(t) = &mut self.trace {
            t.record(
                "timings",
                serde_json::to_value(&timings).unwrap_or_default(),
            );
        }
        Ok(RunResult {
            answer,
            finish,
            steps: records,
            timings,
            tools_offered: names,
        })
    }

    /// Run allowed calls concurrently; results in call order as (output, ok, ms).
    fn run_calls(&self, calls: &[ToolCall], decisions: &[Decision]) -> Vec<(Value, bool, f64)> {
        let timeout = self.policy.timeout;
        let handles: Vec<_> = calls
            .iter()
            .zip(decisions)
            .map(|(call, decision)| {
                let tool = match decision {
                    Decision::Refused(_) => None,
                    _ => self.registry.get(&call.name).cloned(),
                };
                let args = call.arguments.clone();
                let refused = match decision {
                    Decision::Refused(r) => Some(r.clone()),
                    _ => None,
                };
                self.runtime.spawn(async move {
                    let start = Instant::now();
                    let result = match (tool, refused) {
                        (_, Some(reason)) => Err(ToolError::Refused(reason)),
                        (None, None) => Err(ToolError::Failed("no such tool".into())),
                        (Some(tool), None) => {
                            let cx = ToolContext { timeout };
                            match tokio::time::timeout(timeout, tool.call(args, &cx)).await {
                                Ok(r) => r,
                                Err(_) => Err(ToolError::Timeout(timeout)),
                            }
                        }
                    };
                    (result, start.elapsed())
                })
            })
            .collect();
        self.runtime.block_on(async {
            let mut out = Vec::with_capacity(handles.len());
            for h in handles {
                let (result, took): (Result<Value, ToolError>, Duration) = match h.await {
                    Ok(x) => x,
                    // A panicking tool is a failed call, not a crashed agent.
                    Err(e) => (
                        Err(ToolError::Failed(format!("the tool crashed: {e}"))),
                        Duration::ZERO,
                    ),
                };
                let ms = took.as_secs_f64() * 1e3;
                out.push(match result {
                    Ok(mut v) => {
                        let removed = self.policy.redact(&mut v);
                        if removed > 0 {
                            if let Value::Object(m) = &mut v {
                                m.insert("hidden_by_policy".into(), json!(removed));
                            }
                        }
                        (v, true, ms)
                    }
                    Err(e) => (json!({"error": e.to_string()}), false, ms),
                });
            }
            out
        })
    }
}

/// JSON equality with numbers compared by value (3 and 3.0 are the same argument).
fn same_value(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => x.as_f64() == y.as_f64(),
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| same_value(p, q))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| same_value(v, w)))
        }
        _ => a == b,
    }
}

/// The answer as the operator reads it: when the model ran into the length cap, cut
/// back to its last complete sentence.
fn tidy_answer(text: &str, cap: usize) -> String {
    let t = text.trim();
    if t.chars().count() < cap {
        return t.to_string();
    }
    match t.rfind(['.', '!', '?']) {
        Some(i) if i > 0 => t[..=i].to_string(),
        _ => t.to_string(),
    }
}

fn summary(last: &str) -> String {
    if last.is_empty() {
        "No tool returned anything yet.".to_string()
    } else {
        format!("Last result: {}", truncate_output(last, 300))
    }
}
