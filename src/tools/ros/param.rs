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

pub(crate) struct ParamList(pub(super) Ros);

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
        self.0
            .params
            .record(&absolute(&a.node), super::param_names::names(&r));
        let mut listed: Vec<&str> = names
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(Value::as_str)
            .collect();
        // The node's own parameters first: the client library declares the same few on
        // every node, which would otherwise fill the names shown.
        listed.sort_by_key(|n| {
            *n == "use_sim_time"
                || *n == "start_type_description_service"
                || n.starts_with("qos_overrides.")
        });
        let summary = format!(
            "{}: {}",
            absolute(&a.node),
            super::base::summary("parameters", &listed)
        );
        Ok(
            json!({"summary": summary, "node": absolute(&a.node), "count": listed.len(), "parameters": names}),
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

    fn live_parameters(&self) -> Option<Value> {
        by_node(&self.0, &[])
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

#[derive(Deserialize, JsonSchema, Clone)]
#[serde(untagged)]
pub(crate) enum ParamInput {
    Bool(bool),
    Number(f64),
    Text(String),
}

pub struct ParamSet(pub(super) Ros);

/// A value written as text for a parameter of another type (`kind`, ROS 2's parameter
/// type: 1 bool, 2 integer, 3 double) read as that type when it is one ("100" for an
/// integer, "true" for a bool); else as given, for the node to judge.
fn coerced(value: &ParamInput, kind: u64) -> ParamInput {
    let ParamInput::Text(text) = value else {
        return value.clone();
    };
    let t = text.trim();
    match kind {
        1 if t.eq_ignore_ascii_case("true") => ParamInput::Bool(true),
        1 if t.eq_ignore_ascii_case("false") => ParamInput::Bool(false),
        2 | 3 => t
            .parse::<f64>()
            .ok()
            .filter(|n| n.is_finite())
            .map_or_else(|| value.clone(), ParamInput::Number),
        _ => value.clone(),
    }
}

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
        let value = match (&coerced(&a.value, kind), kind) {
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

    fn live_parameters(&self) -> Option<Value> {
        let value = json!({"anyOf": [{"type": "boolean"}, {"type": "number"}, {"type": "string"}]});
        by_node(&self.0, &[("value", value)])
    }
}

/// A parameter tool's arguments as the robot can take them: one branch per node whose
/// parameters are known (`ParamNames`), its `name` one of them or another (which
/// `reading::bound` holds to those the request points at and those the operator wrote),
/// and one for a node the robot lacks (`reading::bound` holds its node to names the operator
/// wrote; the call then reports it missing). `more`: the tool's other arguments, all
/// required. `None` when no node's parameters are known.
fn by_node(ros: &Ros, more: &[(&str, Value)]) -> Option<Value> {
    let g = crate::ros::graph_now(ros.graph.as_ref())?;
    let known = ros.params.of(&ros.graph, &g);
    let branch = |node: Value, name: Value| {
        let mut properties = serde_json::Map::new();
        properties.insert("node".into(), node);
        properties.insert("name".into(), name);
        let mut required = vec![json!("node"), json!("name")];
        for (k, v) in more {
            properties.insert(k.to_string(), v.clone());
            required.push(json!(k));
        }
        json!({"type": "object", "properties": properties, "required": required,
               "additionalProperties": false})
    };
    let mut branches: Vec<Value> = known
        .into_iter()
        .filter(|(_, names)| !names.is_empty())
        .map(|(node, names)| {
            branch(
                json!({"type": "string", "const": node}),
                json!({"anyOf": [{"type": "string", "enum": names}, {"type": "string"}]}),
            )
        })
        .collect();
    if branches.is_empty() {
        return None;
    }
    branches.push(branch(json!({"type": "string"}), json!({"type": "string"})));
    Some(json!({ "anyOf": branches }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn number(v: ParamInput) -> Option<f64> {
        match v {
            ParamInput::Number(n) => Some(n),
            _ => None,
        }
    }

    #[test]
    fn a_number_written_as_text_keeps_the_parameters_type() {
        let text = |t: &str| ParamInput::Text(t.into());
        assert_eq!(number(coerced(&text(" 100 "), 2)), Some(100.0));
        assert_eq!(number(coerced(&text("0.25"), 3)), Some(0.25));
        assert!(matches!(coerced(&text("TRUE"), 1), ParamInput::Bool(true)));
        // Text for a text parameter, or text that is no number, stays as written: the
        // node says what it takes.
        assert!(matches!(coerced(&text("100"), 4), ParamInput::Text(t) if t == "100"));
        assert!(matches!(coerced(&text("blue"), 2), ParamInput::Text(t) if t == "blue"));
        assert!(matches!(coerced(&text("inf"), 2), ParamInput::Text(_)));
    }
}
