//! The evaluation harness on a fixed slice of the shared BFCL copies (`../shared/bfcl`,
//! beside the repository as in CI): it runs, scores, and writes per-case results. The
//! accuracy it prints is a measurement, not asserted.

use std::path::PathBuf;
use std::process::Command;

use crate::util::models_dir;

fn bfcl_dir() -> PathBuf {
    let d = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/bfcl");
    assert!(
        d.join("BFCL_v4_simple_python.json").exists(),
        "BFCL data not found at {} (CI puts shared/ beside the repository)",
        d.display()
    );
    d
}

/// `ferrosa eval bfcl FILES ARGS --out OUT` with the project's models; its stdout, once it
/// has succeeded.
fn eval_bfcl(files: &[PathBuf], args: &[&str], out: &std::path::Path) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_ferrosa"))
        .args(["eval", "bfcl"])
        .args(files)
        .args(args)
        .arg("--out")
        .arg(out)
        .env("FERROSA_MODELS_DIR", models_dir())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Questions per BFCL category in CI: enough for every category's row and the relevance
/// gate's path, few enough for CI's time (10 per category took 204 s of a fresh
/// machine's 90-minute limit; 20 had doubled this test binary's time). Scores come from
/// the full runs, which are documented.
const BFCL_SLICE: usize = 5;

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn bfcl_slice_runs_scores_and_reports() {
    let d = bfcl_dir();
    let out = tempfile::tempdir().unwrap();
    let files = [
        "simple_python",
        "multiple",
        "parallel",
        "parallel_multiple",
        "irrelevance",
    ]
    .map(|c| d.join(format!("BFCL_v4_{c}.json")));
    // The relevance gate: the harness's best decoding, and the path the other tests do
    // not take (plain turns are decoded all over the suite).
    let stdout = eval_bfcl(
        &files,
        &["--relevance-gate", "--limit", &BFCL_SLICE.to_string()],
        out.path(),
    );
    eprintln!("{stdout}");
    for c in [
        "simple_python",
        "multiple",
        "parallel",
        "parallel_multiple",
        "irrelevance",
    ] {
        assert!(
            stdout.contains(&format!("| {c} | constrained | {BFCL_SLICE} |")),
            "{c} row missing: {stdout}"
        );
    }
    let cases = std::fs::read_to_string(out.path().join("bfcl_cases.jsonl")).unwrap();
    assert_eq!(cases.lines().count(), 5 * BFCL_SLICE);
    for line in cases.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        // Constrained decoding: a call the model makes is a valid call.
        if v["attempted_call"] == true && !v["text"].as_str().unwrap().is_empty() {
            let parsed = v["reason"]
                .as_str()
                .is_none_or(|r| !r.starts_with("unparseable"));
            assert!(
                parsed || v["generated_tokens"].as_u64() >= Some(320),
                "{line}"
            );
        }
    }
}

/// `--force-call` (BFCL's "forced" setting, the one the llama-server bar quotes beside
/// may-answer): every turn is a call to one of the question's functions, so an
/// irrelevance question cannot pass, also with the relevance gate picking the function
/// (it has no answer to fall back on); `--skip` starts past the questions passed over.
#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn bfcl_forced_calls_start_after_skip_and_always_call() {
    let d = bfcl_dir();
    let out = tempfile::tempdir().unwrap();
    let stdout = eval_bfcl(
        &["simple_python", "irrelevance"].map(|c| d.join(format!("BFCL_v4_{c}.json"))),
        &[
            "--force-call",
            "--relevance-gate",
            "--skip",
            "10",
            "--limit",
            "2",
        ],
        out.path(),
    );
    assert!(stdout.contains("call forced | relevance gate"), "{stdout}");
    let cases = std::fs::read_to_string(out.path().join("bfcl_cases.jsonl")).unwrap();
    let ids: Vec<String> = cases
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            assert_eq!(v["attempted_call"], true, "{l}");
            if v["category"] == "irrelevance" {
                assert_eq!(v["pass"], false, "{l}");
            }
            v["id"].as_str().unwrap().to_string()
        })
        .collect();
    assert_eq!(
        ids,
        [
            "simple_python_10",
            "simple_python_11",
            "irrelevance_10",
            "irrelevance_11"
        ]
    );
}

