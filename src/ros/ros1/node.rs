//! ferrosa's own ROS 1 node: the XML-RPC API other nodes and the master call on it
//! (`requestTopic`, `publisherUpdate`, `getPid`, …), the TCPROS server its topics'
//! subscribers connect to, its publications and services; its subscriptions are in
//! `subscription`.
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

use self::subscription::{SubKey, Subscription, MAX_PUBLISHERS};
use super::master::Master;
use super::wire::{self, ros1_type};
use super::xmlrpc::{self, XValue};
use crate::ros::msg::{normalize_type, BaseType, Interfaces, Shape};
use crate::ros::{cdr, RosError};

mod subscription;

/// How long a peer has to answer a connection or a call.
pub const PEER_LIMIT: Duration = Duration::from_secs(3);

/// How long a persistent service client may wait between requests (others send theirs
/// within `PEER_LIMIT`).
pub const SERVICE_IDLE: Duration = Duration::from_secs(600);

pub struct Node {
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
pub struct Publication {
    pub type_name: String,
    connections: tokio::sync::Mutex<Vec<(u64, tokio::net::tcp::OwnedWriteHalf)>>,
}

/// What serves one service: the request in, the response or the failure's text out.
pub type Handler =
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
        let weak = Arc::downgrade(&node);
        tokio::spawn(async move {
            while let Ok((stream, _)) = api.accept().await {
                let Some(node) = weak.upgrade() else { return };
                tokio::spawn(async move { node.serve_api(stream).await });
            }
        });
        let weak = Arc::downgrade(&node);
        tokio::spawn(async move {
            while let Ok((stream, _)) = tcpros.accept().await {
                let Some(node) = weak.upgrade() else { return };
                tokio::spawn(async move {
                    if let Err(e) = node.accept(stream).await {
                        tracing::debug!("TCPROS connection: {e}");
                    }
                });
            }
        });
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
    pub fn ensure_definition(&self, ty: &str) -> Result<(), RosError> {
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
    pub async fn set_param(&self, key: &str, value: XValue) -> Result<(), RosError> {
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
    pub fn tried(&self, ty: &str) -> bool {
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
    pub async fn shutdown(&self) {
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
