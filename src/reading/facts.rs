//! What a tool returned, in one line, and whether an answer says it.
//!
//! Every result the model reads carries a `summary`: the tool's own when it writes one
//! (listings, status), else one made here from the result's values ("node /turtlesim,
//! name background_r, value 69"; for messages read from a topic, the newest message's
//! fields). A small model copies a line far more reliably than it reads nested JSON.
//!
//! An answer is held to the result it answers (`Run::ground` chooses it): when the
//! answer states none of its facts (the numbers and names in its summary), or speaks
//! of something else than the request and the result (`on_topic`), the answer is that
//! summary; a sentence said twice in a row is said once. Nothing here reads the
//! operator's language: facts are numbers and names, compared as written, and words
//! are compared by how they start.
//!
//! Cost: one walk of each result (bounded by `MAX_ITEMS`); one scan of the answer.

use serde_json::Value;

/// Values a made summary holds at most.
const MAX_ITEMS: usize = 12;
/// Characters a made summary holds at most (a six-joint arm's state, one row a joint,
/// fits).
const MAX_CHARS: usize = 480;
/// Keys whose values say nothing an operator asked about.
const NOISE: &[&str] = &[
    "header",
    "stamp",
    "covariance",
    "filters",
    "qos",
    "definition",
    "example",
    "t",
    "window_s",
];

/// `output` with a `summary` first when it had none; an output that is not an object,
/// or has nothing to say, is left as it is.
pub(crate) fn with_summary(mut output: Value) -> Value {
    if output.get("summary").is_some_and(Value::is_string) {
        return output;
    }
    let Some(line) = summarize(&output) else {
        return output;
    };
    let Value::Object(fields) = &mut output else {
        return output;
    };
    let mut ordered = serde_json::Map::new();
    ordered.insert("summary".into(), Value::String(line));
    ordered.append(fields);
    Value::Object(ordered)
}

/// One line of `output`'s values: "key value, key value, …" (nested keys joined by
/// dots; of a list of messages, the newest one).
pub(crate) fn summarize(output: &Value) -> Option<String> {
    let Value::Object(fields) = output else {
        return None;
    };
    let mut items = Vec::new();
    for (key, value) in fields {
        if key == "messages" {
            if let Some(last) = value.as_array().and_then(|a| a.last()) {
                leaves(last, "", &mut items);
            }
            continue;
        }
        leaves(value, key, &mut items);
    }
    if items.is_empty() {
        return None;
    }
    let mut line = String::new();
    for item in items.iter().take(MAX_ITEMS) {
        if line.len() + item.len() + 2 > MAX_CHARS {
            break;
        }
        if !line.is_empty() {
            line.push_str(", ");
        }
        line.push_str(item);
    }
    Some(line)
}

/// "path value" for each scalar under `v` (a list of scalars as one value).
fn leaves(v: &Value, path: &str, out: &mut Vec<String>) {
    if out.len() >= MAX_ITEMS {
        return;
    }
    let key = path.rsplit('.').next().unwrap_or(path);
    if NOISE.contains(&key) {
        return;
    }
    let named = |text: String| {
        if path.is_empty() {
            text
        } else {
            format!("{path} {text}")
        }
    };
    match v {
        Value::Object(m) => {
            let rows = by_name(m);
            for row in &rows.0 {
                out.push(named(row.clone()));
            }
            for (k, child) in m {
                if rows.1.contains(&k.as_str()) {
                    continue;
                }
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                leaves(child, &p, out);
            }
        }
        Value::Array(items) if items.iter().all(|i| !i.is_object() && !i.is_array()) => {
            if !items.is_empty() {
                let shown: Vec<String> = items.iter().take(8).map(scalar).collect();
                let more = items.len().saturating_sub(shown.len());
                let mut text = shown.join(" ");
                if more > 0 {
                    text.push_str(&format!(" and {more} more"));
                }
                // A list of words (names, poses, modes) says how many it holds, so a
                // question of how many is answered by its count.
                if items.len() > 1 && items.iter().all(Value::is_string) {
                    text = format!("({}) {text}", items.len());
                }
                out.push(named(text));
            }
        }
        Value::Array(items) => {
            for (i, child) in items.iter().enumerate().take(4) {
                let p = if path.is_empty() {
                    i.to_string()
                } else {
                    format!("{path}.{i}")
                };
                leaves(child, &p, out);
            }
        }
        Value::Null => {}
        other => out.push(named(scalar(other))),
    }
}

