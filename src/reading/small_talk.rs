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
    let mut held: Vec<(&str, usize)> = Vec::new();
    for (lang, _, k) in replies() {
        let theirs: Vec<String> = k.examples.iter().flat_map(|e| folded_words(e)).collect();
        let n = words.iter().filter(|w| theirs.contains(w)).count();
        match held.iter_mut().find(|(l, _)| l == lang) {
            Some((_, m)) => *m += n,
            None => held.push((lang, n)),
        }
    }
    let top = held.iter().map(|(_, n)| *n).max().filter(|n| *n > 0)?;
    match held.iter().filter(|(_, n)| *n == top).collect::<Vec<_>>()[..] {
        [(lang, _)] => Language::parse(lang).ok(),
        _ => None,
    }
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
    let listed = grouped(&reads).join(", ");
    k.say
        .replace("{count}", &tools.each.len().to_string())
        .replace("{reads}", &listed)
        .replace("{acts}", &acts.join(", "))
}

/// Tool names as a line lists them: those that share a prefix (`ros_topic_list`,
/// `ros_node_list`) as one entry with their count (`ros_* (2)`), in the order met.
fn grouped(names: &[&str]) -> Vec<String> {
    let prefix = |n: &str| {
        n.split_once('_')
            .map_or(n.to_string(), |(p, _)| p.to_string())
    };
    let mut out: Vec<(String, Vec<&str>)> = Vec::new();
    for n in names {
        let p = prefix(n);
        match out.iter_mut().find(|(q, _)| *q == p) {
            Some((_, v)) => v.push(n),
            None => out.push((p, vec![n])),
        }
    }
    out.into_iter()
        .map(|(p, v)| match v.as_slice() {
            [one] => one.to_string(),
            _ => format!("{p}_* ({})", v.len()),
        })
        .collect()
}

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
            abilities.contains("(arm_* (2), gripper_state)")
                && abilities.contains("(arm_move, robot_stop)"),
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
