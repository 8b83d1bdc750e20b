//! The ROS graph as the tools see it: nodes, and every topic endpoint, service and action
//! attributed to its node.
//!
//! DDS discovery knows endpoints (a GID, a DDS topic name, a type, QoS) but not nodes;
//! ROS 2's `ros_discovery_info` knows which GIDs each node owns. `GraphCache` joins the
//! two by GID and demangles DDS names (`rt/x` topics, `rq/xRequest` / `rr/xReply`
//! services, `pkg::msg::dds_::T_` types). The same cache backs the DDS graph and the
//! fake, so the join is tested without a network.

use std::collections::{BTreeMap, BTreeSet};

use serde::Serialize;

use super::msg::normalize_type;

/// A DDS endpoint GID (GUID prefix + entity id).
pub(crate) type Gid = [u8; 16];

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reliability {
    Reliable,
    BestEffort,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Durability {
    Volatile,
    TransientLocal,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Qos {
    pub reliability: Reliability,
    pub durability: Durability,
}

/// One discovered DDS reader or writer.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct DdsEndpoint {
    pub gid: Gid,
    pub writer: bool,
    pub dds_topic: String,
    pub dds_type: String,
    pub qos: Qos,
    /// The type's hash (`RIHS01_<hex>`), from the endpoint's USER_DATA (Jazzy and newer).
    pub type_hash: Option<String>,
}

/// The `typehash=RIHS01_…;` entry ROS 2 (Iron and newer) puts in an endpoint's USER_DATA
/// (an octet sequence: the text follows its length, so it is searched for).
pub(crate) fn type_hash_from_user_data(user_data: &[u8]) -> Option<String> {
    const KEY: &[u8] = b"typehash=";
    let at = user_data.windows(KEY.len()).position(|w| w == KEY)? + KEY.len();
    let value: Vec<u8> = user_data[at..]
        .iter()
        .take_while(|b| b.is_ascii_alphanumeric() || **b == b'_')
        .copied()
        .collect();
    let hash = String::from_utf8(value).ok()?;
    hash.starts_with("RIHS").then_some(hash)
}

/// A node's entities as announced on `ros_discovery_info`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct NodeEntities {
    pub name: String,
    pub namespace: String,
    pub readers: Vec<Gid>,
    pub writers: Vec<Gid>,
}

impl NodeEntities {
    pub(crate) fn full_name(&self) -> String {
        if self.namespace.ends_with('/') {
            format!("{}{}", self.namespace, self.name)
        } else {
            format!("{}/{}", self.namespace, self.name)
        }
    }
}

/// A topic endpoint after the join.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TopicEndpoint {
    pub topic: String,
    #[serde(rename = "type")]
    pub type_name: String,
    /// The owning node, when `ros_discovery_info` named it (plain DDS peers have none).
    pub node: Option<String>,
    pub qos: Qos,
    /// For fetching the type's definition from the node (`~/get_type_description`).
    #[serde(skip)]
    pub type_hash: Option<String>,
}

/// A service server or client after the join.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ServiceEndpoint {
    pub service: String,
    #[serde(rename = "type")]
    pub type_name: String,
    pub node: Option<String>,
}

/// The joined graph at one moment.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Graph {
    pub nodes: Vec<String>,
    pub publishers: Vec<TopicEndpoint>,
    pub subscribers: Vec<TopicEndpoint>,
    pub servers: Vec<ServiceEndpoint>,
    pub clients: Vec<ServiceEndpoint>,
}

/// An action, found from its `send_goal` service.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ActionInfo {
    pub action: String,
    #[serde(rename = "type")]
    pub type_name: String,
    pub servers: Vec<String>,
}

impl Graph {
    /// Topics with their types, hidden `_action/` plumbing left out.
    pub fn topics(&self) -> BTreeMap<String, BTreeSet<String>> {
        let mut out: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for e in self.publishers.iter().chain(&self.subscribers) {
            if !e.topic.contains("/_action/") {
                out.entry(e.topic.clone())
                    .or_default()
                    .insert(e.type_name.clone());
            }
        }
        out
    }

    /// Services with their types, action plumbing and parameter services included.
    pub fn services(&self) -> BTreeMap<String, BTreeSet<String>> {
        let mut out: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for e in &self.servers {
            if !e.service.contains("/_action/") {
                out.entry(e.service.clone())
                    .or_default()
                    .insert(e.type_name.clone());
            }
        }
        out
    }

    pub fn actions(&self) -> Vec<ActionInfo> {
        let mut out: BTreeMap<String, ActionInfo> = BTreeMap::new();
        for e in &self.servers {
            let Some(action) = e.service.strip_suffix("/_action/send_goal") else {
                continue;
            };
            let type_name = e
                .type_name
                .strip_suffix("_SendGoal")
                .unwrap_or(&e.type_name)
                .to_string();
            let info = out.entry(action.to_string()).or_insert_with(|| ActionInfo {
                action: action.to_string(),
                type_name,
                servers: Vec::new(),
            });
            if let Some(node) = &e.node {
                info.servers.push(node.clone());
            }
        }
        out.into_values().collect()
    }

