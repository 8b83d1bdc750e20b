//! Tool-call envelopes: how one model family writes tool calls, as a grammar (from
//! `grammars/<family>.lark`, tool schemas filled in per turn), as prompt text (how the
//! tools are described, how past calls are shown) and as a parser back to `ToolCall`s.
//! The three always agree: the prompt shows the model exactly what the grammar allows.

use serde_json::{json, Value};

use crate::tool::{ToolCall, ToolSpec};

const SMOLLM2: &str = include_str!("../../grammars/smollm2.lark");
const QWEN: &str = include_str!("../../grammars/qwen.lark");
const JSON: &str = include_str!("../../grammars/json.lark");

/// Calls one turn may make at most: a small model that starts repeating a call would
/// otherwise fill its whole turn with copies.
pub(crate) const MAX_PARALLEL: usize = 4;

/// A tool-call format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Envelope {
    /// `<tool_call>[{...}, ...]</tool_call>` in plain text (SmolLM2-Instruct family).
    Smollm2,
    /// `<tool_call>\n{...}\n</tool_call>` per call, markers are special tokens (Qwen 2.5/3).
    Qwen,
    /// `{"tool_calls": [...]}` as the whole turn (families with no format of their own).
    Json,
}

/// Whether the turn may, must or must not call a tool.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ToolChoice {
    /// Prose, or a call once the envelope's opening marker appears.
    #[default]
    Auto,
    /// One or more calls, nothing else.
    Required,
    /// Calls, or an empty call list that declines (the way SmolLM2 was trained to say
    /// that no tool fits). Envelopes with no empty form treat it as `Auto`.
    Decline,
    /// Prose only.
    None,
}

/// A parsed assistant turn.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Turn {
    /// Text outside any call (the answer, when there are no calls).
    pub prose: String,
    pub calls: Vec<ToolCall>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EnvelopeError {
    #[error("tool call is not valid JSON: {0}")]
    Json(String),
    #[error("tool call has no \"name\"/\"arguments\" pair: {0}")]
    Shape(String),
    #[error("no tool named '{name}'; available: {available}")]
    UnknownTool { name: String, available: String },
    #[error("arguments of {name} do not match its schema: {errors}")]
    Arguments { name: String, errors: String },
}

/// JSON as the envelopes write it: `", "` between items and `": "` after keys, which is
/// also what the grammar enforces and what these models saw in training (Python's
/// `json.dumps` default).
pub(crate) fn to_json_spaced(v: &Value) -> String {
    let mut out = String::new();
    write_spaced(v, &mut out);
    out
}

fn write_spaced(v: &Value, out: &mut String) {
    match v {
        Value::Array(items) => {
            out.push('[');
            for (i, x) in items.iter().enumerate() {
                if i > 0 {
                    out.push_str(", ");
                }
                write_spaced(x, out);
            }
            out.push(']');
        }
        Value::Object(map) => {
            out.push('{');
            for (i, (k, x)) in map.iter().enumerate() {
                if i > 0 {
                    out.push_str(", ");
                }
                out.push_str(&Value::String(k.clone()).to_string());
                out.push_str(": ");
                write_spaced(x, out);
            }
            out.push('}');
        }
        scalar => out.push_str(&scalar.to_string()),
    }
}

/// The first JSON value in `s` (after whitespace), and the bytes it took.
fn first_json(s: &str) -> Result<(Value, usize), EnvelopeError> {
    let mut it = serde_json::Deserializer::from_str(s).into_iter::<Value>();
    match it.next() {
        Some(Ok(v)) => Ok((v, it.byte_offset())),
        Some(Err(e)) => Err(EnvelopeError::Json(format!("{e}: {s}"))),
        None => Err(EnvelopeError::Json(format!(
            "no JSON after the marker: {s}"
        ))),
    }
}

impl Envelope {
    /// The envelope a model family uses.
    pub fn for_family(family: &str) -> Envelope {
        let f = family.to_ascii_lowercase();
        if f.starts_with("qwen") {
            Envelope::Qwen
        } else if f.starts_with("smollm") {
            Envelope::Smollm2
        } else {
            Envelope::Json
        }
    }

