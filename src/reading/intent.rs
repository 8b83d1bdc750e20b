//! Actuation the operator asked for. A small model that has run one tool tends to call
//! the next one it was shown, and with an operator who approves everything (`--yes`) that
//! moves the robot unasked ("where does the turtle stand?" → pose, then move, rotate,
//! teleport).
//! So an actuating call runs only when the request asks for it (`concepts`: in a clause
//! that neither forbids it, "don't move", nor only asks about it, "is it moving?"):
//!
//! - a tool whose name names an act (`turtle_move`, `turtle_reset`) when the request asks
//!   for that act;
//! - a generic tool (a service call, a publish, a goal, a parameter) when the request
//!   asks for what its target names (`/spawn` for "spawn a turtle", `/turtle1/cmd_vel`
//!   for "drive forward") or names the target itself; the generic verb alone ("call",
//!   "run") unlocks nothing;
//! - a tool whose name names no act the lexicon knows (a robot's own `eels_raise_head`)
//!   when the request uses one of its own name words that no observing tool uses.
//!
//! Tools the request cannot ask for leave the grammar before the model writes; the rest
//! are checked once the call is made. Stopping (`robot_stop`) is never gated.

use std::collections::BTreeSet;

use serde_json::Value;

use super::concepts::{acts_of, asked_acts, clauses, with_name_words, Act, Clause, Mood};
use crate::lexicon::folded_words;
use crate::tool::{ToolCall, ToolSpec};

/// The words of tool names and descriptions: `tools` are the observing ones.
pub fn vocabulary<'a>(tools: impl IntoIterator<Item = &'a ToolSpec>) -> BTreeSet<String> {
    tools
        .into_iter()
        .flat_map(|s| name_words(&s.name))
        .collect()
}

/// The folded words of a tool's name (`turtle_move`: turtle, move).
pub(crate) fn name_words(name: &str) -> Vec<String> {
    folded_words(&name.replace(['_', '.'], " "))
}

/// String arguments that name what a generic tool acts on: a ROS thing, or a place.
pub(crate) const TARGET_KEYS: &[&str] = &[
    "service", "topic", "action", "node", "name", "goal_id", "place",
];

/// A tool that acts on a thing its arguments name (a service call, a publish, a drive
/// to a place). Not one whose name says it deletes (`place_forget`): naming what it
/// deletes is not asking to delete it, the act must be asked for.
pub(crate) fn is_generic(spec: &ToolSpec) -> bool {
    !acts_of(&name_words(&spec.name)).contains(&Act::Forget)
        && spec.parameters["properties"].as_object().is_some_and(|p| {
            TARGET_KEYS
                .iter()
                .any(|k| p.get(*k).is_some_and(|v| v["type"] == "string"))
        })
}

/// Whether every target `call` names in words (no ROS name) is one of `known`, compared
/// folded.
pub(crate) fn targets_known(call: &ToolCall, known: &[String]) -> bool {
    let known: Vec<Vec<String>> = known.iter().map(|k| folded_words(k)).collect();
    TARGET_KEYS
        .iter()
        .filter_map(|k| call.arguments.get(*k).and_then(Value::as_str))
        .filter(|t| !t.contains(['/', '_']))
        .all(|t| known.contains(&folded_words(t)))
}

fn target_words(call: &ToolCall) -> Vec<String> {
    TARGET_KEYS
        .iter()
        .filter_map(|k| call.arguments.get(*k).and_then(Value::as_str))
        .flat_map(|t| folded_words(&t.replace(['_', '/'], " ")))
        .collect()
}

/// Whether `text` writes one of `call`'s targets whole: its words side by side, in its
/// order (`background_b` in "read background_b", `/gripper/close` in "is the gripper
/// close to the part"), whatever the clause's mood. A node counts only for a call on
/// nothing else: a parameter's node is where the setting lives, not the setting.
pub(crate) fn names_target(text: &str, call: &ToolCall) -> bool {
    let said = folded_words(&text.replace(['_', '/'], " "));
    let words_of = |k: &&str| {
        let t = call.arguments.get(*k)?.as_str()?;
        Some(folded_words(&t.replace(['_', '/'], " "))).filter(|w| !w.is_empty())
    };
    let own: Vec<Vec<String>> = TARGET_KEYS
        .iter()
        .filter(|k| **k != "node")
        .filter_map(words_of)
        .collect();
    let named = if own.is_empty() {
        TARGET_KEYS.iter().filter_map(words_of).collect()
    } else {
        own
    };
    named
        .iter()
        .any(|t| said.windows(t.len()).any(|w| w == t.as_slice()))
}