    /// The type published on `topic`, if one is known.
    pub(crate) fn topic_type(&self, topic: &str) -> Option<String> {
        self.publishers
            .iter()
            .chain(&self.subscribers)
            .find(|e| e.topic == topic)
            .map(|e| e.type_name.clone())
    }
}

/// What DDS and `ros_discovery_info` have said so far.
#[derive(Debug, Default, Clone)]
pub(crate) struct GraphCache {
    /// Per participant (by GID), the nodes it last announced.
    participants: BTreeMap<Gid, Vec<NodeEntities>>,
}

/// A DDS topic name as ROS names it.
enum Demangled {
    Topic(String),
    Request(String),
    Reply,
    Other,
}

fn demangle_topic(dds: &str) -> Demangled {
    if let Some(t) = dds.strip_prefix("rt/") {
        Demangled::Topic(format!("/{t}"))
    } else if let Some(s) = dds
        .strip_prefix("rq/")
        .and_then(|s| s.strip_suffix("Request"))
    {
        Demangled::Request(format!("/{s}"))
    } else if dds.starts_with("rr/") && dds.ends_with("Reply") {
        Demangled::Reply
    } else {
        Demangled::Other
    }
}

/// `pkg::srv::dds_::X_Request_` to `pkg/srv/X`.
fn service_type(dds_type: &str) -> String {
    let t = normalize_type(dds_type);
    t.strip_suffix("_Request")
        .or_else(|| t.strip_suffix("_Response"))
        .unwrap_or(&t)
        .to_string()
}

impl GraphCache {
    /// Replace what participant `participant` announced.
    pub(crate) fn update_participant(&mut self, participant: Gid, nodes: Vec<NodeEntities>) {
        self.participants.insert(participant, nodes);
    }

    /// Keep only the participants `live` accepts.
    pub(crate) fn retain_participants(&mut self, mut live: impl FnMut(&Gid) -> bool) {
        self.participants.retain(|gid, _| live(gid));
    }

    /// Forget a participant that left.
    #[cfg(test)]
    pub(crate) fn remove_participant(&mut self, participant: &Gid) {
        self.participants.remove(participant);
    }

    /// Join the announced nodes with the discovered endpoints. Endpoints of participants
    /// no longer announced still appear, without a node.
    pub fn join(&self, endpoints: &[DdsEndpoint]) -> Graph {
        let mut owner: BTreeMap<(Gid, bool), String> = BTreeMap::new();
        let mut nodes = BTreeSet::new();
        for entities in self.participants.values().flatten() {
            let name = entities.full_name();
            for g in &entities.readers {
                owner.insert((*g, false), name.clone());
            }
            for g in &entities.writers {
                owner.insert((*g, true), name.clone());
            }
            nodes.insert(name);
        }
        let mut graph = Graph {
            nodes: nodes.into_iter().collect(),
            ..Graph::default()
        };
        for e in endpoints {
            let node = owner.get(&(e.gid, e.writer)).cloned();
            match demangle_topic(&e.dds_topic) {
                Demangled::Topic(topic) => {
                    let ep = TopicEndpoint {
                        topic,
                        type_name: normalize_type(&e.dds_type),
                        node,
                        qos: e.qos,
                        type_hash: e.type_hash.clone(),
                    };
                    if e.writer {
                        graph.publishers.push(ep);
                    } else {
                        graph.subscribers.push(ep);
                    }
                }
                // A server reads requests; a client writes them.
                Demangled::Request(service) => {
                    let ep = ServiceEndpoint {
                        service,
                        type_name: service_type(&e.dds_type),
                        node,
                    };
                    if e.writer {
                        graph.clients.push(ep);
                    } else {
                        graph.servers.push(ep);
                    }
                }
                Demangled::Reply | Demangled::Other => {}
            }
        }
        let key = |t: &TopicEndpoint| (t.topic.clone(), t.node.clone());
        graph.publishers.sort_by_key(key);
        graph.subscribers.sort_by_key(key);
        graph.publishers.dedup();
        graph.subscribers.dedup();
        let skey = |s: &ServiceEndpoint| (s.service.clone(), s.node.clone());
        graph.servers.sort_by_key(skey);
        graph.clients.sort_by_key(skey);
        graph.servers.dedup();
        graph.clients.dedup();
        graph
    }
}

/// Synthetic GIDs and endpoints for tests of the graph and of the tools on it.
#[cfg(test)]
pub(crate) mod testing {
    use super::*;

