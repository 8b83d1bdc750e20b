//! The node's subscriptions: one per topic and type it is read as, each with its
//! listeners (the tools' and the e-stop's) and a reader per publisher. A reader checks
//! its publisher before reading a byte of its messages (`open_publisher`): the type
//! asked for, by name and md5sum, or a definition that hashes to the md5sum sent; a
//! publisher refused is reported. Readers are added by the master's answers and by
//! `publisherUpdate` (which any local process can send), never dropped by them: one
//! ends when its publisher closes the connection.

use std::sync::atomic::Ordering;
use std::sync::Arc;

use serde_json::Value;
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;
use tokio::task::JoinHandle;

use super::{refused, short, Node, PEER_LIMIT};
use crate::ros::msg::normalize_type;
use crate::ros::ros1::wire::{self, ros1_type};
use crate::ros::ros1::xmlrpc::{self, XValue};
use crate::ros::{cdr, RosError};

/// Most publishers of one topic read at once (what a `publisherUpdate` may add).
pub(super) const MAX_PUBLISHERS: usize = 256;

/// A subscription's key: the topic and the type it is read as (`None`: any).
pub(super) type SubKey = (String, Option<String>);

#[derive(Default)]
pub(super) struct Subscription {
    pub(super) listeners: Vec<(u64, tokio::sync::mpsc::UnboundedSender<Value>)>,
    pub(super) readers: std::collections::BTreeMap<String, JoinHandle<()>>,
}

/// A listener on a topic; dropping it ends its share of the subscription.
pub struct Listener {
    node: Arc<Node>,
    key: SubKey,
    id: u64,
    pub rx: tokio::sync::mpsc::UnboundedReceiver<Value>,
}

impl Drop for Listener {
    fn drop(&mut self) {
        let node = self.node.clone();
        let (key, id) = (self.key.clone(), self.id);
        self.node
            .rt
            .spawn(async move { node.unlisten(&key, id).await });
    }
}

impl Node {
    /// Listen to `topic` as `type_name` (registering with the master on the first
    /// listener of that type): only publishers of that type are read. Without a type,
    /// any publisher whose type checks out.
    pub async fn listen(
        self: &Arc<Self>,
        topic: &str,
        type_name: Option<&str>,
    ) -> Result<Listener, RosError> {
        let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
        let id = self.next_listener.fetch_add(1, Ordering::Relaxed);
        let key: SubKey = (topic.to_string(), type_name.map(normalize_type));
        let first = {
            let mut subs = self.subscriptions.lock().expect("subscriptions");
            let entry = subs.entry(key.clone()).or_default();
            entry.listeners.push((id, tx));
            entry.listeners.len() == 1 && entry.readers.is_empty()
        };
        let listener = Listener {
            node: self.clone(),
            key: key.clone(),
            id,
            rx,
        };
        if first {
            let ty = key.1.as_deref().map_or("*".to_string(), ros1_type);
            let publishers = self
                .master
                .call(
                    "registerSubscriber",
                    &[
                        XValue::str(topic),
                        XValue::str(&ty),
                        XValue::str(&self.api_uri),
                    ],
                )
                .await?;
            let uris: Vec<String> = publishers
                .as_array()
                .iter()
                .filter_map(|u| u.as_str().map(str::to_string))
                .collect();
            self.connect_publishers(&key, &uris);
        }
        Ok(listener)
    }

    async fn unlisten(self: &Arc<Self>, key: &SubKey, id: u64) {
        let ended = {
            let mut subs = self.subscriptions.lock().expect("subscriptions");
            let Some(sub) = subs.get_mut(key) else {
                return;
            };
            sub.listeners.retain(|(i, _)| *i != id);
            if sub.listeners.is_empty() {
                for r in sub.readers.values() {
                    r.abort();
                }
                subs.remove(key);
            }
            // The master is told only when no type of the topic is read any more.
            !subs.keys().any(|(t, _)| *t == key.0)
        };
        if ended {
            let _ = self
                .master
                .call(
                    "unregisterSubscriber",
                    &[XValue::str(&key.0), XValue::str(&self.api_uri)],
                )
                .await;
        }
    }

    /// Read from each publisher in `uris` not being read from now (at most
    /// `MAX_PUBLISHERS` at once).
    pub(super) fn connect_publishers(&self, key: &SubKey, uris: &[String]) {
        let Some(me) = self.me() else { return };
        let mut subs = self.subscriptions.lock().expect("subscriptions");
        let Some(sub) = subs.get_mut(key) else {
            return;
        };
        sub.readers.retain(|_, r| !r.is_finished());
        for uri in uris {
            if uri == &self.api_uri || sub.readers.contains_key(uri) {
                continue;
            }
            if sub.readers.len() >= MAX_PUBLISHERS {
                tracing::warn!(target: "ferrosa::ros1", "{}: more than {MAX_PUBLISHERS} publishers; {uri} is not read", key.0);
                break;
            }
            let (me, key2, uri2) = (me.clone(), key.clone(), uri.clone());
            let task = self.rt.spawn(async move {
                if let Err(e) = me.read_publisher(&key2, &uri2).await {
                    tracing::debug!("{} from {uri2}: {e}", key2.0);
                }
            });
            sub.readers.insert(uri.clone(), task);
        }
    }

