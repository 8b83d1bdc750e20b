//! The ROS 1 master's API (XML-RPC): the graph from `getSystemState` and `getTopicTypes`,
//! registrations, service lookup, and the parameter server.
//!
//! A node's parameters (those under its name, as ROS 1's private parameters are) are
//! offered as ROS 2's parameter services (`<node>/list_parameters`, `get_parameters`,
//! `set_parameters`, `rcl_interfaces` types), so the parameter tools work unchanged:
//! `Params::call` answers them from the parameter server.

use std::time::Duration;

use serde_json::{json, Value};

use super::xmlrpc::{self, XValue};
use crate::ros::RosError;

/// How long one master call may take.
pub(crate) const MASTER_LIMIT: Duration = Duration::from_secs(3);

/// The parameter services a node is given, with their types.
pub(crate) const PARAM_SERVICES: [(&str, &str); 3] = [
    ("list_parameters", "rcl_interfaces/srv/ListParameters"),
    ("get_parameters", "rcl_interfaces/srv/GetParameters"),
    ("set_parameters", "rcl_interfaces/srv/SetParameters"),
];

#[derive(Debug, Clone)]
pub(crate) struct Master {
    pub uri: String,
    pub caller_id: String,
}

/// `getSystemState`: per topic its publishers and subscribers, per service its servers.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct SystemState {
    pub publishers: Vec<(String, Vec<String>)>,
    pub subscribers: Vec<(String, Vec<String>)>,
    pub services: Vec<(String, Vec<String>)>,
}

fn pairs(v: &XValue) -> Vec<(String, Vec<String>)> {
    v.as_array()
        .iter()
        .filter_map(|entry| {
            let [name, nodes] = entry.as_array() else {
                return None;
            };
            let nodes = nodes
                .as_array()
                .iter()
                .filter_map(|n| n.as_str().map(str::to_string))
                .collect();
            Some((name.as_str()?.to_string(), nodes))
        })
        .collect()
}

impl Master {
    /// Call `method` with the caller id first: the `[code, status, value]` answer.
    async fn raw(
        &self,
        method: &str,
        params: &[XValue],
    ) -> Result<(i64, String, XValue), RosError> {
        let mut all = vec![XValue::str(&self.caller_id)];
        all.extend_from_slice(params);
        let answer = xmlrpc::call(&self.uri, method, &all, MASTER_LIMIT)
            .await
            .map_err(|e| {
                RosError::Other(format!(
                    "the ROS master at {} ({method}): {e}; is roscore running, and ROS_MASTER_URI right?",
                    self.uri
                ))
            })?;
        match answer.as_array() {
            [code, status, value] => Ok((
                code.as_int().unwrap_or(-1),
                status.as_str().unwrap_or_default().to_string(),
                value.clone(),
            )),
            _ => Err(RosError::Other(format!(
                "the ROS master answered {method} with {answer:?}"
            ))),
        }
    }

    /// `raw`'s value when the code is 1 (success), else its status as the error.
    pub async fn call(&self, method: &str, params: &[XValue]) -> Result<XValue, RosError> {
        match self.raw(method, params).await? {
            (1, _, value) => Ok(value),
            (_, status, _) => Err(RosError::Other(format!(
                "the ROS master refused {method}: {status}"
            ))),
        }
    }

    pub(crate) async fn system_state(&self) -> Result<SystemState, RosError> {
        let v = self.call("getSystemState", &[]).await?;
        let [p, s, r] = v.as_array() else {
            return Err(RosError::Other(format!("getSystemState answered {v:?}")));
        };
        Ok(SystemState {
            publishers: pairs(p),
            subscribers: pairs(s),
            services: pairs(r),
        })
    }

    /// Every topic's type as the master knows it (`pkg/Name`).
    pub(crate) async fn topic_types(&self) -> Result<Vec<(String, String)>, RosError> {
        let v = self.call("getTopicTypes", &[]).await?;
        Ok(v.as_array()
            .iter()
            .filter_map(|e| match e.as_array() {
                [t, ty] => Some((t.as_str()?.to_string(), ty.as_str()?.to_string())),
                _ => None,
            })
            .collect())
    }

