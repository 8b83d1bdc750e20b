//! Tool-calling evaluation: Berkeley Function Calling Leaderboard files run through the
//! model one assistant turn per question (the real grammar and decode path), scored as
//! BFCL's AST checker does, reported per category with validity, latency and speed.
//!
//! Layout:
//! - `bfcl`: reading BFCL files and answers, Python-typed docs to JSON schema
//! - `score`: the checker (names, required parameters, allowed values, parallel order)
//! - `ros`: the ROS task suite (agent episodes on the sim): cases and their checker
//! - `speech`: speech recognition on spoken operator requests (word error rate)

pub mod bfcl;
pub mod ros;
pub mod score;
#[cfg(feature = "candle")]
pub mod speech;

use std::ops::ControlFlow;
use std::time::Instant;

use serde::Serialize;

use crate::agent::{answer_spec, AnswerMode, ANSWER_TOOL};
use crate::backend::{Backend, Vocab};
use crate::chat::{ChatMessage, Role};
use crate::decode::envelope::{Envelope, ToolChoice};
use crate::decode::request::TurnRequest;
use crate::decode::{DecodeError, Decoding, Draft, Grammars, Sampler, SamplerConfig, Session};
use crate::strategy::choice::Calibrated;
use crate::strategy::copy::{defaults, CopyBias, CopyIndex};
use crate::strategy::ground::Grounding;
use crate::strategy::repeats::{LoopGuard, RepeatGuard};
use crate::strategy::verify::Verification;
use crate::strategy::Pipeline;
use crate::tool::{ToolCall, ToolSpec};
use crate::turn::{run, Engine};
use bfcl::Case;

/// The system message of every BFCL question (the tool list is appended to it).
pub const SYSTEM: &str = "You are a function-calling assistant. If the request matches a function, call it with the values from the request. If no function fits, answer in plain text.";

#[derive(Debug, Clone, Serialize)]
pub(crate) struct CaseResult {
    pub id: String,
    pub category: String,
    pub decoding: String,
    pub pass: bool,
    pub reason: Option<String>,
    /// Did the model try to call (the envelope's marker appeared)?
    pub attempted_call: bool,
    /// Did what it wrote parse into calls valid for their schemas?
    pub valid_call: bool,
    pub calls: Vec<ToolCall>,
    pub text: String,
    pub ms: f64,
    pub generated_tokens: usize,
    pub tok_per_s: f64,
}

/// How a BFCL turn may end.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TurnRules {
    /// How the model answers instead of calling.
    pub answer_mode: AnswerMode,
    /// The case's functions only and a call required: the model cannot answer (BFCL's
    /// "forced" setting; `answer_mode` is then unused).
    pub force_call: bool,
    /// Decide the turn with the relevance gate (`AnswerMode::Tool`, or with
    /// `force_call`, where it picks the function and the list's length but never
    /// answers).
    pub relevance_gate: bool,
    /// The copy bias's logit bonus for argument values that copy the question (0: off).
    pub copy_bias: f32,
    /// Drop optional string and number arguments that neither the question spells nor
    /// their schema declares as the default, as the agent does before a call runs
    /// (`strategy::ground`; the agent holds strings only to it).
    pub ground: bool,
    /// How far decoding guesses ahead (`decode::draft`; the text is the same).
    pub draft: Draft,
}

impl TurnRules {
    /// The strategies a BFCL turn runs with under these rules.
    pub fn pipeline(&self, vocab: &Vocab, specs: &[ToolSpec], questions: &[&str]) -> Pipeline {
        let mut p = Pipeline::new();
        let last = questions.last().copied().unwrap_or_default();
        if self.gated() {
            p = p
                .with(Calibrated { lists: true })
                .with(Verification::new(last, specs))
                .with(RepeatGuard::new(last));
        }
        if self.copy_bias > 0.0 {
            let index = CopyIndex::new(
                vocab,
                questions,
                &defaults(specs),
                self.copy_bias,
                Some(ANSWER_TOOL),
            );
            p = p.with(CopyBias::new(index)).with(LoopGuard::new(vocab));
        }
        p
    }

    /// Under a forced call the answer tool is not offered, so the gate has no fallback.
    fn gated(&self) -> bool {
        self.relevance_gate && (self.force_call || self.answer_mode == AnswerMode::Tool)
    }
}

