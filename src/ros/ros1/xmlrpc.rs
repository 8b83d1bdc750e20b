//! XML-RPC as ROS 1 uses it: the master's and every node's API. Values, the call and
//! response documents, a reader for them, and the HTTP/1.0 exchange over one TCP
//! connection (the master is Python's `SimpleXMLRPCServer`; nodes answer the same way).
//!
//! The reader takes the subset XML-RPC documents use: elements, text, the five named
//! entities and numeric character references; no attributes, namespaces or CDATA.

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Largest document read from a peer (a `getSystemState` of a big robot is ~100 KB).
const MAX_DOCUMENT: usize = 16 << 20;

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

    pub fn as_int(&self) -> Option<i64> {
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
pub fn response_document(value: &XValue) -> String {
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

fn unescape(raw: &str) -> Result<String, String> {
    let mut out = String::with_capacity(raw.len());
    let mut rest = raw;
    while let Some(at) = rest.find('&') {
        out.push_str(&rest[..at]);
        let end = rest[at..]
            .find(';')
            .ok_or_else(|| "an unterminated entity".to_string())?;
        let name = &rest[at + 1..at + end];
        let c = match name {
            "lt" => '<',
            "gt" => '>',
            "amp" => '&',
            "quot" => '"',
            "apos" => '\'',
            n if n.starts_with("#x") => u32::from_str_radix(&n[2..], 16)
                .ok()
                .and_then(char::from_u32)
                .ok_or_else(|| format!("a bad character reference &{n};"))?,
            n if n.starts_with('#') => n[1..]
                .parse::<u32>()
                .ok()
                .and_then(char::from_u32)
                .ok_or_else(|| format!("a bad character reference &{n};"))?,
            n => return Err(format!("an unknown entity &{n};")),
        };
        out.push(c);
        rest = &rest[at + end + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

fn tokens(doc: &str) -> Result<Vec<Token>, String> {
    let mut out = Vec::new();
    let mut rest = doc;
    while !rest.is_empty() {
        let Some(lt) = rest.find('<') else {
            out.push(Token::Text(unescape(rest)?));
            break;
        };
        if lt > 0 {
            out.push(Token::Text(unescape(&rest[..lt])?));
        }
        rest = &rest[lt..];
        if rest.starts_with("<?") || rest.starts_with("<!") {
            let end = rest.find('>').ok_or("an unterminated declaration")?;
            rest = &rest[end + 1..];
            continue;
        }
        let end = rest.find('>').ok_or("an unterminated tag")?;
        let inner = &rest[1..end];
        rest = &rest[end + 1..];
        if let Some(name) = inner.strip_prefix('/') {
            out.push(Token::Close(name.trim().to_string()));
        } else if let Some(name) = inner.strip_suffix('/') {
            let name = name.split_whitespace().next().unwrap_or("").to_string();
            out.push(Token::Open(name.clone()));
            out.push(Token::Close(name));
        } else {
            let name = inner.split_whitespace().next().unwrap_or("").to_string();
            out.push(Token::Open(name));
        }
    }
    Ok(out)
}

struct Reader {
    tokens: Vec<Token>,
    at: usize,
}

impl Reader {
    fn skip_space(&mut self) {
        while let Some(Token::Text(t)) = self.tokens.get(self.at) {
            if !t.trim().is_empty() {
                break;
            }
            self.at += 1;
        }
    }

    fn open(&mut self, name: &str) -> Result<(), String> {
        self.skip_space();
        match self.tokens.get(self.at) {
            Some(Token::Open(n)) if n == name => {
                self.at += 1;
                Ok(())
            }
            other => Err(format!("expected <{name}>, found {other:?}")),
        }
    }

    fn close(&mut self, name: &str) -> Result<(), String> {
        self.skip_space();
        match self.tokens.get(self.at) {
            Some(Token::Close(n)) if n == name => {
                self.at += 1;
                Ok(())
            }
            other => Err(format!("expected </{name}>, found {other:?}")),
        }
    }

    fn peek_open(&mut self) -> Option<String> {
        self.skip_space();
        match self.tokens.get(self.at) {
            Some(Token::Open(n)) => Some(n.clone()),
            _ => None,
        }
    }

    /// Text up to the next tag (empty when there is none).
    fn text(&mut self) -> String {
        match self.tokens.get(self.at) {
            Some(Token::Text(t)) => {
                self.at += 1;
                t.clone()
            }
            _ => String::new(),
        }
    }

    fn value(&mut self) -> Result<XValue, String> {
        self.open("value")?;
        // A value with no type element is a string.
        let v = match self.tokens.get(self.at) {
            Some(Token::Close(n)) if n == "value" => XValue::Str(String::new()),
            Some(Token::Text(_))
                if !matches!(self.tokens.get(self.at + 1), Some(Token::Open(_))) =>
            {
                XValue::Str(self.text())
            }
            _ => self.typed()?,
        };
        self.close("value")?;
        Ok(v)
    }

    fn typed(&mut self) -> Result<XValue, String> {
        let kind = self.peek_open().ok_or("a value without a type")?;
        self.open(&kind)?;
        let v = match kind.as_str() {
            "i4" | "int" | "i8" => {
                let t = self.text();
                XValue::Int(t.trim().parse().map_err(|_| format!("bad integer {t:?}"))?)
            }
            "boolean" => XValue::Bool(self.text().trim() == "1"),
            "double" => {
                let t = self.text();
                XValue::Double(t.trim().parse().map_err(|_| format!("bad double {t:?}"))?)
            }
            "string" => XValue::Str(self.text()),
            "base64" | "dateTime.iso8601" => XValue::Other(self.text()),
            "nil" => XValue::Other(String::new()),
            "array" => {
                self.open("data")?;
                let mut items = Vec::new();
                while self.peek_open().as_deref() == Some("value") {
                    items.push(self.value()?);
                }
                self.close("data")?;
                XValue::Array(items)
            }
            "struct" => {
                let mut members = Vec::new();
                while self.peek_open().as_deref() == Some("member") {
                    self.open("member")?;
                    self.open("name")?;
                    let name = self.text();
                    self.close("name")?;
                    members.push((name, self.value()?));
                    self.close("member")?;
                }
                XValue::Struct(members)
            }
            other => return Err(format!("unknown XML-RPC type <{other}>")),
        };
        self.close(&kind)?;
        Ok(v)
    }
}

/// The method name and parameters of a `methodCall`.
pub fn parse_call(doc: &str) -> Result<(String, Vec<XValue>), String> {
    let mut r = Reader {
        tokens: tokens(doc)?,
        at: 0,
    };
    r.open("methodCall")?;
    r.open("methodName")?;
    let method = r.text().trim().to_string();
    r.close("methodName")?;
    let mut params = Vec::new();
    if r.peek_open().as_deref() == Some("params") {
        r.open("params")?;
        while r.peek_open().as_deref() == Some("param") {
            r.open("param")?;
            params.push(r.value()?);
            r.close("param")?;
        }
        r.close("params")?;
    }
    Ok((method, params))
}

/// The value of a `methodResponse`, or the fault's text.
pub fn parse_response(doc: &str) -> Result<XValue, String> {
    let mut r = Reader {
        tokens: tokens(doc)?,
        at: 0,
    };
    r.open("methodResponse")?;
    if r.peek_open().as_deref() == Some("fault") {
        r.open("fault")?;
        let fault = r.value()?;
        return Err(format!("XML-RPC fault: {fault:?}"));
    }
    r.open("params")?;
    r.open("param")?;
    r.value()
}

/// `http://host:port/` split into the address to connect to and the path.
pub fn split_uri(uri: &str) -> Result<(String, String), String> {
    let rest = uri
        .strip_prefix("http://")
        .ok_or_else(|| format!("{uri}: not an http:// URI"))?;
    let (host, path) = match rest.find('/') {
        Some(i) => (&rest[..i], &rest[i..]),
        None => (rest, "/"),
    };
    if !host.contains(':') {
        return Err(format!("{uri}: no port"));
    }
    Ok((host.to_string(), path.to_string()))
}

/// Read one HTTP message (headers, then a body of `Content-Length` bytes or up to EOF).
pub async fn read_http(stream: &mut TcpStream) -> Result<(String, String), String> {
    let mut buf = Vec::new();
    let mut chunk = [0u8; 8192];
    let head_end = loop {
        if let Some(i) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            break i;
        }
        let n = stream.read(&mut chunk).await.map_err(|e| e.to_string())?;
        if n == 0 {
            return Err("the connection closed before the HTTP headers ended".into());
        }
        buf.extend_from_slice(&chunk[..n]);
        if buf.len() > MAX_DOCUMENT {
            return Err("HTTP headers too long".into());
        }
    };
    let head = String::from_utf8_lossy(&buf[..head_end]).to_string();
    let mut body = buf[head_end + 4..].to_vec();
    let length = head.lines().find_map(|l| {
        let (k, v) = l.split_once(':')?;
        k.trim()
            .eq_ignore_ascii_case("content-length")
            .then(|| v.trim().parse::<usize>().ok())?
    });
    match length {
        Some(n) if n > MAX_DOCUMENT => return Err(format!("an HTTP body of {n} bytes")),
        Some(n) => {
            while body.len() < n {
                let got = stream.read(&mut chunk).await.map_err(|e| e.to_string())?;
                if got == 0 {
                    return Err("the connection closed inside the HTTP body".into());
                }
                body.extend_from_slice(&chunk[..got]);
            }
            body.truncate(n);
        }
        None => {
            stream
                .take(MAX_DOCUMENT as u64)
                .read_to_end(&mut body)
                .await
                .map_err(|e| e.to_string())?;
        }
    }
    String::from_utf8(body)
        .map(|b| (head, b))
        .map_err(|_| "an HTTP body that is not UTF-8".into())
}

/// Call `method` on the XML-RPC server at `uri`, within `timeout`.
pub async fn call(
    uri: &str,
    method: &str,
    params: &[XValue],
    timeout: Duration,
) -> Result<XValue, String> {
    let (host, path) = split_uri(uri)?;
    let body = call_document(method, params);
    let exchange = async {
        let mut stream = TcpStream::connect(&host)
            .await
            .map_err(|e| format!("cannot reach {uri}: {e}"))?;
        let request = format!(
            "POST {path} HTTP/1.0\r\nHost: {host}\r\nUser-Agent: ferrosa\r\nContent-Type: text/xml\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        );
        stream
            .write_all(request.as_bytes())
            .await
            .map_err(|e| e.to_string())?;
        let (head, doc) = read_http(&mut stream).await?;
        let status = head.split_whitespace().nth(1);
        if !head.starts_with("HTTP/1.") || status != Some("200") {
            return Err(format!(
                "{uri} answered {}",
                head.lines().next().unwrap_or("")
            ));
        }
        parse_response(&doc)
    };
    tokio::time::timeout(timeout, exchange)
        .await
        .map_err(|_| format!("{uri} did not answer {method} within {timeout:?}"))?
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
        assert!(parse_response(fault).unwrap_err().contains("fault"));
        assert!(parse_response("<methodResponse><params><param><value><int>x</int>").is_err());
        assert!(parse_response("<methodResponse><params><param><value>&bogus;</value>").is_err());
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