/// Whether `text` writes a name of its own (a word with `_` or `/`: `fan_speed`).
pub(crate) fn writes_name(text: &str) -> bool {
    text.split_whitespace().any(|w| w.contains(['_', '/']))
}

/// The operator's request, read for actuation.
pub(crate) struct Intent {
    clauses: Vec<Clause>,
    asked: Vec<Act>,
    /// The numbers the request writes in clauses that ask for something.
    numbers: Vec<f64>,
}

impl Intent {
    pub fn new(query: &str) -> Intent {
        let clauses = clauses(query);
        let numbers = clauses
            .iter()
            .filter(|c| c.mood == Mood::Asked)
            .flat_map(|c| c.words.iter())
            .filter_map(|w| w.parse::<f64>().ok())
            .collect();
        Intent {
            asked: asked_acts(&clauses),
            clauses,
            numbers,
        }
    }

    /// Words of the clauses that ask for something.
    fn asking_words(&self) -> impl Iterator<Item = &String> {
        self.clauses
            .iter()
            .filter(|c| c.mood == Mood::Asked)
            .flat_map(|c| c.words.iter())
    }

    /// Whether a clause that asks for something says `name`'s words, side by side.
    pub(crate) fn says_name(&self, name: &str) -> bool {
        let name = folded_words(name);
        !name.is_empty()
            && self
                .clauses
                .iter()
                .filter(|c| c.mood == Mood::Asked)
                .any(|c| c.words.windows(name.len()).any(|w| w == name.as_slice()))
    }

    /// Whether a clause that asks for something writes a number.
    pub(crate) fn says_numbers(&self) -> bool {
        !self.numbers.is_empty()
    }

    /// Whether a clause that asks for something writes the number `n`.
    pub(crate) fn says_number(&self, n: f64) -> bool {
        self.numbers.iter().any(|m| (m - n).abs() < 1e-9)
    }

    /// Whether the request uses one of `words` in a clause that asks for something.
    pub(crate) fn says(&self, words: &[String]) -> bool {
        // A word in another language says the English word of names it says
        // ("cierra": `close`).
        let said = with_name_words(self.asking_words());
        words.iter().any(|w| {
            w.len() > 2
                && said
                    .iter()
                    .any(|s| s == w || (w.len() > 4 && s.starts_with(w.as_str())))
        })
    }

    /// Whether this part asks for `call`'s own act, or its target's, pointing back
    /// (`concepts::refers_back`) without saying any word of what the call acts on: a
    /// later part that refers back ("change it to 20" after the part that read the
    /// setting) may take its target from the part before (`names_target`).
    pub(crate) fn acts_on_unnamed(&self, call: &ToolCall, spec: &ToolSpec) -> bool {
        let target = target_words(call);
        let refers = self
            .asking_words()
            .any(|w| crate::reading::concepts::refers_back(w));
        if !refers || target.is_empty() || self.says(&target) {
            return false;
        }
        let mut acts = acts_of(&name_words(&spec.name));
        acts.extend(acts_of(&target));
        acts.iter().any(|a| self.asked.contains(a))
    }

    /// A tool that changes a setting (`ros_param_set`: its own name's act is `Set`) is
    /// asked for by a request to change something, or one that writes the number the
    /// call sets ("make the gripper force 20"), not by one that names the
    /// setting: "read the background blue value" asks for nothing to change. `own`: the
    /// acts the tool's name names; `call`: the call, once written (before, any number
    /// the request writes may be the one).
    fn asks_own_setting(&self, own: &[Act], call: Option<&ToolCall>) -> bool {
        if !own.contains(&Act::Set) || self.asked.contains(&Act::Set) {
            return true;
        }
        match call {
            None => !self.numbers.is_empty(),
            Some(c) => c
                .arguments
                .get("value")
                .and_then(Value::as_f64)
                .is_some_and(|v| self.numbers.iter().any(|n| (n - v).abs() < 1e-9)),
        }
    }

