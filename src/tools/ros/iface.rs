//! Interface definitions and the `/rosout` log.

use std::time::Duration;

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use super::base::{failed, Ros};
use crate::ros::cdr;
use crate::tool::{Effect, Tool, ToolContext, ToolError};

#[derive(Deserialize, JsonSchema)]
pub(crate) struct InterfaceArgs {
    /// Type name, e.g. "geometry_msgs/msg/Twist" or "turtlesim/srv/Spawn".
    #[serde(rename = "type")]
    pub type_name: String,
}

pub(crate) struct InterfaceShow(pub(super) Ros);

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
        let summary = format!("{ty}: {}", fields(&definition, &ty, Some(ifaces)));
        Ok(json!({"summary": summary, "type": ty, "definition": definition, "example": example}))
    }
}

/// The fields a definition declares, "name (type)", a service's or an action's parts
/// named ("request: a (int64); response: sum (int64)"): what an operator asking for a
/// type's fields wants said, without its comments and constants.
pub(super) fn fields(
    definition: &str,
    ty: &str,
    nested: Option<&crate::ros::Interfaces>,
) -> String {
    let parts: &[&str] = if ty.contains("/srv/") {
        &["request", "response"]
    } else if ty.contains("/action/") {
        &["goal", "result", "feedback"]
    } else {
        &[]
    };
    let package = ty.split('/').next().unwrap_or_default();
    let mut sections: Vec<Vec<String>> = vec![Vec::new()];
    for line in definition.lines() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line == "---" {
            sections.push(Vec::new());
            continue;
        }
        let Some((ty, rest)) = line.split_once(char::is_whitespace) else {
            continue;
        };
        // A constant ("uint8 OK=0", "int8 WARN = 1") is not a field; a bounded type
        // ("string<=8 id") is.
        if let (Some(name), false) = (rest.split_whitespace().next(), rest.contains('=')) {
            if let Some(last) = sections.last_mut() {
                last.push(field(name, ty, package, nested));
            }
        }
    }
    let sections: Vec<String> = sections
        .into_iter()
        .map(|s| {
            if s.is_empty() {
                "none".to_string()
            } else {
                s.join(", ")
            }
        })
        .collect();
    if sections.len() == parts.len() {
        let named: Vec<String> = parts
            .iter()
            .zip(&sections)
            .map(|(p, s)| format!("{p}: {s}"))
            .collect();
        named.join("; ")
    } else {
        sections.join("; ")
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
pub(crate) struct LogArgs {
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

pub(crate) struct LogRead(pub(super) Ros);

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

/// "name (type)"; a field of a message type (not a header or a time) with that type's
/// own fields, one level down: "wrench (Wrench: force (Vector3), torque (Vector3))",
/// so what a message holds is said without asking for each part.
fn field(name: &str, ty: &str, package: &str, nested: Option<&crate::ros::Interfaces>) -> String {
    let base = ty.split(['[', '<']).next().unwrap_or(ty);
    let builtin = base.chars().next().is_some_and(char::is_lowercase) && !base.contains('/');
    let plumbing = ["Header", "Time", "Duration"]
        .iter()
        .any(|t| base.rsplit('/').next() == Some(t));
    let inner = nested.filter(|_| !builtin && !plumbing).and_then(|ifaces| {
        let full = match base.split('/').collect::<Vec<_>>().as_slice() {
            [pkg, "msg", t] => format!("{pkg}/msg/{t}"),
            [pkg, t] => format!("{pkg}/msg/{t}"),
            [t] => format!("{package}/msg/{t}"),
            _ => return None,
        };
        let text = ifaces.source(&full).ok()?;
        Some(fields(&text, &full, None))
    });
    match inner {
        Some(inner) => format!("{name} ({ty}: {inner})"),
        None => format!("{name} ({ty})"),
    }
}
