//! The ROS tools, `ros_<noun>_<verb>`, over any `RosGraph` (ROS 2, the sim, the fake).
//! Each returns structured JSON with counts and the filters applied, so a small model
//! reads answers instead of counting; listings take a `pattern` (regex) and a
//! `namespace`. String arguments pass the policy's deny-list before a call runs, and
//! listings are redacted after, like every tool.
//!
//! Parameters are reached through the node's `rcl_interfaces` services, logs through
//! `/rosout`; the action tools are in `action`.

mod action;

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Duration;

use regex::Regex;
use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Map, Value};

use crate::ros::{cdr, Graph, RosError, RosGraph};
use crate::tool::{Effect, Package, Tool, ToolContext, ToolError};

/// Every ROS tool over `graph`.
pub fn package(graph: Arc<dyn RosGraph>) -> Package {
    let g = || Ros {
        graph: graph.clone(),
    };
    Package::new("ros")
        .with(NodeList(g()))
        .with(NodeInfo(g()))
        .with(TopicList(g()))
        .with(TopicInfo(g()))
        .with(TopicEcho(g()))
        .with(TopicHz(g()))
        .with(TopicPublish(g()))
        .with(ServiceList(g()))
        .with(ServiceInfo(g()))
        .with(ServiceCall(g()))
        .with(ParamList(g()))
        .with(ParamGet(g()))
        .with(ParamSet(g()))
        .with(InterfaceShow(g()))
        .with(LogRead(g()))
        .with(action::ActionList(g()))
        .with(action::ActionSendGoal(g()))
        .with(action::ActionCancel(g()))
}

#[derive(Clone)]
pub struct Ros {
    graph: Arc<dyn RosGraph>,
}

/// A ROS failure as the model reads it (also used by the turtle tools).
pub(crate) fn failed(e: RosError) -> ToolError {
    ToolError::Failed(e.to_string())
}

impl Ros {
    async fn snapshot(&self) -> Result<Graph, ToolError> {
        self.graph.graph().await.map_err(failed)
    }

    /// The type of `topic`, or a "no topic" error with near names.
    async fn topic_type(&self, topic: &str) -> Result<String, ToolError> {
        let g = self.snapshot().await?;
        g.topic_type(topic).ok_or_else(|| no_topic(topic, &g))
    }
}

/// "no topic /x; did you mean /y?" or, with nothing near, which tool lists them.
fn not_found<'a>(
    kind: &str,
    wanted: &str,
    names: impl Iterator<Item = &'a String>,
    list_tool: &str,
) -> ToolError {
    let near = suggest(wanted, names);
    ToolError::Failed(if near.is_empty() {
        format!("no {kind} {wanted}; call {list_tool} to see the {kind}s")
    } else {
        format!("no {kind} {wanted}; did you mean {}?", near.join(" or "))
    })
}

fn require_node(g: &Graph, node: &str) -> Result<(), ToolError> {
    if g.nodes.iter().any(|n| n == node) {
        Ok(())
    } else {
        Err(ToolError::Failed(format!(
            "no node {node}; running nodes: {}",
            g.nodes.join(", ")
        )))
    }
}

/// `{name, type}` items of a name → types map, keyed by their name for filtering.
fn typed(item: &str, map: BTreeMap<String, BTreeSet<String>>) -> Vec<(String, Value)> {
    map.into_iter()
        .map(|(name, types)| {
            let ty = types.into_iter().collect::<Vec<_>>().join(", ");
            (name.clone(), json!({item: name, "type": ty}))
        })
        .collect()
}

/// `pattern` and `namespace` of a listing, compiled.
struct Filter {
    pattern: Option<Regex>,
    namespace: Option<String>,
    echo: Value,
}

impl Filter {
    fn new(pattern: Option<String>, namespace: Option<String>) -> Result<Filter, ToolError> {
        let re = match pattern.as_deref().filter(|p| !p.is_empty()) {
            Some(p) => Some(
                Regex::new(p)
                    .map_err(|e| ToolError::InvalidArguments(format!("pattern {p:?}: {e}")))?,
            ),
            None => None,
        };
        let namespace = namespace.filter(|n| !n.is_empty() && n != "/").map(|n| {
            if n.starts_with('/') {
                n
            } else {
                format!("/{n}")
            }
        });
        Ok(Filter {
            echo: json!({"pattern": pattern, "namespace": namespace}),
            pattern: re,
            namespace,
        })
    }

