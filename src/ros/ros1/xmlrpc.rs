//! XML-RPC as ROS 1 uses it: the master's and every node's API. Values, the call and
//! response documents, a reader for them, and the HTTP/1.0 exchange over one TCP
//! connection (the master is Python's `SimpleXMLRPCServer`; nodes answer the same way).
//!
//! The reader takes the subset XML-RPC documents use: elements, text, the five named
//! entities and numeric character references; no attributes, namespaces or CDATA.
//!
//! Any local process can call a node's API, so the reader is bounded: values nest at
//! most `MAX_DEPTH` deep, a document holds at most `MAX_ELEMENTS` tags and texts, an
//! HTTP message's head at most `MAX_HEAD` bytes and its body at most the limit the
//! caller gives (`MAX_REQUEST` for what a node is asked, `MAX_DOCUMENT` for what a
//! master answers), each checked before it is kept. The reader walks the text once,
//! keeping nothing but the values it builds.

use std::collections::VecDeque;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Largest answer read from the master or a node (a `getSystemState` of a big robot is
/// ~100 KB; a `getParam` of the whole tree can be more).
pub(crate) const MAX_DOCUMENT: usize = 16 << 20;

/// Largest call read by the node's API server (ROS's are a few hundred bytes).
pub(crate) const MAX_REQUEST: usize = 1 << 20;

/// Largest HTTP head (request or status line and headers).
pub(crate) const MAX_HEAD: usize = 64 << 10;

/// Deepest nesting of arrays and structs in one value (ROS's go three or four deep).
pub const MAX_DEPTH: usize = 32;

/// Most tags and texts in one document.
pub(crate) const MAX_ELEMENTS: usize = 1 << 20;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum XmlRpcError {
    #[error("a malformed XML-RPC document: {0}")]
    Malformed(String),
    #[error("an XML-RPC value nested more than {MAX_DEPTH} deep: refused")]
    TooDeep,
    #[error("an XML-RPC document of more than {MAX_ELEMENTS} elements: refused")]
    TooManyElements,
    #[error("{what} of {len} bytes, more than {limit}: refused")]
    TooLarge {
        what: &'static str,
        len: usize,
        limit: usize,
    },
    #[error("XML-RPC fault: {0}")]
    Fault(String),
    #[error("HTTP: {0}")]
    Http(String),
}

fn malformed(what: impl Into<String>) -> XmlRpcError {
    XmlRpcError::Malformed(what.into())
}

#[derive(Debug, Clone, PartialEq)]
pub enum XValue {
    Int(i64),
    Bool(bool),
    Double(f64),
    Str(String),
    Array(Vec<XValue>),
    Struct(Vec<(String, XValue)>),
    /// `base64` and `dateTime.iso8601` bodies, kept as written.
    Other(String),
}

impl XValue {
    pub fn str(s: &str) -> XValue {
        XValue::Str(s.to_string())
    }

    pub fn as_str(&self) -> Option<&str> {
        match self {
            XValue::Str(s) => Some(s),
            _ => None,
        }
    }

    pub(crate) fn as_int(&self) -> Option<i64> {
        match self {
            XValue::Int(i) => Some(*i),
            _ => None,
        }
    }

    pub fn as_array(&self) -> &[XValue] {
        match self {
            XValue::Array(a) => a,
            _ => &[],
        }
    }

    fn write(&self, out: &mut String) {
        out.push_str("<value>");
        match self {
            XValue::Int(i) if i32::try_from(*i).is_ok() => out.push_str(&format!("<i4>{i}</i4>")),
            // Beyond i32 XML-RPC has no integer: a double keeps the value.
            XValue::Int(i) => out.push_str(&format!("<double>{i}</double>")),
            XValue::Bool(b) => out.push_str(&format!("<boolean>{}</boolean>", u8::from(*b))),
            XValue::Double(d) => out.push_str(&format!("<double>{d:?}</double>")),
            XValue::Str(s) | XValue::Other(s) => {
                out.push_str("<string>");
                escape(s, out);
                out.push_str("</string>");
            }
            XValue::Array(items) => {
                out.push_str("<array><data>");
                for v in items {
                    v.write(out);
                }
                out.push_str("</data></array>");
            }
            XValue::Struct(members) => {
                out.push_str("<struct>");
                for (k, v) in members {
                    out.push_str("<member><name>");
                    escape(k, out);
                    out.push_str("</name>");
                    v.write(out);
                    out.push_str("</member>");
                }
                out.push_str("</struct>");
            }
        }
        out.push_str("</value>");
    }
}

fn escape(s: &str, out: &mut String) {
    for c in s.chars() {
        match c {
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '&' => out.push_str("&amp;"),
            c => out.push(c),
        }
    }
}

/// A `methodCall` document.
pub fn call_document(method: &str, params: &[XValue]) -> String {
    let mut out = String::from("<?xml version=\"1.0\"?>\n<methodCall><methodName>");
    escape(method, &mut out);
    out.push_str("</methodName><params>");
    for p in params {
        out.push_str("<param>");
        p.write(&mut out);
        out.push_str("</param>");
    }
    out.push_str("</params></methodCall>\n");
    out
}

/// A `methodResponse` document with one value.
pub(crate) fn response_document(value: &XValue) -> String {
    let mut out = String::from("<?xml version=\"1.0\"?>\n<methodResponse><params><param>");
    value.write(&mut out);
    out.push_str("</param></params></methodResponse>\n");
    out
}

#[derive(Debug, Clone, PartialEq)]
enum Token {
    Open(String),
    Close(String),
    Text(String),
}

fn unescape(raw: &str) -> Result<String, XmlRpcError> {
    let mut out = String::with_capacity(raw.len());
    let mut rest = raw;
    while let Some(at) = rest.find('&') {
        out.push_str(&rest[..at]);
        let end = rest[at..]
            .find(';')
            .ok_or_else(|| malformed("an unterminated entity"))?;
        let name = &rest[at + 1..at + end];
        let reference = |digits: Option<u32>| {
            digits
                .and_then(char::from_u32)
                .ok_or_else(|| malformed(format!("a bad character reference &{name};")))
        };
        let c = match name {
            "lt" => '<',
            "gt" => '>',
            "amp" => '&',
            "quot" => '"',
            "apos" => '\'',
            n if n.starts_with("#x") => reference(u32::from_str_radix(&n[2..], 16).ok())?,
            n if n.starts_with('#') => reference(n[1..].parse::<u32>().ok())?,
            n => {
                let shown: String = n.chars().take(20).collect();
                return Err(malformed(format!("an unknown entity &{shown};")));
            }
        };
        out.push(c);
        rest = &rest[at + end + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

/// Reads a document's tokens one at a time (two looked ahead at most), counting them.
struct Reader<'a> {
    rest: &'a str,
    ahead: VecDeque<Token>,
    elements: usize,
    depth: usize,
}

impl<'a> Reader<'a> {
    fn new(doc: &'a str) -> Reader<'a> {
        Reader {
            rest: doc,
            ahead: VecDeque::new(),
            elements: 0,
            depth: 0,
        }
    }

    /// Scan the next token (two for `<x/>`) onto `ahead`; false at the text's end.
    fn fill(&mut self) -> Result<bool, XmlRpcError> {
        loop {
            if self.rest.is_empty() {
                return Ok(false);
            }
            self.elements += 1;
            if self.elements > MAX_ELEMENTS {
                return Err(XmlRpcError::TooManyElements);
            }
            let lt = self.rest.find('<').unwrap_or(self.rest.len());
            if lt > 0 {
                let text = unescape(&self.rest[..lt])?;
                self.rest = &self.rest[lt..];
                self.ahead.push_back(Token::Text(text));
                return Ok(true);
            }
            let end = self
                .rest
                .find('>')
                .ok_or_else(|| malformed("an unterminated tag"))?;
            let inner = &self.rest[1..end];
            self.rest = &self.rest[end + 1..];
            if inner.starts_with('?') || inner.starts_with('!') {
                continue;
            }
            if let Some(name) = inner.strip_prefix('/') {
                self.ahead.push_back(Token::Close(name.trim().to_string()));
                return Ok(true);
            }
            let (name, empty) = match inner.strip_suffix('/') {
                Some(name) => (name, true),
                None => (inner, false),
            };
            let name = name.split_whitespace().next().unwrap_or("").to_string();
            self.ahead.push_back(Token::Open(name.clone()));
            if empty {
                self.ahead.push_back(Token::Close(name));
            }
            return Ok(true);
        }
    }

    /// The `i`th token ahead (0 or 1), scanned if need be.
    fn peek(&mut self, i: usize) -> Result<Option<&Token>, XmlRpcError> {
        while self.ahead.len() <= i && self.fill()? {}
        Ok(self.ahead.get(i))
    }

    fn next(&mut self) -> Result<Option<Token>, XmlRpcError> {
        self.peek(0)?;
        Ok(self.ahead.pop_front())
    }

    fn skip_space(&mut self) -> Result<(), XmlRpcError> {
        while matches!(self.peek(0)?, Some(Token::Text(t)) if t.trim().is_empty()) {
            self.ahead.pop_front();
        }
        Ok(())
    }

    fn expect(&mut self, want: Token) -> Result<(), XmlRpcError> {
        self.skip_space()?;
        match self.next()? {
            Some(t) if t == want => Ok(()),
            other => {
                let (open, name) = match &want {
                    Token::Open(n) => ("", n),
                    Token::Close(n) | Token::Text(n) => ("/", n),
                };
                Err(malformed(format!(
                    "expected <{open}{name}>, found {other:?}"
                )))
            }
        }
    }

    fn open(&mut self, name: &str) -> Result<(), XmlRpcError> {
        self.expect(Token::Open(name.to_string()))
    }

    fn close(&mut self, name: &str) -> Result<(), XmlRpcError> {
        self.expect(Token::Close(name.to_string()))
    }

    fn peek_open(&mut self) -> Result<Option<String>, XmlRpcError> {
        self.skip_space()?;
        Ok(match self.peek(0)? {
            Some(Token::Open(n)) => Some(n.clone()),
            _ => None,
        })
    }

    /// Text up to the next tag (empty when there is none).
    fn text(&mut self) -> Result<String, XmlRpcError> {
        if !matches!(self.peek(0)?, Some(Token::Text(_))) {
            return Ok(String::new());
        }
        match self.ahead.pop_front() {
            Some(Token::Text(t)) => Ok(t),
            _ => Ok(String::new()),
        }
    }

    fn value(&mut self) -> Result<XValue, XmlRpcError> {
        self.open("value")?;
        // A value with no type element is a string.
        let empty = matches!(self.peek(0)?, Some(Token::Close(n)) if n == "value");
        let text = matches!(self.peek(0)?, Some(Token::Text(_)));
        let v = if empty {
            XValue::Str(String::new())
        } else if text && !matches!(self.peek(1)?, Some(Token::Open(_))) {
            XValue::Str(self.text()?)
        } else {
            self.typed()?
        };
        self.close("value")?;
        Ok(v)
    }

    fn typed(&mut self) -> Result<XValue, XmlRpcError> {
        let kind = self
            .peek_open()?
            .ok_or_else(|| malformed("a value without a type"))?;
        self.open(&kind)?;
        let v = match kind.as_str() {
            "i4" | "int" | "i8" => {
                let t = self.text()?;
                XValue::Int(
                    t.trim()
                        .parse()
                        .map_err(|_| malformed(format!("bad integer {:?}", short(&t))))?,
                )
            }
            "boolean" => XValue::Bool(self.text()?.trim() == "1"),
            "double" => {
                let t = self.text()?;
                XValue::Double(
                    t.trim()
                        .parse()
                        .map_err(|_| malformed(format!("bad double {:?}", short(&t))))?,
                )
            }
            "string" => XValue::Str(self.text()?),
            "base64" | "dateTime.iso8601" => XValue::Other(self.text()?),
            "nil" => XValue::Other(String::new()),
            "array" | "struct" => self.nested(&kind)?,
            other => {
                return Err(malformed(format!(
                    "unknown XML-RPC type <{}>",
                    short(other)
                )))
            }
        };
        self.close(&kind)?;
        Ok(v)
    }

    /// An array's or a struct's members, one level deeper (at most `MAX_DEPTH`).
    fn nested(&mut self, kind: &str) -> Result<XValue, XmlRpcError> {
        if self.depth >= MAX_DEPTH {
            return Err(XmlRpcError::TooDeep);
        }
        self.depth += 1;
        let v = if kind == "array" {
            self.open("data")?;
            let mut items = Vec::new();
            while self.peek_open()?.as_deref() == Some("value") {
                items.push(self.value()?);
            }
            self.close("data")?;
            XValue::Array(items)
        } else {
            let mut members = Vec::new();
            while self.peek_open()?.as_deref() == Some("member") {
                self.open("member")?;
                self.open("name")?;
                let name = self.text()?;
                self.close("name")?;
                members.push((name, self.value()?));
                self.close("member")?;
            }
            XValue::Struct(members)
        };
        self.depth -= 1;
        Ok(v)
    }
}

/// At most 40 characters of `s`, for messages.
fn short(s: &str) -> String {
    s.chars().take(40).collect()
}

/// The method name and parameters of a `methodCall`.
pub fn parse_call(doc: &str) -> Result<(String, Vec<XValue>), XmlRpcError> {
    let mut r = Reader::new(doc);
    r.open("methodCall")?;
    r.open("methodName")?;
    let method = r.text()?.trim().to_string();
    r.close("methodName")?;
    let mut params = Vec::new();
    if r.peek_open()?.as_deref() == Some("params") {
        r.open("params")?;
        while r.peek_open()?.as_deref() == Some("param") {
            r.open("param")?;
            params.push(r.value()?);
            r.close("param")?;
        }
        r.close("params")?;
    }
    Ok((method, params))
}

/// The value of a `methodResponse`, or the fault's text.
pub fn parse_response(doc: &str) -> Result<XValue, XmlRpcError> {
    let mut r = Reader::new(doc);
    r.open("methodResponse")?;
    if r.peek_open()?.as_deref() == Some("fault") {
        r.open("fault")?;
        let fault = r.value()?;
        return Err(XmlRpcError::Fault(format!("{fault:?}")));
    }
    r.open("params")?;
    r.open("param")?;
    r.value()
}

/// `http://host:port/` split into the address to connect to and the path.
pub(crate) fn split_uri(uri: &str) -> Result<(String, String), XmlRpcError> {
    let rest = uri
        .strip_prefix("http://")
        .ok_or_else(|| XmlRpcError::Http(format!("{uri}: not an http:// URI")))?;
    let (host, path) = match rest.find('/') {
        Some(i) => (&rest[..i], &rest[i..]),
        None => (rest, "/"),
    };
    if !host.contains(':') {
        return Err(XmlRpcError::Http(format!("{uri}: no port")));
    }
    Ok((host.to_string(), path.to_string()))
}

/// Read one HTTP message: a head of at most `MAX_HEAD` bytes, then a body of
/// `Content-Length` bytes or up to EOF, at most `limit` either way (a declared length
/// over it is refused before any of it is read).
pub(crate) async fn read_http(
    stream: &mut TcpStream,
    limit: usize,
) -> Result<(String, String), XmlRpcError> {
    let io = |e: std::io::Error| XmlRpcError::Http(e.to_string());
    let mut buf = Vec::new();
    let mut chunk = [0u8; 8192];
    let head_end = loop {
        if let Some(i) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            break i;
        }
        if buf.len() > MAX_HEAD {
            return Err(XmlRpcError::TooLarge {
                what: "an HTTP head",
                len: buf.len(),
                limit: MAX_HEAD,
            });
        }
        let n = stream.read(&mut chunk).await.map_err(io)?;
        if n == 0 {
            return Err(XmlRpcError::Http(
                "the connection closed before the HTTP headers ended".into(),
            ));
        }
        buf.extend_from_slice(&chunk[..n]);
    };
    let head = String::from_utf8_lossy(&buf[..head_end]).to_string();
    let mut body = buf[head_end + 4..].to_vec();
    let length = head.lines().find_map(|l| {
        let (k, v) = l.split_once(':')?;
        k.trim()
            .eq_ignore_ascii_case("content-length")
            .then(|| v.trim().parse::<usize>().ok())?
    });
    let too_large = |len: usize| XmlRpcError::TooLarge {
        what: "an HTTP body",
        len,
        limit,
    };
    match length {
        Some(n) if n > limit => return Err(too_large(n)),
        Some(n) => {
            while body.len() < n {
                let got = stream.read(&mut chunk).await.map_err(io)?;
                if got == 0 {
                    return Err(XmlRpcError::Http(
                        "the connection closed inside the HTTP body".into(),
                    ));
                }
                body.extend_from_slice(&chunk[..got]);
            }
            body.truncate(n);
        }
        None => {
            stream
                .take((limit + 1).saturating_sub(body.len()) as u64)
                .read_to_end(&mut body)
                .await
                .map_err(io)?;
            if body.len() > limit {
                return Err(too_large(body.len()));
            }
        }
    }
    String::from_utf8(body)
        .map(|b| (head, b))
        .map_err(|_| XmlRpcError::Http("an HTTP body that is not UTF-8".into()))
}

/// Call `method` on the XML-RPC server at `uri`, within `timeout`.
pub async fn call(
    uri: &str,
    method: &str,
    params: &[XValue],
    timeout: Duration,
) -> Result<XValue, XmlRpcError> {
    let (host, path) = split_uri(uri)?;
    let body = call_document(method, params);
    let exchange = async {
        let mut stream = TcpStream::connect(&host)
            .await
            .map_err(|e| XmlRpcError::Http(format!("cannot reach {uri}: {e}")))?;
        let request = format!(
            "POST {path} HTTP/1.0\r\nHost: {host}\r\nUser-Agent: ferrosa\r\nContent-Type: text/xml\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        );
        stream
            .write_all(request.as_bytes())
            .await
            .map_err(|e| XmlRpcError::Http(e.to_string()))?;
        let (head, doc) = read_http(&mut stream, MAX_DOCUMENT).await?;
        let status = head.split_whitespace().nth(1);
        if !head.starts_with("HTTP/1.") || status != Some("200") {
            return Err(XmlRpcError::Http(format!(
                "{uri} answered {}",
                short(head.lines().next().unwrap_or(""))
            )));
        }
        parse_response(&doc)
    };
    tokio::time::timeout(timeout, exchange).await.map_err(|_| {
        XmlRpcError::Http(format!("{uri} did not answer {method} within {timeout:?}"))
    })?
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_call_reads_back_as_written() {
        let params = vec![
            XValue::str("/ferrosa <&>"),
            XValue::Int(-3),
            XValue::Bool(true),
            XValue::Double(0.5),
            XValue::Array(vec![XValue::str("TCPROS"), XValue::Array(vec![])]),
            XValue::Struct(vec![("a".into(), XValue::Int(1))]),
        ];
        let doc = call_document("requestTopic", &params);
        assert_eq!(parse_call(&doc).unwrap(), ("requestTopic".into(), params));
    }

    #[test]
    fn python_responses_read_with_untyped_strings_and_entities() {
        // As Python's xmlrpc writes them: newlines between elements, untyped strings.
        let doc = "<?xml version='1.0'?>\n<methodResponse>\n<params>\n<param>\n<value><array><data>\n<value><int>1</int></value>\n<value><string>current system state</string></value>\n<value>a &amp; b&#62;</value>\n<value><string></string></value>\n<value><boolean>0</boolean></value>\n</data></array></value>\n</param>\n</params>\n</methodResponse>\n";
        let v = parse_response(doc).unwrap();
        assert_eq!(
            v,
            XValue::Array(vec![
                XValue::Int(1),
                XValue::str("current system state"),
                XValue::str("a & b>"),
                XValue::str(""),
                XValue::Bool(false),
            ])
        );
    }

    #[test]
    fn faults_and_broken_documents_are_errors() {
        let fault = "<methodResponse><fault><value><struct><member><name>faultCode</name><value><int>1</int></value></member></struct></value></fault></methodResponse>";
        assert!(matches!(
            parse_response(fault).unwrap_err(),
            XmlRpcError::Fault(_)
        ));
        assert!(parse_response("<methodResponse><params><param><value><int>x</int>").is_err());
        assert!(parse_response("<methodResponse><params><param><value>&bogus;</value>").is_err());
    }

    fn nested_call(depth: usize) -> String {
        format!(
            "<methodCall><methodName>publisherUpdate</methodName><params><param>{}<value><i4>1</i4></value>{}</param></params></methodCall>",
            "<value><array><data>".repeat(depth),
            "</data></array></value>".repeat(depth)
        )
    }

    #[test]
    fn nesting_and_element_counts_are_bounded() {
        let (_, params) = parse_call(&nested_call(MAX_DEPTH)).unwrap();
        assert_eq!(params.len(), 1);
        assert_eq!(
            parse_call(&nested_call(MAX_DEPTH + 1)).unwrap_err(),
            XmlRpcError::TooDeep
        );
        // Deep enough to overflow any stack, were it read recursively.
        assert_eq!(
            parse_call(&nested_call(1_000_000)).unwrap_err(),
            XmlRpcError::TooDeep
        );
        let many = format!(
            "<methodCall><methodName>m</methodName><params><param><value><array><data>{}</data></array></value></param></params></methodCall>",
            "<value/>".repeat(MAX_ELEMENTS)
        );
        assert_eq!(parse_call(&many).unwrap_err(), XmlRpcError::TooManyElements);
        let empty = "<methodCall><methodName>m</methodName><params><param><value><array><data><value/><value></value></data></array></value></param></params></methodCall>";
        assert_eq!(
            parse_call(empty).unwrap().1,
            [XValue::Array(vec![XValue::str(""), XValue::str("")])]
        );
    }

    #[test]
    fn uris_split_into_address_and_path() {
        assert_eq!(
            split_uri("http://127.0.0.1:11311/").unwrap(),
            ("127.0.0.1:11311".into(), "/".into())
        );
        assert_eq!(
            split_uri("http://localhost:45000").unwrap(),
            ("localhost:45000".into(), "/".into())
        );
        assert!(split_uri("rosrpc://x:1").is_err());
    }
}
