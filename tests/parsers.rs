//! Bounded parsers: arbitrary and adversarial input to every parser that reads what a
//! peer, a file or another process sends (property tests), each through its real surface.
//!
//! Issue 41: each parser bounds recursion, counts and sizes before it allocates, and
//! answers bad input with an error that says what is wrong. The named tests drive the
//! surfaces an attacker reaches: `calc_eval` through the tool executor, the prompt cache
//! file on disk through a start of the agent's session (and of the binary), a model
//! server's event stream over a socket on loopback, a recording through the console's
//! speech path. The property tests feed each parser generated input.
//!
//! Every test here runs in a child process of this test binary, alone, under an address
//! space limit (`in_child`): a parser that overflows its stack or allocates from an
//! untrusted count aborts that child, and the test fails, instead of taking the whole
//! binary down (which is what the code before issue 41 did).
//!
//! Layout: the surfaces here; the property tests in `parsers/property.rs`.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpListener;
use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use ferrosa::backend::prompt_cache::DEFAULT_MAX_BYTES;
use ferrosa::backend::template::{ChatTemplate, TemplateOrigin};
use ferrosa::backend::{Backend, BackendError, PromptCache, Session, TokenId, Tokenize, Vocab};
use ferrosa::tool::{Policy, Registry, ToolCall};
use serde_json::{json, Value};

mod property;

/// Set in the child process `in_child` starts.
const CHILD: &str = "FERROSA_PARSERS_CHILD";
/// Address space a child may take beyond what it holds when its test starts: far more
/// than any bounded parser needs here, far less than a reservation from a crafted count.
const HEADROOM: u64 = 1 << 30;

/// Run `test` (this test's full name) again in a child process, alone, under an address
/// space limit; true in the parent, which then returns. In the child, sets the limit and
/// returns false: the test's body runs there.
fn in_child(test: &str) -> bool {
    if std::env::var_os(CHILD).is_some() {
        limit_address_space();
        return false;
    }
    let exe = std::env::current_exe().expect("the test binary");
    let out = Command::new("timeout")
        .args(["-k", "5", "600"])
        .arg(exe)
        .args([
            "--exact",
            test,
            "--nocapture",
            "--test-threads=1",
            "--include-ignored",
        ])
        .env(CHILD, "1")
        // Few malloc arenas: the limit then measures what the code asks for.
        .env("MALLOC_ARENA_MAX", "2")
        // Property tests that fail print many panics while shrinking.
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("re-running the test binary");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("{text}");
    assert!(
        out.status.success() && text.contains("1 passed"),
        "{test} in a child process: {} (a signal means an abort: stack overflow or a failed allocation)",
        out.status
    );
    true
}

/// Property test settings: `cases` cases, failures not written next to the sources.
fn cases(cases: u32) -> proptest::prelude::ProptestConfig {
    proptest::prelude::ProptestConfig {
        failure_persistence: None,
        ..proptest::prelude::ProptestConfig::with_cases(cases)
    }
}

/// This process may map `HEADROOM` more bytes than it does now.
fn limit_address_space() {
    let status = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status");
    let kib: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmSize:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmSize");
    let limit = kib * 1024 + HEADROOM;
    let ok = Command::new("prlimit")
        .args([
            "--pid",
            &std::process::id().to_string(),
            &format!("--as={limit}:{limit}"),
        ])
        .status()
        .expect("prlimit (util-linux)");
    assert!(ok.success(), "prlimit --as");
}

// ------------------------------------------------------------------ calc_eval

/// `calc_eval` as every caller reaches it: through the policy and the executor.
fn calc(exec: &ferrosa::tool::exec::Executor, expression: &str) -> (bool, Value) {
    let call = ToolCall {
        name: "calc_eval".into(),
        arguments: json!({ "expression": expression }),
    };
    let out = exec.call(&call, &Arc::new(AtomicBool::new(false)));
    (out.ok, out.output)
}

fn executor() -> ferrosa::tool::exec::Executor {
    let mut registry = Registry::new();
    for p in ferrosa::tools::standard() {
        registry.add(p);
    }
    ferrosa::tool::exec::Executor::new(registry, Arc::new(Policy::default())).unwrap()
}

