//! Guards on what a turn writes: patterns a small model falls into and never leaves.
//!
//! - `LoopGuard`: an arguments array whose new item equals the one before it goes on
//!   repeating it until the token limit (`["Friends", "Stranger Things", "Stranger
//!   Things", ...]`); once an item equals the one before it, the tokens that would go on
//!   to another item are pushed down and the array closes.
//! - `RepeatGuard`: a call after the first that would repeat an earlier one word for word
//!   (a repeat is dropped when the turn is parsed, so it would be a wasted call): while
//!   the call matches an earlier one up to that call's last string or number argument,
//!   the tokens that would finish that value as it was are pushed down, and those that
//!   only lead towards it, unless they also start another value the request spells ("1"
//!   after a call with 10 is allowed for "5,10 and 15"). The earlier arguments are left
//!   to the model: a list mostly shares its first values and varies a later one ("for
//!   10, 20 and 30 years").
//!
//! Pushed down, never to −∞: if the grammar allows nothing else, the model still may.

use super::Strategy;
use crate::backend::{TokenId, Vocab};
use crate::decode::TokenContext;
use crate::json::{JsonScan, Loop, Value};
use crate::lexicon::{number_byte, number_end, without_digit_grouping, word_end, word_start};

/// Pushed below every ordinary logit, far above the grammar's −∞.
const PENALTY: f32 = 1.0e4;

/// See the module header. Cost: per token of an array, a look at the scan; the token
/// lists are read from the vocabulary once.
pub(crate) struct LoopGuard {
    /// Tokens that go on to another item (start with `,`), and those that close a string
    /// item and go on (start with `",`).
    commas: Vec<TokenId>,
    quote_commas: Vec<TokenId>,
}

impl LoopGuard {
    pub fn new(vocab: &Vocab) -> LoopGuard {
        let mut g = LoopGuard {
            commas: Vec::new(),
            quote_commas: Vec::new(),
        };
        for id in 0..vocab.len() as TokenId {
            let piece = vocab.piece(id);
            if piece.starts_with(b",") {
                g.commas.push(id);
            } else if piece.starts_with(b"\",") {
                g.quote_commas.push(id);
            }
        }
        g
    }
}

impl Strategy for LoopGuard {
    fn name(&self) -> &'static str {
        "loop-guard"
    }

    fn adjust(&mut self, cx: &TokenContext, logits: &mut [f32]) {
        let banned = match cx.scan.looping() {
            Some(Loop::Number | Loop::Closed) => &self.commas,
            Some(Loop::String) => &self.quote_commas,
            None => return,
        };
        for &t in banned {
            if let Some(l) = logits.get_mut(t as usize) {
                *l -= PENALTY;
            }
        }
    }
}

/// See the module header. Cost: the earlier calls are read once per call; per token of
/// a call that matches an earlier one up to its last plain argument, a pass over the
/// vocabulary.
pub(crate) struct RepeatGuard {
    /// The request, as written and with its digit groups joined.
    request: [Vec<u8>; 2],
    /// The earlier calls and the key of each one's last string or number argument, for
    /// the call starting at `for_call`.
    earlier: Vec<(Vec<u8>, Option<Vec<u8>>)>,
    for_call: Option<usize>,
}

impl RepeatGuard {
    pub fn new(request: &str) -> RepeatGuard {
        let text = request.as_bytes().to_vec();
        let plain = without_digit_grouping(&text);
        RepeatGuard {
            request: [text, plain],
            earlier: Vec::new(),
            for_call: None,
        }
    }
}

impl Strategy for RepeatGuard {
    fn name(&self) -> &'static str {
        "repeat-guard"
    }

    fn adjust(&mut self, cx: &TokenContext, logits: &mut [f32]) {
        let Some(start) = cx.scan.call_start() else {
            return;
        };
        if self.for_call != Some(start) {
            self.for_call = Some(start);
            self.earlier = cx
                .scan
                .closed_calls()
                .map(|c| (c.to_vec(), last_plain_argument(c).map(<[u8]>::to_vec)))
                .collect();
        }
        if self.earlier.is_empty() {
            return;
        }
        for t in repeating_after(cx.vocab, &self.earlier, &self.request, cx.scan, start) {
            logits[t as usize] -= PENALTY;
        }
    }
}