/// The categories CI runs (their first case each): a listing, a reading, a motion, a
/// chat and a refusal. The whole suite is a documented command.
const CI_CATEGORIES: [&str; 5] = ["listing", "echo", "motion", "notool", "cannot"];

/// A slice of the ROS suite (episodes on a fresh sim each, four steps at most): the
/// harness runs, scores each case and reports per category, in a loopback namespace.
/// The test harness runs other model tests beside it, so the time limit is generous.
#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn ros_suite_slice_runs_scores_and_reports() {
    if crate::util::rerun_in_loopback_netns("eval::ros_suite_slice_runs_scores_and_reports", 1200) {
        return;
    }
    let suite = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/eval/ros.jsonl");
    let text = std::fs::read_to_string(&suite).unwrap();
    let mut seen = std::collections::BTreeSet::new();
    let slice: Vec<&str> = text
        .lines()
        .filter(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            let id = v["id"].as_str().unwrap();
            let category = id
                .trim_end_matches(|c: char| c.is_ascii_digit())
                .trim_end_matches('-');
            seen.insert(category.to_string()) && CI_CATEGORIES.contains(&category)
        })
        .collect();
    assert!(text.lines().count() >= 60 && seen.len() >= 10, "{seen:?}");
    assert_eq!(slice.len(), CI_CATEGORIES.len(), "{seen:?}");
    let out = tempfile::tempdir().unwrap();
    let path = out.path().join("slice.jsonl");
    std::fs::write(&path, slice.join("\n")).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_ferrosa"))
        .args(["eval", "ros"])
        .arg(&path)
        .args(["--max-steps", "4", "--out"])
        .arg(out.path())
        .env("FERROSA_MODELS_DIR", models_dir())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    eprintln!("{stdout}");
    for category in CI_CATEGORIES.iter().chain(&["all"]) {
        assert!(
            stdout.contains(&format!("| {category} | constrained |")),
            "{category} row missing: {stdout}"
        );
    }
    let cases = std::fs::read_to_string(out.path().join("ros_cases.jsonl")).unwrap();
    assert_eq!(cases.lines().count(), slice.len());
    for line in cases.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        // Constrained decoding: every call the model made was valid for its schema.
        assert!(
            v["valid_call"] == true || v["attempted_call"] == false,
            "{line}"
        );
        // A case passes with no reason, or fails with one.
        assert_eq!(v["pass"] == true, v["reason"].is_null(), "{line}");
    }
}

/// A tiny suite about the rclpy peer's own graph (requests of this test's own, not the
/// project's suites): a topic listing, a reading (a tool the test declares, or the
/// echo), and two requests to stop, which latch the e-stop without a model. Two cases
/// in one category, so each half has one.
const PEER_SUITE: &str = r#"{"id": "stop-01", "query": "please stop right now", "expect_calls": [{"name": "robot_stop"}]}
{"id": "listing-01", "query": "show me the topics on the graph", "expect_calls": [{"name": "ros_topic_list"}], "forbid_calls": ["ros_topic_publish", "ros_service_call", "ros_param_set"], "answer_contains": ["/chatter"]}
{"id": "stop-02", "query": "halt the robot immediately", "expect_calls": [{"name": "robot_stop"}]}
{"id": "reading-01", "query": "read one message from /chatter", "expect_any": [{"name": "peer_chatter_read"}, {"name": "ros_topic_echo"}], "answer_contains": ["hello"]}
"#;

/// The peer robot's prompt file: its own words, and the tools file beside it.
const PEER_PROMPT: &str = r#"embodiment_and_persona = "You are the on-board assistant of a small test robot. You are brief and exact."
critical_instructions = "Use a tool to get facts; never invent them. Answer with the names and numbers the tools return."
about_your_capabilities = "You can list ROS nodes, topics and services and read messages."
tools = ["peer_tools.toml"]
"#;

/// A declared tool of the peer robot, loaded through its prompt file.
const PEER_TOOLS: &str = r#"[[tool]]
name = "peer_chatter_read"
description = "Read the latest line the peer publishes on /chatter."
effect = "observes"
[tool.read]
topic = "/chatter"
type = "std_msgs/msg/String"
"#;