#[test]
fn calc_eval_refuses_deep_nesting_and_operator_runs_issue_41() {
    if in_child("parsers::calc_eval_refuses_deep_nesting_and_operator_runs_issue_41") {
        return;
    }
    let exec = executor();
    let n = 100_000;
    let cases = [
        (
            "nested parentheses",
            format!("{}1{}", "(".repeat(n), ")".repeat(n)),
        ),
        ("a run of unary minus", format!("{}1", "-".repeat(2 * n))),
        ("a run of unary plus", format!("{}1", "+".repeat(2 * n))),
        ("a tower of powers", format!("{}2", "2^".repeat(n))),
        (
            "nested calls",
            format!("{}4{}", "sqrt(".repeat(n), ")".repeat(n)),
        ),
        // Short enough to be read, too deep to be evaluated.
        (
            "parentheses nested a thousand deep",
            format!("{}1{}", "(".repeat(1000), ")".repeat(1000)),
        ),
    ];
    for (what, expression) in cases {
        let (ok, out) = calc(&exec, &expression);
        assert!(!ok, "{what}: {out}");
        let text = out.to_string();
        assert!(
            text.contains("too long") || text.contains("nest"),
            "{what}: a clear error, not {text}"
        );
    }
    // What a model writes still works, nesting included.
    let (ok, out) = calc(&exec, "((3 + 5) * 2) ^ 2 - -4");
    assert!(ok, "{out}");
    assert_eq!(out["result"], json!(260.0));
    let (ok, out) = calc(&exec, "--1 + sqrt(sqrt(16))");
    assert!(ok, "{out}");
    assert_eq!(out["result"], json!(3.0));
}

// ------------------------------------------------------------------ the prompt cache

/// A runtime whose KV cache is the token list, snapshot as bytes: enough for the prompt
/// cache's real files, keys and loading path.
struct Kv {
    vocab: Vocab,
    template: ChatTemplate,
    logits: Vec<f32>,
    cached: Vec<TokenId>,
}

struct NoText;
impl Tokenize for NoText {
    fn tokenize(&self, _: &str, _: bool) -> Vec<TokenId> {
        Vec::new()
    }
}

impl Kv {
    fn new() -> Kv {
        Kv {
            vocab: Vocab::from_pieces(&["a"; 300]),
            template: ChatTemplate::new("", TemplateOrigin::File, "", "").unwrap(),
            logits: vec![0.0; 300],
            cached: Vec::new(),
        }
    }
}

impl Backend for Kv {
    fn name(&self) -> &'static str {
        "kv"
    }
    fn vocab(&self) -> &Vocab {
        &self.vocab
    }
    fn chat_template(&self) -> &ChatTemplate {
        &self.template
    }
    fn context_len(&self) -> usize {
        4096
    }
    fn tokenize(&self, _: &str, _: bool) -> Result<Vec<TokenId>, BackendError> {
        Ok(Vec::new())
    }
    fn tokenizer(&self) -> Arc<dyn Tokenize> {
        Arc::new(NoText)
    }
    fn forward(&mut self, keep: usize, t: &[TokenId]) -> Result<&mut [f32], BackendError> {
        self.cached.truncate(keep);
        self.cached.extend_from_slice(t);
        Ok(&mut self.logits)
    }
    fn snapshot_key(&self) -> Option<String> {
        Some("kv runtime 1".into())
    }
    fn snapshot(&self) -> Result<Vec<u8>, BackendError> {
        Ok(self.cached.iter().flat_map(|t| t.to_le_bytes()).collect())
    }
    fn restore(&mut self, bytes: &[u8], n: usize) -> Result<(), BackendError> {
        let tokens: Vec<TokenId> = bytes
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        if tokens.len() != n || bytes.len() % 4 != 0 {
            self.cached.clear();
            return Err(BackendError::BadToken(0));
        }
        self.cached = tokens;
        Ok(())
    }
}

/// The prompt every start sees, and its stable prefix's length.
fn cache_prompt() -> (Vec<TokenId>, usize) {
    ((0..300).map(|i| i % 250).collect(), 200)
}

/// One start of a process with the prompt cache in `dir`: its session prepares the
/// prompt as the agent's first turn does. How many tokens it restored from disk.
fn start_with_cache(dir: &Path) -> usize {
    let mut kv = Kv::new();
    let cache = PromptCache::open(dir, "model-sha", &kv, DEFAULT_MAX_BYTES).expect("a cache");
    let cache = Arc::new(cache);
    let mut session = Session::with_cache(cache.clone());
    let (prompt, stable) = cache_prompt();
    session.set_stable(&prompt[..stable]);
    let (_, held) = session.prepare(&mut kv, &prompt).expect("prepare");
    assert_eq!(
        held, stable,
        "the stable prefix is held, restored or evaluated"
    );
    assert_eq!(kv.cached, prompt[..stable], "the runtime holds exactly it");
    cache.flush();
    cache.counts().0
}

