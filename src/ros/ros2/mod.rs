//! ROS 2 over ros2-client (RustDDS, built for Jazzy): the `RosGraph` a robot's agent uses.
//!
//! What ros2-client leaves to us lives here: the graph cache fed from
//! `ros_discovery_info` (read with our own type, since ros2-client keeps the GID lists
//! private) and DDS discovery; type-erased payloads (`Raw`) encoded and decoded by
//! `cdr` from interface definitions, a type nobody shipped learnt from the node that
//! uses it (`~/get_type_description`, with the hash from discovery); subscriptions that
//! take the QoS their publishers offer; a wait for the server before every service
//! call; and the environment (`ROS_DOMAIN_ID`, `ROS_AUTOMATIC_DISCOVERY_RANGE`,
//! `ROS_LOCALHOST_ONLY`), with discovery limited to this machine unless the operator says
//! otherwise. Actions are in `action`.
//!
//! ros2-client is async and runtime-agnostic; each participant's spinner and discovery
//! pump run on a small background thread of their own, so callers may use any runtime.

mod action;
mod dds;

pub(crate) use action::server_qos as action_server_qos;
pub(crate) use dds::{background, context, reliable_qos, ros_name, split_type, Raw};
use dds::{dds_qos, service_ready, EndpointCache, MATCH_SETTLE};
pub use dds::{DiscoveryRange, Ros2Options};

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ros2_client::qos::{Durability as QDurability, Reliability as QReliability};
use ros2_client::{
    Context, Message, MessageTypeName, Node, NodeName, NodeOptions, ServiceMapping, ServiceTypeName,
};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::cdr;
use super::graph::{
    type_hash_from_user_data, DdsEndpoint, Durability, Gid, Graph, GraphCache, NodeEntities,
    Reliability,
};
use super::msg::normalize_type;
use super::{
    typedesc, BoxFuture, CancelOutcome, GoalOutcome, Interfaces, RosError, RosGraph, Sample,
};

/// How soon after a subscription joins a latched topic its history arrives: a sample
/// published before the join (by the publisher's clock) counts as history only then, so
/// a publisher whose clock runs behind ours does not make every later sample history.
const HISTORY_BURST: Duration = Duration::from_millis(500);

