//! Running calls: the one path every call takes after the policy, whoever asked for it
//! (the agent's model, `ferrosa call`, a front end). Allowed calls run concurrently,
//! each under the policy's time limit; all of them are aborted the moment the e-stop is
//! engaged or the run is cancelled (a call's future is dropped where it stands, so a
//! motion loop stops sending); an aborted call's error says what it last reported (a
//! drive: the leg, where it was and how far it had to go). Every output, result or error, is redacted by the fence
//! before anyone sees it, and a result the ROS boundary clamped is marked as such.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde_json::{json, Value};

use super::{Decision, Effect, Policy, Progress, Registry, ToolCall, ToolContext, ToolError};

/// Why a call aborted by the e-stop stopped (its error: "stopped: " and this).
const ESTOP_PRESSED: &str = "the e-stop was engaged";

/// Whether a call's `error` is that of a call the e-stop aborted.
pub(crate) fn stopped_by_estop(error: &str) -> bool {
    error
        .strip_prefix("stopped: ")
        .is_some_and(|why| why.starts_with(ESTOP_PRESSED))
}

/// What came of one call.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub output: Value,
    pub ok: bool,
    pub ms: f64,
    /// The decision as it stands after the call (`Clamped` when the boundary clamped it).
    pub decision: Decision,
}

/// Runs calls (see the module header).
pub struct Executor {
    registry: Registry,
    policy: Arc<Policy>,
    runtime: tokio::runtime::Runtime,
}