/// The `.kv` entry files in `dir`.
fn kv_files(dir: &Path) -> Vec<std::path::PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "kv"))
        .collect()
}

/// An entry file's parts: its header (JSON) and its payload.
fn split_entry(bytes: &[u8]) -> (Value, Vec<u8>) {
    assert_eq!(&bytes[..8], b"FRSKV01\n");
    let len = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
    let header = serde_json::from_slice(&bytes[12..12 + len]).unwrap();
    (header, bytes[12 + len..].to_vec())
}

fn join_entry(header: &Value, payload: &[u8]) -> Vec<u8> {
    let h = serde_json::to_vec(header).unwrap();
    let mut out = b"FRSKV01\n".to_vec();
    out.extend_from_slice(&(h.len() as u32).to_le_bytes());
    out.extend_from_slice(&h);
    out.extend_from_slice(payload);
    out
}

#[test]
fn a_prompt_cache_file_claiming_a_huge_payload_is_a_miss_issue_41() {
    if in_child("parsers::a_prompt_cache_file_claiming_a_huge_payload_is_a_miss_issue_41") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    assert_eq!(start_with_cache(dir.path()), 0, "nothing on disk yet");
    let (_, stable) = cache_prompt();
    assert_eq!(
        start_with_cache(dir.path()),
        stable,
        "the next start restores"
    );
    let path = kv_files(dir.path()).pop().expect("an entry");
    let good = std::fs::read(&path).unwrap();
    let (header, payload) = split_entry(&good);
    let real = header["payload_len"].as_u64().unwrap();
    // Each claim in the header, the rest of the file as written: a start reads it as a
    // miss, evaluates, writes a good entry again, and the start after restores it.
    for claim in [1u64 << 50, u64::MAX, 1 << 40, real + 1, real - 4, 0] {
        let mut h = header.clone();
        h["payload_len"] = json!(claim);
        std::fs::write(&path, join_entry(&h, &payload)).unwrap();
        assert_eq!(
            start_with_cache(dir.path()),
            0,
            "a payload of {claim} bytes claimed: a miss"
        );
        let again = std::fs::read(&path).unwrap();
        assert_eq!(
            again, good,
            "claim {claim}: the entry was written again, whole"
        );
        assert_eq!(
            start_with_cache(dir.path()),
            stable,
            "claim {claim}: the start after that restores"
        );
    }
    // A header whose own length runs past the file.
    let mut bad = good.clone();
    bad[8..12].copy_from_slice(&(u32::MAX - 1).to_le_bytes());
    std::fs::write(&path, &bad).unwrap();
    assert_eq!(start_with_cache(dir.path()), 0);
    assert_eq!(start_with_cache(dir.path()), stable);
}

#[test]
#[ignore = "needs the model weights: cargo test --release -- --include-ignored"]
fn a_crafted_prompt_cache_file_does_not_stop_the_binary_starting_issue_41() {
    let cache = tempfile::tempdir().unwrap();
    let ask = || {
        let out = Command::new("timeout")
            .args(["-k", "5", "300", env!("CARGO_BIN_EXE_ferrosa")])
            .args(["ask", "--threads", "2", "convert 3 meters to feet"])
            .env("FERROSA_MODELS_DIR", crate::util::models_dir())
            .env("FERROSA_CACHE_DIR", cache.path())
            .output()
            .expect("running ferrosa");
        let answer = String::from_utf8_lossy(&out.stdout).into_owned();
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "ferrosa ask: {}\n{err}", out.status);
        eprintln!("answer: {answer}");
        answer
    };
    let first = ask();
    let prompts = cache.path().join("prompts");
    let entries = kv_files(&prompts);
    assert!(!entries.is_empty(), "the first start kept its prefix");
    for path in &entries {
        let (mut header, payload) = split_entry(&std::fs::read(path).unwrap());
        header["payload_len"] = json!(1u64 << 50);
        std::fs::write(path, join_entry(&header, &payload)).unwrap();
    }
    // Two starts after the crafted file: each answers as the first did.
    assert_eq!(ask(), first, "the start after the crafted file");
    assert_eq!(ask(), first, "and the one after it");
    for path in kv_files(&prompts) {
        let (header, payload) = split_entry(&std::fs::read(path).unwrap());
        assert_eq!(header["payload_len"], json!(payload.len()), "whole again");
    }
}

