//! The DDS plumbing every ROS 2 part of ferrosa shares: the participant and its
//! discovery range (this machine only unless the operator says otherwise), the
//! background runtime ROS tasks run on, type-erased payloads, QoS and name spelling, and
//! the cache of endpoints made on first use.

use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr};
use std::sync::{Arc, Mutex};

use ros2_client::dds::rustdds::{self, DomainParticipantBuilder};
use ros2_client::qos::{Durability as QDurability, History, Reliability as QReliability, WhenFull};
use ros2_client::{Context, Message, Name, Node, QosProfile};
use serde::de::{SeqAccess, Visitor};
use serde::ser::SerializeTuple;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::ros::graph::{Durability, Qos, Reliability};
use crate::ros::msg::normalize_type;
use crate::ros::RosError;

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

pub(crate) fn dds_qos(q: &rustdds::QosPolicies) -> Qos {
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

/// Wait up to `timeout` for `client` to see its server, holding the node's lock only a
/// few milliseconds at a time: a wait for a slow service never keeps another task (the
/// brake, above all) from the node.
pub(crate) async fn service_ready<Q, A>(
    node: &tokio::sync::Mutex<Node>,
    client: &ros2_client::Client<Q, A>,
    timeout: std::time::Duration,
) -> bool
where
    Q: Message + 'static,
    A: Message + 'static,
{
    let deadline = std::time::Instant::now() + timeout;
    loop {
        let ready = {
            let node = node.lock().await;
            tokio::time::timeout(
                std::time::Duration::from_millis(5),
                client.wait_for_service(&node),
            )
            .await
            .is_ok()
        };
        if ready {
            return true;
        }
        if std::time::Instant::now() >= deadline {
            return false;
        }
        tokio::time::sleep(std::time::Duration::from_millis(25)).await;
    }
}

/// Pause after a new endpoint first matches, before the first message or request, for
/// the other side to match it too (a publisher's first message, a service client's
/// first request, an action client's first goal).
pub(crate) const MATCH_SETTLE: std::time::Duration = std::time::Duration::from_millis(300);

/// Endpoints made on first use and kept, by (ROS name, type).
pub(crate) struct EndpointCache<T> {
    map: Mutex<HashMap<(String, String), Arc<T>>>,
}

impl<T> Default for EndpointCache<T> {
    fn default() -> Self {
        EndpointCache {
            map: Mutex::new(HashMap::new()),
        }
    }
}

impl<T> EndpointCache<T> {
    /// The endpoint kept under (`name`, `ty`), or one `make` creates on `node`, then
    /// kept; `true` when it was made by this call.
    pub(crate) async fn get_or_make(
        &self,
        node: &tokio::sync::Mutex<Node>,
        name: &str,
        ty: &str,
        make: impl FnOnce(&mut Node) -> Result<T, RosError>,
    ) -> Result<(Arc<T>, bool), RosError> {
        let key = (name.to_string(), ty.to_string());
        let cached = self.map.lock().expect("endpoint cache").get(&key).cloned();
        if let Some(e) = cached {
            return Ok((e, false));
        }
        let made = Arc::new(make(&mut *node.lock().await)?);
        self.map
            .lock()
            .expect("endpoint cache")
            .insert(key, made.clone());
        Ok((made, true))
    }
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

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
        use ros2_client::dds::rustdds::no_key::{DeserializerAdapter, SerializerAdapter};
        use ros2_client::dds::rustdds::{
            CDRDeserializerAdapter, CDRSerializerAdapter, RepresentationIdentifier,
        };
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
