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
//! declared default (`tool::default`: "Default is true.") is the schema's own guess for
//! it; that default is one more source, for that parameter alone.
//!
//! The same wrapper keeps an argument's array from looping: a 135M model that has
//! written an item equal to the one before it goes on repeating it until the token
//! limit, so once an item equals the one before it, the tokens that would go on to
//! another item are pushed down and the array closes.
//!
//! The bonus is applied by a `Backend` wrapper (`Copying`), so the grammar, the sampler
//! and the decode loop are untouched; the wrapper reads what the turn has written so far
//! to know where in the JSON it is. It knows nothing of tools beyond one name to leave
//! alone (the pseudo-tool that answers in words).

use std::collections::HashMap;

use crate::backend::{Backend, BackendError, ChatTemplate, TokenId, Tokenize, Vocab};
use crate::tool::{default, ToolSpec};

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
pub struct CopyIndex {
    sources: Vec<Vec<u8>>,
    /// Per source: the one tool parameter it is for (a declared default), or any.
    scope: Vec<Option<(Vec<u8>, Vec<u8>)>>,
    /// Declared defaults that are JSON literals (`true`, `false`): the parameter, and
    /// the tokens that start the literal (with or without a space before it).
    literals: Vec<(Vec<u8>, Vec<u8>, Vec<TokenId>)>,
    /// Per source, per byte position: the tokens that spell the source from there.
    at: Vec<Vec<Vec<Entry>>>,
    /// Tokens that close a string value (start with `"`).
    string_enders: Vec<TokenId>,
    /// Tokens that can follow a finished number (start with `,`, `}` or `]`).
    number_enders: Vec<TokenId>,
    /// Tokens that go on to another item (start with `,`), and those that close a
    /// string item and go on (start with `",`).
    commas: Vec<TokenId>,
    quote_commas: Vec<TokenId>,
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
        for d in defaults {
            let place = (d.tool.as_bytes().to_vec(), d.key.as_bytes().to_vec());
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
        let mut commas = Vec::new();
        let mut quote_commas = Vec::new();
        for id in 0..vocab.len() as TokenId {
            let piece = vocab.piece(id);
            if piece.starts_with(b",") {
                commas.push(id);
            } else if piece.starts_with(b"\",") {
                quote_commas.push(id);
            }
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
            literals,
            at,
            string_enders,
            number_enders,
            commas,
            quote_commas,
            bonus,
            exempt: exempt.map(str::to_string),
        }
    }

    /// The tokens to favour after the turn has written `written` (into `out`); returns
    /// the tokens that would make an array loop there. One scan of the text serves both.
    fn favoured(&self, written: &[u8], out: &mut Vec<TokenId>) -> &[TokenId] {
        out.clear();
        let scan = Scan::over(written);
        let looping: &[TokenId] = match scan.looping() {
            Some(Loop::Number | Loop::Closed) => &self.commas,
            Some(Loop::String) => &self.quote_commas,
            None => &[],
        };
        let Some(cx) = scan.context() else {
            return looping;
        };
        if self
            .exempt
            .as_deref()
            .is_some_and(|e| cx.tool == e.as_bytes())
        {
            return looping;
        }
        if cx.value == Value::Start {
            for (tool, key, starts) in &self.literals {
                if cx.tool == tool.as_slice() && cx.key == key.as_slice() {
                    out.extend_from_slice(starts);
                }
            }
        }
        for (s, text) in self.sources.iter().enumerate() {
            if let Some((tool, key)) = &self.scope[s] {
                if cx.tool != tool.as_slice() || cx.key != key.as_slice() {
                    continue;
                }
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
        looping
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
            });
        }
    }
    out
}

/// Wraps the backend for one generation: every forward pass's logits get the copy bonus
/// for what the turn has written up to then.
pub struct Copying<'a> {
    pub inner: &'a mut dyn Backend,
    pub index: &'a CopyIndex,
    /// Every token of the context, as the cache holds it.
    pub seq: Vec<TokenId>,
    /// Where the turn's own text starts in `seq`.
    pub turn_start: usize,
    /// Added to each favoured token's logit (the index's own bonus unless raised).
    pub bonus: f32,
    favoured: Vec<TokenId>,
    written: Vec<u8>,
}