    pub(crate) fn call_any_of(specs: &[&ToolSpec]) -> Value {
        let branches: Vec<Value> = specs.iter().map(|s| s.call_schema()).collect();
        json!({ "anyOf": branches })
    }

    fn separators() -> Value {
        json!({"whitespace_flexible": false, "item_separator": ", ", "key_separator": ": "})
    }

    /// The tools called alone and the others, and whether the others may be a list:
    /// when every tool is called alone, the list is simply one call long.
    pub(crate) fn split_alone(
        specs: &[ToolSpec],
        parallel: bool,
    ) -> (Vec<&ToolSpec>, Vec<&ToolSpec>, bool) {
        let (alone, others): (Vec<&ToolSpec>, Vec<&ToolSpec>) = specs.iter().partition(|s| s.alone);
        if others.is_empty() {
            (Vec::new(), alone, false)
        } else {
            (alone, others, parallel)
        }
    }

    /// The JSON schema of a turn's list of calls: one to `MAX_PARALLEL` (`parallel`) of
    /// `specs`, none allowed when declining, or one tool of `alone` by itself.
    pub(crate) fn list_schema(
        alone: &[&ToolSpec],
        specs: &[&ToolSpec],
        choice: ToolChoice,
        parallel: bool,
    ) -> Value {
        let list = |specs: &[&ToolSpec], min: usize, max: usize| {
            json!({
                "type": "array",
                "items": Envelope::call_any_of(specs),
                "minItems": min,
                "maxItems": max,
            })
        };
        let min = usize::from(choice != ToolChoice::Decline);
        let array = list(specs, min, if parallel { MAX_PARALLEL } else { 1 });
        if alone.is_empty() {
            array
        } else {
            json!({"anyOf": [list(alone, 1, 1), array]})
        }
    }

    /// The Lark grammar of one assistant turn over `specs`. With no tools, the only choice
    /// is prose.
    pub fn grammar(&self, specs: &[ToolSpec], choice: ToolChoice, parallel: bool) -> String {
        let choice = if specs.is_empty() {
            ToolChoice::None
        } else {
            choice
        };
        let start = match (choice, self) {
            (ToolChoice::Auto, _) | (ToolChoice::Decline, Envelope::Qwen) => "auto",
            (ToolChoice::Required, _) => "required",
            (ToolChoice::Decline, _) => "decline",
            (ToolChoice::None, _) => "none",
        };
        // Tools called alone are a list of one call of their own; when every tool is one,
        // the list is simply one call long.
        let (alone, specs, parallel) = Envelope::split_alone(specs, parallel);
        let one_of = |specs: &[&ToolSpec]| {
            let mut v = Envelope::call_any_of(specs);
            v["x-guidance"] = Envelope::separators();
            v.to_string()
        };
        let (template, calls) = match self {
            Envelope::Smollm2 => (SMOLLM2, one_of(&specs)),
            Envelope::Qwen => (QWEN, one_of(&specs)),
            Envelope::Json => {
                let mut wrapper = json!({
                    "type": "object",
                    "properties": {"tool_calls": Envelope::list_schema(&alone, &specs, choice, parallel)},
                    "required": ["tool_calls"],
                    "additionalProperties": false,
                });
                wrapper["x-guidance"] = Envelope::separators();
                (JSON, wrapper.to_string())
            }
        };
        // The JSON envelope has them in its schema; the others as a rule of their own.
        let alone_rules = match self {
            _ if alone.is_empty() => String::new(),
            Envelope::Smollm2 => format!("alone_call: %json {}", one_of(&alone)),
            Envelope::Qwen => format!(
                "alone_call: <tool_call> \"\\n\" alone_json \"\\n\" </tool_call>\n\
                 alone_json: %json {}",
                one_of(&alone)
            ),
            Envelope::Json => String::new(),
        };
        let alone_choice = if alone_rules.is_empty() {
            ""
        } else {
            "| alone_call"
        };
        template
            .replace("@START@", start)
            .replace("@CALLS@", &calls)
            .replace("@CALL@", &calls)
            .replace("@MORE@", if parallel { "more_calls" } else { "" })
            .replace("@MAX_MORE@", &(MAX_PARALLEL - 1).to_string())
            .replace("@ALONE@", alone_choice)
            .replace("@ALONE_RULES@", &alone_rules)
    }

