//! A request of several parts ("list every service, then tell me the type of /spawn",
//! "move 3 m and tell me where it ended up") is worked through one part at
//! a time. A small model shown the whole request answers after its first call; shown one
//! part as the operator's turn, then the next part after that part's result, it makes
//! each part's call with the earlier results in view, as in a conversation.
//!
//! Where a request is cut, read without a model and in the languages `concepts` reads:
//!
//! - at the end of a sentence (". ", "? ", "! ", "; ");
//! - at a comma or at a chaining conjunction ("and", "then", "y luego", "puis", "und
//!   dann"), when the words after it open a request of their own: a question word, a
//!   "tell me", a word naming an act, or a word of a tool's name ("echo", "list");
//!   never at "or" nor "but".
//!
//! A part of one word joins its neighbour ("hi, what can you do?" is one part), and a
//! request with a negation anywhere is not cut ("don't move, just turn" is read whole,
//! as the guards read it). Cutting only changes what the model is shown; the guards and
//! the policy still judge every call against the whole request.

use std::collections::BTreeSet;

use super::concepts::{chains, clauses, opens_request, Mood};
use crate::lexicon::folded_words;

/// At most this many parts; a longer request is worked as one.
pub(crate) const MAX_PARTS: usize = 4;

/// One word of the request: where it lies, and how it ends.
struct Word {
    start: usize,
    end: usize,
    folded: Vec<String>,
    /// Ends a sentence ("it.", "now?").
    sentence_end: bool,
    /// Ends with a comma or a colon.
    pause: bool,
}

fn words(request: &str) -> Vec<Word> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, c) in request.char_indices().chain([(request.len(), ' ')]) {
        match (c.is_whitespace(), start) {
            (false, None) => start = Some(i),
            (true, Some(s)) => {
                let text = &request[s..i];
                let tail = text.trim_end_matches(['"', '\'', ')', ']', '»', '”']);
                out.push(Word {
                    start: s,
                    end: i,
                    folded: folded_words(text),
                    sentence_end: tail.ends_with(['.', '?', '!', ';']),
                    pause: tail.ends_with([',', ':']),
                });
                start = None;
            }
            _ => {}
        }
    }
    out
}

/// The parts of `request`, in order (one part: the request itself). `tool_words` are
/// the folded words of the offered tools' names.
pub fn parts(request: &str, tool_words: &BTreeSet<String>) -> Vec<String> {
    let whole = vec![request.trim().to_string()];
    if clauses(request).iter().any(|c| c.mood == Mood::Forbidden) {
        return whole;
    }
    let words = words(request);
    let first_word = |w: &Word| w.folded.first().cloned().unwrap_or_default();
    let chaining = |w: &Word| w.folded.len() == 1 && chains(&w.folded[0]) == Some(true);
    // Whether the words from `i` on open a request (past any chaining words).
    let opens = |i: usize| {
        words[i..]
            .iter()
            .map(first_word)
            .find(|w| chains(w) != Some(true))
            .is_some_and(|w| {
                opens_request(&w) || (w.chars().count() > 2 && tool_words.contains(&w))
            })
    };
    // Each piece as a range of words.
    let mut pieces: Vec<(usize, usize)> = Vec::new();
    let mut from = 0;
    for i in 0..words.len() {
        let next = i + 1;
        if next >= words.len() {
            break;
        }
        let w = &words[i];
        let cut_after = w.sentence_end || (w.pause && opens(next));
        // At the first of the chaining words ("y luego"), not within them.
        let chain_next = chaining(&words[next]) && !chaining(w) && !w.folded.is_empty();
        if cut_after || (chain_next && next > from && opens(next)) {
            pieces.push((from, next));
            from = next;
        }
    }
    pieces.push((from, words.len()));
    // Drop the chaining words a piece opens with; a piece of one word joins a neighbour.
    let lead = |&(a, b): &(usize, usize)| {
        let skip = words[a..b].iter().take_while(|w| chaining(w)).count();
        (a + skip, b)
    };
    let mut merged: Vec<(usize, usize)> = Vec::new();
    let mut carry: Option<usize> = None;
    for p in pieces.iter().map(lead) {
        let p = (carry.take().unwrap_or(p.0), p.1);
        if p.1 - p.0 < 2 {
            carry = Some(p.0);
        } else {
            merged.push(p);
        }
    }
    if let Some(start) = carry {
        match merged.last_mut() {
            Some(last) => last.1 = words.len(),
            None => merged.push((start, words.len())),
        }
    }
    if merged.len() < 2 || merged.len() > MAX_PARTS {
        return whole;
    }
    merged
        .iter()
        .map(|&(a, b)| {
            request[words[a].start..words[b - 1].end]
                .trim()
                .trim_end_matches([',', ':', ';'])
                .to_string()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tool_words() -> BTreeSet<String> {
        [
            "ros", "topic", "echo", "list", "node", "param", "get", "set", "turtle", "pose",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    }

    fn cut(q: &str) -> Vec<String> {
        parts(q, &tool_words())
    }

    #[test]
    fn requests_of_several_parts_are_cut_where_a_new_request_opens() {
        assert_eq!(
            cut("list every service, then tell me the type of /spawn"),
            ["list every service", "tell me the type of /spawn"]
        );
        assert_eq!(
            cut("move 3 m and tell me where it ended up"),
            ["move 3 m", "tell me where it ended up"]
        );
        assert_eq!(
            cut("show the services and echo /turtle1/pose"),
            ["show the services", "echo /turtle1/pose"]
        );
        assert_eq!(
            cut("which node offers /spawn and what topics does it publish?"),
            ["which node offers /spawn", "what topics does it publish?"]
        );
        assert_eq!(
            cut("mueve la tortuga 1 metro y luego dime dónde está"),
            ["mueve la tortuga 1 metro", "dime dónde está"]
        );
        assert_eq!(
            cut("Bewege die Schildkröte 1 Meter. Wo ist sie jetzt?"),
            ["Bewege die Schildkröte 1 Meter.", "Wo ist sie jetzt?"]
        );
    }

    #[test]
    fn one_request_stays_whole() {
        for q in [
            "show every ROS node",
            "hi, what can you do?",
            "thank you, that will do",
            "spawn another turtle at x 4 y 1",
            "teleport turtle1 to x 6 y 2 via the teleport_absolute service",
            "teleport the turtle to x 2.5, y 3",
            "what are the x and y of the turtle?",
            "list the nodes and topics",
            "don't move, just turn 90 degrees and then tell me the heading",
            "move forward or turn left",
        ] {
            assert_eq!(cut(q), [q], "{q}");
        }
    }
}
