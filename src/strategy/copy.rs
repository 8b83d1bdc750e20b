//! Copy bias: argument values lean towards spans of the text they should come from.
//!
//! A tool call's values are nearly always written somewhere already: the operator's
//! request ("Seattle", "$400,000", "Maroon 5") or, in an agent run, a tool's result (a
//! topic name). A 135M model often writes a likelier-looking value instead ("New York"
//! for Seattle, 400 for 400,000). While a string or number value of a call's arguments is
//! being written, the tokens that would go on copying a source from a word start get a
//! fixed bonus on their logits, and so do the tokens that end the value where the copied
//! span ends a word. It is a nudge, not a rule: a value the request does not spell (a
//! unit, an enum member, a converted date) is still written when the model prefers it by
//! more than the bonus.
//!
//! A required parameter the request says nothing of must still be written, and its
//! declared default (`default`: "Default is true.") is the schema's own guess for it;
//! that default is one more source, for that parameter alone.
//!
//! Cost: the index is built once per turn (a few milliseconds at a 49k vocabulary: every
//! token looked up against every span of the sources); per token of an argument value,
//! a walk over the sources' word starts. Nothing outside argument values.

use std::collections::HashMap;

use super::{default, Strategy};
use crate::backend::{TokenId, Vocab};
use crate::decode::TokenContext;
use crate::json::{JsonScan, Value};
use crate::lexicon::{
    number_byte, number_end, number_words_as_digits, without_digit_grouping, word_end, word_start,
};
use crate::tool::ToolSpec;

/// Longest piece of a source a single token is looked up for (longer tokens are rare
/// and would only copy runs of spaces or digits).
const MAX_PIECE: usize = 32;

/// A vocabulary entry that spells part of a source from some position.
#[derive(Debug, Clone, Copy)]
struct Entry {
    token: TokenId,
    /// Bytes of the source it spells (quotes left out).
    len: u16,
    /// The token begins with the value's opening quote.
    open: bool,
    /// The token ends with the value's closing quote.
    close: bool,
    /// What it spells is a number's digits.
    numeric: bool,
}

/// The sources of one turn, indexed against a vocabulary: built once per turn (a few
/// milliseconds at a 49k vocabulary), read at every step of a value.
#[derive(Debug)]
pub(crate) struct CopyIndex {
    sources: Vec<Vec<u8>>,
    /// Per source: the one tool parameter it is for (a declared default), or any.
    scope: Vec<Option<(Vec<u8>, Vec<u8>)>>,
    /// Parameters (tool, key) whose sources are their scoped ones alone.
    exclusive: Vec<(Vec<u8>, Vec<u8>)>,
    /// Declared defaults that are JSON literals (`true`, `false`): the parameter, and
    /// the tokens that start the literal (with or without a space before it).
    literals: Vec<(Vec<u8>, Vec<u8>, Vec<TokenId>)>,
    /// Per source, per byte position: the tokens that spell the source from there.
    at: Vec<Vec<Vec<Entry>>>,
    /// Tokens that close a string value (start with `"`).
    string_enders: Vec<TokenId>,
    /// Tokens that can follow a finished number (start with `,`, `}` or `]`).
    number_enders: Vec<TokenId>,
    /// Added to each favoured token's logit.
    bonus: f32,
    /// Calls of this tool are left alone.
    exempt: Option<String>,
}

