//! How an agent runs: step and token limits, the envelope, decoding, answering, the
//! budgets of its context, and the strategies it uses.

use super::answer::ANSWER_TOOL;
use crate::reading::language::Language;

use crate::decode::envelope::Envelope;
use crate::decode::{Decoding, Draft, SamplerConfig};
pub use crate::tool::STOP_TOOL;

/// How the model ends a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AnswerMode {
    /// Every turn is a call; answering is the `reply` tool. Small models follow a
    /// forced structure far better than they decide between prose and a call.
    #[default]
    Tool,
    /// The model may answer in prose (tool choice `auto`).
    Prose,
    /// Calls only, or an empty call list when no tool fits (tool choice `decline`).
    Decline,
}

/// How the first step of a request, or of a part of one (`plan`), picks its tool
/// (`strategy::choice`; constrained decoding only). Later steps decode the name as the
/// model writes it: whether the work is done is for the model to say.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pick {
    /// The model's likeliest name.
    Likeliest,
    /// The name the request raised most over a content-free request. On, a request to
    /// average a few numbers is answered without a tool (the README has the ROS suite
    /// with it).
    Calibrated,
    /// The model's log-probability of each name, weighed with the tool retrieval's
    /// score of the tool for the request (`select::prior`).
    #[default]
    Weighed,
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
    /// Tokens the system prompt's tool listing may take with every tool in it. Within
    /// it, every request's prompt lists all the tools in one order (the grammar still
    /// holds each step to the tools it is offered), so the prompt before the request is
    /// the same each time and the KV and prompt caches keep it: a request evaluates its
    /// own words, not a listing of its own. Beyond it, or at 0 (this struct's default;
    /// the command line's `--listing all` sets a budget), a prompt lists the tools its
    /// request is offered.
    pub listing_budget_tokens: usize,
    /// Tools always offered when selecting.
    pub always_on: Vec<String>,
    /// Characters of a tool's output shown to the model.
    pub output_chars: usize,
    /// Logit bonus for argument values that copy what the operator said or a tool
    /// returned this run (see `strategy::copy`); 0 turns it off.
    pub copy_bias: f32,
    /// How the first step of a request (and of each of its parts) picks its tool.
    pub pick: Pick,
    /// Once a result is in and the answer is all that may follow, the answer is that
    /// result (`facts`), with no model turn; off, the model writes it (a benchmark of
    /// the model's own answers, a script that gives every turn its answer).
    pub composed_answers: bool,
    /// The language answers are written in; `None`: each request's own
    /// (`language::Language::of`).
    pub language: Option<Language>,
    pub sampler: SamplerConfig,
    /// How far local decoding guesses ahead (`decode::draft`; the text is the same).
    pub draft: Draft,
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
            listing_budget_tokens: 0,
            always_on: vec![ANSWER_TOOL.to_string(), STOP_TOOL.to_string()],
            output_chars: 1500,
            copy_bias: 0.0,
            pick: Pick::default(),
            composed_answers: true,
            language: None,
            sampler: SamplerConfig::default(),
            draft: Draft::default(),
        }
    }
}
