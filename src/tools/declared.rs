//! Declarative tools: an integrator adds a robot-specific tool in a TOML file, without
//! recompiling. A tool is a name, a description, an argument schema, an effect, and one
//! ROS action (publish this message on this topic, or call this service with this
//! request) whose JSON may place arguments with `"{{name}}"` (a string that is exactly a
//! placeholder takes the argument's JSON value; inside longer text it is spliced in).
//!
//! ```toml
//! [[tool]]
//! name = "spot_stand_up"
//! description = "Make Spot stand up. Moves the robot."
//! effect = "actuates"
//! [tool.call]
//! service = "/spot/stand_up"
//! type = "std_srvs/srv/Trigger"
//! request = {}
//!
//! [[tool]]
//! name = "eels_raise_head"
//! description = "Raise EELS's head by angle degrees (0-45). Moves the robot."
//! effect = "actuates"
//! parameters = { type = "object", properties = { angle = { type = "number", minimum = 0, maximum = 45 } }, required = ["angle"] }
//! [tool.publish]
//! topic = "/eels/head/cmd"
//! type = "std_msgs/msg/Float64"
//! message = { data = "{{angle}}" }
//! ```

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use serde::Deserialize;
use serde_json::{json, Value};

use crate::ros::RosGraph;
use crate::tool::registry::BoxFuture;
use crate::tool::{DynTool, Effect, Package, SpecError, ToolContext, ToolError, ToolSpec};

