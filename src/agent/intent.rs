//! Actuation the operator asked for. A small model that has run one tool tends to call
//! the next one it was shown, and with an operator who approves everything (`--yes`) that
//! moves the robot unasked ("where is the turtle?" → pose, then move, rotate, teleport).
//! So an actuating call runs only when a word of the request points at it: one of the
//! tool's own words (its name and description, minus every word an observing tool also
//! uses: "turtle" names the robot, "drive" names an act), or a word of one of the call's
//! string arguments (the `/spawn` of a service call). Tools the request cannot point at
//! (no own word in it, no string argument to name a target) are left out of the grammar;
//! the rest are checked once the call is made.

use std::collections::BTreeSet;

use serde_json::Value;

use super::select::stems;
use crate::tool::{ToolCall, ToolSpec};

/// The words of tool names and descriptions: `tools` are the observing ones.
pub fn vocabulary<'a>(tools: impl IntoIterator<Item = &'a ToolSpec>) -> BTreeSet<String> {
    tools.into_iter().flat_map(spec_words).collect()
}

fn spec_words(spec: &ToolSpec) -> Vec<String> {
    let mut w = stems(&spec.name.replace('_', " "));
    w.extend(stems(&spec.description));
    w
}

fn has_string_parameter(spec: &ToolSpec) -> bool {
    spec.parameters["properties"]
        .as_object()
        .is_some_and(|props| props.values().any(|p| p["type"] == "string"))
}

fn string_words(v: &Value, out: &mut Vec<String>) {
    match v {
        Value::String(s) => out.extend(stems(s)),
        Value::Array(a) => a.iter().for_each(|x| string_words(x, out)),
        Value::Object(o) => o.values().for_each(|x| string_words(x, out)),
        _ => {}
    }
}

/// The operator's request, as words.
pub struct Intent {
    words: BTreeSet<String>,
}

impl Intent {
    pub fn new(query: &str) -> Intent {
        Intent {
            words: stems(query).into_iter().collect(),
        }
    }

    /// Whether the request uses one of the actuating tool's own words (those no observing
    /// tool uses, `observing` being their vocabulary).
    pub fn names_tool(&self, spec: &ToolSpec, observing: &BTreeSet<String>) -> bool {
        spec_words(spec)
            .iter()
            .any(|w| !observing.contains(w) && self.words.contains(w))
    }

    /// Whether some call of `spec` could be asked for by this request.
    pub fn may_ask_for(&self, spec: &ToolSpec, observing: &BTreeSet<String>) -> bool {
        self.names_tool(spec, observing) || has_string_parameter(spec)
    }

    /// Whether this call of an actuating tool is what the request points at.
    pub fn asks_for(&self, call: &ToolCall, spec: &ToolSpec, observing: &BTreeSet<String>) -> bool {
        if self.names_tool(spec, observing) {
            return true;
        }
        let mut words = Vec::new();
        string_words(&call.arguments, &mut words);
        words.iter().any(|w| self.words.contains(w))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn spec(name: &str, desc: &str, props: Value) -> ToolSpec {
        ToolSpec::new(name, desc, json!({"type": "object", "properties": props})).unwrap()
    }

    fn tools() -> (Vec<ToolSpec>, Vec<ToolSpec>) {
        let observing = vec![
            spec(
                "turtle_pose",
                "Where the turtle is: its pose (x, y, heading).",
                json!({}),
            ),
            spec(
                "ros_service_list",
                "List the ROS services with their types.",
                json!({}),
            ),
        ];
        let actuating = vec![
            spec(
                "turtle_move",
                "Drive the turtle straight forward (or backward) a distance in meters. Moves the robot.",
                json!({"distance": {"type": "number"}}),
            ),
            spec(
                "ros_service_call",
                "Call a ROS service with a request.",
                json!({"service": {"type": "string"}, "request": {"type": "object"}}),
            ),
        ];
        (observing, actuating)
    }

    #[test]
    fn a_question_about_the_robot_asks_for_no_motion() {
        let (obs, act) = tools();
        let vocab = vocabulary(&obs);
        let q = Intent::new("where is the turtle?");
        // "turtle" is an observing tool's word too: it names the robot, not an act.
        assert!(!q.names_tool(&act[0], &vocab));
        assert!(!q.may_ask_for(&act[0], &vocab));
        let call = ToolCall {
            name: "turtle_move".into(),
            arguments: json!({"distance": 1.0}),
        };
        assert!(!q.asks_for(&call, &act[0], &vocab));
    }

    #[test]
    fn the_tools_own_words_or_its_target_ask_for_it() {
        let (obs, act) = tools();
        let vocab = vocabulary(&obs);
        let drive = Intent::new("drive forward 2 meters");
        assert!(drive.names_tool(&act[0], &vocab));
        let moving = Intent::new("move the turtle back");
        assert!(
            moving.names_tool(&act[0], &vocab),
            "stems meet: move / moves"
        );
        // A service call is pointed at by the service it names.
        let spawn = Intent::new("spawn a new turtle at x 2 y 3");
        assert!(spawn.may_ask_for(&act[1], &vocab));
        let call = |service: &str| ToolCall {
            name: "ros_service_call".into(),
            arguments: json!({"service": service, "request": {"x": 2.0}}),
        };
        assert!(spawn.asks_for(&call("/spawn"), &act[1], &vocab));
        assert!(!spawn.asks_for(&call("/kill"), &act[1], &vocab));
        assert!(!Intent::new("what services are there?").asks_for(
            &call("/reset"),
            &act[1],
            &vocab
        ));
    }
}
