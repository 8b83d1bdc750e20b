//! The remote engine's HTTP client: JSON requests to one server over HTTP/1.1 (hyper),
//! each answer read whole or as server-sent events, every wait bounded by a time-out.
//!
//! A server is input, not trusted (issue 41): a whole answer is bounded in bytes, a
//! streamed one line by line and event by event (`Events`), so a server that never ends
//! a line or an event is cut off with a reason instead of growing memory.
//!
//! Plain `http://` only: a server across a network is reached through a TLS proxy or a
//! tunnel. One connection per request (a turn makes one or two), on a runtime of the
//! client's own so the synchronous agent loop can call it.

use std::time::Duration;

use bytes::Bytes;
use http_body_util::{BodyExt, Full};
use hyper::body::Incoming;
use serde_json::Value;

use super::error::RemoteError;

/// Where the server is and how to reach it.
pub(crate) struct Client {
    host: String,
    port: u16,
    /// Path prefix before `/v1/...` (empty, or e.g. `/llm`).
    base: String,
    api_key: Option<String>,
    /// Longest wait for a connection, for the answer to start, and between two pieces
    /// of a streamed answer.
    pub timeout: Duration,
    rt: tokio::runtime::Runtime,
}

/// Longest line of a streamed answer taken.
pub const MAX_LINE: usize = 1 << 20;

/// Largest event of a streamed answer taken (its data lines together).
pub const MAX_EVENT: usize = 2 << 20;

/// Why a stream of server-sent events was cut off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum StreamLimit {
    #[error("a line of the stream runs past {} KiB without ending", MAX_LINE >> 10)]
    Line,
    #[error("an event of the stream runs past {} KiB without the blank line that ends it", MAX_EVENT >> 10)]
    Event,
}

/// Largest whole answer read (`read_all`).
const MAX_BODY: usize = 16 << 20;

/// A request's answer once its status is known.
pub(crate) struct Response {
    pub status: u16,
    body: Incoming,
    timeout: Duration,
    /// The connection's task: aborted when the answer is dropped (`Client::close`).
    conn: tokio::task::JoinHandle<()>,
}

impl Client {
    /// `url`: `http://HOST[:PORT][/BASE]` (what precedes `/v1`).
    pub fn new(
        url: &str,
        api_key: Option<String>,
        timeout: Duration,
    ) -> Result<Client, RemoteError> {
        let bad = |why: &str| RemoteError::Url {
            url: url.to_string(),
            reason: why.to_string(),
        };
        let rest = match url.split_once("://") {
            Some(("http", rest)) => rest,
            Some(("https", _)) => {
                return Err(bad(
                    "https is not supported: reach the server through a TLS proxy or an SSH tunnel on a local http:// address",
                ))
            }
            Some((scheme, _)) => return Err(bad(&format!("unknown scheme '{scheme}'"))),
            None => return Err(bad("expected http://HOST:PORT")),
        };
        let (authority, base) = match rest.find('/') {
            Some(at) => (&rest[..at], rest[at..].trim_end_matches('/')),
            None => (rest, ""),
        };
        let base = base.strip_suffix("/v1").unwrap_or(base).to_string();
        // `host`, `host:port`, `[v6]`, `[v6]:port`.
        let (host, port) = match authority.strip_prefix('[') {
            Some(v6) => {
                let (h, rest) = v6.split_once(']').ok_or_else(|| bad("unclosed '['"))?;
                (h, rest.strip_prefix(':'))
            }
            None => match authority.split_once(':') {
                Some((h, p)) => (h, Some(p)),
                None => (authority, None),
            },
        };
        let port = match port {
            Some(p) => p
                .parse::<u16>()
                .map_err(|_| bad(&format!("bad port '{p}'")))?,
            None => 80,
        };
        if host.is_empty() {
            return Err(bad("no host"));
        }
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_io()
            .enable_time()
            .build()
            .map_err(|e| RemoteError::Connect {
                url: url.to_string(),
                reason: format!("cannot start the client's runtime: {e}"),
            })?;
        Ok(Client {
            host: host
                .trim_start_matches('[')
                .trim_end_matches(']')
                .to_string(),
            port,
            base,
            api_key,
            timeout,
            rt,
        })
    }

    /// The server's address as given (for messages and traces).
    pub fn url(&self) -> String {
        format!("http://{}{}", self.authority(), self.base)
    }

