//! What the agent says to a request it made no call for. A small model's own reply to a
//! greeting or a thank-you is rarely about it ("function_name1", "This is a test of your
//! patience"), so the reply is the agent's: the request is matched by meaning to the
//! nearest kind of small talk (a greeting, thanks or a farewell, who the agent is, what
//! it can do: `data/replies/<lang>.toml`, each kind's examples in every language), and
//! answered with that kind's line in the request's language. What the agent can do is
//! read from the robot's tools. A request near no kind is told that no tool was used, so
//! an act the robot cannot do is never answered as if it were done.
//!
//! Without the sentence encoder the model's own reply stands.

use std::collections::BTreeSet;
use std::sync::OnceLock;

use crate::lexicon::folded_words;
use crate::tool::examples::{replies, ReplyKind};
use crate::tool::Effect;

use super::language::Language;
use super::meaning::Meaning;

/// A request must be at least this near (cosine) a kind's nearest example to be taken
/// for that kind: the sentence encoder puts paraphrases above it and unrelated
/// sentences well below.
const NEAR: f64 = 0.5;

/// The kind answered when no kind is near.
const OTHER: &str = "other";

/// The robot's tools as the replies describe them.
pub struct Tools<'a> {
    /// Each tool's name and effect, in the registry's order.
    pub each: Vec<(&'a str, Effect)>,
}

/// The kind of small talk `request` is (its name in `data/replies`), by meaning, and the
/// language of the example it is nearest (`None` when near none).
pub fn kind(meaning: &Meaning, request: &str) -> (&'static str, Option<&'static str>) {
    let mut best: Option<(&'static str, &'static str, f64)> = None;
    for (lang, name, k) in replies() {
        let near = meaning.nearest(request, &k.examples);
        if near >= NEAR && best.is_none_or(|(_, _, b)| near > b) {
            best = Some((name.as_str(), lang, near));
        }
    }
    best.map_or((OTHER, None), |(name, lang, _)| (name, Some(lang)))
}

/// The agent's reply to `request`: in `set` when the operator set a language, else in
/// the request's when it shows one, else in that of the small talk examples that share
/// the most of its words ("thanks, bye": English's "bye"), else in that of the example
/// it is nearest by meaning (a short "merci beaucoup" shows too little of its language
/// to tell), else in English.
pub fn reply(meaning: &Meaning, request: &str, set: Option<Language>, tools: &Tools) -> String {
    let (kind, near) = kind(meaning, request);
    let language = set
        .or_else(|| Language::of(request))
        .or_else(|| by_examples(request))
        .or_else(|| near.and_then(|l| Language::parse(l).ok()))
        .unwrap_or_default();
    say(kind, language, tools)
}

/// The language whose small talk examples (every kind's) hold more of `request`'s words
/// than any other language's do; none on a tie or when none holds one. Nearness by
/// meaning crosses languages, so the nearest example of "thanks, bye" was German.
fn by_examples(request: &str) -> Option<Language> {
    let words = folded_words(request);
    let held: Vec<(&str, usize)> = example_words()
        .iter()
        .map(|(lang, set)| (*lang, words.iter().filter(|w| set.contains(*w)).count()))
        .collect();
    let top = held.iter().map(|(_, n)| *n).max().filter(|n| *n > 0)?;
    match held.iter().filter(|(_, n)| *n == top).collect::<Vec<_>>()[..] {
        [(lang, _)] => Language::parse(lang).ok(),
        _ => None,
    }
}