    /// Whether some call of `spec` could be asked for by this request (tools that
    /// cannot leave the grammar).
    pub(crate) fn may_ask_for(&self, spec: &ToolSpec, observing: &BTreeSet<String>) -> bool {
        let own = name_words(&spec.name);
        let acts = acts_of(&own);
        if is_generic(spec) {
            if !self.asks_own_setting(&acts, None) {
                return false;
            }
            return !self.asked.is_empty() || self.asking_words().any(|w| w.len() > 3);
        }
        if acts.is_empty() {
            let own: Vec<String> = own.into_iter().filter(|w| !observing.contains(w)).collect();
            return self.says(&own);
        }
        acts.iter().any(|a| self.asked.contains(a))
    }

    /// Whether this call of an actuating tool is what the request asks for.
    #[cfg(test)]
    pub(crate) fn asks_for(
        &self,
        call: &ToolCall,
        spec: &ToolSpec,
        observing: &BTreeSet<String>,
    ) -> bool {
        self.asks_for_known(call, spec, observing, &[])
    }

    /// `asks_for`, knowing the names the tool's targets take (`known`: a place's names,
    /// from its live schema). A target said in words that is none of them ("a cake" in
    /// "bake me a cake") is a name the robot lacks, not one that points at the
    /// tool: the request must ask for the tool's own act ("go to the greenhouse").
    pub(crate) fn asks_for_known(
        &self,
        call: &ToolCall,
        spec: &ToolSpec,
        observing: &BTreeSet<String>,
        known: &[String],
    ) -> bool {
        if !is_generic(spec) {
            // A tool that names its act (forgetting a place) and takes one of the
            // robot's names is never asked for about a name the robot lacks.
            return self.may_ask_for(spec, observing)
                && (known.is_empty() || targets_known(call, known));
        }
        if !self.asks_own_setting(&acts_of(&name_words(&spec.name)), Some(call)) {
            return false;
        }
        let target = target_words(call);
        let target_acts = acts_of(&target);
        if target_acts.iter().any(|a| self.asked.contains(a)) {
            return true;
        }
        // A request that asks for acts, none of them this tool's own or its target's,
        // asks another tool to act on what it names: "forget the dock" does not ask to
        // drive there. A motion is the exception: a generic tool moves the robot through
        // the target it names ("drive the joints to …" publishes on a joint command), so
        // a motion asked of a target the words name is asked of it (below).
        let own = acts_of(&name_words(&spec.name));
        let asks_own = own.iter().any(|a| self.asked.contains(a));
        let motion = self
            .asked
            .iter()
            .all(|a| matches!(a, Act::Move | Act::Turn));
        if !self.asked.is_empty() && !asks_own && !motion {
            return false;
        }
        if !known.is_empty() && !targets_known(call, known) {
            return asks_own;
        }
        self.says(
            &target
                .into_iter()
                .filter(|w| !observing.contains(w))
                .collect::<Vec<_>>(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn spec(name: &str, props: Value) -> ToolSpec {
        ToolSpec::new(name, "", json!({"type": "object", "properties": props})).unwrap()
    }

    fn tools() -> (BTreeSet<String>, Vec<ToolSpec>) {
        let observing = [
            spec("turtle_pose", json!({})),
            spec("ros_service_list", json!({})),
            spec("ros_topic_echo", json!({"topic": {"type": "string"}})),
        ];
        let actuating = vec![
            spec("turtle_move", json!({"distance": {"type": "number"}})),
            spec("turtle_rotate", json!({"degrees": {"type": "number"}})),
            spec(
                "ros_service_call",
                json!({"service": {"type": "string"}, "request": {"type": "object"}}),
            ),
            spec("eels_raise_head", json!({"angle": {"type": "number"}})),
        ];
        (vocabulary(&observing), actuating)
    }

    fn call(name: &str, args: Value) -> ToolCall {
        ToolCall {
            name: name.into(),
            arguments: args,
        }
    }

    #[test]
    fn the_request_must_ask_for_the_act() {
        let (obs, act) = tools();
        let asks = |q: &str, i: usize, args: Value| {
            Intent::new(q).asks_for(&call(&act[i].name, args), &act[i], &obs)
        };
        assert!(asks("move forward 4 meters", 0, json!({})));
        assert!(!asks("where can I find the turtle?", 0, json!({})));
        assert!(!asks("don't move the turtle", 0, json!({})));
        assert!(!asks("how much battery is left?", 1, json!({})));
        assert!(!asks("stop the turtle now", 0, json!({})));
        assert!(asks(
            "Bewege die Schildkröte drei Meter geradeaus",
            0,
            json!({})
        ));
        assert!(asks("gira 90 grados a la izquierda", 1, json!({})));
    }

    #[test]
    fn a_generic_call_is_asked_for_by_its_target() {
        let (obs, act) = tools();
        let svc = |q: &str, s: &str| {
            Intent::new(q).asks_for(
                &call("ros_service_call", json!({"service": s})),
                &act[2],
                &obs,
            )
        };
        assert!(svc("spawn another turtle at x 4 y 1", "/spawn"));
        assert!(!svc("spawn another turtle at x 4 y 1", "/kill"));
        assert!(svc("call the reset service", "/reset"));
        assert!(!svc("call the reset service", "/kill"));
        assert!(!svc("list the running nodes", "/reset"));
        assert!(!svc("what services are there?", "/reset"));
        // Naming the target while asking for another act asks another tool.
        let go = spec("place_go", json!({"place": {"type": "string"}}));
        let drive = |q: &str| {
            Intent::new(q).asks_for(&call("place_go", json!({"place": "shed"})), &go, &obs)
        };
        assert!(drive("head over to the shed"));
        assert!(drive("drive to the shed"));
        assert!(!drive("forget the shed"));
        assert!(!drive("where is the shed?"));
        // A name the robot lacks points at nothing: only the tool's own act asks for it.
        let known = ["dock".to_string(), "pond".to_string()];
        let to = |q: &str, place: &str| {
            let c = call("place_go", json!({ "place": place }));
            Intent::new(q).asks_for_known(&c, &go, &obs, &known)
        };
        assert!(to("head over to the pond", "pond"));
        assert!(!to("bake me a cake", "a cake"));
        assert!(to("drive to the greenhouse", "the greenhouse"));
        assert!(!to("take me to the greenhouse", "the greenhouse"));
        let forget = spec("place_forget", json!({"name": {"type": "string"}}));
        let drop = |q: &str, name: &str| {
            let c = call("place_forget", json!({ "name": name }));
            Intent::new(q).asks_for_known(&c, &forget, &obs, &known)
        };
        assert!(drop("forget the pond", "pond"));
        assert!(!drop("delete the greenhouse", "greenhouse"));
        assert!(!drop("go to the pond", "pond"));
        assert!(Intent::new("please forget the loading area").says_name("Loading Area"));
        assert!(!Intent::new("where is the loading area?").says_name("loading area"));
        assert!(!svc("don't reset anything", "/reset"));
        // A robot's own tool: its own words ask for it.
        let raise =
            |q: &str| Intent::new(q).asks_for(&call("eels_raise_head", json!({})), &act[3], &obs);
        // A setting changes when the request asks for a change, not when it names it.
        let param = spec(
            "ros_param_set",
            json!({"node": {"type": "string"}, "name": {"type": "string"}, "value": {}}),
        );
        let set = |q: &str| {
            Intent::new(q).asks_for(
                &call(
                    "ros_param_set",
                    json!({"node": "/sim", "name": "max_speed", "value": 2}),
                ),
                &param,
                &obs,
            )
        };
        assert!(set("change max_speed to 2"));
        assert!(set("make max_speed 2"));
        assert!(!set("make max_speed 3"));
        assert!(set("ajusta la velocidad max_speed a 2"));
        assert!(!set("read the max speed"));
        assert!(!set("what is max_speed?"));
        assert!(!Intent::new("show me the max speed setting").may_ask_for(&param, &obs));
        assert!(raise("raise the head by 10 degrees"));
        assert!(!raise("what is the head angle?"));
    }
}