    /// `host:port`, an IPv6 address in brackets.
    fn authority(&self) -> String {
        if self.host.contains(':') {
            format!("[{}]:{}", self.host, self.port)
        } else {
            format!("{}:{}", self.host, self.port)
        }
    }

    /// `GET path` (after the base).
    pub fn get(&self, path: &str) -> Result<Response, RemoteError> {
        self.send("GET", path, None)
    }

    /// `POST path` with a JSON body.
    pub fn post(&self, path: &str, body: &Value) -> Result<Response, RemoteError> {
        self.send("POST", path, Some(body.to_string()))
    }

    fn send(
        &self,
        method: &str,
        path: &str,
        body: Option<String>,
    ) -> Result<Response, RemoteError> {
        let url = format!("{}{path}", self.url());
        let connect_err = |url: &str, reason: String| RemoteError::Connect {
            url: url.to_string(),
            reason,
        };
        let mut req = hyper::Request::builder()
            .method(method)
            .uri(format!("{}{path}", self.base))
            .header(hyper::header::HOST, self.authority())
            .header(hyper::header::ACCEPT, "application/json, text/event-stream");
        if let Some(key) = &self.api_key {
            req = req.header(hyper::header::AUTHORIZATION, format!("Bearer {key}"));
        }
        if body.is_some() {
            req = req.header(hyper::header::CONTENT_TYPE, "application/json");
        }
        let req = req
            .body(Full::new(Bytes::from(body.unwrap_or_default())))
            .map_err(|e| connect_err(&url, e.to_string()))?;
        let timeout = self.timeout;
        let (host, port) = (self.host.clone(), self.port);
        let _guard = self.rt.enter();
        self.rt.block_on(async move {
            let stream = tokio::time::timeout(
                timeout,
                tokio::net::TcpStream::connect((host.as_str(), port)),
            )
            .await
            .map_err(|_| RemoteError::Timeout {
                url: url.clone(),
                after: timeout,
                waiting: "a connection",
            })?
            .map_err(|e| connect_err(&url, e.to_string()))?;
            let io = hyper_util::rt::TokioIo::new(stream);
            let (mut sender, conn) = hyper::client::conn::http1::handshake(io)
                .await
                .map_err(|e| connect_err(&url, e.to_string()))?;
            let conn = tokio::spawn(async move {
                let _ = conn.await;
            });
            let resp = tokio::time::timeout(timeout, sender.send_request(req))
                .await
                .map_err(|_| RemoteError::Timeout {
                    url: url.clone(),
                    after: timeout,
                    waiting: "the answer to start",
                })?
                .map_err(|e| connect_err(&url, e.to_string()))?;
            Ok(Response {
                status: resp.status().as_u16(),
                body: resp.into_body(),
                timeout,
                conn,
            })
        })
    }

    /// The whole body of `resp` (at most 16 MiB), arrived within the time-out once it has
    /// started: a server that trickles it a byte at a time, each piece within the
    /// time-out, is cut off too.
    pub(crate) fn read_all(&self, resp: Response) -> Result<Vec<u8>, RemoteError> {
        let mut out = Vec::new();
        let mut r = resp;
        let start = std::time::Instant::now();
        while let Some(chunk) = self.next_chunk(&mut r)? {
            out.extend_from_slice(&chunk);
            if out.len() > MAX_BODY {
                self.close(r);
                return Err(RemoteError::BadAnswer {
                    path: self.url(),
                    reason: "the answer runs past 16 MiB".into(),
                });
            }
            if start.elapsed() > self.timeout {
                self.close(r);
                return Err(RemoteError::Timeout {
                    url: self.url(),
                    after: self.timeout,
                    waiting: "the rest of an answer that comes a little at a time",
                });
            }
        }
        Ok(out)
    }

    /// Drop `resp` and close its connection now (its task runs only inside this
    /// client's runtime, so it is aborted and the runtime given a turn to drop it).
    pub fn close(&self, resp: Response) {
        let Response { body, conn, .. } = resp;
        drop(body);
        conn.abort();
        self.rt.block_on(async {
            tokio::task::yield_now().await;
            tokio::task::yield_now().await;
        });
    }

