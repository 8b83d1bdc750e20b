//! The agent's own thread: it takes the console's jobs one at a time (a request, or
//! forgetting the conversation) and publishes every event of a run as it happens.

use std::sync::mpsc::Receiver;

use serde_json::json;

use super::hub::Hub;
use crate::agent::Agent;
use crate::reading::language::Language;

/// What the agent's thread is asked to do.
pub(crate) enum Job {
    Ask {
        run: u64,
        text: String,
        language: Option<Language>,
    },
    Clear,
}

/// The agent's thread: one job at a time, its events published as they happen.
pub fn work(mut agent: Agent, hub: &Hub, queue: &Receiver<Job>) {
    let set = agent.config.language;
    for job in queue {
        match job {
            Job::Ask {
                run,
                text,
                language,
            } => {
                agent.config.language = language.or(set);
                let result = agent.ask(&text, &mut |e| {
                    let mut v = serde_json::to_value(e).unwrap_or_default();
                    v["run"] = json!(run);
                    // A page that joins later needs neither the tokens (the answer
                    // has them) nor a finished call's progress.
                    let keep = !matches!(
                        e,
                        crate::agent::Event::Token { .. }
                            | crate::agent::Event::ToolProgress { .. }
                    );
                    hub.publish("agent", &v, keep);
                });
                let done = match result {
                    Ok(r) => json!({"run": run, "finish": r.finish, "timings": r.timings,
                                    "calls": r.steps.len()}),
                    Err(e) => json!({"run": run, "error": e.to_string()}),
                };
                hub.publish("done", &done, true);
            }
            Job::Clear => {
                agent.clear();
                hub.publish("cleared", &json!({}), true);
            }
        }
        hub.release();
    }
}
