//! Names off limits: the operator's deny-list (and the patterns the model may add, never
//! remove), checked on ROS names in their canonical form, and applied to text as
//! redaction.
//!
//! A name is judged as a terminal would show it: escape sequences, control characters and
//! Unicode format characters (category Cf: zero-width space and joiners, bidi controls,
//! the BOM, the soft hyphen) are dropped first (`visible`), so `/turtle\u{200B}1` is
//! `/turtle1`, and patterns match without regard to case. It is then judged in every
//! form it could be meant in: as written, trimmed, made absolute (`secret` and
//! ` /secret/` are `/secret`), for logger names with dots as slashes (`secret_node.worker`
//! is `/secret_node/worker`), in DDS spelling (`rt/secret`) or as a private name
//! (`~/secret`), and by every name it lies under (`/secret/cmd` is under `/secret`). A
//! pattern matching any form denies it. A node's parameter is named `/node/parameter`
//! (`parameter_name`), so denying `/turtlesim/background_r` denies that parameter and
//! denying `/turtlesim` denies them all.
//!
//! Redaction finds name-like words in the visible text (a log line, an error, an answer)
//! and replaces the denied ones, hidden characters inside them included, with
//! `[off limits]`; in JSON, array items that are denied names (or objects named by one)
//! are dropped and every string is redacted. The terminal's cleaning (`ui::term::clean`)
//! is `visible` too, so what is printed is what was judged.
//!
//! The ROS boundary (`ros::boundary`) and the policy (`tool::policy`) both consult the same
//! fence, so a name a tool builds itself meets it exactly as one the model wrote.
//! Depends on nothing else in the crate.

use std::borrow::Cow;
use std::sync::{LazyLock, RwLock};

use regex::{Regex, RegexBuilder};
use serde_json::Value;

/// What a denied name becomes in text.
pub const REDACTED: &str = "[off limits]";

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FenceError {
    #[error("invalid pattern {pattern:?}: {message}")]
    Pattern { pattern: String, message: String },
    #[error("pattern {0:?} would deny ordinary names (it matches /{1}); write one that names what to stay away from, e.g. \"^/camera\"")]
    TooBroad(String, String),
    #[error("{0:?} is not a ROS name: use letters, digits, _ and / (e.g. /turtle1/pose)")]
    BadName(String),
}

/// The deny-list (see the module header).
#[derive(Debug, Default)]
pub struct Fence {
    operator: Vec<Regex>,
    model: RwLock<Vec<Regex>>,
}

/// A deny pattern: case does not matter (`/Turtle1` is `/turtle1` to the fence).
fn compile(p: &str) -> Result<Regex, FenceError> {
    RegexBuilder::new(p)
        .case_insensitive(true)
        .build()
        .map_err(|e| FenceError::Pattern {
            pattern: p.to_string(),
            message: regex_error(&e),
        })
}

/// What is wrong with a pattern, in one line: the regex crate draws a multi-line caret
/// diagram, and its last line says what.
pub(crate) fn regex_error(e: &regex::Error) -> String {
    e.to_string()
        .lines()
        .rfind(|l| !l.trim().is_empty())
        .unwrap_or("invalid regex")
        .trim_start_matches("error: ")
        .to_string()
}

/// Names that stand for nothing: a pattern that matches one of these matches names in
/// general, not a thing the operator asked to leave alone.
const PROBES: &[&str] = &["x", "zq_7", "a/b/c", "k9/w_4", "Q"];

impl Fence {
    /// The operator's patterns (regexes on names).
    pub fn new(patterns: &[String]) -> Result<Fence, FenceError> {
        Ok(Fence {
            operator: patterns
                .iter()
                .map(|p| compile(p))
                .collect::<Result<_, _>>()?,
            model: RwLock::new(Vec::new()),
        })
    }

