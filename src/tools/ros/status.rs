//! The robot's health in one call: battery, diagnostics and the running nodes. Topics
//! are found by their message type (`sensor_msgs/msg/BatteryState`,
//! `diagnostic_msgs/msg/DiagnosticArray`), not by name, so it works on any robot that
//! publishes the standard messages, whatever it calls the topics.
//!
//! Cost: one graph snapshot and one message read per status topic, all at once; the
//! call takes about one publishing period of the slowest topic (1 s on the sim).

use std::time::Duration;

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use super::base::Ros;
use crate::tool::{Effect, Tool, ToolContext, ToolError};

const BATTERY: &str = "sensor_msgs/msg/BatteryState";
const DIAGNOSTICS: &str = "diagnostic_msgs/msg/DiagnosticArray";

#[derive(Deserialize, JsonSchema)]
pub(crate) struct StatusArgs {
    /// Seconds to wait for each status message, 0.5 to 5 (default 2.5).
    #[serde(default)]
    #[schemars(range(min = 0.5, max = 5.0))]
    pub timeout_s: Option<f64>,
}

pub(crate) struct RobotStatus(pub(super) Ros);

impl Tool for RobotStatus {
    type Args = StatusArgs;
    const NAME: &'static str = "robot_status";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "The robot's health in one call: battery level, diagnostics (OK, warnings, errors) and running nodes. Answers: how is the robot, battery level, any errors, status report.".into()
    }
    async fn call(&self, a: StatusArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let window =
            Duration::from_secs_f64(a.timeout_s.unwrap_or(2.5).clamp(0.5, 5.0)).min(cx.timeout);
        let g = self.0.snapshot().await?;
        let of_type = |wanted: &str| -> Vec<String> {
            g.topics()
                .into_iter()
                .filter(|(_, types)| types.iter().any(|t| same_type(t, wanted)))
                .map(|(name, _)| name)
                .collect()
        };
        let (batteries, diagnostics) = (of_type(BATTERY), of_type(DIAGNOSTICS));
        let read = |topic: String, ty: &'static str| async move {
            let got = self.0.graph.subscribe(&topic, Some(ty), 1, window).await;
            let message = got
                .ok()
                .and_then(|s| s.into_iter().next())
                .map(|s| s.message);
            (topic, message)
        };
        let (battery_msgs, diagnostic_msgs) = futures::join!(
            futures::future::join_all(batteries.into_iter().map(|t| read(t, BATTERY))),
            futures::future::join_all(diagnostics.into_iter().map(|t| read(t, DIAGNOSTICS))),
        );
        Ok(report(&g.nodes, &battery_msgs, &diagnostic_msgs, window))
    }
}

/// `pkg/msg/Name` and `pkg/Name` are the same type.
fn same_type(a: &str, b: &str) -> bool {
    let parts = |t: &str| {
        let mut it = t.split('/');
        (
            it.next().map(str::to_string),
            it.next_back().map(str::to_string),
        )
    };
    parts(a) == parts(b)
}

/// The status as the model reads it: a one-line `summary` first, then the figures.
fn report(
    nodes: &[String],
    batteries: &[(String, Option<Value>)],
    diagnostics: &[(String, Option<Value>)],
    window: Duration,
) -> Value {
    let mut lines = Vec::new();
    let mut silent = Vec::new();
    let mut battery_out = Vec::new();
    for (topic, msg) in batteries {
        let Some(m) = msg else {
            silent.push(topic.clone());
            continue;
        };
        let b = battery(m);
        lines.push(format!(
            "battery {}",
            b["text"].as_str().unwrap_or("unknown")
        ));
        battery_out.push(json!({"topic": topic, "percent": b["percent"], "voltage": b["voltage"], "status": b["status"]}));
    }
    let mut diag_out = Vec::new();
    for (topic, msg) in diagnostics {
        let Some(m) = msg else {
            silent.push(topic.clone());
            continue;
        };
        let items: Vec<Value> = m["status"]
            .as_array()
            .map(|a| a.iter().map(diagnostic).collect())
            .unwrap_or_default();
        let mut counts = [0usize; 4];
        for i in &items {
            let l = i["level_code"].as_u64().unwrap_or(3).min(3) as usize;
            counts[l] += 1;
        }
        let mut text = ["OK", "WARN", "ERROR", "STALE"]
            .iter()
            .zip(counts)
            .filter(|(_, n)| *n > 0)
            .map(|(l, n)| format!("{n} {l}"))
            .collect::<Vec<_>>()
            .join(", ");
        let problems: Vec<String> = items
            .iter()
            .filter(|i| i["level_code"].as_u64() != Some(0))
            .map(|i| {
                format!(
                    "{} {}: {}",
                    i["name"].as_str().unwrap_or("?"),
                    i["level"].as_str().unwrap_or("?"),
                    i["message"].as_str().unwrap_or("")
                )
            })
            .collect();
        if !problems.is_empty() {
            text.push_str(&format!(" ({})", problems.join("; ")));
        }
        if items.is_empty() {
            text = "no entries".into();
        }
        lines.push(format!("diagnostics {text}"));
        diag_out.push(json!({"topic": topic, "ok": counts[0], "warn": counts[1], "error": counts[2], "stale": counts[3], "items": items}));
    }
    if batteries.is_empty() {
        lines.push("no battery topic".into());
    }
    if diagnostics.is_empty() {
        lines.push("no diagnostics topic".into());
    }
    let shown: Vec<&str> = nodes.iter().take(12).map(String::as_str).collect();
    let more = nodes.len().saturating_sub(shown.len());
    let mut node_text = format!(
        "{} node{} running: {}",
        nodes.len(),
        if nodes.len() == 1 { "" } else { "s" },
        shown.join(", ")
    );
    if more > 0 {
        node_text.push_str(&format!(" and {more} more"));
    }
    lines.push(node_text);
    let mut out = json!({
        "summary": lines.join("; "),
        "battery": battery_out,
        "diagnostics": diag_out,
        "nodes": nodes,
    });
    if !silent.is_empty() {
        out["silent"] = json!(silent);
        out["note"] = json!(format!(
            "no message within {:.1} s on {}",
            window.as_secs_f64(),
            silent.join(", ")
        ));
    }
    out
}