impl<'a> Copying<'a> {
    pub fn new(
        inner: &'a mut dyn Backend,
        index: &'a CopyIndex,
        seq: Vec<TokenId>,
        turn_start: usize,
    ) -> Copying<'a> {
        Copying {
            inner,
            index,
            seq,
            turn_start,
            bonus: index.bonus,
            favoured: Vec::with_capacity(256),
            written: Vec::with_capacity(1024),
        }
    }
}

impl Backend for Copying<'_> {
    fn name(&self) -> &'static str {
        self.inner.name()
    }
    fn vocab(&self) -> &Vocab {
        self.inner.vocab()
    }
    fn chat_template(&self) -> &ChatTemplate {
        self.inner.chat_template()
    }
    fn context_len(&self) -> usize {
        self.inner.context_len()
    }
    fn tokenize(&self, text: &str, special: bool) -> Result<Vec<TokenId>, BackendError> {
        self.inner.tokenize(text, special)
    }
    fn tokenizer(&self) -> std::sync::Arc<dyn Tokenize> {
        self.inner.tokenizer()
    }
    fn forward(&mut self, keep: usize, tokens: &[TokenId]) -> Result<&mut [f32], BackendError> {
        self.seq.truncate(keep);
        self.seq.extend_from_slice(tokens);
        self.written.clear();
        let vocab = self.inner.vocab();
        for &t in &self.seq[self.turn_start.min(self.seq.len())..] {
            self.written.extend_from_slice(vocab.piece(t));
        }
        let looping = self.index.favoured(&self.written, &mut self.favoured);
        let bonus = self.bonus;
        let logits = self.inner.forward(keep, tokens)?;
        for &t in &self.favoured {
            if let Some(l) = logits.get_mut(t as usize) {
                *l += bonus;
            }
        }
        for &t in looping {
            if let Some(l) = logits.get_mut(t as usize) {
                *l -= LOOP_PENALTY;
            }
        }
        Ok(logits)
    }
}

/// How an array is about to repeat its last item.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Loop {
    /// The number being written equals the item before it.
    Number,
    /// The string being written equals the item before it, up to its closing quote.
    String,
    /// The string just closed equals the item before it.
    Closed,
}

/// Pushed below every ordinary logit (not to -inf: if the grammar allows nothing else,
/// the model still may).
const LOOP_PENALTY: f32 = 1.0e4;

/// Where a value of a call's arguments stands.
#[derive(Debug, PartialEq)]
enum Value<'a> {
    /// Nothing of it written yet.
    Start,
    /// Inside a string: the bytes after the opening quote.
    String(&'a [u8]),
    /// Inside a number: its bytes so far.
    Number(&'a [u8]),
}

#[derive(Debug, PartialEq)]
struct Context<'a> {
    /// The call's tool name (empty if not yet known).
    tool: &'a [u8],
    /// The key of the innermost object the value is in (an array item's is the
    /// array's).
    key: &'a [u8],
    value: Value<'a>,
}

#[derive(Debug)]
enum Frame {
    /// An object: the key last read, and whether a key comes next.
    Object {
        key: Option<(usize, usize)>,
        want_key: bool,
    },
    /// An array: the spans of its last two scalar items (strings with their quotes).
    Array { items: [Option<(usize, usize)>; 2] },
}

/// The JSON a turn has written, read byte by byte (text outside any JSON value, such as
/// an envelope's markers, is passed over).
struct Scan<'a> {
    text: &'a [u8],
    stack: Vec<Frame>,
    /// Start of the string or number being read.
    open: Option<(usize, bool)>,
    escaped: bool,
    /// The last tool name read, as a span of `text`.
    tool: (usize, usize),
    last: u8,
}

