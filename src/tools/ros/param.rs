//! Node parameters, through each node's `rcl_interfaces` services.

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use super::base::{absolute, failed, require_node, with_note, NodeArgs, Ros};
use crate::ros::{Reply, RosError};
use crate::tool::{Effect, Tool, ToolContext, ToolError};

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
) -> Result<Reply, ToolError> {
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

pub struct ParamList(pub(super) Ros);

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
        .await?
        .response;
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

pub struct ParamGet(pub(super) Ros);

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
        .await?
        .response;
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

pub struct ParamSet(pub(super) Ros);

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
        .await?
        .response;
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
        let result = &r.response["results"][0];
        if result["successful"] != json!(true) {
            return Err(ToolError::Failed(format!(
                "{} refused: {}",
                absolute(&a.node),
                result["reason"].as_str().unwrap_or("no reason given")
            )));
        }
        Ok(with_note(
            json!({"node": absolute(&a.node), "name": a.name, "value": param_value(&value), "set": true}),
            r.note,
        ))
    }
}
