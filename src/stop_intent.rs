//! Whether what the operator typed or said asks the robot to stop, read without a model
//! ("stop", "hold on", "don't move", "kill the motors", "¡para!", "arrête", "halt an",
//! "fermati", "pare"), so a stop is never queued behind a run, never sent to the model and
//! never mistaken for a tool to call.
//!
//! The ways of saying stop are data: `data/stop/<language>.txt`, one file per language,
//! built into the binary. A sentence asks to stop when, after filler words ("please",
//! "hey", "por favor", "bitte"), it opens with one of its language's stop phrases and says
//! little more: up to ten more words for a plain stop ("stop it right there"; the stop
//! said again does not count), up to two for a phrase that also means something else
//! ("wait", "para", "hold on"); a phrase that says wait is no stop when an amount follows
//! it ("wait 40 seconds" asks for a wait). A plain stop also stops when it closes a short sentence
//! that does not negate it and is no question ("I said stop", "turtle, halt", not "why
//! did it stop"). A question stops only when
//! it asks politely ("can you stop?"), never "why did it stop?" or "brake status?".
//! Phrases a language uses for something else ("para adelante": forward) are listed as
//! never stops. A stop phrase elsewhere ("don't stop", "no pares") is not a stop. A
//! request of several sentences stops when any does: a mistake here brakes a robot that
//! was not asked to, never the other way round.
//!
//! Owns the reading only; engaging the e-stop is the caller's (`estop`).

use std::sync::OnceLock;

use crate::lexicon::folded_words;

/// The tables, one per language (their order is not significant: all are read at once,
/// since the language of a two-word request cannot be told).
const TABLES: [(&str, &str); 6] = [
    ("en", include_str!("../data/stop/en.txt")),
    ("es", include_str!("../data/stop/es.txt")),
    ("fr", include_str!("../data/stop/fr.txt")),
    ("de", include_str!("../data/stop/de.txt")),
    ("it", include_str!("../data/stop/it.txt")),
    ("pt", include_str!("../data/stop/pt.txt")),
];

/// Words a plain stop may be followed by ("stop the turtle right now, please").
const MAX_AFTER_STOP: usize = 10;
/// Words a stop that also means something else may be followed by ("para el robot").
const MAX_AFTER_ALONE: usize = 2;
/// Words a plain stop that closes its sentence may follow ("I said stop").
const MAX_BEFORE_STOP: usize = 4;

/// Words that negate the stop that follows them ("don't stop", "nicht stoppen",
/// "ne t'arrête pas"): "t" is what "don't" leaves once split at the apostrophe.
const NEGATIONS: &[&str] = &[
    "don", "dont", "t", "not", "never", "nicht", "nie", "non", "nao", "ne", "pas", "jamais",
    "nunca", "mai", "kein", "keine",
];

/// One phrase: its words, each whole or (ending in `*`) a prefix.
#[derive(Debug)]
struct Phrase(Vec<String>);

impl Phrase {
    /// How many of `words`' first words it covers, if it opens them; filler words may
    /// stand between its words ("bleib sofort stehen").
    fn opens(&self, words: &[String], filler: impl Fn(&str) -> bool) -> Option<usize> {
        let mut i = 0;
        for (k, p) in self.0.iter().enumerate() {
            let matches = |w: &str| word_matches(p, w);
            while k > 0 && i < words.len() && !matches(&words[i]) && filler(&words[i]) {
                i += 1;
            }
            if !matches(words.get(i)?) {
                return None;
            }
            i += 1;
        }
        Some(i)
    }
}

/// Whether `word` is the phrase word `p`: whole, or begun by it when `p` ends in `*`.
fn word_matches(p: &str, word: &str) -> bool {
    match p.strip_suffix('*') {
        Some(prefix) => word.starts_with(prefix),
        None => p == word,
    }
}

#[derive(Debug, Default)]
struct Table {
    stop: Vec<Phrase>,
    alone: Vec<Phrase>,
    /// Phrases that say wait: as `alone`, but an amount after one makes it a wait.
    wait: Vec<Phrase>,
    never: Vec<Phrase>,
    question: Vec<String>,
    filler: Vec<String>,
}

/// The tables of every language, read once.
fn table() -> &'static Table {
    static TABLE: OnceLock<Table> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = Table::default();
        for (_, text) in TABLES {
            read_table(text, &mut t);
        }
        // Longest first, so "hold on" is tried before a one-word phrase it begins with.
        t.stop.sort_by_key(|p| std::cmp::Reverse(p.0.len()));
        t.alone.sort_by_key(|p| std::cmp::Reverse(p.0.len()));
        t.wait.sort_by_key(|p| std::cmp::Reverse(p.0.len()));
        t.never.sort_by_key(|p| std::cmp::Reverse(p.0.len()));
        t
    })
}

