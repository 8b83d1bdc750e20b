//! What every client of the console shares: the session's events (numbered, kept for a
//! client that joins or reconnects, broadcast live), the approvals waiting for an
//! operator, the robot's recent trail, and whether the agent is busy.
//!
//! An approval is asked once and shown to every client; the first answer decides, the
//! others see it decided. Its id is 64 random bits (only a client holding the console's
//! secret sees it, and none can guess the next one). One not answered is refused when its time runs out, when the
//! e-stop is engaged or when the run is cancelled: the agent never waits on a page
//! nobody looks at.

use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, RecvTimeoutError, SyncSender};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use serde_json::{json, Value};
use tokio::sync::broadcast;

use crate::estop::EStop;
use crate::fence::Fence;
use crate::tool::{Confirm, ToolCall};

/// How long an approval waits for an operator.
pub(crate) const APPROVAL_WAIT: Duration = Duration::from_secs(120);
/// Events kept for clients that join later (streamed text is never kept), at most
/// this many and this many bytes.
const KEPT: usize = 5000;
const KEPT_BYTES: usize = 16 << 20;
/// Poses kept for the robot view's trail.
const TRAIL: usize = 4000;

/// One event as clients receive it: its number, its kind (the SSE event name) and its
/// JSON.
#[derive(Debug, Clone)]
pub struct Logged {
    pub seq: u64,
    pub kind: &'static str,
    pub data: String,
}

/// A planar pose: metres and radians.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Pose {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

#[derive(Default)]
struct Kept {
    events: VecDeque<Arc<Logged>>,
    bytes: usize,
}

struct Waiting {
    /// The order it was asked in.
    seq: u64,
    /// The call as shown (fenced names redacted).
    shown: ToolCall,
    answer: SyncSender<(bool, String)>,
    answered: bool,
}

/// The console's shared state (see the module header).
pub struct Hub {
    seq: AtomicU64,
    kept: Mutex<Kept>,
    live: broadcast::Sender<Arc<Logged>>,
    waiting: Mutex<BTreeMap<String, Waiting>>,
    next_approval: AtomicU64,
    busy: AtomicBool,
    trail: Mutex<VecDeque<Pose>>,
    pub estop: Arc<EStop>,
    /// The agent's cancel flag.
    pub cancel: Arc<AtomicBool>,
    /// Set once the policy exists: what shown calls are redacted with.
    fence: OnceLock<Arc<Fence>>,
}

impl Hub {
    pub fn new(estop: Arc<EStop>, cancel: Arc<AtomicBool>) -> Arc<Hub> {
        Arc::new(Hub {
            seq: AtomicU64::new(0),
            kept: Mutex::new(Kept::default()),
            live: broadcast::channel(4096).0,
            waiting: Mutex::new(BTreeMap::new()),
            next_approval: AtomicU64::new(1),
            busy: AtomicBool::new(false),
            trail: Mutex::new(VecDeque::new()),
            estop,
            cancel,
            fence: OnceLock::new(),
        })
    }

    pub fn set_fence(&self, fence: Arc<Fence>) {
        let _ = self.fence.set(fence);
    }

    /// Send `data` to every client as a `kind` event; `keep` it for later clients.
    pub fn publish(&self, kind: &'static str, data: &Value, keep: bool) {
        let logged = {
            // Numbered and kept under one lock, so the kept events are in number order.
            let mut kept = self.kept.lock().expect("console log");
            let logged = Arc::new(Logged {
                seq: self.seq.fetch_add(1, Ordering::SeqCst) + 1,
                kind,
                // Nothing that would make text read otherwise than it is (bidi overrides,
                // invisible format characters) reaches a page.
                data: crate::ui::term::clean(&data.to_string()),
            });
            if keep {
                kept.bytes += logged.data.len();
                kept.events.push_back(logged.clone());
                while kept.events.len() > KEPT || kept.bytes > KEPT_BYTES {
                    let Some(old) = kept.events.pop_front() else {
                        break;
                    };
                    kept.bytes -= old.data.len();
                }
            }
            let _ = self.live.send(logged.clone());
            logged
        };
        tracing::trace!(seq = logged.seq, kind, "console event");
    }

