//! ROS 1 (Noetic and Debian's ROS 1) behind the same `RosGraph` as ROS 2, so the tools,
//! the policy and the prompts are the same: a client of our own over XML-RPC (the master
//! and node APIs) and TCPROS, with no generated code: types come from the bundle,
//! translated, or from their peers' connection headers (checked by md5sum, bounded).
//!
//! ROS 1 has no authentication: every peer is input to check, never to obey. A peer
//! cannot redefine a type ferrosa ships or has learnt (its connection is refused and
//! reported), nor change what a watched topic is read as: `watch` (the e-stop's
//! `/ferrosa/estop` as `std_msgs/Bool`) takes only publishers of the type asked for,
//! whatever type the master was told.
//!
//! What ROS 1 does differently is met here: parameters live on the parameter server
//! (offered as each node's ROS 2 parameter services, `master`), `/rosout` carries
//! `rosgraph_msgs/Log` (read as `rcl_interfaces/msg/Log` when that is asked for, levels
//! mapped), and a service's type is learnt by probing it. Actions (actionlib) are plain
//! topics in ROS 1 and are not offered as actions.
//!
//! Everything runs on a runtime of its own with I/O, whatever runtime the caller polls
//! from. The graph is refreshed from the master twice a second and answered from that
//! copy at once, as the DDS graph is.
//!
//! - `xmlrpc`: the documents and the HTTP exchange
//! - `master`: the master's API and the parameter server
//! - `wire`: TCPROS headers and frames, md5sums, definitions
//! - `node`: our node's API server, publications, services and subscriptions

pub mod bridge;
mod master;
mod node;
pub mod wire;
pub mod xmlrpc;

use std::collections::BTreeMap;
use std::future::Future;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use serde_json::{json, Value};
use tokio::io::AsyncReadExt;
use tokio::net::TcpStream;

use master::{Master, SystemState, PARAM_SERVICES};
use node::{Node, PEER_LIMIT};

use super::graph::{Durability, Graph, Qos, Reliability, ServiceEndpoint, TopicEndpoint};
use super::msg::normalize_type;
use super::{cdr, BoxFuture, CancelOutcome, GoalOutcome, Interfaces, RosError, RosGraph, Sample};

/// How often the graph is read from the master.
const REFRESH: Duration = Duration::from_millis(500);

/// Where the master is and how this node is reached.
#[derive(Debug, Clone)]
pub struct Ros1Options {
    pub master_uri: String,
    /// The name other nodes reach this one by (`ROS_HOSTNAME`, else `ROS_IP`).
    pub host: String,
    /// The address the node's two servers listen on: loopback unless a name or an
    /// address for other machines is given.
    pub bind: String,
}

impl Ros1Options {
    pub fn from_env() -> Ros1Options {
        let var = |k: &str| std::env::var(k).ok().filter(|v| !v.trim().is_empty());
        let master_uri = var("ROS_MASTER_URI").unwrap_or_else(|| "http://127.0.0.1:11311/".into());
        let host = var("ROS_HOSTNAME").or_else(|| var("ROS_IP"));
        let bind = match host.as_deref() {
            None | Some("localhost" | "127.0.0.1") => "127.0.0.1",
            Some(_) => "0.0.0.0",
        };
        Ros1Options {
            master_uri,
            host: host.unwrap_or_else(|| "127.0.0.1".into()),
            bind: bind.into(),
        }
    }
}

/// The runtime every ROS 1 task runs on.
fn runtime() -> tokio::runtime::Handle {
    static RT: OnceLock<tokio::runtime::Handle> = OnceLock::new();
    RT.get_or_init(|| {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("ros1".into())
            .spawn(move || {
                let rt = tokio::runtime::Builder::new_multi_thread()
                    .worker_threads(2)
                    .thread_name("ros1-worker")
                    .enable_all()
                    .build()
                    .expect("a tokio runtime for ROS 1");
                tx.send(rt.handle().clone())
                    .expect("handing out the runtime");
                rt.block_on(std::future::pending::<()>());
            })
            .expect("spawning the ROS 1 thread");
        rx.recv().expect("the ROS 1 runtime")
    })
    .clone()
}

