//! The console's HTTP side: the page, its JSON API and the event stream (SSE), and the
//! checks every request passes first.
//!
//! - On loopback, the `Host` must be a loopback name: a page elsewhere cannot reach the
//!   console through a name it rebinds to 127.0.0.1.
//! - Every request carries the console's secret (`ui::secret`), on every address,
//!   loopback included: as `Authorization: Bearer`, or the HttpOnly cookie of a session
//!   the browser started by opening the printed address (its login code works once) or
//!   `/?token=…` (the cookie holds the session, never the secret).
//! - A POST must send JSON (a recording to transcribe: WAV) and, when the browser names
//!   its origin, come from the console's own page: another site's form cannot approve a
//!   call or ask for a move.
//!
//! Routes: `GET /` (the page), `/console.js`, `/console.css`; `GET /api/state`,
//! `GET /api/events` (SSE, replayed from `Last-Event-ID`), `GET /api/trace.jsonl`;
//! `POST /api/ask {text, language?}` (a request that asks to stop engages the e-stop at
//! once, busy or not, and runs nothing), `/api/approval {id, approve}`, `/api/estop`,
//! `/api/reset`, `/api/clear`; `POST /api/transcribe` (a WAV recording → `{text}`),
//! `/api/say {text, language}` (→ a WAV of it spoken); `GET /api/memory` (the robot's
//! places, facts and latest requests), `POST /api/memory/forget {place | fact | runs |
//! all}`.

use std::convert::Infallible;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::Sender;
use std::sync::{Arc, Mutex};

use axum::body::Bytes;
use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, HeaderValue, Method, StatusCode};
use axum::middleware::{self, Next};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures::{Stream, StreamExt};
use serde::Deserialize;
use serde_json::{json, Value};
use tokio::sync::broadcast::error::RecvError;

use super::ears::{Ears, SpeechFailure};
use super::hub::{Hub, Logged};
use super::memory::{Forget, Memory};
use super::worker::Job;
use crate::reading::language::Language;
use crate::ui::secret::{bearer, Secret};

/// The longest request the console takes, in characters.
const MAX_REQUEST_CHARS: usize = 2000;
/// Browser sessions kept at once (each a sign-in with the secret or the login code);
/// past it the oldest is signed out.
const MAX_SESSIONS: usize = 64;
/// The largest recording taken (30 s of 48 kHz stereo 32-bit is 11.5 MB).
const MAX_RECORDING: usize = 12 << 20;

const PAGE: &str = include_str!("../../../web/console.html");
const SCRIPT: &str = include_str!("../../../web/console.js");
const STYLE: &str = include_str!("../../../web/console.css");
const SIGN_IN: &str = include_str!("../../../web/sign-in.html");

/// What the handlers share.
#[derive(Clone)]
pub(crate) struct App {
    hub: Arc<Hub>,
    jobs: Sender<Job>,
    info: Arc<Value>,
    secret: Arc<Secret>,
    /// The printed address's login code, until it is used.
    login: Arc<Mutex<Option<String>>>,
    /// The sessions signed in (their cookies), newest last.
    sessions: Arc<Mutex<Vec<String>>>,
    loopback: bool,
    trace: Option<Arc<PathBuf>>,
    next_run: Arc<AtomicU64>,
    /// The session cookie's name, for the port (cookies are not kept apart by port).
    cookie: Arc<str>,
    ears: Arc<Ears>,
    memory: Arc<Memory>,
}

/// How a client signs in: the console's secret, and the login code of the printed
/// address (spent by its first use).
pub(crate) struct SignIn {
    pub secret: Arc<Secret>,
    pub login: String,
}

type Failure = (StatusCode, Json<Value>);

fn fail(status: StatusCode, message: impl Into<String>) -> Failure {
    (status, Json(json!({"error": message.into()})))
}