    /// The live stream from now on, and the kept events numbered after `after`
    /// (subscribed first, so nothing falls between the two).
    pub fn subscribe(&self, after: u64) -> (Vec<Arc<Logged>>, broadcast::Receiver<Arc<Logged>>) {
        let kept = self.kept.lock().expect("console log");
        let rx = self.live.subscribe();
        let past = kept
            .events
            .iter()
            .filter(|l| l.seq > after)
            .cloned()
            .collect();
        (past, rx)
    }

    /// Claim the agent for a request; false when it is already busy.
    pub fn claim(&self) -> bool {
        self.busy
            .compare_exchange(false, true, Ordering::SeqCst, Ordering::SeqCst)
            .is_ok()
    }

    pub fn release(&self) {
        self.busy.store(false, Ordering::SeqCst);
    }

    pub(crate) fn is_busy(&self) -> bool {
        self.busy.load(Ordering::SeqCst)
    }

    /// A new pose of the robot: kept for the trail when it moved, sent to clients. A
    /// pose that is not finite is dropped.
    pub fn pose(&self, p: Pose) {
        if !(p.x.is_finite() && p.y.is_finite() && p.theta.is_finite()) {
            return;
        }
        {
            let mut trail = self.trail.lock().expect("trail");
            let moved = trail.back().is_none_or(|q| {
                (q.x - p.x).hypot(q.y - p.y) > 1e-3 || (q.theta - p.theta).abs() > 1e-3
            });
            if !moved {
                return;
            }
            trail.push_back(p);
            if trail.len() > TRAIL {
                trail.pop_front();
            }
        }
        self.publish("pose", &json!(p), false);
    }

    pub fn trail(&self) -> Vec<Pose> {
        self.trail.lock().expect("trail").iter().copied().collect()
    }

    /// The approvals waiting, as shown.
    pub fn waiting(&self) -> Vec<Value> {
        let waiting = self.waiting.lock().expect("approvals");
        let mut asked: Vec<(&String, &Waiting)> = waiting.iter().collect();
        asked.sort_by_key(|(_, w)| w.seq);
        asked
            .into_iter()
            .map(|(id, w)| approval_json(id, &w.shown))
            .collect()
    }

    /// An operator's answer to approval `id`; `Err` says why it was not taken.
    pub fn answer(&self, id: &str, approve: bool) -> Result<(), String> {
        let mut waiting = self.waiting.lock().expect("approvals");
        let w = waiting.get_mut(id).ok_or_else(|| {
            format!("no call is waiting for approval {id}: it was answered, timed out or withdrawn")
        })?;
        let why = if approve {
            "approved in the console"
        } else {
            "denied in the console"
        };
        if w.answered {
            return Err(format!("approval {id} was already answered"));
        }
        w.answered = true;
        // The asker holds the receiver until it removes this entry, under this lock.
        w.answer
            .try_send((approve, why.into()))
            .map_err(|_| format!("approval {id} was already answered"))
    }
}

fn approval_json(id: &str, call: &ToolCall) -> Value {
    json!({"id": id, "name": call.name, "arguments": call.arguments,
           "timeout_s": APPROVAL_WAIT.as_secs()})
}

impl Confirm for Hub {
    /// Ask every client about `call` and wait for the first answer (see the module
    /// header for when it is refused without one).
    fn confirm(&self, call: &ToolCall) -> bool {
        let seq = self.next_approval.fetch_add(1, Ordering::SeqCst);
        let id = match crate::ui::secret::random_hex(8) {
            Ok(id) => id,
            Err(e) => {
                tracing::error!("no approval id could be drawn ({e}): the call is refused");
                return false;
            }
        };
        let mut shown = call.clone();
        if let Some(f) = self.fence.get() {
            f.redact_json(&mut shown.arguments);
        }
        let (tx, rx) = sync_channel(1);
        let asked = approval_json(&id, &shown);
        // Waiting before it is shown: an answer may come back at once.
        self.waiting.lock().expect("approvals").insert(
            id.clone(),
            Waiting {
                seq,
                shown,
                answer: tx,
                answered: false,
            },
        );
        self.publish("approval", &asked, true);
        let start = Instant::now();
        let (approved, why) = loop {
            match rx.recv_timeout(Duration::from_millis(50)) {
                Ok(answer) => break answer,
                Err(RecvTimeoutError::Disconnected) => break (false, "withdrawn".into()),
                Err(RecvTimeoutError::Timeout) => {}
            }
            if self.estop.is_engaged() {
                break (false, "the e-stop is engaged".into());
            }
            if self.cancel.load(Ordering::SeqCst) {
                break (false, "the run was stopped".into());
            }
            if start.elapsed() >= APPROVAL_WAIT {
                break (
                    false,
                    format!("no answer within {} s", APPROVAL_WAIT.as_secs()),
                );
            }
        };
        self.waiting.lock().expect("approvals").remove(&id);
        self.publish(
            "approved",
            &json!({"id": id, "approved": approved, "why": why}),
            true,
        );
        approved
    }
}