/// Run one case: one assistant turn with the case's functions, where the model may call
/// or answer (unless `rules.force_call`). With `AnswerMode::Tool` (the agent's default)
/// answering is the `answer` pseudo-function, so the turn is always structured; its call
/// is not counted as a call.
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_case(
    backend: &mut dyn Backend,
    session: &mut Session,
    grammars: &Grammars,
    remote: Option<&mut crate::remote::Remote>,
    envelope: Envelope,
    decoding: Decoding,
    rules: TurnRules,
    case: &Case,
) -> Result<CaseResult, DecodeError> {
    let messages = case_messages(case);
    let mut specs = case.functions.clone();
    let choice = match rules.answer_mode {
        _ if rules.force_call => ToolChoice::Required,
        AnswerMode::Tool => {
            specs.push(answer_spec());
            ToolChoice::Required
        }
        AnswerMode::Prose => ToolChoice::Auto,
        AnswerMode::Decline => ToolChoice::Decline,
    };
    let questions: Vec<&str> = messages
        .iter()
        .filter(|m| m.role == Role::User)
        .map(|m| m.content.as_str())
        .collect();
    let req = TurnRequest {
        messages: &messages,
        specs: &specs,
        allowed: None,
        envelope,
        choice,
        parallel: true,
        decoding,
        // Room for the longest answer text (240 characters can be 240 digit tokens).
        max_tokens: 320,
    };
    let mut pipeline = match decoding {
        Decoding::Constrained => rules.pipeline(backend.vocab(), &specs, &questions),
        Decoding::Free => Pipeline::new(),
    };
    let fallback = (rules.gated() && !rules.force_call).then_some(ANSWER_TOOL);
    let mut sampler = Sampler::new(SamplerConfig::default(), backend.vocab().len());
    let start = Instant::now();
    let mut engine = Engine {
        backend,
        session,
        grammars,
        sampler: &mut sampler,
        remote,
        draft: rules.draft,
    };
    let r = match run(&mut engine, &req, &mut pipeline, fallback, &mut |_| {
        ControlFlow::Continue(())
    }) {
        // A question whose functions give no grammar fails alone; the run goes on.
        Err(DecodeError::Constraint(e)) => {
            tracing::warn!(case = %case.id, "no grammar for this case: {e}");
            let ms = start.elapsed().as_secs_f64() * 1e3;
            return Ok(no_grammar(case, decoding, &e.to_string(), ms));
        }
        r => r?,
    };
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let attempted_call = match envelope {
        Envelope::Json => r.text.trim_start().starts_with('{'),
        _ => r.text.contains("<tool_call>"),
    } && !matches!(&r.turn, Ok(t) if t.calls.iter().all(|c| c.name == ANSWER_TOOL));
    let (calls, valid_call, verdict) = score_turn(case, &r.turn, rules.ground, &questions);
    Ok(CaseResult {
        id: case.id.clone(),
        category: case.category.clone(),
        decoding: format!("{decoding:?}").to_lowercase(),
        pass: verdict.passed(),
        reason: match verdict {
            score::Verdict::Pass => None,
            score::Verdict::Fail(w) => Some(w),
        },
        attempted_call,
        valid_call,
        calls,
        text: r.text,
        ms,
        generated_tokens: r.stats.generated_tokens,
        tok_per_s: r.stats.output_tok_per_s(),
    })
}

/// A case whose functions give no grammar: failed, with no turn.
fn no_grammar(case: &Case, decoding: Decoding, error: &str, ms: f64) -> CaseResult {
    CaseResult {
        id: case.id.clone(),
        category: case.category.clone(),
        decoding: format!("{decoding:?}").to_lowercase(),
        pass: false,
        reason: Some(format!("grammar: {error}")),
        attempted_call: false,
        valid_call: false,
        calls: Vec::new(),
        text: String::new(),
        ms,
        generated_tokens: 0,
        tok_per_s: 0.0,
    }
}

/// The case's conversation after the evaluation's system message (a case's own system
/// text joins it).
fn case_messages(case: &Case) -> Vec<ChatMessage> {
    let mut messages = vec![ChatMessage::new(Role::System, SYSTEM)];
    for (role, content) in &case.messages {
        let role = match role.as_str() {
            "system" => Role::System,
            "assistant" => Role::Assistant,
            _ => Role::User,
        };
        if role == Role::System {
            messages[0].content = format!("{}\n{content}", messages[0].content);
        } else {
            messages.push(ChatMessage::new(role, content.clone()));
        }
    }
    messages
}