/// Each language's small talk words, every kind's examples together (a word counts
/// once), read once.
fn example_words() -> &'static [(&'static str, BTreeSet<String>)] {
    static WORDS: OnceLock<Vec<(&'static str, BTreeSet<String>)>> = OnceLock::new();
    WORDS.get_or_init(|| {
        let mut theirs: Vec<(&'static str, BTreeSet<String>)> = Vec::new();
        for (lang, _, k) in replies() {
            let each = k.examples.iter().flat_map(|e| folded_words(e));
            match theirs.iter_mut().find(|(l, _)| l == lang) {
                Some((_, set)) => set.extend(each),
                None => theirs.push((lang, each.collect())),
            }
        }
        theirs
    })
}

/// The line of `kind` in `language` (English when the language lacks it), its
/// placeholders filled from `tools`.
pub fn say(kind: &str, language: Language, tools: &Tools) -> String {
    let line = |lang: &str| -> Option<&'static ReplyKind> {
        replies()
            .iter()
            .find(|(l, n, _)| *l == lang && n == kind)
            .map(|(_, _, k)| k)
    };
    let Some(k) = line(language.code()).or_else(|| line("en")) else {
        return String::new();
    };
    let reads: Vec<&str> = tools
        .each
        .iter()
        .filter(|(_, e)| *e == Effect::Observes)
        .map(|(n, _)| *n)
        .collect();
    let acts: Vec<&str> = tools
        .each
        .iter()
        .filter(|(_, e)| *e != Effect::Observes)
        .map(|(n, _)| *n)
        .collect();
    k.say
        .replace("{count}", &tools.each.len().to_string())
        .replace("{reads}", &grouped(&reads))
        .replace("{acts}", &grouped(&acts))
}

/// Tool names as an operator reads them: those that share a prefix (`turtle_move`,
/// `turtle_rotate`) as one entry, the prefix then what each does ("turtle: move,
/// rotate"), at most `SHOWN` of them and how many more; a tool alone in its words
/// ("robot status"). Entries in the order met, apart by "; ".
fn grouped(names: &[&str]) -> String {
    let mut out: Vec<(&str, Vec<&str>)> = Vec::new();
    for n in names {
        let (p, rest) = n.split_once('_').unwrap_or((n, ""));
        match out.iter_mut().find(|(q, _)| *q == p) {
            Some((_, v)) => v.push(rest),
            None => out.push((p, vec![rest])),
        }
    }
    out.into_iter()
        .map(|(p, v)| match v.as_slice() {
            [""] => p.to_string(),
            [one] => format!("{p} {}", one.replace('_', " ")),
            _ => {
                // A tool named by the prefix alone, beside others that share it, says
                // the prefix ("arm: arm, move").
                let words = |r: &str| match r {
                    "" => p.to_string(),
                    r => r.replace('_', " "),
                };
                let mut each: Vec<String> = v.iter().take(SHOWN).map(|r| words(r)).collect();
                if v.len() > SHOWN {
                    each.push(format!("+{}", v.len() - SHOWN));
                }
                format!("{p}: {}", each.join(", "))
            }
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// The most tools of one prefix a line names.
const SHOWN: usize = 6;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_too_short_to_show_its_language_is_read_by_the_examples_words() {
        assert_eq!(by_examples("ok thanks, bye now"), Some(Language::English));
        assert_eq!(by_examples("tschüss!"), Some(Language::German));
        assert_eq!(by_examples("xyzzy"), None);
    }

    fn tools() -> Tools<'static> {
        Tools {
            each: vec![
                ("arm_joints", Effect::Observes),
                ("arm_limits", Effect::Observes),
                ("gripper_state", Effect::Observes),
                ("arm_move", Effect::Actuates),
                ("robot_stop", Effect::Stops),
            ],
        }
    }

    #[test]
    fn a_line_is_filled_from_the_robots_tools() {
        let abilities = say("abilities", Language::English, &tools());
        assert!(
            abilities.contains("(arm: joints, limits; gripper state)")
                && abilities.contains("(arm move; robot stop)"),
            "{abilities}"
        );
        assert!(say("identity", Language::German, &tools()).contains(" 5 "));
        assert!(!say("other", Language::Spanish, &tools()).contains('{'));
    }

    #[test]
    fn every_line_fills_every_placeholder() {
        for (lang, kind, _) in replies() {
            let language = Language::parse(lang).expect("a shipped language");
            let line = say(kind, language, &tools());
            assert!(
                !line.contains('{') && !line.contains('}'),
                "{lang} {kind}: {line}"
            );
        }
    }
}
