//! A turn's grammar as a server that enforces only JSON schemas can take it.
//!
//! Each envelope writes its calls as JSON between fixed markers (or, for the JSON
//! envelope, as one JSON object). So a turn that must call is asked for as: the prompt,
//! the envelope's opening written by ferrosa, then one JSON value under the call list's
//! schema, then the closing written by ferrosa again. The text is what the envelope's
//! own grammar allows (up to whitespace inside the JSON), and it is parsed and checked
//! exactly as a local turn's.
//!
//! What a schema cannot say: a choice between prose and a call. Such a turn (`Auto`) is
//! written freely first and, if the model opens a call, the call is asked for again
//! under its schema after the prose (see `remote::Remote::turn`).
//!
//! Schemas go out as a server's converter can enforce them whole (`portable`).

use serde_json::Value;

use crate::decode::{Envelope, ToolChoice};
use crate::tool::ToolSpec;

/// How one turn is asked for.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Frame {
    /// Prose, no grammar (`ToolChoice::None`, or no tools).
    Free,
    /// The whole turn is one JSON value.
    Whole { schema: Value },
    /// `opening`, then one JSON value, then `closing`.
    Marked {
        opening: &'static str,
        schema: Value,
        closing: &'static str,
    },
    /// Prose, or a call once `marker` starts one: written freely, then, from the
    /// marker on, as `then`.
    Either { marker: Marker, then: Box<Frame> },
}

/// Where a freely written turn starts a call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Marker {
    /// At this text.
    Text(&'static str),
    /// When the turn (after spaces) starts with `{` (the JSON envelope).
    LeadingBrace,
}

impl Marker {
    /// The byte where the call starts in `text`, if it does.
    pub fn find(self, text: &str) -> Option<usize> {
        match self {
            Marker::Text(m) => text.find(m),
            Marker::LeadingBrace => {
                let lead = text.len() - text.trim_start().len();
                text[lead..].starts_with('{').then_some(lead)
            }
        }
    }
}

/// `schema` as llama.cpp's JSON-schema converter can enforce it whole. That converter
/// takes a string's `pattern` over its `minLength`/`maxLength` (dropping the bounds), and
/// turns a pattern it cannot read into "any string" with only a warning in the server's
/// log. So: class escapes (`\s`, `\d`, `\w` inside `[...]`) are spelled out, and the
/// bounds are folded into a pattern of single characters and classes with one `*` (the
/// shape of the answer tool's). What still cannot be said is caught afterwards: every turn
/// is checked against the real schema.
pub(crate) fn portable(schema: &Value) -> Value {
    match schema {
        Value::Object(map) => {
            // Values that are data, not schemas, stay as they are.
            const DATA: [&str; 4] = ["const", "enum", "default", "examples"];
            let mut out: serde_json::Map<String, Value> = map
                .iter()
                .map(|(k, v)| {
                    let v = if DATA.contains(&k.as_str()) {
                        v.clone()
                    } else {
                        portable(v)
                    };
                    (k.clone(), v)
                })
                .collect();
            if let Some(p) = map.get("pattern").and_then(Value::as_str) {
                let p = spell_out_classes(p);
                let min = map.get("minLength").and_then(Value::as_u64).unwrap_or(0) as usize;
                let max = map
                    .get("maxLength")
                    .and_then(Value::as_u64)
                    .map(|m| m as usize);
                let bounded = match max {
                    Some(max) => bound_star(&p, min, max),
                    None if min > 0 => bound_star(&p, min, usize::MAX),
                    None => None,
                };
                out.insert("pattern".into(), Value::String(bounded.unwrap_or(p)));
            }
            Value::Object(out)
        }
        Value::Array(items) => Value::Array(items.iter().map(portable).collect()),
        other => other.clone(),
    }
}

/// A pattern as llama.cpp's converter can take it. The converter writes what a pattern
/// allows into the JSON text as it stands, so it must also be valid inside a JSON string:
/// `.` and negated classes are kept off the quote, the backslash and control characters
/// (or the model could end the string early and write anything after it). Class escapes
/// (`\s`, `\d`, `\w`) are spelled out in the escapes the converter reads (`\t`, `\x0b`).
fn spell_out_classes(pattern: &str) -> String {
    const NOT_JSON: &str = r#""\\\x00-\x1f"#;
    let mut out = String::with_capacity(pattern.len() + 16);
    // Inside a class: whether it is negated.
    let mut class: Option<bool> = None;
    let mut chars = pattern.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\\' => {
                let next = chars.next().unwrap_or('\\');
                let spelled = match next {
                    's' if class.is_some() => Some(r" \t\n\r\x0b\x0c"),
                    'd' if class.is_some() => Some("0-9"),
                    'w' if class.is_some() => Some("a-zA-Z0-9_"),
                    _ => None,
                };
                match spelled {
                    Some(s) => out.push_str(s),
                    None => {
                        out.push('\\');
                        out.push(next);
                    }
                }
            }
            '[' if class.is_none() => {
                out.push(c);
                let negated = chars.peek() == Some(&'^');
                if negated {
                    out.push(chars.next().unwrap_or('^'));
                }
                class = Some(negated);
            }
            ']' if class.is_some() => {
                if class == Some(true) {
                    out.push_str(NOT_JSON);
                }
                class = None;
                out.push(c);
            }
            '.' if class.is_none() => out.push_str(&format!("[^{NOT_JSON}]")),
            _ => out.push(c),
        }
    }
    out
}

