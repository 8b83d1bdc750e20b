//! Grounding of optional arguments: a small model fills optional arguments it was never
//! asked for (a listing's `namespace` set to the tool's own name, a filter copied from a
//! description's example, a gravity of 9.81 where the tool's default is -9.81), and a
//! filter nobody asked for hides the answer. Before a call runs, an optional free-text
//! argument is kept only when its words occur in what the operator said or what a tool
//! returned this run, or in the default its schema declares; otherwise it is dropped,
//! which is always valid (it is optional) and means "no filter" / "the default".
//! `with_numbers` holds optional numbers to the same rule: their value must be spelled
//! (by value, as the call verifier reads numbers) or be the declared default.
//!
//! Required arguments, enums, booleans and arrays are never touched: the grammar already
//! bounds them, and a required value must be the model's own guess.
//!
//! Cost: per call, each optional argument's words looked up in the text gathered so far;
//! nothing per token.

use serde_json::Value;

use super::verify::Request;
use super::{default, Strategy};
use crate::tool::schema::is_open;
use crate::tool::{ToolCall, ToolSpec};

/// Words of at least this many characters must be grounded; shorter ones ("/", "x") are
/// left alone.
const MIN_WORD: usize = 3;

/// What optional arguments may draw on: the operator's words and what tools returned,
/// kept lowercased as it grows.
#[derive(Debug, Clone, Default)]
pub(crate) struct Grounding {
    text: String,
    /// Each piece of text added, read for numbers; `None` while numbers are left alone.
    numbers: Option<Vec<Request>>,
}

impl Grounding {
    /// Grounding from what the operator said (earlier queries and this one).
    pub fn new<'a>(said: impl IntoIterator<Item = &'a str>) -> Grounding {
        let mut g = Grounding::default();
        for s in said {
            g.add(s);
        }
        g
    }

    /// Hold optional numbers to the rule too (from here on, and for the text already
    /// added).
    pub(crate) fn with_numbers(mut self) -> Grounding {
        self.numbers = Some(
            self.text
                .split('\n')
                .filter(|t| !t.is_empty())
                .map(Request::new)
                .collect(),
        );
        self
    }

    /// `with_numbers`, the numbers held to this `request`'s (and those tools return from
    /// here on), while words stay grounded by the whole session: a number an earlier
    /// request said is no ground for this one's optional arguments ("half a meter",
    /// then a status read waiting 0.5 s, too short for a 1 Hz battery topic).
    pub(crate) fn with_numbers_of(mut self, request: &str) -> Grounding {
        self.numbers = Some(vec![Request::new(request)]);
        self
    }

    /// Add text a tool returned.
    pub fn add(&mut self, text: &str) {
        self.text.push('\n');
        self.text.push_str(&text.to_lowercase());
        if let Some(n) = &mut self.numbers {
            n.push(Request::new(text));
        }
    }

    /// Is `value` of the optional property `prop` spelled here or by its default?
    fn grounds(&self, prop: &Value, value: &Value) -> bool {
        let default = || default::declared(prop);
        match value {
            Value::String(v) if is_open(prop, &["string"]) => {
                grounded(v, &self.text) || default().is_some_and(|d| d.spells_words(v))
            }
            Value::Number(_) if is_open(prop, &["integer", "number"]) => match &self.numbers {
                None => true,
                Some(said) => {
                    // A direction said in words is a sign ("back 2 m" is -2).
                    let magnitude = value.as_f64().map(|x| serde_json::json!(x.abs()));
                    said.iter().any(|r| {
                        r.spells(value) == Some(true)
                            || magnitude
                                .as_ref()
                                .is_some_and(|m| r.spells(m) == Some(true))
                    }) || default().is_some_and(|d| d.is(value))
                }
            },
            _ => true,
        }
    }

    /// Drop the optional string (and, `with_numbers`, number) arguments of `call` never
    /// mentioned here nor declared as their default; returns the names of the dropped
    /// arguments.
    pub(crate) fn drop_ungrounded(&self, call: &mut ToolCall, spec: &ToolSpec) -> Vec<String> {
        let required: Vec<&str> = spec.parameters["required"]
            .as_array()
            .map(|r| r.iter().filter_map(Value::as_str).collect())
            .unwrap_or_default();
        let props = &spec.parameters["properties"];
        let Some(args) = call.arguments.as_object_mut() else {
            return Vec::new();
        };
        let dropped: Vec<String> = args
            .iter()
            .filter(|(name, value)| {
                !required.contains(&name.as_str()) && !self.grounds(&props[name.as_str()], value)
            })
            .map(|(name, _)| name.clone())
            .collect();
        for name in &dropped {
            args.remove(name);
        }
        dropped
    }
}

impl Strategy for Grounding {
    fn name(&self) -> &'static str {
        "grounding"
    }

    fn settle(&self, call: &mut ToolCall, spec: &ToolSpec) -> Vec<String> {
        self.drop_ungrounded(call, spec)
    }
}

/// Values without a word this short or shorter ("/", ".*") are left alone; longer ones
/// that are all punctuation (a regex copied from some schema) are not grounded.
const MAX_BARE: usize = 4;

