//! The ReAct agent: reason (one constrained assistant turn), act (run the calls, in
//! parallel, through the guards and the policy), observe (results appended as tool
//! messages), repeated until the model answers, the step limit, or cancellation.
//!
//! It sees the model only through `Backend` and the world only through `tool`: it never
//! imports `ros` or a concrete tool.
//!
//! Context, in the order the model reads it: the robot system prompt with the tool specs
//! (one system message, stable across steps and turns so the KV cache keeps it), the chat
//! history (trimmed oldest pair first to the budget), the new query, then this run's
//! scratchpad (the calls made and what they returned).
//!
//! What a request says is read without a model in `crate::reading`; the model's turn is
//! decoded by `crate::turn`.
//!
//! Layout:
//! - `state`: the `Agent` between requests (model, session, tools, policy, history) and
//!   what a run asks of it
//! - `run`: one request as a state machine (think → guards → policy → act → observe)
//! - `guard`: the guards between the model's turn and the policy, in order
//! - `said_order`: the guard that holds a route to the order the request names it in
//! - `config`: limits, budgets and modes
//! - `outcome`: what a run returns (answer, finish, calls, timings)
//! - `answer`: the `reply` pseudo-tool and the answer as the operator reads it
//! - `prompt`: robot system prompts (ROSA's fields) from TOML
//! - `history`: the conversation's exchanges, trimming, output truncation
//! - `event`: the typed event stream every front end consumes
//! - `trace`: JSONL session traces

pub mod answer;
pub mod config;
pub mod event;
pub mod guard;
pub mod history;
pub mod outcome;
pub mod prompt;
mod run;
mod said_order;
mod state;
pub mod trace;

use std::sync::atomic::Ordering;
use std::time::Instant;

use serde_json::json;

pub use answer::{answer_spec, ANSWER_TOOL};
pub use config::{AgentConfig, AnswerMode};
pub use event::Event;
pub use outcome::{AgentError, Finish, RunResult, StepRecord, Timings};
pub use state::{Agent, Journal, NameSource};

/// What a run's arguments may copy from among the operator's words (`queries`, this
/// session's, the current one last): the current request whole, and the earlier ones
/// without their numbers. A name said before ("echo it") is still there to copy; an
/// amount said before is not: "turn 60 degrees" after "turn 90 degrees" copied 90, and
/// "go back half a meter" after "rotate 30 degrees" drove 3 m.
fn copy_sources(queries: &[String]) -> Vec<String> {
    let Some((current, earlier)) = queries.split_last() else {
        return Vec::new();
    };
    let is_number = |w: &str| {
        w.trim_matches(|c: char| !c.is_ascii_alphanumeric())
            .parse::<f64>()
            .is_ok()
    };
    earlier
        .iter()
        .map(|q| {
            q.split_whitespace()
                .filter(|w| !is_number(w))
                .collect::<Vec<_>>()
                .join(" ")
        })
        .chain([current.clone()])
        .collect()
}

impl Agent {
    /// Answer `query`: reason, act and observe until an answer, the step limit or
    /// cancellation. Tool failures are observations; only a broken model runtime is an
    /// error. `events` sees every event as it happens.
    pub fn ask(
        &mut self,
        query: &str,
        events: &mut dyn FnMut(&Event),
    ) -> Result<RunResult, AgentError> {
        self.cancel.store(false, Ordering::SeqCst);
        let start = Instant::now();
        let engaged_at = self.exec.policy().estop().engaged_by().map(|e| e.at);
        let mut offered = self.offered_tools(query);
        let queries: Vec<String> = self
            .history
            .queries()
            .into_iter()
            .map(str::to_string)
            .chain([query.to_string()])
            .collect();
        let said: Vec<&str> = queries.iter().map(String::as_str).collect();
        let asked = self.config.asked_actuation_only.then(|| {
            let registry = self.exec.registry();
            self.asked
                .clone()
                .with_known(|name| Some(registry.get(name)?.live_spec()?.parameters))
        });
        let guards = guard::Guards::standard(query, &said, asked);
        let parts =
            crate::reading::plan::parts(query, &crate::reading::intent::vocabulary(&offered));
        // Each part is offered what it would be offered alone, beside what the whole
        // request is: "turn, then tell me where it points" needs the pose tool, which
        // the whole request's words point at less than at the turn.
        if parts.len() > 1 {
            for part in &parts {
                for spec in self.offered_tools(part) {
                    if !offered.iter().any(|s| s.name == spec.name) {
                        offered.push(spec);
                    }
                }
            }
        }
        let engine = self.engine();
        if let Some(t) = &mut self.trace {
            t.record(
                "query",
                json!({"query": query, "tools_offered": offered.iter().map(|s| &s.name).collect::<Vec<_>>(),
                       "tools_total": self.exec.registry().len(), "guards": guards.names(),
                       "engine": engine}),
            );
        }
        let language = crate::reading::language::Language::for_request(self.config.language, query);
        let listed = self.listed(&offered);
        run::Run {
            agent: self,
            query,
            events,
            start,
            offered,
            listed,
            guards,
            scratch: Vec::new(),
            records: Vec::new(),
            timings: Timings::default(),
            answer: String::new(),
            last_observation: String::new(),
            grounds: Vec::new(),
            earlier_grounds: Vec::new(),
            copy_from: copy_sources(&queries),
            answer_only: false,
            step_first_token: None,
            stop_withdrawn: false,
            parts,
            part: 0,
            partial_answers: Vec::new(),
            language,
            part_failure: None,
            engaged_at,
            turned_down: Vec::new(),
        }
        .run()
    }
}

#[cfg(test)]
mod tests {
    use super::copy_sources;

    #[test]
    fn numbers_said_before_are_not_copied_names_are() {
        let q = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let sources = copy_sources(&q(&[
            "lift the arm 40 cm, then wait 2.5 s",
            "echo /arm2/state",
            "now lower it",
        ]));
        assert_eq!(
            sources,
            [
                "lift the arm cm, then wait s",
                "echo /arm2/state",
                "now lower it"
            ]
        );
        // The current request keeps its own numbers.
        assert_eq!(copy_sources(&q(&["open it 15 mm"])), ["open it 15 mm"]);
        assert!(copy_sources(&[]).is_empty());
    }
}
