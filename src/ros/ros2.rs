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

pub(crate) use action::server_qos as action_server_qos;

use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ros2_client::dds::rustdds::{self, DomainParticipantBuilder};
use ros2_client::qos::{Durability as QDurability, History, Reliability as QReliability, WhenFull};
use ros2_client::{
    Context, Message, MessageTypeName, Name, Node, NodeName, NodeOptions, QosProfile,
    ServiceMapping, ServiceTypeName,
};
use serde::de::{SeqAccess, Visitor};
use serde::ser::SerializeTuple;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use serde_json::Value;

use super::cdr;
use super::graph::{
    type_hash_from_user_data, DdsEndpoint, Durability, Gid, Graph, GraphCache, NodeEntities, Qos,
    Reliability,
};
use super::msg::normalize_type;
use super::{BoxFuture, CancelOutcome, GoalOutcome, Interfaces, RosError, RosGraph, Sample};

/// Where DDS discovery may reach.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DiscoveryRange {
    /// This machine only (loopback): the default.
    Localhost,
    /// Every network the machine is on.
    Subnet,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ros2Options {
    pub domain_id: u16,
    pub range: DiscoveryRange,
}

impl Default for Ros2Options {
    fn default() -> Self {
        Ros2Options {
            domain_id: 0,
            range: DiscoveryRange::Localhost,
        }
    }
}

impl Ros2Options {
    /// From the environment a ROS user sets: `ROS_DOMAIN_ID` (0..=232),
    /// `ROS_AUTOMATIC_DISCOVERY_RANGE` (LOCALHOST or SUBNET; OFF and SYSTEM_DEFAULT are
    /// treated as LOCALHOST), else the older `ROS_LOCALHOST_ONLY=0|1`. Unset means
    /// domain 0, localhost only.
    pub fn from_env() -> Result<Ros2Options, RosError> {
        Self::from_vars(|k| std::env::var(k).ok())
    }

    fn from_vars(get: impl Fn(&str) -> Option<String>) -> Result<Ros2Options, RosError> {
        let mut opts = Ros2Options::default();
        if let Some(d) = get("ROS_DOMAIN_ID").filter(|d| !d.trim().is_empty()) {
            opts.domain_id = d
                .trim()
                .parse::<u16>()
                .ok()
                .filter(|d| *d <= 232)
                .ok_or_else(|| {
                    RosError::Other(format!("ROS_DOMAIN_ID={d} is not a domain id (0-232)"))
                })?;
        }
        match get("ROS_AUTOMATIC_DISCOVERY_RANGE").map(|r| r.trim().to_ascii_uppercase()) {
            Some(r) if r == "SUBNET" => opts.range = DiscoveryRange::Subnet,
            Some(r) if ["LOCALHOST", "OFF", "SYSTEM_DEFAULT", ""].contains(&r.as_str()) => {}
            Some(r) => {
                return Err(RosError::Other(format!(
                    "ROS_AUTOMATIC_DISCOVERY_RANGE={r}: use LOCALHOST or SUBNET"
                )))
            }
            None => {
                if get("ROS_LOCALHOST_ONLY")
                    .map(|v| v.trim() == "0")
                    .unwrap_or(false)
                {
                    opts.range = DiscoveryRange::Subnet;
                }
            }
        }
        Ok(opts)
    }
}

/// A ROS 2 context (one DDS participant) with these options.
pub fn context(opts: &Ros2Options) -> Result<Context, RosError> {
    let mut builder = DomainParticipantBuilder::new(opts.domain_id);
    if opts.range == DiscoveryRange::Localhost {
        builder = builder.with_only_networks([IpAddr::V4(Ipv4Addr::LOCALHOST)]);
    }
    let participant = builder
        .build()
        .map_err(|e| RosError::Other(format!("cannot start DDS: {e:?}")))?;
    Context::from_domain_participant(participant)
        .map_err(|e| RosError::Other(format!("cannot start ROS 2: {e:?}")))
}

/// A background runtime (two worker threads) for ROS tasks, so a slow task never
/// starves a participant's spinner.
pub(crate) fn background() -> tokio::runtime::Handle {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name("ros2".into())
        .spawn(move || {
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .thread_name("ros2-worker")
                .enable_time()
                .build()
                .expect("a tokio runtime for ROS");
            tx.send(rt.handle().clone())
                .expect("handing out the runtime");
            rt.block_on(std::future::pending::<()>());
        })
        .expect("spawning the ROS thread");
    rx.recv().expect("the ROS thread's runtime")
}

