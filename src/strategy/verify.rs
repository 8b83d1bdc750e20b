//! Whether one more call in a list earns its place: the values it brings must come from
//! the request.
//!
//! A small model asked for "Chicago, Sacramento and Portland" stops after one city as
//! readily as it goes on to invent a fourth; whether the list should go on is hard to
//! read off its odds alone. What the next call would say settles most of it: a call
//! worth making changes at least one value of the calls before it to something the
//! request spells ("Sacramento", 52.33), and changes nothing to something it does not
//! ("Minyan" for "Mauryan", a year 3000 nobody mentioned). Values an earlier call
//! already used (the shared city of two bookings, or the first call's numbers swapped
//! around) and booleans say nothing either way.
//!
//! Strings are compared as lowercased words (a value must be a run of the request's
//! words), numbers by value, both read by `lexicon`.
//!
//! Cost: the request is read once per turn; a closed call's leaves are compared once.

use serde_json::Value;

use super::default;
use super::{Review, Strategy};
use crate::lexicon::{numbers, same_number, words};
use crate::tool::ToolCall;

/// The request a proposed call is checked against, split once.
#[derive(Debug, Clone)]
pub struct Request {
    words: Vec<String>,
    numbers: Vec<f64>,
}

/// What a proposed call brings that no earlier call had.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct Novelty {
    /// New values the request spells.
    pub grounded: usize,
    /// New values it does not.
    pub ungrounded: usize,
}

impl Novelty {
    /// The call adds something the operator asked for and nothing they did not.
    pub(crate) fn earns_its_place(&self) -> bool {
        self.grounded > 0 && self.ungrounded == 0
    }
}

impl Request {
    pub fn new(text: &str) -> Request {
        Request {
            words: words(text),
            numbers: numbers(text),
        }
    }

    /// Does the request spell `v` (a string's words in a row, or a number's value)?
    pub fn spells(&self, v: &Value) -> Option<bool> {
        match v {
            Value::String(s) => {
                let w = words(s);
                if w.is_empty() {
                    return Some(false);
                }
                if w.iter().all(|x| x.chars().all(|c| c.is_ascii_digit())) {
                    if let Ok(n) = w.concat().parse::<f64>() {
                        if w.len() == 1 && self.numbers.contains(&n) {
                            return Some(true);
                        }
                    }
                }
                Some(self.words.windows(w.len()).any(|win| win == w.as_slice()))
            }
            Value::Number(n) => {
                let n = n.as_f64()?;
                Some(self.numbers.iter().any(|&m| same_number(m, n)))
            }
            // Booleans and nulls: the request cannot spell them.
            _ => None,
        }
    }

    /// What `call`'s arguments bring that none of `earlier` had.
    /// Values the schema enumerates (units, modes) or declares as a parameter's default
    /// come from the schema, not the request, and count for nothing.
    pub(crate) fn novelty(
        &self,
        call: &Value,
        earlier: &[Value],
        schema: Option<&Value>,
    ) -> Novelty {
        let mut leaves = Vec::new();
        flatten(call, &mut String::new(), &mut leaves);
        let mut before = Vec::new();
        for e in earlier {
            flatten(e, &mut String::new(), &mut before);
        }
        let mut n = Novelty::default();
        for (path, v) in leaves {
            // A value an earlier call already used, wherever, adds nothing: a call that
            // only swaps the first one's values around was not asked for.
            let kept = before.iter().any(|(_, b)| same(b, v));
            let prop = schema.and_then(|s| schema_at(s, &path));
            let listed = prop.is_some_and(|s| s.get("enum").is_some() || s.get("const").is_some());
            // The parameter's declared default is what the call means when the request
            // says nothing, so it tells nothing either.
            let default = prop.and_then(default::declared).is_some_and(|d| d.is(v));
            if kept || default {
                continue;
            }
            // A value from a closed list is the grammar's as much as the model's: spelt by
            // the request it grounds the call, otherwise it tells nothing.
            if listed {
                n.grounded += usize::from(self.spells(v) == Some(true));
                continue;
            }
            match self.spells(v) {
                Some(true) => n.grounded += 1,
                Some(false) => n.ungrounded += 1,
                None => {}
            }
        }
        n
    }
}