impl CopyIndex {
    /// Index `sources` against `vocab`. Each source is also indexed with the thousands
    /// separators of its numbers removed ("400,000" → "400000"), since JSON numbers have
    /// none.
    /// Each of `defaults` is offered to its own parameter only.
    pub fn new(
        vocab: &Vocab,
        sources: &[&str],
        defaults: &[Scoped],
        bonus: f32,
        exempt: Option<&str>,
    ) -> CopyIndex {
        let mut texts: Vec<Vec<u8>> = Vec::new();
        let mut scope = Vec::new();
        let mut literals = Vec::new();
        let mut exclusive = Vec::new();
        for d in defaults {
            let place = (d.tool.as_bytes().to_vec(), d.key.as_bytes().to_vec());
            if d.exclusive && !exclusive.contains(&place) {
                exclusive.push(place.clone());
            }
            if d.literal {
                let starts: Vec<TokenId> = (0..vocab.len() as TokenId)
                    .filter(|&t| {
                        let piece = vocab.piece(t).trim_ascii_start();
                        !piece.is_empty() && d.text.as_bytes().starts_with(piece)
                    })
                    .collect();
                literals.push((place.0, place.1, starts));
            } else if !d.text.is_empty() {
                texts.push(d.text.as_bytes().to_vec());
                scope.push(Some(place));
            }
        }
        for s in sources.iter().filter(|s| !s.is_empty()) {
            let bytes = s.as_bytes().to_vec();
            let plain = without_digit_grouping(&bytes);
            let digits = number_words_as_digits(&plain);
            if digits != plain {
                texts.push(digits);
            }
            if plain != bytes {
                texts.push(plain);
            }
            texts.push(bytes);
        }
        scope.resize(texts.len(), None);
        let mut spans: HashMap<&[u8], Vec<(usize, usize)>> = HashMap::new();
        for (s, text) in texts.iter().enumerate() {
            for pos in 0..text.len() {
                for len in 1..=MAX_PIECE.min(text.len() - pos) {
                    spans
                        .entry(&text[pos..pos + len])
                        .or_default()
                        .push((s, pos));
                }
            }
        }
        let mut at: Vec<Vec<Vec<Entry>>> =
            texts.iter().map(|t| vec![Vec::new(); t.len()]).collect();
        let mut string_enders = Vec::new();
        let mut number_enders = Vec::new();
        for id in 0..vocab.len() as TokenId {
            let piece = vocab.piece(id);
            match piece.first() {
                Some(b'"') => string_enders.push(id),
                Some(b',' | b'}' | b']') => number_enders.push(id),
                _ => {}
            }
            let open = piece.first() == Some(&b'"');
            let core = &piece[usize::from(open)..];
            let close = core.len() > 1 && core.last() == Some(&b'"');
            let core = &core[..core.len() - usize::from(close)];
            if core.is_empty() || core.iter().any(|&b| b == b'"' || b == b'\\') {
                continue;
            }
            let numeric = core.iter().all(|&b| number_byte(b));
            for &(s, pos) in spans.get(core).map_or(&[][..], Vec::as_slice) {
                at[s][pos].push(Entry {
                    token: id,
                    len: core.len() as u16,
                    open,
                    close,
                    numeric,
                });
            }
        }
        CopyIndex {
            sources: texts,
            scope,
            exclusive,
            literals,
            at,
            string_enders,
            number_enders,
            bonus,
            exempt: exempt.map(str::to_string),
        }
    }

    /// The tokens to favour where `scan` stands (into `out`).
    fn favoured(&self, scan: &JsonScan, out: &mut Vec<TokenId>) {
        out.clear();
        let Some(cx) = scan.context() else {
            return;
        };
        if self
            .exempt
            .as_deref()
            .is_some_and(|e| cx.tool == e.as_bytes())
        {
            return;
        }
        if cx.value == Value::Start {
            for (tool, key, starts) in &self.literals {
                if cx.tool == tool.as_slice() && cx.key == key.as_slice() {
                    out.extend_from_slice(starts);
                }
            }
        }
        let only_scoped = self
            .exclusive
            .iter()
            .any(|(tool, key)| cx.tool == tool.as_slice() && cx.key == key.as_slice());
        for (s, text) in self.sources.iter().enumerate() {
            match &self.scope[s] {
                Some((tool, key)) if cx.tool != tool.as_slice() || cx.key != key.as_slice() => {
                    continue
                }
                None if only_scoped => continue,
                _ => {}
            }
            let mut ends = false;
            let starts = (0..text.len()).filter(|&p| word_start(text, p));
            match cx.value {
                Value::Start => {
                    for p in starts {
                        for e in &self.at[s][p] {
                            let end = p + e.len as usize;
                            let fits = if e.open {
                                !e.close || word_end(text, end)
                            } else {
                                e.numeric && !e.close
                            };
                            if fits {
                                out.push(e.token);
                            }
                        }
                    }
                }
                Value::String(partial) | Value::Number(partial) => {
                    let numeric = matches!(cx.value, Value::Number(_));
                    for q in starts {
                        if !text[q..].starts_with(partial) {
                            continue;
                        }
                        let c = q + partial.len();
                        if partial.is_empty() || c < text.len() {
                            for e in self.at[s].get(c).map_or(&[][..], Vec::as_slice) {
                                let end = c + e.len as usize;
                                let fits = !e.open
                                    && if numeric {
                                        e.numeric && !e.close
                                    } else {
                                        !e.close || word_end(text, end)
                                    };
                                if fits {
                                    out.push(e.token);
                                }
                            }
                        }
                        if !partial.is_empty() {
                            ends |= if numeric {
                                number_end(text, c)
                            } else {
                                word_end(text, c)
                            };
                        }
                    }
                }
            }
            if ends {
                match cx.value {
                    Value::Number(_) => out.extend_from_slice(&self.number_enders),
                    _ => out.extend_from_slice(&self.string_enders),
                }
            }
        }
        out.sort_unstable();
        out.dedup();
    }
}