    /// `{count, <key>: the items whose names the filters keep, filters}`; when they keep
    /// nothing but there is something, the unfiltered listing too, so a wrong filter is
    /// seen as one.
    fn listing(&self, key: &str, items: Vec<(String, Value)>) -> Value {
        let (kept_names, kept): (Vec<&str>, Vec<&Value>) = items
            .iter()
            .filter(|(n, _)| self.keeps(n))
            .map(|(n, v)| (n.as_str(), v))
            .unzip();
        let mut out = json!({"summary": summary(key, &kept_names), "count": kept.len(), key: kept, "filters": self.echo});
        let filtered = self.pattern.is_some() || self.namespace.is_some();
        if kept.is_empty() && !items.is_empty() && filtered {
            let (all_names, all): (Vec<&str>, Vec<&Value>) =
                items.iter().map(|(n, v)| (n.as_str(), v)).unzip();
            out["summary"] = json!(format!(
                "No {key} matched the filters; without them, {}",
                summary(key, &all_names)
            ));
            out[format!("all_{key}")] = json!(all);
            out["all_count"] = json!(all.len());
        }
        out
    }

    fn keeps(&self, name: &str) -> bool {
        let ns_ok = self.namespace.as_deref().is_none_or(|ns| {
            name == ns || name.starts_with(&format!("{}/", ns.trim_end_matches('/')))
        });
        ns_ok && self.pattern.as_ref().is_none_or(|re| re.is_match(name))
    }
}

/// "2 nodes: /a, /b" (at most 12 names, then "and N more"), the sentence a small model
/// copies into its answer instead of counting a JSON array itself.
fn summary(key: &str, names: &[&str]) -> String {
    const SHOWN: usize = 12;
    let noun = if names.len() == 1 {
        key.trim_end_matches('s')
    } else {
        key
    };
    if names.is_empty() {
        return format!("0 {key}");
    }
    let mut text = format!(
        "{} {noun}: {}",
        names.len(),
        names[..names.len().min(SHOWN)].join(", ")
    );
    if names.len() > SHOWN {
        text.push_str(&format!(" and {} more", names.len() - SHOWN));
    }
    text
}

fn absolute(name: &str) -> String {
    let name = name.trim();
    if name.starts_with('/') {
        name.to_string()
    } else {
        format!("/{name}")
    }
}

/// Names close to `wanted`, for "no such X" answers.
fn suggest<'a>(wanted: &str, names: impl Iterator<Item = &'a String>) -> Vec<String> {
    let tail = wanted.rsplit('/').next().unwrap_or(wanted).to_lowercase();
    names
        .filter(|n| {
            let n = n.to_lowercase();
            !tail.is_empty()
                && (n.contains(&tail) || tail.contains(n.rsplit('/').next().unwrap_or("")))
        })
        .take(5)
        .cloned()
        .collect()
}

#[derive(Deserialize, JsonSchema)]
pub struct ListArgs {
    /// Only names matching this regular expression; leave out to list all.
    #[serde(default)]
    pub pattern: Option<String>,
    /// Only names under this namespace; leave out to list all.
    #[serde(default)]
    #[schemars(regex(pattern = r"^/[A-Za-z0-9_/]*$"))]
    pub namespace: Option<String>,
}

pub struct NodeList(Ros);

