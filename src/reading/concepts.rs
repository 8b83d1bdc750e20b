//! What an operator's request says, read without a model: which acts it asks for (move,
//! turn, reset, …), which it forbids ("don't move"), and which it only asks about ("is
//! it moving?"), in English, Spanish, French, German, Italian and Portuguese.
//!
//! A request is cut into clauses (at punctuation and at "but", "then", "and" and their
//! translations). A clause that holds a negation ("don't", "no", "ne … pas", "nicht",
//! "never", …) forbids every act it names; a clause that opens with a question word
//! ("how", "is", "dónde", "wo", …) asks about them; any other clause asks for them.
//! "Can you …" and "please …" are requests, not questions.
//!
//! Words are compared folded (lowercase, no accents) and by prefix, so "muévete",
//! "muevas" and "mueve" all meet "muev". The lexicon is of acts a robot performs, not of
//! any one request's wording.
//!
//! The words are data: one file per language, `data/words/<lang>.toml`, compiled in, a
//! section per act (`[acts.move]`, …) and per kind of word (`[negation]`, `[question]`,
//! …), each opened by the tool or ROS concept that justifies it. Every language's words
//! are read together, so a request that mixes languages is read alike.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::OnceLock;

use serde::Deserialize;

use crate::lexicon::{folded_words, is_number};

/// Something a request may ask the robot to do. Named in the word files in lowercase
/// (`[acts.move]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Deserialize)]
#[serde(rename_all = "lowercase")]
pub(crate) enum Act {
    Move,
    Turn,
    Teleport,
    Pen,
    Reset,
    Spawn,
    Kill,
    Clear,
    Set,
    Publish,
    Call,
    Goal,
    Cancel,
    Forget,
    Stop,
    Fence,
}

/// A direction a motion is asked in. By REP 103 (x forward, z up), a linear amount
/// forward and a turn counter-clockwise (to the left) are positive; backward and
/// clockwise (to the right) are negative.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Deserialize)]
#[serde(rename_all = "lowercase")]
pub(crate) enum Direction {
    Forward,
    Backward,
    Left,
    Right,
}

/// The signs a request's words give a motion: of a linear amount and of a turn (`true`
/// negative), each `None` unless the words name one direction of it and not the other.
/// "Counter-clockwise" is read as its words, so the left list holds "counter".
pub fn signs(request: &str) -> (Option<bool>, Option<bool>) {
    let words = folded_words(request);
    let table = &table().directions;
    let is = |d: Direction, w: &str| table.get(&d).is_some_and(|set| set.contains(w));
    // A right word just after a left one is its other half ("counter clockwise",
    // "gegen den Uhrzeigersinn").
    let says = |d: Direction| {
        words.iter().enumerate().any(|(i, w)| {
            is(d, w)
                && !(d == Direction::Right
                    && words[i.saturating_sub(2)..i]
                        .iter()
                        .any(|b| is(Direction::Left, b)))
        })
    };
    let sign = |plus: Direction, minus: Direction| match (says(plus), says(minus)) {
        (false, true) => Some(true),
        (true, false) => Some(false),
        _ => None,
    };
    (
        sign(Direction::Forward, Direction::Backward),
        sign(Direction::Left, Direction::Right),
    )
}

/// The word files, one per language, compiled in.
const FILES: &[(&str, &str)] = &[
    ("en", include_str!("../../data/words/en.toml")),
    ("es", include_str!("../../data/words/es.toml")),
    ("fr", include_str!("../../data/words/fr.toml")),
    ("de", include_str!("../../data/words/de.toml")),
    ("it", include_str!("../../data/words/it.toml")),
    ("pt", include_str!("../../data/words/pt.toml")),
];

/// One section of a word file: its folded words.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Section {
    words: Vec<String>,
}

