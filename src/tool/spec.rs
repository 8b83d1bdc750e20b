//! `ToolSpec`: what a tool looks like to the model. The schema is normalised once here
//! (objects closed with `additionalProperties: false`, `required` kept) so the prompt, the
//! grammar and the validator all read the same contract.

use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

#[derive(Debug, thiserror::Error)]
pub enum SpecError {
    #[error("tool name '{0}' is invalid: use letters, digits and _ (e.g. ros_topic_list)")]
    Name(String),
    #[error("tool {tool}: parameters must be a JSON schema of type object: {reason}")]
    Schema { tool: String, reason: String },
    #[error("tool {0} is listed twice")]
    Duplicate(String),
}

/// A tool's contract: the name the model writes, what it is for, and its arguments.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ToolSpec {
    pub name: String,
    pub description: String,
    /// JSON schema of the `arguments` object.
    pub parameters: Value,
    /// Called alone: a turn that calls it calls nothing else (the grammar offers it as
    /// the first call only, and then closes the list). The answer tool is: it ends the
    /// run, so a call written beside it would never run, and an answer written before a
    /// call's result is a guess.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub alone: bool,
    /// Requests an operator makes when this tool is the one to call (`examples`: the
    /// shipped tools' come from data files; declared tools and robot prompt files add
    /// theirs). Tool choice reads them; the prompt does not show them.
    #[serde(skip)]
    pub examples: Vec<String>,
    /// Arguments that together name things in the order they are to be done, as the
    /// operator says them (`place_go`'s `place`, then its `then` list): one string
    /// argument after another, the last may be a list of strings. A call's order is
    /// held to the request's (`agent::said_order`).
    #[serde(skip)]
    pub sequence: Vec<String>,
    /// Whether a call records what the agent keeps (`Tool::RECORDS`): after an act of
    /// the part failed, it is not made (`agent::guard`'s no-substitute), so a drive
    /// that never arrived is not remembered as the place it was for.
    #[serde(skip)]
    pub records: bool,
    /// Whether it computes from numbers given in a text argument (`Tool::COMPUTES`):
    /// not offered while nothing said or returned spells a number (`agent::guard`).
    #[serde(skip)]
    pub computes: bool,
    /// The kind of the robot's names a call lists in full (`Tool::LISTS`: `node`,
    /// `topic`, `service`, `action`): a request about several of that kind that writes
    /// none asks for this tool (`reading::select`).
    #[serde(skip)]
    pub lists: Option<String>,
}

impl ToolSpec {
    /// Check the name and schema, and close every object in the schema.
    pub fn new(
        name: impl Into<String>,
        description: impl Into<String>,
        parameters: Value,
    ) -> Result<ToolSpec, SpecError> {
        let name = name.into();
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.')
        {
            return Err(SpecError::Name(name));
        }
        let mut parameters = parameters;
        if parameters.is_null() {
            parameters = json!({"type": "object", "properties": {}});
        }
        let schema_err = |reason: String| SpecError::Schema {
            tool: name.clone(),
            reason,
        };
        if parameters.get("type").and_then(Value::as_str) != Some("object") {
            return Err(schema_err("top-level \"type\" is not \"object\"".into()));
        }
        close_objects(&mut parameters);
        jsonschema::validator_for(&parameters).map_err(|e| schema_err(e.to_string()))?;
        Ok(ToolSpec {
            examples: super::examples::shipped(&name),
            name,
            description: description.into(),
            parameters,
            alone: false,
            sequence: Vec::new(),
            records: false,
            computes: false,
            lists: None,
        })
    }

    /// Whether it waits for numbers the operator or a result gives: it computes from an
    /// expression (`computes`), or its arguments need numbers only the operator can
    /// give (`takes_given_numbers`). `agent::guard` does not offer it until one is said
    /// or returned.
    pub(crate) fn waits_for_numbers(&self) -> bool {
        self.computes || takes_given_numbers(&self.parameters)
    }

