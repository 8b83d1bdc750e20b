//! The one reader of the JSON a model's turn writes: fed a token's bytes at a time, it
//! knows how deep the turn is, whether a string or number is open, which tool's call is
//! being written and which argument value. Everything that needs to know where a turn
//! stands (the decode loop's closing steer, logits hooks, list decisions, repeat guards)
//! reads it here. It depends on nothing but `lexicon`.
//!
//! Text outside any JSON value (an envelope's `<tool_call>` marker) is passed over. It
//! does not validate: the grammar does that.
//!
//! Cost: O(1) per byte pushed; `context` walks the frame stack, which is kept shallow:
//! past `MAX_DEPTH` open brackets only a count is kept (the text may come from a server,
//! issue 41), and nothing inside them is an argument value this reader reports.

/// Open objects and arrays whose keys and items are followed; deeper ones are counted.
pub const MAX_DEPTH: usize = 64;

/// What an argument value is, where the turn stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Value<'a> {
    /// Nothing of it written yet.
    Start,
    /// Inside a string: the bytes after the opening quote.
    String(&'a [u8]),
    /// Inside a number: its bytes so far.
    Number(&'a [u8]),
}

/// The argument value being written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ValueContext<'a> {
    /// The call's tool name (empty if not yet known).
    pub tool: &'a [u8],
    /// The key of the innermost object the value is in (an array item's is the array's).
    pub key: &'a [u8],
    pub value: Value<'a>,
}

/// How an arguments array is about to repeat its last item (a small model's lists loop:
/// `["a", "b", "b", "b", ...]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loop {
    /// The number being written equals the item before it.
    Number,
    /// The string being written equals the item before it, up to its closing quote.
    String,
    /// The string just closed equals the item before it.
    Closed,
}

#[derive(Debug, Clone)]
enum Frame {
    /// An object: where it starts, the key last read, and whether a key comes next.
    Object {
        start: usize,
        key: Option<(usize, usize)>,
        want_key: bool,
    },
    /// An array: the spans of its last two scalar items (strings with their quotes).
    Array { items: [Option<(usize, usize)>; 2] },
}

/// The JSON a turn has written so far, read byte by byte.
#[derive(Debug, Clone, Default)]
pub struct JsonScan {
    text: Vec<u8>,
    stack: Vec<Frame>,
    /// Start of the string (after its quote) or number being read, and which it is.
    open: Option<(usize, bool)>,
    escaped: bool,
    /// The last tool name read, as a span of `text`.
    tool: (usize, usize),
    /// The last byte that is not whitespace.
    last: u8,
    /// The calls written so far, whole (`{` to `}`), in order.
    calls: Vec<(usize, usize)>,
    /// Brackets open past `MAX_DEPTH` (inside the last frame of `stack`).
    deep: usize,
}

impl JsonScan {
    pub fn new() -> JsonScan {
        JsonScan {
            text: Vec::with_capacity(1024),
            ..JsonScan::default()
        }
    }

    /// A scan of `text` from its start.
    pub fn over(text: &[u8]) -> JsonScan {
        let mut s = JsonScan::new();
        s.push(text);
        s
    }

    /// Everything pushed so far.
    pub fn text(&self) -> &[u8] {
        &self.text
    }

