//! The remote engine's HTTP client: JSON requests to one server over HTTP/1.1 (hyper),
//! each answer read whole or as server-sent events, every wait bounded by a time-out.
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
pub struct Client {
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

/// Largest whole answer read (`read_all`).
const MAX_BODY: usize = 16 << 20;

/// A request's answer once its status is known.
pub struct Response {
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

    /// The whole body of `resp` (at most 16 MiB).
    pub fn read_all(&self, resp: Response) -> Result<Vec<u8>, RemoteError> {
        let mut out = Vec::new();
        let mut r = resp;
        while let Some(chunk) = self.next_chunk(&mut r)? {
            out.extend_from_slice(&chunk);
            if out.len() > MAX_BODY {
                self.close(r);
                return Err(RemoteError::BadAnswer {
                    path: self.url(),
                    reason: "the answer runs past 16 MiB".into(),
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
    pub fn next_chunk(&self, resp: &mut Response) -> Result<Option<Bytes>, RemoteError> {
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
    pub fn post_json(&self, path: &str, body: &Value) -> Result<Value, RemoteError> {
        let resp = self.post(path, body)?;
        self.json_of(path, resp)
    }

    /// `GET path`'s JSON answer (as `post_json`).
    pub fn get_json(&self, path: &str) -> Result<Value, RemoteError> {
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
pub fn server_message(bytes: &[u8]) -> String {
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
pub fn preview(bytes: &[u8]) -> String {
    let text = String::from_utf8_lossy(bytes);
    let text = text.trim();
    match text.char_indices().nth(300) {
        Some((at, _)) => format!("{}…", &text[..at]),
        None => text.to_string(),
    }
}

/// Server-sent events, cut from a body's pieces: each event's `data` lines joined.
#[derive(Default)]
pub struct Events {
    pending: Vec<u8>,
    data: Vec<String>,
}

impl Events {
    /// Feed a piece; returns the events it completed.
    pub fn push(&mut self, chunk: &[u8]) -> Vec<String> {
        self.pending.extend_from_slice(chunk);
        let mut out = Vec::new();
        while let Some(nl) = self.pending.iter().position(|&b| b == b'\n') {
            let line: Vec<u8> = self.pending.drain(..=nl).collect();
            let line = String::from_utf8_lossy(&line);
            let line = line.trim_end_matches(['\n', '\r']);
            if line.is_empty() {
                if !self.data.is_empty() {
                    out.push(self.data.join("\n"));
                    self.data.clear();
                }
            } else if let Some(d) = line.strip_prefix("data:") {
                self.data.push(d.strip_prefix(' ').unwrap_or(d).to_string());
            } else if let Some(d) = line.strip_prefix("error:") {
                // llama-server sends a failure mid-stream as an `error:` line.
                self.data.push(format!("{{\"error\": {}}}", d.trim()));
            }
        }
        out
    }

    /// Bytes of a line not yet ended.
    pub fn pending_len(&self) -> usize {
        self.pending.len()
    }

    /// What is left when the body ends (an event with no blank line after it).
    pub fn finish(&mut self) -> Option<String> {
        let tail = String::from_utf8_lossy(&self.pending).trim().to_string();
        if let Some(d) = tail.strip_prefix("data:") {
            self.data.push(d.trim_start().to_string());
        }
        self.pending.clear();
        (!self.data.is_empty()).then(|| std::mem::take(&mut self.data).join("\n"))
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
                got.extend(ev.push(piece));
            }
            got.extend(ev.finish());
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
    fn an_error_answer_gives_the_servers_message() {
        assert_eq!(
            server_message(br#"{"error": {"code": 400, "message": "bad grammar"}}"#),
            "bad grammar"
        );
        assert_eq!(server_message(b"oops"), "oops");
    }
}
