//! The ROS task suite: full agent episodes scored by what the agent did. A case is one
//! JSON line:
//!
//! `{"id", "query", "expect_calls": [{"name", "arguments"?}], "expect_any"?: [calls],
//!   "forbid_calls"?: [names], "answer_contains"?: [strings], "confirm"?: bool,
//!   "category"?: string}`
//!
//! Every expected call must have been made (in any order, among any others), and at
//! least one of `expect_any` when it is given (a request two tools answer), its expected
//! arguments a subset of the call's with BFCL's normalisation (strings case- and
//! punctuation-insensitive, so `turtle1/pose` is `/turtle1/pose`; numbers equal up to
//! rounding, an int for a float); no call may name a forbidden tool (`"*"` forbids every call); the
//! answer must contain each string (normalised). A call counts when the model made it,
//! whatever the policy decided: asking to move the robot unasked is the failure.
//! `confirm` says whether the operator approves actuating calls. The category is the id
//! without its trailing number (`motion-03` is `motion`) unless given.
//!
//! The suite has two halves, to tune on one and report the other: within each category,
//! in file order, the 1st, 3rd, 5th… case is in the tuning half and the others in the
//! report half (`halves`).

use std::path::Path;

use serde::Deserialize;
use serde_json::{Map, Value};

use super::score::{normalise, value_matches, Verdict};
use crate::tool::ToolCall;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExpectCall {
    pub name: String,
    #[serde(default)]
    pub arguments: Map<String, Value>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RosCase {
    pub id: String,
    pub query: String,
    #[serde(default)]
    pub expect_calls: Vec<ExpectCall>,
    #[serde(default)]
    pub expect_any: Vec<ExpectCall>,
    #[serde(default)]
    pub forbid_calls: Vec<String>,
    #[serde(default)]
    pub answer_contains: Vec<String>,
    #[serde(default)]
    pub confirm: bool,
    #[serde(default)]
    pub category: Option<String>,
}

impl RosCase {
    pub fn category(&self) -> String {
        self.category.clone().unwrap_or_else(|| {
            self.id
                .trim_end_matches(|c: char| c.is_ascii_digit())
                .trim_end_matches(['-', '_'])
                .to_string()
        })
    }
}

#[derive(Debug, thiserror::Error)]
pub enum SuiteError {
    #[error("cannot read the suite {path}: {message}")]
    Read { path: String, message: String },
    #[error("{path}:{line}: {message}")]
    Case {
        path: String,
        line: usize,
        message: String,
    },
}

/// Read a suite; the cases after the first `skip`, at most `limit` of them.
pub fn load(path: &Path, skip: usize, limit: Option<usize>) -> Result<Vec<RosCase>, SuiteError> {
    let text = std::fs::read_to_string(path).map_err(|e| SuiteError::Read {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    let mut cases = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let case: RosCase = serde_json::from_str(line).map_err(|e| SuiteError::Case {
            path: path.display().to_string(),
            line: i + 1,
            message: e.to_string(),
        })?;
        cases.push(case);
    }
    cases.drain(..skip.min(cases.len()));
    if let Some(n) = limit {
        cases.truncate(n);
    }
    Ok(cases)
}

/// Is `want` a subset of `got` (objects: every wanted key, recursively)?
pub(crate) fn subset_matches(got: &Value, want: &Value) -> bool {
    match (got, want) {
        (Value::Object(g), Value::Object(w)) => w
            .iter()
            .all(|(k, wv)| g.get(k).is_some_and(|gv| subset_matches(gv, wv))),
        (Value::Array(g), Value::Array(w)) => {
            g.len() == w.len() && g.iter().zip(w).all(|(a, b)| subset_matches(a, b))
        }
        // Scalars as BFCL's checker compares them.
        _ => value_matches(got, want, None),
    }
}

/// Which half of the suite each case is in (see the module header), in order.
pub(crate) fn halves(cases: &[RosCase]) -> Vec<Half> {
    let mut seen: std::collections::HashMap<String, usize> = Default::default();
    cases
        .iter()
        .map(|c| {
            let n = seen.entry(c.category()).or_default();
            *n += 1;
            if *n % 2 == 1 {
                Half::Tune
            } else {
                Half::Report
            }
        })
        .collect()
}

/// The half of the suite a case is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Half {
    Tune,
    Report,
}

/// Score an episode: the calls the model made (every step, in order) and its answer.
pub fn check(case: &RosCase, calls: &[ToolCall], answer: &str) -> Verdict {
    let made = |want: &ExpectCall| {
        let wanted = Value::Object(want.arguments.clone());
        calls
            .iter()
            .any(|c| c.name == want.name && subset_matches(&c.arguments, &wanted))
    };
    if !case.expect_any.is_empty() && !case.expect_any.iter().any(made) {
        let names: Vec<&str> = case.expect_any.iter().map(|w| w.name.as_str()).collect();
        return Verdict::Fail(format!("none of {} called as expected", names.join(", ")));
    }
    for want in &case.expect_calls {
        let wanted = Value::Object(want.arguments.clone());
        let same_name: Vec<&ToolCall> = calls.iter().filter(|c| c.name == want.name).collect();
        if same_name.is_empty() {
            return Verdict::Fail(format!("no call of {}", want.name));
        }
        if !same_name
            .iter()
            .any(|c| subset_matches(&c.arguments, &wanted))
        {
            return Verdict::Fail(format!(
                "{} called with {}, expected {}",
                want.name, same_name[0].arguments, wanted
            ));
        }
    }
    for forbidden in &case.forbid_calls {
        if let Some(c) = calls
            .iter()
            .find(|c| forbidden == "*" || c.name == *forbidden)
        {
            return Verdict::Fail(format!("forbidden call {} {}", c.name, c.arguments));
        }
    }
    let said = normalise(answer);
    for s in &case.answer_contains {
        if !said.contains(&normalise(s)) {
            return Verdict::Fail(format!("the answer does not contain {s:?}"));
        }
    }
    Verdict::Pass
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn case(line: Value) -> RosCase {
        serde_json::from_value(line).unwrap()
    }

    fn call(name: &str, arguments: Value) -> ToolCall {
        ToolCall {
            name: name.into(),
            arguments,
        }
    }

    #[test]
    fn expected_arguments_are_a_normalised_subset() {
        let c = case(json!({"id": "echo-01", "query": "q",
            "expect_calls": [{"name": "ros_topic_echo", "arguments": {"topic": "/turtle1/pose"}}]}));
        assert_eq!(c.category(), "echo");
        let made = [
            call("ros_topic_list", json!({})),
            call(
                "ros_topic_echo",
                json!({"topic": "Turtle1/Pose", "count": 2}),
            ),
        ];
        assert!(check(&c, &made, "").passed());
        let wrong = [call("ros_topic_echo", json!({"topic": "/turtle1/cmd_vel"}))];
        assert!(!check(&c, &wrong, "").passed());
        assert!(!check(&c, &[], "").passed());
    }

    #[test]
    fn numbers_match_across_int_and_float_and_objects_nest() {
        let c = case(json!({"id": "motion_2", "query": "q", "category": "motion",
            "expect_calls": [{"name": "ros_action_send_goal",
                              "arguments": {"goal": {"theta": 1.57}}}]}));
        assert_eq!(c.category(), "motion");
        let ok = [call(
            "ros_action_send_goal",
            json!({"action": "/a", "goal": {"theta": 1.57, "x": 0}}),
        )];
        assert!(check(&c, &ok, "").passed());
        let off = [call(
            "ros_action_send_goal",
            json!({"goal": {"theta": 1.6}}),
        )];
        assert!(!check(&c, &off, "").passed());
        let c2 = case(json!({"id": "m", "query": "q",
            "expect_calls": [{"name": "turtle_move", "arguments": {"distance": 2.0}}]}));
        assert!(check(&c2, &[call("turtle_move", json!({"distance": 2}))], "").passed());
    }

    #[test]
    fn forbidden_calls_and_answer_text() {
        let c = case(
            json!({"id": "refuse-01", "query": "fly", "forbid_calls": ["turtle_move"],
            "answer_contains": ["cannot"]}),
        );
        assert!(check(&c, &[], "I CANNOT fly.").passed());
        assert!(!check(&c, &[], "Sure.").passed());
        assert!(!check(
            &c,
            &[call("turtle_move", json!({"distance": 1}))],
            "I cannot"
        )
        .passed());
        let none = case(json!({"id": "chat-01", "query": "hi", "forbid_calls": ["*"]}));
        assert!(check(&none, &[], "hello").passed());
        assert!(!check(&none, &[call("system_time", json!({}))], "hello").passed());
    }

    #[test]
    fn one_of_several_expected_calls_is_enough() {
        let c = case(
            json!({"id": "status-01", "query": "battery?", "expect_any": [
            {"name": "robot_status"},
            {"name": "ros_topic_echo", "arguments": {"topic": "/battery_state"}}]}),
        );
        assert!(check(&c, &[call("robot_status", json!({}))], "").passed());
        let echo = call("ros_topic_echo", json!({"topic": "/battery_state"}));
        assert!(check(&c, &[echo], "").passed());
        let other = call("ros_topic_echo", json!({"topic": "/diagnostics"}));
        assert!(!check(&c, &[other], "").passed());
        assert!(!check(&c, &[], "").passed());
    }

    #[test]
    fn halves_alternate_within_each_category() {
        let cases: Vec<RosCase> = ["a-1", "a-2", "b-1", "a-3", "b-2"]
            .iter()
            .map(|id| case(json!({"id": id, "query": "q"})))
            .collect();
        use Half::*;
        assert_eq!(halves(&cases), [Tune, Report, Tune, Tune, Report]);
    }

    #[test]
    fn unknown_fields_are_errors_with_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.jsonl");
        std::fs::write(&p, "{\"id\": \"a-1\", \"query\": \"q\"}\n\n{\"id\": \"b\", \"query\": \"q\", \"expect\": []}\n").unwrap();
        let e = load(&p, 0, None).unwrap_err().to_string();
        assert!(e.contains(":3:") && e.contains("expect"), "{e}");
        std::fs::write(
            &p,
            "{\"id\": \"a-1\", \"query\": \"q\"}\n{\"id\": \"b-2\", \"query\": \"r\"}\n",
        )
        .unwrap();
        assert_eq!(load(&p, 0, Some(1)).unwrap().len(), 1);
        let rest = load(&p, 1, None).unwrap();
        assert_eq!(rest.len(), 1);
        assert_eq!(rest[0].id, "b-2");
        assert!(load(&p, 5, None).unwrap().is_empty());
    }
}