#[derive(Debug, thiserror::Error)]
pub enum DeclaredError {
    #[error("cannot read tools file {path}: {message}")]
    Read { path: String, message: String },
    #[error("tools file: tool {tool}: {message}")]
    Tool { tool: String, message: String },
    #[error(transparent)]
    Spec(#[from] SpecError),
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct PublishAction {
    topic: String,
    #[serde(rename = "type")]
    type_name: String,
    message: Value,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct CallAction {
    service: String,
    #[serde(rename = "type")]
    type_name: String,
    #[serde(default = "empty_object")]
    request: Value,
}

fn empty_object() -> Value {
    json!({})
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct ToolDecl {
    name: String,
    description: String,
    #[serde(default)]
    parameters: Option<Value>,
    effect: EffectDecl,
    #[serde(default)]
    publish: Option<PublishAction>,
    #[serde(default)]
    call: Option<CallAction>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(rename_all = "lowercase")]
enum EffectDecl {
    Observes,
    Actuates,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ToolsFile {
    tool: Vec<ToolDecl>,
}

#[derive(Debug, Clone)]
enum Action {
    Publish(PublishAction),
    Call(CallAction),
}

/// A tool defined in a tools file.
pub struct Declared {
    spec: ToolSpec,
    effect: Effect,
    action: Action,
    ros: Arc<dyn RosGraph>,
}

/// Replace `"{{name}}"` placeholders in `template` with values from `args`.
fn fill(template: &Value, args: &Value) -> Result<Value, String> {
    Ok(match template {
        Value::String(s) => {
            let t = s.trim();
            if let Some(name) = t.strip_prefix("{{").and_then(|r| r.strip_suffix("}}")) {
                if !name.contains("{{") {
                    return args
                        .get(name.trim())
                        .cloned()
                        .ok_or_else(|| format!("argument {} is missing", name.trim()));
                }
            }
            let mut out = s.clone();
            while let Some(start) = out.find("{{") {
                let end = out[start..].find("}}").ok_or("unclosed {{ in template")? + start;
                let name = out[start + 2..end].trim().to_string();
                let v = args
                    .get(&name)
                    .ok_or_else(|| format!("argument {name} is missing"))?;
                let text = match v {
                    Value::String(x) => x.clone(),
                    other => other.to_string(),
                };
                out.replace_range(start..end + 2, &text);
            }
            Value::String(out)
        }
        Value::Array(a) => Value::Array(a.iter().map(|x| fill(x, args)).collect::<Result<_, _>>()?),
        Value::Object(m) => Value::Object(
            m.iter()
                .map(|(k, v)| Ok((k.clone(), fill(v, args)?)))
                .collect::<Result<_, String>>()?,
        ),
        other => other.clone(),
    })
}

/// Parse a tools file into tools acting on `ros`.
pub fn parse(text: &str, origin: &str, ros: Arc<dyn RosGraph>) -> Result<Package, DeclaredError> {
    let file: ToolsFile = toml::from_str(text).map_err(|e| DeclaredError::Read {
        path: origin.to_string(),
        message: e.message().to_string(),
    })?;
    let mut pkg = Package::new("declared");
    for d in file.tool {
        let err = |message: &str| DeclaredError::Tool {
            tool: d.name.clone(),
            message: message.to_string(),
        };
        let action = match (d.publish.clone(), d.call.clone()) {
            (Some(p), None) => Action::Publish(p),
            (None, Some(c)) => Action::Call(c),
            _ => {
                return Err(err(
                    "give exactly one action: [tool.publish] or [tool.call]",
                ))
            }
        };
        let spec = ToolSpec::new(
            &d.name,
            &d.description,
            d.parameters.clone().unwrap_or(Value::Null),
        )?;
        pkg = pkg.with_dyn(Arc::new(Declared {
            spec,
            effect: match d.effect {
                EffectDecl::Observes => Effect::Observes,
                EffectDecl::Actuates => Effect::Actuates,
            },
            action,
            ros: ros.clone(),
        }));
    }
    Ok(pkg)
}

pub fn load(path: &Path, ros: Arc<dyn RosGraph>) -> Result<Package, DeclaredError> {
    let text = std::fs::read_to_string(path).map_err(|e| DeclaredError::Read {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    parse(&text, &path.display().to_string(), ros)
}

impl DynTool for Declared {
    fn spec(&self) -> &ToolSpec {
        &self.spec
    }

    fn effect(&self) -> Effect {
        self.effect
    }

    fn call<'a>(
        &'a self,
        args: Value,
        cx: &'a ToolContext,
    ) -> BoxFuture<'a, Result<Value, ToolError>> {
        Box::pin(async move {
            match &self.action {
                Action::Publish(p) => {
                    let message = fill(&p.message, &args).map_err(ToolError::InvalidArguments)?;
                    let sent = self
                        .ros
                        .publish(&p.topic, &p.type_name, message.clone())
                        .await
                        .map_err(|e| ToolError::Failed(e.to_string()))?;
                    let mut out = json!({"published": true, "topic": sent.topic, "type": p.type_name,
                                         "message": sent.sent.unwrap_or(message)});
                    if let Some(n) = sent.note {
                        out["limited"] = json!(n);
                    }
                    Ok(out)
                }
                Action::Call(c) => {
                    let request = fill(&c.request, &args).map_err(ToolError::InvalidArguments)?;
                    let timeout = cx.timeout.min(Duration::from_secs(30));
                    let reply = self
                        .ros
                        .call_service(&c.service, &c.type_name, request, timeout)
                        .await
                        .map_err(|e| ToolError::Failed(e.to_string()))?;
                    let mut out = json!({"service": c.service, "response": reply.response});
                    if let Some(n) = reply.note {
                        out["limited"] = json!(n);
                    }
                    Ok(out)
                }
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::fake::{FakeGraph, Sent};

    const FILE: &str = r#"
[[tool]]
name = "spot_stand_up"
description = "Make Spot stand up. Moves the robot."
effect = "actuates"
[tool.call]
service = "/spot/stand_up"
type = "std_srvs/srv/Trigger"

[[tool]]
name = "eels_raise_head"
description = "Raise the head by angle degrees (0-45)."
effect = "actuates"
parameters = { type = "object", properties = { angle = { type = "number", minimum = 0, maximum = 45 } }, required = ["angle"] }
[tool.publish]
topic = "/eels/head/cmd"
type = "std_msgs/msg/Float64"
message = { data = "{{angle}}", note = "raise by {{angle}} deg" }
"#;

    fn run(t: &dyn DynTool, args: Value) -> Result<Value, ToolError> {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(t.call(
            args,
            &ToolContext {
                timeout: Duration::from_secs(1),
            },
        ))
    }

    #[test]
    fn publish_and_call_actions_fill_arguments() {
        let graph = Arc::new(
            FakeGraph::new()
                .with_service("/spot/stand_up", json!({"success": true, "message": ""})),
        );
        let pkg = parse(FILE, "test", graph.clone()).unwrap();
        assert_eq!(pkg.tools.len(), 2);
        assert_eq!(pkg.tools[0].effect(), Effect::Actuates);
        let out = run(pkg.tools[0].as_ref(), json!({})).unwrap();
        assert_eq!(out["response"]["success"], json!(true));
        run(pkg.tools[1].as_ref(), json!({"angle": 30})).unwrap();
        assert_eq!(
            graph.sent()[1],
            Sent::Publish {
                topic: "/eels/head/cmd".into(),
                type_name: "std_msgs/msg/Float64".into(),
                message: json!({"data": 30, "note": "raise by 30 deg"}),
            }
        );
        // The schema is the contract: the policy validates against it before a call.
        assert!(pkg.tools[1].spec().validate(&json!({"angle": 90})).is_err());
    }

    #[test]
    fn a_tool_needs_exactly_one_action() {
        let bad = r#"
[[tool]]
name = "x"
description = "d"
effect = "observes"
"#;
        let err = parse(bad, "t", Arc::new(FakeGraph::new())).err().unwrap();
        assert!(err.to_string().contains("exactly one action"), "{err}");
    }
}