/// One language's word file as written; a language may leave a section out.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct WordFile {
    #[serde(default)]
    acts: BTreeMap<Act, Section>,
    stop_at_start: Option<Section>,
    wait_at_start: Option<Section>,
    negation: Option<Section>,
    question: Option<Section>,
    conjunction: Option<Section>,
    disjunction: Option<Section>,
    contrast: Option<Section>,
    sequencer: Option<Section>,
    tell: Option<Section>,
    reference: Option<Section>,
    #[serde(default)]
    direction: BTreeMap<Direction, Section>,
    /// Per kind of the robot's names (`node`, `topic`, ...), its plural words.
    #[serde(default)]
    many: BTreeMap<String, Section>,
    /// Per arithmetic operator (`+`, `-`, `*`, `/`, `^`), the words that say it, each
    /// one or a few words ("mal", "divided by").
    #[serde(default)]
    operator: BTreeMap<String, Section>,
    /// Per English word robots' ROS names are made of (`gripper`, `close`), the words
    /// that say it in this language, as prefixes as `[acts.*]` are.
    #[serde(default)]
    name: BTreeMap<String, Section>,
}

/// The words of every language together.
#[derive(Default)]
struct Words {
    /// Folded word prefixes that name each act. A prefix of three letters or fewer
    /// matches only a whole word.
    acts: BTreeMap<Act, BTreeSet<String>>,
    /// Stop words too ambiguous to count anywhere but at a clause's start ("para" is
    /// also "for", "halte" a German filler, "pare" Portuguese for "stop" and Spanish for
    /// "seem").
    stop_at_start: BTreeSet<String>,
    /// Words that say wait: a stop at a clause's start as `stop_at_start`, unless an
    /// amount follows ("wait 40 seconds" asks for a wait).
    wait_at_start: BTreeSet<String>,
    /// Words that make a clause a negation.
    negations: BTreeSet<String>,
    /// Words that open a question about the world (not a request).
    question_words: BTreeSet<String>,
    /// Words that cut a request into clauses.
    conjunctions: BTreeSet<String>,
    /// Conjunctions that join alternatives.
    disjunctions: BTreeSet<String>,
    /// Words that turn a sentence around ("don't move, just turn"): a clause they open
    /// does not take the negation or the question of the clause before it.
    contrasts: BTreeSet<String>,
    /// Contrasts that only order what is asked ("then", "luego", "dann").
    sequencers: BTreeSet<String>,
    /// Verbs that ask to be told, not to act ("explain how to move it").
    tell: BTreeSet<String>,
    /// Words by which a later part points back at what an earlier one named ("change
    /// it").
    references: BTreeSet<String>,
    /// Whole words that name each direction of a motion (REP 103's signs).
    directions: BTreeMap<Direction, BTreeSet<String>>,
    /// Whole words that say a kind of the robot's names in the plural ("topics",
    /// "servicios"), by kind.
    many: BTreeMap<String, BTreeSet<String>>,
    /// Each operator's phrases (folded words) with its symbol (`arithmetic`).
    operators: Vec<(Vec<String>, char)>,
    /// Folded prefixes that say an English word of ROS names, with that word.
    name_words: Vec<(String, String)>,
}

impl Words {
    fn add(&mut self, file: WordFile) {
        for (act, section) in file.acts {
            self.acts.entry(act).or_default().extend(section.words);
        }
        for (into, section) in [
            (&mut self.stop_at_start, file.stop_at_start),
            (&mut self.wait_at_start, file.wait_at_start),
            (&mut self.negations, file.negation),
            (&mut self.question_words, file.question),
            (&mut self.conjunctions, file.conjunction),
            (&mut self.disjunctions, file.disjunction),
            (&mut self.contrasts, file.contrast),
            (&mut self.sequencers, file.sequencer),
            (&mut self.tell, file.tell),
            (&mut self.references, file.reference),
        ] {
            into.extend(section.into_iter().flat_map(|s| s.words));
        }
        for (d, section) in file.direction {
            self.directions.entry(d).or_default().extend(section.words);
        }
        for (kind, section) in file.many {
            self.many.entry(kind).or_default().extend(section.words);
        }
        for (english, section) in file.name {
            self.name_words
                .extend(section.words.into_iter().map(|w| (w, english.clone())));
        }
        for (symbol, section) in file.operator {
            let Some(symbol) = symbol
                .chars()
                .next()
                .filter(|_| symbol.chars().count() == 1)
            else {
                continue;
            };
            for phrase in section.words {
                self.operators.push((
                    phrase.split_whitespace().map(String::from).collect(),
                    symbol,
                ));
            }
        }
    }
}

