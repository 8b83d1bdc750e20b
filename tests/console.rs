//! `ferrosa serve` in a real browser: headless Chromium, driven over WebDriver, against
//! the console with the built-in sim and the default model, inside a loopback-only
//! network namespace. An operator's session: a question, a move approved and seen on the
//! canvas, an e-stop during a move, a denied move, a request spoken into the page's
//! microphone (Chromium's fake capture device plays a WAV espeak-ng spoke) and
//! transcribed; a screenshot of each step goes to `target/test-artifacts/console/`. Then
//! the HTTP rules: the token off loopback, the host and origin checks, JSON only, and the
//! spoken answer.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use serde_json::Value;

use crate::support::webdriver::{http, Browser};
use crate::util::{models_dir, rerun_in_loopback_netns, spawn_until, stop};

const TEST: &str = "console::an_operator_drives_the_robot_from_the_console_in_a_browser";

/// The console's secret in these tests (the browser signs in with the printed address).
const TOKEN: &str = "console-test-token-0123456789";

/// Start `ferrosa serve ARGS` and wait for the address it prints.
fn serve(args: &[&str], env: &[(&str, &str)]) -> (Child, String) {
    let mut cmd = Command::new("timeout");
    cmd.args(["-k", "5", "500", env!("CARGO_BIN_EXE_ferrosa"), "serve"])
        .args(args)
        .env("FERROSA_MODELS_DIR", models_dir())
        .stdin(Stdio::null())
        .stdout(Stdio::null());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let (child, rest) = spawn_until(
        &mut cmd,
        "ferrosa serve: console on ",
        "serve",
        Duration::from_secs(120),
    );
    let url = rest.split_whitespace().next().unwrap().to_string();
    (child, url)
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn shots() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-artifacts/console")
}

/// The number the canvas shows for the turtle's `x`.
fn turtle_x(b: &Browser) -> f64 {
    let v = b.wait_for(
        "the turtle on the canvas",
        "return document.getElementById('canvas').dataset.x",
        Duration::from_secs(20),
    );
    v.as_str().unwrap().parse().unwrap()
}

/// Type `request`, send it, and return the run's bubble selector once the page shows
/// the request sent (the agent busy).
fn send(b: &Browser, request: &str) -> String {
    let before = b.eval("return document.querySelectorAll('#messages li.agent').length");
    b.type_into("#prompt", request);
    b.click("#send");
    b.wait_for(
        "the request to be taken",
        &format!("return document.querySelectorAll('#messages li.agent').length > {before}"),
        Duration::from_secs(10),
    );
    "#messages li.agent:last-child".to_string()
}

/// Wait for the last run to finish; its answer.
fn answer(b: &Browser) -> String {
    b.wait_for(
        "the answer",
        "const li = document.querySelector('#messages li.agent:last-child');
         return li && !li.classList.contains('writing') && document.body.dataset.busy === 'false' && li.innerText",
        Duration::from_secs(180),
    )
    .as_str()
    .unwrap()
    .to_string()
}

/// Wait for the approval dialog; the call it shows (name, arguments).
fn approval_shown(b: &Browser) -> (String, Value) {
    b.wait_for(
        "the approval dialog, ready to answer",
        "return document.getElementById('approval').open && !document.getElementById('approve').disabled",
        Duration::from_secs(120),
    );
    let name = b.eval("return document.getElementById('approval-name').textContent");
    let args = b.eval("return document.getElementById('approval-args').textContent");
    (
        name.as_str().unwrap().to_string(),
        serde_json::from_str(args.as_str().unwrap()).unwrap(),
    )
}