/// A turn's calls (the answer pseudo-call left out; with `ground`, arguments the
/// questions do not ground dropped), whether there are any, and the verdict.
fn score_turn(
    case: &Case,
    turn: &Result<crate::decode::Turn, crate::decode::envelope::EnvelopeError>,
    ground: bool,
    questions: &[&str],
) -> (Vec<ToolCall>, bool, score::Verdict) {
    match turn {
        Ok(turn) => {
            let mut calls: Vec<ToolCall> = turn
                .calls
                .iter()
                .filter(|c| c.name != ANSWER_TOOL)
                .cloned()
                .collect();
            if ground {
                let grounding = Grounding::new(questions.iter().copied()).with_numbers();
                for c in &mut calls {
                    if let Some(spec) = case.functions.iter().find(|s| s.name == c.name) {
                        grounding.drop_ungrounded(c, spec);
                    }
                }
            }
            let v = score::check(case, &calls);
            let valid = !calls.is_empty();
            (calls, valid, v)
        }
        Err(e) => (
            Vec::new(),
            false,
            score::Verdict::Fail(format!("unparseable turn: {e}")),
        ),
    }
}

/// Per category and decoding mode.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub category: String,
    pub decoding: String,
    pub cases: usize,
    pub accuracy: f64,
    /// Of the turns that attempted a call, the share that parsed into schema-valid calls.
    pub valid_call_rate: Option<f64>,
    pub mean_ms: f64,
    pub p95_ms: f64,
    pub tok_per_s: f64,
}

pub(crate) fn summarize(results: &[CaseResult]) -> Vec<Summary> {
    let mut keys: Vec<(String, String)> = results
        .iter()
        .map(|r| (r.category.clone(), r.decoding.clone()))
        .collect();
    keys.dedup();
    keys.sort();
    keys.dedup();
    keys.into_iter()
        .map(|(category, decoding)| {
            let rs: Vec<&CaseResult> = results
                .iter()
                .filter(|r| r.category == category && r.decoding == decoding)
                .collect();
            let n = rs.len().max(1) as f64;
            let attempted: Vec<&&CaseResult> = rs.iter().filter(|r| r.attempted_call).collect();
            let mut ms: Vec<f64> = rs.iter().map(|r| r.ms).collect();
            ms.sort_by(f64::total_cmp);
            Summary {
                category,
                decoding,
                cases: rs.len(),
                accuracy: rs.iter().filter(|r| r.pass).count() as f64 / n,
                valid_call_rate: (!attempted.is_empty()).then(|| {
                    attempted.iter().filter(|r| r.valid_call).count() as f64
                        / attempted.len() as f64
                }),
                mean_ms: ms.iter().sum::<f64>() / n,
                p95_ms: ms
                    .get(((ms.len() as f64 - 1.0) * 0.95).round() as usize)
                    .copied()
                    .unwrap_or(0.0),
                tok_per_s: rs.iter().map(|r| r.tok_per_s).sum::<f64>() / n,
            }
        })
        .collect()
}

/// One row per decoding mode over every category ("all").
pub(crate) fn summarize_overall(results: &[CaseResult]) -> Vec<Summary> {
    let all: Vec<CaseResult> = results
        .iter()
        .cloned()
        .map(|mut r| {
            r.category = "all".into();
            r
        })
        .collect();
    summarize(&all)
}

/// A markdown table, decoding modes side by side per category.
pub fn markdown(summaries: &[Summary]) -> String {
    let mut out = String::from(
        "| category | decoding | cases | accuracy | valid calls | mean ms | p95 ms | tok/s |\n|---|---|---|---|---|---|---|---|\n",
    );
    for s in summaries {
        out.push_str(&format!(
            "| {} | {} | {} | {:.1}% | {} | {:.0} | {:.0} | {:.1} |\n",
            s.category,
            s.decoding,
            s.cases,
            100.0 * s.accuracy,
            s.valid_call_rate
                .map_or("-".into(), |v| format!("{:.1}%", 100.0 * v)),
            s.mean_ms,
            s.p95_ms,
            s.tok_per_s
        ));
    }
    out
}