/// A BatteryState read as people say it: "87% (12.3 V, discharging)".
fn battery(m: &Value) -> Value {
    // `percentage` is 0 to 1 (NaN when unknown, which JSON carries as null).
    let percent = m["percentage"]
        .as_f64()
        .filter(|p| p.is_finite() && (0.0..=1.0).contains(p))
        .map(|p| (p * 1000.0).round() / 10.0);
    let voltage = m["voltage"]
        .as_f64()
        .filter(|v| v.is_finite())
        .map(|v| (v * 100.0).round() / 100.0);
    let status = match m["power_supply_status"].as_u64() {
        Some(1) => "charging",
        Some(2) => "discharging",
        Some(3) => "not charging",
        Some(4) => "full",
        _ => "unknown",
    };
    let mut text = percent.map_or("level unknown".to_string(), |p| format!("{p}%"));
    let detail: Vec<String> = voltage
        .map(|v| format!("{v} V"))
        .into_iter()
        .chain((status != "unknown").then(|| status.to_string()))
        .collect();
    if !detail.is_empty() {
        text.push_str(&format!(" ({})", detail.join(", ")));
    }
    json!({"percent": percent, "voltage": voltage, "status": status, "text": text})
}

/// One DiagnosticStatus: its level by name, its name and message.
fn diagnostic(s: &Value) -> Value {
    // `level` is a byte; decoders give it as a number or a one-character string.
    let code = s["level"].as_u64().or_else(|| {
        s["level"]
            .as_str()
            .and_then(|t| t.bytes().next())
            .map(u64::from)
    });
    let level = match code {
        Some(0) => "OK",
        Some(1) => "WARN",
        Some(2) => "ERROR",
        _ => "STALE",
    };
    json!({"name": s["name"], "level": level, "level_code": code.unwrap_or(3).min(3), "message": s["message"]})
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn battery_reads_as_people_say_it() {
        let b = battery(&json!({"percentage": 0.873, "voltage": 12.333, "power_supply_status": 2}));
        assert_eq!(b["text"], "87.3% (12.33 V, discharging)");
        let unknown = battery(&json!({"percentage": null, "voltage": 0.0}));
        assert_eq!(unknown["text"], "level unknown (0 V)");
        assert_eq!(unknown["percent"], Value::Null);
    }

    #[test]
    fn the_summary_names_problems_and_silent_topics() {
        let diag = json!({"status": [
            {"level": 0, "name": "motors", "message": "ok"},
            {"level": 1, "name": "battery", "message": "battery low"},
        ]});
        let out = report(
            &["/base".to_string()],
            &[("/bat".to_string(), None)],
            &[("/diagnostics".to_string(), Some(diag))],
            Duration::from_secs(2),
        );
        let s = out["summary"].as_str().unwrap();
        assert!(
            s.contains("diagnostics 1 OK, 1 WARN (battery WARN: battery low)"),
            "{s}"
        );
        assert!(s.contains("1 node running: /base"), "{s}");
        assert_eq!(out["silent"], json!(["/bat"]));
        let none = report(&[], &[], &[], Duration::from_secs(1));
        let s = none["summary"].as_str().unwrap();
        assert!(
            s.contains("no battery topic") && s.contains("no diagnostics topic"),
            "{s}"
        );
    }

    #[test]
    fn type_spellings_match() {
        assert!(same_type("sensor_msgs/msg/BatteryState", BATTERY));
        assert!(same_type("sensor_msgs/BatteryState", BATTERY));
        assert!(!same_type("my_msgs/msg/BatteryState", BATTERY));
    }
}