/// The words of `data/words/`, parsed once.
fn table() -> &'static Words {
    static TABLE: OnceLock<Words> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut out = Words::default();
        for (lang, text) in FILES {
            // The files ship inside the binary; a unit test parses every one.
            let file: WordFile =
                toml::from_str(text).unwrap_or_else(|e| panic!("data/words/{lang}.toml: {e}"));
            out.add(file);
        }
        out
    })
}

/// How a clause treats an act.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Mood {
    /// Asks for it.
    Asked,
    /// Forbids it.
    Forbidden,
    /// Asks about it.
    Questioned,
}

/// One clause of a request.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Clause {
    /// Its folded words.
    pub words: Vec<String>,
    pub acts: Vec<Act>,
    pub mood: Mood,
}

/// Whether `word` (folded) names `prefix`: by prefix, or whole for short prefixes.
pub(crate) fn word_matches(word: &str, prefix: &str) -> bool {
    if prefix.len() <= 3 {
        word == prefix
    } else {
        word.starts_with(prefix)
    }
}

/// The English words of ROS names that `word` (folded) says in another language
/// (`[name.*]`: "cierra" says `close`, "Greifer" `gripper`), so a request in any of the
/// six languages meets the names robots are given in English. Empty for a word that
/// is itself English or no such word.
pub(crate) fn says_in_names(word: &str) -> Vec<&'static str> {
    let mut out: Vec<&'static str> = table()
        .name_words
        .iter()
        .filter(|(prefix, english)| word != english && word_matches(word, prefix))
        .map(|(_, english)| english.as_str())
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// `words` (folded) with the English name words each says (`says_in_names`) after it.
pub(crate) fn with_name_words<'a>(words: impl IntoIterator<Item = &'a String>) -> Vec<String> {
    words
        .into_iter()
        .flat_map(|w| {
            std::iter::once(w.clone()).chain(says_in_names(w).into_iter().map(String::from))
        })
        .collect()
}

/// Whether `first`, opening a clause, asks the robot to stop (`stop_at_start`), or says
/// wait with no amount (`next`) after it (`wait_at_start`).
fn stops_at_start(table: &Words, first: &str, next: Option<&String>) -> bool {
    table.stop_at_start.contains(first)
        || (table.wait_at_start.contains(first) && !next.is_some_and(|n| is_number(n)))
}

/// The acts `words` (folded) name.
pub(crate) fn acts_of(words: &[String]) -> Vec<Act> {
    let table = table();
    let mut acts: Vec<Act> = table
        .acts
        .iter()
        .filter(|(_, prefixes)| {
            words
                .iter()
                .any(|w| prefixes.iter().any(|p| word_matches(w, p)))
        })
        .map(|(a, _)| *a)
        .collect();
    if words
        .first()
        .is_some_and(|w| stops_at_start(table, w, words.get(1)))
    {
        acts.push(Act::Stop);
    }
    acts.sort();
    acts.dedup();
    acts
}

