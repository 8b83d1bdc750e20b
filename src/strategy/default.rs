//! What a parameter's schema says its default is: the JSON schema `default`, or, as
//! function docs mostly put it, a phrase in the description ("Default is -9.81 m/s^2.",
//! "defaults to 'cm'", "Default: true", "Default is all if not specified").
//!
//! Not a strategy of its own: what the strategies know of defaults. A value the operator
//! never gave is best left to the tool's default: grounding keeps a value equal to it,
//! call verification counts it for nothing, and the copy bias offers a required
//! parameter's default as one more thing its value may copy.
//!
//! Cost: a scan of one description per call; nothing per token.

use serde_json::Value;

use crate::lexicon::{same_number, words};

/// A parameter's declared default.
#[derive(Debug, Clone, PartialEq)]
pub struct Declared {
    /// The default as a JSON value, when it reads as one: the schema's own, or a quoted
    /// string, a number or a boolean right after "default" in the description.
    pub value: Option<Value>,
    /// How the value is spelled where it was read (the number as written, "-9.81", not
    /// -9.81's shortest form; a string's text without its quotes).
    pub spelled: Option<String>,
    /// The description's words from "default" to the end of that sentence, lowercased
    /// (empty for a schema `default`).
    pub clause: String,
}

/// Words between "default" and the value that say nothing ("Default value is", "defaults
/// to", "default it's set to").
const FILLER: [&str; 12] = [
    "is", "to", "value", "values", "of", "be", "will", "set", "it", "it's", "s", "as",
];

/// The default `prop` (one property's schema) declares, if any.
pub fn declared(prop: &Value) -> Option<Declared> {
    if let Some(d) = prop.get("default").filter(|d| !d.is_null()) {
        let spelled = match d {
            Value::String(s) => Some(s.clone()),
            Value::Number(_) | Value::Bool(_) => Some(d.to_string()),
            _ => None,
        };
        return Some(Declared {
            value: Some(d.clone()),
            spelled,
            clause: String::new(),
        });
    }
    let desc = prop["description"].as_str()?;
    let lower = desc.to_lowercase();
    let at = lower.find("default")?;
    // The original text from the same place (lowercasing keeps ASCII offsets, and a
    // description whose lowercase differs in length is read lowercased).
    let rest = if lower.len() == desc.len() {
        &desc[at + "default".len()..]
    } else {
        &lower[at + "default".len()..]
    };
    let end = rest
        .char_indices()
        .find(|&(i, c)| c == '.' && rest[i + 1..].chars().next().is_none_or(char::is_whitespace))
        .map_or(rest.len(), |(i, _)| i);
    let sentence = &rest[..end];
    let (value, spelled) = match value_after(sentence) {
        Some((v, s)) => (Some(v), Some(s)),
        None => (None, None),
    };
    Some(Declared {
        value,
        spelled,
        clause: sentence.to_lowercase(),
    })
}

/// The value a default phrase starts with, after any filler: a quoted string, a number
/// or a boolean (with its spelling). Unquoted words ("Default is all if not specified")
/// give none: where they end is anyone's guess.
fn value_after(sentence: &str) -> Option<(Value, String)> {
    let mut s = sentence;
    loop {
        s = s.trim_start_matches(|c: char| c.is_whitespace() || matches!(c, ':' | '=' | ','));
        let word_end = s
            .find(|c: char| !(c.is_alphanumeric() || c == '\''))
            .unwrap_or(s.len());
        if word_end > 0 && FILLER.contains(&s[..word_end].to_lowercase().as_str()) {
            s = &s[word_end..];
            continue;
        }
        break;
    }
    let first = s.chars().next()?;
    if first == '\'' || first == '"' || first == '`' {
        let body = &s[1..];
        let close = body.find(first)?;
        let text = &body[..close];
        return Some((Value::String(text.to_string()), text.to_string()));
    }
    let word: String = s
        .chars()
        .take_while(|c| c.is_alphanumeric())
        .collect::<String>()
        .to_lowercase();
    match word.as_str() {
        "true" => return Some((Value::Bool(true), "true".into())),
        "false" => return Some((Value::Bool(false), "false".into())),
        _ => {}
    }
    let b = s.as_bytes();
    let mut end = 0;
    while end < b.len() {
        let c = b[end];
        let sign = matches!(c, b'-' | b'+') && (end == 0 || matches!(b[end - 1], b'e' | b'E'));
        if !(c.is_ascii_digit() || c == b'.' || matches!(c, b'e' | b'E') || sign) {
            break;
        }
        end += 1;
    }
    let mut spelled = &s[..end];
    // A sentence's full stop or a word's first letter ("5 evenings") is not the number's.
    while spelled.ends_with(['.', 'e', 'E', '-', '+']) {
        spelled = &spelled[..spelled.len() - 1];
    }
    if !spelled.bytes().any(|c| c.is_ascii_digit()) {
        return None;
    }
    let n: f64 = spelled.parse().ok()?;
    let value = if spelled.contains(['.', 'e', 'E']) {
        serde_json::Number::from_f64(n).map(Value::Number)?
    } else {
        spelled
            .parse::<i64>()
            .map(Value::from)
            .unwrap_or_else(|_| Value::from(n))
    };
    Some((value, spelled.to_string()))
}

