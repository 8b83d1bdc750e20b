//! One run of the agent, as a small state machine. Each step is:
//!
//! 1. **think**: one assistant turn (the model, through the strategy pipeline), with the
//!    tools the guards leave;
//! 2. **guard**: the calls pass the guards (`guard`) in order;
//! 3. **policy**: each call the guards passed is checked (and confirmed) by the policy;
//! 4. **act**: the allowed calls run concurrently, each under the time limit;
//! 5. **observe**: results (or the reasons for refusals) are appended for the next step.
//!
//! A request of several parts (`plan`) is worked one part at a time: the model is shown
//! the first part as the operator's turn, and each next part once a call of the part
//! before has run (or the model answered it). The run ends with the last part's answer
//! (the `reply` call), at the step limit, or on cancellation. Events stream as they happen: tokens during the turn, each call with its
//! decision, each result.

use std::ops::ControlFlow;
use std::sync::atomic::Ordering;
use std::time::Instant;

use serde_json::{json, Value};

use super::answer::{self, ANSWER_CHARS, ANSWER_TOOL};
use super::config::STOP_TOOL;
use super::guard::{Came, Guards, Verdict};
use super::history::truncate_output;
use super::{Agent, AgentError, Event, Finish, RunResult, StepRecord, Timings};
use crate::backend::BackendError;
use crate::chat::{ChatMessage, Role};
use crate::decode::envelope::to_json_spaced;
use crate::decode::request::TurnResult;
use crate::decode::{DecodeError, Decoding, Finish as DecodeFinish, Sampler, Turn};
use crate::reading::bound;
use crate::reading::facts;
use crate::reading::language::{Language, Phrase};
use crate::reading::small_talk;
use crate::tool::exec::Outcome;
use crate::tool::{Decision, ToolCall, ToolSpec};
use crate::turn::Engine;

/// With every tool listed (`Agent::listed`), how many of the tools a request is
/// offered the request names after its words, best first: the listing is the same for
/// every request, and a small model reads what is near the request most.
const HINTED: usize = 3;

/// What the model's turn came to.
enum Thought {
    /// Calls to make.
    Calls(Vec<ToolCall>),
    /// The model answered a part of the request that is not the last: on to the next.
    NextPart,
    /// The run is over.
    Done(Finish),
}

/// A run in progress.
pub(super) struct Run<'a> {
    pub agent: &'a mut Agent,
    pub query: &'a str,
    pub events: &'a mut dyn FnMut(&Event),
    pub start: Instant,
    pub offered: Vec<ToolSpec>,
    /// The tools every step's prompt lists (`Agent::listed`): the offered ones, or all.
    pub listed: Vec<ToolSpec>,
    pub guards: Guards,
    /// This run's calls and results, as the model reads them.
    pub scratch: Vec<ChatMessage>,
    pub records: Vec<StepRecord>,
    pub timings: Timings,
    pub answer: String,
    /// What the last tool returned, in one line: its summary, or a failure's error.
    pub last_observation: String,
    /// The summaries of the calls of the part being worked that succeeded, each with its
    /// tool, in the order they ran: what an answer is held to (`ground`).
    pub grounds: Vec<(String, String)>,
    /// The same of the parts before: what a part answered without a call of its own
    /// is held to ("move 1 m, then tell me where it is" answered from the move's pose).
    pub earlier_grounds: Vec<(String, String)>,
    /// What argument values may be copied from: what the operator said, what tools
    /// returned.
    pub copy_from: Vec<String>,
    /// A turn was cut off: the next may only answer.
    pub answer_only: bool,
    /// When this step's first token came (ms since the query).
    pub step_first_token: Option<f64>,
    /// The model called `robot_stop` on a request that asked no stop: the robot was
    /// braked (not latched) and the tool is not offered again this run.
    pub stop_withdrawn: bool,
    /// The request's parts (`plan`; one when it is not cut), the one being worked, and
    /// the answers given to the parts before it.
    pub parts: Vec<String>,
    pub part: usize,
    pub partial_answers: Vec<String>,
    /// The language the answer is written in.
    pub language: Language,
    /// What the first call of the part being worked that failed or was refused said
    /// (its error, else the text the model read; a later one is most often a try the
    /// guards turned down): what an answer of a part with no
    /// result of its own is answered with (`held`).
    pub part_failure: Option<String>,
    /// When the e-stop was engaged, if it was when the run began: an engagement since
    /// ends the run (`pressed_since`). Presses of an e-stop already engaged do not (a
    /// bridge that publishes `true` at a rate presses it again and again).
    pub engaged_at: Option<Instant>,
    /// The calls of this step a guard refused (`Came::TurnedDown`).
    pub turned_down: Vec<ToolCall>,
}