impl App {
    pub fn new(
        hub: Arc<Hub>,
        jobs: Sender<Job>,
        info: Value,
        sign_in: SignIn,
        bind: SocketAddr,
        trace: Option<PathBuf>,
        ears: Ears,
    ) -> App {
        App {
            hub,
            jobs,
            info: Arc::new(info),
            secret: sign_in.secret,
            login: Arc::new(Mutex::new(Some(sign_in.login))),
            sessions: Arc::new(Mutex::new(Vec::new())),
            loopback: bind.ip().is_loopback(),
            trace: trace.map(Arc::new),
            next_run: Arc::new(AtomicU64::new(1)),
            cookie: format!("ferrosa_token_{}", bind.port()).into(),
            ears: Arc::new(ears),
            memory: Arc::new(Memory::none()),
        }
    }

    /// The robot's memory, for the memory panel (none until given).
    pub(crate) fn with_memory(mut self, memory: Memory) -> App {
        self.memory = Arc::new(memory);
        self
    }

    /// Claim the agent and hand it the job `make` builds (after anything it publishes);
    /// `busy` is what a caller hears while it works on another.
    fn submit(&self, busy: &str, make: impl FnOnce() -> Job) -> Result<(), Failure> {
        if !self.hub.claim() {
            return Err(fail(StatusCode::CONFLICT, busy));
        }
        self.jobs.send(make()).map_err(|_| {
            self.hub.release();
            fail(
                StatusCode::SERVICE_UNAVAILABLE,
                "the agent has stopped; restart ferrosa serve",
            )
        })
    }

    /// `None` when `req` holds the secret (bearer) or a session's cookie; otherwise the
    /// answer: a redirect that starts a session (an HttpOnly cookie) when a GET's address
    /// carries the login code (once) or the token, else 401 saying how to get in.
    fn authenticate(&self, req: &Request) -> Option<Response> {
        let headers = req.headers();
        if bearer(headers).is_some_and(|t| self.secret.matches(t)) {
            return None;
        }
        let signed_in = {
            let sessions = self.sessions.lock().unwrap_or_else(|p| p.into_inner());
            headers
                .get_all(header::COOKIE)
                .iter()
                .filter_map(|h| h.to_str().ok())
                .flat_map(|h| h.split(';'))
                .filter_map(|c| c.trim().strip_prefix(&*self.cookie)?.strip_prefix('='))
                .any(|c| sessions.iter().any(|s| crate::ui::secret::same(s, c)))
        };
        if signed_in {
            return None;
        }
        let query = req.uri().query().unwrap_or_default();
        let given = |key: &str| {
            query
                .split('&')
                .find_map(|kv| kv.strip_prefix(key)?.strip_prefix('='))
        };
        let get = req.method() == Method::GET;
        let by_token = get && given("token").is_some_and(|t| self.secret.matches(t));
        // The login code is spent by its first use (a GET: a prefetch's HEAD does not).
        let by_login = get
            && given("login").is_some_and(|code| {
                let mut login = self.login.lock().unwrap_or_else(|p| p.into_inner());
                let ok = login
                    .as_deref()
                    .is_some_and(|l| crate::ui::secret::same(l, code));
                if ok {
                    *login = None;
                }
                ok
            });
        if by_token || by_login {
            // A session of its own in the cookie, not the secret: browsers send a host's
            // cookies to every port of it, and another local server must not learn the
            // secret from them. The address bar loses the code.
            let session = match crate::ui::secret::random_hex(16) {
                Ok(s) => s,
                Err(e) => {
                    return Some(
                        fail(
                            StatusCode::INTERNAL_SERVER_ERROR,
                            format!(
                                "no session could be drawn ({e}); send Authorization: Bearer TOKEN"
                            ),
                        )
                        .into_response(),
                    )
                }
            };
            {
                let mut sessions = self.sessions.lock().unwrap_or_else(|p| p.into_inner());
                if sessions.len() >= MAX_SESSIONS {
                    sessions.remove(0);
                }
                sessions.push(session.clone());
            }
            let cookie = format!(
                "{}={session}; Path=/; HttpOnly; SameSite=Strict",
                self.cookie
            );
            return Some(
                (
                    StatusCode::SEE_OTHER,
                    [(header::SET_COOKIE, cookie), (header::LOCATION, "/".into())],
                )
                    .into_response(),
            );
        }
        if req.method() == Method::GET && req.uri().path() == "/" {
            // A browser without the secret gets a page saying how to sign in (and a box
            // for the token from the file), not a bare error.
            return Some(
                (
                    StatusCode::UNAUTHORIZED,
                    page(SIGN_IN, "text/html; charset=utf-8"),
                )
                    .into_response(),
            );
        }
        Some(
            fail(
                StatusCode::UNAUTHORIZED,
                format!(
                    "this console needs its secret: open the address `ferrosa serve` printed (its login code works once), or send Authorization: Bearer TOKEN ({})",
                    self.secret.where_kept()
                ),
            )
            .into_response(),
        )
    }