    /// The next piece of `resp`'s body, `None` at its end.
    pub(crate) fn next_chunk(&self, resp: &mut Response) -> Result<Option<Bytes>, RemoteError> {
        let timeout = resp.timeout;
        let url = self.url();
        self.rt.block_on(async {
            loop {
                let frame = tokio::time::timeout(timeout, resp.body.frame())
                    .await
                    .map_err(|_| RemoteError::Timeout {
                        url: url.clone(),
                        after: timeout,
                        waiting: "the rest of the answer",
                    })?;
                match frame {
                    None => return Ok(None),
                    Some(Err(e)) => {
                        return Err(RemoteError::Connect {
                            url: url.clone(),
                            reason: format!("the answer broke off: {e}"),
                        })
                    }
                    Some(Ok(f)) => {
                        if let Ok(data) = f.into_data() {
                            return Ok(Some(data));
                        }
                    }
                }
            }
        })
    }

    /// A JSON request's JSON answer; a status other than 2xx is an error carrying the
    /// server's own message.
    pub(crate) fn post_json(&self, path: &str, body: &Value) -> Result<Value, RemoteError> {
        let resp = self.post(path, body)?;
        self.json_of(path, resp)
    }

    /// `GET path`'s JSON answer (as `post_json`).
    pub(crate) fn get_json(&self, path: &str) -> Result<Value, RemoteError> {
        let resp = self.get(path)?;
        self.json_of(path, resp)
    }

    fn json_of(&self, path: &str, resp: Response) -> Result<Value, RemoteError> {
        let status = resp.status;
        let bytes = self.read_all(resp)?;
        if !(200..300).contains(&status) {
            return Err(RemoteError::Status {
                path: path.to_string(),
                status,
                message: server_message(&bytes),
            });
        }
        serde_json::from_slice(&bytes).map_err(|e| RemoteError::BadAnswer {
            path: path.to_string(),
            reason: format!("not JSON ({e}): {}", preview(&bytes)),
        })
    }
}

/// The message an error answer carries: OpenAI's `{"error": {"message": ...}}` (or a
/// plain string there), else the start of the body.
pub(crate) fn server_message(bytes: &[u8]) -> String {
    let v: Option<Value> = serde_json::from_slice(bytes).ok();
    let message = v.as_ref().and_then(|v| {
        let e = v.get("error")?;
        e.get("message")
            .and_then(Value::as_str)
            .or_else(|| e.as_str())
            .map(str::to_string)
    });
    message.unwrap_or_else(|| preview(bytes))
}

/// The first 300 characters of a body, for messages.
pub(crate) fn preview(bytes: &[u8]) -> String {
    let text = String::from_utf8_lossy(bytes);
    let text = text.trim();
    match text.char_indices().nth(300) {
        Some((at, _)) => format!("{}…", &text[..at]),
        None => text.to_string(),
    }
}

/// Server-sent events, cut from a body's pieces: each event's `data` lines joined. A
/// line is held until it ends, at most `MAX_LINE` bytes; an event until its blank line,
/// at most `MAX_EVENT` bytes. The work is linear in the bytes, whatever the pieces.
#[derive(Default)]
pub struct Events {
    pending: Vec<u8>,
    data: Vec<String>,
    /// Bytes of `data`, with a line end each.
    size: usize,
}

impl Events {
    /// Feed a piece; returns the events it completed.
    pub fn push(&mut self, chunk: &[u8]) -> Result<Vec<String>, StreamLimit> {
        let mut out = Vec::new();
        let mut rest = chunk;
        while let Some(nl) = rest.iter().position(|&b| b == b'\n') {
            let (line, after) = rest.split_at(nl + 1);
            rest = after;
            if self.pending.len() + line.len() > MAX_LINE + 2 {
                return Err(StreamLimit::Line);
            }
            let mut whole = std::mem::take(&mut self.pending);
            whole.extend_from_slice(line);
            self.line(&whole, &mut out)?;
            whole.clear();
            self.pending = whole;
        }
        if self.pending.len() + rest.len() > MAX_LINE {
            return Err(StreamLimit::Line);
        }
        self.pending.extend_from_slice(rest);
        Ok(out)
    }

    /// One whole line (with its end).
    fn line(&mut self, raw: &[u8], out: &mut Vec<String>) -> Result<(), StreamLimit> {
        let line = String::from_utf8_lossy(raw);
        let line = line.trim_end_matches(['\n', '\r']);
        if line.is_empty() {
            if !self.data.is_empty() {
                out.push(self.data.join("\n"));
                self.data.clear();
                self.size = 0;
            }
        } else if let Some(d) = line.strip_prefix("data:") {
            self.add(d.strip_prefix(' ').unwrap_or(d).to_string())?;
        } else if let Some(d) = line.strip_prefix("error:") {
            // llama-server sends a failure mid-stream as an `error:` line.
            self.add(format!("{{\"error\": {}}}", d.trim()))?;
        }
        Ok(())
    }