    /// Add a pattern on the model's behalf. A pattern that would deny ordinary names
    /// (`.`, `^/`, `.*`) is refused: the model may fence off a thing, not everything.
    pub fn add_model_pattern(&self, pattern: &str) -> Result<(), FenceError> {
        let re = compile(pattern)?;
        if let Some(hit) = PROBES
            .iter()
            .find(|p| variants(p).iter().any(|v| re.is_match(v)))
        {
            return Err(FenceError::TooBroad(pattern.to_string(), hit.to_string()));
        }
        self.model.write().expect("fence lock").push(re);
        Ok(())
    }

    /// Whether any pattern denies `name` in any of its forms (see the module header).
    pub(crate) fn denies(&self, name: &str) -> bool {
        let forms = variants(name);
        let hit = |re: &Regex| forms.iter().any(|f| re.is_match(f));
        self.operator.iter().any(hit) || self.model.read().expect("fence lock").iter().any(hit)
    }

    pub fn is_empty(&self) -> bool {
        self.operator.is_empty() && self.model.read().expect("fence lock").is_empty()
    }

    /// Whether parameter `param` of `node` is denied: its full name (`parameter_name`)
    /// or the node is.
    pub(crate) fn denies_parameter(&self, node: &str, param: &str) -> bool {
        self.denies(node) || self.denies(&parameter_name(node, param))
    }

    /// `text` with every denied name-like word replaced by `[off limits]`. Words are
    /// found in the text as shown (`visible`): a word a hidden character splits is one
    /// word, replaced with the hidden characters inside it.
    pub(crate) fn redact<'a>(&self, text: &'a str) -> Cow<'a, str> {
        if self.is_empty() {
            return Cow::Borrowed(text);
        }
        let shown = visible(text);
        // Where each shown character lies in `text` (when something was hidden).
        let at: Option<Vec<(usize, usize, usize)>> = match &shown {
            Cow::Borrowed(_) => None,
            Cow::Owned(_) => {
                let mut v = 0;
                Some(
                    shown_chars(text)
                        .map(|(i, c)| {
                            let entry = (v, i, i + c.len_utf8());
                            v += c.len_utf8();
                            entry
                        })
                        .collect(),
                )
            }
        };
        let mut out = String::new();
        let mut last = 0;
        for (start, end) in name_words(&shown) {
            if !self.denies(&shown[start..end]) {
                continue;
            }
            let (start, end) = match &at {
                None => (start, end),
                Some(at) => {
                    // A word is never empty: it starts at a shown character and ends
                    // after one.
                    let first = at.partition_point(|e| e.0 < start);
                    let after = at.partition_point(|e| e.0 < end);
                    match (at.get(first), after.checked_sub(1).and_then(|i| at.get(i))) {
                        (Some(a), Some(b)) => (a.1, b.2),
                        _ => continue,
                    }
                }
            };
            out.push_str(&text[last..start]);
            out.push_str(REDACTED);
            last = end;
        }
        if last == 0 {
            return Cow::Borrowed(text);
        }
        out.push_str(&text[last..]);
        Cow::Owned(out)
    }

    /// Redact a JSON value in place: array items that are denied names, or objects whose
    /// name-like fields are, are removed; every other string is redacted. Returns how many
    /// strings or items were hidden.
    pub(crate) fn redact_json(&self, v: &mut Value) -> usize {
        if self.is_empty() {
            return 0;
        }
        match v {
            Value::String(s) => match self.redact(s) {
                Cow::Owned(r) => {
                    *s = r;
                    1
                }
                Cow::Borrowed(_) => 0,
            },
            Value::Array(items) => {
                let before = items.len();
                items.retain(|item| !self.names_denied_item(item));
                let mut n = before - items.len();
                for item in items.iter_mut() {
                    n += self.redact_json(item);
                }
                n
            }
            Value::Object(map) => {
                let mut n = 0;
                // Keys are text too (a map keyed by topic or node).
                if map.keys().any(|k| matches!(self.redact(k), Cow::Owned(_))) {
                    let old = std::mem::take(map);
                    for (k, v) in old {
                        let key = self.redact(&k).into_owned();
                        n += usize::from(key != k);
                        map.insert(key, v);
                    }
                }
                n + map.values_mut().map(|x| self.redact_json(x)).sum::<usize>()
            }
            _ => 0,
        }
    }

    fn names_denied_item(&self, item: &Value) -> bool {
        match item {
            Value::String(s) => self.denies(s),
            Value::Object(map) => ["name", "topic", "node", "service", "action", "parameter"]
                .iter()
                .filter_map(|k| map.get(*k).and_then(Value::as_str))
                .any(|s| self.denies(s)),
            _ => false,
        }
    }
}