/// The tokens that would go on repeating one of `earlier` where `scan` stands (in the
/// call starting at `start`).
fn repeating_after(
    vocab: &Vocab,
    earlier: &[(Vec<u8>, Option<Vec<u8>>)],
    request: &[Vec<u8>],
    scan: &JsonScan,
    start: usize,
) -> Vec<TokenId> {
    let Some(cx) = scan.context() else {
        return Vec::new();
    };
    let cur = &scan.text()[start..];
    // The value written so far, a string's opening quote included; a value not yet
    // begun counts once the separator before it is written whole.
    let (partial, string): (&[u8], Option<bool>) = match cx.value {
        Value::Start if !cur.ends_with(b" ") => return Vec::new(),
        Value::Start => (&[], None),
        Value::String(p) => (&cur[cur.len() - p.len() - 1..], Some(true)),
        Value::Number(p) => (p, Some(false)),
    };
    let mut banned = Vec::new();
    for (call, last_key) in earlier {
        let Some(rest) = call.strip_prefix(cur) else {
            continue;
        };
        if last_key.as_deref() != Some(cx.key) {
            continue;
        }
        // How many bytes of `rest` finish the value (a string's closing quote included).
        let string = string.unwrap_or(rest.first() == Some(&b'"'));
        let end = if string {
            let mut j = JsonScan::over(b"[");
            j.push(partial);
            let Some(close) = rest.iter().position(|&b| {
                let was_open = j.in_string();
                j.push(&[b]);
                was_open && !j.in_string()
            }) else {
                continue;
            };
            close + 1
        } else {
            rest.iter()
                .position(|&b| !number_byte(b))
                .unwrap_or(rest.len())
        };
        // The value as it was, and as written so far (quotes left out).
        let strip = |v: &[u8]| -> Vec<u8> { v.iter().copied().filter(|&b| b != b'"').collect() };
        let written_so_far = strip(partial);
        let before = [written_so_far.as_slice(), &strip(&rest[..end])].concat();
        for t in 0..vocab.len() as TokenId {
            let p = vocab.piece(t);
            if p.is_empty() || !rest.starts_with(p) {
                continue;
            }
            let so_far = [written_so_far.as_slice(), &strip(p)].concat();
            if p.len() >= end || !spells_another(request, &so_far, &before, string) {
                banned.push(t);
            }
        }
    }
    banned
}

/// Does one of `texts` spell, from a word start, a value that begins with `so_far` and is
/// not `before`?
fn spells_another(texts: &[Vec<u8>], so_far: &[u8], before: &[u8], string: bool) -> bool {
    let ends = |t: &[u8], at: usize| {
        if string {
            word_end(t, at)
        } else {
            number_end(t, at)
        }
    };
    texts.iter().any(|t| {
        (0..t.len()).any(|q| {
            word_start(t, q)
                && t[q..].starts_with(so_far)
                && !(t[q..].starts_with(before) && ends(t, q + before.len()))
        })
    })
}

