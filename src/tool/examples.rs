//! The example requests the shipped tools come with: what an operator says when the tool
//! is the one to call, one data file per language (`data/examples/<lang>.toml`, a list
//! per tool name), compiled in. `ToolSpec::new` gives a tool the examples of its name;
//! declared tool files and robot prompt files add their own. Tool choice compares a
//! request with them by meaning (`agent::select`, with `embed`).

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
    }
}