impl<'a> Scan<'a> {
    fn over(text: &'a [u8]) -> Scan<'a> {
        let mut s = Scan {
            text,
            stack: Vec::new(),
            open: None,
            escaped: false,
            tool: (0, 0),
            last: 0,
        };
        for i in 0..text.len() {
            s.push(i);
        }
        s
    }

    fn key_is(&self, frame: &Frame, name: &[u8]) -> bool {
        matches!(frame, Frame::Object { key: Some((a, b)), .. } if &self.text[*a..*b] == name)
    }

    /// Some frame below the innermost one is the value of an "arguments" key.
    fn in_arguments(&self) -> bool {
        let n = self.stack.len();
        n >= 2
            && self.stack[..n - 1]
                .iter()
                .any(|f| self.key_is(f, b"arguments"))
    }

    fn push(&mut self, i: usize) {
        let b = self.text[i];
        if let Some((start, is_string)) = self.open {
            if is_string {
                if self.escaped {
                    self.escaped = false;
                } else if b == b'\\' {
                    self.escaped = true;
                } else if b == b'"' {
                    self.open = None;
                    self.end_string(start, i);
                }
                return;
            }
            if number_byte(b) {
                return;
            }
            self.open = None;
            self.item((start, i));
        }
        match b {
            b'{' => self.stack.push(Frame::Object {
                key: None,
                want_key: true,
            }),
            b'[' => self.stack.push(Frame::Array { items: [None; 2] }),
            b'}' | b']' => {
                self.stack.pop();
            }
            b',' => {
                if let Some(Frame::Object { want_key, .. }) = self.stack.last_mut() {
                    *want_key = true;
                }
            }
            b'"' if !self.stack.is_empty() => self.open = Some((i + 1, true)),
            b'-' | b'0'..=b'9' if !self.stack.is_empty() => self.open = Some((i, false)),
            _ => {}
        }
        if !b.is_ascii_whitespace() {
            self.last = b;
        }
    }

    fn end_string(&mut self, start: usize, end: usize) {
        let in_arguments = self.in_arguments();
        match self.stack.last_mut() {
            Some(Frame::Object { key, want_key }) if *want_key => {
                *key = Some((start, end));
                *want_key = false;
            }
            Some(Frame::Object {
                key: Some((a, b)), ..
            }) if !in_arguments && &self.text[*a..*b] == b"name" => {
                self.tool = (start, end);
            }
            Some(Frame::Array { .. }) => self.item((start - 1, end + 1)),
            _ => {}
        }
        self.last = b'"';
    }

    /// A scalar value ended at `span`: if it is an array's item, remember it.
    fn item(&mut self, span: (usize, usize)) {
        if let Some(Frame::Array { items }) = self.stack.last_mut() {
            *items = [items[1], Some(span)];
        }
    }

    /// Is the array being written about to repeat its last item as the next one? An
    /// item equal to the one before it is how a small model's list starts looping.
    fn looping(&self) -> Option<Loop> {
        let Some(Frame::Array {
            items: [prev, Some(last)],
        }) = self.stack.last()
        else {
            return None;
        };
        if !self.in_arguments() {
            return None;
        }
        let last = &self.text[last.0..last.1];
        let same = |a: &[u8], b: &[u8]| a == b;
        match self.open {
            Some((start, false)) if same(&self.text[start..], last) => Some(Loop::Number),
            Some((start, true)) => {
                let cur = &self.text[start - 1..];
                (last.len() == cur.len() + 1 && last.starts_with(cur)).then_some(Loop::String)
            }
            None if self.last == b'"' => {
                let prev = prev.map(|p| &self.text[p.0..p.1]);
                prev.is_some_and(|p| same(p, last)).then_some(Loop::Closed)
            }
            _ => None,
        }
    }

    /// What is being written at the end of the text, if it is a value of the arguments.
    fn context(&self) -> Option<Context<'a>> {
        if !self.in_arguments() {
            return None;
        }
        let value = match (self.open, self.stack.last()?) {
            (
                Some((start, true)),
                Frame::Object {
                    want_key: false, ..
                }
                | Frame::Array { .. },
            ) => Value::String(&self.text[start..]),
            (Some((start, false)), _) => Value::Number(&self.text[start..]),
            (
                None,
                Frame::Object {
                    want_key: false, ..
                },
            ) if self.last == b':' => Value::Start,
            (None, Frame::Array { .. }) if matches!(self.last, b'[' | b',') => Value::Start,
            _ => return None,
        };
        let key = self
            .stack
            .iter()
            .rev()
            .find_map(|f| match f {
                Frame::Object { key, .. } => Some(key.map_or(&[][..], |(a, b)| &self.text[a..b])),
                Frame::Array { .. } => None,
            })
            .unwrap_or_default();
        Some(Context {
            tool: &self.text[self.tool.0..self.tool.1],
            key,
            value,
        })
    }
}