/// Every word of `value` (runs of letters, digits and `_`, as in ROS names;
/// case-insensitive) occurs in `context` (lowercase).
fn grounded(value: &str, context: &str) -> bool {
    let value = value.to_lowercase();
    let words: Vec<&str> = value
        .split(|c: char| !c.is_alphanumeric() && c != '_')
        .filter(|w| w.chars().count() >= MIN_WORD)
        .collect();
    if words.is_empty() {
        return value.chars().count() <= MAX_BARE;
    }
    words.iter().all(|w| context.contains(w))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn spec() -> ToolSpec {
        ToolSpec::new(
            "ros_node_list",
            "List nodes.",
            json!({"type": "object", "properties": {
                "namespace": {"type": "string"},
                "pattern": {"type": ["string", "null"]},
                "level": {"type": "string", "enum": ["info", "warn"]},
                "node": {"type": "string"},
                "count": {"type": "integer"}
            }, "required": ["node"]}),
        )
        .unwrap()
    }

    fn call(args: Value) -> ToolCall {
        ToolCall {
            name: "ros_node_list".into(),
            arguments: args,
        }
    }

    #[test]
    fn an_optional_filter_nobody_mentioned_is_dropped() {
        let mut c = call(json!({"node": "/made_up", "namespace": "ros_node_list", "count": 3}));
        let dropped =
            Grounding::new(["show me every running node"]).drop_ungrounded(&mut c, &spec());
        assert_eq!(dropped, ["namespace"]);
        // The required guess and the number stay.
        assert_eq!(c.arguments, json!({"node": "/made_up", "count": 3}));
    }

    #[test]
    fn words_from_the_query_or_a_tool_result_are_kept() {
        let ctx = "which topics does turtle1 have? {\"nodes\": [\"/turtlesim\"]}";
        let mut c =
            call(json!({"node": "/x", "namespace": "/Turtle1", "pattern": "turtlesim|turtle1"}));
        assert!(Grounding::new([ctx])
            .drop_ungrounded(&mut c, &spec())
            .is_empty());
        assert_eq!(c.arguments["namespace"], "/Turtle1");
    }

    #[test]
    fn one_unknown_word_is_enough_to_drop_and_enums_are_untouched() {
        let mut c = call(json!({"node": "/x", "pattern": "turtle.*pose", "level": "warn"}));
        let dropped = Grounding::new(["show turtle logs"]).drop_ungrounded(&mut c, &spec());
        assert_eq!(dropped, ["pattern"]);
        assert_eq!(c.arguments["level"], "warn");
    }

    #[test]
    fn short_words_and_empty_values_are_left_alone() {
        let mut c = call(json!({"node": "/x", "namespace": "/", "pattern": ".*"}));
        assert!(Grounding::new(["anything"])
            .drop_ungrounded(&mut c, &spec())
            .is_empty());
        // A regex of punctuation copied from another tool's schema is noise.
        let mut c = call(json!({"node": "/x", "pattern": "^[^{}<>]*[^{}<>:\\s]$"}));
        assert_eq!(
            Grounding::new(["anything"]).drop_ungrounded(&mut c, &spec()),
            ["pattern"]
        );
    }

    #[test]
    fn optional_numbers_must_be_spelled_or_the_default_when_held_to_it() {
        let spec = ToolSpec::new(
            "final_speed",
            "Speed of a falling object.",
            json!({"type": "object", "properties": {
                "time": {"type": "integer"},
                "gravity": {"type": "number", "description": "Default is -9.81 m/s^2."},
                "initial": {"type": "integer", "description": "Initial speed, default 0."},
                "drag": {"type": "number"},
                "unit": {"type": "string", "description": "Defaults to 'm/s'."}
            }, "required": ["time"]}),
        )
        .unwrap();
        let call = |args: Value| ToolCall {
            name: "final_speed".into(),
            arguments: args,
        };
        let said = "How fast after falling for 5 seconds, with a drag of 0.3?";
        // Strings only, as the agent runs it: the numbers stay.
        let mut c = call(json!({"time": 7, "gravity": 9.81, "unit": "feet"}));
        assert_eq!(
            Grounding::new([said]).drop_ungrounded(&mut c, &spec),
            ["unit"]
        );
        assert_eq!(c.arguments, json!({"time": 7, "gravity": 9.81}));
        // Held to it: 9.81 is neither said nor the default (-9.81); the required time is
        // the model's own guess; 0.3 is said, 0 and "m/s" are the defaults.
        let g = Grounding::new([said]).with_numbers();
        let mut c =
            call(json!({"time": 7, "gravity": 9.81, "drag": 0.3, "initial": 0, "unit": "m/s"}));
        assert_eq!(g.drop_ungrounded(&mut c, &spec), ["gravity"]);
        let mut c = call(json!({"time": 5, "gravity": -9.81, "drag": 2}));
        assert_eq!(g.drop_ungrounded(&mut c, &spec), ["drag"]);
        // Held to this request's numbers: an earlier request's 0.3 is no ground.
        let g2 = Grounding::new(["drive at 0.3 m/s", "and now?"]).with_numbers_of("and now?");
        let mut c = call(json!({"time": 5, "drag": 0.3}));
        assert_eq!(g2.drop_ungrounded(&mut c, &spec), ["drag"]);
        // Numbers a tool returned later ground too.
        let mut g = g;
        g.add("{\"drag\": 2}");
        let mut c = call(json!({"time": 5, "drag": 2}));
        assert!(g.drop_ungrounded(&mut c, &spec).is_empty());
    }
}