/// The ROS 1 graph, through one node of our own.
pub struct Ros1Graph {
    node: Arc<Node>,
    rt: tokio::runtime::Handle,
    cache: Arc<Mutex<Option<Graph>>>,
    /// Each service's type, from a probe (`service` → `pkg/srv/Name`).
    service_types: Arc<Mutex<BTreeMap<String, String>>>,
    fence: Arc<OnceLock<Arc<crate::fence::Fence>>>,
    refresher: tokio::task::JoinHandle<()>,
}

impl Drop for Ros1Graph {
    fn drop(&mut self) {
        self.refresher.abort();
    }
}

/// Unregisters the node's topics from the master when dropped, so the master does not
/// list a node that is gone (what holds the graph, the tools and the e-stop's watch,
/// may live to the process's end).
pub struct Leave {
    node: Arc<Node>,
    rt: tokio::runtime::Handle,
}

impl Drop for Leave {
    fn drop(&mut self) {
        let node = self.node.clone();
        let done = self.rt.spawn(async move {
            tokio::time::timeout(Duration::from_secs(2), node.shutdown()).await
        });
        let _ = futures::executor::block_on(done);
    }
}

impl Ros1Graph {
    /// Register with the master as `name` (made unique with the process id) and read
    /// the graph once.
    pub fn start(opts: &Ros1Options, name: &str) -> Result<Ros1Graph, RosError> {
        let rt = runtime();
        let master = Master {
            uri: opts.master_uri.clone(),
            caller_id: format!("/{name}_{}", std::process::id()),
        };
        let (host, bind) = (opts.host.clone(), opts.bind.clone());
        let node = block(&rt, async move { Node::start(master, &host, &bind).await })?;
        let cache = Arc::new(Mutex::new(None));
        let service_types = Arc::new(Mutex::new(BTreeMap::new()));
        let fence: Arc<OnceLock<Arc<crate::fence::Fence>>> = Arc::new(OnceLock::new());
        let (n, c, s, f) = (
            node.clone(),
            cache.clone(),
            service_types.clone(),
            fence.clone(),
        );
        let refresher = rt.spawn(async move {
            loop {
                match read_graph(&n, &s, &f).await {
                    Ok(g) => *c.lock().expect("graph cache") = Some(g),
                    Err(e) => tracing::debug!("ROS 1 graph: {e}"),
                }
                tokio::time::sleep(REFRESH).await;
            }
        });
        let graph = Ros1Graph {
            node,
            rt,
            cache,
            service_types,
            fence,
            refresher,
        };
        // A master that cannot be reached is an error now, not at the first tool call.
        let (n, s, f) = (
            graph.node.clone(),
            graph.service_types.clone(),
            graph.fence.clone(),
        );
        let first = block(&graph.rt, async move { read_graph(&n, &s, &f).await })?;
        *graph.cache.lock().expect("graph cache") = Some(first);
        Ok(graph)
    }

    /// What unregisters this node when dropped.
    pub(crate) fn leave_on_drop(&self) -> Leave {
        Leave {
            node: self.node.clone(),
            rt: self.rt.clone(),
        }
    }

    /// Run `f` on the ROS 1 runtime and wait for it from any runtime.
    fn on_rt<T: Send + 'static>(
        &self,
        f: impl Future<Output = Result<T, RosError>> + Send + 'static,
    ) -> impl Future<Output = Result<T, RosError>> + Send + 'static {
        let task = self.rt.spawn(f);
        async move {
            task.await
                .map_err(|e| RosError::Other(format!("a ROS 1 task failed: {e}")))?
        }
    }

    fn snapshot(&self) -> Option<Graph> {
        self.cache.lock().expect("graph cache").clone()
    }
}

