//! Scoring one turn against BFCL's answers, with the semantics of BFCL's AST checker:
//! the right function name(s); every parameter without "" among its allowed values is
//! present; every value is among the allowed ones after normalisation (strings compared
//! case- and punctuation-insensitively, an int accepted where a float is declared); no
//! parameter the answer does not know; parallel calls matched in any order; and for
//! irrelevance, no call at all.

use serde_json::{Map, Value};

use super::bfcl::Case;
use crate::tool::ToolCall;

#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    Pass,
    Fail(String),
}

impl Verdict {
    pub fn passed(&self) -> bool {
        *self == Verdict::Pass
    }
}

/// BFCL's string normalisation: drop spaces and `,./-_*^`, lowercase, `'` → `"`.
pub(crate) fn normalise(s: &str) -> String {
    s.chars()
        .filter(|c| !matches!(c, ' ' | ',' | '.' | '/' | '-' | '_' | '*' | '^'))
        .flat_map(char::to_lowercase)
        .map(|c| if c == '\'' { '"' } else { c })
        .collect()
}

fn declared_type(decl: Option<&Value>) -> &str {
    decl.and_then(|d| d.get("type"))
        .and_then(Value::as_str)
        .unwrap_or("any")
}

/// Does the model's `got` equal the allowed `want` for a parameter declared as `decl`?
pub(crate) fn value_matches(got: &Value, want: &Value, decl: Option<&Value>) -> bool {
    let ty = declared_type(decl);
    match (got, want) {
        (Value::Number(g), Value::Number(w)) => {
            // An int where a float is declared is fine; a float where an int is declared is not.
            if matches!(ty, "integer" | "int") && g.as_i64().is_none() && g.as_u64().is_none() {
                return false;
            }
            match (g.as_f64(), w.as_f64()) {
                (Some(a), Some(b)) => (a - b).abs() <= 1e-9 * b.abs().max(1.0),
                _ => false,
            }
        }
        (Value::String(g), Value::String(w)) => normalise(g) == normalise(w),
        (Value::Array(g), Value::Array(w)) => {
            let item = decl.and_then(|d| d.get("items"));
            g.len() == w.len() && g.iter().zip(w).all(|(a, b)| value_matches(a, b, item))
        }
        (Value::Object(g), Value::Object(w)) => dict_matches(g, w, decl),
        _ => got == want,
    }
}

/// BFCL writes nested dict answers with a list of allowed values per key.
fn dict_matches(got: &Map<String, Value>, want: &Map<String, Value>, decl: Option<&Value>) -> bool {
    let props = decl.and_then(|d| d.get("properties"));
    if got.keys().any(|k| !want.contains_key(k)) {
        return false;
    }
    want.iter().all(|(k, allowed)| {
        let sub = props.and_then(|p| p.get(k));
        let options: Vec<&Value> = match allowed {
            Value::Array(a) => a.iter().collect(),
            one => vec![one],
        };
        match got.get(k) {
            Some(v) => options.iter().any(|o| value_matches(v, o, sub)),
            None => options.iter().any(|o| *o == &Value::String(String::new())),
        }
    })
}

fn call_matches(
    call: &ToolCall,
    name: &str,
    params: &Map<String, Value>,
    case: &Case,
) -> Result<(), String> {
    if call.name != name {
        return Err(format!("called {} instead of {name}", call.name));
    }
    let decls = case.types.get(name);
    let empty = Map::new();
    let args = call.arguments.as_object().unwrap_or(&empty);
    for k in args.keys() {
        if !params.contains_key(k) {
            return Err(format!("unexpected parameter {k}"));
        }
    }
    for (k, allowed) in params {
        let options: Vec<&Value> = allowed
            .as_array()
            .map(|a| a.iter().collect())
            .unwrap_or_default();
        let optional = options.iter().any(|o| *o == &Value::String(String::new()));
        match args.get(k) {
            None if optional => {}
            None => return Err(format!("missing parameter {k}")),
            Some(v) => {
                let decl = decls.and_then(|d| d.get(k));
                if !options.iter().any(|o| value_matches(v, o, decl)) {
                    return Err(format!("{k} = {v} is not among {allowed}"));
                }
            }
        }
    }
    Ok(())
}

/// Find a one-to-one matching of expected calls to made calls (any order).
fn assign(
    expected: &[(String, Map<String, Value>)],
    calls: &[ToolCall],
    used: &mut Vec<bool>,
    case: &Case,
) -> bool {
    let Some(((name, params), rest)) = expected.split_first() else {
        return true;
    };
    for i in 0..calls.len() {
        if !used[i] && call_matches(&calls[i], name, params, case).is_ok() {
            used[i] = true;
            if assign(rest, calls, used, case) {
                return true;
            }
            used[i] = false;
        }
    }
    false
}