/// A payload of any type: the CDR body, passed through serde untouched.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Raw(pub Vec<u8>);

impl Message for Raw {}

impl Serialize for Raw {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        // A tuple of bytes: CDR writes them as they are, with no length or padding.
        let mut t = s.serialize_tuple(self.0.len())?;
        for b in &self.0 {
            t.serialize_element(b)?;
        }
        t.end()
    }
}

impl<'de> Deserialize<'de> for Raw {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Raw, D::Error> {
        struct Bytes;
        impl<'de> Visitor<'de> for Bytes {
            type Value = Raw;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a CDR payload")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Raw, A::Error> {
                // Read bytes until the payload ends (the deserializer reports the end
                // as an error, which here only means "no more bytes").
                let mut out = Vec::new();
                while let Ok(Some(b)) = seq.next_element::<u8>() {
                    out.push(b);
                }
                Ok(Raw(out))
            }
        }
        d.deserialize_tuple(usize::MAX, Bytes)
    }
}

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

pub(crate) fn reliable_qos(durability: QDurability, depth: usize) -> QosProfile {
    QosProfile::subscription_default()
        .reliability(QReliability::Reliable {
            when_full: WhenFull::DEFAULT,
        })
        .durability(durability)
        .history(History::KeepLast { depth })
}

/// `pkg/msg/Name` (any spelling) split for ros2-client's type names.
pub(crate) fn split_type(type_name: &str) -> Result<(String, String, String), RosError> {
    let full = normalize_type(type_name);
    match full.split('/').collect::<Vec<_>>().as_slice() {
        [pkg, kind, name] => Ok((pkg.to_string(), kind.to_string(), name.to_string())),
        _ => Err(RosError::Other(format!(
            "{type_name}: not a ROS type name (pkg/msg/Name)"
        ))),
    }
}

pub(crate) fn ros_name(name: &str) -> Result<Name, RosError> {
    let name = if name.starts_with('/') {
        name.to_string()
    } else {
        format!("/{name}")
    };
    Name::parse(&name).map_err(|_| RosError::BadName(name))
}

fn dds_qos(q: &rustdds::QosPolicies) -> Qos {
    use rustdds::policy;
    Qos {
        reliability: match q.reliability() {
            Some(policy::Reliability::BestEffort) => Reliability::BestEffort,
            _ => Reliability::Reliable,
        },
        durability: match q.durability() {
            Some(policy::Durability::TransientLocal)
            | Some(policy::Durability::Transient)
            | Some(policy::Durability::Persistent) => Durability::TransientLocal,
            _ => Durability::Volatile,
        },
    }
}

/// Endpoints made on first use and kept, by (ROS name, type).
type Endpoints<T> = Mutex<HashMap<(String, String), Arc<T>>>;

/// The ROS 2 graph, through one hidden node of our own.
pub struct Ros2Graph {
    context: Context,
    node: tokio::sync::Mutex<Node>,
    cache: Arc<Mutex<GraphCache>>,
    interfaces: Interfaces,
    publishers: Endpoints<ros2_client::Publisher<Raw>>,
    clients: Endpoints<ros2_client::Client<Raw, Raw>>,
    actions: Endpoints<action::RawActionClient>,
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
            publishers: Mutex::new(HashMap::new()),
            clients: Mutex::new(HashMap::new()),
            actions: Mutex::new(HashMap::new()),
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

    /// The endpoint kept in `cache` under (`name`, `ty`), or one `make` creates on our
    /// node, then kept; `true` when it was made by this call.
    async fn endpoint<T>(
        &self,
        cache: &Endpoints<T>,
        name: &str,
        ty: &str,
        make: impl FnOnce(&mut Node) -> Result<T, RosError>,
    ) -> Result<(Arc<T>, bool), RosError> {
        let key = (name.to_string(), ty.to_string());
        let cached = cache.lock().expect("endpoint cache").get(&key).cloned();
        if let Some(e) = cached {
            return Ok((e, false));
        }
        let made = Arc::new(make(&mut *self.node.lock().await)?);
        cache
            .lock()
            .expect("endpoint cache")
            .insert(key, made.clone());
        Ok((made, true))
    }