    /// A service's `rosrpc://host:port`, or `NoService`.
    pub(crate) async fn lookup_service(&self, service: &str) -> Result<String, RosError> {
        match self.call("lookupService", &[XValue::str(service)]).await {
            Ok(XValue::Str(uri)) if !uri.is_empty() => Ok(uri),
            _ => Err(RosError::NoService(service.to_string())),
        }
    }

    pub(crate) async fn param_names(&self) -> Result<Vec<String>, RosError> {
        let v = self.call("getParamNames", &[]).await?;
        Ok(v.as_array()
            .iter()
            .filter_map(|n| n.as_str().map(str::to_string))
            .collect())
    }

    /// A parameter's value, `None` when it is not set.
    pub(crate) async fn get_param(&self, key: &str) -> Result<Option<XValue>, RosError> {
        let (code, _, value) = self.raw("getParam", &[XValue::str(key)]).await?;
        Ok((code == 1).then_some(value))
    }

    pub(crate) async fn set_param(&self, key: &str, value: XValue) -> Result<(), RosError> {
        self.call("setParam", &[XValue::str(key), value])
            .await
            .map(|_| ())
    }
}

/// A parameter server value as `rcl_interfaces/ParameterValue` JSON (a dictionary, or a
/// list of mixed kinds, as its JSON text).
pub(crate) fn parameter_value(v: &XValue) -> Value {
    fn plain(v: &XValue) -> Value {
        match v {
            XValue::Int(i) => json!(i),
            XValue::Bool(b) => json!(b),
            XValue::Double(d) => json!(d),
            XValue::Str(s) | XValue::Other(s) => json!(s),
            XValue::Array(a) => Value::Array(a.iter().map(plain).collect()),
            XValue::Struct(m) => {
                Value::Object(m.iter().map(|(k, v)| (k.clone(), plain(v))).collect())
            }
        }
    }
    let all = |f: fn(&XValue) -> bool, a: &[XValue]| !a.is_empty() && a.iter().all(f);
    match v {
        XValue::Bool(b) => json!({"type": 1, "bool_value": b}),
        XValue::Int(i) => json!({"type": 2, "integer_value": i}),
        XValue::Double(d) => json!({"type": 3, "double_value": d}),
        XValue::Str(s) => json!({"type": 4, "string_value": s}),
        XValue::Array(a) if all(|x| matches!(x, XValue::Bool(_)), a) => {
            json!({"type": 6, "bool_array_value": plain(v)})
        }
        XValue::Array(a) if all(|x| matches!(x, XValue::Int(_)), a) => {
            json!({"type": 7, "integer_array_value": plain(v)})
        }
        XValue::Array(a) if all(|x| matches!(x, XValue::Double(_) | XValue::Int(_)), a) => {
            json!({"type": 8, "double_array_value": plain(v)})
        }
        XValue::Array(a) if all(|x| matches!(x, XValue::Str(_)), a) => {
            json!({"type": 9, "string_array_value": plain(v)})
        }
        other => json!({"type": 4, "string_value": plain(other).to_string()}),
    }
}

/// `rcl_interfaces/ParameterValue` JSON as a parameter server value.
pub(crate) fn xml_value(v: &Value) -> Result<XValue, String> {
    fn plain(v: &Value) -> Result<XValue, String> {
        Ok(match v {
            Value::Bool(b) => XValue::Bool(*b),
            Value::Number(n) => match n.as_i64() {
                Some(i) => XValue::Int(i),
                None => XValue::Double(n.as_f64().unwrap_or(0.0)),
            },
            Value::String(s) => XValue::Str(s.clone()),
            Value::Array(a) => XValue::Array(a.iter().map(plain).collect::<Result<_, _>>()?),
            other => return Err(format!("a parameter cannot hold {other}")),
        })
    }
    let field = match v["type"].as_u64().unwrap_or(0) {
        1 => "bool_value",
        2 => "integer_value",
        3 => "double_value",
        4 => "string_value",
        6 => "bool_array_value",
        7 => "integer_array_value",
        8 => "double_array_value",
        9 => "string_array_value",
        t => return Err(format!("parameter type {t} is not supported on ROS 1")),
    };
    let value = plain(&v[field])?;
    Ok(match (v["type"].as_u64(), value) {
        // A whole double stays a double on the server.
        (Some(3), XValue::Int(i)) => XValue::Double(i as f64),
        (_, value) => value,
    })
}

