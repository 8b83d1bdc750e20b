//! Types learnt from a peer, verified: a node's `~/get_type_description` answer is
//! trusted only when its structured description hashes (REP 2011's RIHS01) to the type
//! hash the node announced in discovery, and the definitions used are built from that
//! same structured description (what was hashed), not from the free text beside it.
//! Field types ROS defines but ferrosa cannot encode (wstring, long double, wchar) make
//! the type unusable, as does a fixed array beyond `msg::MAX_FIXED_ARRAY`, and a
//! description past `msg`'s bounds (types, fields, nesting depth, values; a type that
//! contains itself).

use std::sync::Arc;

use serde_json::Value;
use sha2::{Digest, Sha256};

pub use super::msg::MAX_LEAVES;
use super::msg::{
    check_extent, normalize_type, BaseType, Field, MessageDef, MsgError, Primitive, Shape,
    MAX_FIELDS, MAX_FIXED_ARRAY, MAX_TYPES,
};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(crate) enum TypeDescError {
    #[error("the type description of {0} is malformed")]
    Malformed(String),
    #[error("the type description of {name} hashes to {computed}, not the {announced} its node announced; it is not used")]
    HashMismatch {
        name: String,
        computed: String,
        announced: String,
    },
    #[error("{type_name}.{field}: {reason}")]
    Unsupported {
        type_name: String,
        field: String,
        reason: String,
    },
    #[error("{0} is too large to use: {1}")]
    TooLarge(String, String),
}

/// The RIHS01 hash of a `type_description_interfaces/msg/TypeDescription` (as JSON): a
/// SHA-256 of its fields without default values, written as Python's `json.dumps` writes
/// them, the referenced types sorted by name.
pub(crate) fn rihs01(description: &Value) -> Result<String, TypeDescError> {
    let main = &description["type_description"];
    let name = main["type_name"].as_str().unwrap_or_default().to_string();
    let malformed = || TypeDescError::Malformed(name.clone());
    let mut refs: Vec<&Value> = description["referenced_type_descriptions"]
        .as_array()
        .ok_or_else(malformed)?
        .iter()
        .collect();
    refs.sort_by(|a, b| a["type_name"].as_str().cmp(&b["type_name"].as_str()));
    let mut text = String::from("{\"type_description\": ");
    individual(main, &mut text).ok_or_else(malformed)?;
    text.push_str(", \"referenced_type_descriptions\": [");
    for (i, r) in refs.iter().enumerate() {
        if i > 0 {
            text.push_str(", ");
        }
        individual(r, &mut text).ok_or_else(malformed)?;
    }
    text.push_str("]}");
    let hex: String = Sha256::digest(text.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    Ok(format!("RIHS01_{hex}"))
}

/// One individual description, hashable form.
fn individual(d: &Value, out: &mut String) -> Option<()> {
    out.push_str("{\"type_name\": ");
    out.push_str(&ascii_json(d["type_name"].as_str()?));
    out.push_str(", \"fields\": [");
    for (i, f) in d["fields"].as_array()?.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        let t = &f["type"];
        out.push_str(&format!(
            "{{\"name\": {}, \"type\": {{\"type_id\": {}, \"capacity\": {}, \"string_capacity\": {}, \"nested_type_name\": {}}}}}",
            ascii_json(f["name"].as_str()?),
            t["type_id"].as_u64()?,
            t["capacity"].as_u64()?,
            t["string_capacity"].as_u64()?,
            ascii_json(t["nested_type_name"].as_str()?),
        ));
    }
    out.push_str("]}");
    Some(())
}

/// A JSON string with every non-ASCII character escaped (Python's `ensure_ascii`).
fn ascii_json(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    for c in Value::String(s.to_string()).to_string().chars() {
        if c.is_ascii() {
            out.push(c);
        } else {
            let mut buf = [0u16; 2];
            for u in c.encode_utf16(&mut buf) {
                out.push_str(&format!("\\u{u:04x}"));
            }
        }
    }
    out
}