impl Tool for NodeList {
    type Args = ListArgs;
    const NAME: &'static str = "ros_node_list";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "List the running ROS nodes (names and count).".into()
    }
    async fn call(&self, a: ListArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let f = Filter::new(a.pattern, a.namespace)?;
        let g = self.0.snapshot().await?;
        let nodes = g.nodes.iter().map(|n| (n.clone(), json!(n))).collect();
        Ok(f.listing("nodes", nodes))
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct NodeArgs {
    /// Node name, e.g. "/turtlesim".
    pub node: String,
}

pub struct NodeInfo(Ros);

impl Tool for NodeInfo {
    type Args = NodeArgs;
    const NAME: &'static str = "ros_node_info";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "What one ROS node publishes, subscribes to and serves.".into()
    }
    async fn call(&self, a: NodeArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let node = absolute(&a.node);
        let g = self.0.snapshot().await?;
        require_node(&g, &node)?;
        let mine = |n: &Option<String>| n.as_deref() == Some(node.as_str());
        let topics = |eps: &[crate::ros::graph::TopicEndpoint]| -> Vec<Value> {
            let set: BTreeSet<(String, String)> = eps
                .iter()
                .filter(|e| mine(&e.node) && !e.topic.contains("/_action/"))
                .map(|e| (e.topic.clone(), e.type_name.clone()))
                .collect();
            set.into_iter()
                .map(|(t, ty)| json!({"topic": t, "type": ty}))
                .collect()
        };
        let services = |eps: &[crate::ros::graph::ServiceEndpoint]| -> Vec<Value> {
            let set: BTreeSet<(String, String)> = eps
                .iter()
                .filter(|e| mine(&e.node))
                .map(|e| (e.service.clone(), e.type_name.clone()))
                .collect();
            set.into_iter()
                .map(|(s, ty)| json!({"service": s, "type": ty}))
                .collect()
        };
        let (p, s, sv, c) = (
            topics(&g.publishers),
            topics(&g.subscribers),
            services(&g.servers),
            services(&g.clients),
        );
        Ok(json!({
            "node": node,
            "counts": {"publishers": p.len(), "subscribers": s.len(), "services": sv.len(), "clients": c.len()},
            "publishers": p, "subscribers": s, "services": sv, "clients": c,
        }))
    }
}

pub struct TopicList(Ros);

impl Tool for TopicList {
    type Args = ListArgs;
    const NAME: &'static str = "ros_topic_list";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "List ROS topics with their message types.".into()
    }
    async fn call(&self, a: ListArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let f = Filter::new(a.pattern, a.namespace)?;
        let g = self.0.snapshot().await?;
        Ok(f.listing("topics", typed("topic", g.topics())))
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct TopicArgs {
    /// Topic name, e.g. "/turtle1/pose".
    pub topic: String,
}

pub struct TopicInfo(Ros);

impl Tool for TopicInfo {
    type Args = TopicArgs;
    const NAME: &'static str = "ros_topic_info";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "A topic's type, publishers and subscribers (by node) and their QoS.".into()
    }
    async fn call(&self, a: TopicArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let topic = absolute(&a.topic);
        let g = self.0.snapshot().await?;
        let topics = g.topics();
        let Some(types) = topics.get(&topic) else {
            return Err(no_topic(&topic, &g));
        };
        let side = |eps: &[crate::ros::graph::TopicEndpoint]| -> Vec<Value> {
            eps.iter()
                .filter(|e| e.topic == topic)
                .map(|e| json!({"node": e.node, "qos": e.qos}))
                .collect()
        };
        let (p, s) = (side(&g.publishers), side(&g.subscribers));
        Ok(json!({
            "topic": topic, "type": types.iter().cloned().collect::<Vec<_>>().join(", "),
            "publisher_count": p.len(), "subscriber_count": s.len(),
            "publishers": p, "subscribers": s,
        }))
    }
}

fn no_topic(topic: &str, g: &Graph) -> ToolError {
    not_found("topic", topic, g.topics().keys(), "ros_topic_list")
}

#[derive(Deserialize, JsonSchema)]
pub struct EchoArgs {
    /// Topic name, e.g. "/turtle1/pose".
    pub topic: String,
    /// Messages to collect, 1 to 20 (default 1).
    #[serde(default)]
    #[schemars(range(min = 1, max = 20))]
    pub count: Option<u32>,
    /// Seconds to wait at most, 0.1 to 10 (default 3).
    #[serde(default)]
    #[schemars(range(min = 0.1, max = 10.0))]
    pub timeout_s: Option<f64>,
}

/// Long arrays (images, scans) are cut so one message cannot flood the context.
fn shorten(v: &mut Value) {
    match v {
        Value::Array(items) => {
            if items.len() > 16 {
                let n = items.len();
                items.truncate(16);
                items.push(json!(format!("... {} more of {n}", n - 16)));
            }
            items.iter_mut().for_each(shorten);
        }
        Value::Object(m) => m.values_mut().for_each(shorten),
        _ => {}
    }
}

