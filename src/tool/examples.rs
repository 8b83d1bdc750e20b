//! The example requests the shipped tools come with: what an operator says when the tool
//! is the one to call, one data file per language (`data/examples/<lang>.toml`, a list
//! per tool name), compiled in. `ToolSpec::new` gives a tool the examples of its name;
//! declared tool files and robot prompt files add their own. Tool choice compares a
//! request with them by meaning (`reading::select`, with `embed`).
//!
//! The answer tool's (`reply`) are the small-talk kinds' (`data/replies/<lang>.toml`:
//! per kind, its examples and what the agent says to it, `replies`).

use std::collections::HashMap;
use std::sync::OnceLock;

const FILES: &[(&str, &str)] = &[
    ("en", include_str!("../../data/examples/en.toml")),
    ("es", include_str!("../../data/examples/es.toml")),
    ("fr", include_str!("../../data/examples/fr.toml")),
    ("de", include_str!("../../data/examples/de.toml")),
    ("it", include_str!("../../data/examples/it.toml")),
    ("pt", include_str!("../../data/examples/pt.toml")),
];

const REPLIES: &[(&str, &str)] = &[
    ("en", include_str!("../../data/replies/en.toml")),
    ("es", include_str!("../../data/replies/es.toml")),
    ("fr", include_str!("../../data/replies/fr.toml")),
    ("de", include_str!("../../data/replies/de.toml")),
    ("it", include_str!("../../data/replies/it.toml")),
    ("pt", include_str!("../../data/replies/pt.toml")),
];

/// One kind of request the agent answers without a tool, in one language.
#[derive(Debug, Clone, serde::Deserialize)]
pub struct ReplyKind {
    #[serde(default)]
    pub examples: Vec<String>,
    pub say: String,
}

/// The small-talk kinds of each language: (language code, kind name, kind).
pub fn replies() -> &'static [(&'static str, String, ReplyKind)] {
    static KINDS: OnceLock<Vec<(&'static str, String, ReplyKind)>> = OnceLock::new();
    KINDS.get_or_init(|| {
        let mut out = Vec::new();
        for (lang, text) in REPLIES {
            // Shipped inside the binary; a unit test parses every one.
            let parsed: std::collections::BTreeMap<String, ReplyKind> =
                toml::from_str(text).unwrap_or_else(|e| panic!("data/replies/{lang}.toml: {e}"));
            out.extend(parsed.into_iter().map(|(kind, k)| (*lang, kind, k)));
        }
        out
    })
}

fn table() -> &'static HashMap<String, Vec<String>> {
    static TABLE: OnceLock<HashMap<String, Vec<String>>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut out: HashMap<String, Vec<String>> = HashMap::new();
        for (lang, text) in FILES {
            // The files ship inside the binary; a unit test parses every one.
            let parsed: HashMap<String, Vec<String>> =
                toml::from_str(text).unwrap_or_else(|e| panic!("data/examples/{lang}.toml: {e}"));
            for (tool, examples) in parsed {
                out.entry(tool).or_default().extend(examples);
            }
        }
        let small_talk = replies()
            .iter()
            .flat_map(|(_, _, k)| k.examples.iter().cloned());
        out.entry("reply".to_string())
            .or_default()
            .extend(small_talk);
        out
    })
}

/// The shipped examples of the tool `name`, every language (none for a tool the files do
/// not name).
pub fn shipped(name: &str) -> Vec<String> {
    table().get(name).cloned().unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_file_parses_and_names_only_lists_of_sentences() {
        for (lang, text) in FILES {
            let parsed: HashMap<String, Vec<String>> =
                toml::from_str(text).unwrap_or_else(|e| panic!("data/examples/{lang}.toml: {e}"));
            for (tool, examples) in parsed {
                assert!(!examples.is_empty(), "{lang}: {tool} has an empty list");
                assert!(
                    examples
                        .iter()
                        .all(|e| !e.trim().is_empty() && e.len() < 200),
                    "{lang}: {tool}"
                );
            }
        }
        assert!(!shipped("ros_topic_list").is_empty());
        assert!(shipped("no_such_tool").is_empty());
        assert!(shipped("reply").len() >= 6 * 4);
    }

    #[test]
    fn every_language_has_every_small_talk_kind() {
        let kinds = |lang: &str| -> Vec<&str> {
            replies()
                .iter()
                .filter(|(l, _, _)| *l == lang)
                .map(|(_, k, _)| k.as_str())
                .collect()
        };
        let en = kinds("en");
        assert!(en.contains(&"other") && en.len() >= 4, "{en:?}");
        for (lang, _) in REPLIES {
            assert_eq!(kinds(lang), en, "{lang}");
        }
        for (lang, kind, k) in replies() {
            assert!(!k.say.trim().is_empty(), "{lang} {kind}");
            assert_eq!(k.examples.is_empty(), kind == "other", "{lang} {kind}");
        }
    }
}