    /// This tool, called alone (see `alone`).
    pub(crate) fn called_alone(self) -> ToolSpec {
        ToolSpec {
            alone: true,
            ..self
        }
    }

    /// The schema of one call as the grammar enforces it: `{"name": <this name>,
    /// "arguments": <parameters>}`, name first (the grammar emits properties in schema
    /// order), and every unbounded number given finite bounds (see `bound_values`).
    pub(crate) fn call_schema(&self) -> Value {
        let mut arguments = self.parameters.clone();
        bound_values(&mut arguments);
        json!({
            "type": "object",
            "properties": {
                "name": {"const": self.name},
                "arguments": arguments,
            },
            "required": ["name", "arguments"],
            "additionalProperties": false,
        })
    }

    /// Check `arguments` against the schema; the error lists every violation.
    pub(crate) fn validate(&self, arguments: &Value) -> Result<(), String> {
        let v = jsonschema::validator_for(&self.parameters).map_err(|e| e.to_string())?;
        let errors: Vec<String> = v
            .iter_errors(arguments)
            .map(|e| {
                let at = e.instance_path().to_string();
                if at.is_empty() {
                    e.to_string()
                } else {
                    format!("{at}: {e}")
                }
            })
            .collect();
        if errors.is_empty() {
            Ok(())
        } else {
            Err(errors.join("; "))
        }
    }
}

/// Read tool specs from JSON: an array of `{"name", "description", "parameters"}`, or of
/// OpenAI-style `{"type": "function", "function": {...}}` wrappers.
pub fn specs_from_json(text: &str) -> Result<Vec<ToolSpec>, SpecError> {
    let raw: Vec<Value> = serde_json::from_str(text).map_err(|e| SpecError::Schema {
        tool: "<file>".into(),
        reason: format!("expected a JSON array of tools: {e}"),
    })?;
    let mut specs: Vec<ToolSpec> = Vec::with_capacity(raw.len());
    for t in raw {
        let t = t.get("function").cloned().unwrap_or(t);
        let name = t.get("name").and_then(Value::as_str).unwrap_or_default();
        let spec = ToolSpec::new(
            name,
            t.get("description")
                .and_then(Value::as_str)
                .unwrap_or_default(),
            t.get("parameters").cloned().unwrap_or(Value::Null),
        )?;
        if specs.iter().any(|s| s.name == spec.name) {
            return Err(SpecError::Duplicate(spec.name));
        }
        specs.push(spec);
    }
    Ok(specs)
}

/// One call the model made: a tool name and its arguments, already parsed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ToolCall {
    pub name: String,
    pub arguments: Value,
}

/// Largest integer every JSON reader holds exactly (2^53 − 1).
const SAFE_INT: i64 = 9_007_199_254_740_991;
/// Bound for unbounded `number`s: far beyond any robot quantity, far below f64 overflow.
const SAFE_NUMBER: f64 = 1e15;
/// Items an unbounded array may hold in a call: a small model that starts counting
/// (1, 2, 3, …) would otherwise fill its whole turn.
const MAX_ITEMS: u64 = 32;
/// Characters an unbounded string may hold in a call, for the same reason (a model that
/// keeps talking inside an argument).
const MAX_CHARS: u64 = 160;