fn alnum(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b >= 0x80
}

/// A copied value may start at `p`: the start of a word (or of a number after `$`), or
/// of a path or negative number (`/turtle1/pose`, `-7`) after a space or an opening.
pub(super) fn word_start(text: &[u8], p: usize) -> bool {
    let Some(&b) = text.get(p) else {
        return false;
    };
    let before = p.checked_sub(1).map(|i| text[i]);
    if alnum(b) {
        return before.is_none_or(|c| !alnum(c));
    }
    matches!(b, b'/' | b'~' | b'-')
        && before.is_none_or(|c| c.is_ascii_whitespace() || b"\"'([{,:=".contains(&c))
}

/// A byte a JSON number may hold.
pub(super) fn number_byte(b: u8) -> bool {
    b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E')
}

/// A copied string may end at `p`.
pub(super) fn word_end(text: &[u8], p: usize) -> bool {
    p > 0 && (p == text.len() || !alnum(text[p]))
}

/// A copied number may end at `p`: no digit follows, nor a decimal point and a digit, nor
/// an exponent ("1e-9"), nor a digit group ("5,10" ends after the 5; "400,000" does not).
pub(super) fn number_end(text: &[u8], p: usize) -> bool {
    let digit_at = |i: usize| text.get(i).is_some_and(u8::is_ascii_digit);
    match text.get(p) {
        None => true,
        Some(b) if b.is_ascii_digit() => false,
        Some(b'.') => !digit_at(p + 1),
        Some(b'e' | b'E') if p > 0 && text[p - 1].is_ascii_digit() => {
            !(digit_at(p + 1) || (matches!(text.get(p + 1), Some(b'-' | b'+')) && digit_at(p + 2)))
        }
        Some(b',') => !digit_group_at(text, p),
        Some(_) => true,
    }
}

/// The comma at `p` separates digit groups: a digit before it and exactly three after.
fn digit_group_at(text: &[u8], p: usize) -> bool {
    text[p] == b','
        && p > 0
        && text[p - 1].is_ascii_digit()
        && text
            .get(p + 1..p + 4)
            .is_some_and(|g| g.iter().all(u8::is_ascii_digit))
        && !text.get(p + 4).is_some_and(u8::is_ascii_digit)
}

/// `text` with the numbers it spells as words written in digits ("initial velocity is
/// zero" → "initial velocity is 0").
fn number_words_as_digits(text: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(text.len());
    let mut i = 0;
    while i < text.len() {
        let end = i + text[i..]
            .iter()
            .position(|b| !b.is_ascii_alphabetic())
            .unwrap_or(text.len() - i);
        if end == i {
            out.push(text[i]);
            i += 1;
            continue;
        }
        let word = String::from_utf8_lossy(&text[i..end]).to_ascii_lowercase();
        let alone = i == 0 || !alnum(text[i - 1]);
        match super::verify::number_word(&word)
            .filter(|_| alone && !text.get(end).is_some_and(|&b| alnum(b)))
        {
            Some(n) => out.extend_from_slice(format!("{n}").as_bytes()),
            None => out.extend_from_slice(&text[i..end]),
        }
        i = end;
    }
    out
}

