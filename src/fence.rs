//! Names off limits: the operator's deny-list (and the patterns the model may add, never
//! remove), checked on ROS names in their canonical form, and applied to text as
//! redaction.
//!
//! A name is judged in every form it could be meant in: as written, trimmed, made
//! absolute (`secret` and ` /secret/` are `/secret`), for logger names with dots as
//! slashes (`secret_node.worker` is `/secret_node/worker`), in DDS spelling (`rt/secret`)
//! or as a private name (`~/secret`), and by every name it lies under (`/secret/cmd` is
//! under `/secret`). A pattern matching any form denies it. Redaction finds name-like words in any text (a log line, an error,
//! an answer) and replaces the denied ones with `[off limits]`; in JSON, array items that
//! are denied names (or objects named by one) are dropped and every string is redacted.
//!
//! The ROS boundary (`ros::guard`) and the policy (`tool::policy`) both consult the same
//! fence, so a name a tool builds itself meets it exactly as one the model wrote.
//! Depends on nothing else in the crate.

use std::borrow::Cow;
use std::sync::RwLock;

use regex::Regex;
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

fn compile(p: &str) -> Result<Regex, FenceError> {
    Regex::new(p).map_err(|e| FenceError::Pattern {
        pattern: p.to_string(),
        message: regex_error(&e),
    })
}

/// What is wrong with a pattern, in one line: the regex crate draws a multi-line caret
/// diagram, and its last line says what.
pub fn regex_error(e: &regex::Error) -> String {
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

    /// Whether any pattern denies `name` in any of its forms.
    pub fn denies(&self, name: &str) -> bool {
        let forms = variants(name);
        let hit = |re: &Regex| forms.iter().any(|f| re.is_match(f));
        self.operator.iter().any(hit) || self.model.read().expect("fence lock").iter().any(hit)
    }

    pub fn is_empty(&self) -> bool {
        self.operator.is_empty() && self.model.read().expect("fence lock").is_empty()
    }

    /// `text` with every denied name-like word replaced by `[off limits]`.
    pub fn redact<'a>(&self, text: &'a str) -> Cow<'a, str> {
        if self.is_empty() {
            return Cow::Borrowed(text);
        }
        let mut out = String::new();
        let mut last = 0;
        for (start, end) in name_words(text) {
            if self.denies(&text[start..end]) {
                out.push_str(&text[last..start]);
                out.push_str(REDACTED);
                last = end;
            }
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
    pub fn redact_json(&self, v: &mut Value) -> usize {
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

/// The canonical form of a ROS name: trimmed, absolute, single slashes, no trailing
/// slash. Names with characters ROS does not allow are an error (`~` private names and
/// `{}` substitutions are not resolved here: they are refused).
pub fn canonical(name: &str) -> Result<String, FenceError> {
    let t = name.trim();
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

/// Every form `name` could be meant in (see the module header), and every name it lies
/// under (a denied node or namespace covers its own topics, services and parameters).
fn variants(name: &str) -> Vec<String> {
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

/// Byte spans of the name-like words of `text`: runs of letters, digits, `_`, `/`, `.`,
/// `~` and `-` (a sentence's final full stop left out).
fn name_words(text: &str) -> Vec<(usize, usize)> {
    let name_char = |c: char| c.is_alphanumeric() || matches!(c, '_' | '/' | '.' | '~' | '-');
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