/// Score the calls a model made for `case`.
pub fn check(case: &Case, calls: &[ToolCall]) -> Verdict {
    if case.answer.is_empty() {
        return if calls.is_empty() {
            Verdict::Pass
        } else {
            Verdict::Fail(format!(
                "called {} although no function fits",
                calls[0].name
            ))
        };
    }
    if calls.len() != case.answer.len() {
        return Verdict::Fail(format!(
            "{} call(s), expected {}",
            calls.len(),
            case.answer.len()
        ));
    }
    if let [(name, params)] = case.answer.as_slice() {
        return match call_matches(&calls[0], name, params, case) {
            Ok(()) => Verdict::Pass,
            Err(why) => Verdict::Fail(why),
        };
    }
    let mut used = vec![false; calls.len()];
    if assign(&case.answer, calls, &mut used, case) {
        Verdict::Pass
    } else {
        // Say what the first unmatched expectation lacked.
        let why = case
            .answer
            .iter()
            .find_map(|(n, p)| {
                calls
                    .iter()
                    .map(|c| call_matches(c, n, p, case))
                    .find(Result::is_ok)
                    .is_none()
                    .then(|| format!("no call matches the expected {n}"))
            })
            .unwrap_or_else(|| "calls do not pair up with the expected ones".into());
        Verdict::Fail(why)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;
    use std::collections::HashMap;

    fn case(answer: Value, types: Value) -> Case {
        let answer = answer
            .as_array()
            .unwrap()
            .iter()
            .map(|c| {
                let (k, v) = c.as_object().unwrap().iter().next().unwrap();
                (k.clone(), v.as_object().unwrap().clone())
            })
            .collect();
        let mut t = HashMap::new();
        for (k, v) in types.as_object().unwrap() {
            t.insert(k.clone(), v.as_object().unwrap().clone());
        }
        Case {
            id: "t".into(),
            category: "t".into(),
            messages: vec![],
            functions: vec![],
            types: t,
            answer,
        }
    }

    fn call(name: &str, args: Value) -> ToolCall {
        ToolCall {
            name: name.into(),
            arguments: args,
        }
    }

    #[test]
    fn exact_alternatives_and_optional_parameters() {
        // From simple_python_0: unit may be "units" or omitted.
        let c = case(
            json!([{"calculate_triangle_area": {"base": [10], "height": [5], "unit": ["units", ""]}}]),
            json!({"calculate_triangle_area": {"base": {"type": "integer"}, "height": {"type": "integer"}, "unit": {"type": "string"}}}),
        );
        assert!(check(
            &c,
            &[call(
                "calculate_triangle_area",
                json!({"base": 10, "height": 5})
            )]
        )
        .passed());
        assert!(check(
            &c,
            &[call(
                "calculate_triangle_area",
                json!({"base": 10, "height": 5, "unit": "Units"})
            )]
        )
        .passed());
        assert!(!check(
            &c,
            &[call(
                "calculate_triangle_area",
                json!({"base": 10, "height": 5, "unit": "cm"})
            )]
        )
        .passed());
        assert!(
            !check(&c, &[call("calculate_triangle_area", json!({"base": 10}))]).passed(),
            "height is required"
        );
        assert!(!check(&c, &[call("area", json!({"base": 10, "height": 5}))]).passed());
        assert!(!check(
            &c,
            &[call(
                "calculate_triangle_area",
                json!({"base": 10, "height": 5, "color": "red"})
            )]
        )
        .passed());
    }

    #[test]
    fn strings_ignore_case_and_punctuation_and_ints_pass_for_floats() {
        let c = case(
            json!([{"f": {"city": ["New York, NY"], "x": [2.0], "n": [3]}}]),
            json!({"f": {"city": {"type": "string"}, "x": {"type": "float"}, "n": {"type": "integer"}}}),
        );
        assert!(check(
            &c,
            &[call("f", json!({"city": "new york ny", "x": 2, "n": 3}))]
        )
        .passed());
        assert!(
            !check(
                &c,
                &[call("f", json!({"city": "new york ny", "x": 2, "n": 3.5}))]
            )
            .passed(),
            "a float for an int"
        );
    }

    #[test]
    fn parallel_calls_match_in_any_order() {
        let c = case(
            json!([{"spotify.play": {"artist": ["Taylor Swift"], "duration": [20]}}, {"spotify.play": {"artist": ["Maroon 5"], "duration": [15]}}]),
            json!({"spotify.play": {"artist": {"type": "string"}, "duration": {"type": "integer"}}}),
        );
        let a = call(
            "spotify.play",
            json!({"artist": "Maroon 5", "duration": 15}),
        );
        let b = call(
            "spotify.play",
            json!({"artist": "Taylor Swift", "duration": 20}),
        );
        assert!(check(&c, &[a.clone(), b.clone()]).passed());
        assert!(check(&c, &[b.clone(), a.clone()]).passed());
        assert!(
            !check(&c, &[a.clone(), a.clone()]).passed(),
            "one call cannot answer both"
        );
        assert!(!check(&c, &[a]).passed());
    }

    #[test]
    fn irrelevance_passes_only_without_calls() {
        let c = case(json!([]), json!({}));
        assert!(check(&c, &[]).passed());
        assert!(!check(&c, &[call("determine_body_mass_index", json!({}))]).passed());
    }

    #[test]
    fn lists_and_nested_dicts() {
        let c = case(
            json!([{"g": {"xs": [[1, 2, 3]], "opt": [{"mode": ["fast", ""], "level": [2]}]}}]),
            json!({"g": {"xs": {"type": "array", "items": {"type": "integer"}}, "opt": {"type": "dict", "properties": {"mode": {"type": "string"}, "level": {"type": "integer"}}}}}),
        );
        assert!(check(
            &c,
            &[call("g", json!({"xs": [1, 2, 3], "opt": {"level": 2}}))]
        )
        .passed());
        assert!(
            !check(
                &c,
                &[call("g", json!({"xs": [3, 2, 1], "opt": {"level": 2}}))]
            )
            .passed(),
            "list order matters"
        );
        assert!(!check(
            &c,
            &[call(
                "g",
                json!({"xs": [1, 2, 3], "opt": {"level": 2, "x": 1}})
            )]
        )
        .passed());
    }
}
