//! The robot's names a request asks to act on, read by meaning. `intent` reads an act
//! from words: a request asks for a generic actuator's target when it says the target's
//! own words ("close the gripper" for `/gripper/close`) or an act the lexicon knows. A
//! request in other words or another language ("ferme la pince", "bring the arm home
//! again" for `/arm/go_home`) says neither, and the actuator was never offered.
//!
//! Here the sentence encoder decides, when three things agree:
//! - the request only asks for something: no question, no negation, no request to be
//!   told, no stop, cancel or removal (`concepts`), in Latin letters (the languages
//!   `concepts` reads);
//! - of all the tools, the one its meaning is nearest (`meaning::Meaning::similarities`,
//!   the tools' examples and the robot file's) is a generic actuator (a service call, a
//!   publish, a goal);
//! - of the robot's names of a kind that tool takes, one is nearest
//!   (`meaning::Meaning::name_similarity`: a name read as its words, as the robot prompt
//!   file's examples for it and as what its prose says of it), at `MEANT_NAME_MIN` or
//!   more and `MEANT_GAP` nearer than the next, and the tool's and the name's cosines
//!   together reach `MEANT_MIN`.
//!
//! That name then counts as asked for. The other guards still hold the call: it is
//! confirmed, limited and stopped like any other.

use crate::reading::concepts::{clauses, Act, Mood};

/// Fewest sum of the tool's and the name's cosines for a name to be asked for by
/// meaning (chosen on the tune half of the arm's suite, see `docs/agent.md`).
pub(crate) const MEANT_MIN: f64 = 0.75;

/// Fewest cosine of the nearest name alone. An impossible request is near a tool
/// (a drive to a room is near a service that moves the arm home) and near some name
/// of it ("close the window" is 0.55 from `/gripper/close`); requests for one of the
/// arm's names in the six languages were 0.59 to 1.0 from it, the impossible ones at
/// most 0.55 (sentences of our own, not the suite's: `docs/agent.md`).
const MEANT_NAME_MIN: f64 = 0.6;

/// How much nearer the nearest name must be than the next: the encoder reads opposites
/// as near ("schließ den Greifer" is nearer `/gripper/open` than `/gripper/close`), and
/// two names that near each other mean neither.
const MEANT_GAP: f64 = 0.05;

/// The kinds of names an actuator acts on.
pub(crate) const ACTED_ON: &[&str] = &["topic", "service", "action"];

/// Names every node has, which no operator asks for by meaning: its parameter and type
/// services, and the graph's own topics. `bound` holds no service argument to one the
/// request does not write.
const EVERY_NODE: &[&str] = &[
    "list_parameters",
    "get_parameters",
    "set_parameters",
    "set_parameters_atomically",
    "describe_parameters",
    "get_parameter_types",
    "get_type_description",
    "rosout",
    "parameter_events",
];

/// The tool a request is nearest by meaning, when it is a generic actuator: its cosine
/// with the request and the kinds of names it takes.
pub(crate) struct Nearest<'a> {
    pub similarity: f64,
    pub kinds: Vec<&'a str>,
}

/// The name of `names` ((kind, name) pairs) that `part` asks to act on, by meaning
/// (`near`: a name's cosine with the part): the nearest, when it is near enough on its
/// own and clearly nearer than the next. None when the part asks
/// about something, forbids something or asks to be told, or when the tool it is
/// nearest (`tool`) is no generic actuator (`None`).
pub(crate) fn meant(
    part: &str,
    names: &[(String, String)],
    near: &dyn Fn(&str) -> f64,
    tool: Option<Nearest>,
) -> Vec<String> {
    let read = clauses(part);
    let Some(tool) = tool else {
        return Vec::new();
    };
    // The mood is read in the six languages `concepts` knows, all written in Latin
    // letters; the encoder reads more, whose negations and questions would pass unseen.
    let latin = part
        .chars()
        .filter(|c| c.is_alphabetic())
        .all(|c| c < '\u{0250}');
    let asks_only = read.iter().all(|c| {
        c.mood == Mood::Asked
            && !c.acts.iter().any(|a| {
                matches!(
                    a,
                    Act::Stop | Act::Cancel | Act::Forget | Act::Kill | Act::Fence
                )
            })
    });
    if !latin || read.is_empty() || !asks_only || part.contains(['\u{ff1f}', '\u{00bf}']) {
        return Vec::new();
    }
    let mut sims: Vec<(f64, &str)> = names
        .iter()
        .filter(|(kind, name)| {
            ACTED_ON.contains(&kind.as_str())
                && tool.kinds.contains(&kind.as_str())
                && !every_node(name)
        })
        .map(|(_, name)| (near(name), name.as_str()))
        .collect();
    sims.sort_by(|a, b| b.0.total_cmp(&a.0));
    sims.dedup_by(|a, b| a.1 == b.1);
    tracing::debug!(target: "ferrosa::select", part, tool = tool.similarity, nearest = ?&sims[..sims.len().min(3)], "names by meaning");
    let Some(&(top, name)) = sims.first() else {
        return Vec::new();
    };
    let next = sims.get(1).map_or(f64::NEG_INFINITY, |s| s.0);
    if tool.similarity + top < MEANT_MIN || top < MEANT_NAME_MIN || top - next < MEANT_GAP {
        return Vec::new();
    }
    vec![name.to_string()]
}