/// `^...$` made of single characters and classes, one of them starred: the star as a
/// count that keeps the whole between `min` and `max` characters. `None` for any other
/// shape.
fn bound_star(pattern: &str, min: usize, max: usize) -> Option<String> {
    let body = pattern.strip_prefix('^')?.strip_suffix('$')?;
    // Atoms: a class `[...]` (escapes inside kept) or one character (or escape).
    let mut atoms: Vec<(String, bool)> = Vec::new();
    let mut chars = body.chars().peekable();
    while let Some(c) = chars.next() {
        let atom = match c {
            '[' => {
                let mut a = String::from('[');
                loop {
                    let d = chars.next()?;
                    a.push(d);
                    if d == '\\' {
                        a.push(chars.next()?);
                    } else if d == ']' && a.len() > 2 {
                        break;
                    }
                }
                a
            }
            '\\' => format!("\\{}", chars.next()?),
            '(' | ')' | '|' | '?' | '+' | '{' | '}' | '*' => return None,
            c => c.to_string(),
        };
        let starred = chars.peek() == Some(&'*');
        if starred {
            chars.next();
        }
        atoms.push((atom, starred));
    }
    let (starred, fixed): (Vec<_>, Vec<_>) = atoms.iter().partition(|(_, s)| *s);
    if starred.len() != 1 || max < fixed.len() || min > max {
        return None;
    }
    let lo = min.saturating_sub(fixed.len());
    let hi = max.saturating_sub(fixed.len());
    let count = if max == usize::MAX {
        format!("{{{lo},}}")
    } else {
        format!("{{{lo},{hi}}}")
    };
    let mut out = String::from("^");
    for (atom, s) in &atoms {
        out.push_str(atom);
        if *s {
            out.push_str(&count);
        }
    }
    out.push('$');
    Some(out)
}

