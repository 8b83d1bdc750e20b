//! Things done in the order the operator says them: a call that lists places (or any
//! tool's `ToolSpec::sequence`) is put in the order its items come in the request, and
//! an item the call repeats more often than the request names it is dropped.
//!
//! A small model copies the right names into a route but not always in the right order
//! ("A, then B" written as B, A), and fills a list with a name it already wrote. The
//! names are the operator's own words (the copy bias leans values towards spans of the
//! request), so where each one stands in the request says where it goes, in any
//! language. The rule holds only when every item is found in the request (as words,
//! without case or accents): a call naming something the request does not (an alias
//! the model chose, a translation) is left as it is. An order said with words against
//! the order of the names ("the pond, but the dock first") is not read.
//!
//! Cost: per call of a tool with a sequence, its items looked up in the request's
//! words; nothing for other tools.

use serde_json::Value;

use super::guard::{Guard, Verdict};
use crate::lexicon::folded_words;
use crate::tool::{ToolCall, ToolSpec};

pub(crate) struct SaidOrder {
    /// The request's words, folded.
    said: Vec<String>,
}

impl SaidOrder {
    pub fn new(query: &str) -> SaidOrder {
        SaidOrder {
            said: folded_words(query),
        }
    }

    /// `items` in the request's order, with repeats it does not make dropped; `None`
    /// when an item is not in the request.
    ///
    /// Each item takes a mention of its own, whole: longer names first, so "dock" is not
    /// read inside "north dock" when both are named.
    fn ordered(&self, items: &[String]) -> Option<Vec<String>> {
        let words: Vec<Vec<String>> = items.iter().map(|i| folded_words(i)).collect();
        if words.iter().any(|w| w.is_empty()) {
            return None;
        }
        let mut by_length: Vec<usize> = (0..items.len()).collect();
        by_length.sort_by_key(|&i| std::cmp::Reverse(words[i].len()));
        let mut used = vec![false; self.said.len()];
        let mut placed: Vec<(usize, usize)> = Vec::new();
        for i in by_length {
            let n = words[i].len();
            let starts: Vec<usize> = self
                .said
                .windows(n)
                .enumerate()
                .filter(|(_, w)| *w == words[i].as_slice())
                .map(|(at, _)| at)
                .collect();
            if starts.is_empty() {
                return None;
            }
            // The first mention not taken yet; none left: a repeat nobody said.
            if let Some(&at) = starts.iter().find(|&&at| !used[at..at + n].contains(&true)) {
                used[at..at + n].iter_mut().for_each(|u| *u = true);
                placed.push((at, i));
            }
        }
        placed.sort_by_key(|&(at, i)| (at, i));
        Some(placed.into_iter().map(|(_, i)| items[i].clone()).collect())
    }

    /// Put `call`'s sequence in the request's order; whether it changed.
    fn reorder(&self, call: &mut ToolCall, sequence: &[String]) -> bool {
        let Some(args) = call.arguments.as_object_mut() else {
            return false;
        };
        let mut items = Vec::new();
        for (i, name) in sequence.iter().enumerate() {
            match args.get(name) {
                Some(Value::String(s)) => items.push(s.clone()),
                Some(Value::Array(list)) if i + 1 == sequence.len() => {
                    for v in list {
                        let Value::String(s) = v else { return false };
                        items.push(s.clone());
                    }
                }
                None => {}
                Some(_) => return false,
            }
        }
        let Some(ordered) = self.ordered(&items) else {
            return false;
        };
        if ordered == items {
            return false;
        }
        // The new values first, written only when every argument has one.
        let mut next = ordered.into_iter();
        let mut new = Vec::new();
        for (i, name) in sequence.iter().enumerate() {
            match args.get(name) {
                Some(Value::String(_)) => {
                    // Fewer items come back only by dropping repeats; a string argument
                    // left without one leaves the call as it was.
                    let Some(item) = next.next() else {
                        return false;
                    };
                    new.push((name.clone(), Value::String(item)));
                }
                Some(Value::Array(_)) if i + 1 == sequence.len() => {
                    let rest: Vec<Value> = next.by_ref().map(Value::String).collect();
                    new.push((name.clone(), Value::Array(rest)));
                }
                _ => {}
            }
        }
        for (name, value) in new {
            args.insert(name, value);
        }
        true
    }
}