/// Whether a parameter is one every ROS 2 node declares of itself (the clock it runs
/// on, its publishers' QoS overrides, its type-description service), not a setting of
/// the robot's: tool choice does not read it as one of the robot's names.
pub(crate) fn every_node_parameter(name: &str) -> bool {
    matches!(name, "use_sim_time" | "start_type_description_service")
        || name.starts_with("qos_overrides.")
}

/// Whether `name` is one of the names every node has (`EVERY_NODE`), by its last part.
pub(crate) fn every_node(name: &str) -> bool {
    let last = name.rsplit('/').next().unwrap_or(name);
    EVERY_NODE.contains(&last)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_nodes_own_parameters_are_told_from_the_robots() {
        assert!(every_node_parameter("use_sim_time"));
        assert!(every_node_parameter(
            "qos_overrides./rosout.publisher.depth"
        ));
        assert!(!every_node_parameter("grip_force"));
    }

    fn names() -> Vec<(String, String)> {
        [
            ("service", "/hatch/open"),
            ("service", "/hatch/shut"),
            ("service", "/probe/set_parameters"),
            ("topic", "/hatch/state"),
            ("node", "/hatch"),
        ]
        .iter()
        .map(|(k, n)| (k.to_string(), n.to_string()))
        .collect()
    }

    /// A stand-in for the encoder: how many of the name's words the request writes.
    fn near(part: &'static str) -> impl Fn(&str) -> f64 {
        move |name: &str| {
            let said = crate::lexicon::folded_words(part);
            let words = crate::lexicon::name_words(name);
            let hits = words.iter().filter(|w| said.contains(w)).count();
            hits as f64 / words.len().max(1) as f64
        }
    }

    fn caller(similarity: f64) -> Option<Nearest<'static>> {
        Some(Nearest {
            similarity,
            kinds: vec!["service"],
        })
    }

    #[test]
    fn the_nearest_name_an_actuator_takes_is_meant_when_the_request_only_asks() {
        let q = "shut the hatch now";
        assert_eq!(meant(q, &names(), &near(q), caller(0.5)), ["/hatch/shut"]);
        // Two names about as near: neither.
        let q = "the hatch, open it or shut it";
        assert!(meant(q, &names(), &near(q), caller(0.5)).is_empty());
        // Near a tool, but no name near enough on its own.
        let q = "shut the valve now";
        assert!(meant(q, &names(), &near(q), caller(0.9)).is_empty());
        // Nodes, every node's services and names too far are never meant.
        let q = "probe set parameters";
        assert!(meant(q, &names(), &near(q), caller(0.5)).is_empty());
        let q = "bake a cake";
        assert!(meant(q, &names(), &near(q), caller(0.7)).is_empty());
        // Near a name, but nearest no actuator, or one too far: nothing.
        let q = "shut the hatch now";
        assert!(meant(q, &names(), &near(q), None).is_empty());
        assert!(meant(q, &names(), &near(q), caller(-0.3)).is_empty());
        // Only names of the kinds the tool takes.
        let topics = Some(Nearest {
            similarity: 0.5,
            kinds: vec!["topic"],
        });
        assert_eq!(
            meant(
                "hatch state now",
                &names(),
                &near("hatch state now"),
                topics
            ),
            ["/hatch/state"]
        );
    }

    #[test]
    fn a_question_a_negation_or_a_request_to_be_told_means_no_act() {
        for q in [
            "is the hatch shut?",
            "do not shut the hatch",
            "tell me whether the hatch is shut",
            "stop the hatch and shut it",
            "闸门关了吗？",
        ] {
            assert!(meant(q, &names(), &near(q), caller(0.9)).is_empty(), "{q}");
        }
    }
}
