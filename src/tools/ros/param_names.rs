//! The parameter names of the robot's nodes, for what is built inside a model's turn:
//! the parameter tools' arguments as the robot can take them (`Tool::live_parameters`),
//! so "make the background's blue 255" can only name a parameter `/turtlesim` has, and
//! `reading::bound` can hold it to `background_b`.
//!
//! Listing a node's parameters is a service call (`<node>/list_parameters`), and a turn
//! never waits on the robot for long: the catalog answers from what it knows, and
//! fetches the nodes it does not know on a thread of its own, waiting at most
//! `FIRST_WAIT` after a node was asked (by this turn or an earlier one, or by the
//! prefetch made when the tools are built, so a first request finds them listed). A
//! node is asked again after `RETRY`, whether it answered or not. A listing the agent
//! made (`ros_param_list`) is recorded too. The fetch goes through the same graph as
//! the tools, so the fence refuses what it refuses for them.

use std::collections::BTreeMap;
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

use crate::ros::{Graph, RosGraph};

/// Longest a turn waits for a fetch it started.
const FIRST_WAIT: Duration = Duration::from_millis(800);
/// Each node's time limit in a fetch.
const CALL_LIMIT: Duration = Duration::from_secs(2);
/// How soon a node is asked again: one that did not answer, or one whose parameters
/// were listed this long ago (a node may declare more, or restart).
const RETRY: Duration = Duration::from_secs(30);

/// How long the prefetch waits for the robot's nodes to be discovered.
const PREFETCH_WINDOW: Duration = Duration::from_secs(10);

#[derive(Default)]
pub(crate) struct ParamNames {
    shared: Arc<Shared>,
}

/// The catalog's state, and the signal a fetch gives when it records a node.
#[derive(Default)]
struct Shared {
    state: Mutex<State>,
    recorded: Condvar,
}

#[derive(Default)]
struct State {
    /// Per node, its parameter names, as last listed, and when.
    known: BTreeMap<String, (Instant, Vec<String>)>,
    /// Per node, when a fetch last asked it.
    asked: BTreeMap<String, Instant>,
}

impl ParamNames {
    /// The parameter names known now of the nodes of `g` that serve `list_parameters`.
    /// Nodes not known are fetched first, waiting at most `FIRST_WAIT` for them.
    pub fn of(&self, graph: &Arc<dyn RosGraph>, g: &Graph) -> BTreeMap<String, Vec<String>> {
        let serving = serving(g);
        let missing: Vec<String> = {
            let mut s = self.lock();
            let now = Instant::now();
            let missing: Vec<String> = serving
                .iter()
                .filter(|n| s.known.get(*n).is_none_or(|(t, _)| now - *t >= RETRY))
                .filter(|n| s.asked.get(*n).is_none_or(|t| now - *t >= RETRY))
                .cloned()
                .collect();
            for n in &missing {
                s.asked.insert(n.clone(), now);
            }
            missing
        };
        if !missing.is_empty() {
            fetch(self.shared.clone(), graph.clone(), missing);
        }
        // Wait for the nodes asked less than `FIRST_WAIT` ago and not listed since.
        let mut s = self.lock();
        loop {
            let now = Instant::now();
            let until = serving
                .iter()
                .filter_map(|n| {
                    let asked = *s.asked.get(n)?;
                    let listed = s.known.get(n).is_some_and(|(t, _)| *t >= asked);
                    Some(asked + FIRST_WAIT).filter(|_| !listed)
                })
                .filter(|&until| until > now)
                .max();
            let Some(until) = until else { break };
            s = self
                .shared
                .recorded
                .wait_timeout(s, until - now)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
        serving
            .into_iter()
            .filter_map(|n| Some((n.clone(), s.known.get(&n)?.1.clone())))
            .collect()
    }

    /// List the parameters of the nodes `graph` shows once it shows any that serve
    /// them (within `PREFETCH_WINDOW`), on a thread of its own, so the first turn does
    /// not wait for them.
    pub(crate) fn prefetch(self: &Arc<Self>, graph: Arc<dyn RosGraph>) {
        let me = self.clone();
        let _ = std::thread::Builder::new()
            .name("param-prefetch".into())
            .spawn(move || {
                let start = Instant::now();
                while start.elapsed() < PREFETCH_WINDOW {
                    let g = crate::ros::graph_now(graph.as_ref());
                    if let Some(g) = g.filter(|g| !serving(g).is_empty()) {
                        me.of(&graph, &g);
                        return;
                    }
                    std::thread::sleep(Duration::from_millis(50));
                }
            });
    }

    /// Record `node`'s parameters as a listing gave them.
    pub fn record(&self, node: &str, names: Vec<String>) {
        self.shared.record(node, names);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.shared.lock()
    }
}

impl Shared {
    fn record(&self, node: &str, names: Vec<String>) {
        self.lock()
            .known
            .insert(node.to_string(), (Instant::now(), names));
        self.recorded.notify_all();
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// The nodes of `g` that serve `list_parameters`.
fn serving(g: &Graph) -> Vec<String> {
    let services = g.services();
    g.nodes
        .iter()
        .filter(|n| services.contains_key(&list_service(n)))
        .cloned()
        .collect()
}

fn list_service(node: &str) -> String {
    format!("{}/list_parameters", node.trim_end_matches('/'))
}

/// List `nodes`' parameters on a thread of its own, recording each node as it answers.
fn fetch(shared: Arc<Shared>, graph: Arc<dyn RosGraph>, nodes: Vec<String>) {
    let _ = std::thread::Builder::new()
        .name("param-names".into())
        .spawn(move || {
            let Ok(rt) = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
            else {
                return;
            };
            for node in nodes {
                let service = list_service(&node);
                let call = graph.call_service(
                    &service,
                    "rcl_interfaces/srv/ListParameters",
                    json!({"prefixes": [], "depth": 0}),
                    CALL_LIMIT,
                );
                if let Ok(reply) = rt.block_on(call) {
                    shared.record(&node, names(&reply.response));
                }
            }
        });
}

/// The names a `ListParameters` response holds.
pub fn names(response: &Value) -> Vec<String> {
    response["result"]["names"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .map(str::to_string)
        .collect()
}
