//! The ROS 2 graph against the built-in sim, over real DDS on loopback: discovery,
//! the node join, echo with the offered QoS, publish, services, parameters, logs.
//! Every test runs in its own loopback-only network namespace (see util).

use std::time::{Duration, Instant};

use ferrosa::ros::ros2::{Ros2Graph, Ros2Options};
use ferrosa::ros::sim::{Sim, CENTER};
use ferrosa::ros::{GoalStatus, RosGraph};
use serde_json::json;

use crate::util::{rerun_in_loopback_netns, runtime};

/// Wait until the graph shows `/turtlesim` with its services; returns the time taken.
pub async fn wait_for_sim(graph: &Ros2Graph, limit: Duration) -> Duration {
    let start = Instant::now();
    loop {
        let g = graph.graph().await.unwrap();
        if Sim::discovered_in(&g) {
            return start.elapsed();
        }
        assert!(
            start.elapsed() < limit,
            "sim not discovered within {limit:?}: nodes {:?} topics {:?} services {:?}",
            g.nodes,
            g.topics(),
            g.services().keys().collect::<Vec<_>>()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn sim_graph_echo_publish_services_parameters() {
    if rerun_in_loopback_netns("ros::sim_graph_echo_publish_services_parameters", 120) {
        return;
    }
    let rt = runtime();
    rt.block_on(async {
        let opts = Ros2Options::default();
        let start = Instant::now();
        let graph = Ros2Graph::start(&opts, "_ferrosa_test").unwrap();
        let _sim = Sim::start(&opts).unwrap();
        let took = wait_for_sim(&graph, Duration::from_secs(20)).await;
        eprintln!("sim discovered {:?} after start", took.max(start.elapsed()));

        let g = graph.graph().await.unwrap();
        assert_eq!(g.nodes, ["/turtlesim"], "our own node is hidden");
        let topics = g.topics();
        assert!(topics["/turtle1/pose"].contains("turtlesim/msg/Pose"));
        assert!(topics["/turtle1/cmd_vel"].contains("geometry_msgs/msg/Twist"));
        assert!(topics.contains_key("/battery_state") && topics.contains_key("/rosout"));
        let pose_pub = g.publishers.iter().find(|p| p.topic == "/turtle1/pose").unwrap();
        assert_eq!(pose_pub.node.as_deref(), Some("/turtlesim"));
        let cmd_sub = g.subscribers.iter().find(|p| p.topic == "/turtle1/cmd_vel").unwrap();
        assert_eq!(cmd_sub.node.as_deref(), Some("/turtlesim"));
        let services = g.services();
        for s in ["/spawn", "/kill", "/reset", "/clear", "/turtle1/set_pen", "/turtle1/teleport_absolute",
                  "/turtle1/teleport_relative", "/turtlesim/get_parameters", "/turtlesim/set_parameters"] {
            assert!(services.contains_key(s), "{s} missing from {services:?}");
        }

        // Echo, type and QoS from discovery.
        let poses = graph.subscribe("/turtle1/pose", None, 3, Duration::from_secs(5)).await.unwrap();
        assert_eq!(poses.len(), 3);
        assert!((poses[0].message["x"].as_f64().unwrap() - CENTER).abs() < 1e-4);

        // Drive: 1.5 m/s for the 1 s turtlesim holds a command.
        graph.publish("/turtle1/cmd_vel", "geometry_msgs/msg/Twist", json!({"linear": {"x": 1.5}})).await.unwrap();
        tokio::time::sleep(Duration::from_millis(1500)).await;
        eprintln!("DIRECT {:?}", _sim.pose("turtle1"));
        let after = graph.subscribe("/turtle1/pose", None, 1, Duration::from_secs(5)).await.unwrap();
        let x = after[0].message["x"].as_f64().unwrap();
        assert!((x - (CENTER + 1.5)).abs() < 0.1, "x = {x}");

        // Services.
        graph.call_service("/turtle1/teleport_absolute", "turtlesim/srv/TeleportAbsolute",
            json!({"x": 2.0, "y": 3.0, "theta": 0.5}), Duration::from_secs(5)).await.unwrap();
        let spawned = graph.call_service("/spawn", "turtlesim/srv/Spawn",
            json!({"x": 1.0, "y": 1.0, "theta": 0.0, "name": "rafael"}), Duration::from_secs(5)).await.unwrap().response;
        assert_eq!(spawned, json!({"name": "rafael"}));
        let p = graph.subscribe("/turtle1/pose", None, 1, Duration::from_secs(5)).await.unwrap();
        assert!((p[0].message["x"].as_f64().unwrap() - 2.0).abs() < 1e-4);
        let err = graph.call_service("/nope", "std_srvs/srv/Empty", json!({}), Duration::from_millis(500)).await.unwrap_err();
        assert!(err.to_string().contains("no service /nope"), "{err}");

        // Parameters are services.
        let got = graph.call_service("/turtlesim/get_parameters", "rcl_interfaces/srv/GetParameters",
            json!({"names": ["background_r"]}), Duration::from_secs(5)).await.unwrap().response;
        assert_eq!(got["values"][0]["integer_value"], json!(69));
        let set = graph.call_service("/turtlesim/set_parameters", "rcl_interfaces/srv/SetParameters",
            json!({"parameters": [{"name": "background_r", "value": {"type": 2, "integer_value": 10}}]}),
            Duration::from_secs(5)).await.unwrap().response;
        assert_eq!(set["results"][0]["successful"], json!(true), "{set}");

        // Logs: /rosout keeps history for late joiners.
        let logs = graph.subscribe("/rosout", None, 50, Duration::from_secs(2)).await.unwrap();
        assert!(logs.iter().any(|l| l.message["msg"].as_str().unwrap().contains("Spawning turtle [rafael]")), "{logs:?}");
    });
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn sim_rotate_absolute_action_succeeds_and_cancels() {
    if rerun_in_loopback_netns("ros::sim_rotate_absolute_action_succeeds_and_cancels", 120) {
        return;
    }
    let rt = runtime();
    rt.block_on(async {
        let opts = Ros2Options::default();
        let graph = Ros2Graph::start(&opts, "_ferrosa_test").unwrap();
        let sim = Sim::start(&opts).unwrap();
        wait_for_sim(&graph, Duration::from_secs(20)).await;
        let action = "/turtle1/rotate_absolute";
        let ty = "turtlesim/action/RotateAbsolute";
        let g = graph.graph().await.unwrap();
        // The turtle's own action (the sim also serves Nav2's /navigate_to_pose).
        let actions: Vec<_> = g
            .actions()
            .into_iter()
            .filter(|a| a.action.starts_with("/turtle1/"))
            .collect();
        assert_eq!(actions.len(), 1, "{actions:?}");
        assert_eq!(
            (actions[0].action.as_str(), actions[0].type_name.as_str()),
            (action, ty)
        );
        assert_eq!(actions[0].servers, ["/turtlesim"]);

        // A quarter turn at turtlesim's 1 rad/s: about 1.6 s, with feedback all along.
        let start = Instant::now();
        let done = graph
            .send_goal(
                action,
                ty,
                json!({"theta": std::f64::consts::FRAC_PI_2}),
                Duration::from_secs(10),
            )
            .await
            .unwrap();
        eprintln!(
            "quarter turn: {:?}, {} feedback",
            start.elapsed(),
            done.feedback.len()
        );
        assert_eq!(done.status, GoalStatus::Succeeded, "{done:?}");
        let delta = done.result.as_ref().unwrap()["delta"].as_f64().unwrap();
        assert!(
            (delta + std::f64::consts::FRAC_PI_2).abs() < 0.05,
            "turned {delta}: {done:?}"
        );
        let first = done.feedback.first().expect("feedback while turning");
        let last = done.feedback.last().unwrap();
        let remaining = |s: &ferrosa::ros::Sample| s.message["remaining"].as_f64().unwrap();
        assert!(
            remaining(first) > remaining(last) + 0.3 && remaining(last) < 0.2,
            "{:?}",
            done.feedback
        );
        let theta = sim.pose("turtle1").unwrap()["theta"].as_f64().unwrap();
        assert!(
            (theta - std::f64::consts::FRAC_PI_2).abs() < 0.03,
            "theta {theta}"
        );

        // A goal followed for 0.3 s is still running; cancelling it stops the turtle.
        let running = graph
            .send_goal(
                action,
                ty,
                json!({"theta": -std::f64::consts::FRAC_PI_2}),
                Duration::from_millis(300),
            )
            .await
            .unwrap();
        assert_eq!(running.status, GoalStatus::Running, "{running:?}");
        let cancel = graph
            .cancel_goals(action, ty, Some(&running.goal_id), Duration::from_secs(5))
            .await
            .unwrap();
        assert_eq!(cancel.return_code, "accepted", "{cancel:?}");
        assert_eq!(cancel.canceling, std::slice::from_ref(&running.goal_id));
        tokio::time::sleep(Duration::from_millis(300)).await;
        let stopped = sim.pose("turtle1").unwrap()["theta"].as_f64().unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let later = sim.pose("turtle1").unwrap()["theta"].as_f64().unwrap();
        assert!(
            stopped > 0.0 && (later - stopped).abs() < 1e-6,
            "{stopped} then {later}"
        );

        // Nothing left to cancel; an unknown action is an error naming it.
        let none = graph
            .cancel_goals(action, ty, None, Duration::from_secs(5))
            .await
            .unwrap();
        assert_eq!(none.return_code, "rejected", "{none:?}");
        let err = graph
            .send_goal("/turtle1/spin", ty, json!({}), Duration::from_secs(1))
            .await
            .unwrap_err();
        assert!(err.to_string().contains("/turtle1/spin"), "{err}");
    });
}

/// `ferrosa ask --robot sim --json QUERY` with the real default model; the JSON result.
fn ask_sim(query: &str, extra: &[&str]) -> serde_json::Value {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_ferrosa"))
        .args(["ask", "--robot", "sim", "--json", "--threads", "2"])
        .args(extra)
        .arg(query)
        .env("FERROSA_MODELS_DIR", crate::util::models_dir())
        .output()
        .expect("running ferrosa");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "ferrosa ask failed: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn ask_sim_lists_nodes_with_the_real_model() {
    if rerun_in_loopback_netns("ros::ask_sim_lists_nodes_with_the_real_model", 240) {
        return;
    }
    let result = ask_sim("list the ROS nodes", &[]);
    let steps = result["steps"].as_array().unwrap();
    let call = steps
        .iter()
        .find(|s| s["name"] == "ros_node_list")
        .unwrap_or_else(|| panic!("{result:#}"));
    let output = call["output"].to_string();
    assert!(output.contains("/turtlesim"), "{result:#}");
    let answer = result["answer"].as_str().unwrap();
    assert!(
        answer.contains("/turtlesim"),
        "the answer names the node: {result:#}"
    );
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn ask_sim_moves_the_turtle_with_the_real_model() {
    if rerun_in_loopback_netns("ros::ask_sim_moves_the_turtle_with_the_real_model", 240) {
        return;
    }
    let result = ask_sim("move the turtle forward 2 meters", &["--yes"]);
    let steps = result["steps"].as_array().unwrap();
    let moved = steps
        .iter()
        .find(|s| s["name"] == "turtle_move" && s["ok"] == true)
        .unwrap_or_else(|| panic!("no turtle_move: {result:#}"));
    // The pose the tool read back over ROS after the move.
    let x = moved["output"]["pose"]["x"].as_f64().unwrap();
    assert!((x - (CENTER + 2.0)).abs() < 0.1, "x = {x}: {result:#}");
}

/// The Python of the rclpy virtualenv `.ci/setup` makes (or `FERROSA_RCLPY_PYTHON`).
pub fn rclpy_python() -> std::path::PathBuf {
    let p = std::env::var_os("FERROSA_RCLPY_PYTHON")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| {
            std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/rosvenv/bin/python")
        });
    assert!(
        p.exists(),
        "{} missing: run .ci/setup (it makes the rclpy virtualenv)",
        p.display()
    );
    p
}

pub fn peer_script() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/peers/rclpy_peer.py")
}

/// Stops the peer when the test ends: SIGTERM to its `timeout`, which passes it on (a
/// SIGKILL would leave the peer running); `timeout` alone ends it if this process dies.
pub struct Peer(pub std::process::Child);

impl Drop for Peer {
    fn drop(&mut self) {
        let _ = std::process::Command::new("kill")
            .arg(self.0.id().to_string())
            .status();
        let _ = self.0.wait();
    }
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn ferrosa_tools_on_an_rclpy_peer() {
    use ferrosa::tool::{Registry, ToolContext};
    if rerun_in_loopback_netns("ros::ferrosa_tools_on_an_rclpy_peer", 120) {
        return;
    }
    let _peer = Peer(
        std::process::Command::new("timeout")
            .args(["100"])
            .arg(rclpy_python())
            .arg(peer_script())
            .arg("serve")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("starting the rclpy peer"),
    );
    let rt = runtime();
    rt.block_on(async {
        let graph = std::sync::Arc::new(
            Ros2Graph::start(&Ros2Options::default(), "_ferrosa_test").unwrap(),
        );
        let start = Instant::now();
        loop {
            let g = graph.graph().await.unwrap();
            if g.nodes.iter().any(|n| n == "/peer")
                && g.services().contains_key("/peer/trigger")
                && g.topics().contains_key("/chatter")
            {
                break;
            }
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "rclpy peer not discovered: {:?}",
                g.nodes
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        eprintln!("rclpy peer discovered after {:?}", start.elapsed());
        let mut tools = Registry::new();
        tools.add(ferrosa::tools::ros::package(graph.clone()));
        let cx = ToolContext::new(Duration::from_secs(10));
        let call = |name: &str, args: serde_json::Value| {
            let tool = tools.get(name).expect("a ROS tool").clone();
            let cx = cx.clone();
            async move { tool.call(args, &cx).await }
        };

        let nodes = call("ros_node_list", json!({})).await.unwrap();
        assert!(
            nodes["nodes"].as_array().unwrap().contains(&json!("/peer")),
            "{nodes}"
        );
        let info = call("ros_node_info", json!({"node": "/peer"}))
            .await
            .unwrap();
        assert!(
            info["publishers"].to_string().contains("/chatter"),
            "{info}"
        );
        let echo = call("ros_topic_echo", json!({"topic": "/chatter", "count": 2}))
            .await
            .unwrap();
        assert_eq!(echo["count"], 2, "{echo}");
        assert!(
            echo["messages"][0]["data"]
                .as_str()
                .unwrap()
                .starts_with("hello "),
            "{echo}"
        );
        // A type ferrosa does not ship: its definition (and those it nests) comes from
        // the peer's ~/get_type_description, found by the hash in discovery.
        assert!(
            graph
                .interfaces()
                .message("lifecycle_msgs/msg/TransitionEvent")
                .is_err(),
            "the test needs a type outside the bundle"
        );
        let event = call("ros_topic_echo", json!({"topic": "/peer/transition"}))
            .await
            .unwrap();
        assert_eq!(event["count"], 1, "{event}");
        let m = &event["messages"][0];
        assert_eq!(m["transition"]["label"], "configure", "{event}");
        assert_eq!(m["start_state"]["label"], "unconfigured", "{event}");
        assert_eq!(m["goal_state"]["id"], 2, "{event}");
        let trig = call("ros_service_call", json!({"service": "/peer/trigger"}))
            .await
            .unwrap();
        assert_eq!(trig["response"]["success"], true, "{trig}");
        assert!(
            trig["response"]["message"]
                .as_str()
                .unwrap()
                .starts_with("triggered after"),
            "{trig}"
        );
        // ferrosa publishes once, as soon as the subscriber has matched: a Fast DDS
        // reader must still get it (the peer reports what it received).
        let sent = call(
            "ros_topic_publish",
            json!({"topic": "/peer/command", "message": {"data": "go"}}),
        )
        .await
        .unwrap();
        assert_eq!(sent["type"], "std_msgs/msg/String", "{sent}");
        let heard = async {
            for _ in 0..20 {
                let t = call("ros_service_call", json!({"service": "/peer/trigger"}))
                    .await
                    .unwrap();
                let m = t["response"]["message"].as_str().unwrap_or("").to_string();
                if m.ends_with("commands: ['go']") {
                    return Ok(m);
                }
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            Err("the peer never received the published command")
        };
        heard.await.unwrap();
        let flag = call(
            "ros_service_call",
            json!({"service": "/peer/set_flag", "request": {"data": true}}),
        )
        .await
        .unwrap();
        assert_eq!(flag["response"]["message"], "flag is True", "{flag}");
        let params = call("ros_param_list", json!({"node": "/peer"}))
            .await
            .unwrap();
        assert!(
            params["parameters"]
                .as_array()
                .unwrap()
                .contains(&json!("speed")),
            "{params}"
        );
        let speed = call("ros_param_get", json!({"node": "/peer", "name": "speed"}))
            .await
            .unwrap();
        assert_eq!(speed["value"], 0.5);
        call(
            "ros_param_set",
            json!({"node": "/peer", "name": "speed", "value": 0.75}),
        )
        .await
        .unwrap();
        let speed = call("ros_param_get", json!({"node": "/peer", "name": "speed"}))
            .await
            .unwrap();
        assert_eq!(speed["value"], 0.75);
    });
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn rclpy_sees_and_drives_the_sim() {
    if rerun_in_loopback_netns("ros::rclpy_sees_and_drives_the_sim", 120) {
        return;
    }
    let sim = Sim::start(&Ros2Options::default()).unwrap();
    let out = std::process::Command::new("timeout")
        .args(["60"])
        .arg(rclpy_python())
        .arg(peer_script())
        .arg("drive")
        .output()
        .expect("running the rclpy driver");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "rclpy driver: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    let seen: serde_json::Value =
        serde_json::from_str(stdout.lines().last().unwrap_or("")).unwrap();
    assert!(
        seen["nodes"]
            .as_array()
            .unwrap()
            .contains(&json!("/turtlesim")),
        "{seen}"
    );
    assert_eq!(
        seen["topics"]["/turtle1/pose"],
        json!(["turtlesim/msg/Pose"]),
        "{seen}"
    );
    assert_eq!(
        seen["services"]["/spawn"],
        json!(["turtlesim/srv/Spawn"]),
        "{seen}"
    );
    assert_eq!(seen["subscribers"], 1, "{seen}");
    assert_eq!(seen["cleared"], true, "{seen}");
    std::thread::sleep(Duration::from_millis(1200));
    // At 1 m/s from the first command received to the last (up to 0.9 s), plus the 1 s
    // turtlesim holds the last one. Under load the ten can arrive together, which leaves
    // just the hold: 62 updates of 16 ms, 0.992 m (seen once in a clean CI run: 0.993 m).
    let x = sim.pose("turtle1").unwrap()["x"].as_f64().unwrap();
    assert!((0.95..2.2).contains(&(x - CENTER)), "x = {x}");
}

/// Every number an answer states is one a result or the request holds: nothing is
/// invented.
fn assert_states_only_results(r: &ferrosa::agent::RunResult, request: &str, why: &str) {
    let held: String = r
        .steps
        .iter()
        .map(|s| s.output.to_string())
        .chain([request.to_string()])
        .collect();
    let numbers = |t: &str| -> Vec<String> {
        t.split(|c: char| !c.is_ascii_digit() && c != '.')
            .map(|w| w.trim_matches('.'))
            .filter(|w| w.chars().any(|c| c.is_ascii_digit()))
            .map(str::to_string)
            .collect()
    };
    let known = numbers(&held);
    for n in numbers(&r.answer) {
        let value: f64 = n.parse().unwrap_or(f64::NAN);
        let found = known
            .iter()
            .any(|k| k == &n || k.parse::<f64>().is_ok_and(|v| (v - value).abs() < 0.005))
            || held.contains(&n);
        assert!(found, "{n} is in no result: {why}");
    }
}

/// The operator at the console: approves what they are asked about, and remembers it.
#[derive(Default)]
struct Approver(std::sync::Mutex<Vec<String>>);

impl ferrosa::tool::Confirm for Approver {
    fn confirm(&self, call: &ferrosa::tool::ToolCall) -> bool {
        self.0.lock().unwrap().push(call.name.clone());
        true
    }
}

/// The agent with the real default model on the sim, as an operator uses it: a
/// greeting (no call), a count, a field, a type's definition, a parameter, two questions
/// in one request (each answer stating the asked fact and no number the results lack), a
/// status report, a request whose call fails, a Spanish
/// request, a two-step request and a Spanish motion request after confirmation, with
/// the default tool pick (weighed). One model load for all of them.
#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn the_agent_serves_operator_requests_with_the_real_model() {
    use ferrosa::agent::StepRecord;
    use ferrosa::ui::agent::{build_with, connect, Robot};
    use std::sync::Arc;
    if rerun_in_loopback_netns(
        "ros::the_agent_serves_operator_requests_with_the_real_model",
        400,
    ) {
        return;
    }
    let link = connect(Robot::Sim, false).unwrap();
    let graph = link.graph.clone().unwrap();
    let args = crate::util::agent_args(Robot::Sim, false);
    let operator = Arc::new(Approver::default());
    let estop = ferrosa::estop::EStop::new();
    let mut agent = build_with(&args, operator.clone(), Some(graph.clone()), estop).unwrap();
    graph.set_fence(agent.fence().clone());
    let mut ask = |q: &str| crate::util::ask_shown(&mut agent, q);
    let ok =
        |steps: &[StepRecord], name: &str| steps.iter().find(|s| s.name == name && s.ok).cloned();

    // A greeting is answered without a call, so with nothing invented from one.
    let (r, why) = ask("hi there, glad to meet you");
    assert!(r.steps.is_empty(), "{why}");
    // It is the agent's own greeting (`data/replies`), not the model's words; thanks in
    // German get the German line, though three words show too little of a language.
    assert!(r.answer.starts_with("Hello!"), "{why}");
    let (r, why) = ask("vielen Dank, tschüss");
    assert!(
        r.steps.is_empty() && r.answer.starts_with("Gern geschehen"),
        "{why}"
    );

    // A count is answered with the count the listing gave.
    let (r, why) = ask("how many topics does this robot have at the moment?");
    let listing = ok(&r.steps, "ros_topic_list").unwrap_or_else(|| panic!("{why}"));
    let count = listing.output["count"].as_u64().unwrap();
    let said: Vec<&str> = r
        .answer
        .split(|c: char| !c.is_ascii_digit())
        .filter(|w| !w.is_empty())
        .collect();
    assert!(said.contains(&count.to_string().as_str()), "{why}");

    // A field: the value asked for, as the result gave it, and no number the results
    // and the request do not hold.
    let q = "what is the turtle's x position right now?";
    let (r, why) = ask(q);
    let read = r
        .steps
        .iter()
        .find(|s| s.ok && (s.name == "turtle_pose" || s.name == "ros_topic_echo"))
        .unwrap_or_else(|| panic!("{why}"));
    let x = if read.name == "turtle_pose" {
        read.output["x"].as_f64()
    } else {
        read.output["messages"][0]["x"].as_f64()
    };
    let x = format!("{:.3}", x.unwrap_or_else(|| panic!("{why}")));
    assert!(r.answer.contains(&x[..x.len() - 1]), "{why}");
    assert_states_only_results(&r, q, &why);

    // A definition: the fields of the type, by name.
    let q = "which fields does a turtlesim/srv/Spawn request carry?";
    let (r, why) = ask(q);
    ok(&r.steps, "ros_interface_show").unwrap_or_else(|| panic!("{why}"));
    for field in ["x", "y", "theta", "name"] {
        let words: Vec<&str> = r
            .answer
            .split(|c: char| !c.is_alphanumeric() && c != '_')
            .collect();
        assert!(words.contains(&field), "{field}: {why}");
    }
    assert_states_only_results(&r, q, &why);

    // A parameter: its value as read.
    let q = "tell me the value of background_b on /turtlesim";
    let (r, why) = ask(q);
    let param = ok(&r.steps, "ros_param_get").unwrap_or_else(|| panic!("{why}"));
    let value = param.output["value"].to_string();
    assert!(r.answer.contains(&value), "{why}");
    assert_states_only_results(&r, q, &why);

    // Two questions in one request: each answered, each from its own listing.
    let q = "show me the nodes, then show me the services";
    let (r, why) = ask(q);
    let nodes = ok(&r.steps, "ros_node_list").unwrap_or_else(|| panic!("{why}"));
    let services = ok(&r.steps, "ros_service_list").unwrap_or_else(|| panic!("{why}"));
    assert!(r.answer.contains("/turtlesim"), "{why}");
    let listed = services.output["count"].as_u64().unwrap_or_default();
    assert!(
        listed > 0 && r.answer.contains(&listed.to_string()),
        "{why}"
    );
    assert!(nodes.output["count"].as_u64() == Some(1), "{why}");
    assert_states_only_results(&r, q, &why);

    // A status report: battery, diagnostics and nodes in one call; the answer states
    // the battery's charge as read.
    let (r, why) = ask("give me a status report");
    let status = ok(&r.steps, "robot_status").unwrap_or_else(|| panic!("{why}"));
    let percent = status.output["battery"][0]["percent"].as_f64().unwrap();
    assert!(
        r.answer.contains(&format!("{percent}")),
        "{why}: {}",
        r.answer
    );

    // A failing call is never made again as it was.
    let (r, why) = ask("echo the /odom topic");
    let failed: Vec<&StepRecord> = r.steps.iter().filter(|s| !s.ok).collect();
    assert!(!failed.is_empty(), "no call failed: {why}");
    for f in &failed {
        let again = r
            .steps
            .iter()
            .filter(|s| s.name == f.name && s.arguments == f.arguments)
            .count();
        assert_eq!(again, 1, "{} {} repeated: {why}", f.name, f.arguments);
    }

    // Spanish: the same tool as in English, and the answer names what it found.
    let (r, why) = ask("lista los nodos de ROS");
    ok(&r.steps, "ros_node_list").unwrap_or_else(|| panic!("{why}"));
    assert!(r.answer.contains("/turtlesim"), "{why}");
    // Nothing here moved the robot, so the operator was asked nothing.
    assert!(operator.0.lock().unwrap().is_empty(), "{why}");

    // Two steps: each part of the request gets its call, in order, each confirmed, and
    // the second starts where the first left the turtle.
    let (r, why) = ask("rotate the turtle 90 degrees and then move it forward 1 meter");
    let names: Vec<&str> = r.steps.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["turtle_rotate", "turtle_move"], "{why}");
    assert!(r.steps.iter().all(|s| s.ok), "{why}");
    let heading = r.steps[1].output["pose"]["theta_deg"].as_f64().unwrap();
    assert!((heading - 90.0).abs() < 5.0, "{why}");
    assert_eq!(
        *operator.0.lock().unwrap(),
        ["turtle_rotate", "turtle_move"],
        "{why}"
    );

    // Spanish motion: confirmed, then moved the distance asked.
    operator.0.lock().unwrap().clear();
    let (r, why) = ask("mueve la tortuga 1 metro hacia adelante");
    let moved = ok(&r.steps, "turtle_move").unwrap_or_else(|| panic!("{why}"));
    assert!(
        (moved.output["moved_m"].as_f64().unwrap() - 1.0).abs() < 0.1,
        "{why}"
    );
    assert_eq!(*operator.0.lock().unwrap(), ["turtle_move"], "{why}");
}