    pub(crate) fn router(self) -> Router {
        Router::new()
            .route(
                "/",
                get(|| async { page(PAGE, "text/html; charset=utf-8") }),
            )
            .route(
                "/console.js",
                get(|| async { page(SCRIPT, "text/javascript; charset=utf-8") }),
            )
            .route(
                "/console.css",
                get(|| async { page(STYLE, "text/css; charset=utf-8") }),
            )
            .route("/api/state", get(state))
            .route("/api/events", get(events))
            .route("/api/trace.jsonl", get(trace))
            .route("/api/ask", post(ask))
            .route("/api/approval", post(approval))
            .route("/api/estop", post(estop))
            .route("/api/reset", post(reset))
            .route("/api/clear", post(clear))
            .route(
                "/api/transcribe",
                post(transcribe).layer(axum::extract::DefaultBodyLimit::max(MAX_RECORDING)),
            )
            .route("/api/say", post(say))
            .route("/api/memory", get(memory))
            .route("/api/memory/forget", post(forget))
            .layer(middleware::from_fn_with_state(self.clone(), check))
            .with_state(self)
    }
}

/// A built-in file, never framed by another page (an approve button must not be
/// clickjacked) and allowed to load nothing from elsewhere.
fn page(body: &'static str, kind: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, kind),
            (
                header::CONTENT_SECURITY_POLICY,
                "default-src 'self'; img-src 'self' data:; media-src 'self' blob:; frame-ancestors 'none'",
            ),
            (header::X_FRAME_OPTIONS, "DENY"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response()
}

/// The checks of the module header, before any route.
async fn check(State(app): State<App>, req: Request, next: Next) -> Response {
    let headers = req.headers();
    let host = headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .unwrap_or_default()
        .to_string();
    if app.loopback && !loopback_host(&host) {
        return fail(
            StatusCode::FORBIDDEN,
            format!("this console answers to loopback names only (127.0.0.1, localhost, [::1]), not {host:?}"),
        )
        .into_response();
    }
    if let Some(refused) = app.authenticate(&req) {
        return refused;
    }
    if req.method() == Method::POST {
        let kind = headers
            .get(header::CONTENT_TYPE)
            .and_then(|h| h.to_str().ok())
            .unwrap_or_default();
        let wanted = match req.uri().path() {
            "/api/transcribe" => ["audio/wav", "audio/x-wav"].as_slice(),
            _ => ["application/json"].as_slice(),
        };
        if !wanted.iter().any(|w| kind.starts_with(w)) {
            return fail(
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                format!("send the request as {} (Content-Type)", wanted[0]),
            )
            .into_response();
        }
        if let Some(origin) = headers.get(header::ORIGIN) {
            if origin.as_bytes() != format!("http://{host}").as_bytes() {
                return fail(
                    StatusCode::FORBIDDEN,
                    "requests to the console come from its own page only",
                )
                .into_response();
            }
        }
    }
    next.run(req).await
}

/// `Host` names a loopback address (with or without a port).
fn loopback_host(host: &str) -> bool {
    let name = match host.strip_prefix('[') {
        Some(v6) => v6.split(']').next().unwrap_or_default(),
        None => host.rsplit_once(':').map_or(host, |(n, _)| n),
    };
    name.eq_ignore_ascii_case("localhost")
        || name
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

/// A JSON body as `T`, or a 400 saying what was wrong.
fn body<T: for<'de> Deserialize<'de>>(bytes: &Bytes) -> Result<T, Failure> {
    serde_json::from_slice(bytes)
        .map_err(|e| fail(StatusCode::BAD_REQUEST, format!("the request body: {e}")))
}

async fn state(State(app): State<App>) -> Json<Value> {
    let mut v = (*app.info).clone();
    let engaged = app.hub.estop.engaged_by();
    v["estop"] = super::hub::estop_json(engaged.as_ref());
    v["busy"] = json!(app.hub.is_busy());
    v["waiting"] = json!(app.hub.waiting());
    v["trail"] = json!(app.hub.trail());
    v["trace"] = json!(app.trace.is_some());
    Json(v)
}

/// The session's events: those kept after `Last-Event-ID` (all at first), then live.
async fn events(
    State(app): State<App>,
    headers: HeaderMap,
) -> Sse<impl Stream<Item = Result<SseEvent, Infallible>>> {
    let after = headers
        .get("last-event-id")
        .and_then(|h| h.to_str().ok()?.parse().ok())
        .unwrap_or(0u64);
    let (past, rx) = app.hub.subscribe(after);
    let last = past.last().map_or(after, |l| l.seq);
    let live = futures::stream::unfold((rx, last), |(mut rx, last)| async move {
        loop {
            match rx.recv().await {
                Ok(l) if l.seq > last => {
                    let seq = l.seq;
                    return Some((Ok(sse(&l)), (rx, seq)));
                }
                Ok(_) => {}
                // Too slow a client: the stream ends, and the browser reconnects from
                // the last event it has (the kept ones are replayed; streamed text is not).
                Err(RecvError::Lagged(_)) => return None,
                Err(RecvError::Closed) => return None,
            }
        }
    });
    let past = futures::stream::iter(past.into_iter().map(|l| Ok(sse(&l))));
    // "ready": the replay is over; what follows happens now.
    let ready = futures::stream::once(async { Ok(SseEvent::default().event("ready").data("{}")) });
    Sse::new(past.chain(ready).chain(live)).keep_alive(KeepAlive::default())
}

fn sse(l: &Logged) -> SseEvent {
    SseEvent::default()
        .id(l.seq.to_string())
        .event(l.kind)
        .data(&l.data)
}

async fn trace(State(app): State<App>) -> Result<Response, Failure> {
    let Some(path) = &app.trace else {
        return Err(fail(
            StatusCode::NOT_FOUND,
            "this console keeps no trace: this machine has no data directory; start it with --trace-dir DIR",
        ));
    };
    let file = path.clone();
    let text = blocking(move || std::fs::read(file.as_ref()))
        .await?
        .map_err(|e| {
            fail(
                StatusCode::INTERNAL_SERVER_ERROR,
                format!("reading the trace {}: {e}", path.display()),
            )
        })?;
    let name = path
        .file_name()
        .map_or("trace.jsonl".into(), |n| n.to_string_lossy().into_owned());
    let disposition = HeaderValue::from_str(&format!("attachment; filename=\"{name}\""))
        .unwrap_or(HeaderValue::from_static("attachment"));
    Ok((
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static("application/jsonl"),
            ),
            (header::CONTENT_DISPOSITION, disposition),
        ],
        text,
    )
        .into_response())
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Ask {
    text: String,
    /// A language code, or "auto" (absent: the console's own setting).
    #[serde(default)]
    language: Option<String>,
}

async fn ask(State(app): State<App>, bytes: Bytes) -> Result<Response, Failure> {
    let a: Ask = body(&bytes)?;
    let text = a.text.trim().to_string();
    if text.is_empty() {
        return Err(fail(StatusCode::BAD_REQUEST, "the request is empty"));
    }
    // Stop wins: the e-stop first, whatever is running or waiting, and no model (a
    // dictated stop that runs on past the length limit too).
    let head: String = text.chars().take(MAX_REQUEST_CHARS).collect();
    if crate::reading::concepts::operator_stops(&head) {
        let estop = app.hub.estop.clone();
        let _ = tokio::task::spawn_blocking(move || {
            estop.trigger("the operator (a stop sent to the web console)")
        })
        .await;
        return Ok((StatusCode::OK, Json(json!({"stopped": true}))).into_response());
    }
    if head.len() < text.len() {
        return Err(fail(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("a request is at most {MAX_REQUEST_CHARS} characters"),
        ));
    }
    let language = match a.language.as_deref().map(str::trim) {
        None | Some("") | Some("auto") => None,
        Some(code) => Some(Language::parse(code).map_err(|e| fail(StatusCode::BAD_REQUEST, e))?),
    };
    let mut run = 0;
    app.submit(
        "the agent is still working on a request: wait for its answer, or press the e-stop",
        || {
            run = app.next_run.fetch_add(1, Ordering::SeqCst);
            app.hub.publish(
                "request",
                &json!({"run": run, "text": text, "language": language.map(Language::code)}),
                true,
            );
            Job::Ask {
                run,
                text,
                language,
            }
        },
    )?;
    Ok((StatusCode::ACCEPTED, Json(json!({"run": run}))).into_response())
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Approval {
    /// The approval's id as the event gave it (64 random bits in hex: not guessable).
    id: String,
    approve: bool,
}

async fn approval(State(app): State<App>, bytes: Bytes) -> Result<Json<Value>, Failure> {
    let a: Approval = body(&bytes)?;
    app.hub
        .answer(&a.id, a.approve)
        .map_err(|e| fail(StatusCode::CONFLICT, e))?;
    Ok(Json(json!({"id": a.id, "approve": a.approve})))
}

/// The e-stop: the run is cancelled, running calls aborted, the robot braked, motion
/// refused until a reset.
async fn estop(State(app): State<App>) -> Json<Value> {
    // The run is cancelled by the console's e-stop follower, as for any other source.
    let estop = app.hub.estop.clone();
    // The brake publishes on ROS: off the server's own threads.
    let _ = tokio::task::spawn_blocking(move || estop.trigger("the web console")).await;
    Json(json!({"engaged": true}))
}

async fn reset(State(app): State<App>) -> Json<Value> {
    Json(json!({"released": app.hub.estop.reset()}))
}

async fn memory(State(app): State<App>) -> Result<Json<Value>, Failure> {
    let memory = app.memory.clone();
    Ok(Json(blocking(move || memory.view()).await?))
}

/// Delete from memory what the operator asked; every page is told to read it again.
async fn forget(State(app): State<App>, Json(what): Json<Forget>) -> Result<Json<Value>, Failure> {
    let memory = app.memory.clone();
    let done = blocking(move || memory.forget(&what))
        .await?
        .map_err(|e| fail(StatusCode::BAD_REQUEST, e))?;
    app.hub.publish("memory", &done, false);
    Ok(Json(done))
}

async fn clear(State(app): State<App>) -> Result<Json<Value>, Failure> {
    app.submit(
        "the agent is working on a request: clear the conversation after its answer",
        || Job::Clear,
    )?;
    Ok(Json(json!({"cleared": true})))
}

/// `f` on a blocking thread (model runs, child processes, files), its panic a 500.
async fn blocking<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> Result<T, Failure> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| fail(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))
}