/// JSON grammar allows `1e99999` and 400-digit integers, which parse to infinity or lose
/// precision in every consumer, and strings and arrays of any length. Give unbounded
/// numbers, strings and arrays finite bounds in the grammar only; the prompt keeps the
/// tool author's schema.
fn bound_values(schema: &mut Value) {
    match schema {
        Value::Object(map) => {
            // `type` is a name or a list of names.
            let types: Vec<String> = match map.get("type") {
                Some(Value::String(t)) => vec![t.clone()],
                Some(Value::Array(ts)) => ts
                    .iter()
                    .filter_map(Value::as_str)
                    .map(String::from)
                    .collect(),
                _ => Vec::new(),
            };
            let has = |t: &str| types.iter().any(|x| x == t);
            if has("array") && !map.contains_key("maxItems") {
                map.insert("maxItems".into(), json!(MAX_ITEMS));
            }
            if has("string")
                && !["maxLength", "enum", "const", "pattern", "format"]
                    .iter()
                    .any(|k| map.contains_key(*k))
            {
                map.insert("maxLength".into(), json!(MAX_CHARS));
            }
            let bound = if has("number") {
                Some((json!(-SAFE_NUMBER), json!(SAFE_NUMBER)))
            } else if has("integer") {
                Some((json!(-SAFE_INT), json!(SAFE_INT)))
            } else {
                None
            };
            if let Some((lo, hi)) = bound {
                if !map.contains_key("minimum") && !map.contains_key("exclusiveMinimum") {
                    map.insert("minimum".into(), lo);
                }
                if !map.contains_key("maximum") && !map.contains_key("exclusiveMaximum") {
                    map.insert("maximum".into(), hi);
                }
            }
            for (k, v) in map.iter_mut() {
                if k != "enum" && k != "const" && k != "default" && k != "examples" {
                    bound_values(v);
                }
            }
        }
        Value::Array(items) => items.iter_mut().for_each(bound_values),
        _ => {}
    }
}

/// Set `additionalProperties: false` on every object schema that does not say otherwise,
/// so neither the grammar nor the validator accepts keys the tool does not define.
fn close_objects(schema: &mut Value) {
    match schema {
        Value::Object(map) => {
            let is_object = map.get("type").and_then(Value::as_str) == Some("object")
                || map.contains_key("properties");
            if is_object && !map.contains_key("additionalProperties") {
                map.insert("additionalProperties".into(), Value::Bool(false));
                // A required name the schema never declares (BFCL has such objects) is
                // declared, so closing the object does not make it unsatisfiable: as any
                // scalar, since under an open `{}` a small model nested objects under the
                // same name until the token limit.
                let required: Vec<String> = map
                    .get("required")
                    .and_then(Value::as_array)
                    .map(|r| {
                        r.iter()
                            .filter_map(Value::as_str)
                            .map(String::from)
                            .collect()
                    })
                    .unwrap_or_default();
                if !required.is_empty() {
                    let properties = map
                        .entry("properties")
                        .or_insert_with(|| Value::Object(Default::default()));
                    if let Value::Object(props) = properties {
                        for name in required {
                            props.entry(name).or_insert_with(
                                || json!({"type": ["string", "number", "boolean"]}),
                            );
                        }
                    }
                }
            }
            for (k, v) in map.iter_mut() {
                // Enum and const values are data, not schemas.
                if k != "enum" && k != "const" && k != "default" && k != "examples" {
                    close_objects(v);
                }
            }
        }
        Value::Array(items) => items.iter_mut().for_each(close_objects),
        _ => {}
    }
}