/// The clauses of `request`. Within one sentence a negation or a question carries on
/// into the clauses that follow ("don't move or turn", "is it moving or turning?",
/// "do not move, rotate or teleport it") unless one opens with a contrast ("but",
/// "just", "instead"): read this way a mistake blocks a motion, never allows one.
pub(crate) fn clauses(request: &str) -> Vec<Clause> {
    let table = table();
    let mut out = Vec::new();
    for sentence in request.split_inclusive(['.', ';', '!', '?', '\n']) {
        let question_mark = sentence.trim_end().ends_with('?');
        let mut carried: Option<Mood> = None;
        // Clauses joined by "or": a negation anywhere among them governs them all
        // ("bewege oder drehe sie nicht").
        let mut alternatives = out.len();
        for part in sentence.split([',', ':']) {
            let mut current: Vec<String> = Vec::new();
            let mut contrast = false;
            for w in folded_words(part) {
                if table.conjunctions.contains(w.as_str()) {
                    carried = push_clause(
                        &mut out,
                        std::mem::take(&mut current),
                        question_mark,
                        carried,
                        contrast,
                    );
                    forbid_alternatives(&mut out, alternatives);
                    if !table.disjunctions.contains(w.as_str()) {
                        alternatives = out.len();
                    }
                    contrast = table.contrasts.contains(w.as_str());
                } else {
                    if current.is_empty() && table.contrasts.contains(w.as_str()) {
                        contrast = true;
                    }
                    current.push(w);
                }
            }
            carried = push_clause(&mut out, current, question_mark, carried, contrast);
            forbid_alternatives(&mut out, alternatives);
        }
    }
    out
}

/// When the newest clause forbids, so do the alternatives before it (from `from` on).
fn forbid_alternatives(out: &mut [Clause], from: usize) {
    if out.last().is_some_and(|c| c.mood == Mood::Forbidden) {
        for c in out.iter_mut().skip(from) {
            if c.mood == Mood::Asked {
                c.mood = Mood::Forbidden;
            }
        }
    }
}

/// Add the clause of `words`; the mood the next clause of the sentence may take on.
fn push_clause(
    out: &mut Vec<Clause>,
    words: Vec<String>,
    question_mark: bool,
    carried: Option<Mood>,
    contrast: bool,
) -> Option<Mood> {
    if words.is_empty() {
        return carried;
    }
    let table = table();
    let acts = acts_of(&words);
    let negated = words.iter().any(|w| table.negations.contains(w.as_str()));
    // A question word before the first act ("how do I move", "explain how to move").
    let first_act = words
        .iter()
        .position(|w| !acts_of(std::slice::from_ref(w)).is_empty())
        .unwrap_or(words.len());
    let asks_about = words[..first_act]
        .iter()
        .any(|w| table.question_words.contains(w.as_str()) || table.tell.contains(w.as_str()))
        && !words
            .first()
            .is_some_and(|w| stops_at_start(table, w, words.get(1)));
    let inherited = carried.filter(|_| !contrast);
    let mood = if negated || inherited == Some(Mood::Forbidden) {
        Mood::Forbidden
    } else if asks_about
        || inherited == Some(Mood::Questioned)
        || (question_mark && acts.is_empty())
    {
        Mood::Questioned
    } else {
        Mood::Asked
    };
    // "Avoid moving": avoiding is an act of its own (fencing a name off); what it is
    // said of is forbidden.
    if acts.contains(&Act::Fence) && acts.len() > 1 && mood == Mood::Asked {
        let others: Vec<Act> = acts.iter().copied().filter(|a| *a != Act::Fence).collect();
        out.push(Clause {
            words: words.clone(),
            acts: others,
            mood: Mood::Forbidden,
        });
        out.push(Clause {
            words,
            acts: vec![Act::Fence],
            mood: Mood::Asked,
        });
        return Some(Mood::Forbidden);
    }
    let mut acts = acts;
    if mood == Mood::Asked && !question_mark {
        for act in motion_by_amount(&words) {
            if !acts.contains(&act) {
                acts.push(act);
            }
        }
    }
    out.push(Clause { words, acts, mood });
    (mood != Mood::Asked).then_some(mood)
}