fn speech_failure(e: SpeechFailure) -> Failure {
    match e {
        SpeechFailure::Input(m) => fail(StatusCode::BAD_REQUEST, m),
        SpeechFailure::Unavailable(m) => fail(StatusCode::SERVICE_UNAVAILABLE, m),
    }
}

async fn transcribe(State(app): State<App>, bytes: Bytes) -> Result<Json<Value>, Failure> {
    let ears = app.ears.clone();
    blocking(move || ears.transcribe(&bytes))
        .await?
        .map(Json)
        .map_err(speech_failure)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Say {
    text: String,
    #[serde(default)]
    language: Option<String>,
}

async fn say(State(app): State<App>, bytes: Bytes) -> Result<Response, Failure> {
    let s: Say = body(&bytes)?;
    let ears = app.ears.clone();
    let voice = s.language.unwrap_or_else(|| "en".into());
    let wav = blocking(move || ears.say(&s.text, &voice))
        .await?
        .map_err(speech_failure)?;
    Ok(([(header::CONTENT_TYPE, "audio/wav")], wav).into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_names_only() {
        for h in [
            "127.0.0.1:8080",
            "localhost:1",
            "LOCALHOST",
            "[::1]:8080",
            "127.1.2.3",
        ] {
            assert!(loopback_host(h), "{h}");
        }
        for h in [
            "",
            "evil.example:8080",
            "10.0.0.1:8080",
            "[fe80::1]:80",
            "localhost.evil.com",
        ] {
            assert!(!loopback_host(h), "{h}");
        }
    }
}