#[test]
#[ignore = "needs the default model, Debian's chromium and chromium-driver (.ci/setup) and a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn an_operator_drives_the_robot_from_the_console_in_a_browser() {
    if rerun_in_loopback_netns(TEST, 900) {
        return;
    }
    let traces = tempfile_dir("traces");
    let memory = traces.join("memory.sqlite");
    let (mut server, url) = serve(
        &[
            "--robot",
            "sim",
            "--bind",
            "127.0.0.1:0",
            "--trace-dir",
            traces.to_str().unwrap(),
            "--memory",
            memory.to_str().unwrap(),
        ],
        &[("FERROSA_CONSOLE_TOKEN", TOKEN)],
    );
    // What the page's microphone will hear: a request, spoken once, then silence.
    let spoken = traces.join("spoken.wav");
    let said = Command::new(env!("CARGO_BIN_EXE_ferrosa"))
        .args([
            "say",
            "where is the turtle",
            "--out",
            spoken.to_str().unwrap(),
        ])
        .status()
        .expect("ferrosa say");
    assert!(
        said.success(),
        "ferrosa say (espeak-ng, installed by .ci/setup)"
    );
    let mic = [
        "--use-fake-ui-for-media-stream".to_string(),
        "--use-fake-device-for-media-stream".to_string(),
        format!(
            "--use-file-for-fake-audio-capture={}%noloop",
            spoken.display()
        ),
        "--autoplay-policy=no-user-gesture-required".to_string(),
    ];
    let b = Browser::start(free_port(), 1280, 900, &mic);
    b.open(&url);
    b.wait_for(
        "the page to load its state",
        "return document.getElementById('engine').textContent",
        Duration::from_secs(20),
    );
    let x0 = turtle_x(&b);
    // The robot file's places, on the robot view and in the memory panel.
    let drawn = b.wait_for(
        "the places on the canvas",
        "return document.getElementById('canvas').dataset.places",
        Duration::from_secs(10),
    );
    assert!(
        drawn.as_str().unwrap().split('|').any(|p| p == "pond"),
        "{drawn}"
    );
    let listed = b.eval("return document.getElementById('memory-places').innerText");
    assert!(listed.as_str().unwrap().contains("robot file"), "{listed}");

    // A question: the answer names the sim's node, the trace shows the call.
    let bubble = send(&b, "list the ROS nodes");
    let said = answer(&b);
    assert!(said.contains("/turtlesim"), "{bubble}: {said}");
    // The request is logged in the robot's memory, and the panel shows it.
    b.wait_for(
        "the request in the memory panel",
        "return document.getElementById('memory-runs').innerText.includes('list the ROS nodes')",
        Duration::from_secs(10),
    );
    b.wait_for(
        "the call in the trace",
        "return document.querySelector('#trace li.call[data-name=\"ros_node_list\"]') !== null",
        Duration::from_secs(5),
    );
    b.screenshot(&shots().join("1-question.png"));

    // A move: asked for approval with its arguments, approved, seen on the canvas.
    send(&b, "move the turtle forward 1 meter");
    let (name, args) = approval_shown(&b);
    eprintln!("approval asked: {name} {args}");
    b.screenshot(&shots().join("2-approval.png"));
    b.click("#approve");
    let said = answer(&b);
    let x1 = turtle_x(&b);
    b.screenshot(&shots().join("3-moved.png"));
    assert!(
        x1 - x0 > 0.5,
        "the turtle did not move forward on the canvas ({x0} → {x1}) after approving {name} {args}: {said}"
    );
    assert!(
        b.eval(
            "return document.querySelector('#trace li.call[data-decision=\"confirmed\"]') !== null"
        ) == Value::Bool(true),
        "no confirmed call in the trace"
    );

    // An e-stop during a move: the turtle stops short and stays.
    send(&b, "move the turtle forward 3 meters");
    approval_shown(&b);
    b.click("#approve");
    b.wait_for(
        "the turtle to start moving",
        &format!(
            "return Number(document.getElementById('canvas').dataset.x) > {}",
            x1 + 0.2
        ),
        Duration::from_secs(20),
    );
    // The move says how far it has got while it runs.
    b.wait_for(
        "the move's progress on its line",
        "return [...document.querySelectorAll('#messages .steps .took')].some(t => /of 3.0 m driven/.test(t.textContent))",
        Duration::from_secs(10),
    );
    b.click("#estop");
    b.wait_for(
        "the e-stop banner",
        "return !document.getElementById('estop-banner').hidden",
        Duration::from_secs(5),
    );
    std::thread::sleep(Duration::from_millis(700));
    let stopped = turtle_x(&b);
    std::thread::sleep(Duration::from_millis(1500));
    let later = turtle_x(&b);
    b.screenshot(&shots().join("4-estop.png"));
    assert!(
        (later - stopped).abs() < 0.05,
        "the turtle went on after the e-stop: {stopped} → {later}"
    );
    assert!(
        later < x1 + 2.7,
        "the e-stop did not stop the move short: {x1} → {later}"
    );
    answer(&b);
    b.click("#reset");
    b.wait_for(
        "the e-stop released",
        "return document.getElementById('estop-banner').hidden",
        Duration::from_secs(5),
    );

    // A denied move: refused in the trace, the turtle where it was.
    send(&b, "move the turtle forward 1 meter");
    approval_shown(&b);
    b.click("#deny");
    let said = answer(&b);
    b.screenshot(&shots().join("5-denied.png"));
    let refused = b.eval(
        "const li = [...document.querySelectorAll('#trace li.call')].pop();
         return li && li.dataset.decision",
    );
    assert_eq!(refused, "refused", "the last call was not refused: {said}");
    assert!(
        (turtle_x(&b) - later).abs() < 0.05,
        "the turtle moved after a denial"
    );

    // Speech: click to talk, the request plays into the microphone, click to send; the
    // transcript is the request, and the agent answers it.
    let asked = b.eval("return document.querySelectorAll('#messages li.user').length");
    b.click("#talk");
    b.wait_for(
        "the page to listen",
        "return document.getElementById('talk').classList.contains('recording')",
        Duration::from_secs(10),
    );
    std::thread::sleep(Duration::from_millis(3500));
    b.click("#talk");
    let heard = b.wait_for(
        "the spoken request to be sent",
        &format!(
            "const u = document.querySelectorAll('#messages li.user');
             return u.length > {asked} && u[u.length - 1].textContent"
        ),
        Duration::from_secs(60),
    );
    let heard = heard.as_str().unwrap().to_lowercase();
    assert!(heard.contains("turtle"), "heard {heard:?}");
    let said = answer(&b);
    b.screenshot(&shots().join("6-spoken.png"));
    eprintln!("spoken: {heard:?} → {said:?}");

    // The session's trace, as the download link gives it.
    let host = url.trim_start_matches("http://").split('/').next().unwrap();
    let bearer = format!("Bearer {TOKEN}");
    let auth = [("Authorization", bearer.as_str())];
    let (status, _, jsonl) = http(host, "GET", "/api/trace.jsonl", &auth, None);
    assert_eq!(status, 200);
    let queries = jsonl
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter(|v| v["kind"] == "query")
        .count();
    assert_eq!(queries, 5, "{jsonl}");
    // The operator deletes the request log from the panel.
    b.click("#forget-runs");
    b.wait_for(
        "the request log gone from the panel",
        "return document.getElementById('memory-runs').innerText.trim() === 'none'",
        Duration::from_secs(10),
    );
    let (status, _, kept) = http(host, "GET", "/api/memory", &auth, None);
    assert_eq!(status, 200, "{kept}");
    let kept: Value = serde_json::from_str(&kept).unwrap();
    assert_eq!(kept["runs"], serde_json::json!([]), "{kept}");
    drop(b);
    stop(&mut server);

    http_rules();
}

