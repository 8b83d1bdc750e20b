//! Trust only the operator (issue 41), through the real surfaces on loopback: the console
//! (`ferrosa serve`) and MCP over HTTP (`ferrosa mcp --http`) refuse a local process
//! that does not hold their secret, loopback included; the secret is kept in a file only
//! the user can read; the printed address signs in once; approval ids cannot be guessed;
//! a stop sent while the agent works is taken at once (never "still working") and
//! engages the e-stop before anything else, in the words people use, without the model.
//! With the built-in sim and the default model, in a loopback-only network namespace.

use std::io::{Read, Write};
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

use crate::support::webdriver::http;
use crate::util::{models_dir, rerun_in_loopback_netns, spawn_until, stop};

/// A private runtime directory for one server, so its token file is the test's to read.
fn runtime_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ferrosa-trust-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    std::fs::set_permissions(&d, std::fs::Permissions::from_mode(0o700)).unwrap();
    d
}

/// Start `ferrosa ARGS` (no secret given: it draws one) and wait for `prefix`; the
/// child, the address it printed, and the secret read from the file it names.
fn start(args: &[&str], prefix: &str, runtime: &Path) -> (Child, String, String) {
    let mut cmd = Command::new("timeout");
    cmd.args(["-k", "5", "400", env!("CARGO_BIN_EXE_ferrosa")])
        .args(args)
        .env("FERROSA_MODELS_DIR", models_dir())
        .env("XDG_RUNTIME_DIR", runtime)
        .env_remove("FERROSA_CONSOLE_TOKEN")
        .env_remove("FERROSA_MCP_TOKEN")
        .stdin(Stdio::null())
        .stdout(Stdio::null());
    let (child, rest) = spawn_until(&mut cmd, prefix, "server", Duration::from_secs(120));
    let url = rest.split_whitespace().next().unwrap().to_string();
    let file = rest
        .split("the token is in ")
        .nth(1)
        .unwrap_or_else(|| panic!("no token file named: {rest}"))
        .split([';', ')'])
        .next()
        .unwrap()
        .trim()
        .to_string();
    let file = PathBuf::from(file);
    assert!(file.starts_with(runtime), "{}", file.display());
    let meta = std::fs::metadata(&file).unwrap();
    assert_eq!(
        meta.permissions().mode() & 0o777,
        0o600,
        "the token file is readable by others"
    );
    let token = std::fs::read_to_string(&file).unwrap().trim().to_string();
    assert!(token.len() >= 32, "{token}");
    (child, url, token)
}

fn host_of(url: &str) -> String {
    url.trim_start_matches("http://")
        .split('/')
        .next()
        .unwrap()
        .to_string()
}

/// A JSON request to the console; its status and JSON body.
fn api(
    addr: &str,
    method: &str,
    path: &str,
    bearer: Option<&str>,
    body: Option<Value>,
) -> (u16, Value) {
    let auth = bearer.map(|t| format!("Bearer {t}"));
    let mut headers = vec![("Content-Type", "application/json")];
    if let Some(a) = &auth {
        headers.push(("Authorization", a.as_str()));
    }
    let body = body.map(|b| b.to_string());
    let (status, _, text) = http(addr, method, path, &headers, body.as_deref());
    (
        status,
        serde_json::from_str(&text).unwrap_or(Value::String(text)),
    )
}

