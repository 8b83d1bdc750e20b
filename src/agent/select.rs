//! Choosing which tools to offer when their specs alone exceed the prompt budget (ROSA's
//! turtle demo has 75): lexical scoring of the query against each tool's name and
//! description, plus an always-on set. Cheap, deterministic, and reported in the trace.

use crate::tool::ToolSpec;

const STOPWORDS: &[&str] = &[
    "a", "an", "the", "of", "to", "in", "on", "for", "and", "or", "is", "are", "what", "me", "my",
    "it", "its", "with", "by", "from", "at", "be", "this", "that", "you", "your", "can", "please",
    "how", "which", "show", "tell", "give", "do", "does", "all", "any", "i",
];

fn words(s: &str) -> Vec<String> {
    s.split(|c: char| !c.is_alphanumeric())
        .filter(|w| !w.is_empty())
        .map(|w| w.to_lowercase())
        .filter(|w| !STOPWORDS.contains(&w.as_str()))
        .collect()
}

/// Crude stemming so "topics"/"topic" and "moving"/"move" meet.
fn stem(w: &str) -> &str {
    for suffix in ["ing", "es", "s", "ed"] {
        if w.len() > suffix.len() + 2 {
            if let Some(s) = w.strip_suffix(suffix) {
                return s;
            }
        }
    }
    w
}

/// Score of a tool for a query: name words count triple, description words once.
pub fn score(query: &str, spec: &ToolSpec) -> f64 {
    let q: Vec<String> = words(query).iter().map(|w| stem(w).to_string()).collect();
    if q.is_empty() {
        return 0.0;
    }
    let name: Vec<String> = words(&spec.name.replace('_', " "))
        .iter()
        .map(|w| stem(w).to_string())
        .collect();
    let desc: Vec<String> = words(&spec.description)
        .iter()
        .map(|w| stem(w).to_string())
        .collect();
    let mut s = 0.0;
    for w in &q {
        if name.contains(w) {
            s += 3.0;
        }
        if desc.contains(w) {
            s += 1.0;
        }
    }
    s
}

/// Indices of the tools to offer: the always-on ones, then the best scoring, within
/// `budget` tokens as measured by `cost`, best scoring first and the always-on ones last.
/// When everything fits, all tools in registry order.
pub fn select(
    query: &str,
    specs: &[ToolSpec],
    always_on: &[String],
    budget: usize,
    cost: impl Fn(&ToolSpec) -> usize,
) -> Vec<usize> {
    let costs: Vec<usize> = specs.iter().map(&cost).collect();
    if costs.iter().sum::<usize>() <= budget {
        return (0..specs.len()).collect();
    }
    let always: Vec<usize> = (0..specs.len())
        .filter(|&i| always_on.contains(&specs[i].name))
        .collect();
    let mut used: usize = always.iter().map(|&i| costs[i]).sum();
    let mut ranked: Vec<(f64, usize)> = specs
        .iter()
        .enumerate()
        .filter(|(i, _)| !always.contains(i))
        .map(|(i, s)| (score(query, s), i))
        .filter(|(sc, _)| *sc > 0.0)
        .collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut chosen: Vec<usize> = Vec::new();
    for (_, i) in ranked {
        if used + costs[i] <= budget {
            chosen.push(i);
            used += costs[i];
        }
    }
    // Best first: a small model leans toward the first tool it is shown.
    chosen.extend(always);
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn spec(name: &str, desc: &str) -> ToolSpec {
        ToolSpec::new(name, desc, json!({"type": "object", "properties": {}})).unwrap()
    }

    #[test]
    fn picks_relevant_tools_within_budget() {
        let specs = vec![
            spec("ros_topic_list", "List topics with their types."),
            spec("ros_node_list", "List running nodes."),
            spec("calc_stats", "Mean, median of numbers."),
            spec("turtle_move", "Drive the turtle forward."),
            spec("answer", "Give the final answer."),
        ];
        let picked = select(
            "what topics are there?",
            &specs,
            &["answer".into()],
            20,
            |_| 10,
        );
        assert_eq!(picked, vec![0, 4]);
        let picked = select(
            "what is the mean of 3 and 5",
            &specs,
            &["answer".into()],
            20,
            |_| 10,
        );
        assert_eq!(picked, vec![2, 4]);
        // Everything fits: everything is offered.
        assert_eq!(select("hi", &specs, &[], 1000, |_| 10).len(), 5);
    }
}