/// A message's parallel lists read one entry at a time: a `name` list of strings and
/// the lists of scalars as long as it (a joint state's `position`, `velocity`, `effort`)
/// give one row per name, "elbow_joint: position 1.5 velocity 0 effort 2.1", so the
/// values of a joint stand beside its name. Returns the rows and the keys they took.
fn by_name(m: &serde_json::Map<String, Value>) -> (Vec<String>, Vec<&str>) {
    let Some(names) = m.get("name").and_then(Value::as_array) else {
        return (Vec::new(), Vec::new());
    };
    if names.is_empty() || !names.iter().all(Value::is_string) {
        return (Vec::new(), Vec::new());
    }
    let columns: Vec<(&str, &Vec<Value>)> = m
        .iter()
        .filter(|(k, _)| k.as_str() != "name")
        .filter_map(|(k, v)| Some((k.as_str(), v.as_array()?)))
        .filter(|(_, a)| {
            a.len() == names.len() && a.iter().all(|x| !x.is_object() && !x.is_array())
        })
        .collect();
    if columns.is_empty() {
        return (Vec::new(), Vec::new());
    }
    let rows = names
        .iter()
        .enumerate()
        .map(|(i, n)| {
            let values: Vec<String> = columns
                .iter()
                .map(|(k, a)| format!("{k} {}", scalar(&a[i])))
                .collect();
            format!("{}: {}", scalar(n), values.join(" "))
        })
        .collect();
    let mut taken: Vec<&str> = columns.iter().map(|(k, _)| *k).collect();
    taken.push("name");
    (rows, taken)
}

fn scalar(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Number(n) => n.to_string(),
        other => other.to_string(),
    }
}

/// The facts of a summary: its numbers and its names (words holding `/` or `_`), as
/// written, lowercased.
pub fn facts(summary: &str) -> Vec<String> {
    words(summary)
        .map(|w| w.trim_end_matches('.').to_lowercase())
        .filter(|w| {
            let number = w.parse::<f64>().is_ok();
            let name = w.len() > 1 && (w.contains('/') || w.contains('_'));
            number || name
        })
        .collect()
}

/// The answer the operator reads: `reply` with a repeated sentence said once, or, when
/// it states none of the facts of the `summary` of the result it answers (a call that
/// succeeded), that summary. Facts the `request` itself states ("move 1 m" and a result's
/// 1.0) do not show the reply read the result, unless there are no others.
pub(crate) fn grounded(reply: &str, summary: Option<&str>, request: &str) -> String {
    let reply = once(unlooped(reply));
    let Some(summary) = summary else {
        return reply;
    };
    // Digits and punctuation alone ("1.0.0.0:8080:1:1:1") say nothing the summary
    // does not say better.
    if !reply.chars().any(char::is_alphabetic) {
        return summary.to_string();
    }
    let all = facts(summary);
    let asked = request.to_lowercase();
    let asked_numbers: Vec<f64> = written_numbers(&asked).map(|(n, _)| n).collect();
    let in_request = |f: &String| match f.parse::<f64>() {
        Ok(n) => asked_numbers.contains(&n),
        Err(_) => asked.contains(f.as_str()),
    };
    let new: Vec<String> = all.iter().filter(|f| !in_request(f)).cloned().collect();
    let facts = if new.is_empty() { all } else { new };
    let lower = reply.to_lowercase();
    // Numbers are compared as numbers, to the precision the answer writes them: "42"
    // states 42.0, "5.54" states 5.544.
    let said: Vec<(f64, f64)> = written_numbers(&lower).collect();
    let stated = |f: &String| match f.parse::<f64>() {
        Ok(n) => said.iter().any(|(s, tol)| (s - n).abs() <= *tol + 1e-9),
        Err(_) => lower.contains(f.as_str()),
    };
    if (facts.is_empty() || facts.iter().any(stated)) && on_topic(&reply, &[summary, request]) {
        return reply;
    }
    summary.to_string()
}