impl Guard for SaidOrder {
    fn name(&self) -> &'static str {
        "said-order"
    }

    /// A request of several parts (`plan`): each part's route is held to its own words.
    fn next_part(&mut self, part: &str) {
        self.said = folded_words(part);
    }

    fn check(&mut self, calls: &mut [ToolCall], offered: &[ToolSpec]) -> Vec<Verdict> {
        for c in calls.iter_mut() {
            let Some(spec) = offered.iter().find(|s| s.name == c.name) else {
                continue;
            };
            if spec.sequence.is_empty() {
                continue;
            }
            let before = c.arguments.clone();
            if self.reorder(c, &spec.sequence) {
                tracing::debug!(tool = %c.name, %before, after = %c.arguments, "put in the order said");
            }
        }
        vec![Verdict::Pass; calls.len()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// A tool that visits rooms in order: `room`, then `then`.
    fn spec() -> ToolSpec {
        let mut spec = ToolSpec::new(
            "visit",
            "Visit rooms in order.",
            json!({"type": "object", "properties": {
                "room": {"type": "string"},
                "then": {"type": "array", "items": {"type": "string"}},
                "slowly": {"type": "boolean"}}}),
        )
        .unwrap();
        spec.sequence = vec!["room".into(), "then".into()];
        spec
    }

    /// `args` for the visit tool as `guard` settles them.
    fn settled_by(guard: &mut SaidOrder, args: Value) -> Value {
        let mut calls = [ToolCall {
            name: "visit".into(),
            arguments: args,
        }];
        guard.check(&mut calls, &[spec()]);
        calls[0].arguments.clone()
    }

    fn settled(query: &str, args: Value) -> Value {
        settled_by(&mut SaidOrder::new(query), args)
    }

    #[test]
    fn a_sequence_follows_the_order_the_request_names_it_in() {
        assert_eq!(
            settled(
                "check the boiler room, after that the Küche",
                json!({"room": "kuche", "then": ["boiler room"], "slowly": true})
            ),
            json!({"room": "boiler room", "then": ["kuche"], "slowly": true})
        );
        // Already in order: untouched.
        let kept = json!({"room": "attic", "then": ["cellar", "garage"]});
        assert_eq!(
            settled("attic first, cellar next, garage last", kept.clone()),
            kept
        );
    }

    #[test]
    fn repeats_the_request_does_not_make_are_dropped_and_those_it_makes_kept() {
        assert_eq!(
            settled(
                "stop by the lab and the garage",
                json!({"room": "garage", "then": ["lab", "garage"]})
            ),
            json!({"room": "lab", "then": ["garage"]})
        );
        let twice = json!({"room": "lab", "then": ["garage", "lab"]});
        assert_eq!(
            settled("lab, garage, then the lab again", twice.clone()),
            twice
        );
    }

    #[test]
    fn a_name_inside_a_longer_one_takes_a_mention_of_its_own() {
        let right = json!({"room": "north hall", "then": ["lab", "hall"]});
        assert_eq!(
            settled("the north hall, then the lab, then the hall", right.clone()),
            right
        );
        assert_eq!(
            settled(
                "the boiler room first, then the boiler",
                json!({"room": "boiler", "then": ["boiler room"]})
            ),
            json!({"room": "boiler room", "then": ["boiler"]})
        );
    }

    #[test]
    fn each_part_of_a_request_is_held_to_its_own_words() {
        let mut guard = SaidOrder::new("Go to the lab. Then the garage and back to the lab.");
        guard.next_part("Then the garage and back to the lab.");
        let args = json!({"room": "garage", "then": ["lab"]});
        assert_eq!(settled_by(&mut guard, args.clone()), args);
    }

    #[test]
    fn a_call_naming_what_the_request_does_not_is_left_alone() {
        let other = json!({"room": "garage", "then": ["workshop"]});
        assert_eq!(
            settled("the shop and then the garage", other.clone()),
            other
        );
        let lone = json!({"room": "garage"});
        assert_eq!(settled("the garage please", lone.clone()), lone);
    }
}