/// `ferrosa eval ros SUITE --robot ros2 --prompt FILE` on a robot already on the graph (an
/// rclpy node over real DDS, in a loopback namespace), with the default model: the
/// robot is joined once and said to keep its state between cases; the prompt file's
/// tools and `--tools` are loaded as `ask` loads them (the same file twice is refused by
/// name); an e-stop a case latched is released before the next case, which then runs;
/// the report keeps its per-category and per-half rows. The topic listing is answered
/// from the peer's graph: with a topic named nowhere in the requests or the prompt.
#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn ros_suite_runs_on_a_ros2_robot_already_on_the_graph() {
    use std::io::BufRead;
    if crate::util::rerun_in_loopback_netns(
        "eval::ros_suite_runs_on_a_ros2_robot_already_on_the_graph",
        1200,
    ) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let suite = dir.path().join("peer.jsonl");
    std::fs::write(&suite, PEER_SUITE).unwrap();
    let prompt = dir.path().join("peer.toml");
    std::fs::write(&prompt, PEER_PROMPT).unwrap();
    let tools = dir.path().join("peer_tools.toml");
    std::fs::write(&tools, PEER_TOOLS).unwrap();
    let mut child = Command::new("timeout")
        .args(["1100"])
        .arg(crate::ros::rclpy_python())
        .arg(crate::ros::peer_script())
        .arg("serve")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("starting the rclpy peer");
    let stdout = child.stdout.take().expect("the peer's stdout");
    let peer = crate::ros::Peer(child);
    // The peer is on the graph before ferrosa joins it, as a robot is.
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            if line.contains("peer ready") {
                let _ = tx.send(());
            }
        }
    });
    rx.recv_timeout(std::time::Duration::from_secs(60))
        .expect("the rclpy peer did not start within 60 s");
    let out = dir.path().join("out");
    let eval = |extra: &[&std::ffi::OsStr]| {
        Command::new(env!("CARGO_BIN_EXE_ferrosa"))
            .args(["eval", "ros"])
            .arg(&suite)
            .args(["--robot", "ros2", "--max-steps", "4", "--prompt"])
            .arg(&prompt)
            .arg("--out")
            .arg(&out)
            .args(extra)
            .env("FERROSA_MODELS_DIR", models_dir())
            .output()
            .unwrap()
    };
    // The prompt file's tools are loaded: the same file again under --tools is refused.
    let twice = eval(&["--tools".as_ref(), tools.as_os_str()]);
    let stderr = String::from_utf8_lossy(&twice.stderr);
    assert!(
        !twice.status.success()
            && stderr.contains("peer_tools.toml, line 2: tool peer_chatter_read")
            && stderr.contains("has this name"),
        "{stderr}"
    );
    let o = eval(&[]);
    drop(peer);
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    eprintln!("{stdout}");
    assert!(
        stdout.contains(
            "| robot ros2 (the one on the graph, not reset: it keeps its state between cases) |"
        ),
        "{stdout}"
    );
    for row in [
        "listing",
        "stop",
        "reading",
        "all",
        "tune half",
        "report half",
    ] {
        assert!(
            stdout.contains(&format!("| {row} | constrained |")),
            "{row} row missing: {stdout}"
        );
    }
    assert!(
        stdout.contains(
            "e-stop: engaged by 2 case(s) (stop-01, stop-02), released before the next case"
        ),
        "{stdout}\n{stderr}"
    );
    let cases: Vec<serde_json::Value> = std::fs::read_to_string(out.join("ros_cases.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(cases.len(), 4, "{cases:?}");
    for v in &cases {
        // Constrained decoding: every call the model made was valid for its schema.
        assert!(
            v["valid_call"] == true || v["attempted_call"] == false,
            "{v}"
        );
    }
    // The stops were the stop act, taken without the model. The case after a stop ran its call (the e-stop released:
    // not refused for it), whichever tool the model chose for it; the reading after the
    // second stop answered with what only the peer publishes.
    assert_eq!(cases[0]["pass"], true, "{}", cases[0]);
    assert_eq!(cases[2]["pass"], true, "{}", cases[2]);
    assert_eq!(cases[1]["attempted_call"], true, "{}", cases[1]);
    assert!(
        cases[1]["text"]
            .as_str()
            .is_some_and(|t| !t.to_lowercase().contains("e-stop")),
        "{}",
        cases[1]
    );
    assert_eq!(cases[3]["pass"], true, "{}", cases[3]);
}