/// Verify `description` against the hash the node `announced`, and build the message
/// definitions it describes (the type and every type it references).
pub(crate) fn verified_definitions(
    description: &Value,
    announced: &str,
) -> Result<Vec<MessageDef>, TypeDescError> {
    let computed = rihs01(description)?;
    let main = &description["type_description"];
    let name = main["type_name"].as_str().unwrap_or_default().to_string();
    if computed != announced {
        return Err(TypeDescError::HashMismatch {
            name,
            computed,
            announced: announced.to_string(),
        });
    }
    let refs = description["referenced_type_descriptions"]
        .as_array()
        .map_or(&[][..], Vec::as_slice);
    if refs.len() >= MAX_TYPES {
        return Err(TypeDescError::TooLarge(
            name,
            format!("more than {MAX_TYPES} types in one description"),
        ));
    }
    let mut defs = vec![definition(main)?];
    for r in refs {
        defs.push(definition(r)?);
    }
    // A shipped type nested in a learnt one counts as one value: it is bounded already.
    let table: std::collections::BTreeMap<String, Arc<MessageDef>> = defs
        .iter()
        .map(|d| (d.name.clone(), Arc::new(d.clone())))
        .collect();
    check_extent(&defs[0].name, &|n: &str| table.get(n).cloned()).map_err(|e| {
        let why = match e {
            MsgError::Recursive { path, .. } => format!("it contains itself ({path})"),
            MsgError::TooLarge { reason, .. } => reason,
            other => other.to_string(),
        };
        TypeDescError::TooLarge(defs[0].name.clone(), why)
    })?;
    Ok(defs)
}

/// The message definition one individual description gives.
fn definition(d: &Value) -> Result<MessageDef, TypeDescError> {
    let type_name = normalize_type(d["type_name"].as_str().unwrap_or_default());
    let malformed = || TypeDescError::Malformed(type_name.clone());
    let mut fields = Vec::new();
    let mut text = String::new();
    let all = d["fields"].as_array().ok_or_else(malformed)?;
    if all.len() > MAX_FIELDS {
        return Err(TypeDescError::TooLarge(
            type_name,
            format!("more than {MAX_FIELDS} fields"),
        ));
    }
    for f in all {
        let name = f["name"].as_str().ok_or_else(malformed)?.to_string();
        let t = &f["type"];
        let unsupported = |reason: &str| TypeDescError::Unsupported {
            type_name: type_name.clone(),
            field: name.clone(),
            reason: reason.to_string(),
        };
        let id = t["type_id"].as_u64().ok_or_else(malformed)?;
        let capacity = t["capacity"].as_u64().unwrap_or(0) as usize;
        let string_capacity = t["string_capacity"].as_u64().unwrap_or(0) as usize;
        let (base, string_max) = match id % 48 {
            1 => (
                BaseType::Message(normalize_type(
                    t["nested_type_name"].as_str().unwrap_or_default(),
                )),
                None,
            ),
            17 => (BaseType::Primitive(Primitive::String), None),
            19 | 21 => (
                BaseType::Primitive(Primitive::String),
                Some(string_capacity),
            ),
            b => (
                BaseType::Primitive(primitive(b).ok_or_else(|| {
                    unsupported(
                        "a field type ferrosa cannot encode (wstring, wchar or long double)",
                    )
                })?),
                None,
            ),
        };
        let shape = match id / 48 {
            0 => Shape::Single,
            1 if capacity <= MAX_FIXED_ARRAY => Shape::Array(capacity),
            1 => {
                return Err(unsupported(&format!(
                    "a fixed array of {capacity} elements"
                )))
            }
            2 => Shape::Sequence {
                max: Some(capacity),
            },
            3 => Shape::Sequence { max: None },
            _ => return Err(unsupported(&format!("field type id {id}"))),
        };
        text.push_str(&format!("{} {name}\n", t["type_id"]));
        fields.push(Field {
            name,
            base,
            shape,
            string_max,
            default: None,
        });
    }
    Ok(MessageDef {
        name: type_name,
        fields,
        constants: Vec::new(),
        text,
    })
}

