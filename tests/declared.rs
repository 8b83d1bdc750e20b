//! Robot tools declared in TOML and loaded from the command line (`--tools`), against
//! the built-in sim: the shipped examples run through `ferrosa chat`'s `/call` (the
//! agent's policy path), the real model reaches one from an operator's words, and a
//! malformed file stops `ferrosa` at start with its line and the fix. One namespace,
//! one test: each check starts its own sim.

use std::io::Write;
use std::process::{Command, Stdio};

use serde_json::Value;

use crate::util::rerun_in_loopback_netns;

fn example(name: &str) -> String {
    format!("{}/examples/tools/{name}", env!("CARGO_MANIFEST_DIR"))
}

/// `ferrosa chat --robot sim --yes` with both example files, fed `lines`; each `/call`
/// report, in order.
fn chat_calls(lines: &[&str]) -> Vec<Value> {
    let mut child = Command::new("timeout")
        .arg("120")
        .arg(env!("CARGO_BIN_EXE_ferrosa"))
        .args(["chat", "--robot", "sim", "--yes", "--threads", "2"])
        .args(["--tools", &example("mobile_base.toml")])
        .args(["--tools", &example("inspection.toml")])
        .env("FERROSA_MODELS_DIR", crate::util::models_dir())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("running ferrosa chat");
    let mut stdin = child.stdin.take().unwrap();
    for l in lines.iter().chain(&["/quit"]) {
        writeln!(stdin, "{l}").unwrap();
    }
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "ferrosa chat: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter(|v| v.get("decision").is_some())
        .collect()
}

fn pose_of(report: &Value) -> (f64, f64) {
    let out = &report["output"];
    (out["x"].as_f64().unwrap(), out["y"].as_f64().unwrap())
}

#[test]
#[ignore = "needs the model weights and a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn declared_tools_load_from_the_cli_and_run_against_the_sim() {
    if rerun_in_loopback_netns(
        "declared::declared_tools_load_from_the_cli_and_run_against_the_sim",
        300,
    ) {
        return;
    }
    // The examples, through the policy path: a waypoint and the dock move the turtle, a
    // reading and the battery come back from the sim's topics.
    let reports = chat_calls(&[
        r#"/call base_go_to_waypoint {"x": 2.5, "y": 3}"#,
        "/call turtle_pose {}",
        "/call base_dock {}",
        "/call turtle_pose {}",
        "/call inspect_take_reading {}",
        "/call base_battery {}",
        r#"/call base_go_to_waypoint {"x": 40, "y": 3}"#,
    ]);
    assert_eq!(reports.len(), 7, "{reports:#?}");
    let ran = |i: usize| {
        let r: &Value = &reports[i];
        assert_eq!(r["ok"], true, "{r:#}");
    };
    (0..6).for_each(ran);
    let (x, y) = pose_of(&reports[1]);
    assert!(
        (x - 2.5).abs() < 0.01 && (y - 3.0).abs() < 0.01,
        "{:#}",
        reports[1]
    );
    let (x, y) = pose_of(&reports[3]);
    assert!(
        (x - 1.0).abs() < 0.01 && (y - 1.0).abs() < 0.01,
        "{:#}",
        reports[3]
    );
    for key in ["r", "g", "b"] {
        assert!(
            reports[4]["output"]["message"][key].is_number(),
            "{:#}",
            reports[4]
        );
    }
    assert!(
        reports[5]["output"]["message"]["percentage"].is_number(),
        "{:#}",
        reports[5]
    );
    // Outside the bounds the file declares: refused before anything is sent.
    assert_eq!(
        reports[6]["decision"]["decision"], "refused",
        "{:#}",
        reports[6]
    );
    let why = reports[6]["decision"]["reason"].to_string();
    assert!(why.contains("invalid arguments"), "{why}");

    // The real model reaches a declared tool from the operator's words.
    let out = Command::new("timeout")
        .arg("120")
        .arg(env!("CARGO_BIN_EXE_ferrosa"))
        .args(["ask", "--robot", "sim", "--yes", "--json", "--threads", "2"])
        .args(["--tools", &example("mobile_base.toml")])
        .arg("dock the robot")
        .env("FERROSA_MODELS_DIR", crate::util::models_dir())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let result: Value = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{e}: {stdout}"));
    let docked = result["steps"]
        .as_array()
        .unwrap()
        .iter()
        .any(|s| s["name"] == "base_dock" && s["ok"] == true);
    assert!(docked, "{result:#}");

    // A malformed file stops ferrosa at start, naming its line and the fix.
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        "[[tool]]\nname = \"arm_lift\"\ndescription = \"Lift the arm. Moves the robot.\"\neffect = \"actuates\"\nparameters = { type = \"object\", properties = { height = { type = \"number\" } }, required = [\"height\"] }\n[tool.publish]\ntopic = \"/arm/lift\"\ntype = \"std_msgs/msg/Float64\"\nmessage = { data = \"{{height}}\" }\n",
    )
    .unwrap();
    let out = Command::new("timeout")
        .arg("60")
        .arg(env!("CARGO_BIN_EXE_ferrosa"))
        .args(["call", "--robot", "sim", "--tools"])
        .arg(&bad)
        .arg("ros_node_list")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("bad.toml, line 5") && stderr.contains("minimum and maximum"),
        "{stderr}"
    );
}