/// Whether a tool's arguments (`schema`) need numbers only the operator can give: a
/// required list of numbers, or a required number with no default, no choices and no
/// range to pick within (the data a computation runs on, not an amount of an act, which
/// a tool bounds).
fn takes_given_numbers(schema: &Value) -> bool {
    let numeric = |p: &Value| {
        let is = |t: &str| match p.get("type") {
            Some(Value::String(s)) => s == t,
            Some(Value::Array(a)) => a.iter().any(|x| x == t),
            _ => false,
        };
        is("number") || is("integer")
    };
    let Some(required) = schema.get("required").and_then(Value::as_array) else {
        return false;
    };
    required.iter().filter_map(Value::as_str).any(|name| {
        let Some(p) = schema.get("properties").and_then(|ps| ps.get(name)) else {
            return false;
        };
        if p.get("default").is_some() || p.get("enum").is_some() || p.get("const").is_some() {
            return false;
        }
        let ranged = p.get("minimum").is_some() && p.get("maximum").is_some();
        (numeric(p) && !ranged) || p.get("items").is_some_and(numeric)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> ToolSpec {
        ToolSpec::new(
            "ros_topic_echo",
            "Read messages from a topic.",
            json!({
                "type": "object",
                "properties": {
                    "topic": {"type": "string"},
                    "count": {"type": "integer", "minimum": 1, "maximum": 100},
                    "qos": {"type": "object", "properties": {"depth": {"type": "integer"}}}
                },
                "required": ["topic"]
            }),
        )
        .unwrap()
    }

    #[test]
    fn objects_are_closed_recursively() {
        let s = spec();
        assert_eq!(s.parameters["additionalProperties"], json!(false));
        assert_eq!(
            s.parameters["properties"]["qos"]["additionalProperties"],
            json!(false)
        );
    }

    #[test]
    fn validation_reports_each_problem() {
        let s = spec();
        assert!(s.validate(&json!({"topic": "/odom", "count": 3})).is_ok());
        let err = s.validate(&json!({"count": 0, "extra": 1})).unwrap_err();
        assert!(err.contains("topic"), "{err}");
        assert!(err.contains("/count"), "{err}");
        assert!(err.contains("extra"), "{err}");
    }

    #[test]
    fn bad_names_and_schemas_are_refused() {
        assert!(matches!(
            ToolSpec::new("bad name", "", json!({"type": "object"})),
            Err(SpecError::Name(_))
        ));
        assert!(matches!(
            ToolSpec::new("x", "", json!({"type": "string"})),
            Err(SpecError::Schema { .. })
        ));
    }

    #[test]
    fn specs_load_from_plain_and_openai_style_json() {
        let specs = specs_from_json(
            r#"[{"name": "a", "description": "A", "parameters": {"type": "object"}},
                {"type": "function", "function": {"name": "b", "parameters": {"type": "object", "properties": {}}}}]"#,
        )
        .unwrap();
        assert_eq!(specs.len(), 2);
        assert_eq!(specs[1].name, "b");
        let dup = specs_from_json(r#"[{"name": "a"}, {"name": "a"}]"#).unwrap_err();
        assert!(matches!(dup, SpecError::Duplicate(_)));
    }

    #[test]
    fn unbounded_values_get_finite_bounds_in_the_grammar_only() {
        let s = spec();
        let c = s.call_schema();
        let count = &c["properties"]["arguments"]["properties"]["count"];
        assert_eq!(count["minimum"], json!(1), "the author's bound stays");
        let depth = &c["properties"]["arguments"]["properties"]["qos"]["properties"]["depth"];
        assert_eq!(depth["maximum"], json!(SAFE_INT));
        assert!(s.parameters["properties"]["qos"]["properties"]["depth"]
            .get("maximum")
            .is_none());
        // A list of types is bounded for each type it names.
        let s = ToolSpec::new(
            "t",
            "",
            json!({"type": "object", "properties": {"v": {"type": ["string", "number", "null"]}}}),
        )
        .unwrap();
        let v = &s.call_schema()["properties"]["arguments"]["properties"]["v"];
        assert_eq!(v["maxLength"], json!(MAX_CHARS));
        assert_eq!(v["maximum"], json!(SAFE_NUMBER));
    }

    #[test]
    fn closing_an_object_declares_the_names_it_requires() {
        let s = ToolSpec::new(
            "waste",
            "",
            json!({
                "type": "object",
                "properties": {
                    "population": {"type": "object", "properties": {}, "required": ["adults", "children"]}
                },
                "required": ["population"]
            }),
        )
        .unwrap();
        let population = &s.parameters["properties"]["population"];
        assert_eq!(population["additionalProperties"], json!(false));
        assert_eq!(
            population["properties"]["adults"],
            json!({"type": ["string", "number", "boolean"]})
        );
        assert!(s
            .validate(&json!({"population": {"adults": 2, "children": 1}}))
            .is_ok());
        assert!(s
            .validate(&json!({"population": {"adults": 2, "children": 1, "pets": 3}}))
            .is_err());
    }

    #[test]
    fn call_schema_puts_the_name_first() {
        let c = spec().call_schema();
        let keys: Vec<&String> = c["properties"].as_object().unwrap().keys().collect();
        assert_eq!(keys, ["name", "arguments"]);
    }
}