fn primitive(id: u64) -> Option<Primitive> {
    Some(match id {
        2 => Primitive::I8,
        3 => Primitive::U8,
        4 => Primitive::I16,
        5 => Primitive::U16,
        6 => Primitive::I32,
        7 => Primitive::U32,
        8 => Primitive::I64,
        9 => Primitive::U64,
        10 => Primitive::F32,
        11 => Primitive::F64,
        13 => Primitive::Char,
        15 => Primitive::Bool,
        16 => Primitive::Byte,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn field(name: &str, id: u64, cap: u64, nested: &str) -> Value {
        json!({"name": name, "type": {"type_id": id, "capacity": cap, "string_capacity": 0, "nested_type_name": nested}, "default_value": ""})
    }

    fn description() -> Value {
        json!({
            "type_description": {"type_name": "demo/msg/Reading", "fields": [
                field("value", 11, 0, ""), field("samples", 59, 3, ""), field("where", 1, 0, "geometry_msgs/msg/Point")]},
            "referenced_type_descriptions": [
                {"type_name": "geometry_msgs/msg/Point", "fields": [field("x", 11, 0, ""), field("y", 11, 0, ""), field("z", 11, 0, "")]}]
        })
    }

    #[test]
    fn a_description_is_used_only_when_it_hashes_to_what_was_announced() {
        let d = description();
        let hash = rihs01(&d).unwrap();
        assert!(hash.starts_with("RIHS01_") && hash.len() == 7 + 64);
        let defs = verified_definitions(&d, &hash).unwrap();
        assert_eq!(defs[0].name, "demo/msg/Reading");
        assert_eq!(defs[0].fields[1].shape, Shape::Array(3));
        assert_eq!(
            defs[0].fields[2].base,
            BaseType::Message("geometry_msgs/msg/Point".into())
        );
        // The same description with one field changed is another type.
        let mut forged = d.clone();
        forged["type_description"]["fields"][0]["type"]["type_id"] = json!(10);
        assert!(matches!(
            verified_definitions(&forged, &hash),
            Err(TypeDescError::HashMismatch { .. })
        ));
        // Default values are not part of the hash.
        let mut defaults = d.clone();
        defaults["type_description"]["fields"][0]["default_value"] = json!("1.5");
        assert_eq!(rihs01(&defaults).unwrap(), hash);
    }

    #[test]
    fn huge_or_self_containing_types_and_unencodable_fields_are_refused() {
        let mut d = description();
        d["type_description"]["fields"][1]["type"]["capacity"] = json!(1_000_000_000u64);
        let hash = rihs01(&d).unwrap();
        assert!(matches!(
            verified_definitions(&d, &hash),
            Err(TypeDescError::Unsupported { .. })
        ));
        // Each array within bounds, their product not: 65,536 × 65,536 values.
        let big = |name: &str, nested: &str| json!({"type_name": name, "fields": [field("a", 49, 65_536, nested)]});
        let d = json!({"type_description": big("evil/msg/Outer", "evil/msg/Inner"),
                       "referenced_type_descriptions": [{"type_name": "evil/msg/Inner", "fields": [field("v", 59, 65_536, "")]}]});
        let hash = rihs01(&d).unwrap();
        assert!(matches!(
            verified_definitions(&d, &hash),
            Err(TypeDescError::TooLarge(..))
        ));
        // A binary tree of types: 2^31 leaves from 31 small definitions.
        let level = |k: usize| {
            let below = format!("evil/msg/T{}", k - 1);
            json!({"type_name": format!("evil/msg/T{k}"), "fields": [field("l", 1, 0, &below), field("r", 1, 0, &below)]})
        };
        let mut refs: Vec<Value> = (1..31).map(level).collect();
        refs.push(json!({"type_name": "evil/msg/T0", "fields": [field("v", 11, 0, "")]}));
        let d = json!({"type_description": level(31), "referenced_type_descriptions": refs});
        let hash = rihs01(&d).unwrap();
        assert!(matches!(
            verified_definitions(&d, &hash),
            Err(TypeDescError::TooLarge(..))
        ));
        // A type that contains itself.
        let d = json!({"type_description": {"type_name": "evil/msg/Loop", "fields": [field("next", 1, 0, "evil/msg/Loop")]},
                       "referenced_type_descriptions": []});
        let hash = rihs01(&d).unwrap();
        assert!(matches!(
            verified_definitions(&d, &hash),
            Err(TypeDescError::TooLarge(..))
        ));
        // A chain of 10,000 types, each nesting the next: refused, not a deep walk.
        let link = |k: usize| json!({"type_name": format!("evil/msg/L{k}"), "fields": [field("n", 1, 0, &format!("evil/msg/L{}", k + 1))]});
        let d = json!({"type_description": link(0), "referenced_type_descriptions": (1..10_000).map(link).collect::<Vec<_>>()});
        let hash = rihs01(&d).unwrap();
        assert!(matches!(
            verified_definitions(&d, &hash),
            Err(TypeDescError::TooLarge(..))
        ));
        let d = json!({"type_description": link(0), "referenced_type_descriptions": (1..40).map(link).collect::<Vec<_>>()});
        let hash = rihs01(&d).unwrap();
        assert!(matches!(
            verified_definitions(&d, &hash),
            Err(TypeDescError::TooLarge(_, why)) if why.contains("deep")
        ));
        let mut w = description();
        w["type_description"]["fields"][0]["type"]["type_id"] = json!(18);
        let hash = rihs01(&w).unwrap();
        assert!(matches!(
            verified_definitions(&w, &hash),
            Err(TypeDescError::Unsupported { .. })
        ));
    }
}