/// The frame of a turn over `specs` (see the module header).
pub(crate) fn for_turn(
    envelope: Envelope,
    specs: &[ToolSpec],
    choice: ToolChoice,
    parallel: bool,
) -> Frame {
    if specs.is_empty() || choice == ToolChoice::None {
        return Frame::Free;
    }
    let (alone, others, parallel) = Envelope::split_alone(specs, parallel);
    let must = |choice| match envelope {
        Envelope::Smollm2 => Frame::Marked {
            opening: "<tool_call>",
            schema: portable(&Envelope::list_schema(&alone, &others, choice, parallel)),
            closing: "</tool_call>",
        },
        // One block per turn: a schema holds one JSON value.
        Envelope::Qwen => {
            let all: Vec<&ToolSpec> = alone.iter().chain(&others).copied().collect();
            Frame::Marked {
                opening: "<tool_call>\n",
                schema: portable(&Envelope::call_any_of(&all)),
                closing: "\n</tool_call>",
            }
        }
        Envelope::Json => Frame::Whole {
            schema: portable(&serde_json::json!({
                "type": "object",
                "properties": {"tool_calls": Envelope::list_schema(&alone, &others, choice, parallel)},
                "required": ["tool_calls"],
                "additionalProperties": false,
            })),
        },
    };
    match (choice, envelope) {
        (ToolChoice::Required, _) | (ToolChoice::Decline, Envelope::Smollm2 | Envelope::Json) => {
            must(choice)
        }
        _ => Frame::Either {
            marker: match envelope {
                Envelope::Json => Marker::LeadingBrace,
                Envelope::Smollm2 | Envelope::Qwen => Marker::Text("<tool_call>"),
            },
            then: Box::new(must(ToolChoice::Required)),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn spec(name: &str) -> ToolSpec {
        ToolSpec::new(
            name,
            "d",
            json!({"type": "object", "properties": {"x": {"type": "integer"}}, "required": ["x"]}),
        )
        .unwrap()
    }

    #[test]
    fn each_envelope_frames_a_required_call_as_its_grammar_writes_it() {
        let specs = [spec("a"), spec("b")];
        let Frame::Marked {
            opening,
            schema,
            closing,
        } = for_turn(Envelope::Smollm2, &specs, ToolChoice::Required, true)
        else {
            panic!("smollm2 marks its list");
        };
        assert_eq!((opening, closing), ("<tool_call>", "</tool_call>"));
        assert_eq!(schema["type"], "array");
        assert_eq!(schema["minItems"], 1);
        assert_eq!(schema["items"]["anyOf"].as_array().unwrap().len(), 2);
        // A list of calls the schema takes parses back as the envelope's own text.
        let text = format!(
            "{opening}{}{closing}",
            json!([{"name": "b", "arguments": {"x": 2}}])
        );
        let turn = Envelope::Smollm2.parse(&text, &specs).unwrap();
        assert_eq!(turn.calls[0].name, "b");

        let Frame::Whole { schema } = for_turn(Envelope::Json, &specs, ToolChoice::Decline, false)
        else {
            panic!("the JSON envelope is one value");
        };
        assert_eq!(schema["properties"]["tool_calls"]["minItems"], 0);
        assert_eq!(schema["properties"]["tool_calls"]["maxItems"], 1);

        let Frame::Marked { schema, .. } =
            for_turn(Envelope::Qwen, &specs, ToolChoice::Required, true)
        else {
            panic!("qwen marks each call");
        };
        assert!(schema["anyOf"].is_array());
    }

    #[test]
    fn schemas_are_rewritten_into_what_the_servers_converter_enforces() {
        // The answer tool's text: the class escape spelled out, the length in the star.
        let answer =
            json!({"type": "string", "maxLength": 240, "pattern": "^[^{}<>]*[^{}<>:\\s]$"});
        let p = portable(&json!({"properties": {"text": answer}}));
        assert_eq!(
            p["properties"]["text"]["pattern"],
            r#"^[^{}<>"\\\x00-\x1f]{0,239}[^{}<>: \t\n\r\x0b\x0c"\\\x00-\x1f]$"#
        );
        // The same strings match before and after (the bounds now inside the pattern).
        let before = regex::Regex::new("^[^{}<>]*[^{}<>:\\s]$").unwrap();
        let after =
            regex::Regex::new(p["properties"]["text"]["pattern"].as_str().unwrap()).unwrap();
        for (text, ok) in [
            ("It is 9.84 feet", true),
            ("ends in space ", false),
            ("a}", false),
        ] {
            assert_eq!(before.is_match(text), ok, "{text}");
            assert_eq!(after.is_match(text), ok, "{text}");
        }
        // Nothing that would end the JSON string early, or break it.
        for text in ["say \"hi\" now", "a\\b", "two\nlines"] {
            assert!(before.is_match(text), "{text:?}");
            assert!(!after.is_match(text), "{text:?}");
        }
        assert_eq!(
            portable(&json!({"pattern": "^a.b$"}))["pattern"],
            r#"^a[^"\\\x00-\x1f]b$"#
        );
        assert!(!after.is_match(&"a".repeat(241)));
        assert!(after.is_match(&"a".repeat(240)));
        // Shapes it cannot bound stay as they were; a pattern alone is only spelled out.
        let other = json!({"type": "string", "maxLength": 5, "pattern": "^(a|b)*$"});
        assert_eq!(portable(&other), other);
        let data = json!({"const": {"pattern": "^[\\d]*$"}, "default": {"pattern": "."}});
        assert_eq!(portable(&data), data);
        let never = json!({"pattern": "^[a]*$", "minLength": 5, "maxLength": 2});
        assert_eq!(portable(&never), never);
        assert_eq!(portable(&json!({"pattern": "^\\d+$"}))["pattern"], "^\\d+$");
        assert_eq!(
            portable(&json!({"pattern": "^[\\d.]*$", "minLength": 1}))["pattern"],
            "^[0-9.]{1,}$"
        );
    }

    #[test]
    fn prose_or_a_call_is_written_freely_then_framed_from_the_marker() {
        let specs = [spec("a")];
        let Frame::Either { marker, then } =
            for_turn(Envelope::Smollm2, &specs, ToolChoice::Auto, true)
        else {
            panic!("auto is either");
        };
        assert_eq!(marker.find("Sure. <tool_call>[..."), Some(6));
        assert_eq!(marker.find("Hello."), None);
        assert!(matches!(*then, Frame::Marked { .. }));
        assert_eq!(Marker::LeadingBrace.find("  {\"tool_calls\""), Some(2));
        assert_eq!(Marker::LeadingBrace.find("It is {x}"), None);
        assert_eq!(
            for_turn(Envelope::Qwen, &specs, ToolChoice::None, true),
            Frame::Free
        );
        assert_eq!(
            for_turn(Envelope::Qwen, &[], ToolChoice::Required, true),
            Frame::Free
        );
    }
}