/// Wait for `f` on `rt` from outside any runtime.
fn block<T: Send + 'static>(
    rt: &tokio::runtime::Handle,
    f: impl Future<Output = Result<T, RosError>> + Send + 'static,
) -> Result<T, RosError> {
    let task = rt.spawn(f);
    futures::executor::block_on(task)
        .map_err(|e| RosError::Other(format!("a ROS 1 task failed: {e}")))?
}

/// The graph as the master has it, our own node left out; each node with parameters
/// under its name is given the parameter services.
async fn read_graph(
    node: &Arc<Node>,
    service_types: &Mutex<BTreeMap<String, String>>,
    fence: &OnceLock<Arc<crate::fence::Fence>>,
) -> Result<Graph, RosError> {
    let master = &node.master;
    let state = master.system_state().await?;
    let types: BTreeMap<String, String> = master.topic_types().await?.into_iter().collect();
    let params = master.param_names().await.unwrap_or_default();
    // Probe services not yet typed (ROS 1's master does not know their types).
    for (service, _) in &state.services {
        let known = service_types
            .lock()
            .expect("service types")
            .contains_key(service);
        if known || fence.get().is_some_and(|f| f.denies(service)) {
            continue;
        }
        if let Ok(uri) = master.lookup_service(service).await {
            match probe(&uri, service, &master.caller_id).await {
                Ok(ty) => {
                    service_types
                        .lock()
                        .expect("service types")
                        .insert(service.clone(), ty);
                }
                Err(e) => tracing::debug!("probing {service}: {e}"),
            }
        }
    }
    // Each topic's type learnt once (from the bundle or a publisher), so tools can
    // offer its schema.
    for (topic, ty) in &types {
        if node.wire.has(&normalize_type(ty)) || !node.tried(ty) {
            continue;
        }
        let publishers = state
            .publishers
            .iter()
            .find(|(t, _)| t == topic)
            .map(|(_, nodes)| {
                nodes
                    .iter()
                    .filter(|n| **n != master.caller_id)
                    .cloned()
                    .collect::<Vec<_>>()
            })
            .unwrap_or_default();
        if !publishers.is_empty() {
            if let Err(e) = node.learn(topic, ty, &publishers).await {
                tracing::debug!("{topic}: {e}");
            }
        } else {
            let _ = node.ensure_definition(ty);
        }
    }
    let service_types = service_types.lock().expect("service types").clone();
    let offered = PARAM_SERVICES.iter().map(|(_, ty)| ty.to_string());
    for ty in service_types.values().cloned().chain(offered) {
        if !node.wire.has(&format!("{ty}_Request")) && node.tried(&ty) {
            let _ = node.ensure_definition(&ty);
        }
    }
    Ok(join(
        &state,
        &types,
        &service_types,
        &params,
        &master.caller_id,
    ))
}

fn join(
    state: &SystemState,
    types: &BTreeMap<String, String>,
    service_types: &BTreeMap<String, String>,
    params: &[String],
    us: &str,
) -> Graph {
    let qos = Qos {
        reliability: Reliability::Reliable,
        durability: Durability::Volatile,
    };
    let endpoints = |list: &[(String, Vec<String>)]| -> Vec<TopicEndpoint> {
        list.iter()
            .flat_map(|(topic, nodes)| {
                nodes
                    .iter()
                    .filter(|n| n.as_str() != us)
                    .map(move |n| TopicEndpoint {
                        topic: topic.clone(),
                        type_name: types
                            .get(topic)
                            .map_or(String::new(), |t| normalize_type(t)),
                        node: Some(n.clone()),
                        qos,
                        type_hash: None,
                    })
            })
            .collect()
    };
    let mut g = Graph {
        publishers: endpoints(&state.publishers),
        subscribers: endpoints(&state.subscribers),
        ..Graph::default()
    };
    for (service, nodes) in &state.services {
        for n in nodes.iter().filter(|n| n.as_str() != us) {
            g.servers.push(ServiceEndpoint {
                service: service.clone(),
                type_name: service_types.get(service).cloned().unwrap_or_default(),
                node: Some(n.clone()),
            });
        }
    }
    let mut nodes: Vec<String> = g
        .publishers
        .iter()
        .chain(&g.subscribers)
        .filter_map(|e| e.node.clone())
        .chain(g.servers.iter().filter_map(|s| s.node.clone()))
        .collect();
    nodes.sort();
    nodes.dedup();
    for n in &nodes {
        if master::names_under(n, params).is_empty() {
            continue;
        }
        for (which, ty) in PARAM_SERVICES {
            g.servers.push(ServiceEndpoint {
                service: format!("{n}/{which}"),
                type_name: ty.to_string(),
                node: Some(n.clone()),
            });
        }
    }
    g.nodes = nodes;
    g
}