/// The motions a clause asks for by a direction and an amount alone, with no verb of
/// motion: a linear direction (REP 103's x, `Direction::Forward`, `Backward`) and a
/// length ("reverse 20 inches", "back 30 cm") is a move; a turning direction and an
/// angle ("45 degrees to the right") is a turn. Either alone is none: "back" and "left"
/// say other things too.
fn motion_by_amount(words: &[String]) -> Vec<Act> {
    let table = &table().directions;
    let says = |ds: [Direction; 2]| {
        words.iter().any(|w| {
            ds.iter()
                .any(|d| table.get(d).is_some_and(|set| set.contains(w)))
        })
    };
    let kinds: Vec<&str> = crate::units::amounts(&words.join(" "))
        .iter()
        .map(|a| a.unit.kind.as_str())
        .collect();
    let mut acts = Vec::new();
    if kinds.contains(&"length") && says([Direction::Forward, Direction::Backward]) {
        acts.push(Act::Move);
    }
    if kinds.contains(&"angle") && says([Direction::Left, Direction::Right]) {
        acts.push(Act::Turn);
    }
    acts
}

/// How a folded word joins what follows to what came before: `Some(true)` when it
/// only chains ("and", "then", "puis"), `Some(false)` when it joins alternatives or
/// turns the sentence around ("or", "but"), `None` when it is no conjunction.
pub fn chains(word: &str) -> Option<bool> {
    let table = table();
    table.conjunctions.contains(word).then(|| {
        !table.disjunctions.contains(word)
            && (!table.contrasts.contains(word) || table.sequencers.contains(word))
    })
}

/// Whether a folded word can open a request of its own: it asks ("what", "wo"), asks to
/// be told ("tell", "dime") or names an act ("move", "gira").
pub(crate) fn opens_request(word: &str) -> bool {
    let table = table();
    table.question_words.contains(word) || tells(word) || asks_act(word)
}

/// Whether a folded word only orders what is asked ("then", "luego", "dann"): said
/// between two asks, it cuts even where the second leaves its verb unsaid.
pub(crate) fn sequences(word: &str) -> bool {
    table().sequencers.contains(word)
}

/// Whether a folded word names an act ("move", "gira", "set").
pub(crate) fn asks_act(word: &str) -> bool {
    !acts_of(std::slice::from_ref(&word.to_string())).is_empty()
}

/// Whether a folded word asks to be told ("show", "tell", "describe").
pub(crate) fn tells(word: &str) -> bool {
    table().tell.contains(word)
}

/// The kinds of the robot's names (`node`, `topic`, `service`, `action`, `type`) that
/// `words` (folded) say in the plural: "which topics carry turtle data?" asks about
/// several topics, not one.
pub(crate) fn kinds_in_plural(words: &[String]) -> Vec<&'static str> {
    table()
        .many
        .iter()
        .filter(|(_, plural)| words.iter().any(|w| plural.contains(w.as_str())))
        .map(|(kind, _)| kind.as_str())
        .collect()
}

/// The words that say an arithmetic operator, each a phrase of folded words with the
/// operator's symbol (`arithmetic`).
pub(crate) fn operators() -> &'static [(Vec<String>, char)] {
    &table().operators
}

/// Whether `word` (folded) points back at what an earlier part of the request named.
pub(crate) fn refers_back(word: &str) -> bool {
    table().references.contains(word)
}

/// Acts the request asks for (in some clause, and forbidden in none).
pub(crate) fn asked_acts(clauses: &[Clause]) -> Vec<Act> {
    let mut acts: Vec<Act> = clauses
        .iter()
        .filter(|c| c.mood == Mood::Asked)
        .flat_map(|c| c.acts.iter().copied())
        .filter(|a| {
            !clauses
                .iter()
                .any(|c| c.mood == Mood::Forbidden && c.acts.contains(a))
        })
        .collect();
    acts.sort();
    acts.dedup();
    acts
}

/// Whether the request, read on its own, asks the robot to stop.
pub(crate) fn asks_to_stop(request: &str) -> bool {
    asked_acts(&clauses(request)).contains(&Act::Stop)
}