/// Add one file's sections to `t`. The files are built in and checked by the tests, so
/// a line outside a section is skipped rather than reported.
fn read_table(text: &str, t: &mut Table) {
    #[derive(Clone, Copy)]
    enum Section {
        None,
        Stop,
        Alone,
        Wait,
        Never,
        Question,
        Filler,
    }
    let mut section = Section::None;
    for line in text.lines().map(str::trim) {
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        match line {
            "[stop]" => section = Section::Stop,
            "[alone]" => section = Section::Alone,
            "[wait]" => section = Section::Wait,
            "[never]" => section = Section::Never,
            "[question]" => section = Section::Question,
            "[filler]" => section = Section::Filler,
            _ => {
                let words: Vec<String> = line.split_whitespace().map(str::to_string).collect();
                match section {
                    Section::Stop => t.stop.push(Phrase(words)),
                    Section::Alone => t.alone.push(Phrase(words)),
                    Section::Wait => t.wait.push(Phrase(words)),
                    Section::Never => t.never.push(Phrase(words)),
                    Section::Question => t.question.extend(words),
                    Section::Filler => t.filler.extend(words),
                    Section::None => {}
                }
            }
        }
    }
}

/// Whether `request` asks the robot to stop (see the module header).
pub(crate) fn asks_to_stop(request: &str) -> bool {
    sentences(request).any(|(text, question)| sentence_stops(text, question))
}

/// `text` cut at sentence and clause marks, each piece with whether it asks a question.
fn sentences(text: &str) -> impl Iterator<Item = (&str, bool)> {
    let mut rest = text;
    std::iter::from_fn(move || loop {
        if rest.is_empty() {
            return None;
        }
        let end = rest
            .find(|c: char| ",.;:!?¡¿…\n".contains(c))
            .unwrap_or(rest.len());
        let (piece, tail) = rest.split_at(end);
        let mark = tail.chars().next();
        let opened_as_question = piece.is_empty() && mark == Some('¿');
        rest = mark.map_or("", |m| &tail[m.len_utf8()..]);
        if opened_as_question {
            // "¿para qué sirve?": the question runs to its closing mark.
            let close = rest.find('?').unwrap_or(rest.len());
            let question = &rest[..close];
            rest = rest.get(close + 1..).unwrap_or("");
            return Some((question, true));
        }
        if piece.trim().is_empty() {
            continue;
        }
        return Some((piece, mark == Some('?')));
    })
}

fn sentence_stops(text: &str, question: bool) -> bool {
    let t = table();
    let words = folded_words(text);
    let is_filler = |w: &str| t.filler.iter().any(|f| f == w);
    let start = words.iter().take_while(|w| is_filler(w)).count();
    let polite = start > 0;
    let words = &words[start..];
    if t.never.iter().any(|p| p.opens(words, is_filler).is_some()) {
        return false;
    }
    // The stop said again ("stop, stop, stop") is no more words.
    let is_stop = |w: &str| {
        t.stop
            .iter()
            .any(|p| p.0.len() == 1 && word_matches(&p.0[0], w))
    };
    let after = |n: usize| {
        words[n..]
            .iter()
            .filter(|w| !is_filler(w) && !is_stop(w))
            .count()
    };
    if let Some(n) = t.stop.iter().find_map(|p| p.opens(words, is_filler)) {
        return (!question || polite) && after(n) <= MAX_AFTER_STOP;
    }
    if question {
        return false;
    }
    if let Some(n) = t.alone.iter().find_map(|p| p.opens(words, is_filler)) {
        return after(n) <= MAX_AFTER_ALONE;
    }
    if let Some(n) = t.wait.iter().find_map(|p| p.opens(words, is_filler)) {
        // Followed by an amount, a wait is asked for ("wait 40 seconds", "espera 5
        // segundos"), which an e-stop would have to be reset after.
        let amount = words.get(n).is_some_and(|w| crate::lexicon::is_number(w));
        return !amount && after(n) <= MAX_AFTER_ALONE;
    }
    closes_with_stop(t, words, &is_filler)
}