/// A service's type (`pkg/srv/Name`), asked of its server as `rosservice type` does.
async fn probe(uri: &str, service: &str, caller: &str) -> Result<String, String> {
    let fields = [
        ("probe", "1"),
        ("md5sum", "*"),
        ("service", service),
        ("callerid", caller),
    ];
    let (_, header) = open_rosrpc(uri, &fields).await?;
    let ty = header.get("type").ok_or("the probe's answer has no type")?;
    let (pkg, name) = ty.split_once('/').ok_or_else(|| format!("a type {ty}"))?;
    Ok(format!("{pkg}/srv/{name}"))
}

/// Connect to the service server at `uri` (`rosrpc://host:port`) and exchange
/// connection headers: the stream, and the server's header.
async fn open_rosrpc(
    uri: &str,
    fields: &[(&str, &str)],
) -> Result<(TcpStream, BTreeMap<String, String>), String> {
    let addr = uri
        .strip_prefix("rosrpc://")
        .ok_or_else(|| format!("{uri}: not a rosrpc:// URI"))?
        .trim_end_matches('/');
    let mut stream = tokio::time::timeout(PEER_LIMIT, TcpStream::connect(addr))
        .await
        .map_err(|_| format!("{uri} did not accept a connection"))?
        .map_err(|e| format!("{uri}: {e}"))?;
    stream.set_nodelay(true).map_err(|e| e.to_string())?;
    tokio::io::AsyncWriteExt::write_all(&mut stream, &wire::encode_header(fields))
        .await
        .map_err(|e| e.to_string())?;
    let header = tokio::time::timeout(PEER_LIMIT, wire::read_header(&mut stream))
        .await
        .map_err(|_| format!("{uri} sent no connection header"))?
        .map_err(|e| e.to_string())?;
    Ok((stream, header))
}

/// Call a ROS 1 service: the request checked against the server's type by md5sum.
async fn call(
    node: Arc<Node>,
    service: String,
    ty: String,
    request: Value,
) -> Result<Value, RosError> {
    let uri = node.master.lookup_service(&service).await?;
    node.ensure_definition(&ty)?;
    let md5 = wire::service_md5sum(&node.wire, &ty).map_err(|e| other_error(&ty, e))?;
    let failed = |e: String| RosError::Other(format!("{service}: {e}"));
    let body = cdr::encode_ros1(&node.wire, &format!("{ty}_Request"), &request).map_err(|e| {
        RosError::Encode {
            type_name: ty.clone(),
            reason: e.to_string(),
        }
    })?;
    let caller = node.master.caller_id.clone();
    let fields = [
        ("callerid", caller.as_str()),
        ("service", service.as_str()),
        ("md5sum", md5.as_str()),
        ("persistent", "0"),
    ];
    let (mut stream, header) = open_rosrpc(&uri, &fields).await.map_err(failed)?;
    if let Some(e) = header.get("error") {
        return Err(failed(format!(
            "the server refused the call ({e}); ferrosa's {ty} (its md5sum {md5}) is not the server's"
        )));
    }
    wire::write_frame(&mut stream, &body)
        .await
        .map_err(|e| failed(e.to_string()))?;
    let ok = stream.read_u8().await.map_err(|e| failed(e.to_string()))?;
    let frame = wire::read_frame(&mut stream)
        .await
        .map_err(|e| failed(e.to_string()))?;
    if ok != 1 {
        return Err(failed(format!(
            "the service failed: {}",
            String::from_utf8_lossy(&frame)
        )));
    }
    cdr::decode_ros1(&node.wire, &format!("{ty}_Response"), &frame).map_err(|e| RosError::Decode {
        type_name: ty,
        reason: e.to_string(),
    })
}