impl Run<'_> {
    /// Send an event to the trace and the front end, with nothing behind the fence.
    fn emit(&mut self, mut e: Event) {
        let policy = self.agent.exec.policy();
        match &mut e {
            Event::ToolCall { arguments, .. } => {
                policy.redact(arguments);
            }
            Event::ToolResult { output, .. } => {
                policy.redact(output);
            }
            Event::Answer { text, .. } | Event::Error { message: text } => {
                *text = policy.redact_text(text).into_owned();
            }
            // The executor redacted it.
            Event::Step { .. } | Event::Token { .. } | Event::ToolProgress { .. } => {}
        }
        if let Some(t) = &mut self.agent.trace {
            t.event(&e);
        }
        (self.events)(&e);
    }

    /// Run steps until the run ends. A request to stop stops the robot before anything
    /// else, without the model (stopping needs no model, no intent, no confirmation).
    pub fn run(mut self) -> Result<RunResult, AgentError> {
        if crate::reading::concepts::operator_stops(self.query) {
            let estop = self.agent.exec.policy().estop().clone();
            estop.trigger(&format!("the operator: {}", self.query.trim()));
            // The stop is the `robot_stop` act, taken without the model: the run's
            // record and its events say so, as for a stop the model calls.
            let output = json!({"stopped": true, "by": "the operator's words"});
            self.emit(Event::ToolCall {
                step: 0,
                index: 0,
                name: STOP_TOOL.to_string(),
                arguments: json!({}),
                decision: Decision::Allowed,
            });
            self.emit(Event::ToolResult {
                step: 0,
                index: 0,
                name: STOP_TOOL.to_string(),
                output: output.clone(),
                ok: true,
                ms: 0.0,
            });
            self.records.push(StepRecord {
                step: 0,
                name: STOP_TOOL.to_string(),
                arguments: json!({}),
                output,
                ok: true,
                ms: 0.0,
                decision: Decision::Allowed,
            });
            self.answer =
                "Stopped. Motion stays refused until the operator resets the e-stop.".into();
            return Ok(self.end(Finish::Answer));
        }
        self.read_meant();
        if self.parts.len() > 1 {
            self.guards.next_part(&self.parts[0]);
            if let Some(t) = &mut self.agent.trace {
                t.record("parts", json!({ "parts": self.parts }));
            }
        }
        let mut finish = Finish::MaxSteps;
        for step in 0..self.agent.config.max_steps {
            if self.agent.cancel.load(Ordering::SeqCst) {
                finish = Finish::Cancelled;
                break;
            }
            if let Some(answer) = self.pressed_since() {
                self.answer = answer;
                finish = Finish::Answer;
                break;
            }
            let mut calls = match self.think(step)? {
                Thought::Done(f) => {
                    finish = f;
                    break;
                }
                Thought::NextPart => {
                    self.next_part();
                    continue;
                }
                Thought::Calls(c) => c,
            };
            // Pressed while the model wrote these calls: none of them runs.
            if let Some(answer) = self.pressed_since() {
                self.answer = answer;
                finish = Finish::Answer;
                break;
            }
            let verdicts = self.guards.check(&mut calls, &self.offered);
            if verdicts.iter().all(|v| *v == Verdict::Skip) {
                let mut record = json!({"step": step, "calls": calls});
                self.agent.exec.policy().redact(&mut record);
                if let Some(t) = &mut self.agent.trace {
                    t.record("repeat", record);
                }
                continue;
            }
            let decisions = self.decide(&calls, verdicts);
            let done = self.act_and_observe(step, &calls, decisions);
            if done && self.part + 1 < self.parts.len() {
                // The part's answer is its result, kept for the run's answer: "the
                // nodes, then the services" states both.
                let said = self.held("");
                self.keep_partial(said);
                self.next_part();
            }
        }
        Ok(self.end(finish))
    }

    /// The answer of a run whose robot was e-stopped while it ran (pressed by anyone:
    /// the operator, a ROS node, the console): the run ends there, saying so and what
    /// the call it stopped had last reported. A small model reaches for the next
    /// motion (refused) and then writes a reply that says nothing of where the robot
    /// stopped; a run that goes on after the e-stop serves no one.
    fn pressed_since(&self) -> Option<String> {
        let now = self.agent.exec.policy().estop().engaged_by().map(|e| e.at);
        if now.is_none() || now == self.engaged_at {
            return None;
        }
        // The call the press aborted, if one was running (`Executor::run` words it).
        let stopped = self
            .records
            .iter()
            .rev()
            .filter(|r| !r.ok)
            .filter_map(|r| r.output.get("error").and_then(Value::as_str))
            .find(|e| crate::tool::exec::stopped_by_estop(e));
        let said = self.language.say(Phrase::EStopped);
        let stopped = match stopped {
            Some(error) => format!("{said} {}", answer::last_result(error, self.language)),
            None => said,
        };
        // What the parts before were answered stays.
        let mut answer = self.partial_answers.clone();
        answer.push(stopped);
        Some(answer.join(" "))
    }

    /// The robot's names the current part asks to act on by meaning, told to the guards
    /// (`reading::meant`; none without the sentence encoder).
    fn read_meant(&mut self) {
        let Some(meaning) = self.agent.meaning.clone() else {
            return;
        };
        let part = &self.parts[self.part];
        let names = self.agent.robot_names();
        // The tool the part is nearest by meaning, when it is a generic actuator.
        let sims = meaning.similarities(part, &self.offered, &names);
        let nearest = self
            .offered
            .iter()
            .zip(sims)
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .filter(|(s, _)| {
                self.agent.asked.actuators.contains(&s.name)
                    && crate::reading::intent::is_generic(s)
            });
        let nearest_tool = nearest.map(|(s, _)| s.name.as_str());
        let nearest = nearest.map(|(s, similarity)| crate::reading::meant::Nearest {
            similarity,
            kinds: crate::reading::select::name_kinds(s).collect(),
        });
        // Only the names that tool can take now (a publish: the topics some node
        // subscribes to), where its live schema lists them.
        let takes = nearest_tool
            .and_then(|t| self.agent.exec.registry().get(t)?.live_spec())
            .and_then(|s| super::guard::bound_targets(&s.parameters));
        let names: Vec<(String, String)> = match takes {
            Some(takes) => names
                .into_iter()
                .filter(|(_, n)| takes.iter().any(|(_, t)| t == n))
                .collect(),
            None => names,
        };
        let near = |n: &str| meaning.name_similarity(part, n);
        let meant = crate::reading::meant::meant(part, &names, &near, nearest);
        self.guards.by_meaning(&meant);
    }

    /// On to the next part of the request: the operator's next turn, as the model reads it.
    fn next_part(&mut self) {
        self.part += 1;
        let part = self.parts[self.part].clone();
        self.guards.next_part(&part);
        self.read_meant();
        self.answer_only = false;
        self.part_failure = None;
        let done = std::mem::take(&mut self.grounds);
        self.earlier_grounds.extend(done);
        if let Some(t) = &mut self.agent.trace {
            t.record("next_part", json!({ "part": self.part, "text": part }));
        }
        self.scratch.push(ChatMessage::new(Role::User, part));
    }

    /// Keep a part's answer (not the last part's) for the run's answer, once.
    fn keep_partial(&mut self, said: String) {
        if !said.is_empty() && !self.partial_answers.contains(&said) {
            self.partial_answers.push(said);
        }
    }

    /// The model answered: the run's answer when this is the last part, else the
    /// part's, kept for the answer.
    fn answered(&mut self, text: String) -> Thought {
        if self.part + 1 < self.parts.len() {
            self.keep_partial(text);
            return Thought::NextPart;
        }
        let mut said = std::mem::take(&mut self.partial_answers);
        if !said.contains(&text) {
            said.push(text);
        }
        self.answer = said.join(" ");
        Thought::Done(Finish::Answer)
    }

    /// The answer the operator reads for what the model `said`: held to the result it
    /// answers (`facts::grounded`) and to the run's language. A reply plainly in another
    /// language is replaced by the result as one that states none of its facts is, and a
    /// result given in place of a reply is led by a word in the run's language.
    fn held(&self, said: &str) -> String {
        // No call this run (so no result to hold it to): the agent's own reply
        // (`small_talk`) when it can read the request by meaning.
        if self.records.is_empty() {
            if let Some(meaning) = &self.agent.meaning {
                let registry = self.agent.exec.registry();
                let tools = small_talk::Tools {
                    each: registry
                        .tools()
                        .map(|t| (t.spec().name.as_str(), t.effect()))
                        .collect(),
                };
                return small_talk::reply(meaning, self.query, self.agent.config.language, &tools);
            }
        }
        // A part whose calls all came to nothing is answered with what went wrong: the
        // model's words about a failure read as a result ("the place where you can find
        // the greenhouse is home, dock, pond", after "no place called greenhouse").
        if let (true, Some(failure)) = (self.grounds.is_empty(), &self.part_failure) {
            return self.language.lead(failure);
        }
        // A reply that writes a call (or JSON) is no answer: the result stands for it.
        let said = if answer::writes_a_call(said) {
            ""
        } else {
            said
        };
        let ground = self.ground();
        let grounded = facts::grounded(said, ground, self.query);
        let answer = match ground {
            Some(summary) if grounded == summary || self.language.differs(&grounded) => {
                self.language.lead(summary)
            }
            _ if grounded.trim().is_empty() => {
                answer::last_result(&self.last_observation, self.language)
            }
            _ => grounded,
        };
        // A failure before the part's result is said first, so a result read after it
        // (the places listed after a drive to an unknown one) does not hide it.
        match &self.part_failure {
            Some(failure) if !self.grounds.is_empty() => format!("{failure}. {answer}"),
            _ => answer,
        }
    }

    /// What the part's answer is held to: of the part's calls that succeeded, the latest
    /// of those whose tool the part's words meet best (`select::grounding`). A call the
    /// request did not ask for (the pose read after the battery) does not replace the
    /// result the operator asked for. A part with no result of its own is held to those
    /// of the parts before it.
    fn ground(&self) -> Option<&str> {
        let grounds = if self.grounds.is_empty() {
            &self.earlier_grounds
        } else {
            &self.grounds
        };
        let tools: Vec<&str> = grounds.iter().map(|(t, _)| t.as_str()).collect();
        let priors = self
            .agent
            .prior(&self.parts[self.part], &tools, &self.agent.robot_names());
        let i = crate::reading::select::grounding(&priors)?;
        Some(grounds[i].1.as_str())
    }

    /// Once a call of the part succeeded, the part's next step may answer, or call a
    /// tool the part's words point at more than at every tool whose call succeeded
    /// (the retrieval prior); one that acts (or cancels), or records what the agent
    /// keeps (`ToolSpec::records`), only when the part asks for an act ("where am I
    /// pointing now?" read the pose, then taught it as a place called "pointing now").
    /// So a
    /// first call of the tool the request names best is followed by the answer, and a
    /// first call of a weaker match may be followed by a better one. A small model
    /// otherwise goes on with calls nobody asked for (`ros_action_cancel` after a
    /// service's info, a service call after a parameter read, the stop tool it is
    /// always shown). A part that asks for two things in one clause may lose its second
    /// tool; `plan` cuts most such requests in two.
    fn settled(
        &self,
        allowed: Option<Vec<String>>,
        robot_names: &[(String, String)],
    ) -> Option<Vec<String>> {
        if self.grounds.is_empty() {
            return allowed;
        }
        let names: Vec<String> =
            allowed.unwrap_or_else(|| self.offered.iter().map(|s| s.name.clone()).collect());
        let part = &self.parts[self.part];
        let mut candidates: Vec<&str> = names.iter().map(String::as_str).collect();
        candidates.extend(self.grounds.iter().map(|(t, _)| t.as_str()));
        let priors = self.agent.prior(part, &candidates, robot_names);
        let (offered, done) = priors.split_at(names.len());
        let further = crate::reading::select::beyond(offered, done);
        let part_acts = {
            use crate::reading::concepts::{asked_acts, clauses, Act};
            asked_acts(&clauses(part))
                .iter()
                .any(|a| !matches!(a, Act::Stop | Act::Fence))
        };
        let registry = self.agent.exec.registry();
        let acts = |n: &str| {
            registry
                .get(n)
                .is_some_and(|t| t.effect() != crate::tool::Effect::Observes || t.spec().records)
        };
        let kept: Vec<String> = names
            .iter()
            .zip(further)
            .filter(|(n, further)| {
                *n == ANSWER_TOOL || (*further && *n != STOP_TOOL && (part_acts || !acts(n)))
            })
            .map(|(n, _)| n.clone())
            .collect();
        // Answering in prose needs no tool; a grammar needs one to write.
        Some(if kept.is_empty() { names } else { kept })
    }

    /// `allowed` (all offered when `None`) without the tools that record what the agent
    /// keeps (`ToolSpec::records`) unless the part points at one of them most (the
    /// retrieval prior, by meaning and words, of every tool it may call): what the
    /// operator asks to keep, not a fact the model makes of another request. On the arm,
    /// a request to drive the bolted-down arm to a dock was noted as a fact, and a German
    /// request to raise the grip force was kept as one beside two junk calls.
    fn asked_to_record(
        &self,
        allowed: Option<Vec<String>>,
        robot_names: &[(String, String)],
    ) -> Option<Vec<String>> {
        let registry = self.agent.exec.registry();
        let records = |n: &str| registry.get(n).is_some_and(|t| t.spec().records);
        let names: Vec<String> = allowed
            .clone()
            .unwrap_or_else(|| self.offered.iter().map(|s| s.name.clone()).collect());
        if !names.iter().any(|n| records(n)) {
            return allowed;
        }
        let candidates: Vec<&str> = names
            .iter()
            .map(String::as_str)
            .filter(|n| *n != ANSWER_TOOL && *n != STOP_TOOL)
            .collect();
        let priors = self
            .agent
            .prior(&self.parts[self.part], &candidates, robot_names);
        let best = priors.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let pointed: Vec<&str> = candidates
            .iter()
            .zip(&priors)
            .filter(|(_, p)| **p >= best - 1e-9)
            .map(|(n, _)| *n)
            .collect();
        if pointed.iter().any(|n| records(n)) {
            return allowed;
        }
        tracing::debug!(target: "ferrosa::guard", ?pointed, "recording tools held back");
        let kept: Vec<String> = names.iter().filter(|n| !records(n)).cloned().collect();
        Some(if kept.is_empty() {
            vec![ANSWER_TOOL.to_string()]
        } else {
            kept
        })
    }

    /// The step's turn: the model writes calls, or the answer.
    fn think(&mut self, step: usize) -> Result<Thought, AgentError> {
        let allowed = if self.answer_only {
            Some(vec![ANSWER_TOOL.to_string()])
        } else {
            self.guards.narrow(&self.offered)
        };
        // One graph snapshot for the step: the follow-up rule, the grammar, the pick.
        let robot_names = self.agent.robot_names();
        let allowed = self.settled(allowed, &robot_names);
        let allowed = match allowed {
            Some(names) if self.stop_withdrawn => {
                Some(names.into_iter().filter(|n| n != STOP_TOOL).collect())
            }
            None if self.stop_withdrawn => Some(
                self.offered
                    .iter()
                    .map(|s| s.name.clone())
                    .filter(|n| n != STOP_TOOL)
                    .collect(),
            ),
            other => other,
        };
        let allowed = self.asked_to_record(allowed, &robot_names);
        // A result (or the part's failure) is in and answering is all that is left: the
        // answer is the result as `held` gives it, without the model. Its reply here would be one the
        // answer replaces (a small model's rarely states the result) and the turn's
        // slowest part.
        if self.agent.config.composed_answers
            && (!self.grounds.is_empty() || self.part_failure.is_some())
            && allowed
                .as_deref()
                .is_some_and(|names| names.iter().all(|n| n == ANSWER_TOOL))
        {
            let held = self.held("");
            return Ok(self.answered(held));
        }
        let t_model = Instant::now();
        let result = self.turn(allowed, &robot_names);
        self.timings.model_ms += t_model.elapsed().as_secs_f64() * 1e3;
        let r = match result {
            Ok(r) => r,
            Err(DecodeError::Backend(BackendError::ContextFull { needed, limit })) => {
                self.answer = format!(
                    "I ran out of context ({needed} tokens needed, {limit} available) before finishing. {}",
                    answer::last_result(&self.last_observation, self.language)
                );
                let message = self.answer.clone();
                self.emit(Event::Error { message });
                return Ok(Thought::Done(Finish::MaxSteps));
            }
            Err(e) => return Err(e.into()),
        };
        self.timings.generated_tokens += r.stats.generated_tokens;
        self.timings.prompt_tokens.push(r.stats.prompt_tokens);
        self.timings.reused_tokens.push(r.stats.reused_tokens);
        self.emit(Event::Step {
            step,
            prompt_tokens: r.stats.prompt_tokens,
            reused_tokens: r.stats.reused_tokens,
            tools: self.offered.iter().map(|s| s.name.clone()).collect(),
        });
        if r.finish == DecodeFinish::Stopped && self.agent.cancel.load(Ordering::SeqCst) {
            return Ok(Thought::Done(Finish::Cancelled));
        }
        self.read_turn(r)
    }

    /// The turn's text, as calls or an answer.
    fn read_turn(&mut self, r: TurnResult) -> Result<Thought, AgentError> {
        let turn: Turn = match r.turn {
            Ok(t) => t,
            Err(e)
                if r.finish == DecodeFinish::Length
                    && self.agent.config.decoding == Decoding::Constrained =>
            {
                // Cut off before the call was complete (only past the closing steer's
                // overrun): tell the model, as a failed step, and let it only answer.
                let msg = format!(
                    "your reply was cut off after {} tokens before the call was complete ({e}); answer now",
                    self.agent.config.max_turn_tokens
                );
                self.emit(Event::Error {
                    message: msg.clone(),
                });
                self.scratch
                    .push(ChatMessage::new(Role::Assistant, r.text.clone()));
                self.scratch.push(ChatMessage::tool(
                    "system",
                    to_json_spaced(&json!({ "error": msg })),
                ));
                self.answer_only = true;
                return Ok(Thought::Calls(Vec::new()));
            }
            Err(e) => {
                // Free decoding: what the model wrote is all there is; show it as the
                // answer rather than inventing one.
                self.emit(Event::Error {
                    message: format!("the model's turn did not parse: {e}"),
                });
                self.answer = r.text.trim().to_string();
                return Ok(Thought::Done(Finish::Answer));
            }
        };
        if let Some(a) = turn.calls.iter().find(|c| c.name == ANSWER_TOOL) {
            let said = answer::tidy(
                a.arguments["text"].as_str().unwrap_or_default(),
                ANSWER_CHARS,
            );
            let held = self.held(&said);
            return Ok(self.answered(held));
        }
        if turn.calls.is_empty() {
            // Prose (no tool was left to write) is held as a reply call is: with no call
            // before it, the agent's own reply replaces it; after calls, it is held to
            // their results (a small model wrote a made-up call as prose).
            let prose = if self.records.is_empty() && self.agent.meaning.is_none() {
                turn.prose
            } else {
                self.held(&turn.prose)
            };
            return Ok(self.answered(prose));
        }
        if self.timings.first_call_token_ms.is_none() {
            self.timings.first_call_token_ms = self.step_first_token;
            self.timings.first_call_ms = Some(self.start.elapsed().as_secs_f64() * 1e3);
        }
        Ok(Thought::Calls(turn.calls))
    }

    /// The policy's decision on each call the guards passed, in call order (so
    /// confirmations are asked in order).
    fn decide(&mut self, calls: &[ToolCall], verdicts: Vec<Verdict>) -> Vec<Option<Decision>> {
        self.turned_down = calls
            .iter()
            .zip(&verdicts)
            .filter(|(_, v)| matches!(v, Verdict::Refuse(_)))
            .map(|(c, _)| c.clone())
            .collect();
        calls
            .iter()
            .zip(verdicts)
            .map(|(c, v)| match v {
                Verdict::Skip => None,
                Verdict::Refuse(why) => Some(Decision::Refused(
                    self.agent.exec.policy().off_limits(c).unwrap_or(why),
                )),
                Verdict::Pass => Some(self.agent.exec.decide(c)),
            })
            .collect()
    }

    /// Run the allowed calls and append what came of each call that was not skipped;
    /// whether one of them is done (it ran, or was refused).
    fn act_and_observe(
        &mut self,
        step: usize,
        calls: &[ToolCall],
        decisions: Vec<Option<Decision>>,
    ) -> bool {
        let shown: Vec<(ToolCall, Decision)> = calls
            .iter()
            .zip(decisions)
            .filter_map(|(c, d)| d.map(|d| (c.clone(), d)))
            .collect();
        for (i, (c, d)) in shown.iter().enumerate() {
            self.emit(Event::ToolCall {
                step,
                index: i,
                name: c.name.clone(),
                arguments: c.arguments.clone(),
                decision: d.clone(),
            });
        }
        let (calls, decisions): (Vec<ToolCall>, Vec<Decision>) = shown.into_iter().unzip();
        let t_tools = Instant::now();
        // A stop the request did not ask for (a small model reaches for the tool it was
        // always shown) still brakes the robot, but does not latch the e-stop: the
        // operator's words, `/stop`, Ctrl-C and the ROS topic latch it.
        let unasked = |c: &ToolCall| {
            c.name == STOP_TOOL && !crate::reading::concepts::operator_stops(self.query)
        };
        let (run_calls, run_decisions): (Vec<ToolCall>, Vec<Decision>) = calls
            .iter()
            .zip(&decisions)
            .filter(|(c, _)| !unasked(c))
            .map(|(c, d)| (c.clone(), d.clone()))
            .unzip();
        // Each run call's place among the calls shown, for its progress events.
        let shown_at: Vec<usize> = (0..calls.len()).filter(|&i| !unasked(&calls[i])).collect();
        let (events, agent) = (&mut self.events, &*self.agent);
        // A message reported (an action's feedback) in one line, as results are.
        let mut on_progress = |i: usize, report: Value| {
            let text = match report {
                Value::String(text) => text,
                message => facts::summarize(&message).unwrap_or_else(|| message.to_string()),
            };
            events(&Event::ToolProgress {
                step,
                index: shown_at[i],
                name: run_calls[i].name.clone(),
                text,
            })
        };
        let mut ran = agent
            .exec
            .run(&run_calls, &run_decisions, &agent.cancel, &mut on_progress)
            .into_iter();
        let mut outcomes = Vec::with_capacity(calls.len());
        for (c, d) in calls.iter().zip(&decisions) {
            if unasked(c) {
                outcomes.push(self.brake_unasked(d.clone()));
            } else if let Some(o) = ran.next() {
                outcomes.push(o);
            }
        }
        self.timings.tools_ms += t_tools.elapsed().as_secs_f64() * 1e3;
        self.scratch.push(ChatMessage::new(
            Role::Assistant,
            self.agent.config.envelope.render_calls(&calls),
        ));
        let mut done = false;
        for (i, (call, o)) in calls.into_iter().zip(outcomes).enumerate() {
            done |= self.observe(step, i, call, o);
        }
        done
    }

    /// `robot_stop` on a request that asked no stop: brake without latching, and offer
    /// the tool no more this run.
    fn brake_unasked(&mut self, decision: Decision) -> Outcome {
        let t = Instant::now();
        let estop = self.agent.exec.policy().estop().clone();
        estop.halt("the agent (robot_stop, not asked by the operator)");
        self.stop_withdrawn = true;
        Outcome {
            output: serde_json::json!({"braked": true, "latched": false,
                "summary": "The robot was braked. The operator's request did not ask to stop, so motion is not locked: go on with what the operator asked."}),
            ok: true,
            ms: t.elapsed().as_secs_f64() * 1e3,
            decision,
        }
    }

    /// Append what came of one call; whether it is done (it ran, or was refused).
    fn observe(&mut self, step: usize, index: usize, call: ToolCall, o: Outcome) -> bool {
        let Outcome {
            output,
            ok,
            ms,
            decision,
        } = o;
        let output = if ok {
            facts::with_summary(output)
        } else {
            output
        };
        // A brake answers no request: it is not what an answer is held to.
        let answers = ok && call.name != STOP_TOOL;
        if let Some(summary) = output
            .get("summary")
            .and_then(Value::as_str)
            .filter(|_| answers)
        {
            self.grounds.push((call.name.clone(), summary.to_string()));
        }
        self.emit(Event::ToolResult {
            step,
            index,
            name: call.name.clone(),
            output: output.clone(),
            ok,
            ms,
        });
        let shown = truncate_output(&to_json_spaced(&output), self.agent.config.output_chars);
        let came = match (&decision, ok) {
            (_, true) => Came::Ran,
            (Decision::Refused(_), false) if self.turned_down.contains(&call) => Came::TurnedDown,
            (Decision::Refused(_), false) => Came::Refused,
            (_, false) => Came::Failed,
        };
        // A refused call is as done as a successful one: asking again gets the same.
        let done = came.done();
        self.guards.observe(&call, came, &shown);
        self.copy_from.push(shown.clone());
        // A run that ends without an answer says this one in a line: its summary, or a
        // failure's error, not the JSON the model reads.
        self.last_observation = output
            .get("summary")
            .or_else(|| output.get("error"))
            .and_then(Value::as_str)
            .map_or_else(|| shown.clone(), str::to_string);
        // A guard's refusal speaks to the model ("answer instead"), not the operator.
        if matches!(came, Came::Refused | Came::Failed) && self.part_failure.is_none() {
            self.part_failure = Some(self.last_observation.clone());
        }
        self.scratch.push(ChatMessage::tool(&call.name, shown));
        let mut arguments = call.arguments;
        self.agent.exec.policy().redact(&mut arguments);
        self.records.push(StepRecord {
            step,
            name: call.name,
            arguments,
            output,
            ok,
            ms,
            decision,
        });
        done
    }

    /// The run's result, with what is known when there is no answer.
    fn end(mut self, finish: Finish) -> RunResult {
        match finish {
            Finish::MaxSteps if self.answer.is_empty() => {
                self.answer = format!(
                    "{} {}",
                    self.language
                        .say(Phrase::StoppedAfter(self.agent.config.max_steps)),
                    answer::last_result(&self.last_observation, self.language)
                );
            }
            Finish::Cancelled => {
                self.answer = format!(
                    "{} {}",
                    self.language.say(Phrase::Cancelled),
                    answer::last_result(&self.last_observation, self.language)
                );
            }
            _ => {}
        }
        self.answer = self
            .agent
            .exec
            .policy()
            .redact_text(&self.answer)
            .into_owned();
        self.timings.total_ms = self.start.elapsed().as_secs_f64() * 1e3;
        self.emit(Event::Answer {
            text: self.answer.clone(),
            finish: format!("{finish:?}").to_lowercase(),
        });
        if finish == Finish::Answer {
            self.agent.history.push(self.query, self.answer.clone());
        }
        if let Some(t) = &mut self.agent.trace {
            t.record(
                "timings",
                serde_json::to_value(&self.timings).unwrap_or_default(),
            );
        }
        let result = RunResult {
            answer: self.answer,
            finish,
            steps: self.records,
            timings: self.timings,
            tools_offered: self.offered.iter().map(|s| s.name.clone()).collect(),
        };
        if let Some(journal) = &mut self.agent.journal {
            journal(self.query, &result);
        }
        result
    }

    /// The `allowed` tools (all offered when `None`) as the robot takes them now
    /// (`Tool::live_parameters`), and those of them the guards would write, their name
    /// arguments held to the names that exist (`bound`).
    fn writable(
        &self,
        allowed: Option<&Vec<String>>,
        robot_names: &[(String, String)],
        near: Option<&dyn Fn(&str) -> f64>,
    ) -> (Vec<ToolSpec>, Vec<ToolSpec>) {
        let registry = self.agent.exec.registry();
        let live: Vec<ToolSpec> = self
            .offered
            .iter()
            .filter(|s| allowed.is_none_or(|names| names.contains(&s.name)))
            .map(|s| {
                registry
                    .get(&s.name)
                    .and_then(|t| t.live_spec())
                    .unwrap_or_else(|| s.clone())
            })
            .collect();
        let mut bound = bound::bind(&live, robot_names, &self.parts[self.part], near);
        // Nor is one that would name a thing of a kind the robot has none of.
        bound.retain(|b| !bound::reaches_nothing(b, robot_names, &self.parts[self.part]));
        // A tool every call of which the guards would refuse is not written.
        bound.retain(|b| {
            self.offered
                .iter()
                .find(|s| s.name == b.name)
                .is_none_or(|declared| self.guards.keeps(declared, b))
        });
        (live, bound)
    }

    /// The request as the model reads it: with a note of the answer's language when that
    /// is not the prompt's, and the names of the tools that fit when not every tool is
    /// offered.
    fn first_message(&self) -> String {
        let first = match self.language.note() {
            Some(note) => format!("{}\n{note}", self.parts[0]),
            None => self.parts[0].clone(),
        };
        if self.listed.len() > self.offered.len() {
            let fit: Vec<&str> = self
                .offered
                .iter()
                .map(|s| s.name.as_str())
                .filter(|n| !self.agent.config.always_on.iter().any(|a| a == n))
                .take(HINTED)
                .collect();
            if !fit.is_empty() {
                return format!("{first}\n(Tools that fit: {}.)", fit.join(", "));
            }
        }
        first
    }

    /// The tools a turn's grammar allows, as the robot can take them now, and on a part's
    /// first step (`fresh`: nothing since the operator's words but the part itself) the
    /// names of those that take a name the part writes.
    fn turn_specs(
        &self,
        allowed: Option<Vec<String>>,
        robot_names: &[(String, String)],
        near: Option<&dyn Fn(&str) -> f64>,
        fresh: bool,
    ) -> (Vec<ToolSpec>, Vec<String>) {
        let (allowed_specs, bound_specs) = self.writable(allowed.as_ref(), robot_names, near);
        // The act-first preference, when it leaves nothing the other guards would write
        // (words that ask for an act no call of which the request asks for: "list the
        // places you can go to"), is passed over, as `Guards::narrow` passes over a guard
        // that leaves nothing.
        let only_answer = bound_specs.iter().all(|s| s.name == ANSWER_TOOL);
        let (allowed_specs, bound_specs) =
            if only_answer && !self.answer_only && self.grounds.is_empty() {
                let mut wider = self
                    .guards
                    .narrow_without(&self.offered, "act-first")
                    .unwrap_or_else(|| self.offered.iter().map(|s| s.name.clone()).collect());
                if self.stop_withdrawn {
                    wider.retain(|n| n != STOP_TOOL);
                }
                self.writable(Some(&wider), robot_names, near)
            } else {
                (allowed_specs, bound_specs)
            };
        // On it, which tools take a name the part writes, as the robot has them (before
        // `bind` adds a written name the robot lacks to every argument of its kind).
        let taking: Vec<String> = if fresh {
            let takes = crate::reading::select::takes_written(
                &self.parts[self.part],
                &allowed_specs,
                &self.offered,
            );
            allowed_specs
                .iter()
                .zip(takes)
                .filter(|(_, t)| *t)
                .map(|(s, _)| s.name.clone())
                .collect()
        } else {
            Vec::new()
        };
        let mut allowed_specs = bound_specs;
        // An answer with no call before it is the agent's own (`small_talk`): the model's
        // text would be thrown away, so it writes one character of it, not up to
        // `ANSWER_CHARS` (a thank-you took 9.6 s writing a reply nobody read).
        if self.records.is_empty() && self.agent.meaning.is_some() {
            for spec in allowed_specs.iter_mut().filter(|s| s.name == ANSWER_TOOL) {
                if let Some(text) = spec.parameters.pointer_mut("/properties/text") {
                    text["maxLength"] = serde_json::json!(1);
                }
            }
        }
        (allowed_specs, taking)
    }

    /// Decode one turn with `allowed` tools (all offered when `None`), tokens streamed
    /// as events as they come.
    fn turn(
        &mut self,
        allowed: Option<Vec<String>>,
        robot_names: &[(String, String)],
    ) -> Result<TurnResult, DecodeError> {
        let first = self.first_message();
        let messages = self.agent.context(&first, &self.scratch, &self.listed)?;
        // The grammar takes each tool's arguments as the robot can take them now
        // (`Tool::live_parameters`), name arguments held to the names that exist
        // (`bound`).
        let part = self.parts[self.part].clone();
        // A later part is read with the one before it too, for what it refers back to
        // ("tare the wrist sensor and show it once more": "it" is the sensor's topic); the
        // nearer of the two readings counts.
        let with_before =
            (self.part > 0).then(|| format!("{} {}", self.parts[self.part - 1], part));
        let meaning = self.agent.meaning.clone();
        let near = meaning.as_ref().map(|m| {
            move |name: &str| {
                let own = m.name_similarity(&part, name);
                with_before
                    .as_deref()
                    .map_or(own, |w| own.max(m.name_similarity(w, name)))
            }
        });
        let near = near.as_ref().map(|f| f as &dyn Fn(&str) -> f64);
        let fresh = self.scratch.last().is_none_or(|m| m.role == Role::User);
        let (allowed_specs, taking) = self.turn_specs(allowed, robot_names, near, fresh);
        let sources: Vec<&str> = self.copy_from.iter().map(String::as_str).collect();
        let candidates: Vec<&str> = allowed_specs.iter().map(|s| s.name.as_str()).collect();
        let takes: Vec<bool> = candidates
            .iter()
            .map(|c| taking.iter().any(|t| t == c))
            .collect();
        let pick = fresh.then_some((
            self.parts[self.part].as_str(),
            candidates.as_slice(),
            takes.as_slice(),
        ));
        let mut pipeline = self.agent.pipeline(&sources, pick, robot_names);
        let req = self
            .agent
            .request(&messages, &self.listed, Some(&allowed_specs));
        let cancel = self.agent.cancel.clone();
        let start = self.start;
        self.step_first_token = None;
        let first = &mut self.timings.first_token_ms;
        let step_first = &mut self.step_first_token;
        let events = &mut *self.events;
        let mut words = super::event::WordStream::new(self.agent.exec.policy().fence().clone());
        let agent = &mut *self.agent;
        let mut sampler = Sampler::new(agent.config.sampler, agent.backend.vocab().len());
        let mut engine = Engine {
            backend: agent.backend.as_mut(),
            session: &mut agent.session,
            grammars: &agent.grammars,
            sampler: &mut sampler,
            remote: agent.remote.as_mut(),
            draft: agent.config.draft,
        };
        let result = crate::turn::run(
            &mut engine,
            &req,
            &mut pipeline,
            Some(ANSWER_TOOL),
            &mut |piece: &str| {
                let now = Some(start.elapsed().as_secs_f64() * 1e3);
                if first.is_none() {
                    *first = now;
                }
                if step_first.is_none() {
                    *step_first = now;
                }
                let text = words.push(piece);
                if !text.is_empty() {
                    events(&Event::Token { text });
                }
                if cancel.load(Ordering::SeqCst) {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            },
        );
        let rest = words.finish();
        if !rest.is_empty() {
            events(&Event::Token { text: rest });
        }
        result
    }
}
