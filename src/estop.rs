//! The emergency stop: one latch every part of ferrosa shares. Anything may trigger it
//! (the REPL's `/stop`, Ctrl-C, a ROS node publishing `true` on `/ferrosa/estop`, the
//! web console, the model's `robot_stop` tool); only the operator resets it.
//!
//! Triggering runs every registered reaction at once, on the triggering thread (the ROS
//! brake publishes zero velocities and cancels goals; the agent cancels generation and
//! aborts running calls), and wakes every task waiting on `engaged()`. While engaged,
//! the policy refuses every actuating call and the ROS boundary refuses every motion.
//! Nothing here needs a model, a confirmation or an intent: stopping is always possible.
//!
//! Depends on nothing else in the crate.

use std::sync::{Arc, Mutex};
use std::time::Instant;

type Reaction = Box<dyn Fn(&str) + Send + Sync>;

/// The latch (see the module header).
pub struct EStop {
    state: tokio::sync::watch::Sender<Option<Engaged>>,
    /// How many times it was pressed (engaging an engaged e-stop counts too).
    presses: tokio::sync::watch::Sender<u64>,
    reactions: Mutex<Vec<Reaction>>,
}

/// Why and since when the e-stop is engaged.
#[derive(Debug, Clone, PartialEq)]
pub struct Engaged {
    pub source: String,
    pub at: Instant,
}

impl EStop {
    pub fn new() -> Arc<EStop> {
        Arc::new(EStop {
            state: tokio::sync::watch::channel(None).0,
            presses: tokio::sync::watch::channel(0).0,
            reactions: Mutex::new(Vec::new()),
        })
    }

    /// Run `f` (with the trigger's source) every time the e-stop is triggered. Reactions
    /// must be quick and must not block on the network for long: they run before
    /// `trigger` returns.
    pub(crate) fn on_trigger(&self, f: impl Fn(&str) + Send + Sync + 'static) {
        self.reactions
            .lock()
            .expect("e-stop reactions")
            .push(Box::new(f));
    }

    /// Engage (or engage again: the reactions run every time, so a second press brakes
    /// again). `source` says who pressed it, for the trace and the operator.
    pub fn trigger(&self, source: &str) {
        let mut first = false;
        self.state.send_modify(|s| {
            if s.is_none() {
                first = true;
                *s = Some(Engaged {
                    source: source.to_string(),
                    at: Instant::now(),
                });
            }
        });
        self.presses.send_modify(|n| *n += 1);
        // A held button or a topic published at a rate presses many times: say it once.
        if first {
            tracing::warn!(target: "ferrosa::estop", source, "e-stop engaged");
        }
        for r in self.reactions.lock().expect("e-stop reactions").iter() {
            r(source);
        }
    }

    /// Brake without latching: run the reactions (zero velocities, cancel goals) and
    /// leave motion allowed. What ends a moving call that ran out of time.
    pub fn halt(&self, source: &str) {
        tracing::warn!(target: "ferrosa::estop", source, "halt");
        for r in self.reactions.lock().expect("e-stop reactions").iter() {
            r(source);
        }
    }

    /// The operator's reset: motion is allowed again. Returns whether it was engaged.
    pub fn reset(&self) -> bool {
        let was = self.is_engaged();
        self.state.send_replace(None);
        if was {
            tracing::warn!(target: "ferrosa::estop", "e-stop reset by the operator");
        }
        was
    }

    pub fn is_engaged(&self) -> bool {
        self.state.borrow().is_some()
    }

    /// Why it is engaged, if it is.
    pub fn engaged_by(&self) -> Option<Engaged> {
        self.state.borrow().clone()
    }

    /// Every change of state from now on (engaged by whom, or released).
    pub fn subscribe(&self) -> tokio::sync::watch::Receiver<Option<Engaged>> {
        self.state.subscribe()
    }

    /// Resolves at the next press from now on (what aborts running calls: a call
    /// started while the e-stop was already engaged only reads, and may finish).
    pub async fn pressed(&self) {
        let mut rx = self.presses.subscribe();
        rx.borrow_and_update();
        let _ = rx.changed().await;
    }

    /// Resolves as soon as the e-stop is engaged (at once if it already is).
    pub async fn engaged(&self) {
        let mut rx = self.state.subscribe();
        // The sender lives as long as `self`: `wait_for` ends only by the condition.
        let _ = rx.wait_for(Option::is_some).await;
    }
}

impl std::fmt::Debug for EStop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EStop")
            .field("engaged", &self.engaged_by())
            .finish_non_exhaustive()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn triggers_latch_run_reactions_and_wake_waiters_until_reset() {
        let e = EStop::new();
        let fired = Arc::new(AtomicUsize::new(0));
        let f = fired.clone();
        e.on_trigger(move |_| {
            f.fetch_add(1, Ordering::SeqCst);
        });
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap();
        let waiter = {
            let e = e.clone();
            rt.spawn(async move { e.engaged().await })
        };
        assert!(!e.is_engaged());
        e.trigger("test");
        e.trigger("again");
        assert_eq!(
            fired.load(Ordering::SeqCst),
            2,
            "a second press brakes again"
        );
        assert_eq!(
            e.engaged_by().unwrap().source,
            "test",
            "the first press is kept"
        );
        rt.block_on(waiter).unwrap();
        assert!(e.reset());
        assert!(!e.is_engaged() && !e.reset());
    }
}