fn other_error(what: &str, e: impl std::fmt::Display) -> RosError {
    RosError::Other(format!("{what}: {e}"))
}

/// A `rosgraph_msgs/Log` as `rcl_interfaces/msg/Log` (levels 1/2/4/8/16 as 10..50).
fn log_as_ros2(v: &Value) -> Value {
    let level = match v["level"].as_u64().unwrap_or(0) {
        1 => 10,
        2 => 20,
        4 => 30,
        8 => 40,
        16 => 50,
        _ => 0,
    };
    let stamp = &v["header"]["stamp"];
    json!({
        "stamp": {"sec": stamp["secs"], "nanosec": stamp["nsecs"]},
        "level": level,
        "name": v["name"], "msg": v["msg"], "file": v["file"],
        "function": v["function"], "line": v["line"],
    })
}

/// How messages of a topic reach the tools: as they are, or converted to the type asked
/// for (ROS 1's log as ROS 2's).
#[derive(Clone, Copy)]
enum Reading {
    AsIs,
    LogAsRos2,
}

impl Reading {
    fn of(topic_type: Option<&str>, asked: Option<&str>, topic: &str) -> Result<Reading, RosError> {
        let asked = asked.map(normalize_type);
        let actual = topic_type.filter(|t| !t.is_empty()).map(normalize_type);
        match (asked.as_deref(), actual.as_deref()) {
            (Some("rcl_interfaces/msg/Log"), Some("rosgraph_msgs/msg/Log")) => {
                Ok(Reading::LogAsRos2)
            }
            (Some("rcl_interfaces/msg/Log"), None) if topic == "/rosout" => Ok(Reading::LogAsRos2),
            (Some(a), Some(t)) if a != t => {
                Err(RosError::Other(format!("{topic} carries {t}, not {a}")))
            }
            _ => Ok(Reading::AsIs),
        }
    }

    /// How a watch reads `topic` when `asked` is the type it must carry: the type
    /// asked is fixed, whatever the master was told (ROS 1's log read as ROS 2's).
    fn fixed(asked: &str, topic_type: Option<&str>, topic: &str) -> Reading {
        let asked = normalize_type(asked);
        match Reading::of(topic_type, Some(&asked), topic) {
            Ok(r) => r,
            Err(e) => {
                tracing::warn!(target: "ferrosa::ros1", "{e}, as the master says; it is read as {asked} only, from publishers of {asked}");
                Reading::AsIs
            }
        }
    }

    /// The type a subscription reads for this reading of `asked` (ROS 1's log for ROS
    /// 2's).
    fn wire_type(self, asked: &str) -> String {
        match self {
            Reading::AsIs => normalize_type(asked),
            Reading::LogAsRos2 => "rosgraph_msgs/msg/Log".to_string(),
        }
    }

    fn apply(self, v: Value) -> Value {
        match self {
            Reading::AsIs => v,
            Reading::LogAsRos2 => log_as_ros2(&v),
        }
    }
}