/// A plain stop closing a short sentence that does not negate it ("I said stop",
/// "turtle, halt", "no no no stop").
fn closes_with_stop(t: &Table, words: &[String], is_filler: &impl Fn(&str) -> bool) -> bool {
    let words: Vec<String> = words.iter().filter(|w| !is_filler(w)).cloned().collect();
    if words.first().is_some_and(|w| t.question.contains(w)) {
        return false;
    }
    (1..words.len()).any(|i| {
        let tail = &words[i..];
        i <= MAX_BEFORE_STOP
            && !NEGATIONS.contains(&words[i - 1].as_str())
            && t.stop
                .iter()
                .any(|p| p.opens(tail, |_| false) == Some(tail.len()))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_table_has_its_sections_and_no_stray_line() {
        for (code, text) in TABLES {
            let mut t = Table::default();
            read_table(text, &mut t);
            assert!(
                !t.stop.is_empty()
                    && !t.alone.is_empty()
                    && !t.wait.is_empty()
                    && !t.filler.is_empty(),
                "{code}"
            );
            let mut in_section = false;
            for line in text.lines().map(str::trim) {
                if line.starts_with('[') {
                    in_section = true;
                }
                if !line.is_empty() && !line.starts_with('#') {
                    assert!(in_section, "{code}: {line:?} is outside a section");
                    // Entries are written as `folded_words` reads text.
                    let folded = folded_words(&line.replace('*', "")).join(" ");
                    assert!(
                        line.starts_with('[') || folded == line.replace('*', ""),
                        "{code}: {line:?} is not written folded"
                    );
                }
            }
        }
    }

    #[test]
    fn plain_stops_in_each_language() {
        for s in [
            "Stop!",
            "please stop the robot right now",
            "whoa, whoa",
            "hey robot, kill the motors",
            "can you halt?",
            "ok that's enough. freeze",
            "E-STOP",
            "Detente ya",
            "¡quédate quieto!",
            "no te muevas",
            "arrêtez tout de suite",
            "ne bouge plus",
            "Bleib sofort stehen",
            "kannst du bitte anhalten",
            "non muoverti!",
            "fermati subito",
            "não se mexa",
            "fique parado por favor",
        ] {
            assert!(asks_to_stop(s), "{s:?}");
        }
    }

    #[test]
    fn words_that_also_mean_something_else_stop_only_alone() {
        assert!(asks_to_stop("wait!"));
        assert!(asks_to_stop("para el robot"));
        assert!(!asks_to_stop(
            "wait until the battery is full, then go to the door"
        ));
        assert!(!asks_to_stop("¿para qué sirve el tópico de la batería?"));
        assert!(!asks_to_stop(
            "para mover el robot hacia adelante hay que publicar"
        ));
        assert!(!asks_to_stop("hold on to the cup with the gripper"));
        // An amount after one is its other sense: a wait, not a stop.
        for s in [
            "wait 10 seconds",
            "warte zwei Sekunden",
            "aspetta 4 secondi",
        ] {
            assert!(!asks_to_stop(s), "{s}");
        }
        assert!(asks_to_stop("wait, wait"));
    }

    #[test]
    fn stop_words_elsewhere_are_not_stops() {
        for s in [
            "why did it stop?",
            "don't stop",
            "never stop recording",
            "no pares",
            "non fermarti",
            "não pare",
            "ne t'arrête pas",
            "is the turtle stopped",
            "list the topics",
            "move forward 2 meters",
            "no",
            "",
            "...",
            "what does the brake topic carry? and the stop service?",
        ] {
            assert!(!asks_to_stop(s), "{s:?}");
        }
    }

    #[test]
    fn stops_said_again_late_or_politely() {
        for s in [
            "I said stop",
            "turtle, stop",
            "no no no stop",
            "stop stop stop stop stop stop stop stop stop stop",
            "Stoppen Sie den Roboter!",
            "Roboter anhalten!",
            "can you stop?",
            "Hold!",
            "¡Páralo!",
            "não se mova",
        ] {
            assert!(asks_to_stop(s), "{s:?}");
        }
        for s in [
            "Brake status?",
            "Emergency exits on the map?",
            "Para adelante dos metros",
            "para a esquerda",
            "Chega mais perto da parede",
            "Basta andare avanti di un metro",
            "the turtle did not stop",
            "why did it stop",
        ] {
            assert!(!asks_to_stop(s), "{s:?}");
        }
    }

    #[test]
    fn a_long_request_that_opens_with_stop_is_not_one() {
        assert!(!asks_to_stop(
            "stop words are removed from the text before the nodes index it for search"
        ));
        assert!(asks_to_stop("stop, then tell me where you are"));
    }
}