/// Call verification as a strategy: each call a gated list writes is checked against the
/// request (see the module header). A first call that brings more unasked values than
/// asked ones is written again more strictly, then answered instead; a further call is
/// kept only when it earns its place.
pub struct Verification {
    request: Request,
    /// Each tool's parameter schema, by name.
    schemas: Vec<(String, Value)>,
}

impl Verification {
    pub fn new(request: &str, specs: &[crate::tool::ToolSpec]) -> Verification {
        Verification {
            request: Request::new(request),
            schemas: specs
                .iter()
                .map(|s| (s.name.clone(), s.parameters.clone()))
                .collect(),
        }
    }
}

impl Strategy for Verification {
    fn name(&self) -> &'static str {
        "verify"
    }

    fn review(&mut self, call: &ToolCall, earlier: &[ToolCall], first: bool) -> Review {
        let schema = self
            .schemas
            .iter()
            .find(|(n, _)| *n == call.name)
            .map(|(_, s)| s);
        let same_tool: Vec<Value> = earlier
            .iter()
            .filter(|e| e.name == call.name)
            .map(|e| e.arguments.clone())
            .collect();
        let n = self.request.novelty(&call.arguments, &same_tool, schema);
        tracing::debug!(target: "ferrosa::gate", ?n, first, call = %call.arguments, "reviewed");
        if first {
            if n.ungrounded > 0 && n.ungrounded >= n.grounded {
                Review::Redo
            } else {
                Review::Keep
            }
        } else if n.earns_its_place() {
            Review::Keep
        } else if n.ungrounded > 0 {
            Review::Redo
        } else {
            Review::Reject
        }
    }
}

fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::String(x), Value::String(y)) => words(x) == words(y),
        (Value::Number(x), Value::Number(y)) => x.as_f64() == y.as_f64(),
        _ => a == b,
    }
}

/// The schema of the value at `path` (as `flatten` writes it) under an object schema.
fn schema_at<'a>(schema: &'a Value, path: &str) -> Option<&'a Value> {
    let mut s = schema;
    for seg in path.split('/').skip(1) {
        s = match s.get("properties").and_then(|p| p.get(seg)) {
            Some(p) => p,
            None => s.get("items")?,
        };
    }
    Some(s)
}

