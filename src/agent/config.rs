//! How an agent runs: step and token limits, the envelope, decoding, answering, the
//! budgets of its context, and the strategies it uses.

use super::answer::ANSWER_TOOL;

/// The e-stop tool (`tools::stop`), offered whatever the request.
pub const STOP_TOOL: &str = "robot_stop";
use crate::decode::envelope::Envelope;
use crate::decode::{Decoding, SamplerConfig};

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
    /// returned this run (see `strategy::copy`); 0 turns it off.
    pub copy_bias: f32,
    /// Which tool a run's first step calls is decided by what the request raised in
    /// the model's likelihoods over a content-free request (`strategy::choice`), not by
    /// the likeliest name alone. Off by default: on, "what is the mean of 3, 5 and 10?"
    /// is answered without a tool (the README has the ROS suite with it).
    pub calibrated_choice: bool,
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
            always_on: vec![ANSWER_TOOL.to_string(), STOP_TOOL.to_string()],
            output_chars: 1500,
            copy_bias: 0.0,
            calibrated_choice: false,
            sampler: SamplerConfig::default(),
        }
    }
}
