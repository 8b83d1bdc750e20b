//! ferrosa's own ROS 1 node: the XML-RPC API other nodes and the master call on it
//! (`requestTopic`, `publisherUpdate`, `getPid`, …), the TCPROS server its topics'
//! subscribers connect to, its publications, services and subscriptions (one per topic
//! and type it is read as, each with its listeners and a reader per publisher, checked
//! before a byte of its messages is read: `open_publisher`).
//!
//! Types: a type ferrosa ships (the bundle, translated to ROS 1) or has learnt is never
//! redefined by a peer: a publisher or subscriber whose md5sum differs is refused for
//! that connection and reported (`tracing::warn`). A type ferrosa does not know is
//! learnt from the first peer whose definition hashes to the md5sum it sends
//! (`wire::learn`, bounded). A subscription asked for with a type (the e-stop's
//! `std_msgs/Bool`) reads only publishers of exactly that type, whatever the master or
//! any other node says the topic carries; one without a type reads any publisher whose
//! type checks out. A `publisherUpdate` (which any local process can send) only adds
//! publishers: a reader ends when its publisher closes the connection.
//!
//! Every socket has a time limit: the API server's requests (`PEER_LIMIT`), connection
//! headers (`PEER_LIMIT`), frames once their length has come (`wire::FRAME_LIMIT`), a
//! service client's next request (`SERVICE_IDLE`), and each frame written to a
//! subscriber (`PEER_LIMIT`: one that stops reading is dropped).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;

use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;

use super::master::Master;
use super::wire::{self, ros1_type};
use super::xmlrpc::{self, XValue};
use crate::ros::msg::{normalize_type, BaseType, Interfaces, Shape};
use crate::ros::{cdr, RosError};

/// Connections one of the node's servers holds at once: past it a new one is closed at
/// once, so a peer that opens many cannot use up the process's file descriptors (and
/// with them the e-stop's subscription) or its memory.
const MAX_CONNECTIONS: usize = 128;