/// `text` with the thousands separators of its numbers removed: a comma between a digit
/// and exactly three digits ("1,250,000" → "1250000"; "5,10" stays a list).
pub(super) fn without_digit_grouping(text: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(text.len());
    for (i, &b) in text.iter().enumerate() {
        if !digit_group_at(text, i) {
            out.push(b);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::vocab::TokenKind;

    fn cx(text: &str) -> Option<(String, String)> {
        Scan::over(text.as_bytes()).context().map(|c| {
            let v = match c.value {
                Value::Start => "start".to_string(),
                Value::String(s) => format!("string:{}", String::from_utf8_lossy(s)),
                Value::Number(s) => format!("number:{}", String::from_utf8_lossy(s)),
            };
            (String::from_utf8_lossy(c.tool).into_owned(), v)
        })
    }

    #[test]
    fn the_scan_finds_argument_values_only() {
        let call = "<tool_call>[\n{\"name\": \"f\", \"arguments\": {\"city\": ";
        assert_eq!(cx(call), Some(("f".into(), "start".into())));
        assert_eq!(
            cx(&format!("{call}\"Sea")),
            Some(("f".into(), "string:Sea".into()))
        );
        assert_eq!(cx(&format!("{call}\"Seattle\"")), None);
        assert_eq!(cx(&format!("{call}\"Seattle\", \"d")), None, "a key");
        assert_eq!(
            cx(&format!("{call}\"a\\\"b")),
            Some(("f".into(), "string:a\\\"b".into()))
        );
        assert_eq!(
            cx(&format!("{call}[1, 4")),
            Some(("f".into(), "number:4".into()))
        );
        assert_eq!(
            cx(&format!("{call}[1, ")),
            Some(("f".into(), "start".into()))
        );
        assert_eq!(cx("<tool_call>[\n{\"name\": \"f"), None);
        assert_eq!(cx("<tool_call>[\n{\"name\": \"f\", \"arguments\": "), None);
        let second = "{\"name\": \"f\", \"arguments\": {\"a\": 1}},\n{\"name\": \"g\", \"arguments\": {\"b\": \"x";
        assert_eq!(cx(second), Some(("g".into(), "string:x".into())));
        let json = "{\"tool_calls\": [{\"name\": \"h\", \"arguments\": {\"n\": -1";
        assert_eq!(cx(json), Some(("h".into(), "number:-1".into())));
    }

    #[test]
    fn an_array_that_repeats_its_last_item_is_caught() {
        let l = |t: &str| Scan::over(t.as_bytes()).looping();
        let call = "[{\"name\": \"f\", \"arguments\": {\"xs\": [";
        assert_eq!(l(&format!("{call}\"a\", \"b")), None);
        assert_eq!(l(&format!("{call}\"a\", \"a")), Some(Loop::String));
        assert_eq!(l(&format!("{call}\"a\", \"ab")), None);
        assert_eq!(l(&format!("{call}\"a\", \"a\"")), Some(Loop::Closed));
        assert_eq!(l(&format!("{call}\"a\", \"b\"")), None);
        assert_eq!(l(&format!("{call}1, 1")), Some(Loop::Number));
        assert_eq!(l(&format!("{call}1, 12")), None);
        assert_eq!(l(&format!("{call}1")), None);
        // Only arrays inside arguments.
        assert_eq!(l("[\"a\", \"a\""), None);
    }

    #[test]
    fn number_words_are_also_digits() {
        assert_eq!(
            number_words_as_digits(b"Three hours, velocity zero; someone, 2twelve"),
            b"3 hours, velocity 0; someone, 2twelve"
        );
    }

    #[test]
    fn digit_groups_and_word_edges() {
        assert_eq!(
            without_digit_grouping(b"$1,250,000 and 3,4"),
            b"$1250000 and 3,4"
        );
        assert!(word_start(b"$400", 1) && !word_start(b"ab", 1));
        assert!(word_start(b"echo /turtle1/pose", 5) && !word_start(b"echo /turtle1/pose", 13));
        assert!(word_start(b"b = -7", 4) && !word_start(b"3-7", 1));
        assert!(word_end(b"New York, NY", 8) && !word_end(b"New York", 5));
        assert!(!number_end(b"400,000", 3) && number_end(b"5, 10", 1) && number_end(b"5.", 1));
        // A list written without spaces: each number ends at its comma.
        assert!(number_end(b"5,10 and 15", 1) && number_end(b"1,5 and 10", 1));
        assert!(!number_end(b"2.5", 1) && !number_end(b"1,250,000", 1));
        assert!(!number_end(b"1e-9 C", 1) && !number_end(b"2E5", 1) && number_end(b"2 eggs", 1));
    }

    fn vocab(pieces: &[&str]) -> Vocab {
        Vocab::new(
            pieces.iter().map(|p| p.as_bytes().to_vec()).collect(),
            vec![TokenKind::Normal; pieces.len()],
            Vec::new(),
            None,
            false,
        )
    }

    fn favoured(index: &CopyIndex, v: &Vocab, written: &str) -> Vec<String> {
        let mut out = Vec::new();
        index.favoured(written.as_bytes(), &mut out);
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
}
