//! Topics' traffic: reading messages, measuring rates, publishing one message.

use std::time::Duration;

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Map, Value};

use super::base::{
    absolute, failed, typed_by_name, with_mux, with_note, with_resolved, Resolved, Ros,
};
use crate::ros::Graph;
use crate::tool::schema::schema_for;
use crate::tool::{Effect, Tool, ToolContext, ToolError};

/// The topics some node publishes: what reading a topic can hear. A topic only
/// subscribed to (a command topic: `cmd_vel`, a joint command) is silent.
fn published(g: &Graph) -> Vec<String> {
    let mut out: Vec<String> = g
        .publishers
        .iter()
        .map(|e| e.topic.clone())
        .filter(|t| !t.contains("/_action/"))
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// `Args`'s schema with its `topic` a choice of the topics published now, or any other
/// (`reading::bound` holds it to those the request points at, and keeps a name the
/// operator writes): a reading tool is offered the topics it can hear. `None` while
/// nothing is published.
fn reading<A: JsonSchema>(ros: &Ros) -> Option<Value> {
    let g = crate::ros::graph_now(ros.graph.as_ref())?;
    let topics = published(&g);
    if topics.is_empty() {
        return None;
    }
    // Closed and bounded as the declared arguments are (`ToolSpec::new`).
    let mut schema = crate::tool::ToolSpec::new("reading", "", schema_for::<A>())
        .ok()?
        .parameters;
    schema["properties"]["topic"] =
        json!({"anyOf": [{"type": "string", "enum": topics}, {"type": "string"}]});
    Some(schema)
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct EchoArgs {
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

pub(crate) struct TopicEcho(pub(super) Ros);

impl Tool for TopicEcho {
    type Args = EchoArgs;
    const NAME: &'static str = "ros_topic_echo";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Read the latest messages on a topic (e.g. a pose, a battery state), as JSON.".into()
    }
    async fn call(&self, a: EchoArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let count = a.count.unwrap_or(1).clamp(1, 20) as usize;
        let window =
            Duration::from_secs_f64(a.timeout_s.unwrap_or(3.0).clamp(0.1, 10.0)).min(cx.timeout);
        let Resolved {
            topic,
            type_name: ty,
            note: resolved,
        } = self.0.read_topic(&absolute(&a.topic)).await?;
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
        Ok(with_resolved(out, resolved))
    }

    fn live_parameters(&self) -> Option<Value> {
        reading::<EchoArgs>(&self.0)
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct HzArgs {
    /// Topic name.
    pub topic: String,
    /// Seconds to measure, 0.5 to 10 (default 2).
    #[serde(default)]
    #[schemars(range(min = 0.5, max = 10.0))]
    pub window_s: Option<f64>,
}

pub(crate) struct TopicHz(pub(super) Ros);

impl Tool for TopicHz {
    type Args = HzArgs;
    const NAME: &'static str = "ros_topic_hz";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Measure how often a topic publishes (messages per second).".into()
    }
    async fn call(&self, a: HzArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let window =
            Duration::from_secs_f64(a.window_s.unwrap_or(2.0).clamp(0.5, 10.0)).min(cx.timeout);
        let Resolved {
            topic,
            type_name: ty,
            note: resolved,
        } = self.0.read_topic(&absolute(&a.topic)).await?;
        let samples = self
            .0
            .graph
            .subscribe(&topic, Some(&ty), 100_000, window)
            .await
            .map_err(failed)?;
        // A latched topic's history arrives at once on joining: not a rate.
        let live: Vec<f64> = samples.iter().filter(|s| !s.history).map(|s| s.t).collect();
        let rate = match (live.first(), live.last()) {
            (Some(a), Some(b)) if live.len() > 1 && b > a => (live.len() - 1) as f64 / (b - a),
            _ => 0.0,
        };
        let window_s = window.as_secs_f64();
        let mut out = json!({"topic": topic, "messages": live.len(), "window_s": window_s,
                  "rate_hz": (rate * 100.0).round() / 100.0});
        if live.len() < 2 {
            out["note"] = json!(format!(
                "{} message(s) in {window_s:.1} s: too few for a rate; the topic publishes \
                 less often, or a longer window_s (up to 10) measures it",
                live.len()
            ));
        }
        Ok(with_resolved(out, resolved))
    }

    fn live_parameters(&self) -> Option<Value> {
        reading::<HzArgs>(&self.0)
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct PublishArgs {
    /// Topic name, e.g. "/turtle1/cmd_vel".
    pub topic: String,
    /// The message fields, e.g. {"linear": {"x": 1.0}}; absent fields are zero.
    pub message: Map<String, Value>,
    /// Message type, e.g. "geometry_msgs/msg/Twist"; taken from the topic when omitted.
    #[serde(default)]
    pub message_type: Option<String>,
}

pub(crate) struct TopicPublish(pub(super) Ros);

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
        let sent = self
            .0
            .graph
            .publish(&topic, &ty, message.clone())
            .await
            .map_err(failed)?;
        let out = json!({"published": true, "topic": sent.topic, "type": crate::ros::msg::normalize_type(&ty),
                         "message": sent.sent.clone().unwrap_or(message)});
        Ok(with_note(with_mux(out, &topic, &sent), sent.note))
    }

    /// One branch per topic of a known type that some node subscribes to (a message
    /// nobody reads moves nothing; publishing on a topic the robot only publishes
    /// would feign its state), its message typed by that type, and one for any other
    /// topic (`reading::bound` holds its name to those the operator wrote), which needs
    /// `message_type`. Every topic when none is subscribed to.
    fn live_parameters(&self) -> Option<Value> {
        let g = crate::ros::graph_now(self.0.graph.as_ref())?;
        let mut topics = g.topics();
        let heard: std::collections::BTreeSet<&str> =
            g.subscribers.iter().map(|e| e.topic.as_str()).collect();
        if topics.keys().any(|t| heard.contains(t.as_str())) {
            topics.retain(|t, _| heard.contains(t.as_str()));
        }
        let open = json!({
            "type": "object",
            "properties": {"topic": {"type": "string"},
                           "message": {"type": "object", "additionalProperties": true},
                           "message_type": {"type": "string"}},
            "required": ["topic", "message", "message_type"],
            "additionalProperties": false,
        });
        typed_by_name(&self.0, topics, ("topic", "message", ""), true, open)
    }
}