impl Declared {
    /// A string whose words all occur, in a row, in the default (its value, or the
    /// description's clause when the value did not read as one).
    pub(crate) fn spells_words(&self, v: &str) -> bool {
        let w = words(v);
        if w.is_empty() {
            return false;
        }
        match &self.value {
            Some(Value::String(d)) => words(d) == w,
            Some(_) => false,
            None => words(&self.clause)
                .windows(w.len())
                .any(|win| win == w.as_slice()),
        }
    }

    /// Is `v` the default? Numbers by value with their sign (-9.81 is not 9.81),
    /// strings by their words, booleans as they are.
    pub fn is(&self, v: &Value) -> bool {
        match (v, &self.value) {
            (Value::Number(a), Some(Value::Number(d))) => {
                let (Some(a), Some(d)) = (a.as_f64(), d.as_f64()) else {
                    return false;
                };
                same_number(a, d)
            }
            (Value::String(s), _) => self.spells_words(s),
            (a, Some(d)) => a == d,
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn from(desc: &str) -> Option<Declared> {
        declared(&json!({"type": "number", "description": desc}))
    }

    fn value(desc: &str) -> Option<Value> {
        from(desc).and_then(|d| d.value)
    }

    #[test]
    fn defaults_read_from_descriptions() {
        assert_eq!(
            value("The acceleration due to gravity. Default is -9.81 m/s^2."),
            Some(json!(-9.81))
        );
        assert_eq!(value("Default value is 'real'."), Some(json!("real")));
        assert_eq!(value("The unit. Defaults to \"cm\""), Some(json!("cm")));
        assert_eq!(
            value("Return a string if true. Default is true."),
            Some(json!(true))
        );
        assert_eq!(value("Default: False"), Some(json!(false)));
        assert_eq!(value("Rounding, default is 2."), Some(json!(2)));
        assert_eq!(value("Default 0.1"), Some(json!(0.1)));
        assert_eq!(
            value("The constant. Default is 8.99e9."),
            Some(json!(8.99e9))
        );
        assert_eq!(value("Optional, default to 0.00."), Some(json!(0.0)));
        assert_eq!(value("Default is 1 atm if not provided."), Some(json!(1)));
        // Unquoted words are kept as a clause only.
        let d = from("Default is all if not specified.").unwrap();
        assert_eq!(d.value, None);
        assert!(d.spells_words("all"));
        assert!(!d.spells_words("real"));
        assert_eq!(from("The radius of the circle."), None);
    }

    #[test]
    fn the_clause_ends_with_its_sentence() {
        let d = from("Default is 0.05. Use 'all' for everything.").unwrap();
        assert_eq!(d.value, Some(json!(0.05)));
        assert!(!d.spells_words("all"));
    }

    #[test]
    fn a_schema_default_wins_and_signs_count() {
        let d =
            declared(&json!({"type": "number", "default": -9.81, "description": "Default is 3."}))
                .unwrap();
        assert!(d.is(&json!(-9.81)));
        assert!(!d.is(&json!(9.81)));
        assert_eq!(d.spelled.as_deref(), Some("-9.81"));
        let d = from("Default is true.").unwrap();
        assert!(d.is(&json!(true)));
        assert!(!d.is(&json!(false)));
        let d = from("Default is 'New York'.").unwrap();
        assert!(d.is(&json!("new york")));
        assert!(!d.is(&json!("York")));
    }
}