/// Whether the operator's `request` asks the robot to stop: a stop phrase
/// (`stop_intent`, the words operators use) or a clause that asks for the stop act
/// (`asks_to_stop`). What every channel checks before anything else, the agent's run
/// included.
pub(crate) fn operator_stops(request: &str) -> bool {
    crate::stop_intent::asks_to_stop(request) || asks_to_stop(request)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn asked(q: &str) -> Vec<Act> {
        asked_acts(&clauses(q))
    }

    #[test]
    fn every_word_file_parses_with_no_empty_section() {
        for (lang, text) in FILES {
            let file: WordFile =
                toml::from_str(text).unwrap_or_else(|e| panic!("data/words/{lang}.toml: {e}"));
            let mut sections: Vec<(String, Vec<String>)> = file
                .acts
                .into_iter()
                .map(|(a, s)| (format!("acts.{a:?}"), s.words))
                .collect();
            // A language may have no stop word too ambiguous to count but at a
            // clause's start.
            if let Some(section) = file.stop_at_start {
                sections.push(("stop_at_start".to_string(), section.words));
            }
            for (name, section) in [
                ("wait_at_start", file.wait_at_start),
                ("negation", file.negation),
                ("question", file.question),
                ("conjunction", file.conjunction),
                ("disjunction", file.disjunction),
                ("contrast", file.contrast),
                ("sequencer", file.sequencer),
                ("tell", file.tell),
                ("reference", file.reference),
            ] {
                let section = section.unwrap_or_else(|| panic!("{lang}: no [{name}]"));
                sections.push((name.to_string(), section.words));
            }
            for (kind, section) in file.many {
                assert!(
                    crate::reading::select::NAME_KINDS.contains(&kind.as_str()),
                    "{lang}: [many.{kind}] is no kind of the robot's names"
                );
                sections.push((format!("many.{kind}"), section.words));
            }
            for (english, section) in file.name {
                assert!(
                    english.chars().all(|c| c.is_ascii_lowercase()),
                    "{lang}: [name.{english}] is no word of English names"
                );
                sections.push((format!("name.{english}"), section.words));
            }
            for (symbol, section) in &file.operator {
                assert!(
                    ["+", "-", "*", "/", "^"].contains(&symbol.as_str()),
                    "{lang}: [operator.{symbol:?}] is no operator the evaluator reads"
                );
                for w in &section.words {
                    assert!(
                        !w.trim().is_empty() && crate::lexicon::fold(w) == *w,
                        "{lang}: [operator.{symbol:?}] {w:?} is not folded"
                    );
                }
            }
            for (name, words) in sections {
                assert!(!words.is_empty(), "{lang}: [{name}] is empty");
                for w in words {
                    // Compared folded: a word written otherwise would never match.
                    assert!(
                        !w.is_empty() && crate::lexicon::fold(&w) == w && !w.contains(' '),
                        "{lang}: [{name}] {w:?} is not one folded word"
                    );
                }
            }
            // Each section says first what justifies it.
            let lines: Vec<&str> = text.lines().collect();
            for (i, line) in lines.iter().enumerate() {
                if line.starts_with('[') {
                    assert!(
                        lines.get(i + 1).is_some_and(|l| l.starts_with("# ")),
                        "{lang}: {line} opens without a comment"
                    );
                }
            }
        }
        let table = table();
        for act in [
            Act::Move,
            Act::Turn,
            Act::Teleport,
            Act::Pen,
            Act::Reset,
            Act::Spawn,
            Act::Kill,
            Act::Clear,
            Act::Set,
            Act::Publish,
            Act::Call,
            Act::Goal,
            Act::Cancel,
            Act::Forget,
            Act::Stop,
            Act::Fence,
        ] {
            assert!(
                table.acts.get(&act).is_some_and(|w| !w.is_empty()),
                "{act:?}"
            );
        }
        assert_eq!(table.acts.len(), 16);
    }

    #[test]
    fn a_word_in_another_language_says_the_english_word_of_names() {
        assert_eq!(says_in_names("chiudete"), ["close"]);
        assert_eq!(says_in_names("greifer"), ["gripper"]);
        assert_eq!(says_in_names("ouvrez"), ["open"]);
        // An English word, or no word of names, says nothing more.
        assert!(says_in_names("close").is_empty());
        assert!(says_in_names("tavolo").is_empty());
        let words = with_name_words(&folded_words("Öffne das Ventil"));
        assert_eq!(words, ["offne", "open", "das", "ventil"]);
    }

    #[test]
    fn requests_negations_and_questions() {
        assert_eq!(asked("move the turtle 3 meters ahead"), [Act::Move]);
        assert!(asked("don't move the turtle").is_empty());
        assert!(asked("do not move the turtle").is_empty());
        assert!(asked("how much battery is left?").is_empty());
        assert!(asked("is the turtle moving?").is_empty());
        assert_eq!(asked("can you move the turtle?"), [Act::Move]);
        assert_eq!(asked("move forward but don't turn"), [Act::Move]);
        assert_eq!(asked("stop the turtle now"), [Act::Stop]);
        assert!(asks_to_stop("STOP!") && asks_to_stop("halt") && !asks_to_stop("don't stop"));
        assert!(!asks_to_stop("why did it stop?"));
    }

    #[test]
    fn a_direction_with_an_amount_of_its_motion_asks_for_it() {
        assert_eq!(asked("back it up 25 cm"), [Act::Move]);
        assert_eq!(asked("40 Zentimeter zurück"), [Act::Move]);
        assert_eq!(asked("ten degrees to the left please"), [Act::Turn]);
        // Either alone, or asked about, or of the other motion, is no act.
        assert!(asked("what is left of the 3 meters?").is_empty());
        assert!(asked("the dock is 2 meters back").is_empty());
        assert!(asked("is it 30 cm back?").is_empty());
        assert!(asked("5 degrees ahead").is_empty());
    }

    #[test]
    fn negations_and_questions_reach_every_act_they_govern() {
        for q in [
            "don't move or turn the turtle",
            "do not move, rotate or teleport it",
            "it shouldn't move",
            "you can't turn it",
            "is it moving or turning?",
            "explain how to move the turtle",
            "tell me how to turn it",
            "avoid moving the turtle",
            "bewege oder drehe die Schildkröte nicht",
        ] {
            let acts = asked(q);
            assert!(
                !acts.contains(&Act::Move) && !acts.contains(&Act::Turn),
                "{q}: {acts:?}"
            );
        }
        assert_eq!(asked("don't move, just turn left"), [Act::Turn]);
        assert_eq!(asked("don't turn but move forward 1 m"), [Act::Move]);
        assert_eq!(
            asked("move forward, then turn left"),
            [Act::Move, Act::Turn]
        );
        assert_eq!(asked("Bewege den Roboter 3 Meter nach vorn"), [Act::Move]);
    }

    #[test]
    fn other_languages() {
        assert_eq!(
            asked("Bitte bewege die Schildkröte zwei Meter"),
            [Act::Move]
        );
        assert!(asked("Bewege die Schildkröte nicht").is_empty());
        assert_eq!(asked("mueve el robot dos metros adelante"), [Act::Move]);
        assert!(asked("no muevas la tortuga").is_empty());
        assert_eq!(asked("fais tourner la tortue de 90 degrés"), [Act::Turn]);
        assert!(asked("ne bouge pas la tortue").is_empty());
        assert_eq!(asked("gira la tartaruga di 90 gradi"), [Act::Turn]);
        assert!(
            asks_to_stop("para la tortuga") && asks_to_stop("arrête") && asks_to_stop("Stopp!")
        );
        assert!(!asks_to_stop("avanza 2 metros para probar"));
        // A wait with an amount is a wait; without one, a stop.
        assert!(!operator_stops("wait 20 seconds, then take a picture"));
        assert!(!operator_stops("aspetta 2 secondi"));
        assert!(operator_stops("wait, the cable is caught") && operator_stops("warte!"));
        assert!(asked("¿dónde se encuentra el robot ahora?").is_empty());
    }
}