/// The canonical form of a ROS name: as shown (`visible`: format and control characters
/// dropped), trimmed, absolute, single slashes, no trailing slash. Names with characters
/// ROS does not allow are an error (`~` private names and `{}` substitutions are not
/// resolved here: they are refused).
pub(crate) fn canonical(name: &str) -> Result<String, FenceError> {
    let shown = visible(name);
    let t = shown.trim();
    let ok = |c: char| c.is_ascii_alphanumeric() || c == '_' || c == '/';
    if t.is_empty() || !t.chars().all(ok) {
        return Err(FenceError::BadName(name.to_string()));
    }
    let parts: Vec<&str> = t.split('/').filter(|p| !p.is_empty()).collect();
    if parts
        .iter()
        .any(|p| p.starts_with(|c: char| c.is_ascii_digit()))
    {
        return Err(FenceError::BadName(name.to_string()));
    }
    Ok(format!("/{}", parts.join("/")))
}

/// The full name of parameter `param` of node `node`, as ROS 1's parameter server keys
/// it: `/turtlesim` and `background_r` give `/turtlesim/background_r`.
pub(crate) fn parameter_name(node: &str, param: &str) -> String {
    format!(
        "/{}/{}",
        node.trim().trim_matches('/'),
        param.trim().trim_start_matches('/')
    )
}

/// Whether `c` is a Unicode format character (general category Cf): zero-width space,
/// non-joiner and joiner, word joiner, bidi marks, embeddings, overrides and isolates,
/// the BOM, the soft hyphen, invisible operators, tag characters and the like.
pub(crate) fn is_format(c: char) -> bool {
    static CF: LazyLock<Regex> = LazyLock::new(|| {
        // The pattern is a constant the regex crate's Unicode tables compile.
        Regex::new(r"\p{Cf}").expect("\\p{Cf} compiles")
    });
    !c.is_ascii() && CF.is_match(c.encode_utf8(&mut [0; 4]))
}

/// Whether a terminal shows nothing for `c` (or `c` starts an escape sequence): control
/// characters but newline and tab, and format characters.
fn hidden(c: char) -> bool {
    (c.is_control() && c != '\n' && c != '\t') || is_format(c)
}

/// `text` as a terminal shows it: escape sequences (CSI `ESC [ … final`, OSC
/// `ESC ] … BEL or ESC \`), control characters but newline and tab, and format
/// characters (`is_format`) left out. The one definition of "shown" that name matching,
/// redaction and the terminal's cleaning share.
pub(crate) fn visible(text: &str) -> Cow<'_, str> {
    if !text.chars().any(hidden) {
        return Cow::Borrowed(text);
    }
    Cow::Owned(shown_chars(text).map(|(_, c)| c).collect())
}