/// The rules a request passes first, on a console bound to every address (inside this
/// namespace that is loopback too) and on one bound to loopback.
fn http_rules() {
    let token = "test-token-0123456789";
    let (mut open, url) = serve(
        &["--bind", "0.0.0.0:0"],
        &[("FERROSA_CONSOLE_TOKEN", token)],
    );
    assert!(url.contains("/?login="), "{url}");
    let addr = url
        .trim_start_matches("http://")
        .split('/')
        .next()
        .unwrap()
        .replace("0.0.0.0", "127.0.0.1");
    let get = |headers: &[(&str, &str)], path: &str| http(&addr, "GET", path, headers, None);
    let (status, _, body) = get(&[], "/api/state");
    assert_eq!(status, 401, "{body}");
    assert!(body.contains("token"), "{body}");
    assert_eq!(
        get(
            &[("Authorization", "Bearer wrong-token-000000000")],
            "/api/state"
        )
        .0,
        401
    );
    let bearer = format!("Bearer {token}");
    assert_eq!(get(&[("Authorization", &bearer)], "/api/state").0, 200);
    let (status, head, _) = get(&[], &format!("/?token={token}"));
    assert_eq!(status, 303, "{head}");
    let cookie = head
        .lines()
        .find_map(|l| l.strip_prefix("set-cookie: "))
        .unwrap_or_else(|| panic!("no cookie: {head}"));
    assert!(
        cookie.contains("HttpOnly") && cookie.contains("SameSite=Strict"),
        "{cookie}"
    );
    let cookie = cookie.split(';').next().unwrap();
    assert_eq!(get(&[("Cookie", cookie)], "/api/state").0, 200);
    // The printed address signs in once.
    let login = &url[url.find("/?login=").unwrap()..];
    assert_eq!(get(&[], login).0, 303);
    assert_eq!(get(&[], login).0, 401);
    // With the token: JSON only, and from the console's own page.
    let post = |headers: &[(&str, &str)]| {
        let mut h = vec![("Authorization", bearer.as_str())];
        h.extend_from_slice(headers);
        http(&addr, "POST", "/api/reset", &h, Some("{}")).0
    };
    assert_eq!(post(&[("Content-Type", "text/plain")]), 415);
    assert_eq!(
        post(&[
            ("Content-Type", "application/json"),
            ("Origin", "http://evil.example")
        ]),
        403
    );
    assert_eq!(post(&[("Content-Type", "application/json")]), 200);
    stop(&mut open);

    // On loopback: a name that is not loopback is refused (a rebound name).
    let (mut local, url) = serve(
        &["--bind", "127.0.0.1:0"],
        &[("FERROSA_CONSOLE_TOKEN", TOKEN)],
    );
    let addr = url
        .trim_start_matches("http://")
        .split('/')
        .next()
        .unwrap()
        .to_string();
    let bearer = format!("Bearer {TOKEN}");
    let (status, _, body) = http(
        &addr,
        "GET",
        "/api/state",
        &[("Host", "evil.example")],
        None,
    );
    assert_eq!(status, 403, "{body}");
    // An answer read aloud: a WAV from espeak-ng.
    let json = [
        ("Content-Type", "application/json"),
        ("Authorization", bearer.as_str()),
    ];
    let text = r#"{"text": "The turtle is at five, five."}"#;
    let (status, head, wav) = http(&addr, "POST", "/api/say", &json, Some(text));
    assert_eq!(status, 200, "{head}");
    assert!(wav.starts_with("RIFF"), "{head}");
    // A recording that is not WAV is refused with what to do.
    let wav_type = [
        ("Content-Type", "audio/wav"),
        ("Authorization", bearer.as_str()),
    ];
    let (status, _, body) = http(&addr, "POST", "/api/transcribe", &wav_type, Some("OggS"));
    assert_eq!(status, 400, "{body}");
    assert!(body.contains("WAV"), "{body}");
    stop(&mut local);
}

fn tempfile_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ferrosa-console-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}