/// The last argument of `call` (a call's JSON text) whose value is a string or number,
/// as the call spells its key.
fn last_plain_argument(call: &[u8]) -> Option<&[u8]> {
    let v: serde_json::Value = serde_json::from_slice(call).ok()?;
    let key = v["arguments"]
        .as_object()?
        .iter()
        .rev()
        .find(|(_, v)| v.is_string() || v.is_number())?
        .0
        .clone();
    // Keys are plain names: the JSON text holds them unescaped.
    let quoted = format!("\"{key}\"");
    let at = call
        .windows(quoted.len())
        .rposition(|w| w == quoted.as_bytes())?;
    Some(&call[at + 1..at + 1 + key.len()])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vocab(pieces: &[&str]) -> Vocab {
        Vocab::from_pieces(pieces)
    }

    fn adjusted(s: &mut dyn Strategy, v: &Vocab, text: &str) -> Vec<String> {
        let scan = JsonScan::over(text.as_bytes());
        let mut logits = vec![0.0; v.len()];
        s.adjust(
            &TokenContext {
                vocab: v,
                scan: &scan,
                remaining: 100,
            },
            &mut logits,
        );
        (0..v.len())
            .filter(|&i| logits[i] < 0.0)
            .map(|i| String::from_utf8_lossy(v.piece(i as TokenId)).into_owned())
            .collect()
    }

    #[test]
    fn a_repeat_is_refused_at_the_last_plain_argument_only() {
        let pieces = [
            "4", "1", "15", "5", "\"", "\"Wells", " Fargo", " Fargo\"", "\"W", "}",
        ];
        let v = vocab(&pieces);
        let first = r#"[{"name": "pay", "arguments": {"loan": 400000, "term": 15, "bank": "Wells Fargo", "fixed": true}}, "#;
        assert_eq!(
            last_plain_argument(&first.as_bytes()[1..first.len() - 2]),
            Some(&b"bank"[..])
        );
        let mut g = RepeatGuard::new("Pay 400000 over 15 or 20 years at Wells Fargo or Wells Bank");
        let at = |g: &mut RepeatGuard, rest: &str| adjusted(g, &v, &format!("{first}{rest}"));
        // The loan and the term may be the same again.
        assert!(at(&mut g, r#"{"name": "pay", "arguments": {"loan": "#).is_empty());
        assert!(at(
            &mut g,
            r#"{"name": "pay", "arguments": {"loan": 400000, "term": 1"#
        )
        .is_empty());
        // The bank may not: neither all at once nor piece by piece, but a token that
        // starts another bank the request names is left alone.
        let bank = r#"{"name": "pay", "arguments": {"loan": 400000, "term": 15, "bank": "#;
        assert!(at(&mut g, bank).is_empty());
        let wells = format!("{bank}\"Wells");
        assert_eq!(at(&mut g, &wells), [" Fargo", " Fargo\""]);
        // Once the call differs, nothing is refused.
        assert!(at(
            &mut g,
            r#"{"name": "pay", "arguments": {"loan": 5, "term": 15, "bank": "Wells"#
        )
        .is_empty());
        // A number: "1" may start 10 as well as the 15 of the earlier call; "15" may not.
        let short = r#"[{"name": "f", "arguments": {"n": 15}}, "#;
        let mut g = RepeatGuard::new("factorials of 5,10 and 15");
        let n = r#"{"name": "f", "arguments": {"n": "#;
        assert_eq!(adjusted(&mut g, &v, &format!("{short}{n}")), ["15"]);
        assert_eq!(adjusted(&mut g, &v, &format!("{short}{n}1")), ["5"]);
        // Without another value to go to, the way towards the old one is refused too.
        let mut g = RepeatGuard::new("factorial of 15");
        assert_eq!(adjusted(&mut g, &v, &format!("{short}{n}")), ["1", "15"]);
    }

    #[test]
    fn a_looping_array_is_closed() {
        let v = vocab(&[",", ", \"", "\",", "\"]", "]"]);
        let mut g = LoopGuard::new(&v);
        let call = r#"[{"name": "f", "arguments": {"xs": ["#;
        assert!(adjusted(&mut g, &v, &format!(r#"{call}"a", "b"#)).is_empty());
        assert_eq!(adjusted(&mut g, &v, &format!(r#"{call}"a", "a"#)), ["\","]);
        assert_eq!(
            adjusted(&mut g, &v, &format!(r#"{call}"a", "a""#)),
            [",", ", \""]
        );
        assert_eq!(adjusted(&mut g, &v, &format!("{call}1, 1")), [",", ", \""]);
    }
}
