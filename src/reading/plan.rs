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
//!   never at "or" nor "but";
//! - at an ordering word ("then", "luego", "dann") whose words after it leave their
//!   verb unsaid, when the part before opens with a verb that asks to be told or to
//!   read: the later part takes that verb ("echo the odometry and then the battery":
//!   "echo the battery"). A plain "and" keeps one ask with two objects ("list the nodes
//!   and topics"), and an act's verb is never lent.
//!
//! A part of one word joins its neighbour ("hi, what can you do?" is one part), and a
//! request with a negation anywhere is not cut ("don't move, just turn" is read whole,
//! as the guards read it). Cutting only changes what the model is shown; the guards and
//! the policy still judge every call against the whole request.

use std::collections::BTreeSet;

use super::concepts::{asks_act, chains, clauses, opens_request, sequences, tells, Mood};
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
    // The word at which the piece from `from` opens with a verb that asks to be told or
    // to read ("show", "list", "echo"): what a later piece that leaves its own unsaid
    // ("list the nodes and then the topics") takes over. Never a verb of an act: "move
    // back 2 m and then 1 m" lent as "move 1 m" would lose the direction, and "go to
    // the pond, then the dock" is one route, not two trips.
    let verb = |from: usize| {
        let at = from + words[from..].iter().take_while(|w| chaining(w)).count();
        let w = words.get(at).map(first_word)?;
        let reads = tells(&w) || (w.chars().count() > 2 && tool_words.contains(&w));
        (reads && !asks_act(&w)).then_some(at)
    };
    // Each piece as a range of words, with the word whose verb it takes over.
    let mut pieces: Vec<(usize, usize, Option<usize>)> = Vec::new();
    let mut from = 0;
    let mut borrowed: Option<usize> = None;
    for i in 0..words.len() {
        let next = i + 1;
        if next >= words.len() {
            break;
        }
        let w = &words[i];
        let cut_after = w.sentence_end || (w.pause && opens(next));
        // At the first of the chaining words ("y luego"), not within them.
        let chain_next = chaining(&words[next]) && !chaining(w) && !w.folded.is_empty();
        // A sequencer ("then", "luego") orders two asks, the second without a verb of
        // its own: it takes this piece's.
        let chained = chain_next && next > from;
        let lends = (chained
            && !opens(next)
            && words[next..]
                .iter()
                .take_while(|w| chaining(w))
                .any(|w| sequences(&w.folded[0])))
        .then(|| verb(from).or(borrowed))
        .flatten();
        if cut_after || (chained && opens(next)) || lends.is_some() {
            pieces.push((from, next, borrowed.take()));
            from = next;
            borrowed = lends;
        }
    }
    pieces.push((from, words.len(), borrowed));
    // Drop the chaining words a piece opens with; a piece of one word joins a neighbour
    // (`joined_short`).
    let lead = |&(a, b, v): &(usize, usize, Option<usize>)| {
        let skip = words[a..b].iter().take_while(|w| chaining(w)).count();
        (a + skip, b, v)
    };
    let merged = joined_short(pieces.iter().map(lead), words.len());
    if merged.len() < 2 || merged.len() > MAX_PARTS {
        return whole;
    }
    let text = |a: usize, b: usize| {
        request[words[a].start..words[b - 1].end]
            .trim()
            .trim_end_matches([',', ':', ';'])
    };
    merged
        .iter()
        .map(|&(a, b, v)| match v {
            Some(v) => format!("{} {}", text(v, v + 1), text(a, b)),
            None => text(a, b).to_string(),
        })
        .collect()
}

/// Pieces (word ranges, with the verb each takes over) with every piece of one word
/// joined to the next, or to the last when it ends the request (`len` words).
fn joined_short(
    pieces: impl Iterator<Item = (usize, usize, Option<usize>)>,
    len: usize,
) -> Vec<(usize, usize, Option<usize>)> {
    let mut merged = Vec::new();
    // A piece of one word, with the verb it takes over, carried into the next.
    let mut carry: Option<(usize, Option<usize>)> = None;
    for p in pieces {
        let p = match carry.take() {
            Some((start, v)) => (start, p.1, v),
            None => p,
        };
        if p.1 - p.0 < 2 {
            carry = Some((p.0, p.2));
        } else {
            merged.push(p);
        }
    }
    if let Some((start, v)) = carry {
        match merged.last_mut() {
            Some(last) => last.1 = len,
            None => merged.push((start, len, v)),
        }
    }
    merged
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
    fn a_later_part_without_a_verb_takes_the_verb_before_it() {
        assert_eq!(
            cut("echo the odometry and then the battery"),
            ["echo the odometry", "echo the battery"]
        );
        assert_eq!(
            cut("show the pose, then the battery and then the gps"),
            ["show the pose", "show the battery", "show the gps"]
        );
        // A one-word part joins the next with the verb it takes over.
        assert_eq!(
            cut("echo /odom and then /battery and then the gps"),
            ["echo /odom", "echo /battery and then the gps"]
        );
        // An act's verb is never lent: its direction or its route would be lost.
        for q in [
            "move back 2 m and then 1 m",
            "gira 30 grados a la derecha y luego 60 grados",
            "drive to the pond, then to the dock",
            "set max_speed to 2, then max_accel to 1",
        ] {
            assert_eq!(cut(q), [q], "{q}");
        }
        // Only an ordering word lends the verb; "and" alone joins one ask's objects.
        assert_eq!(
            cut("echo the odometry and the battery"),
            ["echo the odometry and the battery"]
        );
        // A question's first word is not lent, and a one-word rest stays with its ask.
        for q in [
            "what is the speed and then the heading",
            "turn left then right",
        ] {
            assert_eq!(cut(q), [q], "{q}");
        }
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