/// Share of an answer's words that must meet the words of the request or the result.
const ON_TOPIC: f64 = 0.4;
/// Fewest words an answer must have for its share to be judged.
const JUDGED_WORDS: usize = 3;

/// Whether `reply` speaks of what `sources` (the request, the result's summary) speak
/// of: at least `ON_TOPIC` of its words (of three letters or more, each once) meet
/// theirs. A word meets another when the two start alike (four letters, or the whole
/// of the shorter), in any language: "moved" meets "move", "nodos" meets "nodo". A
/// small model may name one fact of the result inside a sentence about something else
/// ("Please use the `/turtlesim` protocol to send a response to the user."), which the
/// facts alone would take for an answer.
fn on_topic(reply: &str, sources: &[&str]) -> bool {
    let long = |w: &String| w.chars().count() >= 3;
    let stem = |w: &str| w.chars().take(4).collect::<String>();
    let theirs: std::collections::BTreeSet<String> = sources
        .iter()
        .flat_map(|s| crate::lexicon::folded_words(s))
        .filter(long)
        .map(|w| stem(&w))
        .collect();
    let mine: std::collections::BTreeSet<String> = crate::lexicon::folded_words(reply)
        .into_iter()
        .filter(long)
        .map(|w| stem(&w))
        .collect();
    if mine.len() < JUDGED_WORDS {
        return true;
    }
    let met = mine.iter().filter(|w| theirs.contains(*w)).count();
    met as f64 >= ON_TOPIC * mine.len() as f64
}

/// The numbers `text` writes, each with half a unit of its last written place ("5.54":
/// 0.005), the precision it states.
fn written_numbers(text: &str) -> impl Iterator<Item = (f64, f64)> + '_ {
    words(text).filter_map(|w| {
        let w = w.trim_end_matches(['.', '%']);
        let n = w.parse::<f64>().ok()?;
        let decimals = w.split_once('.').map_or(0, |(_, d)| d.len()) as i32;
        Some((n, 0.5 * 10f64.powi(-decimals)))
    })
}

/// The words of `text` as `facts` splits it.
fn words(text: &str) -> impl Iterator<Item = &str> {
    text.split(|c: char| c.is_whitespace() || matches!(c, ',' | ';' | '(' | ')' | ':'))
}

/// Longest phrase, in words, looked for as the unit of a loop.
const LOOP_WORDS: usize = 12;

/// `text` up to where it starts going round in a loop: a phrase said three times in a
/// row is said once ("the direction of the direction of the direction of …", "request
/// 1.0, request 1.0, …"; numbers alone may repeat), cut where a comma or stop ends the phrase when one does.
/// Words are compared by their letters and digits alone, in any script.
fn unlooped(text: &str) -> &str {
    // (start, end, key) of each word.
    let mut words: Vec<(usize, usize, String)> = Vec::new();
    let mut start = None;
    for (i, c) in text.char_indices().chain([(text.len(), ' ')]) {
        match (c.is_alphanumeric() || c == '.' && start.is_some(), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                let key: String = text[s..i]
                    .chars()
                    .filter(|c| c.is_alphanumeric())
                    .flat_map(char::to_lowercase)
                    .collect();
                words.push((s, i, key));
                start = None;
            }
            _ => {}
        }
    }
    let same = |a: usize, b: usize, n: usize| (0..n).all(|k| words[a + k].2 == words[b + k].2);
    for i in 0..words.len() {
        for p in 1..=LOOP_WORDS.min((words.len() - i) / 3) {
            // Numbers alone repeat in real data ("0.0 0.0 0.0"); a loop says words.
            let worded = words[i..i + p]
                .iter()
                .any(|w| w.2.chars().any(char::is_alphabetic));
            if !(worded && same(i, i + p, p) && same(i, i + 2 * p, p)) {
                continue;
            }
            // Of the p places to cut the second round, the first after a comma or stop.
            let cut = (i + p..i + 2 * p)
                .find(|&w| text[words[w - 1].1..words[w].0].contains([',', '.', ';']))
                .unwrap_or(i + p);
            return text[..words[cut].0].trim_end_matches(|c: char| c.is_whitespace() || c == ',');
        }
    }
    text
}

