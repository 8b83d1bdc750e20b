//! `ferrosa mcp` against an MCP client nobody here wrote: the Python `mcp` package from
//! PyPI (`tests/peers/mcp_client.py`, in the virtualenv `.ci/setup` makes), over stdio and
//! over streamable HTTP on loopback, against the built-in sim. One namespace, one test.

use std::process::{Command, Stdio};
use std::time::Duration;

use serde_json::Value;

use crate::util::rerun_in_loopback_netns;

fn python() -> String {
    let venv = format!("{}/target/mcpvenv/bin/python", env!("CARGO_MANIFEST_DIR"));
    assert!(
        std::path::Path::new(&venv).exists(),
        "{venv} is missing: run .ci/setup (it makes the virtualenv with the `mcp` package)"
    );
    venv
}

/// The secret the HTTP server is started with, and the client sends.
const TOKEN: &str = "mcp-test-token-0123456789";

fn client(args: &[&str]) -> Value {
    let script = format!("{}/tests/peers/mcp_client.py", env!("CARGO_MANIFEST_DIR"));
    let out = Command::new("timeout")
        .arg("150")
        .arg(python())
        .arg(script)
        .args(args)
        .env("FERROSA_MCP_TOKEN", TOKEN)
        .output()
        .expect("running the MCP client");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "MCP client {args:?}: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

/// What every transport must show: the tools with their schemas, the node list, and a
/// move refused without approval, run with it, refused when declined.
fn judge(transport: &str, seen: &Value) {
    let none = &seen["none"];
    let tools: Vec<&str> = none["tools"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .collect();
    for t in ["ros_node_list", "turtle_move", "robot_stop"] {
        assert!(tools.contains(&t), "{transport}: {t} not listed: {tools:?}");
    }
    assert_eq!(none["read_only"]["ros_node_list"], true, "{transport}");
    assert_eq!(none["read_only"]["turtle_move"], false, "{transport}");
    assert_eq!(none["destructive"]["turtle_move"], true, "{transport}");
    assert_eq!(none["destructive"]["robot_stop"], false, "{transport}");
    assert_eq!(
        none["move_schema"]["properties"]["distance"]["type"], "number",
        "{transport}: {:#}",
        none["move_schema"]
    );
    for session in ["none", "approve", "decline"] {
        let s = &seen[session];
        assert_eq!(s["nodes_error"], false, "{transport}/{session}: {s:#}");
        assert!(
            s["nodes"].as_str().unwrap().contains("/turtlesim"),
            "{transport}/{session}: {s:#}"
        );
    }
    // No elicitation: never asked, refused, and told how to approve.
    assert_eq!(none["move_error"], true, "{transport}: {none:#}");
    let refused = none["move"].as_str().unwrap();
    assert!(
        refused.contains("refused") && refused.contains("--yes"),
        "{transport}: {refused}"
    );
    // Asked and approved: the turtle moved.
    let approved = &seen["approve"];
    assert_eq!(
        approved["asked"].as_array().unwrap().len(),
        1,
        "{transport}: {approved:#}"
    );
    assert!(
        approved["asked"][0]
            .as_str()
            .unwrap()
            .contains("turtle_move"),
        "{transport}: {approved:#}"
    );
    assert_eq!(approved["move_error"], false, "{transport}: {approved:#}");
    let report: Value = serde_json::from_str(approved["move"].as_str().unwrap()).unwrap();
    let moved = report["output"]["moved_m"].as_f64().unwrap();
    assert!((moved - 0.5).abs() < 0.05, "{transport}: {report:#}");
    // Asked and declined: refused.
    let declined = &seen["decline"];
    assert_eq!(
        declined["asked"].as_array().unwrap().len(),
        1,
        "{transport}: {declined:#}"
    );
    assert_eq!(declined["move_error"], true, "{transport}: {declined:#}");
}

#[test]
#[ignore = "needs the MCP client's virtualenv and a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn an_mcp_client_lists_and_calls_the_tools_under_the_policy() {
    if rerun_in_loopback_netns(
        "mcp::an_mcp_client_lists_and_calls_the_tools_under_the_policy",
        400,
    ) {
        return;
    }
    let ferrosa = env!("CARGO_BIN_EXE_ferrosa");
    let seen = client(&["stdio", ferrosa, "mcp", "--robot", "sim"]);
    judge("stdio", &seen);

    let (mut server, rest) = crate::util::spawn_until(
        Command::new("timeout")
            .arg("200")
            .arg(ferrosa)
            .args(["mcp", "--robot", "sim", "--http", "127.0.0.1:0"])
            .env("FERROSA_MCP_TOKEN", TOKEN)
            .stdin(Stdio::null())
            .stdout(Stdio::null()),
        "ferrosa mcp: streamable HTTP on ",
        "mcp",
        Duration::from_secs(60),
    );
    let url = rest.split_whitespace().next().unwrap();
    let seen = client(&["http", url]);
    crate::util::stop(&mut server);
    judge("http", &seen);

    // Anything but loopback is refused at start.
    let out = Command::new("timeout")
        .arg("30")
        .arg(ferrosa)
        .args(["mcp", "--http", "0.0.0.0:8765"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("loopback only"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