    /// The first of this envelope's special-token markers in `text`, with where it is:
    /// they are the only special tokens a message content may hold (Qwen's
    /// `<tool_call>`; the other envelopes write their markers as plain text).
    pub(crate) fn next_marker(&self, text: &str) -> Option<(usize, &'static str)> {
        match self {
            Envelope::Qwen => ["<tool_call>", "</tool_call>"]
                .into_iter()
                .filter_map(|m| text.find(m).map(|at| (at, m)))
                .min_by_key(|&(at, _)| at),
            Envelope::Smollm2 | Envelope::Json => None,
        }
    }

    /// How one tool is listed in the system prompt (one line of JSON).
    pub(crate) fn describe_tool(spec: &ToolSpec) -> String {
        to_json_spaced(&json!({
            "name": spec.name,
            "description": spec.description,
            "parameters": spec.parameters,
        }))
    }

    /// System-prompt text that lists the tools, shows the call format and says what to
    /// write when no tool fits, as `choice` allows.
    pub(crate) fn describe_tools(&self, specs: &[ToolSpec], choice: ToolChoice) -> String {
        let listing: Vec<String> = specs.iter().map(Envelope::describe_tool).collect();
        let example = ToolCall {
            name: "function_name1".into(),
            arguments: json!({"argument1": "value1", "argument2": "value2"}),
        };
        let format = self.render_calls(&[example]);
        let none = match (choice, self) {
            (ToolChoice::Decline, Envelope::Smollm2 | Envelope::Json) => {
                format!(
                    "\nIf no tool fits, reply with only:\n{}",
                    self.render_calls(&[])
                )
            }
            (ToolChoice::Required, _) => String::new(),
            _ => "\nIf no tool is needed, answer in plain text.".into(),
        };
        format!(
            "You can call these tools:\n<tools>\n{}\n</tools>\nTo call a tool, reply with only:\n{format}{none}",
            listing.join("\n")
        )
    }

    /// What follows one call in a list when another comes, and what closes the list,
    /// for envelopes that write several calls as one list (`None` for Qwen's one block
    /// per call).
    pub(crate) fn list_separators(&self) -> Option<(&'static str, &'static str)> {
        match self {
            Envelope::Smollm2 => Some((",\n", "\n]</tool_call>")),
            Envelope::Json => Some((", ", "]}")),
            Envelope::Qwen => None,
        }
    }

    /// What this envelope writes from the start of a turn to the end of the first call's
    /// tool name, closing quote included (the tool chooser scores what follows the
    /// opening the grammar forces).
    pub fn call_opening(&self, name: &str) -> String {
        let call = ToolCall {
            name: name.into(),
            arguments: serde_json::json!({}),
        };
        let text = self.render_calls(&[call]);
        let quoted = serde_json::to_string(name).unwrap_or_default();
        let end = text
            .find(&quoted)
            .map_or(text.len(), |at| at + quoted.len());
        text[..end].to_string()
    }

    /// How calls appear in an assistant message: exactly what the grammar produces.
    pub fn render_calls(&self, calls: &[ToolCall]) -> String {
        let objs: Vec<Value> = calls
            .iter()
            .map(|c| json!({"name": c.name, "arguments": c.arguments}))
            .collect();
        match self {
            Envelope::Smollm2 if objs.is_empty() => "<tool_call>[]</tool_call>".into(),
            Envelope::Smollm2 => format!(
                "<tool_call>[\n{}\n]</tool_call>",
                objs.iter()
                    .map(to_json_spaced)
                    .collect::<Vec<_>>()
                    .join(",\n")
            ),
            Envelope::Qwen => objs
                .iter()
                .map(|o| format!("<tool_call>\n{}\n</tool_call>", to_json_spaced(o)))
                .collect::<Vec<_>>()
                .join("\n"),
            Envelope::Json => to_json_spaced(&json!({"tool_calls": objs})),
        }
    }