impl RosGraph for Ros1Graph {
    fn graph(&self) -> BoxFuture<'_, Result<Graph, RosError>> {
        if let Some(g) = self.snapshot() {
            return Box::pin(async move { Ok(g) });
        }
        let (n, s, f) = (
            self.node.clone(),
            self.service_types.clone(),
            self.fence.clone(),
        );
        let read = self.on_rt(async move { read_graph(&n, &s, &f).await });
        Box::pin(read)
    }

    /// ROS 1's definitions (learnt from peers, or translated from the bundle), so the
    /// schemas the model is given and the limits' reading are ROS 1's.
    fn interfaces(&self) -> &Interfaces {
        &self.node.wire
    }

    fn learn_type<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<(), RosError>> {
        let publishers: Vec<String> = self
            .snapshot()
            .unwrap_or_default()
            .publishers
            .iter()
            .filter(|e| e.topic == topic)
            .filter_map(|e| e.node.clone())
            .collect();
        let (node, topic, ty) = (self.node.clone(), topic.to_string(), type_name.to_string());
        Box::pin(self.on_rt(async move { node.learn(&topic, &ty, &publishers).await }))
    }

    fn subscribe<'a>(
        &'a self,
        topic: &'a str,
        type_name: Option<&'a str>,
        max: usize,
        window: Duration,
    ) -> BoxFuture<'a, Result<Vec<Sample>, RosError>> {
        let g = self.snapshot().unwrap_or_default();
        let actual = g.topic_type(topic);
        let reading = Reading::of(actual.as_deref(), type_name, topic);
        let hint = match (&reading, type_name) {
            (Ok(r), Some(asked)) => Some(r.wire_type(asked)),
            _ => actual.clone(),
        };
        let (node, topic) = (self.node.clone(), topic.to_string());
        let run = self.on_rt(async move {
            let reading = reading?;
            if actual.is_none() && hint.is_none() {
                return Err(RosError::NoTopic(topic));
            }
            let start = Instant::now();
            let mut listener = node.listen(&topic, hint.as_deref()).await?;
            let mut out = Vec::new();
            while out.len() < max {
                let left = window.saturating_sub(start.elapsed());
                match tokio::time::timeout(left, listener.rx.recv()).await {
                    Ok(Some(v)) => {
                        out.push(Sample::new(start.elapsed().as_secs_f64(), reading.apply(v)))
                    }
                    _ => break,
                }
            }
            Ok(out)
        });
        Box::pin(run)
    }

    fn publish<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<super::Delivery, RosError>> {
        // The subscribers the master lists now: a message sent before they connected
        // is lost, so it waits for them (one at least, three seconds at most).
        let us = &self.node.master.caller_id;
        let expected = self
            .snapshot()
            .unwrap_or_default()
            .subscribers
            .iter()
            .filter(|e| e.topic == topic && e.node.as_deref() != Some(us))
            .count()
            .max(1);
        let (node, topic, ty) = (self.node.clone(), topic.to_string(), type_name.to_string());
        Box::pin(self.on_rt(async move {
            let publication = node.publication(&topic, &ty).await?;
            let timeout = Duration::from_secs(3);
            let until = Instant::now() + timeout;
            while publication.connected().await < expected && Instant::now() < until {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            match publication.send(&node.wire, &message).await? {
                0 => Err(RosError::NoSubscriber { topic, timeout }),
                _ => Ok(super::Delivery::to(&topic)),
            }
        }))
    }

    fn publish_now<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<super::Delivery, RosError>> {
        let (node, topic, ty) = (self.node.clone(), topic.to_string(), type_name.to_string());
        Box::pin(self.on_rt(async move {
            let publication = node.publication(&topic, &ty).await?;
            publication.send(&node.wire, &message).await?;
            Ok(super::Delivery::to(&topic))
        }))
    }

    fn advertise<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<(), RosError>> {
        let (node, topic, ty) = (self.node.clone(), topic.to_string(), type_name.to_string());
        Box::pin(self.on_rt(async move { node.publication(&topic, &ty).await.map(|_| ()) }))
    }

    fn call_service<'a>(
        &'a self,
        service: &'a str,
        type_name: &'a str,
        request: Value,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<super::Reply, RosError>> {
        let (node, service, ty) = (
            self.node.clone(),
            service.to_string(),
            normalize_type(type_name),
        );
        Box::pin(self.on_rt(async move {
            let work = async {
                if ty.starts_with("rcl_interfaces/srv/") {
                    if let Some((owner, which)) = master::param_service(&service) {
                        return master::param_call(&node.master, owner, which, &request).await;
                    }
                }
                call(node.clone(), service.clone(), ty.clone(), request).await
            };
            match tokio::time::timeout(timeout, work).await {
                Ok(r) => r.map(super::Reply::from),
                Err(_) => Err(RosError::Timeout { service, timeout }),
            }
        }))
    }

    fn send_goal<'a>(
        &'a self,
        action: &'a str,
        _type_name: &'a str,
        _goal: Value,
        _wait: Duration,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>> {
        Box::pin(async move { Err(no_actions(action)) })
    }

    fn cancel_goals<'a>(
        &'a self,
        action: &'a str,
        _type_name: &'a str,
        _goal_id: Option<&'a str>,
        _timeout: Duration,
    ) -> BoxFuture<'a, Result<CancelOutcome, RosError>> {
        Box::pin(async move { Err(no_actions(action)) })
    }

    fn watch<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<super::Watch, RosError>> {
        let g = self.snapshot().unwrap_or_default();
        let reading = Reading::fixed(type_name, g.topic_type(topic).as_deref(), topic);
        let (node, topic, ty) = (
            self.node.clone(),
            topic.to_string(),
            reading.wire_type(type_name),
        );
        Box::pin(self.on_rt(async move {
            let mut listener = node.listen(&topic, Some(&ty)).await?;
            let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
            tokio::spawn(async move {
                while let Some(v) = listener.rx.recv().await {
                    if tx.send(reading.apply(v)).is_err() {
                        return;
                    }
                }
            });
            Ok(rx)
        }))
    }

    fn set_fence(&self, fence: Arc<crate::fence::Fence>) {
        let _ = self.fence.set(fence);
    }
}

