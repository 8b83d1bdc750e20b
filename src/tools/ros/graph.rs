//! Reading the graph: nodes, topics and services, listed (with counts, filters and a
//! one-line summary) and described one at a time.

use std::collections::BTreeSet;

use serde_json::{json, Value};

use super::base::{
    absolute, no_topic, require_node, resolve_loose, resolved_note, service_type, typed,
    with_resolved, Filter, ListArgs, NodeArgs, Ros, ServiceArgs, TopicArgs,
};
use crate::ros::cdr;
use crate::tool::{Effect, Tool, ToolContext, ToolError};

pub(crate) struct NodeList(pub(super) Ros);

impl Tool for NodeList {
    type Args = ListArgs;
    const NAME: &'static str = "ros_node_list";
    const EFFECT: Effect = Effect::Observes;
    const LISTS: Option<&'static str> = Some("node");
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

pub(crate) struct NodeInfo(pub(super) Ros);

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
        // Each list by name, the node's own before what the client library gives
        // every node (parameter and type description services, `/rosout`).
        let said = |items: &[Value], field: &str, noun: &str| -> String {
            let names =
                super::base::own_first(items.iter().filter_map(|v| Some((v, v[field].as_str()?))));
            super::base::summary(noun, &names)
        };
        let summary = format!(
            "node {node} publishes {}; subscribes to {}; serves {}",
            said(&p, "topic", "topics"),
            said(&s, "topic", "topics"),
            said(&sv, "service", "services")
        );
        Ok(json!({
            "summary": summary,
            "node": node,
            "counts": {"publishers": p.len(), "subscribers": s.len(), "services": sv.len(), "clients": c.len()},
            "publishers": p, "subscribers": s, "services": sv, "clients": c,
        }))
    }
}

pub(crate) struct TopicList(pub(super) Ros);

impl Tool for TopicList {
    type Args = ListArgs;
    const NAME: &'static str = "ros_topic_list";
    const EFFECT: Effect = Effect::Observes;
    const LISTS: Option<&'static str> = Some("topic");
    fn description(&self) -> String {
        "List ROS topics with their message types.".into()
    }
    async fn call(&self, a: ListArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let f = Filter::new(a.pattern, a.namespace)?;
        let g = self.0.snapshot().await?;
        Ok(f.listing("topics", typed("topic", g.topics())))
    }
}

pub(crate) struct TopicInfo(pub(super) Ros);

impl Tool for TopicInfo {
    type Args = TopicArgs;
    const NAME: &'static str = "ros_topic_info";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "A topic's type, publishers and subscribers (by node) and their QoS.".into()
    }
    async fn call(&self, a: TopicArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let asked = absolute(&a.topic);
        let g = self.0.snapshot().await?;
        let topics = g.topics();
        let topic = match topics.contains_key(&asked) {
            true => asked.clone(),
            false => resolve_loose(&asked, &topics).ok_or_else(|| no_topic(&asked, &g))?,
        };
        let types = &topics[&topic];
        let side = |eps: &[crate::ros::graph::TopicEndpoint]| -> Vec<Value> {
            eps.iter()
                .filter(|e| e.topic == topic)
                .map(|e| json!({"node": e.node, "qos": e.qos}))
                .collect()
        };
        let (p, s) = (side(&g.publishers), side(&g.subscribers));
        let type_name = types.iter().cloned().collect::<Vec<_>>().join(", ");
        let note = (topic != asked).then(|| resolved_note(&asked, &topic, &type_name, "described"));
        let out = json!({
            "topic": topic, "type": type_name,
            "publisher_count": p.len(), "subscriber_count": s.len(),
            "publishers": p, "subscribers": s,
        });
        Ok(with_resolved(out, note))
    }
}

pub(crate) struct ServiceList(pub(super) Ros);

impl Tool for ServiceList {
    type Args = ListArgs;
    const NAME: &'static str = "ros_service_list";
    const EFFECT: Effect = Effect::Observes;
    const LISTS: Option<&'static str> = Some("service");
    fn description(&self) -> String {
        "List ROS services with their types.".into()
    }
    async fn call(&self, a: ListArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let f = Filter::new(a.pattern, a.namespace)?;
        let g = self.0.snapshot().await?;
        Ok(f.listing("services", typed("service", g.services())))
    }
}

pub(crate) struct ServiceInfo(pub(super) Ros);

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
        let definition = ifaces.source(&ty).ok();
        // The fields as a definition says them ("request: r (uint8), ..."): the
        // templates' zeros, summarized as values, read as the service's state ("what
        // colour is the pen?" was answered "request.r 0").
        let served: Vec<&str> = servers.iter().filter_map(|s| s.as_deref()).collect();
        let served = if served.is_empty() {
            "none".to_string()
        } else {
            served.join(" ")
        };
        let mut summary = format!("service {service}, type {ty}, servers {served}");
        if let Some(d) = &definition {
            summary.push_str(&format!("; {}", super::iface::fields(d, &ty, Some(ifaces))));
        }
        Ok(
            json!({"summary": summary, "service": service, "type": ty, "servers": servers,
                  "example": {"request": request, "response": response},
                  "definition": definition}),
        )
    }
}