/// Scalar leaves with their paths (`/key/0/inner`).
fn flatten<'a>(v: &'a Value, path: &mut String, out: &mut Vec<(String, &'a Value)>) {
    let len = path.len();
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                path.push('/');
                path.push_str(k);
                flatten(x, path, out);
                path.truncate(len);
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                path.push('/');
                path.push_str(&i.to_string());
                flatten(x, path, out);
                path.truncate(len);
            }
        }
        scalar => out.push((path.clone(), scalar)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn numbers_and_words_of_a_request() {
        let r = Request::new(
            "Tax on $30.45 in Chicago, $1,250,000 in Portland, Oregon; -3 and 5m; 10,11; 2e-9 C.",
        );
        for (v, want) in [
            (json!(30.45), true),
            (json!(1250000), true),
            (json!(-3), true),
            (json!(3), true),
            (json!(5), true),
            (json!(1250), false),
            (json!(11), true),
            (json!(1011), false),
            (json!(2e-9), true),
            (json!(2), false),
            (json!(30), false),
            (json!("portland oregon"), true),
            (json!("Portland, Oregon"), true),
            (json!("Oregon Portland"), false),
            (json!("Chic"), false),
            (json!("5"), true),
            (json!(""), false),
        ] {
            assert_eq!(r.spells(&v), Some(want), "{v}");
        }
        let words = Request::new("the next three hours for a family of four, twenty in all");
        for (v, want) in [
            (json!(3), true),
            (json!(4), true),
            (json!(20), true),
            (json!(2), false),
        ] {
            assert_eq!(words.spells(&v), Some(want), "{v}");
        }
        assert_eq!(r.spells(&json!(true)), None);
    }

    #[test]
    fn a_call_earns_its_place_with_new_values_the_request_spells() {
        let r = Request::new(
            "Sales tax on $30.45 in Chicago, Illinois, $52.33 in Sacramento, California and $11.23 in Portland, Oregon.",
        );
        let first = json!({"amount": 30.45, "city": "Chicago", "state": "Illinois"});
        let next = json!({"amount": 52.33, "city": "Sacramento", "state": "California"});
        let n = r.novelty(&next, std::slice::from_ref(&first), None);
        assert_eq!(
            n,
            Novelty {
                grounded: 3,
                ungrounded: 0
            }
        );
        assert!(n.earns_its_place());
        // An invented city is not asked for.
        let invented = json!({"amount": 11.23, "city": "Seattle", "state": "Oregon"});
        assert!(!r
            .novelty(&invented, &[first.clone(), next.clone()], None)
            .earns_its_place());
        // The same values again (or only values kept) bring nothing.
        assert!(!r
            .novelty(&first, std::slice::from_ref(&first), None)
            .earns_its_place());
        let shared = json!({"amount": 30.45, "city": "chicago", "state": "Illinois", "rush": true});
        assert_eq!(r.novelty(&shared, &[first], None), Novelty::default());
    }

    #[test]
    fn swapped_values_bring_nothing() {
        let r =
            Request::new("Density of an object of mass 45 kg and volume 15 m^3; then from B to C.");
        let first = json!({"mass": 45, "volume": 15});
        let swapped = json!({"mass": 15, "volume": 45});
        assert_eq!(r.novelty(&swapped, &[first], None), Novelty::default());
        let leg = json!({"from": "A", "to": "B"});
        let next = json!({"from": "B", "to": "C"});
        assert_eq!(
            r.novelty(&next, &[leg], None),
            Novelty {
                grounded: 1,
                ungrounded: 0
            }
        );
    }

    #[test]
    fn array_items_are_compared_by_place() {
        let r = Request::new("Distance from (3, 4) to (5, 12), then from (3, 4) to (8, 15).");
        let a = json!({"from": [3, 4], "to": [5, 12]});
        let b = json!({"from": [3, 4], "to": [8, 15]});
        assert_eq!(
            r.novelty(&b, &[a], None),
            Novelty {
                grounded: 2,
                ungrounded: 0
            }
        );
    }

    #[test]
    fn enumerated_values_count_for_nothing() {
        let r = Request::new("Area of a circle of radius 3");
        let schema = json!({"type": "object", "properties": {
            "radius": {"type": "number"},
            "unit": {"type": "string", "enum": ["cm", "m"]},
            "tags": {"type": "array", "items": {"type": "string", "enum": ["x"]}}
        }});
        let call = json!({"radius": 3, "unit": "cm", "tags": ["x"]});
        assert_eq!(
            r.novelty(&call, &[], Some(&schema)),
            Novelty {
                grounded: 1,
                ungrounded: 0
            }
        );
        assert_eq!(
            r.novelty(&call, &[], None),
            Novelty {
                grounded: 1,
                ungrounded: 2
            }
        );
    }

    #[test]
    fn declared_defaults_count_for_nothing() {
        let r = Request::new("Prime factors of 450");
        let schema = json!({"type": "object", "properties": {
            "number": {"type": "integer"},
            "formatted": {"type": "boolean", "description": "Default is true."},
            "limit": {"type": "integer", "description": "At most this many; default 100."}
        }});
        let call = json!({"number": 450, "formatted": true, "limit": 100});
        assert_eq!(
            r.novelty(&call, &[], Some(&schema)),
            Novelty {
                grounded: 1,
                ungrounded: 0
            }
        );
        let call = json!({"number": 450, "limit": 10});
        assert_eq!(r.novelty(&call, &[], Some(&schema)).ungrounded, 1);
    }
}