/// A source for one tool parameter only: the default its schema declares, as written
/// there.
#[derive(Debug, Clone, PartialEq)]
pub struct Scoped {
    pub tool: String,
    pub key: String,
    pub text: String,
    /// A JSON literal (`true`, `false`), not a string's or number's text.
    pub literal: bool,
    /// The parameter's only candidates (with the other exclusive sources for it): what
    /// the request or a result spells is not favoured there. The names a robot holds
    /// are exclusive for the arguments that take them; a declared default is not.
    pub exclusive: bool,
}

/// The declared defaults of the required top-level parameters of `specs` (see
/// `tool::default`). A required value must be written even when the request says nothing
/// of it, and then the default is the schema's own guess; an optional one the request
/// says nothing of is best left out, and offering its default against what the request
/// does say ("by train", where the default is 'bus') only loses it.
pub fn defaults(specs: &[ToolSpec]) -> Vec<Scoped> {
    let mut out = Vec::new();
    for spec in specs {
        let Some(props) = spec.parameters["properties"].as_object() else {
            continue;
        };
        let required = spec.parameters["required"].as_array();
        let is_required = |k: &str| required.is_some_and(|r| r.iter().any(|x| x == k));
        for (key, prop) in props.iter().filter(|(k, _)| is_required(k)) {
            let Some(d) = default::declared(prop) else {
                continue;
            };
            let (Some(value), Some(text)) = (d.value, d.spelled) else {
                continue;
            };
            out.push(Scoped {
                tool: spec.name.clone(),
                key: key.clone(),
                literal: value.is_boolean(),
                text,
                exclusive: false,
            });
        }
    }
    out
}

/// The copy bias as a strategy: an index of one turn's sources and the bonus.
pub(crate) struct CopyBias {
    index: CopyIndex,
    /// The bonus in force (the index's own, or the strict one while a call is redone).
    bonus: f32,
    favoured: Vec<TokenId>,
}

/// Logit bonus of the copy bias when a turned-down call is written again: above the gap
/// between a 135M model's first and second choices at nearly every step, so a value the
/// request spells is written wherever the grammar allows one.
pub(crate) const STRICT_BONUS: f32 = 12.0;

impl CopyBias {
    pub fn new(index: CopyIndex) -> CopyBias {
        CopyBias {
            bonus: index.bonus,
            index,
            favoured: Vec::with_capacity(256),
        }
    }
}