/// Accept on `listener` while the node lives, each connection handled by `handle` on a
/// task of its own. An accept error (file descriptors run out) is waited out, never the
/// end of the server.
fn serve<F, Fut>(listener: TcpListener, node: Weak<Node>, what: &'static str, handle: F)
where
    F: Fn(Arc<Node>, TcpStream) -> Fut + Send + 'static,
    Fut: std::future::Future<Output = ()> + Send + 'static,
{
    let slots = Arc::new(tokio::sync::Semaphore::new(MAX_CONNECTIONS));
    tokio::spawn(async move {
        loop {
            let stream = match listener.accept().await {
                Ok((stream, _)) => stream,
                Err(e) => {
                    if node.strong_count() == 0 {
                        return;
                    }
                    tracing::debug!(target: "ferrosa::ros1", "{what}: accepting a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            };
            let Some(node) = node.upgrade() else { return };
            let Ok(slot) = slots.clone().try_acquire_owned() else {
                tracing::debug!(target: "ferrosa::ros1", "{what}: {MAX_CONNECTIONS} connections open; a new one is closed");
                continue;
            };
            let handled = handle(node, stream);
            tokio::spawn(async move {
                handled.await;
                drop(slot);
            });
        }
    });
}

/// How long a peer has to answer a connection or a call.
pub(crate) const PEER_LIMIT: Duration = Duration::from_secs(3);

/// How long a persistent service client may wait between requests (others send theirs
/// within `PEER_LIMIT`).
pub(crate) const SERVICE_IDLE: Duration = Duration::from_secs(600);

pub(crate) struct Node {
    this: Weak<Node>,
    /// The ROS 1 runtime (with I/O): every task of the node runs on it.
    rt: tokio::runtime::Handle,
    pub master: Master,
    pub api_uri: String,
    host: String,
    tcpros_port: u16,
    /// ROS 1 definitions: learnt from peers, or translated from the bundle.
    pub wire: Interfaces,
    publications: Mutex<BTreeMap<String, Arc<Publication>>>,
    services: Mutex<BTreeMap<String, Arc<Served>>>,
    /// Parameters this node set, deleted when it leaves.
    params: Mutex<Vec<String>>,
    subscriptions: Mutex<BTreeMap<SubKey, Subscription>>,
    next_listener: AtomicU64,
    /// Types the graph's refresh has tried to learn (once each).
    tried: Mutex<std::collections::BTreeSet<String>>,
}

/// One topic this node publishes, and the subscribers connected to it.
pub(crate) struct Publication {
    pub type_name: String,
    connections: tokio::sync::Mutex<Vec<(u64, tokio::net::tcp::OwnedWriteHalf)>>,
}

/// What serves one service: the request in, the response or the failure's text out.
pub(crate) type Handler =
    Arc<dyn Fn(Value) -> crate::ros::BoxFuture<'static, Result<Value, String>> + Send + Sync>;

struct Served {
    type_name: String,
    md5: String,
    handler: Handler,
}

fn other(what: &str, e: impl std::fmt::Display) -> RosError {
    RosError::Other(format!("{what}: {e}"))
}

/// Report a peer refused (the operator reads warnings; the peer gets the reason) and
/// give the reason back.
fn refused(topic: &str, peer: &str, why: impl std::fmt::Display) -> String {
    let why = format!("{topic}: refused {peer}: {why}");
    tracing::warn!(target: "ferrosa::ros1", "{why}");
    why
}

impl Node {
    /// Open the node's two listeners on `bind` (inside the ROS 1 runtime), advertised
    /// as `host`.
    pub async fn start(master: Master, host: &str, bind: &str) -> Result<Arc<Node>, RosError> {
        let api = TcpListener::bind((bind, 0))
            .await
            .map_err(|e| other("bind", e))?;
        let tcpros = TcpListener::bind((bind, 0))
            .await
            .map_err(|e| other("bind", e))?;
        let api_port = api.local_addr().map_err(|e| other("bind", e))?.port();
        let tcpros_port = tcpros.local_addr().map_err(|e| other("bind", e))?.port();
        let node = Arc::new_cyclic(|this| Node {
            this: this.clone(),
            rt: tokio::runtime::Handle::current(),
            master,
            api_uri: format!("http://{host}:{api_port}/"),
            host: host.to_string(),
            tcpros_port,
            wire: wire::table(),
            publications: Mutex::new(BTreeMap::new()),
            services: Mutex::new(BTreeMap::new()),
            params: Mutex::new(Vec::new()),
            subscriptions: Mutex::new(BTreeMap::new()),
            next_listener: AtomicU64::new(0),
            tried: Mutex::new(Default::default()),
        });
        serve(
            api,
            Arc::downgrade(&node),
            "the node API",
            |node, stream| async move { node.serve_api(stream).await },
        );
        serve(
            tcpros,
            Arc::downgrade(&node),
            "TCPROS",
            |node, stream| async move {
                if let Err(e) = node.accept(stream).await {
                    tracing::debug!("TCPROS connection: {e}");
                }
            },
        );
        Ok(node)
    }

    // ------------------------------------------------------------ the node's API

    async fn serve_api(&self, mut stream: TcpStream) {
        let read = xmlrpc::read_http(&mut stream, xmlrpc::MAX_REQUEST);
        let answer = match tokio::time::timeout(PEER_LIMIT, read).await {
            Ok(Ok((_, body))) => match xmlrpc::parse_call(&body) {
                Ok((method, params)) => self.dispatch(&method, &params).await,
                Err(e) => {
                    tracing::debug!("XML-RPC request: {e}");
                    reply(-1, &e.to_string(), XValue::Int(0))
                }
            },
            Ok(Err(e)) => {
                tracing::debug!("XML-RPC request: {e}");
                return;
            }
            Err(_) => {
                tracing::debug!("XML-RPC request: none within {PEER_LIMIT:?}");
                return;
            }
        };
        let doc = xmlrpc::response_document(&answer);
        let http = format!(
            "HTTP/1.0 200 OK\r\nContent-Type: text/xml\r\nContent-Length: {}\r\n\r\n{doc}",
            doc.len()
        );
        let _ = tokio::time::timeout(PEER_LIMIT, stream.write_all(http.as_bytes())).await;
    }

    async fn dispatch(&self, method: &str, params: &[XValue]) -> XValue {
        let arg = |i: usize| params.get(i).and_then(XValue::as_str).unwrap_or_default();
        match method {
            "getPid" => reply(1, "", XValue::Int(std::process::id().into())),
            "getMasterUri" => reply(1, "", XValue::str(&self.master.uri)),
            "getBusInfo" => reply(1, "", XValue::Array(vec![])),
            "shutdown" | "paramUpdate" => reply(1, "", XValue::Int(0)),
            "getPublications" | "getSubscriptions" => {
                let pairs: Vec<XValue> = if method == "getPublications" {
                    let pubs = self.publications.lock().expect("publications");
                    pubs.iter()
                        .map(|(t, p)| {
                            XValue::Array(vec![
                                XValue::str(t),
                                XValue::str(&ros1_type(&p.type_name)),
                            ])
                        })
                        .collect()
                } else {
                    let subs = self.subscriptions.lock().expect("subscriptions");
                    subs.keys()
                        .map(|(t, ty)| {
                            let ty = ty.as_deref().map_or("*".into(), ros1_type);
                            XValue::Array(vec![XValue::str(t), XValue::str(&ty)])
                        })
                        .collect()
                };
                reply(1, "", XValue::Array(pairs))
            }
            "requestTopic" => {
                if self
                    .publications
                    .lock()
                    .expect("publications")
                    .contains_key(arg(1))
                {
                    let endpoint = vec![
                        XValue::str("TCPROS"),
                        XValue::str(&self.host),
                        XValue::Int(self.tcpros_port.into()),
                    ];
                    reply(1, "ready", XValue::Array(endpoint))
                } else {
                    reply(
                        0,
                        &format!("not a publisher of {}", arg(1)),
                        XValue::Array(vec![]),
                    )
                }
            }
            "publisherUpdate" => {
                // Any local process can send this: it only adds publishers to read
                // (each checked by its type), never drops one.
                let uris: Vec<String> = params
                    .get(2)
                    .map(XValue::as_array)
                    .unwrap_or_default()
                    .iter()
                    .filter_map(|u| u.as_str().filter(|u| u.starts_with("http://")))
                    .take(MAX_PUBLISHERS)
                    .map(str::to_string)
                    .collect();
                let keys: Vec<SubKey> = self
                    .subscriptions
                    .lock()
                    .expect("subscriptions")
                    .keys()
                    .filter(|(t, _)| t == arg(1))
                    .cloned()
                    .collect();
                for key in keys {
                    self.connect_publishers(&key, &uris);
                }
                reply(1, "", XValue::Int(0))
            }
            other => reply(-1, &format!("no method {other}"), XValue::Int(0)),
        }
    }

    // ------------------------------------------------------------ publishing

    /// The publication of `topic`, registered with the master on first use.
    pub async fn publication(
        self: &Arc<Self>,
        topic: &str,
        type_name: &str,
    ) -> Result<Arc<Publication>, RosError> {
        let ty = normalize_type(type_name);
        if !wire::valid_type(&ty) {
            return Err(RosError::Encode {
                type_name: type_name.to_string(),
                reason: "not a message type (package/Name)".into(),
            });
        }
        if let Some(p) = self.publications.lock().expect("publications").get(topic) {
            if p.type_name == ty {
                return Ok(p.clone());
            }
            return Err(RosError::Other(format!(
                "{topic} is already published here as {}, not {ty}",
                p.type_name
            )));
        }
        if let Err(e) = self.ensure_definition(&ty) {
            // Not bundled: the subscribers' connection headers will carry it.
            tracing::debug!("{topic}: {e}");
        }
        // Known before the master is told: a subscriber may ask for it at once.
        let publication = self
            .publications
            .lock()
            .expect("publications")
            .entry(topic.to_string())
            .or_insert_with(|| {
                Arc::new(Publication {
                    type_name: ty.clone(),
                    connections: tokio::sync::Mutex::new(Vec::new()),
                })
            })
            .clone();
        let registered = self
            .master
            .call(
                "registerPublisher",
                &[
                    XValue::str(topic),
                    XValue::str(&ros1_type(&ty)),
                    XValue::str(&self.api_uri),
                ],
            )
            .await;
        if let Err(e) = registered {
            self.publications
                .lock()
                .expect("publications")
                .remove(topic);
            return Err(e);
        }
        Ok(publication)
    }

    /// A TCPROS connection: a subscriber of a topic or a client of a service.
    async fn accept(&self, mut stream: TcpStream) -> Result<(), String> {
        stream.set_nodelay(true).map_err(|e| e.to_string())?;
        let header = tokio::time::timeout(PEER_LIMIT, wire::read_header(&mut stream))
            .await
            .map_err(|_| "no connection header".to_string())?
            .map_err(|e| e.to_string())?;
        if header.contains_key("service") {
            self.serve_client(stream, &header).await
        } else {
            self.accept_subscriber(stream, &header).await
        }
    }

    async fn accept_subscriber(
        &self,
        mut stream: TcpStream,
        header: &BTreeMap<String, String>,
    ) -> Result<(), String> {
        let topic = header.get("topic").cloned().unwrap_or_default();
        let publication = self
            .publications
            .lock()
            .expect("publications")
            .get(&topic)
            .cloned();
        let Some(publication) = publication else {
            let refuse = wire::encode_header(&[("error", &format!("not a publisher of {topic}"))]);
            let _ = stream.write_all(&refuse).await;
            return Err(format!(
                "a subscriber asked for {topic}, which is not published here"
            ));
        };
        let ty = &publication.type_name;
        let theirs = header.get("md5sum").map(String::as_str).unwrap_or("*");
        let peer = format!("the subscriber {}", caller(header));
        let checked = if theirs == "*" {
            // `rostopic echo` and the like take any type: ours, if we know it.
            wire::md5sum(&self.wire, ty).map_err(|_| {
                format!("no definition of {ty} is known yet (the subscriber sent none)")
            })
        } else {
            let asked = header.get("type").map(|t| normalize_type(t));
            match asked {
                Some(t) if t != *ty && t != "*" => {
                    Err(format!("it wants {t}, {topic} is published here as {ty}"))
                }
                _ => {
                    let text = header.get("message_definition").map_or("", String::as_str);
                    let ours = |n: &str| self.ensure_definition(n).is_ok();
                    wire::learn(&self.wire, ty, text, theirs, &ours)
                        .map(|()| theirs.to_string())
                        .map_err(|e| e.to_string())
                }
            }
        };
        let ours = match checked {
            Ok(md5) => md5,
            Err(e) => {
                let why = refused(&topic, &peer, e);
                let _ = stream
                    .write_all(&wire::encode_header(&[("error", &why)]))
                    .await;
                return Err(why);
            }
        };
        let definition = wire::full_text(&self.wire, ty).map_err(|e| e.to_string())?;
        let ros1 = ros1_type(ty);
        let caller = self.master.caller_id.clone();
        let answer = wire::encode_header(&[
            ("callerid", &caller),
            ("md5sum", &ours),
            ("type", &ros1),
            ("message_definition", &definition),
            ("latching", "0"),
            ("topic", &topic),
        ]);
        stream.write_all(&answer).await.map_err(|e| e.to_string())?;
        let (mut read, write) = stream.into_split();
        let id = self.next_listener.fetch_add(1, Ordering::Relaxed);
        publication.connections.lock().await.push((id, write));
        // Subscribers send nothing more; reading finds the connection's end, and a
        // subscriber gone is no longer counted as connected.
        let mut sink = [0u8; 256];
        while matches!(read.read(&mut sink).await, Ok(n) if n > 0) {}
        publication
            .connections
            .lock()
            .await
            .retain(|(i, _)| *i != id);
        Ok(())
    }

    /// ROS 1 definitions of `ty` and what it nests, translated from the bundle where no
    /// peer has sent one.
    pub(crate) fn ensure_definition(&self, ty: &str) -> Result<(), RosError> {
        let ty = normalize_type(ty);
        let kind = ty.split('/').nth(1).unwrap_or("msg");
        if kind == "srv" {
            let parts = ["_Request", "_Response"].map(|s| format!("{ty}{s}"));
            if parts.iter().all(|p| self.wire.has(p)) {
                return Ok(());
            }
            let texts: Vec<String> = parts
                .iter()
                .map(|p| self.translate(p))
                .collect::<Result<_, _>>()?;
            return self
                .wire
                .add(&ty, &texts.join("---\n"))
                .map_err(|e| other(&ty, e));
        }
        if self.wire.has(&ty) {
            return Ok(());
        }
        if ty == "std_msgs/msg/Header" {
            // ROS 1's (with `seq`), not the bundle's ROS 2 one.
            return self.wire.add(&ty, wire::HEADER).map_err(|e| other(&ty, e));
        }
        let text = self.translate(&ty)?;
        self.wire.add(&ty, &text).map_err(|e| other(&ty, e))
    }

    /// The ROS 1 text of a bundled ROS 2 definition (nested types added on the way).
    fn translate(&self, ty: &str) -> Result<String, RosError> {
        let bundled = Interfaces::bundled();
        let def = bundled.message(ty).map_err(|e| other(ty, e))?;
        let mut text = String::new();
        for c in &def.constants {
            text.push_str(&format!("{} {}={}\n", c.type_name, c.name, c.value));
        }
        for f in &def.fields {
            let token = match &f.base {
                BaseType::Primitive(p) => p.name().to_string(),
                BaseType::Message(m) if m == "builtin_interfaces/msg/Time" => "time".into(),
                BaseType::Message(m) if m == "builtin_interfaces/msg/Duration" => "duration".into(),
                BaseType::Message(m) if m == "std_msgs/msg/Header" => {
                    if !self.wire.has(m) {
                        self.wire.add(m, wire::HEADER).map_err(|e| other(m, e))?;
                    }
                    "std_msgs/Header".into()
                }
                BaseType::Message(m) => {
                    self.ensure_definition(m)?;
                    ros1_type(m)
                }
            };
            let shape = match f.shape {
                Shape::Single => String::new(),
                Shape::Array(n) => format!("[{n}]"),
                Shape::Sequence { .. } => "[]".into(),
            };
            text.push_str(&format!("{token}{shape} {}\n", f.name));
        }
        Ok(text)
    }

    // ------------------------------------------------------------ serving

    /// Serve `service` (of `type_name`, a bundled definition) with `handler`.
    pub async fn serve(
        &self,
        service: &str,
        type_name: &str,
        handler: Handler,
    ) -> Result<(), RosError> {
        let ty = normalize_type(type_name);
        self.ensure_definition(&ty)?;
        let md5 = wire::service_md5sum(&self.wire, &ty).map_err(|e| other(&ty, e))?;
        self.services.lock().expect("services").insert(
            service.to_string(),
            Arc::new(Served {
                type_name: ty,
                md5,
                handler,
            }),
        );
        self.master
            .call(
                "registerService",
                &[
                    XValue::str(service),
                    XValue::str(&self.service_uri()),
                    XValue::str(&self.api_uri),
                ],
            )
            .await
            .map(|_| ())
    }

    fn service_uri(&self) -> String {
        format!("rosrpc://{}:{}", self.host, self.tcpros_port)
    }

    /// Set a parameter, deleted again when the node leaves.
    pub(crate) async fn set_param(&self, key: &str, value: XValue) -> Result<(), RosError> {
        self.master
            .call("setParam", &[XValue::str(key), value])
            .await?;
        self.params.lock().expect("params").push(key.to_string());
        Ok(())
    }

    async fn serve_client(
        &self,
        mut stream: TcpStream,
        header: &BTreeMap<String, String>,
    ) -> Result<(), String> {
        let service = header.get("service").cloned().unwrap_or_default();
        let served = self
            .services
            .lock()
            .expect("services")
            .get(&service)
            .cloned();
        let theirs = header.get("md5sum").map(String::as_str).unwrap_or("*");
        let served = match served {
            None => Err(format!("{service} is not served here")),
            Some(s) if theirs != "*" && theirs != s.md5 => Err(refused(
                &service,
                &format!("the client {}", caller(header)),
                format!("md5sums do not match: [{theirs}] vs. [{}]", s.md5),
            )),
            Some(s) => Ok(s),
        };
        let served = match served {
            Ok(s) => s,
            Err(why) => {
                let _ = stream
                    .write_all(&wire::encode_header(&[("error", &why)]))
                    .await;
                return Err(why);
            }
        };
        let ros1 = ros1_type(&served.type_name);
        let caller = self.master.caller_id.clone();
        let answer = wire::encode_header(&[
            ("callerid", &caller),
            ("md5sum", &served.md5),
            ("type", &ros1),
            ("request_type", &format!("{ros1}Request")),
            ("response_type", &format!("{ros1}Response")),
        ]);
        stream.write_all(&answer).await.map_err(|e| e.to_string())?;
        if header.get("probe").is_some_and(|p| p == "1") {
            return Ok(());
        }
        let ty = &served.type_name;
        // One request per connection unless the client keeps it (`persistent`).
        let idle = match header.get("persistent").map(String::as_str) {
            Some("1") => SERVICE_IDLE,
            _ => PEER_LIMIT,
        };
        while let Ok(Ok(frame)) = tokio::time::timeout(idle, wire::read_frame(&mut stream)).await {
            let outcome = match cdr::decode_ros1(&self.wire, &format!("{ty}_Request"), &frame) {
                Ok(request) => (served.handler)(request).await.and_then(|response| {
                    cdr::encode_ros1(&self.wire, &format!("{ty}_Response"), &response)
                        .map_err(|e| e.to_string())
                }),
                Err(e) => Err(e.to_string()),
            };
            let (ok, body) = match outcome {
                Ok(bytes) => (1u8, bytes),
                Err(e) => (0u8, e.into_bytes()),
            };
            stream.write_all(&[ok]).await.map_err(|e| e.to_string())?;
            wire::write_frame(&mut stream, &body)
                .await
                .map_err(|e| e.to_string())?;
        }
        Ok(())
    }

    /// Whether `ty` is tried for the first time (and now marked tried).
    pub(crate) fn tried(&self, ty: &str) -> bool {
        self.tried.lock().expect("tried").insert(ty.to_string())
    }

    fn me(&self) -> Option<Arc<Node>> {
        self.this.upgrade()
    }

    /// Make `type_name` (used on `topic`) known: from the bundle, else from a
    /// publisher's connection header (`publishers`: their node names), else from the
    /// first subscriber to connect to a publication of it.
    pub async fn learn(
        self: &Arc<Self>,
        topic: &str,
        type_name: &str,
        publishers: &[String],
    ) -> Result<(), RosError> {
        let ty = normalize_type(type_name);
        if ty.split('/').nth(1) == Some("srv") {
            // ROS 1 servers send no definitions: the bundle's, checked by md5sum at the call.
            return self.ensure_definition(&ty);
        }
        if self.wire.has(&ty) || self.ensure_definition(&ty).is_ok() {
            return Ok(());
        }
        let mut why = format!("no peer on {topic} sent a definition of {ty}");
        for node in publishers {
            let uri = match self.master.call("lookupNode", &[XValue::str(node)]).await {
                Ok(XValue::Str(uri)) => uri,
                _ => continue,
            };
            match self.open_publisher(topic, &uri, Some(&ty)).await {
                Ok(_) if self.wire.has(&ty) => return Ok(()),
                Ok((_, other)) => why = format!("{topic} carries {other}, not {ty}"),
                Err(e) => why = e,
            }
        }
        if publishers.is_empty() {
            let publication = self.publication(topic, &ty).await?;
            let until = tokio::time::Instant::now() + PEER_LIMIT;
            while !self.wire.has(&ty) && tokio::time::Instant::now() < until {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            if self.wire.has(&ty) {
                return Ok(());
            }
            if publication.connected().await == 0 {
                why = format!("no subscriber of {topic} connected to say what {ty} is");
            }
        }
        Err(RosError::Encode {
            type_name: ty,
            reason: why,
        })
    }

    /// Unregister every service, publication and subscription, and delete the
    /// parameters set (the node is going away).
    pub(crate) async fn shutdown(&self) {
        let services: Vec<String> = self
            .services
            .lock()
            .expect("services")
            .keys()
            .cloned()
            .collect();
        for s in services {
            let uri = self.service_uri();
            let _ = self
                .master
                .call("unregisterService", &[XValue::str(&s), XValue::str(&uri)])
                .await;
        }
        let params = std::mem::take(&mut *self.params.lock().expect("params"));
        for p in params {
            let _ = self.master.call("deleteParam", &[XValue::str(&p)]).await;
        }
        let pubs: Vec<String> = self
            .publications
            .lock()
            .expect("publications")
            .keys()
            .cloned()
            .collect();
        let mut subs: Vec<String> = self
            .subscriptions
            .lock()
            .expect("subscriptions")
            .keys()
            .map(|(t, _)| t.clone())
            .collect();
        subs.dedup();
        for t in pubs {
            let _ = self
                .master
                .call(
                    "unregisterPublisher",
                    &[XValue::str(&t), XValue::str(&self.api_uri)],
                )
                .await;
        }
        for t in subs {
            let _ = self
                .master
                .call(
                    "unregisterSubscriber",
                    &[XValue::str(&t), XValue::str(&self.api_uri)],
                )
                .await;
        }
    }
}

impl Publication {
    /// Send `message` to every connected subscriber; how many it reached.
    pub async fn send(&self, wire_table: &Interfaces, message: &Value) -> Result<usize, RosError> {
        let bytes = cdr::encode_ros1(wire_table, &self.type_name, message).map_err(|e| {
            RosError::Encode {
                type_name: self.type_name.clone(),
                reason: e.to_string(),
            }
        })?;
        let mut conns = self.connections.lock().await;
        // To every subscriber at once, each within `PEER_LIMIT`: one that stops reading
        // is dropped, and cannot hold up the others (the brake's zero among them).
        let bytes = &bytes;
        let writes = conns.drain(..).map(|(id, mut c)| async move {
            let sent = tokio::time::timeout(PEER_LIMIT, wire::write_frame(&mut c, bytes)).await;
            matches!(sent, Ok(Ok(()))).then_some((id, c))
        });
        let kept: Vec<_> = futures::future::join_all(writes)
            .await
            .into_iter()
            .flatten()
            .collect();
        let n = kept.len();
        *conns = kept;
        Ok(n)
    }

    pub async fn connected(&self) -> usize {
        self.connections.lock().await.len()
    }
}

/// Who a connection header says it is from, for messages.
fn caller(header: &BTreeMap<String, String>) -> String {
    header
        .get("callerid")
        .map_or_else(|| "(no callerid)".to_string(), |c| short(c))
}

/// At most 80 characters of what a peer sent, for messages.
fn short(s: &str) -> String {
    s.chars().take(80).collect()
}

fn reply(code: i64, status: &str, value: XValue) -> XValue {
    XValue::Array(vec![XValue::Int(code), XValue::str(status), value])
}

/// Most publishers of one topic read at once (what a `publisherUpdate` may add).
const MAX_PUBLISHERS: usize = 256;

/// A subscription's key: the topic and the type it is read as (`None`: any).
type SubKey = (String, Option<String>);

#[derive(Default)]
struct Subscription {
    listeners: Vec<(u64, tokio::sync::mpsc::UnboundedSender<Value>)>,
    readers: std::collections::BTreeMap<String, JoinHandle<()>>,
}

/// A listener on a topic; dropping it ends its share of the subscription.
pub(crate) struct Listener {
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
    fn connect_publishers(&self, key: &SubKey, uris: &[String]) {
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
    async fn open_publisher(
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