    /// Read more of the turn.
    pub fn push(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.text.push(b);
            self.step(self.text.len() - 1);
        }
    }

    /// Forget everything after the first `len` bytes (the turn was rewound). Re-reads
    /// from the start: rewinds are rare and turns short.
    pub fn truncate(&mut self, len: usize) {
        if len >= self.text.len() {
            return;
        }
        let mut text = std::mem::take(&mut self.text);
        text.truncate(len);
        *self = JsonScan::new();
        self.push(&text);
    }

    /// Open objects and arrays.
    pub fn depth(&self) -> usize {
        self.stack.len() + self.deep
    }

    pub(crate) fn in_string(&self) -> bool {
        matches!(self.open, Some((_, true)))
    }

    /// How much is left open: brackets, plus one for an open string or number. The
    /// closing steer (`decode::close`) drives this to zero.
    pub fn open_count(&self) -> usize {
        self.depth() + usize::from(self.open.is_some())
    }

    /// Where the call being written starts (its `{`), if one is open.
    pub fn call_start(&self) -> Option<usize> {
        self.stack.iter().find_map(|f| match f {
            Frame::Object {
                start,
                key: Some((a, b)),
                ..
            } if matches!(&self.text[*a..*b], b"name" | b"arguments") => Some(*start),
            _ => None,
        })
    }

    /// The calls closed so far (their JSON text, `{` to `}`), in order.
    pub fn closed_calls(&self) -> impl Iterator<Item = &[u8]> {
        self.calls.iter().map(|&(a, b)| &self.text[a..b])
    }

    /// Where each closed call's text starts and ends.
    pub(crate) fn closed_call_spans(&self) -> &[(usize, usize)] {
        &self.calls
    }

    /// Whether a call object is open.
    fn in_call(&self) -> bool {
        self.call_start().is_some()
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

    fn step(&mut self, i: usize) {
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
            if crate::lexicon::number_byte(b) {
                return;
            }
            self.open = None;
            self.item((start, i));
        }
        if self.deep > 0 {
            self.step_deep(i, b);
            return;
        }
        match b {
            b'{' | b'[' if self.stack.len() >= MAX_DEPTH => self.deep = 1,
            b'{' => self.stack.push(Frame::Object {
                start: i,
                key: None,
                want_key: true,
            }),
            b'[' => self.stack.push(Frame::Array { items: [None; 2] }),
            b'}' | b']' => {
                if let Some(Frame::Object {
                    start,
                    key: Some((a, b)),
                    ..
                }) = self.stack.pop()
                {
                    if matches!(&self.text[a..b], b"name" | b"arguments") && !self.in_call() {
                        self.calls.push((start, i + 1));
                    }
                }
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

    /// A byte outside strings and numbers past `MAX_DEPTH`: only brackets count there.
    fn step_deep(&mut self, i: usize, b: u8) {
        match b {
            b'{' | b'[' => self.deep += 1,
            b'}' | b']' => self.deep -= 1,
            b'"' => self.open = Some((i + 1, true)),
            b'-' | b'0'..=b'9' => self.open = Some((i, false)),
            _ => {}
        }
        if !b.is_ascii_whitespace() {
            self.last = b;
        }
    }

    fn end_string(&mut self, start: usize, end: usize) {
        if self.deep > 0 {
            self.last = b'"';
            return;
        }
        let in_arguments = self.in_arguments();
        match self.stack.last_mut() {
            Some(Frame::Object { key, want_key, .. }) if *want_key => {
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
        if self.deep > 0 {
            return;
        }
        if let Some(Frame::Array { items }) = self.stack.last_mut() {
            *items = [items[1], Some(span)];
        }
    }

    /// Is the arguments array being written about to repeat its last item as the next?
    pub fn looping(&self) -> Option<Loop> {
        if self.deep > 0 {
            return None;
        }
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
        match self.open {
            Some((start, false)) if &self.text[start..] == last => Some(Loop::Number),
            Some((start, true)) => {
                let cur = &self.text[start - 1..];
                (last.len() == cur.len() + 1 && last.starts_with(cur)).then_some(Loop::String)
            }
            None if self.last == b'"' => {
                let prev = prev.map(|p| &self.text[p.0..p.1]);
                (prev == Some(last)).then_some(Loop::Closed)
            }
            _ => None,
        }
    }

    /// What is being written at the end of the text, if it is a value of the arguments.
    pub fn context(&self) -> Option<ValueContext<'_>> {
        if self.deep > 0 || !self.in_arguments() {
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
        Some(ValueContext {
            tool: &self.text[self.tool.0..self.tool.1],
            key,
            value,
        })
    }
}

/// How much a text leaves open, from a given state: the same rules as `JsonScan`,
/// without remembering keys or text (a copy per candidate token must be cheap).
#[derive(Debug, Clone, Copy)]
pub struct Openness {
    depth: usize,
    string: bool,
    escaped: bool,
    number: bool,
}

impl Openness {
    pub fn of(scan: &JsonScan) -> Openness {
        let mut o = Openness {
            depth: 0,
            string: false,
            escaped: false,
            number: false,
        };
        o.push(scan.text());
        o
    }

    pub fn push(&mut self, bytes: &[u8]) {
        for &b in bytes {
            if self.string {
                match b {
                    _ if self.escaped => self.escaped = false,
                    b'\\' => self.escaped = true,
                    b'"' => self.string = false,
                    _ => {}
                }
                continue;
            }
            if self.number && crate::lexicon::number_byte(b) {
                continue;
            }
            self.number = false;
            match b {
                b'{' | b'[' => self.depth += 1,
                b'}' | b']' => self.depth = self.depth.saturating_sub(1),
                b'"' if self.depth > 0 => self.string = true,
                b'-' | b'0'..=b'9' if self.depth > 0 => self.number = true,
                _ => {}
            }
        }
    }

    /// Brackets open, plus one for an open string or number.
    pub fn count(&self) -> usize {
        self.depth + usize::from(self.string || self.number)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cx(text: &str) -> Option<(String, String)> {
        let scan = JsonScan::over(text.as_bytes());
        scan.context().map(|c| {
            let v = match c.value {
                Value::Start => "start".to_string(),
                Value::String(s) => format!("string:{}", String::from_utf8_lossy(s)),
                Value::Number(s) => format!("number:{}", String::from_utf8_lossy(s)),
            };
            (String::from_utf8_lossy(c.tool).into_owned(), v)
        })
    }

    #[test]
    fn argument_values_are_found_and_nothing_else() {
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
        // Without the envelope's spacing too.
        let tight = "{\"tool_calls\":[{\"name\":\"h\",\"arguments\":{\"n\":-1";
        assert_eq!(cx(tight), Some(("h".into(), "number:-1".into())));
    }

    #[test]
    fn depth_call_start_and_rewind() {
        let text =
            "<tool_call>[\n{\"name\": \"f\", \"arguments\": {\"s\": \"}]{\"}},\n{\"name\": \"g";
        let mut s = JsonScan::over(text.as_bytes());
        assert_eq!(s.depth(), 2);
        assert_eq!(s.call_start(), text.rfind('{'));
        let first_end = text.find("}},").unwrap() + 2;
        assert_eq!(s.closed_calls().count(), 1);
        s.truncate(first_end);
        assert_eq!(s.closed_calls().count(), 1);
        assert_eq!(
            s.closed_calls().next().unwrap(),
            &text.as_bytes()[text.find('{').unwrap()..first_end]
        );
        s.truncate(first_end - 1);
        assert_eq!(s.closed_calls().count(), 0);
        s.push(b"}");
        assert_eq!(s.depth(), 1);
        assert_eq!(s.call_start(), None);
        assert_eq!(s.open_count(), 1);
    }

    #[test]
    fn an_array_that_repeats_its_last_item_is_caught() {
        let l = |t: &str| JsonScan::over(t.as_bytes()).looping();
        let call = "[{\"name\": \"f\", \"arguments\": {\"xs\": [";
        assert_eq!(l(&format!("{call}\"a\", \"b")), None);
        assert_eq!(l(&format!("{call}\"a\", \"a")), Some(Loop::String));
        assert_eq!(l(&format!("{call}\"a\", \"ab")), None);
        assert_eq!(l(&format!("{call}\"a\", \"a\"")), Some(Loop::Closed));
        assert_eq!(l(&format!("{call}\"a\", \"b\"")), None);
        assert_eq!(l(&format!("{call}1, 1")), Some(Loop::Number));
        assert_eq!(l(&format!("{call}1, 12")), None);
        assert_eq!(l(&format!("{call}1")), None);
        assert_eq!(l("[\"a\", \"a\""), None, "only arrays inside arguments");
    }

    #[test]
    fn nesting_past_the_bound_is_counted_not_followed() {
        let call = "[{\"name\": \"f\", \"arguments\": {\"xs\": ";
        let deep = format!("{call}{}", "[".repeat(100_000));
        let mut s = JsonScan::over(deep.as_bytes());
        assert_eq!(s.depth(), 3 + 100_000);
        assert_eq!(s.stack.len(), MAX_DEPTH);
        assert_eq!(s.context(), None);
        assert_eq!(s.open_count(), Openness::of(&s).count());
        // Strings and brackets inside are read as such; closing comes back to the call.
        s.push(b"\"]]\", 1");
        assert_eq!(s.depth(), 3 + 100_000);
        s.push(&b"]".repeat(100_000));
        s.push(b", \"y\": \"ab");
        assert_eq!(s.depth(), 3);
        assert_eq!(
            cx(&String::from_utf8_lossy(s.text())),
            Some(("f".into(), "string:ab".into()))
        );
        assert_eq!(s.context().map(|c| c.key), Some(&b"y"[..]));
        s.push(b"\"}}]");
        assert_eq!(s.depth(), 0);
        assert_eq!(s.closed_calls().count(), 1);
    }

    #[test]
    fn openness_counts_what_is_left_to_close() {
        let at = |t: &str| {
            let mut o = Openness::of(&JsonScan::new());
            o.push(t.as_bytes());
            o.count()
        };
        assert_eq!(
            at("<tool_call>[\n{\"name\": \"f\", \"arguments\": {\"s\": \"ab"),
            4
        );
        assert_eq!(at("[{\"a\": \"}]\\\"\""), 2);
        assert_eq!(at("[{\"n\": 12"), 3);
        assert_eq!(at("[{\"n\": 12}"), 1);
        assert_eq!(at("[{\"n\": true}]"), 0);
    }
}