impl Strategy for CopyBias {
    fn name(&self) -> &'static str {
        "copy-bias"
    }

    fn adjust(&mut self, cx: &TokenContext, logits: &mut [f32]) {
        self.index.favoured(cx.scan, &mut self.favoured);
        for &t in &self.favoured {
            if let Some(l) = logits.get_mut(t as usize) {
                *l += self.bonus;
            }
        }
    }

    fn strict(&mut self, on: bool) -> bool {
        self.bonus = if on {
            self.index.bonus.max(STRICT_BONUS)
        } else {
            self.index.bonus
        };
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vocab(pieces: &[&str]) -> Vocab {
        Vocab::from_pieces(pieces)
    }

    fn favoured(index: &CopyIndex, v: &Vocab, written: &str) -> Vec<String> {
        let mut out = Vec::new();
        index.favoured(&JsonScan::over(written.as_bytes()), &mut out);
        out.iter()
            .map(|&t| String::from_utf8_lossy(v.piece(t)).into_owned())
            .collect()
    }

    #[test]
    fn values_lean_towards_spans_of_the_request() {
        let v = vocab(&[
            "\"", "\"Se", "Se", "attle", "attle\"", "\",", "New", " York", "400", "000", ",", "}",
            "4", "\"San", "rattle",
        ]);
        let index = CopyIndex::new(
            &v,
            &["weather in Seattle for $400,000"],
            &[],
            3.0,
            Some("reply"),
        );
        let call = "[{\"name\": \"f\", \"arguments\": {\"city\": ";
        let start = favoured(&index, &v, call);
        assert!(start.contains(&"\"Se".into()) && start.contains(&"400".into()));
        assert!(start.contains(&"4".into()));
        assert!(!start.contains(&"New".into()) && !start.contains(&"\"San".into()));
        let inside = favoured(&index, &v, &format!("{call}\"Se"));
        assert_eq!(inside, ["attle", "attle\""]);
        // At a word end the value may close.
        let done = favoured(&index, &v, &format!("{call}\"Seattle"));
        assert_eq!(done, ["\"", "\"Se", "\",", "\"San"]);
        // Digit groups are read as one number, which ends only after them.
        let number = favoured(&index, &v, &format!("{call}400"));
        assert_eq!(number, ["000"]);
        let whole = favoured(&index, &v, &format!("{call}400000"));
        assert_eq!(whole, [",", "}"]);
        // The answer pseudo-tool writes its own words.
        let reply = "[{\"name\": \"reply\", \"arguments\": {\"text\": \"Se";
        assert!(favoured(&index, &v, reply).is_empty());
    }

    #[test]
    fn a_required_parameters_default_is_offered_to_it_only() {
        let v = vocab(&[
            "\"", "\"cm", "cm", "\",", "-", "-9", ".81", "9", " true", "true", " false",
        ]);
        let specs = [ToolSpec::new(
            "f",
            "",
            serde_json::json!({"type": "object", "properties": {
                "unit": {"type": "string", "description": "Default is 'cm'."},
                "g": {"type": "number", "description": "Default is -9.81 m/s^2."},
                "fmt": {"type": "boolean", "description": "Default is true."},
                "n": {"type": "number"},
                "opt": {"type": "number", "description": "Default is 4."}
            }, "required": ["unit", "g", "fmt", "n"]}),
        )
        .unwrap()];
        let d = defaults(&specs);
        assert_eq!(d.len(), 3);
        let index = CopyIndex::new(&v, &["no numbers here"], &d, 3.0, None);
        let call = |key: &str| format!("[{{\"name\": \"f\", \"arguments\": {{\"{key}\": ");
        assert_eq!(favoured(&index, &v, &call("unit")), ["\"cm"]);
        assert_eq!(favoured(&index, &v, &format!("{}\"", call("unit"))), ["cm"]);
        // As in the request, the digits after a minus sign are a word start too.
        assert_eq!(favoured(&index, &v, &call("g")), ["-", "-9", "9"]);
        assert_eq!(favoured(&index, &v, &format!("{}-9", call("g"))), [".81"]);
        assert_eq!(favoured(&index, &v, &call("fmt")), [" true", "true"]);
        // Another parameter, or the same name in another tool, gets none of them.
        assert!(favoured(&index, &v, &call("n")).is_empty());
        // An optional parameter's default is not offered.
        assert!(favoured(&index, &v, &call("opt")).is_empty());
        let other = "[{\"name\": \"h\", \"arguments\": {\"unit\": ";
        assert!(favoured(&index, &v, other).is_empty());
    }

    #[test]
    fn exclusive_sources_are_a_parameters_only_candidates() {
        let v = vocab(&[
            "\"", "\"/", "\"back", "ground", "/", "turtle", "sim", "\"turtle",
        ]);
        let names = [Scoped {
            tool: "get".into(),
            key: "node".into(),
            text: "/turtlesim".into(),
            literal: false,
            exclusive: true,
        }];
        let index = CopyIndex::new(&v, &["background of /turtlesim"], &names, 3.0, None);
        let call = |key: &str| format!("[{{\"name\": \"get\", \"arguments\": {{\"{key}\": ");
        // The node leans towards the robot's node, not towards other words of the request.
        let node = favoured(&index, &v, &call("node"));
        assert!(node.contains(&"\"/".into()), "{node:?}");
        assert!(!node.contains(&"\"back".into()), "{node:?}");
        // Another parameter copies the request as before.
        let name = favoured(&index, &v, &call("name"));
        assert!(name.contains(&"\"back".into()), "{name:?}");
    }
}