pub struct TopicEcho(Ros);

impl Tool for TopicEcho {
    type Args = EchoArgs;
    const NAME: &'static str = "ros_topic_echo";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Read the latest messages on a topic (e.g. a pose, a battery state), as JSON.".into()
    }
    async fn call(&self, a: EchoArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let topic = absolute(&a.topic);
        let count = a.count.unwrap_or(1).clamp(1, 20) as usize;
        let window =
            Duration::from_secs_f64(a.timeout_s.unwrap_or(3.0).clamp(0.1, 10.0)).min(cx.timeout);
        let ty = self.0.topic_type(&topic).await?;
        let samples = self
            .0
            .graph
            .subscribe(&topic, Some(&ty), count, window)
            .await
            .map_err(failed)?;
        let messages: Vec<Value> = samples
            .into_iter()
            .map(|mut s| {
                shorten(&mut s.message);
                s.message
            })
            .collect();
        let mut out =
            json!({"topic": topic, "type": ty, "count": messages.len(), "messages": messages});
        if out["count"] == 0 {
            out["note"] = json!(format!(
                "no message within {:.1} s; the publisher may be idle",
                window.as_secs_f64()
            ));
        }
        Ok(out)
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct HzArgs {
    /// Topic name.
    pub topic: String,
    /// Seconds to measure, 0.5 to 10 (default 2).
    #[serde(default)]
    #[schemars(range(min = 0.5, max = 10.0))]
    pub window_s: Option<f64>,
}

pub struct TopicHz(Ros);

impl Tool for TopicHz {
    type Args = HzArgs;
    const NAME: &'static str = "ros_topic_hz";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Measure how often a topic publishes (messages per second).".into()
    }
    async fn call(&self, a: HzArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let topic = absolute(&a.topic);
        let window =
            Duration::from_secs_f64(a.window_s.unwrap_or(2.0).clamp(0.5, 10.0)).min(cx.timeout);
        let ty = self.0.topic_type(&topic).await?;
        let samples = self
            .0
            .graph
            .subscribe(&topic, Some(&ty), 100_000, window)
            .await
            .map_err(failed)?;
        let rate = match (samples.first(), samples.last()) {
            (Some(a), Some(b)) if samples.len() > 1 && b.t > a.t => {
                (samples.len() - 1) as f64 / (b.t - a.t)
            }
            _ => 0.0,
        };
        Ok(
            json!({"topic": topic, "messages": samples.len(), "window_s": window.as_secs_f64(),
                  "rate_hz": (rate * 100.0).round() / 100.0}),
        )
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct PublishArgs {
    /// Topic name, e.g. "/turtle1/cmd_vel".
    pub topic: String,
    /// The message fields, e.g. {"linear": {"x": 1.0}}; absent fields are zero.
    pub message: Map<String, Value>,
    /// Message type, e.g. "geometry_msgs/msg/Twist"; taken from the topic when omitted.
    #[serde(default)]
    pub message_type: Option<String>,
}

pub struct TopicPublish(Ros);

impl Tool for TopicPublish {
    type Args = PublishArgs;
    const NAME: &'static str = "ros_topic_publish";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Publish one message on a topic. Can move the robot.".into()
    }
    async fn call(&self, a: PublishArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let topic = absolute(&a.topic);
        let ty = match a.message_type.filter(|t| !t.is_empty()) {
            Some(t) => t,
            None => {
                let g = self.0.snapshot().await?;
                g.topic_type(&topic).ok_or_else(|| {
                    ToolError::Failed(format!("{topic} has no known type; give message_type"))
                })?
            }
        };
        let message = Value::Object(a.message);
        self.0
            .graph
            .publish(&topic, &ty, message.clone())
            .await
            .map_err(failed)?;
        Ok(
            json!({"published": true, "topic": topic, "type": crate::ros::msg::normalize_type(&ty), "message": message}),
        )
    }
}

pub struct ServiceList(Ros);

impl Tool for ServiceList {
    type Args = ListArgs;
    const NAME: &'static str = "ros_service_list";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "List ROS services with their types.".into()
    }
    async fn call(&self, a: ListArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let f = Filter::new(a.pattern, a.namespace)?;
        let g = self.0.snapshot().await?;
        Ok(f.listing("services", typed("service", g.services())))
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct ServiceArgs {
    /// Service name, e.g. "/spawn".
    pub service: String,
}

fn service_type(g: &Graph, service: &str) -> Result<String, ToolError> {
    let services = g.services();
    match services.get(service).and_then(|t| t.iter().next()) {
        Some(t) => Ok(t.clone()),
        None => Err(not_found(
            "service",
            service,
            services.keys(),
            "ros_service_list",
        )),
    }
}

pub struct ServiceInfo(Ros);

impl Tool for ServiceInfo {
    type Args = ServiceArgs;
    const NAME: &'static str = "ros_service_info";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "A service's type, its servers, and its request and response fields.".into()
    }
    async fn call(&self, a: ServiceArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let service = absolute(&a.service);
        let g = self.0.snapshot().await?;
        let ty = service_type(&g, &service)?;
        let servers: Vec<&Option<String>> = g
            .servers
            .iter()
            .filter(|s| s.service == service)
            .map(|s| &s.node)
            .collect();
        let ifaces = self.0.graph.interfaces();
        let request = cdr::template(ifaces, &format!("{ty}_Request")).ok();
        let response = cdr::template(ifaces, &format!("{ty}_Response")).ok();
        Ok(json!({"service": service, "type": ty, "servers": servers,
                  "request": request, "response": response,
                  "definition": ifaces.source(&ty).ok()}))
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct CallArgs {
    /// Service name, e.g. "/turtle1/teleport_absolute".
    pub service: String,
    /// Request fields, e.g. {"x": 2.0, "y": 3.0}; absent fields are zero.
    #[serde(default)]
    pub request: Option<Map<String, Value>>,
}

pub struct ServiceCall(Ros);

impl Tool for ServiceCall {
    type Args = CallArgs;
    const NAME: &'static str = "ros_service_call";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Call a ROS service with a request and return its response. May act on the robot.".into()
    }
    async fn call(&self, a: CallArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let service = absolute(&a.service);
        let g = self.0.snapshot().await?;
        let ty = service_type(&g, &service)?;
        let request = Value::Object(a.request.unwrap_or_default());
        let response = self
            .0
            .graph
            .call_service(&service, &ty, request, cx.timeout)
            .await
            .map_err(failed)?;
        Ok(json!({"service": service, "type": ty, "response": response}))
    }
}

// ------------------------------------------------------------ parameters

fn node_service(node: &str, which: &str) -> String {
    format!("{}/{which}", absolute(node).trim_end_matches('/'))
}

async fn param_call(
    ros: &Ros,
    node: &str,
    which: &str,
    ty: &str,
    request: Value,
    cx: &ToolContext,
) -> Result<Value, ToolError> {
    let node = absolute(node);
    let g = ros.snapshot().await?;
    require_node(&g, &node)?;
    ros.graph
        .call_service(&node_service(&node, which), ty, request, cx.timeout)
        .await
        .map_err(|e| match e {
            RosError::NoService(_) => {
                ToolError::Failed(format!("{node} has no parameter services"))
            }
            other => failed(other),
        })
}

pub struct ParamList(Ros);

impl Tool for ParamList {
    type Args = NodeArgs;
    const NAME: &'static str = "ros_param_list";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "List the parameters of a ROS node.".into()
    }
    async fn call(&self, a: NodeArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let r = param_call(
            &self.0,
            &a.node,
            "list_parameters",
            "rcl_interfaces/srv/ListParameters",
            json!({"prefixes": [], "depth": 0}),
            cx,
        )
        .await?;
        let names = r["result"]["names"].clone();
        Ok(
            json!({"node": absolute(&a.node), "count": names.as_array().map_or(0, Vec::len), "parameters": names}),
        )
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct ParamArgs {
    /// Node name, e.g. "/turtlesim".
    pub node: String,
    /// Parameter name, e.g. "background_r".
    pub name: String,
}

/// A `rcl_interfaces/ParameterValue` as plain JSON.
fn param_value(v: &Value) -> Value {
    let field = match v["type"].as_u64().unwrap_or(0) {
        1 => "bool_value",
        2 => "integer_value",
        3 => "double_value",
        4 => "string_value",
        5 => "byte_array_value",
        6 => "bool_array_value",
        7 => "integer_array_value",
        8 => "double_array_value",
        9 => "string_array_value",
        _ => return Value::Null,
    };
    v[field].clone()
}

pub struct ParamGet(Ros);

impl Tool for ParamGet {
    type Args = ParamArgs;
    const NAME: &'static str = "ros_param_get";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Read one parameter of a ROS node.".into()
    }
    async fn call(&self, a: ParamArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let r = param_call(
            &self.0,
            &a.node,
            "get_parameters",
            "rcl_interfaces/srv/GetParameters",
            json!({"names": [a.name]}),
            cx,
        )
        .await?;
        let value = param_value(&r["values"][0]);
        if value.is_null() {
            return Err(ToolError::Failed(format!(
                "{} has no parameter {}; call ros_param_list",
                absolute(&a.node),
                a.name
            )));
        }
        Ok(json!({"node": absolute(&a.node), "name": a.name, "value": value}))
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct ParamSetArgs {
    /// Node name, e.g. "/turtlesim".
    pub node: String,
    /// Parameter name, e.g. "background_r".
    pub name: String,
    /// New value: a number, text or true/false.
    pub value: ParamInput,
}

#[derive(Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum ParamInput {
    Bool(bool),
    Number(f64),
    Text(String),
}

pub struct ParamSet(Ros);

impl Tool for ParamSet {
    type Args = ParamSetArgs;
    const NAME: &'static str = "ros_param_set";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Set one parameter of a ROS node. Changes the robot's configuration.".into()
    }
    async fn call(&self, a: ParamSetArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        // Keep the parameter's current type: an integer parameter gets an integer.
        let current = param_call(
            &self.0,
            &a.node,
            "get_parameters",
            "rcl_interfaces/srv/GetParameters",
            json!({"names": [a.name]}),
            cx,
        )
        .await?;
        let kind = current["values"][0]["type"].as_u64().unwrap_or(0);
        let value = match (&a.value, kind) {
            (ParamInput::Bool(b), _) => json!({"type": 1, "bool_value": b}),
            (ParamInput::Number(n), 2) if n.fract() == 0.0 => {
                json!({"type": 2, "integer_value": *n as i64})
            }
            (ParamInput::Number(n), 2) => {
                return Err(ToolError::InvalidArguments(format!(
                    "{} is an integer parameter; {n} is not whole",
                    a.name
                )))
            }
            (ParamInput::Number(n), _) => json!({"type": 3, "double_value": n}),
            (ParamInput::Text(s), _) => json!({"type": 4, "string_value": s}),
        };
        let r = param_call(
            &self.0,
            &a.node,
            "set_parameters",
            "rcl_interfaces/srv/SetParameters",
            json!({"parameters": [{"name": a.name, "value": value}]}),
            cx,
        )
        .await?;
        let result = &r["results"][0];
        if result["successful"] != json!(true) {
            return Err(ToolError::Failed(format!(
                "{} refused: {}",
                absolute(&a.node),
                result["reason"].as_str().unwrap_or("no reason given")
            )));
        }
        Ok(
            json!({"node": absolute(&a.node), "name": a.name, "value": param_value(&value), "set": true}),
        )
    }
}

// ------------------------------------------------------------ interfaces and logs

#[derive(Deserialize, JsonSchema)]
pub struct InterfaceArgs {
    /// Type name, e.g. "geometry_msgs/msg/Twist" or "turtlesim/srv/Spawn".
    #[serde(rename = "type")]
    pub type_name: String,
}

pub struct InterfaceShow(Ros);

impl Tool for InterfaceShow {
    type Args = InterfaceArgs;
    const NAME: &'static str = "ros_interface_show";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Show the fields of a message or service type.".into()
    }
    async fn call(&self, a: InterfaceArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let ifaces = self.0.graph.interfaces();
        let ty = crate::ros::msg::normalize_type(&a.type_name);
        let definition = ifaces
            .source(&ty)
            .map_err(|e| ToolError::Failed(e.to_string()))?;
        let example = if ty.contains("/srv/") {
            json!({"request": cdr::template(ifaces, &format!("{ty}_Request")).ok(),
                   "response": cdr::template(ifaces, &format!("{ty}_Response")).ok()})
        } else {
            cdr::template(ifaces, &ty).unwrap_or(Value::Null)
        };
        Ok(json!({"type": ty, "definition": definition, "example": example}))
    }
}

#[derive(Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Level {
    Debug,
    Info,
    Warn,
    Error,
    Fatal,
}