    /// Split a finished turn into prose and calls, checking every call against `specs` and
    /// dropping word-for-word repeats.
    pub fn parse(&self, text: &str, specs: &[ToolSpec]) -> Result<Turn, EnvelopeError> {
        let (prose, raw_calls) = match self {
            Envelope::Smollm2 => match text.find("<tool_call>") {
                None => (text.to_string(), Vec::new()),
                Some(at) => {
                    let body = &text[at + "<tool_call>".len()..];
                    // Parse one JSON value from the front: a string inside it may itself
                    // contain "</tool_call>", so the marker cannot be searched for first.
                    let (v, _) = first_json(body)?;
                    let calls = match v {
                        Value::Array(a) => a,
                        one @ Value::Object(_) => vec![one],
                        other => return Err(EnvelopeError::Shape(other.to_string())),
                    };
                    (text[..at].to_string(), calls)
                }
            },
            Envelope::Qwen => {
                let mut prose = String::new();
                let mut calls = Vec::new();
                let mut rest = text;
                while let Some(at) = rest.find("<tool_call>") {
                    prose.push_str(&rest[..at]);
                    let body = &rest[at + "<tool_call>".len()..];
                    let (v, used) = first_json(body)?;
                    calls.push(v);
                    let after = body[used..].trim_start();
                    rest = after.strip_prefix("</tool_call>").unwrap_or(after);
                }
                prose.push_str(rest);
                (prose, calls)
            }
            Envelope::Json => {
                let t = text.trim_start();
                if t.starts_with('{') {
                    let v: Value = serde_json::from_str(t.trim_end())
                        .map_err(|e| EnvelopeError::Json(format!("{e}: {t}")))?;
                    match v.get("tool_calls") {
                        Some(Value::Array(a)) => (String::new(), a.clone()),
                        _ => return Err(EnvelopeError::Shape(v.to_string())),
                    }
                } else {
                    (text.to_string(), Vec::new())
                }
            }
        };
        let mut calls = Vec::with_capacity(raw_calls.len());
        for c in raw_calls {
            let (Some(name), Some(arguments)) =
                (c.get("name").and_then(Value::as_str), c.get("arguments"))
            else {
                return Err(EnvelopeError::Shape(c.to_string()));
            };
            let spec = specs.iter().find(|s| s.name == name).ok_or_else(|| {
                EnvelopeError::UnknownTool {
                    name: name.to_string(),
                    available: specs
                        .iter()
                        .map(|s| s.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", "),
                }
            })?;
            spec.validate(arguments)
                .map_err(|errors| EnvelopeError::Arguments {
                    name: name.to_string(),
                    errors,
                })?;
            let call = ToolCall {
                name: name.to_string(),
                arguments: arguments.clone(),
            };
            // A call repeated word for word in one turn is a small model looping, never a
            // second request: keep the first.
            if !calls.contains(&call) {
                calls.push(call);
            }
        }
        Ok(Turn {
            prose: prose.trim().to_string(),
            calls,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn specs() -> Vec<ToolSpec> {
        vec![
            ToolSpec::new(
                "calc_mean",
                "Mean of numbers.",
                json!({"type": "object", "properties": {"values": {"type": "array", "items": {"type": "number"}}}, "required": ["values"]}),
            )
            .unwrap(),
            ToolSpec::new("system_time", "Current time.", json!({"type": "object", "properties": {}})).unwrap(),
        ]
    }

    #[test]
    fn spaced_json_matches_python_dumps() {
        let v = json!({"name": "a", "arguments": {"x": [1, 2.5], "s": "q\""}});
        assert_eq!(
            to_json_spaced(&v),
            r#"{"name": "a", "arguments": {"x": [1, 2.5], "s": "q\""}}"#
        );
    }

    #[test]
    fn rendered_calls_parse_back_for_every_envelope() {
        let calls = vec![
            ToolCall {
                name: "calc_mean".into(),
                arguments: json!({"values": [3, 5, 10]}),
            },
            ToolCall {
                name: "system_time".into(),
                arguments: json!({}),
            },
        ];
        for env in [Envelope::Smollm2, Envelope::Qwen, Envelope::Json] {
            let text = env.render_calls(&calls);
            let turn = env.parse(&text, &specs()).unwrap();
            assert_eq!(turn.calls, calls, "{env:?}: {text}");
            assert_eq!(turn.prose, "");
        }
    }

    #[test]
    fn a_marker_inside_a_string_does_not_end_the_call() {
        let specs = vec![ToolSpec::new(
            "answer",
            "",
            json!({"type": "object", "properties": {"text": {"type": "string"}}}),
        )
        .unwrap()];
        let text = r#"<tool_call>[{"name": "answer", "arguments": {"text": "a }}]</tool_call> b"}}]</tool_call>"#;
        let turn = Envelope::Smollm2.parse(text, &specs).unwrap();
        assert_eq!(
            turn.calls[0].arguments["text"],
            json!("a }}]</tool_call> b")
        );
        let q = "<tool_call>\n{\"name\": \"answer\", \"arguments\": {\"text\": \"x</tool_call>\"}}\n</tool_call>";
        let turn = Envelope::Qwen.parse(q, &specs).unwrap();
        assert_eq!(turn.calls[0].arguments["text"], json!("x</tool_call>"));
    }

    #[test]
    fn word_for_word_repeats_in_one_turn_are_dropped() {
        let mean = |v: Value| ToolCall {
            name: "calc_mean".into(),
            arguments: json!({ "values": v }),
        };
        let looped = vec![
            mean(json!([1])),
            mean(json!([2])),
            mean(json!([1])),
            mean(json!([2])),
        ];
        let text = Envelope::Smollm2.render_calls(&looped);
        let turn = Envelope::Smollm2.parse(&text, &specs()).unwrap();
        assert_eq!(turn.calls, vec![mean(json!([1])), mean(json!([2]))]);
    }

    #[test]
    fn smollm2_calls_are_one_per_line_and_an_empty_list_declines() {
        let calls = vec![ToolCall {
            name: "system_time".into(),
            arguments: json!({}),
        }];
        assert_eq!(
            Envelope::Smollm2.render_calls(&calls),
            "<tool_call>[\n{\"name\": \"system_time\", \"arguments\": {}}\n]</tool_call>"
        );
        assert_eq!(
            Envelope::Smollm2.render_calls(&[]),
            "<tool_call>[]</tool_call>"
        );
        let prompt = Envelope::Smollm2.describe_tools(&specs(), ToolChoice::Decline);
        assert!(prompt.contains("<tool_call>[]</tool_call>"), "{prompt}");
        let prompt = Envelope::Smollm2.describe_tools(&specs(), ToolChoice::Required);
        assert!(!prompt.contains("[]"), "{prompt}");
    }

    #[test]
    fn prose_turns_have_no_calls() {
        for env in [Envelope::Smollm2, Envelope::Qwen, Envelope::Json] {
            let turn = env.parse("The mean is 6.", &specs()).unwrap();
            assert_eq!(turn.prose, "The mean is 6.");
            assert!(turn.calls.is_empty());
        }
    }

    #[test]
    fn bad_calls_are_errors_not_silence() {
        let env = Envelope::Smollm2;
        assert!(matches!(
            env.parse("<tool_call>[{\"name\": ", &specs()),
            Err(EnvelopeError::Json(_))
        ));
        assert!(matches!(
            env.parse(
                r#"<tool_call>[{"name": "fly", "arguments": {}}]</tool_call>"#,
                &specs()
            ),
            Err(EnvelopeError::UnknownTool { .. })
        ));
        assert!(matches!(
            env.parse(
                r#"<tool_call>[{"name": "calc_mean", "arguments": {"values": "x"}}]</tool_call>"#,
                &specs()
            ),
            Err(EnvelopeError::Arguments { .. })
        ));
    }

    #[test]
    fn grammar_fills_every_placeholder() {
        for env in [Envelope::Smollm2, Envelope::Qwen, Envelope::Json] {
            for choice in [
                ToolChoice::Auto,
                ToolChoice::Required,
                ToolChoice::Decline,
                ToolChoice::None,
            ] {
                let g = env.grammar(&specs(), choice, true);
                assert!(!g.contains('@'), "{env:?} {choice:?}: {g}");
            }
        }
    }
}