/// The characters of `text` that `visible` keeps, with their byte offsets in `text`.
fn shown_chars(text: &str) -> impl Iterator<Item = (usize, char)> + '_ {
    let mut chars = text.char_indices().peekable();
    std::iter::from_fn(move || {
        while let Some((i, c)) = chars.next() {
            match c {
                '\u{1b}' => match chars.peek().map(|p| p.1) {
                    Some('[') => {
                        chars.next();
                        for (_, d) in chars.by_ref() {
                            if ('@'..='~').contains(&d) {
                                break;
                            }
                        }
                    }
                    Some(']') => {
                        chars.next();
                        while let Some((_, d)) = chars.next() {
                            if d == '\u{1b}' && chars.peek().map(|p| p.1) == Some('\\') {
                                chars.next();
                                break;
                            }
                            if d == '\u{7}' {
                                break;
                            }
                        }
                    }
                    _ => {}
                },
                c if hidden(c) => {}
                c => return Some((i, c)),
            }
        }
        None
    })
}

/// Every form `name` could be meant in (see the module header), and every name it lies
/// under (a denied node or namespace covers its own topics, services and parameters).
fn variants(name: &str) -> Vec<String> {
    let name = visible(name);
    let mut out = vec![name.to_string()];
    let t = name.trim().trim_end_matches(['.', ',', ';', ':', '!', '?']);
    out.push(t.to_string());
    // DDS spellings (`rt/secret`, `rq/secret/getRequest`) and private names (`~/secret`).
    let dds = ["rt/", "rq/", "rr/", "rs/", "ra/", "~/", "~"]
        .iter()
        .find_map(|p| t.strip_prefix(p))
        .map(|rest| {
            rest.strip_suffix("Request")
                .or_else(|| rest.strip_suffix("Reply"))
                .unwrap_or(rest)
        });
    let slashed = t.replace('.', "/");
    for form in [Some(t), Some(slashed.as_str()), dds].into_iter().flatten() {
        let parts: Vec<&str> = form.split('/').filter(|p| !p.is_empty()).collect();
        for n in 1..=parts.len() {
            out.push(format!("/{}", parts[..n].join("/")));
        }
    }
    out.sort();
    out.dedup();
    out
}

/// Whether `c` continues a name-like word: a letter, a digit, `_`, `/`, `.`, `~`, `-`, or
/// a character a terminal hides (one inside a word splits it for no reader, so text
/// streamed a word at a time must hold it with the word).
pub(crate) fn name_char(c: char) -> bool {
    c.is_alphanumeric() || matches!(c, '_' | '/' | '.' | '~' | '-') || hidden(c)
}