/// The e-stop's state as clients read it.
pub(crate) fn estop_json(state: Option<&crate::estop::Engaged>) -> Value {
    json!({"engaged": state.is_some(), "source": state.map(|e| e.source.clone())})
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hub() -> Arc<Hub> {
        Hub::new(EStop::new(), Arc::new(AtomicBool::new(false)))
    }

    fn call() -> ToolCall {
        ToolCall {
            name: "turtle_move".into(),
            arguments: json!({"distance": 1.0}),
        }
    }

    /// The first approval of a call that is waiting.
    fn wait_for_approval(h: &Hub) -> String {
        for _ in 0..200 {
            if let Some(a) = h.waiting().first() {
                return a["id"].as_str().unwrap().to_string();
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        panic!("no approval was asked");
    }

    #[test]
    fn the_first_answer_decides_and_a_second_is_refused() {
        let h = hub();
        let asker = {
            let h = h.clone();
            std::thread::spawn(move || h.confirm(&call()))
        };
        let id = wait_for_approval(&h);
        assert_eq!(h.waiting()[0]["arguments"]["distance"], 1.0);
        h.answer(&id, true).unwrap();
        let second = h.answer(&id, false);
        assert!(asker.join().unwrap());
        assert!(second.is_err(), "a second answer was taken");
        assert!(h.waiting().is_empty());
        let (kept, _) = h.subscribe(0);
        let kinds: Vec<_> = kept.iter().map(|l| l.kind).collect();
        assert_eq!(kinds, ["approval", "approved"]);
        assert!(
            kept[1].data.contains("\"approved\":true"),
            "{}",
            kept[1].data
        );
    }

    #[test]
    fn the_estop_refuses_a_waiting_approval() {
        let h = hub();
        let asker = {
            let h = h.clone();
            std::thread::spawn(move || h.confirm(&call()))
        };
        let id = wait_for_approval(&h);
        h.estop.trigger("test");
        assert!(!asker.join().unwrap());
        assert!(
            h.answer(&id, true).is_err(),
            "answered after it was refused"
        );
        let (kept, _) = h.subscribe(0);
        assert!(kept[1].data.contains("e-stop"), "{}", kept[1].data);
    }

    #[test]
    fn later_clients_get_kept_events_after_their_last_and_the_live_rest() {
        let h = hub();
        h.publish("a", &json!(1), true);
        h.publish("token", &json!("x"), false);
        h.publish("b", &json!(2), true);
        let (past, mut rx) = h.subscribe(1);
        assert_eq!(past.iter().map(|l| l.kind).collect::<Vec<_>>(), ["b"]);
        h.publish("c", &json!(3), true);
        assert_eq!(rx.try_recv().unwrap().kind, "c");
    }

    #[test]
    fn one_request_at_a_time() {
        let h = hub();
        assert!(h.claim());
        assert!(!h.claim());
        h.release();
        assert!(h.claim());
    }

    #[test]
    fn the_trail_keeps_moves_only() {
        let h = hub();
        let p = Pose {
            x: 1.0,
            y: 2.0,
            theta: 0.0,
        };
        h.pose(p);
        h.pose(p);
        h.pose(Pose { x: f64::NAN, ..p });
        h.pose(Pose { x: 1.5, ..p });
        assert_eq!(h.trail().len(), 2);
    }
}