// `ros_discovery_info`, read with our own types (rmw_dds_common, Jazzy: 16-byte GIDs).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct DiscoveryGid {
    data: [u8; 16],
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct DiscoveryNode {
    node_namespace: String,
    node_name: String,
    reader_gid_seq: Vec<DiscoveryGid>,
    writer_gid_seq: Vec<DiscoveryGid>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct ParticipantEntities {
    gid: DiscoveryGid,
    node_entities_info_seq: Vec<DiscoveryNode>,
}

impl Message for ParticipantEntities {}

/// The ROS 2 graph, through one hidden node of our own.
pub struct Ros2Graph {
    context: Context,
    node: tokio::sync::Mutex<Node>,
    cache: Arc<Mutex<GraphCache>>,
    interfaces: Interfaces,
    publishers: EndpointCache<ros2_client::Publisher<Raw>>,
    clients: EndpointCache<ros2_client::Client<Raw, Raw>>,
    actions: action::Actions,
    fence: std::sync::OnceLock<Arc<crate::fence::Fence>>,
    /// The graph's runtime (its spinner's): watches run on it, not on one each.
    rt: tokio::runtime::Handle,
}

impl Ros2Graph {
    /// Join the ROS 2 graph. `name` is the node's base name; a leading `_` hides it
    /// from node listings, as ROS tools hide theirs.
    pub fn start(opts: &Ros2Options, name: &str) -> Result<Ros2Graph, RosError> {
        let context = context(opts)?;
        let node_name = NodeName::new("/", name)
            .map_err(|e| RosError::Other(format!("node name {name}: {e:?}")))?;
        let mut node = context
            .new_node(node_name, NodeOptions::new().enable_rosout(false))
            .map_err(|e| RosError::Other(format!("cannot create the ROS node: {e:?}")))?;
        let rt = background();
        let spinner = node
            .spinner()
            .map_err(|e| RosError::Other(format!("cannot start the ROS spinner: {e:?}")))?;
        rt.spawn(async move {
            if let Err(e) = spinner.spin().await {
                tracing::warn!("ROS spinner stopped: {e:?}");
            }
        });

        let qos = reliable_qos(QDurability::TransientLocal, 256);
        let topic = context
            .create_topic(
                "ros_discovery_info".to_string(),
                MessageTypeName::new("rmw_dds_common", "ParticipantEntitiesInfo"),
                &qos,
            )
            .map_err(|e| RosError::Other(format!("ros_discovery_info: {e:?}")))?;
        let infos = node
            .create_subscription::<ParticipantEntities>(&topic, Some(qos))
            .map_err(|e| RosError::Other(format!("ros_discovery_info: {e:?}")))?;
        let cache = Arc::new(Mutex::new(GraphCache::default()));
        let feed = cache.clone();
        rt.spawn(async move {
            loop {
                match infos.async_take().await {
                    Ok((info, _)) => {
                        let nodes = info
                            .node_entities_info_seq
                            .into_iter()
                            .map(|n| NodeEntities {
                                name: n.node_name,
                                namespace: n.node_namespace,
                                readers: n.reader_gid_seq.into_iter().map(|g| g.data).collect(),
                                writers: n.writer_gid_seq.into_iter().map(|g| g.data).collect(),
                            })
                            .collect();
                        feed.lock()
                            .expect("graph cache")
                            .update_participant(info.gid.data, nodes);
                    }
                    Err(e) => tracing::debug!("ros_discovery_info: {e:?}"),
                }
            }
        });
        Ok(Ros2Graph {
            context,
            node: tokio::sync::Mutex::new(node),
            cache,
            interfaces: Interfaces::bundled(),
            publishers: EndpointCache::default(),
            clients: EndpointCache::default(),
            actions: action::Actions::default(),
            fence: std::sync::OnceLock::new(),
            rt,
        })
    }

    fn endpoints(&self) -> Vec<DdsEndpoint> {
        let dp = self.context.domain_participant();
        let mut out = Vec::new();
        for w in dp.discovered_writers() {
            let t = &w.publication_topic_data;
            out.push(DdsEndpoint {
                gid: w.writer_proxy.remote_writer_guid.to_bytes(),
                writer: true,
                dds_topic: t.topic_name.clone(),
                dds_type: t.type_name.clone(),
                qos: dds_qos(&t.qos()),
                type_hash: type_hash_from_user_data(&w.user_data),
            });
        }
        for r in dp.discovered_readers() {
            let t = &r.subscription_topic_data;
            out.push(DdsEndpoint {
                gid: r.reader_proxy.remote_reader_guid.to_bytes(),
                writer: false,
                dds_topic: t.topic_name().clone(),
                dds_type: t.type_name().clone(),
                qos: dds_qos(&t.qos()),
                type_hash: type_hash_from_user_data(&r.user_data),
            });
        }
        out
    }

    fn snapshot(&self) -> Graph {
        let endpoints = self.endpoints();
        let mut cache = self.cache.lock().expect("graph cache");
        // A participant with no endpoints left has gone: forget its nodes.
        let live: std::collections::BTreeSet<[u8; 12]> = endpoints
            .iter()
            .map(|e| e.gid[..12].try_into().expect("12 bytes"))
            .collect();
        cache.retain_participants(|gid: &Gid| {
            live.contains(&<[u8; 12]>::try_from(&gid[..12]).expect("12"))
        });
        let mut graph = cache.join(&endpoints);
        graph
            .nodes
            .retain(|n| !n.rsplit('/').next().unwrap_or("").starts_with('_'));
        graph
    }

    /// Learn `ty`, used on `topic`, from a node that publishes or subscribes to it: its
    /// `~/get_type_description` service (Jazzy and newer) answers with the description of
    /// the type and every type it nests; it is used only when it hashes to the type hash
    /// the node announced (`typedesc`), and never replaces a type already known. Nodes
    /// behind the fence are not asked.
    async fn learn_type(&self, topic: &str, ty: &str, timeout: Duration) -> Result<(), RosError> {
        let g = self.snapshot();
        let mut asked = Vec::new();
        let mut why = format!("no node on {topic} described {ty}");
        for e in g.publishers.iter().chain(&g.subscribers) {
            let (Some(node), Some(hash)) = (&e.node, &e.type_hash) else {
                continue;
            };
            if e.topic != topic || e.type_name != ty || asked.contains(node) {
                continue;
            }
            asked.push(node.clone());
            let service = format!("{}/get_type_description", node.trim_end_matches('/'));
            if self.fence.get().is_some_and(|f| f.denies(&service)) {
                continue;
            }
            let request = serde_json::json!({
                "type_name": ty, "type_hash": hash, "include_type_sources": true,
            });
            let answer = self
                .do_call(
                    &service,
                    "type_description_interfaces/srv/GetTypeDescription",
                    request,
                    timeout,
                )
                .await;
            let response = match answer {
                Ok(r) if r["successful"] == true => r,
                Ok(r) => {
                    why = format!("{service}: {}", r["failure_reason"]);
                    continue;
                }
                Err(e) => {
                    why = e.to_string();
                    continue;
                }
            };
            match typedesc::verified_definitions(&response["type_description"], hash) {
                Ok(defs) => {
                    self.interfaces.learn(defs);
                }
                Err(e) => {
                    tracing::warn!(%service, "{e}");
                    why = e.to_string();
                    continue;
                }
            }
            if self.interfaces.message(ty).is_ok() {
                return Ok(());
            }
        }
        Err(RosError::Decode {
            type_name: ty.to_string(),
            reason: why,
        })
    }

    /// The writers of `dds_topic`, waited for until `until` when there are none yet.
    async fn writers_of(&self, dds_topic: &str, until: Instant) -> Vec<DdsEndpoint> {
        loop {
            let writers: Vec<DdsEndpoint> = self
                .endpoints()
                .into_iter()
                .filter(|e| e.writer && e.dds_topic == dds_topic)
                .collect();
            if !writers.is_empty() || Instant::now() >= until {
                return writers;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    async fn do_subscribe(
        &self,
        topic: &str,
        type_name: Option<&str>,
        max: usize,
        window: Duration,
    ) -> Result<Vec<Sample>, RosError> {
        let start = Instant::now();
        let deadline = start + window;
        let dds_topic = format!(
            "rt{}",
            if topic.starts_with('/') {
                topic.to_string()
            } else {
                format!("/{topic}")
            }
        );
        // Wait (briefly) for a publisher, to learn the type and the QoS it offers.
        let offered = self
            .writers_of(&dds_topic, start + window.min(Duration::from_secs(3)))
            .await;
        let ty = match (type_name, offered.first()) {
            (Some(t), _) => normalize_type(t),
            (None, Some(w)) => normalize_type(&w.dds_type),
            (None, None) => return Err(RosError::NoTopic(topic.to_string())),
        };
        if self.interfaces.message(&ty).is_err() {
            self.learn_type(topic, &ty, Duration::from_secs(3)).await?;
        }
        self.interfaces.message(&ty).map_err(|e| RosError::Decode {
            type_name: ty.clone(),
            reason: e.to_string(),
        })?;
        let (qos, latched) = echo_qos(&offered, max);
        let (pkg, _, short) = split_type(&ty)?;
        let name = ros_name(topic)?;
        // RustDDS keeps a participant-wide cache per topic, so a new reader also sees
        // samples an earlier one received: on a volatile topic only newer ones count.
        let since = ros2_client::ROSTime::from_nanos(
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos() as i64)
                .unwrap_or(0),
        );
        let sub = {
            let mut node = self.node.lock().await;
            let t = node
                .create_topic(&name, MessageTypeName::new(&pkg, &short), &qos)
                .map_err(|e| RosError::Other(format!("subscribe {topic}: {e:?}")))?;
            node.create_subscription::<Raw>(&t, Some(qos))
                .map_err(|e| RosError::Other(format!("subscribe {topic}: {e:?}")))?
        };
        let joined = Instant::now();
        let mut out = Vec::new();
        while out.len() < max {
            let now = Instant::now();
            if now >= deadline {
                break;
            }
            match tokio::time::timeout(deadline - now, sub.async_take()).await {
                Ok(Ok((raw, info))) => {
                    if !latched && info.received_timestamp().is_some_and(|t| t < since) {
                        continue;
                    }
                    let message = cdr::decode(&self.interfaces, &ty, &raw.0, 0).map_err(|e| {
                        RosError::Decode {
                            type_name: ty.clone(),
                            reason: e.to_string(),
                        }
                    })?;
                    out.push(Sample {
                        t: start.elapsed().as_secs_f64(),
                        message,
                        // History is delivered on joining; the source time (the
                        // publisher's clock) only tells it apart in that first burst.
                        history: latched
                            && joined.elapsed() < HISTORY_BURST
                            && info.source_timestamp().is_some_and(|t| t < since),
                    });
                }
                Ok(Err(e)) => tracing::debug!("{topic}: {e:?}"),
                Err(_) => break,
            }
        }
        Ok(out)
    }

    /// The publisher for `topic` of type `ty`, made on first use (volatile: a late
    /// subscriber must never receive an old command); `true` when this call made it.
    async fn publisher(
        &self,
        topic: &str,
        ty: &str,
    ) -> Result<(Arc<ros2_client::Publisher<Raw>>, bool), RosError> {
        let made = self
            .publishers
            .get_or_make(&self.node, topic, ty, |node| {
                let (pkg, _, short) = split_type(ty)?;
                let qos = reliable_qos(QDurability::Volatile, 10);
                let failed = |e| RosError::Other(format!("publish {topic}: {e:?}"));
                let t = node
                    .create_topic(&ros_name(topic)?, MessageTypeName::new(&pkg, &short), &qos)
                    .map_err(failed)?;
                node.create_publisher::<Raw>(&t, Some(qos)).map_err(failed)
            })
            .await?;
        Ok(made)
    }

    fn encode(&self, ty: &str, message: &Value) -> Result<Vec<u8>, RosError> {
        cdr::encode(&self.interfaces, ty, message, 0).map_err(|e| RosError::Encode {
            type_name: ty.to_string(),
            reason: e.to_string(),
        })
    }

    async fn do_publish(
        &self,
        topic: &str,
        type_name: &str,
        message: Value,
        wait_for_subscriber: bool,
    ) -> Result<super::Delivery, RosError> {
        let ty = normalize_type(type_name);
        let bytes = self.encode(&ty, &message)?;
        let (publisher, made) = self.publisher(topic, &ty).await?;
        // A volatile message sent before any subscriber matched is lost: wait for one
        // (not when braking: a stop goes out at once to whoever is there).
        let timeout = Duration::from_secs(3);
        let until = Instant::now() + timeout;
        let mut waited = false;
        while wait_for_subscriber && publisher.get_subscription_count(&*self.node.lock().await) == 0
        {
            if Instant::now() >= until {
                return Err(RosError::NoSubscriber {
                    topic: topic.to_string(),
                    timeout,
                });
            }
            waited = true;
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        // Our side matching the subscriber does not mean it has matched us yet: until
        // it has, it drops what we send (a best-effort reader for good; a reliable one
        // asks for it again only while this process lives). Give a match made just now
        // time to become mutual.
        if wait_for_subscriber && (made || waited) {
            tokio::time::sleep(MATCH_SETTLE).await;
        }
        publisher
            .async_publish(Raw(bytes))
            .await
            .map_err(|e| RosError::Other(format!("publish {topic}: {e:?}")))?;
        Ok(super::Delivery::to(topic))
    }

    /// Every message of `topic` from now on, decoded, into a channel; best effort and
    /// volatile, so it matches any publisher.
    async fn do_watch(&self, topic: &str, type_name: &str) -> Result<super::Watch, RosError> {
        let ty = normalize_type(type_name);
        self.interfaces.message(&ty).map_err(|e| RosError::Decode {
            type_name: ty.clone(),
            reason: e.to_string(),
        })?;
        let (pkg, _, short) = split_type(&ty)?;
        let qos = reliable_qos(QDurability::Volatile, 16).reliability(QReliability::BestEffort);
        let sub = {
            let mut node = self.node.lock().await;
            let t = node
                .create_topic(&ros_name(topic)?, MessageTypeName::new(&pkg, &short), &qos)
                .map_err(|e| RosError::Other(format!("watch {topic}: {e:?}")))?;
            node.create_subscription::<Raw>(&t, Some(qos))
                .map_err(|e| RosError::Other(format!("watch {topic}: {e:?}")))?
        };
        let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
        let interfaces = self.interfaces.clone();
        self.rt.spawn(async move {
            loop {
                match sub.async_take().await {
                    Ok((raw, _)) => match cdr::decode(&interfaces, &ty, &raw.0, 0) {
                        Ok(v) => {
                            if tx.send(v).is_err() {
                                return;
                            }
                        }
                        Err(e) => tracing::debug!("watch: {e}"),
                    },
                    Err(e) => tracing::debug!("watch: {e:?}"),
                }
            }
        });
        Ok(rx)
    }

    async fn do_call(
        &self,
        service: &str,
        type_name: &str,
        request: Value,
        timeout: Duration,
    ) -> Result<Value, RosError> {
        let start = Instant::now();
        let ty = normalize_type(type_name);
        let (pkg, kind, short) = split_type(&ty)?;
        if kind != "srv" {
            return Err(RosError::Other(format!(
                "{type_name} is not a service type (pkg/srv/Name)"
            )));
        }
        let req_ty = format!("{ty}_Request");
        let bytes =
            cdr::encode(&self.interfaces, &req_ty, &request, 0).map_err(|e| RosError::Encode {
                type_name: req_ty.clone(),
                reason: e.to_string(),
            })?;
        let (client, fresh) = self
            .clients
            .get_or_make(&self.node, service, &ty, |node| {
                let qos = reliable_qos(QDurability::Volatile, 10);
                node.create_client::<Raw, Raw>(
                    ServiceMapping::Enhanced,
                    &ros_name(service)?,
                    &ServiceTypeName::new(&pkg, &short),
                    qos.clone(),
                    qos,
                )
                .map_err(|e| RosError::Other(format!("client {service}: {e:?}")))
            })
            .await?;
        if !service_ready(&self.node, &client, timeout).await {
            return Err(RosError::NoService(service.to_string()));
        }
        if fresh {
            // We see the server, but the server may not see our reply reader yet: Fast DDS
            // waits only 100 ms for it before dropping the reply. Give discovery a moment.
            tokio::time::sleep(MATCH_SETTLE).await;
        }
        // Calls that read or set state by value may be sent again if the reply went
        // missing; anything else is sent once (a second /spawn would spawn twice).
        let attempts = if idempotent_service(&ty) { 2 } else { 1 };
        let mut raw = None;
        for attempt in 1..=attempts {
            let left = timeout.saturating_sub(start.elapsed());
            let wait =
                if attempt < attempts { left / 2 } else { left }.max(Duration::from_millis(100));
            match tokio::time::timeout(wait, client.async_call_service(Raw(bytes.clone()))).await {
                Ok(Ok(r)) => {
                    raw = Some(r);
                    break;
                }
                Ok(Err(e)) => return Err(RosError::Other(format!("call {service}: {e:?}"))),
                Err(_) => tracing::debug!(service, attempt, "no reply"),
            }
        }
        let Some(raw) = raw else {
            return Err(RosError::Timeout {
                service: service.to_string(),
                timeout,
            });
        };
        let resp_ty = format!("{ty}_Response");
        cdr::decode(&self.interfaces, &resp_ty, &raw.0, 0).map_err(|e| RosError::Decode {
            type_name: resp_ty,
            reason: e.to_string(),
        })
    }
}

impl RosGraph for Ros2Graph {
    fn set_fence(&self, fence: Arc<crate::fence::Fence>) {
        let _ = self.fence.set(fence);
    }

    fn graph(&self) -> BoxFuture<'_, Result<Graph, RosError>> {
        Box::pin(async move { Ok(self.snapshot()) })
    }

    fn interfaces(&self) -> &Interfaces {
        &self.interfaces
    }

    fn subscribe<'a>(
        &'a self,
        topic: &'a str,
        type_name: Option<&'a str>,
        max: usize,
        window: Duration,
    ) -> BoxFuture<'a, Result<Vec<Sample>, RosError>> {
        Box::pin(self.do_subscribe(topic, type_name, max, window))
    }

    fn publish<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<super::Delivery, RosError>> {
        Box::pin(self.do_publish(topic, type_name, message, true))
    }

    fn publish_now<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<super::Delivery, RosError>> {
        Box::pin(self.do_publish(topic, type_name, message, false))
    }

    fn advertise<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<(), RosError>> {
        Box::pin(async move {
            self.publisher(topic, &normalize_type(type_name)).await?;
            Ok(())
        })
    }

    fn watch<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<super::Watch, RosError>> {
        Box::pin(self.do_watch(topic, type_name))
    }

    fn call_service<'a>(
        &'a self,
        service: &'a str,
        type_name: &'a str,
        request: Value,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<super::Reply, RosError>> {
        Box::pin(async move {
            self.do_call(service, type_name, request, timeout)
                .await
                .map(super::Reply::from)
        })
    }

    fn send_goal<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal: Value,
        wait: Duration,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>> {
        Box::pin(self.actions.send_goal(
            &self.node,
            &self.interfaces,
            (action, type_name),
            goal,
            wait,
            None,
        ))
    }

    fn send_goal_watched<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal: Value,
        wait: Duration,
        feedback: super::FeedbackSink,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>> {
        Box::pin(self.actions.send_goal(
            &self.node,
            &self.interfaces,
            (action, type_name),
            goal,
            wait,
            Some(feedback),
        ))
    }

    fn cancel_goals<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal_id: Option<&'a str>,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<CancelOutcome, RosError>> {
        Box::pin(
            self.actions
                .cancel_goals(&self.node, action, type_name, goal_id, timeout),
        )
    }
}

/// Services whose requests may be repeated without changing the outcome: parameter
/// services (get, list, describe, set to a value) and type descriptions.
fn idempotent_service(ty: &str) -> bool {
    ty.starts_with("rcl_interfaces/srv/") || ty.starts_with("type_description_interfaces/srv/")
}

/// The QoS to read a topic with, as `ros2 topic echo` chooses it: best effort if any
/// publisher is, transient local only if every publisher is (then `true`: samples from
/// before the reader count).
fn echo_qos(offered: &[DdsEndpoint], max: usize) -> (ros2_client::QosProfile, bool) {
    let best_effort = offered
        .iter()
        .any(|w| w.qos.reliability == Reliability::BestEffort);
    let latched = !offered.is_empty()
        && offered
            .iter()
            .all(|w| w.qos.durability == Durability::TransientLocal);
    let mut qos = reliable_qos(
        if latched {
            QDurability::TransientLocal
        } else {
            QDurability::Volatile
        },
        max.clamp(10, 1000),
    );
    if best_effort {
        qos = qos.reliability(QReliability::BestEffort);
    }
    (qos, latched)
}