/// Byte spans of the name-like words of `text`: runs of `name_char`s (a sentence's final
/// full stop left out).
fn name_words(text: &str) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, c) in text.char_indices().chain([(text.len(), ' ')]) {
        match (name_char(c), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                let word = text[s..i].trim_end_matches(['.', '-']);
                if !word.is_empty() {
                    out.push((s, s + word.len()));
                }
                start = None;
            }
            _ => {}
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn fence(p: &[&str]) -> Fence {
        Fence::new(&p.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap()
    }

    #[test]
    fn a_name_is_denied_in_every_spelling() {
        let f = fence(&["^/secret", "^/reset$"]);
        for name in [
            "/secret",
            "secret",
            " /secret",
            "/secret/",
            "//secret//x",
            "secret.worker",
            "/reset ",
            "reset",
        ] {
            assert!(f.denies(name), "{name:?}");
        }
        for name in ["/resets", "/turtle1/pose", "/public/secret"] {
            assert!(!f.denies(name), "{name:?}");
        }
    }

    #[test]
    fn canonical_names() {
        assert_eq!(canonical(" turtle1//pose/ ").unwrap(), "/turtle1/pose");
        assert!(canonical("~/private").is_err());
        assert!(canonical("/a b").is_err());
        assert!(canonical("/1abc").is_err());
        assert!(canonical("").is_err());
    }

    #[test]
    fn text_and_json_are_redacted() {
        let f = fence(&["^/secret"]);
        assert_eq!(
            f.redact("no topic /secret_cam; did you mean /secret? Logger secret_node.io said hi."),
            "no topic [off limits]; did you mean [off limits]? Logger [off limits] said hi."
        );
        assert_eq!(f.redact("/turtle1/pose is fine"), "/turtle1/pose is fine");
        let mut v = json!({"summary": "3 nodes: /a, /secret, /b", "nodes": ["/a", "/secret", "/b"],
                           "topics": [{"topic": "/secret/x", "type": "t"}, {"topic": "/ok", "type": "t"}]});
        assert_eq!(f.redact_json(&mut v), 3);
        assert_eq!(v["nodes"], json!(["/a", "/b"]));
        assert_eq!(v["topics"].as_array().unwrap().len(), 1);
        assert!(!v.to_string().contains("secret"));
    }

    /// Issue 41: a name split by a zero-width character, or any other format
    /// character, is the name a terminal shows.
    #[test]
    fn hidden_characters_and_case_do_not_hide_a_name() {
        let f = fence(&["^/turtle1"]);
        for name in [
            "/turtle\u{200B}1/cmd_vel",
            "/\u{FEFF}turtle1",
            "/tur\u{00AD}tle1/pose",
            "/turtle\u{202E}1",
            "/turtle\u{2066}1\u{2069}",
            "/turtle\u{E0041}1",
            "/turtle\u{7}1",
            "/turtle\u{1b}[0m1",
            "/TURTLE1/cmd_vel",
            "Turtle1",
        ] {
            assert!(f.denies(name), "{name:?}");
        }
        assert_eq!(
            canonical(" /turtle\u{200B}1//cmd_vel\u{2060}/ ").unwrap(),
            "/turtle1/cmd_vel"
        );
        assert!(!f.denies("/turtle2\u{200B}"));
    }

    #[test]
    fn format_characters_are_category_cf() {
        for c in [
            '\u{AD}',
            '\u{600}',
            '\u{200B}',
            '\u{200D}',
            '\u{2064}',
            '\u{FEFF}',
            '\u{E007F}',
        ] {
            assert!(is_format(c), "{c:?}");
        }
        for c in ['a', ' ', '\n', 'é', '\u{3164}', '\u{FE0F}', '中'] {
            assert!(!is_format(c), "{c:?}");
        }
        assert_eq!(
            visible("a\u{200B}b\u{1b}[1mc\u{1b}]0;t\u{1b}\\d\r\n"),
            "abcd\n"
        );
        assert!(matches!(visible("plain /name\tok\n"), Cow::Borrowed(_)));
    }

    #[test]
    fn parameters_are_named_under_their_node() {
        assert_eq!(
            parameter_name(" /turtlesim/", "background_r"),
            "/turtlesim/background_r"
        );
        assert_eq!(parameter_name("turtlesim", "/a.b"), "/turtlesim/a.b");
        let f = fence(&["^/turtlesim/background_r$", "^/secret_node$"]);
        assert!(f.denies_parameter("/turtlesim", "background_r"));
        assert!(f.denies_parameter("turtlesim", "background\u{200B}_r"));
        assert!(!f.denies_parameter("/turtlesim", "background_g"));
        assert!(f.denies_parameter("/secret_node", "anything"));
    }

    #[test]
    fn redaction_takes_the_hidden_characters_inside_a_word() {
        let f = fence(&["^/turtle1"]);
        let text = "see /turtle\u{200B}1/cmd_vel\u{200B} and /turtle2 and /Tur\u{AD}tle1.";
        let out = f.redact(text);
        assert_eq!(
            out,
            "see [off limits]\u{200B} and /turtle2 and [off limits]."
        );
        assert_eq!(f.redact("/turtle2 only"), "/turtle2 only");
    }

    mod properties {
        use super::super::*;
        use proptest::prelude::*;

        /// A ROS name: 1 to 3 segments, each a letter then letters, digits, `_`.
        fn ros_name() -> impl Strategy<Value = String> {
            prop::collection::vec("[a-z][a-z0-9_]{0,6}", 1..4)
                .prop_map(|p| format!("/{}", p.join("/")))
        }

        /// Format characters, a few of each kind.
        const FORMAT: &[char] = &[
            '\u{AD}',
            '\u{600}',
            '\u{61C}',
            '\u{180E}',
            '\u{200B}',
            '\u{200C}',
            '\u{200D}',
            '\u{200E}',
            '\u{200F}',
            '\u{202A}',
            '\u{202E}',
            '\u{2060}',
            '\u{2063}',
            '\u{2066}',
            '\u{2069}',
            '\u{FEFF}',
            '\u{FFF9}',
            '\u{110BD}',
            '\u{1D173}',
            '\u{E0001}',
            '\u{E0067}',
        ];

        /// `name` spelt another way that canonicalises to it (but for case): format
        /// characters inserted anywhere, letters' case flipped, slashes doubled, the
        /// leading one dropped, a trailing one added, blanks around.
        fn spelling(name: String) -> impl Strategy<Value = (String, String)> {
            let n = name.chars().count();
            (
                prop::collection::vec((0..=n, prop::sample::select(FORMAT)), 0..6),
                prop::collection::vec(any::<bool>(), n),
                any::<bool>(),
                any::<bool>(),
                any::<bool>(),
                any::<bool>(),
            )
                .prop_map(
                    move |(inserts, upper, double, relative, trailing, blanks)| {
                        let mut chars: Vec<String> = name
                            .chars()
                            .zip(&upper)
                            .map(|(c, &u)| match (c, u) {
                                ('/', _) if double => "//".to_string(),
                                (c, true) => c.to_ascii_uppercase().to_string(),
                                (c, false) => c.to_string(),
                            })
                            .collect();
                        chars.push(String::new());
                        for (at, c) in &inserts {
                            chars[*at].insert(0, *c);
                        }
                        let mut s: String = chars.concat();
                        if relative {
                            s = s.replacen('/', "", 1);
                        }
                        if trailing {
                            s.push('/');
                        }
                        if blanks {
                            s = format!(" {s} ");
                        }
                        (name.clone(), s)
                    },
                )
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(512))]

            /// Any spelling of a denied name, or of a name under it, is denied, and its
            /// canonical form is the name (case aside).
            #[test]
            fn every_spelling_of_a_denied_name_is_denied(
                (name, spelt) in ros_name().prop_flat_map(spelling),
                under in prop::option::of("[a-z][a-z0-9_]{0,6}"),
                anchored in any::<bool>(),
            ) {
                let pattern = if anchored { format!("^{}$", regex::escape(&name)) } else { format!("^{}", regex::escape(&name)) };
                let f = Fence::new(&[pattern]).unwrap();
                let spelt = match &under {
                    Some(u) if !anchored => format!("{}/{u}", spelt.trim().trim_end_matches('/')),
                    _ => spelt,
                };
                prop_assert!(f.denies(&spelt), "{:?} not denied under {:?}", spelt, name);
                let c = canonical(&spelt).unwrap();
                prop_assert!(c.to_lowercase().starts_with(&name), "{:?} gives {:?}", spelt, c);
                // Redacted in text, it never shows again once the hidden characters go.
                let text = format!("found {spelt} here, and {spelt}.");
                let shown = visible(&f.redact(&text)).to_lowercase();
                prop_assert!(!shown.contains(&name), "{:?} shows {:?}", text, shown);
            }
        }
    }

    #[test]
    fn the_model_may_fence_off_a_thing_not_everything() {
        let f = Fence::default();
        for broad in [".", "^/", ".*", "[a-z]", "/"] {
            assert!(
                matches!(f.add_model_pattern(broad), Err(FenceError::TooBroad(..))),
                "{broad}"
            );
        }
        f.add_model_pattern("^/camera").unwrap();
        assert!(f.denies("/camera/image") && !f.denies("/turtle1/pose"));
        assert!(matches!(
            f.add_model_pattern("("),
            Err(FenceError::Pattern { .. })
        ));
    }
}