impl Executor {
    pub fn new(registry: Registry, policy: Arc<Policy>) -> std::io::Result<Executor> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()?;
        Ok(Executor {
            registry,
            policy,
            runtime,
        })
    }

    pub fn registry(&self) -> &Registry {
        &self.registry
    }

    pub fn policy(&self) -> &Arc<Policy> {
        &self.policy
    }

    /// The policy's decision on one call.
    pub fn decide(&self, call: &ToolCall) -> Decision {
        let tool = self.registry.get(&call.name).map(|t| t.as_ref());
        self.policy.check(tool, call)
    }

    /// One call through the policy and, if allowed, run: what `ferrosa call` does.
    pub fn call(&self, call: &ToolCall, cancel: &Arc<AtomicBool>) -> Outcome {
        let decision = self.decide(call);
        self.run(
            std::slice::from_ref(call),
            &[decision],
            cancel,
            &mut |_, _| {},
        )
        .pop()
        .expect("one call, one outcome")
    }

    /// Run the calls whose decision allows it, concurrently; outcomes in call order.
    /// Refused calls come back as their refusal. What a call reports of its progress
    /// goes to `on_progress` (the call's index, the report redacted) while it runs.
    pub fn run(
        &self,
        calls: &[ToolCall],
        decisions: &[Decision],
        cancel: &Arc<AtomicBool>,
        on_progress: &mut dyn FnMut(usize, Value),
    ) -> Vec<Outcome> {
        let (progress, mut reports) = tokio::sync::mpsc::unbounded_channel();
        let engaged_before = self.policy.estop().is_engaged();
        let handles: Vec<_> = calls
            .iter()
            .zip(decisions)
            .enumerate()
            .map(|(index, (call, decision))| {
                self.spawn(call, decision, Progress::to(index, progress.clone()))
            })
            .collect();
        // The calls hold the only senders: the reports end when the calls do.
        drop(progress);
        // A press of the e-stop (or the operator's cancel) during the run aborts every
        // running call but a stop.
        let abortable = self.abortable(calls);
        let aborts: Vec<_> = handles
            .iter()
            .zip(&abortable)
            .filter(|(_, a)| **a)
            .map(|(h, _)| h.abort_handle())
            .collect();
        let estop = self.policy.estop().clone();
        // Each call's latest report in words, for the error of a call aborted mid-way.
        let mut last: Vec<Option<String>> = vec![None; calls.len()];
        let results = self.runtime.block_on(async {
            // A report goes out redacted, and is kept as the call's latest in words.
            let mut pass_on = |index: usize, mut report: Value| {
                self.policy.redact(&mut report);
                if let (Some(said), Some(l)) = (report.as_str(), last.get_mut(index)) {
                    *l = Some(said.to_string());
                }
                on_progress(index, report);
            };
            let mut all = std::pin::pin!(futures::future::join_all(handles));
            let mut stop = std::pin::pin!(async {
                tokio::select! {
                    _ = estop.pressed() => ESTOP_PRESSED,
                    _ = cancelled(cancel) => "the operator cancelled the run",
                }
            });
            let (joined, why) = loop {
                tokio::select! {
                    r = &mut all => break (r, None),
                    why = &mut stop => {
                        aborts.iter().for_each(|a| a.abort());
                        // A cancel without the e-stop still leaves the robot stopped.
                        if !estop.is_engaged() {
                            estop.halt("the operator cancelled the run");
                        }
                        break ((&mut all).await, Some(why));
                    }
                    Some((index, report)) = reports.recv() => pass_on(index, report),
                }
            };
            // What was said just before the calls ended still comes before their results.
            while let Ok((index, report)) = reports.try_recv() {
                pass_on(index, report);
            }
            joined
                .into_iter()
                .zip(&last)
                .map(|(j, said)| j.map_err(|e| join_error(&e, why, said.as_deref())))
                .collect::<Vec<_>>()
        });
        let pressed = !engaged_before && self.policy.estop().is_engaged();
        results
            .into_iter()
            .zip(decisions)
            .zip(abortable)
            .map(|((r, d), abortable)| self.outcome(stopped_if(r, pressed && abortable), d.clone()))
            .collect()
    }

    /// Which calls a press of the e-stop (or a cancel) aborts: every one but a stop.
    fn abortable(&self, calls: &[ToolCall]) -> Vec<bool> {
        calls
            .iter()
            .map(|c| {
                self.registry
                    .get(&c.name)
                    .is_none_or(|t| t.effect() != Effect::Stops)
            })
            .collect()
    }

    /// Start one call on the runtime (a refused one ends at once with its refusal),
    /// under its time limit: its result and how long it took.
    fn spawn(
        &self,
        call: &ToolCall,
        decision: &Decision,
        progress: Progress,
    ) -> tokio::task::JoinHandle<(Result<Value, ToolError>, Duration)> {
        let tool = match decision {
            Decision::Refused(_) => None,
            _ => self.registry.get(&call.name).cloned(),
        };
        let refused = match decision {
            Decision::Refused(r) => Some(r.clone()),
            _ => None,
        };
        let args = call.arguments.clone();
        let estop = self.policy.estop().clone();
        let timeout = self
            .policy
            .time_limit(tool.as_ref().and_then(|t| t.time_limit()));
        self.runtime.spawn(async move {
            let start = Instant::now();
            let result = match (tool, refused) {
                (_, Some(reason)) => Err(ToolError::Refused(reason)),
                (None, None) => Err(ToolError::Failed("no such tool".into())),
                (Some(tool), None) => {
                    let cx = ToolContext { timeout, progress };
                    let moves = tool.effect() == Effect::Actuates;
                    match tokio::time::timeout(timeout, tool.call(args, &cx)).await {
                        Ok(r) => r,
                        Err(_) => {
                            // Out of time while moving: leave the robot stopped.
                            if moves {
                                estop.halt("the time limit of a moving call");
                            }
                            Err(ToolError::Timeout(timeout))
                        }
                    }
                }
            };
            (result, start.elapsed())
        })
    }

    fn outcome(&self, r: Joined, decision: Decision) -> Outcome {
        let (result, took) = match r {
            Ok(x) => x,
            Err(why) if why.contains("e-stop") || why.contains("cancelled") => (
                Err(ToolError::Failed(format!("stopped: {why}"))),
                Duration::ZERO,
            ),
            // A panicking tool is a failed call, not a crashed agent.
            Err(e) => (
                Err(ToolError::Failed(format!("the tool crashed: {e}"))),
                Duration::ZERO,
            ),
        };
        let ms = took.as_secs_f64() * 1e3;
        match result {
            Ok(mut v) => {
                let hidden = self.policy.redact(&mut v);
                if hidden > 0 {
                    if let Value::Object(m) = &mut v {
                        m.insert("hidden_by_policy".into(), json!(hidden));
                    }
                }
                let decision = match v.get("limited").and_then(Value::as_str) {
                    Some(what) => Decision::Clamped(what.to_string()),
                    None => decision,
                };
                Outcome {
                    output: v,
                    ok: true,
                    ms,
                    decision,
                }
            }
            Err(e) => Outcome {
                output: json!({"error": self.policy.redact_text(&e.to_string())}),
                ok: false,
                ms,
                decision,
            },
        }
    }
}