// ------------------------------------------------------------------ a model server's events

/// What the completions stream of `sse_server` sends, forever (up to `SSE_CAP` bytes).
#[derive(Clone, Copy)]
enum Stream {
    /// `data:` lines, never a blank line (one event that never ends).
    Lines,
    /// Bytes without a line end.
    OneLine,
    /// No stream: the model list, a byte at a time, each well within the time-out.
    Trickle,
}

/// Most a scripted stream sends: far past any bound ferrosa keeps.
const SSE_CAP: usize = 128 << 20;

/// A model server on loopback: a model list, no tokenizer, and a completions stream that
/// never ends an event. Its address, and how many stream bytes it got out.
fn sse_server(stream: Stream) -> (String, Arc<AtomicUsize>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let sent = Arc::new(AtomicUsize::new(0));
    let counter = sent.clone();
    std::thread::spawn(move || {
        for conn in listener.incoming().flatten() {
            let sent = counter.clone();
            std::thread::spawn(move || serve_one(conn, stream, &sent));
        }
    });
    (url, sent)
}

fn serve_one(conn: std::net::TcpStream, stream: Stream, sent: &AtomicUsize) {
    let _ = conn.set_read_timeout(Some(Duration::from_secs(60)));
    let mut reader = BufReader::new(conn.try_clone().unwrap());
    let mut line = String::new();
    if reader.read_line(&mut line).is_err() {
        return;
    }
    let path = line.split_whitespace().nth(1).unwrap_or("/").to_string();
    let mut length = 0;
    loop {
        let mut h = String::new();
        if reader.read_line(&mut h).is_err() || h.trim().is_empty() {
            break;
        }
        if let Some(v) = h.to_ascii_lowercase().strip_prefix("content-length:") {
            length = v.trim().parse().unwrap_or(0);
        }
    }
    let mut body = vec![0; length];
    let _ = reader.read_exact(&mut body);
    let mut conn = conn;
    let answer = |status: &str, body: &str| {
        format!("HTTP/1.1 {status}\r\nContent-Type: application/json\r\nConnection: close\r\nContent-Length: {}\r\n\r\n{body}", body.len())
    };
    match path.as_str() {
        "/v1/models" if matches!(stream, Stream::Trickle) => {
            let head = "HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nConnection: close\r\n\r\n{\"data\": [";
            if conn.write_all(head.as_bytes()).is_err() {
                return;
            }
            for _ in 0..600 {
                std::thread::sleep(Duration::from_millis(100));
                if conn.write_all(b" ").is_err() {
                    return;
                }
                sent.fetch_add(1, Ordering::Relaxed);
            }
        }
        "/v1/models" => {
            let _ = conn.write_all(answer("200 OK", r#"{"data": [{"id": "m"}]}"#).as_bytes());
        }
        "/v1/completions" => {
            let head =
                "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nConnection: close\r\n\r\n";
            if conn.write_all(head.as_bytes()).is_err() {
                return;
            }
            let block: Vec<u8> = match stream {
                Stream::Lines => b"data: {\"choices\": [{\"text\": \"x\"}]}\n"
                    .iter()
                    .copied()
                    .cycle()
                    .take(39 * 1024)
                    .collect(),
                Stream::OneLine | Stream::Trickle => vec![b'x'; 64 * 1024],
            };
            while sent.load(Ordering::Relaxed) < SSE_CAP {
                if conn.write_all(&block).is_err() {
                    return;
                }
                sent.fetch_add(block.len(), Ordering::Relaxed);
            }
            // Then hold the connection open, silent, until the client leaves.
            let _ = reader.read(&mut [0u8; 1]);
        }
        _ => {
            let _ = conn.write_all(
                answer("404 Not Found", r#"{"error": {"message": "no such path"}}"#).as_bytes(),
            );
        }
    }
}

/// How the tests reach a server at `url`: JSON schemas, a time-out of 5 s.
fn remote_options(url: &str) -> ferrosa::remote::RemoteOptions {
    ferrosa::remote::RemoteOptions {
        url: url.to_string(),
        api_key_env: None,
        model: None,
        grammar: ferrosa::remote::GrammarMode::JsonSchema,
        timeout: Duration::from_secs(5),
    }
}

/// A turn through a remote engine at `url` that must call `calc_convert`.
fn remote_turn(url: &str) -> ferrosa::remote::RemoteError {
    use ferrosa::chat::{ChatMessage, Role};
    use ferrosa::decode::request::TurnRequest;
    use ferrosa::decode::{Decoding, Envelope, ToolChoice};
    use ferrosa::remote::{Remote, RemoteError};
    let backend = crate::support::scripted::Scripted::synthetic(&[]);
    let mut remote =
        Remote::connect(&remote_options(url), &backend, "synthetic").expect("connected");
    let specs = vec![ferrosa::tool::ToolSpec::new(
        "calc_convert",
        "Convert a value between units.",
        json!({"type": "object", "properties": {"value": {"type": "number"}}, "required": ["value"]}),
    )
    .unwrap()];
    let messages = [ChatMessage::new(Role::User, "convert 3 meters to feet")];
    let req = TurnRequest {
        messages: &messages,
        specs: &specs,
        allowed: None,
        envelope: Envelope::Smollm2,
        choice: ToolChoice::Required,
        parallel: true,
        decoding: Decoding::Constrained,
        max_tokens: 64,
    };
    let turn = remote.turn(&backend, &req, &mut |_| std::ops::ControlFlow::Continue(()));
    let Err(e) = turn else {
        panic!("the turn went through")
    };
    match e {
        ferrosa::decode::DecodeError::Engine(e) => *e.downcast::<RemoteError>().unwrap(),
        other => panic!("not the engine's error: {other}"),
    }
}

#[test]
fn an_event_stream_that_never_ends_an_event_is_cut_off_issue_41() {
    if in_child("parsers::an_event_stream_that_never_ends_an_event_is_cut_off_issue_41") {
        return;
    }
    use ferrosa::remote::RemoteError;
    for (what, stream, says) in [
        ("data lines, no blank line", Stream::Lines, "event"),
        ("one line without an end", Stream::OneLine, "line"),
    ] {
        let (url, sent) = sse_server(stream);
        let e = remote_turn(&url);
        eprintln!("{what}: {e}");
        assert!(
            matches!(e, RemoteError::BadAnswer { .. }),
            "{what}: refused as a bad answer, not {e:?}"
        );
        assert!(e.to_string().contains(says), "{what}: {e}");
        // The client stopped reading soon after its bound: what the server got out is
        // the bound plus what the sockets' buffers hold (a few MiB on loopback).
        let n = sent.load(Ordering::Relaxed);
        eprintln!("{what}: the server got {n} bytes out");
        assert!(
            n < 32 << 20,
            "{what}: the server sent {n} bytes before the client left"
        );
    }
}

#[test]
fn a_model_server_that_trickles_its_answer_is_timed_out_issue_41() {
    if in_child("parsers::a_model_server_that_trickles_its_answer_is_timed_out_issue_41") {
        return;
    }
    use ferrosa::remote::{Remote, RemoteError};
    let (url, sent) = sse_server(Stream::Trickle);
    let backend = crate::support::scripted::Scripted::synthetic(&[]);
    let Err(e) = Remote::connect(&remote_options(&url), &backend, "synthetic") else {
        panic!("connected to a server that never finished its answer")
    };
    eprintln!("{e} (after {} bytes)", sent.load(Ordering::Relaxed));
    assert!(matches!(e, RemoteError::Timeout { .. }), "{e:?}");
    assert!(e.to_string().contains("a little at a time"), "{e}");
}

// ------------------------------------------------------------------ WAV

/// A valid 16-bit mono WAV of `samples` at `rate`.
fn wav_bytes(rate: u32, samples: &[f32]) -> Vec<u8> {
    ferrosa::speech::wav::write(&ferrosa::speech::Audio {
        rate,
        samples: samples.to_vec(),
    })
}

#[test]
fn a_wav_with_a_crafted_header_is_refused_before_use_issue_41() {
    if in_child("parsers::a_wav_with_a_crafted_header_is_refused_before_use_issue_41") {
        return;
    }
    use ferrosa::speech::wav;
    let good = wav_bytes(16000, &[0.1; 1600]);
    assert!(wav::read(&good).is_ok());
    let patched = |at: usize, bytes: &[u8]| {
        let mut b = good.clone();
        b[at..at + bytes.len()].copy_from_slice(bytes);
        b
    };
    let cases = [
        ("sample rate 0", patched(24, &0u32.to_le_bytes()), "rate"),
        ("sample rate 1 Hz", patched(24, &1u32.to_le_bytes()), "rate"),
        (
            "sample rate 4 GHz",
            patched(24, &u32::MAX.to_le_bytes()),
            "rate",
        ),
        ("0 channels", patched(22, &0u16.to_le_bytes()), "channel"),
        (
            "12 bits per sample",
            patched(34, &12u16.to_le_bytes()),
            "bits",
        ),
        (
            "0 bits per sample",
            patched(34, &0u16.to_le_bytes()),
            "bits",
        ),
    ];
    for (what, bytes, says) in cases {
        match wav::read(&bytes) {
            Ok(a) => panic!("{what}: read as {} Hz, {} samples", a.rate, a.samples.len()),
            Err(e) => assert!(e.to_string().contains(says), "{what}: {e}"),
        }
    }
    // Chunk sizes past the file's end: what the file holds is read, nothing more.
    let mut huge = good.clone();
    huge[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
    huge[40..44].copy_from_slice(&u32::MAX.to_le_bytes());
    let a = wav::read(&huge).expect("a streamed WAV's sizes");
    assert_eq!(a.samples.len(), 1600);
    let mut skip = good.clone();
    skip[16..20].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(
        wav::read(&skip).is_err(),
        "a format chunk running past the end"
    );
}

/// The console's speech path (`speech::recogniser`, what `ui::console::ears` holds) with
/// the real Whisper: a recording whose header says 0 Hz is refused with the reason, and
/// the model goes on hearing the next recordings. (The old console read such a file,
/// panicked resampling it while holding the model's lock, and so poisoned speech until
/// restart: `a_wav_with_a_crafted_header_is_refused_before_use_issue_41` and
/// `property::property_wav_reading_and_resampling_never_panic` fail on that code.)
#[cfg(feature = "candle")]
#[test]
#[ignore = "needs espeak-ng and the Whisper weights (.ci/setup): cargo test --release -- --include-ignored"]
fn a_recording_at_zero_hertz_is_refused_and_speech_goes_on_issue_41() {
    use ferrosa::speech::recogniser::{HearError, Recogniser};
    use ferrosa::speech::wav::{self, WavError};
    use ferrosa::speech::whisper::{Whisper, WhisperError};
    let path = crate::util::models_dir().join("ggml-base.en.bin");
    let ears = Recogniser::new(move || Whisper::load(&path).map_err(|e| e.to_string()));
    let spoken = ferrosa::speech::voice::speak("list the ROS nodes", "en-us", None)
        .expect("espeak-ng (.ci/setup)");
    let good = wav::write(&spoken);
    let heard = ears.transcribe_wav(&good).expect("a first recording");
    eprintln!("heard: {:?}", heard.text);
    assert!(heard.text.to_lowercase().contains("nodes"), "{heard:?}");
    for rate in [0u32, 1, u32::MAX] {
        let mut crafted = good.clone();
        crafted[24..28].copy_from_slice(&rate.to_le_bytes());
        let e = ears.transcribe_wav(&crafted).unwrap_err();
        eprintln!("{rate} Hz: {e}");
        assert!(
            matches!(e, HearError::Recording(WavError::Rate(r)) if r == rate),
            "{e:?}"
        );
        assert!(e.is_input() && e.to_string().contains("sample rate"), "{e}");
        // Audio made in this process, past the WAV reader: the model's own check.
        let audio = ferrosa::speech::Audio {
            rate,
            samples: spoken.samples.clone(),
        };
        let e = ears.transcribe(&audio).unwrap_err();
        assert!(
            matches!(e, HearError::Refused(WhisperError::Rate(r)) if r == rate),
            "{e:?}"
        );
        // The next recording is heard, by the model already loaded.
        let again = ears
            .transcribe_wav(&good)
            .expect("speech after a refused recording");
        assert_eq!(again.text, heard.text);
        assert!(ears.is_loaded());
    }
}

// ------------------------------------------------------------------ GGUF

/// GGUF bytes: the header, `kv` as written, no tensors.
fn gguf(n_kv: u64, kv: &[u8]) -> Vec<u8> {
    let mut b = b"GGUF".to_vec();
    b.extend_from_slice(&3u32.to_le_bytes());
    b.extend_from_slice(&0u64.to_le_bytes());
    b.extend_from_slice(&n_kv.to_le_bytes());
    b.extend_from_slice(kv);
    b
}

fn gguf_string(b: &mut Vec<u8>, s: &str) {
    b.extend_from_slice(&(s.len() as u64).to_le_bytes());
    b.extend_from_slice(s.as_bytes());
}

#[test]
fn a_gguf_file_claiming_more_than_it_holds_is_corrupt_issue_41() {
    if in_child("parsers::a_gguf_file_claiming_more_than_it_holds_is_corrupt_issue_41") {
        return;
    }
    use ferrosa::backend::Gguf;
    let dir = tempfile::tempdir().unwrap();
    let open = |name: &str, bytes: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        Gguf::open(&p)
    };
    // Arrays of arrays of arrays, each claiming the most items allowed, in 60 bytes.
    let mut kv = Vec::new();
    gguf_string(&mut kv, "k");
    kv.extend_from_slice(&9u32.to_le_bytes());
    for item in [9u32, 9, 0] {
        kv.extend_from_slice(&item.to_le_bytes());
        kv.extend_from_slice(&(16u64 << 20).to_le_bytes());
    }
    let e = open("nested.gguf", &gguf(1, &kv)).expect_err("nested claims");
    eprintln!("nested arrays: {e}");
    // A string of 60 MiB claimed by a file of 40 bytes.
    let mut kv = Vec::new();
    gguf_string(&mut kv, "k");
    kv.extend_from_slice(&8u32.to_le_bytes());
    kv.extend_from_slice(&(60u64 << 20).to_le_bytes());
    let e = open("string.gguf", &gguf(1, &kv)).expect_err("a long string");
    assert!(
        e.to_string().contains("corrupt") || e.to_string().contains("truncated"),
        "{e}"
    );
    // A million keys claimed by a file of 24 bytes.
    let e = open("keys.gguf", &gguf(1 << 20, &[])).expect_err("keys");
    assert!(
        e.to_string().contains("corrupt") || e.to_string().contains("truncated"),
        "{e}"
    );
    // A tensor whose dimensions overflow: corrupt, not a wrapped size.
    let mut b = b"GGUF".to_vec();
    b.extend_from_slice(&3u32.to_le_bytes());
    b.extend_from_slice(&1u64.to_le_bytes());
    b.extend_from_slice(&0u64.to_le_bytes());
    gguf_string(&mut b, "w");
    b.extend_from_slice(&4u32.to_le_bytes());
    for _ in 0..4 {
        b.extend_from_slice(&(1u64 << 20).to_le_bytes());
    }
    b.extend_from_slice(&0u32.to_le_bytes());
    b.extend_from_slice(&0u64.to_le_bytes());
    let e = open("dims.gguf", &b).expect_err("dims that overflow");
    assert!(e.to_string().contains("corrupt"), "{e}");
}

// ------------------------------------------------------------------ CDR

#[test]
fn cdr_items_of_no_bytes_cannot_multiply_a_payload_issue_41() {
    if in_child("parsers::cdr_items_of_no_bytes_cannot_multiply_a_payload_issue_41") {
        return;
    }
    use ferrosa::ros::cdr;
    use ferrosa::ros::msg::Interfaces;
    // In ROS 1 an empty message takes no bytes: 4,000 × 4,000 of them from 4 KB.
    let ifaces = Interfaces::of(&[
        ("peer/msg/Nothing", ""),
        ("peer/msg/Row", "peer/Nothing[4000] cells\n"),
        ("peer/msg/Grid", "peer/Row[4000] rows\n"),
    ])
    .unwrap();
    let payload = vec![0u8; 4000];
    match cdr::decode_ros1(&ifaces, "peer/Grid", &payload) {
        Ok(v) => panic!(
            "decoded {} rows of {} cells from {} bytes",
            v["rows"].as_array().map_or(0, Vec::len),
            v["rows"][0]["cells"].as_array().map_or(0, Vec::len),
            payload.len()
        ),
        Err(e) => eprintln!("{e}"),
    }
    // A shape to fill in, from the same definitions: bounded too.
    assert!(cdr::template(&ifaces, "peer/Grid").is_err());
}