/// `text` with each sentence that repeats an earlier one left out.
fn once(text: &str) -> String {
    let mut seen: Vec<String> = Vec::new();
    let mut out = String::new();
    for sentence in sentences(text) {
        let key: String = sentence
            .chars()
            .filter(|c| c.is_alphanumeric())
            .flat_map(char::to_lowercase)
            .collect();
        if key.is_empty() || seen.contains(&key) {
            continue;
        }
        seen.push(key);
        out.push_str(sentence);
    }
    out.trim().to_string()
}

/// Sentences with what ends them (and the space after).
fn sentences(text: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut start = 0;
    let b = text.as_bytes();
    for (i, &c) in b.iter().enumerate() {
        let ends =
            matches!(c, b'.' | b'!' | b'?') && b.get(i + 1).is_none_or(|n| n.is_ascii_whitespace());
        if ends {
            let mut end = i + 1;
            while end < b.len() && b[end].is_ascii_whitespace() {
                end += 1;
            }
            out.push(&text[start..end]);
            start = end;
        }
    }
    if start < text.len() {
        out.push(&text[start..]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn a_result_without_a_summary_gets_one_from_its_values() {
        let out = with_summary(json!({"node": "/turtlesim", "name": "background_r", "value": 69}));
        assert_eq!(
            out["summary"],
            "node /turtlesim, name background_r, value 69"
        );
        assert_eq!(out.as_object().unwrap().keys().next().unwrap(), "summary");
        let own = with_summary(json!({"summary": "2 nodes: /a, /b", "count": 2}));
        assert_eq!(own["summary"], "2 nodes: /a, /b");
        assert_eq!(with_summary(json!([1, 2])), json!([1, 2]));
        let list = with_summary(json!({"name": "stored_positions", "value": ["door", "desk"]}));
        assert_eq!(
            list["summary"],
            "name stored_positions, value (2) door desk"
        );
    }

    #[test]
    fn an_echo_is_summarised_by_its_newest_message() {
        let echo = json!({"topic": "/p", "type": "turtlesim/msg/Pose", "count": 2, "messages": [
            {"x": 1.0, "y": 2.0}, {"x": 3.5, "y": 4.0, "header": {"stamp": {"sec": 1}}}
        ]});
        assert_eq!(
            summarize(&echo).unwrap(),
            "topic /p, type turtlesim/msg/Pose, count 2, x 3.5, y 4.0"
        );
        let nested = json!({"pose": {"x": 1.0}, "names": ["a", "b"]});
        assert_eq!(summarize(&nested).unwrap(), "pose.x 1.0, names (2) a b");
    }

    #[test]
    fn parallel_lists_are_read_a_name_at_a_time() {
        let state = json!({"topic": "/j", "messages": [{"name": ["wheel_l", "wheel_r"],
            "position": [0.5, 1.25], "velocity": [0.0, 2.0], "effort": [], "frame": "base"}]});
        assert_eq!(
            summarize(&state).unwrap(),
            "topic /j, wheel_l: position 0.5 velocity 0.0, wheel_r: position 1.25 velocity 2.0, frame base"
        );
        // A name that is not a list of strings reads as before.
        let plain = json!({"name": "x", "position": [1.0]});
        assert_eq!(summarize(&plain).unwrap(), "name x, position 1.0");
    }

    #[test]
    fn an_answer_going_round_in_a_loop_is_cut_where_the_loop_starts() {
        assert_eq!(
            unlooped(
                "The turtle is facing the direction of the direction of the direction of the t"
            ),
            "The turtle is facing the direction of"
        );
        assert_eq!(
            unlooped("response 1.0, request 1.0, request 1.0, request 1.0, request 1.0"),
            "response 1.0, request 1.0"
        );
        // A list that repeats no phrase is kept whole, however long.
        let list = "10 topics: /battery_state, /clock, /diagnostics, /rosout, /turtle1/pose";
        assert_eq!(unlooped(list), list);
        assert_eq!(unlooped("x 1.0, y 1.0, z 1.0"), "x 1.0, y 1.0, z 1.0");
        assert_eq!(unlooped("linear 0.0 0.0 0.0"), "linear 0.0 0.0 0.0");
        let pose = "x 5.54, y 5.54";
        assert_eq!(
            grounded(
                "pose x 5.54 pose x 5.54 pose x 5.54 pose x 5.54",
                Some(pose),
                ""
            ),
            "pose x 5.54"
        );
    }

    #[test]
    fn numbers_count_as_stated_to_the_precision_written() {
        let s = "expression 6 * 7, result 42.0";
        assert_eq!(grounded("It is 42.", Some(s), ""), "It is 42.");
        let pose = "x 5.544, y 2.1";
        assert_eq!(grounded("At 5.54.", Some(pose), ""), "At 5.54.");
        assert_eq!(grounded("At 5.6.", Some(pose), ""), pose);
    }

    #[test]
    fn facts_the_request_states_show_nothing_read() {
        let s = "requested_m 1.0, moved_m 1.0, pose.x 6.54, pose.y 5.54";
        let q = "mueve la tortuga 1 metro";
        assert_eq!(grounded("Mueve la tortuga 1 metro.", Some(s), q), s);
        assert_eq!(
            grounded("Movida 1 m, ahora en x 6.54.", Some(s), q),
            "Movida 1 m, ahora en x 6.54."
        );
        // When the request states every fact, saying one is enough.
        let set = "node /turtlesim, name background_r, value 100";
        let q = "set background_r of /turtlesim to 100";
        assert_eq!(grounded("Set to 100.", Some(set), q), "Set to 100.");
    }

    #[test]
    fn an_answer_that_states_no_fact_is_replaced_by_the_summary() {
        let s = "1 node: /turtlesim";
        assert_eq!(grounded("The response is a response.", Some(s), ""), s);
        assert_eq!(
            grounded("Running: /turtlesim.", Some(s), ""),
            "Running: /turtlesim."
        );
        // Numbers count as facts in any language.
        let pose = "x 5.54, y 5.54, theta 0";
        assert_eq!(
            grounded("La tortuga está en x 5.54.", Some(pose), ""),
            "La tortuga está en x 5.54."
        );
        // With no result to answer (only failures), the model's own words stay.
        assert_eq!(grounded("Hello.", None, ""), "Hello.");
    }

    #[test]
    fn a_repeated_sentence_is_said_once() {
        assert_eq!(
            once("The turtle moved. The turtle moved. The turtle moved. It is at 7."),
            "The turtle moved. It is at 7."
        );
        assert_eq!(once("v1.5 is set."), "v1.5 is set.");
    }

    #[test]
    fn an_answer_without_a_word_is_replaced_by_the_summary() {
        let summary = "1 node: /turtlesim";
        for reply in ["1.0.0.0:8080:8:1:1:1:1:1:1", "1", "42 %"] {
            assert_eq!(
                grounded(reply, Some(summary), "which ROS nodes are up?"),
                summary
            );
        }
        assert_eq!(
            grounded(
                "1 node: /turtlesim",
                Some(summary),
                "which ROS nodes are up?"
            ),
            "1 node: /turtlesim"
        );
    }

    #[test]
    fn facts_are_numbers_and_names() {
        assert_eq!(
            facts("2 topics: /a/b, /c; value 0.5, name background_r."),
            ["2", "/a/b", "/c", "0.5", "background_r"]
        );
    }

    #[test]
    fn an_answer_about_something_else_is_replaced_by_the_result() {
        let summary = "1 node: /turtlesim";
        let request = "which ROS nodes are up?";
        let off = "Hello, World! This is a response to your request. Please use the `/turtlesim` protocol to send a response to the user.";
        assert_eq!(grounded(off, Some(summary), request), summary);
        let on = "There is 1 node running: /turtlesim.";
        assert_eq!(grounded(on, Some(summary), request), on);
        // In another language: the result's names and the request's words are met.
        let es = "Hay 1 nodo: /turtlesim.";
        assert_eq!(
            grounded(es, Some(summary), "enumera los nodos ROS activos"),
            es
        );
    }
}