/// A call's ending that came through the join in words: an abort says why it came
/// (`why`) and what the call had last reported; a panic says what the task said.
fn join_error(e: &tokio::task::JoinError, why: Option<&str>, said: Option<&str>) -> String {
    match (why, said) {
        (Some(why), Some(said)) if e.is_cancelled() => {
            format!("{why}; it had last reported: {said}")
        }
        (Some(why), None) if e.is_cancelled() => why.to_string(),
        _ => e.to_string(),
    }
}

/// A call's result and time as its task's join gave them, or why it has none.
type Joined = Result<(Result<Value, ToolError>, Duration), String>;

/// A call that saw the press itself (its next command refused) may end before the
/// abort does: when `pressed`, its failure was the e-stop's all the same, and says so.
fn stopped_if(r: Joined, pressed: bool) -> Joined {
    match r {
        Ok((Err(ToolError::Failed(e)), _)) if pressed => {
            Err(format!("{ESTOP_PRESSED}; the call had ended with: {e}"))
        }
        r => r,
    }
}

/// Resolves once `flag` is set (checked every 20 ms).
async fn cancelled(flag: &AtomicBool) {
    while !flag.load(Ordering::SeqCst) {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tool::policy::{NoOperator, PolicyFile};
    use crate::tool::Package;

    #[derive(serde::Deserialize, schemars::JsonSchema)]
    struct Steps {
        steps: u32,
    }

    /// Reports each step, one of them naming a denied topic, then returns.
    struct Counts;

    impl crate::tool::Tool for Counts {
        type Args = Steps;
        const NAME: &'static str = "counts";
        const EFFECT: Effect = Effect::Observes;
        fn description(&self) -> String {
            "Counts.".into()
        }
        async fn call(&self, a: Steps, cx: &ToolContext) -> Result<Value, ToolError> {
            for i in 1..=a.steps {
                cx.progress
                    .report(format!("step {i} of {} on /secret/cmd", a.steps));
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
            Ok(json!({"done": a.steps}))
        }
    }

    #[test]
    fn progress_reaches_the_caller_by_call_index_and_behind_the_fence() {
        let mut registry = Registry::new();
        registry.add(Package::new("test").with(Counts));
        let file = PolicyFile {
            deny: vec!["^/secret".into()],
            ..PolicyFile::default()
        };
        let policy = Arc::new(Policy::from_file(file, Arc::new(NoOperator)).unwrap());
        let exec = Executor::new(registry, policy).unwrap();
        let calls: Vec<ToolCall> = [2, 3]
            .iter()
            .map(|n| ToolCall {
                name: "counts".into(),
                arguments: json!({"steps": n}),
            })
            .collect();
        let decisions: Vec<Decision> = calls.iter().map(|c| exec.decide(c)).collect();
        let mut seen: Vec<(usize, String)> = Vec::new();
        let outcomes = exec.run(
            &calls,
            &decisions,
            &Arc::new(AtomicBool::new(false)),
            &mut |i, report| seen.push((i, report.as_str().unwrap_or_default().to_string())),
        );
        assert!(outcomes.iter().all(|o| o.ok), "{outcomes:?}");
        let of = |i: usize| seen.iter().filter(|(j, _)| *j == i).count();
        assert_eq!((of(0), of(1)), (2, 3), "{seen:?}");
        assert!(
            seen.iter().all(|(_, t)| !t.contains("secret")),
            "a denied name reached the front end: {seen:?}"
        );
        assert!(
            seen.iter().any(|(_, t)| t.starts_with("step 3 of 3")),
            "{seen:?}"
        );
        // A context nobody listens to takes reports without complaint.
        ToolContext::new(Duration::from_secs(1))
            .progress
            .report("nobody");
    }
}
