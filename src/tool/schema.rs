//! JSON schemas from Rust argument types (schemars), cleaned into the subset every
//! consumer here reads the same way: subschemas inlined (no `$ref`), no `$schema`/`title`
//! noise in the prompt, integer/float `format`s turned into bounds the grammar enforces.

use schemars::generate::SchemaSettings;
use serde_json::{json, Value};

/// The mark of a string argument that quotes the operator (a fact to keep), in a tool's
/// live parameters (`Tool::live_parameters`): the agent holds it to words the request
/// ends with (`reading::bound`). The prompt never shows it.
pub(crate) const QUOTE: &str = "x-quote";

/// The mark of a string argument that is a unit, in a tool's live parameters: `"from"`,
/// the unit of the number the call is given; `"to"`, the unit it is given in. The agent
/// holds them to the units the request writes, the one written after a number being
/// `from` (`reading::bound`). The prompt never shows it, nor does the grammar.
pub(crate) const UNIT: &str = "x-unit";

/// The names an object schema lists as `required` (none when it lists none).
pub(crate) fn required(object: &Value) -> Vec<String> {
    object["required"]
        .as_array()
        .map(|r| {
            r.iter()
                .filter_map(Value::as_str)
                .map(String::from)
                .collect()
        })
        .unwrap_or_default()
}

/// A property of one of `types` (alone, or beside others such as null) without an enum
/// or const of its own: a value the model writes freely.
pub(crate) fn is_open(prop: &Value, types: &[&str]) -> bool {
    let of = |t: &Value| t.as_str().is_some_and(|t| types.contains(&t));
    let ty = &prop["type"];
    (of(ty) || ty.as_array().is_some_and(|t| t.iter().any(of)))
        && prop.get("enum").is_none()
        && prop.get("const").is_none()
}

/// Whether a schema takes a value of one of `types` anywhere within it.
pub(crate) fn takes(schema: &Value, types: &[&str]) -> bool {
    match schema {
        Value::Object(o) => {
            o.get("type")
                .and_then(Value::as_str)
                .is_some_and(|t| types.contains(&t))
                || o.values().any(|v| takes(v, types))
        }
        Value::Array(items) => items.iter().any(|v| takes(v, types)),
        _ => false,
    }
}

/// The cleaned schema of `T`'s JSON form.
pub(crate) fn schema_for<T: schemars::JsonSchema>() -> Value {
    let settings = SchemaSettings::draft2020_12().with(|s| {
        s.inline_subschemas = true;
    });
    let schema = settings.into_generator().into_root_schema_for::<T>();
    let mut v = schema.to_value();
    clean(&mut v, true);
    if v.get("properties").is_none() {
        v["properties"] = json!({});
    }
    v
}

fn clean(v: &mut Value, root: bool) {
    match v {
        Value::Object(map) => {
            map.remove("$schema");
            if root {
                map.remove("title");
            }
            if let Some(Value::String(f)) = map.get("format").cloned() {
                let bounds = match f.as_str() {
                    "uint8" => Some((0i64, u8::MAX as i64)),
                    "uint16" => Some((0, u16::MAX as i64)),
                    "uint32" => Some((0, u32::MAX as i64)),
                    "int8" => Some((i8::MIN as i64, i8::MAX as i64)),
                    "int16" => Some((i16::MIN as i64, i16::MAX as i64)),
                    "int32" => Some((i32::MIN as i64, i32::MAX as i64)),
                    _ => None,
                };
                if let Some((lo, hi)) = bounds {
                    map.entry("minimum").or_insert(json!(lo));
                    map.entry("maximum").or_insert(json!(hi));
                }
                if f.starts_with("uint") {
                    map.entry("minimum").or_insert(json!(0));
                }
                if f.starts_with("int") || f.starts_with("uint") || f == "double" || f == "float" {
                    map.remove("format");
                }
            }
            // schemars writes `Option<T>` as `"type": ["T", "null"]`; an optional argument
            // is better left out than sent as null.
            if let Some(Value::Array(types)) = map.get("type").cloned() {
                let non_null: Vec<Value> = types.into_iter().filter(|t| t != "null").collect();
                if non_null.len() == 1 {
                    map.insert("type".into(), non_null[0].clone());
                }
            }
            // `Option<T>` with `#[serde(default)]` gets `"default": null`: what leaving
            // it out means anyway, and tokens in every prompt that lists it.
            if map.get("default") == Some(&Value::Null) {
                map.remove("default");
            }
            for (k, x) in map.iter_mut() {
                if k != "enum" && k != "const" && k != "default" && k != "examples" {
                    clean(x, false);
                }
            }
        }
        Value::Array(items) => items.iter_mut().for_each(|x| clean(x, false)),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[allow(dead_code)]
    #[derive(schemars::JsonSchema, serde::Deserialize)]
    struct Args {
        /// The topic to read, e.g. /turtle1/pose.
        topic: String,
        /// How many messages.
        #[schemars(range(min = 1, max = 20))]
        count: Option<u32>,
        mode: Mode,
    }

    #[allow(dead_code)]
    #[derive(schemars::JsonSchema, serde::Deserialize)]
    #[serde(rename_all = "lowercase")]
    enum Mode {
        Fast,
        Slow,
    }

    #[test]
    fn schemas_are_inlined_bounded_and_described() {
        let s = schema_for::<Args>();
        assert!(s.get("$schema").is_none() && s.get("title").is_none());
        assert!(!s.to_string().contains("$ref"), "{s}");
        let count = &s["properties"]["count"];
        assert_eq!(count["type"], json!("integer"));
        assert_eq!(count["minimum"], json!(1));
        assert_eq!(count["maximum"], json!(20));
        assert!(count.get("format").is_none());
        assert_eq!(s["properties"]["mode"]["enum"], json!(["fast", "slow"]));
        assert_eq!(
            s["properties"]["topic"]["description"],
            json!("The topic to read, e.g. /turtle1/pose.")
        );
        assert_eq!(s["required"], json!(["topic", "mode"]));
    }
}