#[derive(Deserialize, JsonSchema)]
pub struct LogArgs {
    /// Lowest level to show (default info).
    #[serde(default)]
    pub level: Option<Level>,
    /// Only this node's logs, e.g. "turtlesim".
    #[serde(default)]
    pub node: Option<String>,
    /// Last N entries, 1 to 50 (default 10).
    #[serde(default)]
    #[schemars(range(min = 1, max = 50))]
    pub count: Option<u32>,
}

pub struct LogRead(Ros);

impl Tool for LogRead {
    type Args = LogArgs;
    const NAME: &'static str = "ros_log_read";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Read recent ROS log messages from /rosout (warnings, errors, info).".into()
    }
    async fn call(&self, a: LogArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let min = match a.level.unwrap_or(Level::Info) {
            Level::Debug => 10,
            Level::Info => 20,
            Level::Warn => 30,
            Level::Error => 40,
            Level::Fatal => 50,
        };
        let node = a.node.map(|n| n.trim_start_matches('/').replace('/', "."));
        let count = a.count.unwrap_or(10).clamp(1, 50) as usize;
        // /rosout keeps a history for late joiners: collect what arrives in a short window.
        let samples = self
            .0
            .graph
            .subscribe(
                "/rosout",
                Some("rcl_interfaces/msg/Log"),
                5000,
                Duration::from_millis(1500),
            )
            .await
            .map_err(failed)?;
        let mut entries: Vec<Value> = samples
            .into_iter()
            .map(|s| s.message)
            .filter(|m| m["level"].as_u64().unwrap_or(0) >= min)
            .filter(|m| {
                node.as_deref()
                    .is_none_or(|n| m["name"].as_str().unwrap_or("").ends_with(n))
            })
            .map(|m| {
                let level = match m["level"].as_u64().unwrap_or(0) {
                    10 => "debug",
                    20 => "info",
                    30 => "warn",
                    40 => "error",
                    _ => "fatal",
                };
                let t = m["stamp"]["sec"].as_f64().unwrap_or(0.0)
                    + m["stamp"]["nanosec"].as_f64().unwrap_or(0.0) * 1e-9;
                json!({"t": t, "level": level, "node": m["name"], "msg": m["msg"]})
            })
            .collect();
        entries.sort_by(|a, b| {
            a["t"]
                .as_f64()
                .partial_cmp(&b["t"].as_f64())
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        let total = entries.len();
        let entries = entries.split_off(total.saturating_sub(count));
        Ok(
            json!({"count": entries.len(), "matching": total, "entries": entries,
                  "filters": {"level": min, "node": node}}),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::fake::{FakeGraph, Sent};
    use crate::ros::graph::testing::{ep, gid};
    use crate::ros::graph::{GraphCache, NodeEntities};

    fn fake() -> Arc<FakeGraph> {
        let mut cache = GraphCache::default();
        cache.update_participant(
            gid(99),
            vec![NodeEntities {
                name: "turtlesim".into(),
                namespace: "/".into(),
                readers: vec![gid(1), gid(3)],
                writers: vec![gid(2)],
            }],
        );
        let graph = cache.join(&[
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
                "rq/turtle1/teleport_absoluteRequest",
                "turtlesim::srv::dds_::TeleportAbsolute_Request_",
            ),
        ]);
        Arc::new(
            FakeGraph::new()
                .with_graph(graph)
                .with_messages(
                    "/turtle1/pose",
                    vec![json!({"x": 1.0}), json!({"x": 2.0}), json!({"x": 3.0})],
                )
                .with_service("/turtle1/teleport_absolute", json!({})),
        )
    }

    /// Run a tool on a current-thread runtime with a 5 s limit (also the action tests').
    pub(super) fn run<T: Tool>(t: &T, args: Value) -> Result<Value, ToolError> {
        let args: T::Args = serde_json::from_value(args).unwrap();
        let cx = ToolContext {
            timeout: Duration::from_secs(5),
        };
        tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap()
            .block_on(t.call(args, &cx))
    }

    #[test]
    fn listings_count_and_filter() {
        let ros = Ros { graph: fake() };
        let out = run(&NodeList(ros.clone()), json!({})).unwrap();
        assert_eq!(out["count"], 1);
        assert_eq!(out["nodes"][0], "/turtlesim");
        let out = run(&TopicList(ros.clone()), json!({"pattern": "pose"})).unwrap();
        assert_eq!(out["count"], 1);
        assert_eq!(out["topics"][0]["type"], "turtlesim/msg/Pose");
        assert_eq!(out["filters"]["pattern"], "pose");
        let out = run(&TopicList(ros.clone()), json!({"namespace": "turtle1"})).unwrap();
        assert_eq!(out["count"], 2);
        let out = run(&TopicList(ros.clone()), json!({"namespace": "/turtle"})).unwrap();
        assert_eq!(out["count"], 0, "a namespace is a whole path segment");
        assert_eq!(
            out["all_count"], 2,
            "an empty filtered listing shows the unfiltered one"
        );
        assert!(run(&TopicList(ros.clone()), json!({"pattern": "("})).is_err());
        let out = run(&ServiceList(ros.clone()), json!({})).unwrap();
        assert_eq!(out["services"][0]["type"], "turtlesim/srv/TeleportAbsolute");
        let info = run(&NodeInfo(ros.clone()), json!({"node": "turtlesim"})).unwrap();
        assert_eq!(
            info["counts"],
            json!({"publishers": 1, "subscribers": 1, "services": 1, "clients": 0})
        );
    }

    #[test]
    fn echo_hz_and_unknown_topics() {
        let ros = Ros { graph: fake() };
        let out = run(
            &TopicEcho(ros.clone()),
            json!({"topic": "/turtle1/pose", "count": 2}),
        )
        .unwrap();
        assert_eq!(out["count"], 2);
        assert_eq!(out["messages"][1]["x"], 2.0);
        let hz = run(
            &TopicHz(ros.clone()),
            json!({"topic": "/turtle1/pose", "window_s": 3.0}),
        )
        .unwrap();
        assert_eq!(hz["rate_hz"], 1.0);
        let err = run(&TopicEcho(ros.clone()), json!({"topic": "/turtle1/pos"})).unwrap_err();
        assert!(
            err.to_string().contains("did you mean /turtle1/pose"),
            "{err}"
        );
    }

    #[test]
    fn publish_and_call_take_types_from_the_graph() {
        let graph = fake();
        let ros = Ros {
            graph: graph.clone(),
        };
        run(
            &TopicPublish(ros.clone()),
            json!({"topic": "/turtle1/cmd_vel", "message": {"linear": {"x": 1.0}}}),
        )
        .unwrap();
        let out = run(
            &ServiceCall(ros.clone()),
            json!({"service": "turtle1/teleport_absolute", "request": {"x": 1.0}}),
        )
        .unwrap();
        assert_eq!(out["type"], "turtlesim/srv/TeleportAbsolute");
        assert_eq!(
            graph.sent(),
            [
                Sent::Publish {
                    topic: "/turtle1/cmd_vel".into(),
                    type_name: "geometry_msgs/msg/Twist".into(),
                    message: json!({"linear": {"x": 1.0}})
                },
                Sent::Call {
                    service: "/turtle1/teleport_absolute".into(),
                    type_name: "turtlesim/srv/TeleportAbsolute".into(),
                    request: json!({"x": 1.0})
                },
            ]
        );
        let err = run(&ServiceCall(ros), json!({"service": "/teleport"})).unwrap_err();
        assert!(
            err.to_string()
                .contains("did you mean /turtle1/teleport_absolute"),
            "{err}"
        );
    }

    #[test]
    fn interface_show_gives_definition_and_example() {
        let ros = Ros { graph: fake() };
        let out = run(&InterfaceShow(ros), json!({"type": "turtlesim/srv/Spawn"})).unwrap();
        assert!(out["definition"].as_str().unwrap().contains("string name"));
        assert_eq!(out["example"]["request"]["name"], "");
    }
}