    /// Learn `ty`, used on `topic`, from a node that publishes or subscribes to it: its
    /// `~/get_type_description` service (Jazzy and newer) answers with the definitions of
    /// the type and every type it nests, given the type hash from discovery.
    async fn learn_type(&self, topic: &str, ty: &str, timeout: Duration) {
        let g = self.snapshot();
        let mut asked = Vec::new();
        for e in g.publishers.iter().chain(&g.subscribers) {
            let (Some(node), Some(hash)) = (&e.node, &e.type_hash) else {
                continue;
            };
            if e.topic != topic || e.type_name != ty || asked.contains(node) {
                continue;
            }
            asked.push(node.clone());
            let request = serde_json::json!({
                "type_name": ty, "type_hash": hash, "include_type_sources": true,
            });
            let service = format!("{}/get_type_description", node.trim_end_matches('/'));
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
                    tracing::debug!("{service}: {}", r["failure_reason"]);
                    continue;
                }
                Err(e) => {
                    tracing::debug!("{service}: {e}");
                    continue;
                }
            };
            for source in response["type_sources"].as_array().into_iter().flatten() {
                let (Some(name), Some(text)) = (
                    source["type_name"].as_str(),
                    source["raw_file_contents"].as_str(),
                ) else {
                    continue;
                };
                if matches!(source["encoding"].as_str(), Some("msg" | "srv" | "action")) {
                    if let Err(e) = self.interfaces.add(name, text) {
                        tracing::debug!("{name} from {service}: {e}");
                    }
                }
            }
            if self.interfaces.message(ty).is_ok() {
                return;
            }
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
        let discover_until = start + window.min(Duration::from_secs(3));
        let offered: Vec<DdsEndpoint> = loop {
            let writers: Vec<DdsEndpoint> = self
                .endpoints()
                .into_iter()
                .filter(|e| e.writer && e.dds_topic == dds_topic)
                .collect();
            if !writers.is_empty() || Instant::now() >= discover_until {
                break writers;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        };
        let ty = match (type_name, offered.first()) {
            (Some(t), _) => normalize_type(t),
            (None, Some(w)) => normalize_type(&w.dds_type),
            (None, None) => return Err(RosError::NoTopic(topic.to_string())),
        };
        if self.interfaces.message(&ty).is_err() {
            self.learn_type(topic, &ty, Duration::from_secs(3)).await;
        }
        self.interfaces.message(&ty).map_err(|e| RosError::Decode {
            type_name: ty.clone(),
            reason: e.to_string(),
        })?;
        // As `ros2 topic echo` does: best effort if any publisher is, transient local only
        // if every publisher is.
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
                    });
                }
                Ok(Err(e)) => tracing::debug!("{topic}: {e:?}"),
                Err(_) => break,
            }
        }
        Ok(out)
    }

    async fn do_publish(
        &self,
        topic: &str,
        type_name: &str,
        message: Value,
    ) -> Result<(), RosError> {
        let ty = normalize_type(type_name);
        let bytes =
            cdr::encode(&self.interfaces, &ty, &message, 0).map_err(|e| RosError::Encode {
                type_name: ty.clone(),
                reason: e.to_string(),
            })?;
        let (publisher, _) = self
            .endpoint(&self.publishers, topic, &ty, |node| {
                let (pkg, _, short) = split_type(&ty)?;
                // Volatile: a late subscriber must never receive an old command.
                let qos = reliable_qos(QDurability::Volatile, 10);
                let failed = |e| RosError::Other(format!("publish {topic}: {e:?}"));
                let t = node
                    .create_topic(&ros_name(topic)?, MessageTypeName::new(&pkg, &short), &qos)
                    .map_err(failed)?;
                node.create_publisher::<Raw>(&t, Some(qos)).map_err(failed)
            })
            .await?;
        // A volatile message sent before any subscriber matched is lost: wait for one.
        let timeout = Duration::from_secs(3);
        let until = Instant::now() + timeout;
        loop {
            let matched = publisher.get_subscription_count(&*self.node.lock().await);
            if matched > 0 {
                break;
            }
            if Instant::now() >= until {
                return Err(RosError::NoSubscriber {
                    topic: topic.to_string(),
                    timeout,
                });
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        publisher
            .async_publish(Raw(bytes))
            .await
            .map_err(|e| RosError::Other(format!("publish {topic}: {e:?}")))
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
            .endpoint(&self.clients, service, &ty, |node| {
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
        {
            let node = self.node.lock().await;
            if tokio::time::timeout(timeout, client.wait_for_service(&node))
                .await
                .is_err()
            {
                return Err(RosError::NoService(service.to_string()));
            }
        }
        if fresh {
            // We see the server, but the server may not see our reply reader yet: Fast DDS
            // waits only 100 ms for it before dropping the reply. Give discovery a moment.
            tokio::time::sleep(NEW_CLIENT_SETTLE).await;
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
    ) -> BoxFuture<'a, Result<(), RosError>> {
        Box::pin(self.do_publish(topic, type_name, message))
    }

    fn call_service<'a>(
        &'a self,
        service: &'a str,
        type_name: &'a str,
        request: Value,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<Value, RosError>> {
        Box::pin(self.do_call(service, type_name, request, timeout))
    }

    fn send_goal<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal: Value,
        wait: Duration,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>> {
        Box::pin(self.do_send_goal(action, type_name, goal, wait))
    }

    fn cancel_goals<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal_id: Option<&'a str>,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<CancelOutcome, RosError>> {
        Box::pin(self.do_cancel_goals(action, type_name, goal_id, timeout))
    }
}

/// Pause before the first request of a new service client (see `do_call`).
const NEW_CLIENT_SETTLE: Duration = Duration::from_millis(300);

/// Services whose requests may be repeated without changing the outcome: parameter
/// services (get, list, describe, set to a value) and type descriptions.
fn idempotent_service(ty: &str) -> bool {
    ty.starts_with("rcl_interfaces/srv/") || ty.starts_with("type_description_interfaces/srv/")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(vars: &[(&str, &str)]) -> Result<Ros2Options, RosError> {
        let vars: HashMap<String, String> = vars
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        Ros2Options::from_vars(|k| vars.get(k).cloned())
    }

    #[test]
    fn environment_defaults_to_localhost() {
        assert_eq!(opts(&[]).unwrap(), Ros2Options::default());
        assert_eq!(opts(&[("ROS_DOMAIN_ID", "42")]).unwrap().domain_id, 42);
        assert!(opts(&[("ROS_DOMAIN_ID", "300")]).is_err());
        assert!(opts(&[("ROS_DOMAIN_ID", "x")]).is_err());
        assert_eq!(
            opts(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "subnet")])
                .unwrap()
                .range,
            DiscoveryRange::Subnet
        );
        assert_eq!(
            opts(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")])
                .unwrap()
                .range,
            DiscoveryRange::Localhost
        );
        assert!(opts(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "everywhere")]).is_err());
        assert_eq!(
            opts(&[("ROS_LOCALHOST_ONLY", "0")]).unwrap().range,
            DiscoveryRange::Subnet
        );
        assert_eq!(
            opts(&[("ROS_LOCALHOST_ONLY", "1")]).unwrap().range,
            DiscoveryRange::Localhost
        );
        // The newer variable wins.
        assert_eq!(
            opts(&[
                ("ROS_LOCALHOST_ONLY", "0"),
                ("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
            ])
            .unwrap()
            .range,
            DiscoveryRange::Localhost
        );
    }

    #[test]
    fn raw_payloads_pass_through_cdr_untouched() {
        use rustdds::no_key::{DeserializerAdapter, SerializerAdapter};
        use rustdds::{CDRDeserializerAdapter, CDRSerializerAdapter, RepresentationIdentifier};
        let raw = Raw(vec![1, 0, 0, 0, 7, 0, 0, 0, 0x41, 0x42]);
        let bytes = <CDRSerializerAdapter<Raw> as SerializerAdapter<Raw>>::to_bytes(&raw).unwrap();
        assert_eq!(&bytes[..], &raw.0[..]);
        let back = <CDRDeserializerAdapter<Raw> as DeserializerAdapter<Raw>>::from_bytes(
            &bytes,
            RepresentationIdentifier::CDR_LE,
        )
        .unwrap();
        assert_eq!(back, raw);
    }
}

/// Set in a process that `loopback_netns` started.
pub const IN_LOOPBACK_NETNS: &str = "FERROSA_IN_NETNS";

/// A command that runs `exe args…` in a new network namespace whose only interface is
/// loopback (`unshare -n`, then `ip link set lo up`), killed after `limit_s` seconds: DDS
/// traffic of tests and benchmarks cannot leave the machine. Needs root (or a user
/// namespace), util-linux and iproute2; the child sees `IN_LOOPBACK_NETNS` set.
pub fn loopback_netns(
    exe: &std::path::Path,
    args: impl IntoIterator<Item = impl AsRef<std::ffi::OsStr>>,
    limit_s: u32,
) -> std::process::Command {
    let mut cmd = std::process::Command::new("unshare");
    cmd.args([
        "-n",
        "sh",
        "-c",
        "ip link set lo up && exec timeout -k 5 \"$@\"",
        "sh",
    ])
    .arg(limit_s.to_string())
    .arg(exe)
    .args(args)
    .env(IN_LOOPBACK_NETNS, "1");
    cmd
}