    /// Connect to the publisher of `topic` whose API is `uri`: the stream after the
    /// headers, and the type it sends (its definition learnt). With `want`, only a
    /// publisher of that type is taken, by name and md5sum; a known type's md5sum must
    /// be ferrosa's, an unknown one's definition must hash to it. A publisher refused
    /// is reported.
    pub(super) async fn open_publisher(
        &self,
        topic: &str,
        uri: &str,
        want: Option<&str>,
    ) -> Result<(TcpStream, String), String> {
        let protocols = XValue::Array(vec![XValue::Array(vec![XValue::str("TCPROS")])]);
        let params = [
            XValue::str(&self.master.caller_id),
            XValue::str(topic),
            protocols,
        ];
        let answer = xmlrpc::call(uri, "requestTopic", &params, PEER_LIMIT)
            .await
            .map_err(|e| e.to_string())?;
        let endpoint = match answer.as_array() {
            [code, _, endpoint] if code.as_int() == Some(1) => endpoint.clone(),
            _ => return Err(format!("requestTopic answered {answer:?}")),
        };
        let (host, port) = match endpoint.as_array() {
            [_, host, port] => (
                host.as_str().unwrap_or_default().to_string(),
                port.as_int().unwrap_or_default(),
            ),
            _ => return Err(format!("requestTopic offered {endpoint:?}")),
        };
        let port = u16::try_from(port).map_err(|_| format!("a port {port}"))?;
        let mut stream =
            tokio::time::timeout(PEER_LIMIT, TcpStream::connect((host.as_str(), port)))
                .await
                .map_err(|_| "connecting timed out".to_string())?
                .map_err(|e| e.to_string())?;
        stream.set_nodelay(true).map_err(|e| e.to_string())?;
        // What we read it as: a known type by its md5sum and definition, as rospy does.
        let (md5, ty, definition) = match want {
            Some(w) if self.ensure_definition(w).is_ok() => (
                wire::md5sum(&self.wire, w).map_err(|e| e.to_string())?,
                ros1_type(w),
                wire::full_text(&self.wire, w).map_err(|e| e.to_string())?,
            ),
            Some(w) => ("*".to_string(), ros1_type(w), String::new()),
            None => ("*".to_string(), "*".to_string(), String::new()),
        };
        let caller = self.master.caller_id.clone();
        let mut hello = vec![
            ("callerid", caller.as_str()),
            ("topic", topic),
            ("md5sum", md5.as_str()),
            ("type", ty.as_str()),
            ("tcp_nodelay", "1"),
        ];
        if !definition.is_empty() {
            hello.push(("message_definition", definition.as_str()));
        }
        stream
            .write_all(&wire::encode_header(&hello))
            .await
            .map_err(|e| e.to_string())?;
        let header = tokio::time::timeout(PEER_LIMIT, wire::read_header(&mut stream))
            .await
            .map_err(|_| "no connection header".to_string())?
            .map_err(|e| e.to_string())?;
        let peer = format!("the publisher at {uri}");
        if let Some(e) = header.get("error") {
            return Err(refused(
                topic,
                &peer,
                format!("it refused us: {}", short(e)),
            ));
        }
        let sent = normalize_type(header.get("type").map(String::as_str).unwrap_or_default());
        if let Some(w) = want.map(normalize_type) {
            if sent != w {
                return Err(refused(
                    topic,
                    &peer,
                    format!("it sends {sent}, and {topic} is read here as {w} only"),
                ));
            }
        }
        let md5 = header.get("md5sum").map_or("", String::as_str);
        let text = header.get("message_definition").map_or("", String::as_str);
        let ours = |n: &str| self.ensure_definition(n).is_ok();
        wire::learn(&self.wire, &sent, text, md5, &ours).map_err(|e| refused(topic, &peer, e))?;
        Ok((stream, sent))
    }

    async fn read_publisher(self: Arc<Self>, key: &SubKey, uri: &str) -> Result<(), String> {
        let topic = &key.0;
        let (mut stream, ty) = self.open_publisher(topic, uri, key.1.as_deref()).await?;
        loop {
            let frame = wire::read_frame(&mut stream)
                .await
                .map_err(|e| e.to_string())?;
            let message = cdr::decode_ros1(&self.wire, &ty, &frame).map_err(|e| e.to_string())?;
            let mut subs = self.subscriptions.lock().expect("subscriptions");
            let Some(sub) = subs.get_mut(key) else {
                return Ok(());
            };
            sub.listeners
                .retain(|(_, tx)| tx.send(message.clone()).is_ok());
        }
    }
}