    /// The GID whose last byte is `n`.
    pub(crate) fn gid(n: u8) -> Gid {
        let mut g = [0u8; 16];
        g[15] = n;
        g
    }

    /// A reliable, volatile endpoint with GID `gid(n)`.
    pub(crate) fn ep(n: u8, writer: bool, topic: &str, ty: &str) -> DdsEndpoint {
        DdsEndpoint {
            gid: gid(n),
            writer,
            dds_topic: topic.into(),
            dds_type: ty.into(),
            qos: Qos {
                reliability: Reliability::Reliable,
                durability: Durability::Volatile,
            },
            type_hash: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::testing::{ep, gid};
    use super::*;

    #[test]
    fn type_hashes_are_read_from_user_data() {
        let hash = "RIHS01_d5f8873a2f0146498f812d7885c7327ce27e463d36811d8792f35ee38c0d6c38";
        assert_eq!(
            type_hash_from_user_data(format!("typehash={hash};").as_bytes()).as_deref(),
            Some(hash)
        );
        // As it arrives: a CDR octet sequence, length first.
        let mut wire = vec![79, 0, 0, 0];
        wire.extend(format!("typehash={hash};").bytes());
        assert_eq!(type_hash_from_user_data(&wire).as_deref(), Some(hash));
        assert_eq!(type_hash_from_user_data(b""), None);
        assert_eq!(type_hash_from_user_data(b"other=1;"), None);
        assert_eq!(type_hash_from_user_data(&[0xff, 0xfe]), None);
    }

    #[test]
    fn endpoints_join_their_nodes_by_gid() {
        let mut cache = GraphCache::default();
        cache.update_participant(
            gid(100),
            vec![NodeEntities {
                name: "turtlesim".into(),
                namespace: "/".into(),
                readers: vec![gid(1), gid(3)],
                writers: vec![gid(2), gid(4)],
            }],
        );
        cache.update_participant(
            gid(101),
            vec![NodeEntities {
                name: "teleop".into(),
                namespace: "/robot".into(),
                readers: vec![],
                writers: vec![gid(5)],
            }],
        );
        let endpoints = [
            ep(
                1,
                false,
                "rt/turtle1/cmd_vel",
                "geometry_msgs::msg::dds_::Twist_",
            ),
            ep(2, true, "rt/turtle1/pose", "turtlesim::msg::dds_::Pose_"),
            ep(
                3,
                false,
                "rq/spawnRequest",
                "turtlesim::srv::dds_::Spawn_Request_",
            ),
            ep(
                4,
                true,
                "rr/spawnReply",
                "turtlesim::srv::dds_::Spawn_Response_",
            ),
            ep(
                5,
                true,
                "rt/turtle1/cmd_vel",
                "geometry_msgs::msg::dds_::Twist_",
            ),
            ep(6, true, "rt/chatter", "std_msgs::msg::dds_::String_"),
            ep(
                3,
                false,
                "rq/turtle1/rotate_absolute/_action/send_goalRequest",
                "turtlesim::action::dds_::RotateAbsolute_SendGoal_Request_",
            ),
        ];
        let g = cache.join(&endpoints);
        assert_eq!(g.nodes, ["/robot/teleop", "/turtlesim"]);
        assert_eq!(g.publishers.len(), 3);
        let cmd: Vec<_> = g
            .publishers
            .iter()
            .filter(|p| p.topic == "/turtle1/cmd_vel")
            .collect();
        assert_eq!(cmd[0].node.as_deref(), Some("/robot/teleop"));
        assert_eq!(g.subscribers[0].node.as_deref(), Some("/turtlesim"));
        assert_eq!(g.subscribers[0].type_name, "geometry_msgs/msg/Twist");
        // A plain DDS writer has no node.
        let chatter = g.publishers.iter().find(|p| p.topic == "/chatter").unwrap();
        assert_eq!(chatter.node, None);
        assert_eq!(
            g.services()["/spawn"].iter().next().unwrap(),
            "turtlesim/srv/Spawn"
        );
        assert_eq!(
            g.servers
                .iter()
                .find(|s| s.service == "/spawn")
                .unwrap()
                .node
                .as_deref(),
            Some("/turtlesim")
        );
        let actions = g.actions();
        assert_eq!(actions[0].action, "/turtle1/rotate_absolute");
        assert_eq!(actions[0].type_name, "turtlesim/action/RotateAbsolute");
        assert!(!g.topics().keys().any(|t| t.contains("_action")));
        assert_eq!(
            g.topic_type("/turtle1/pose").as_deref(),
            Some("turtlesim/msg/Pose")
        );

        // A participant's new announcement replaces its old one.
        cache.update_participant(gid(101), vec![]);
        let g = cache.join(&endpoints);
        assert_eq!(g.nodes, ["/turtlesim"]);
        cache.remove_participant(&gid(100));
        assert!(cache.join(&endpoints).nodes.is_empty());
    }
}