/// Poll the console's state until `done` holds (at most `limit`).
fn state_until(
    addr: &str,
    token: &str,
    what: &str,
    limit: Duration,
    done: impl Fn(&Value) -> bool,
) -> Value {
    let start = Instant::now();
    loop {
        let (status, s) = api(addr, "GET", "/api/state", Some(token), None);
        assert_eq!(status, 200, "{s}");
        if done(&s) {
            return s;
        }
        assert!(start.elapsed() < limit, "waiting for {what}: {s:#}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The turtle's last pose on the console's trail.
fn turtle_x(s: &Value) -> f64 {
    s["trail"]
        .as_array()
        .and_then(|t| t.last())
        .and_then(|p| p["x"].as_f64())
        .unwrap_or(f64::NAN)
}

#[test]
#[ignore = "needs the default model and a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn a_local_process_cannot_drive_the_robot_through_the_console_and_a_stop_always_wins() {
    if rerun_in_loopback_netns(
        "trust::a_local_process_cannot_drive_the_robot_through_the_console_and_a_stop_always_wins",
        600,
    ) {
        return;
    }
    let runtime = runtime_dir("console");
    let (mut server, url, token) = start(
        &["serve", "--robot", "sim", "--bind", "127.0.0.1:0"],
        "ferrosa serve: console on ",
        &runtime,
    );
    let addr = host_of(&url);

    // Another local process, without the secret: nothing it asks is taken, on loopback.
    let move_it = json!({"text": "move the turtle forward 1 meter"});
    for (method, path, body) in [
        ("GET", "/api/state", None),
        ("GET", "/api/events", None),
        ("POST", "/api/ask", Some(move_it.clone())),
        (
            "POST",
            "/api/approval",
            Some(json!({"id": "1", "approve": true})),
        ),
        ("POST", "/api/reset", Some(json!({}))),
    ] {
        let (status, body) = api(&addr, method, path, None, body);
        assert_eq!(status, 401, "{method} {path} without the secret: {body}");
        assert_eq!(
            api(
                &addr,
                method,
                path,
                Some("0123456789abcdef0123456789abcdef"),
                None
            )
            .0,
            401
        );
    }
    // The printed address signs a browser in once: a second use is refused.
    let login = &url[url.find("/?login=").expect("a login code")..];
    let (status, head, _) = http(&addr, "GET", login, &[], None);
    assert_eq!(status, 303, "{head}");
    assert!(head.to_ascii_lowercase().contains("httponly"), "{head}");
    assert_eq!(http(&addr, "GET", login, &[], None).0, 401);

    // The operator asks for a move; the approval's id is not guessable.
    let s = state_until(
        &addr,
        &token,
        "the turtle's pose",
        Duration::from_secs(30),
        |s| turtle_x(s).is_finite(),
    );
    let x0 = turtle_x(&s);
    let ask = json!({"text": "move the turtle forward 3 meters"});
    let (status, body) = api(&addr, "POST", "/api/ask", Some(&token), Some(ask));
    assert_eq!(status, 202, "{body}");
    let s = state_until(
        &addr,
        &token,
        "the approval",
        Duration::from_secs(120),
        |s| s["waiting"].as_array().is_some_and(|w| !w.is_empty()),
    );
    let id = s["waiting"][0]["id"]
        .as_str()
        .expect("an id as text")
        .to_string();
    assert!(
        id.len() == 16 && id.bytes().all(|b| b.is_ascii_hexdigit()),
        "approval id {id:?}"
    );
    let guess = json!({"id": "1", "approve": true});
    assert_eq!(
        api(&addr, "POST", "/api/approval", Some(&token), Some(guess)).0,
        409
    );
    let real = json!({"id": id, "approve": true});
    assert_eq!(
        api(&addr, "POST", "/api/approval", None, Some(real.clone())).0,
        401
    );
    assert_eq!(
        api(&addr, "POST", "/api/approval", Some(&token), Some(real)).0,
        200
    );

    // While it moves, a typed stop is taken at once (not "still working"), and the turtle
    // stops short and stays.
    state_until(
        &addr,
        &token,
        "the turtle to move",
        Duration::from_secs(30),
        |s| turtle_x(s) > x0 + 0.2,
    );
    let (status, body) = api(
        &addr,
        "POST",
        "/api/ask",
        Some(&token),
        Some(json!({"text": "hold on!"})),
    );
    assert_eq!(status, 200, "a stop during a run: {body}");
    assert_eq!(body["stopped"], true, "{body}");
    let s = state_until(
        &addr,
        &token,
        "the run to end",
        Duration::from_secs(30),
        |s| s["busy"] == false,
    );
    assert_eq!(s["estop"]["engaged"], true, "{s:#}");
    std::thread::sleep(Duration::from_millis(700));
    let stopped = turtle_x(&api(&addr, "GET", "/api/state", Some(&token), None).1);
    std::thread::sleep(Duration::from_millis(1500));
    let later = turtle_x(&api(&addr, "GET", "/api/state", Some(&token), None).1);
    assert!(
        (later - stopped).abs() < 0.05,
        "moved after the stop: {stopped} → {later}"
    );
    assert!(
        later < x0 + 2.7,
        "the stop did not stop the move short: {x0} → {later}"
    );

    // Without the secret the e-stop cannot be released; the operator can.
    assert_eq!(
        api(&addr, "POST", "/api/reset", None, Some(json!({}))).0,
        401
    );
    let (status, body) = api(&addr, "POST", "/api/reset", Some(&token), Some(json!({})));
    assert_eq!((status, &body["released"]), (200, &json!(true)), "{body}");

    // Ways of saying stop the model never sees: each engages the e-stop, runs nothing.
    for stop_words in [
        "kill the motors",
        "don't move",
        "¡para!",
        "Halt, sofort anhalten",
    ] {
        let (status, body) = api(
            &addr,
            "POST",
            "/api/ask",
            Some(&token),
            Some(json!({"text": stop_words})),
        );
        assert_eq!(
            (status, &body["stopped"]),
            (200, &json!(true)),
            "{stop_words}: {body}"
        );
        let (_, s) = api(&addr, "GET", "/api/state", Some(&token), None);
        assert_eq!(s["estop"]["engaged"], true, "{stop_words}");
        assert_eq!(s["busy"], false, "{stop_words} started a run");
        api(&addr, "POST", "/api/reset", Some(&token), Some(json!({})));
    }
    stop(&mut server);
    assert!(
        !runtime.join("ferrosa").read_dir().unwrap().any(|e| e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .ends_with(".token")),
        "the token file outlived the console"
    );
}

/// The status line of a POST, read as soon as the head arrives (an SSE answer may stay
/// open).
fn post_status(addr: &str, path: &str, headers: &[(&str, &str)], body: &str) -> u16 {
    let mut s = crate::support::webdriver::send(addr, "POST", path, headers, body);
    let mut head = Vec::new();
    let mut buf = [0u8; 1024];
    while !head.windows(2).any(|w| w == b"\r\n") {
        let n = s.read(&mut buf).unwrap();
        assert!(n > 0, "closed before the status line");
        head.extend_from_slice(&buf[..n]);
    }
    let line = String::from_utf8_lossy(&head);
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

#[test]
#[ignore = "needs a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn mcp_over_http_takes_only_the_operators_client() {
    if rerun_in_loopback_netns("trust::mcp_over_http_takes_only_the_operators_client", 200) {
        return;
    }
    let runtime = runtime_dir("mcp");
    let (mut server, url, token) = start(
        &["mcp", "--robot", "sim", "--http", "127.0.0.1:0"],
        "ferrosa mcp: streamable HTTP on ",
        &runtime,
    );
    let addr = host_of(&url);
    let initialize = json!({"jsonrpc": "2.0", "id": 1, "method": "initialize", "params": {
        "protocolVersion": "2025-06-18", "capabilities": {"elicitation": {}},
        "clientInfo": {"name": "another-process", "version": "1"}}})
    .to_string();
    let bearer = format!("Bearer {token}");
    let base = [
        ("Content-Type", "application/json"),
        ("Accept", "application/json, text/event-stream"),
    ];
    let with = |extra: &[(&'static str, &str)]| -> u16 {
        let mut h: Vec<(&str, &str)> = base.to_vec();
        h.extend_from_slice(extra);
        post_status(&addr, "/mcp", &h, &initialize)
    };
    assert_eq!(with(&[]), 401, "a client without the secret");
    assert_eq!(
        with(&[("Authorization", "Bearer not-the-token-0123456789")]),
        401
    );
    assert_eq!(
        with(&[
            ("Authorization", &bearer),
            ("Origin", "http://evil.example")
        ]),
        403,
        "a web page's request"
    );
    assert_eq!(
        with(&[("Authorization", &bearer), ("Host", "evil.example")]),
        403
    );
    assert_eq!(
        with(&[("Authorization", &bearer)]),
        200,
        "the operator's client"
    );
    stop(&mut server);
}

#[test]
#[ignore = "needs the default model and a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn a_stop_typed_in_the_chat_engages_the_estop_without_the_model() {
    if rerun_in_loopback_netns(
        "trust::a_stop_typed_in_the_chat_engages_the_estop_without_the_model",
        200,
    ) {
        return;
    }
    let mut child = Command::new("timeout")
        .args([
            "-k",
            "5",
            "150",
            env!("CARGO_BIN_EXE_ferrosa"),
            "chat",
            "--robot",
            "sim",
        ])
        .env("FERROSA_MODELS_DIR", models_dir())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // "kill the motors" once went to the model, which called a /kill service.
    child
        .stdin
        .take()
        .unwrap()
        .write_all(b"kill the motors\n/quit\n")
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{text}");
    assert!(
        text.contains("E-STOP engaged by the operator (typed a stop)"),
        "{text}"
    );
    assert!(text.contains("Stopped."), "{text}");
    assert!(
        !text.contains("/kill") && !text.contains("ros_service_call"),
        "{text}"
    );
}