    fn add(&mut self, data: String) -> Result<(), StreamLimit> {
        self.size += data.len() + 1;
        if self.size > MAX_EVENT {
            return Err(StreamLimit::Event);
        }
        self.data.push(data);
        Ok(())
    }

    /// What is left when the body ends (an event with no blank line after it).
    pub fn finish(&mut self) -> Result<Option<String>, StreamLimit> {
        let tail = String::from_utf8_lossy(&self.pending).trim().to_string();
        self.pending.clear();
        if let Some(d) = tail.strip_prefix("data:") {
            self.add(d.trim_start().to_string())?;
        }
        self.size = 0;
        Ok((!self.data.is_empty()).then(|| std::mem::take(&mut self.data).join("\n")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_are_read_or_refused_with_a_reason() {
        let t = Duration::from_secs(1);
        let c = Client::new("http://127.0.0.1:8080", None, t).unwrap();
        assert_eq!(c.url(), "http://127.0.0.1:8080");
        let c = Client::new("http://base-station/llm/v1/", None, t).unwrap();
        assert_eq!(c.url(), "http://base-station:80/llm");
        let e = Client::new("https://x:1", None, t)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("TLS proxy"), "{e}");
        assert!(Client::new("127.0.0.1:8080", None, t).is_err());
        let c = Client::new("http://[::1]:8080/v1", None, t).unwrap();
        assert_eq!(c.url(), "http://[::1]:8080");
        assert_eq!(
            Client::new("http://[::1]", None, t).unwrap().url(),
            "http://[::1]:80"
        );
        assert!(Client::new("http://h:port", None, t).is_err());
    }

    #[test]
    fn events_are_cut_at_blank_lines_whatever_the_pieces() {
        let body = b"data: {\"a\": 1}\n\ndata: {\"a\": 2}\r\n\r\nerror: {\"message\": \"boom\"}\n\ndata: [DONE]";
        for cut in [1, 3, 7, body.len()] {
            let mut ev = Events::default();
            let mut got = Vec::new();
            for piece in body.chunks(cut) {
                got.extend(ev.push(piece).unwrap());
            }
            got.extend(ev.finish().unwrap());
            assert_eq!(
                got,
                [
                    "{\"a\": 1}",
                    "{\"a\": 2}",
                    "{\"error\": {\"message\": \"boom\"}}",
                    "[DONE]"
                ],
                "pieces of {cut}"
            );
        }
    }

    #[test]
    fn a_line_or_an_event_that_never_ends_is_cut_off() {
        let mut ev = Events::default();
        let piece = vec![b'x'; 64 << 10];
        let mut fed = 0;
        let e = loop {
            match ev.push(&piece) {
                Ok(got) => assert!(got.is_empty()),
                Err(e) => break e,
            }
            fed += piece.len();
            assert!(fed <= MAX_LINE, "still taking a line of {fed} bytes");
        };
        assert_eq!(e, StreamLimit::Line);
        // Lines that end, in an event that does not.
        let mut ev = Events::default();
        let line = b"data: {\"choices\": []}\n".repeat(1000);
        let mut fed = 0;
        let e = loop {
            match ev.push(&line) {
                Ok(got) => assert!(got.is_empty()),
                Err(e) => break e,
            }
            fed += line.len();
            // Each line's `data: ` prefix and end are not the event's.
            assert!(fed <= 2 * MAX_EVENT, "still taking an event of {fed} bytes");
        };
        assert_eq!(e, StreamLimit::Event);
        // Keep-alive comments are lines of no event: taken without end.
        let mut ev = Events::default();
        for _ in 0..200 {
            assert!(ev.push(&b": ping\n".repeat(10_000)).unwrap().is_empty());
        }
        assert_eq!(ev.push(b"data: 1\n\n").unwrap(), ["1"]);
    }

    #[test]
    fn an_error_answer_gives_the_servers_message() {
        assert_eq!(
            server_message(br#"{"error": {"code": 400, "message": "bad grammar"}}"#),
            "bad grammar"
        );
        assert_eq!(server_message(b"oops"), "oops");
    }
}