/// The parameter names under `node`, relative to it.
pub(crate) fn names_under(node: &str, all: &[String]) -> Vec<String> {
    let prefix = format!("{}/", node.trim_end_matches('/'));
    let mut out: Vec<String> = all
        .iter()
        .filter_map(|n| n.strip_prefix(&prefix))
        .map(str::to_string)
        .collect();
    out.sort();
    out
}

/// If `service` is one of a node's parameter services, the node and which.
pub(crate) fn param_service(service: &str) -> Option<(&str, &'static str)> {
    PARAM_SERVICES.iter().find_map(|(which, _)| {
        let node = service.strip_suffix(which)?.strip_suffix('/')?;
        (!node.is_empty()).then_some((node, *which))
    })
}

/// Answer one of a node's parameter services from the parameter server.
pub(crate) async fn param_call(
    master: &Master,
    node: &str,
    which: &str,
    request: &Value,
) -> Result<Value, RosError> {
    let key = |name: &str| {
        format!(
            "{}/{}",
            node.trim_end_matches('/'),
            name.trim_start_matches('/')
        )
    };
    match which {
        "list_parameters" => {
            let names = names_under(node, &master.param_names().await?);
            Ok(json!({"result": {"names": names, "prefixes": []}}))
        }
        "get_parameters" => {
            let mut values = Vec::new();
            for name in request["names"].as_array().into_iter().flatten() {
                let name = name.as_str().unwrap_or_default();
                values.push(match master.get_param(&key(name)).await? {
                    Some(v) => parameter_value(&v),
                    None => json!({"type": 0}),
                });
            }
            Ok(json!({ "values": values }))
        }
        _ => {
            let mut results = Vec::new();
            for p in request["parameters"].as_array().into_iter().flatten() {
                let name = p["name"].as_str().unwrap_or_default();
                let result = match xml_value(&p["value"]) {
                    Ok(v) => match master.set_param(&key(name), v).await {
                        Ok(()) => json!({"successful": true, "reason": ""}),
                        Err(e) => json!({"successful": false, "reason": e.to_string()}),
                    },
                    Err(reason) => json!({"successful": false, "reason": reason}),
                };
                results.push(result);
            }
            Ok(json!({ "results": results }))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameter_values_map_both_ways() {
        for (x, kind) in [
            (XValue::Int(69), 2),
            (XValue::Double(0.5), 3),
            (XValue::Bool(true), 1),
            (XValue::str("base"), 4),
            (XValue::Array(vec![XValue::Int(1), XValue::Int(2)]), 7),
            (XValue::Array(vec![XValue::Double(1.5), XValue::Int(2)]), 8),
        ] {
            let v = parameter_value(&x);
            assert_eq!(v["type"], kind, "{x:?}");
            if kind != 8 {
                assert_eq!(xml_value(&v).unwrap(), x);
            }
        }
        let dict = parameter_value(&XValue::Struct(vec![("a".into(), XValue::Int(1))]));
        assert_eq!(dict, json!({"type": 4, "string_value": "{\"a\":1}"}));
        assert_eq!(
            xml_value(&json!({"type": 3, "double_value": 2})).unwrap(),
            XValue::Double(2.0)
        );
        assert!(xml_value(&json!({"type": 5})).is_err());
    }

    #[test]
    fn a_nodes_parameters_are_those_under_its_name() {
        let all: Vec<String> = [
            "/turtlesim/background_r",
            "/turtlesim/pen/width",
            "/turtlesim2/x",
            "/run_id",
        ]
        .map(String::from)
        .to_vec();
        assert_eq!(
            names_under("/turtlesim", &all),
            ["background_r", "pen/width"]
        );
        assert_eq!(
            param_service("/turtlesim/get_parameters"),
            Some(("/turtlesim", "get_parameters"))
        );
        assert_eq!(param_service("/get_parameters"), None);
        assert_eq!(param_service("/turtlesim/spawn"), None);
    }
}