fn no_actions(action: &str) -> RosError {
    RosError::Other(format!(
        "{action}: actions are not offered over ROS 1 (actionlib's goal, feedback and result are topics: echo and publish those)"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_graph_joins_state_types_and_parameters_without_us() {
        let state = SystemState {
            publishers: vec![
                ("/turtle1/pose".into(), vec!["/turtlesim".into()]),
                (
                    "/rosout".into(),
                    vec!["/turtlesim".into(), "/ferrosa_1".into()],
                ),
            ],
            subscribers: vec![("/turtle1/cmd_vel".into(), vec!["/turtlesim".into()])],
            services: vec![("/spawn".into(), vec!["/turtlesim".into()])],
        };
        let types = BTreeMap::from([
            ("/turtle1/pose".to_string(), "turtlesim/Pose".to_string()),
            ("/rosout".to_string(), "rosgraph_msgs/Log".to_string()),
        ]);
        let services = BTreeMap::from([("/spawn".to_string(), "turtlesim/srv/Spawn".to_string())]);
        let params = ["/turtlesim/background_r".to_string(), "/run_id".to_string()];
        let g = join(&state, &types, &services, &params, "/ferrosa_1");
        assert_eq!(g.nodes, ["/turtlesim"]);
        assert_eq!(
            g.topic_type("/turtle1/pose").as_deref(),
            Some("turtlesim/msg/Pose")
        );
        assert_eq!(g.publishers.len(), 2);
        let services: Vec<&str> = g.servers.iter().map(|s| s.service.as_str()).collect();
        assert!(services.contains(&"/spawn"));
        assert!(services.contains(&"/turtlesim/get_parameters"));
    }

    #[test]
    fn logs_are_read_as_ros2_logs_when_asked() {
        let r = Reading::of(
            Some("rosgraph_msgs/msg/Log"),
            Some("rcl_interfaces/msg/Log"),
            "/rosout",
        )
        .unwrap();
        let v = r.apply(json!({"header": {"seq": 1, "stamp": {"secs": 5, "nsecs": 6}, "frame_id": ""},
            "level": 4, "name": "/n", "msg": "wall", "file": "f", "function": "g", "line": 3, "topics": []}));
        assert_eq!(v["level"], 30);
        assert_eq!(v["stamp"], json!({"sec": 5, "nanosec": 6}));
        assert_eq!(v["msg"], "wall");
        assert!(Reading::of(
            Some("std_msgs/String"),
            Some("geometry_msgs/msg/Twist"),
            "/a"
        )
        .is_err());
    }
}
