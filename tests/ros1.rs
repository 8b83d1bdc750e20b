//! ROS 1: ferrosa against Debian's ROS 1 (a real `roscore`, and a rospy robot in
//! `tests/peers/ros1_robot.py`), in a loopback-only network namespace. Debian's own tools
//! (`rostopic`, `rosparam`) check what ferrosa sends from the other side, and the agent
//! with the real default model serves an operator's requests over it.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use ferrosa::agent::StepRecord;
use ferrosa::ui::agent::{build_with, connect, Robot};
use serde_json::json;

use crate::util::rerun_in_loopback_netns;

const MASTER: &str = "http://127.0.0.1:11311/";

/// The children of one test, killed when it ends (passing or not).
struct Peers(Vec<Child>);

impl Peers {
    fn stop(&mut self, i: usize) {
        crate::util::stop(&mut self.0[i]);
    }
}

impl Drop for Peers {
    fn drop(&mut self) {
        for i in (0..self.0.len()).rev() {
            self.stop(i);
        }
    }
}

pub fn ros_env<'a>(cmd: &'a mut Command, home: &Path) -> &'a mut Command {
    cmd.env("ROS_MASTER_URI", MASTER)
        .env("ROS_HOSTNAME", "127.0.0.1")
        .env("HOME", home)
        .env("ROS_LOG_DIR", home.join("log"))
}

/// What `rostopic echo -n 1 TOPIC` prints once ferrosa publishes `text` on it as a
/// std_msgs/String (published until the echo has subscribed, at most 20 s).
pub fn echoed_by_rostopic(
    graph: &dyn ferrosa::ros::RosGraph,
    rt: &tokio::runtime::Runtime,
    home: &Path,
    topic: &str,
    text: &str,
) -> String {
    let echo = ros_env(
        Command::new("timeout").args(["30", "rostopic", "echo", "-n", "1", topic]),
        home,
    )
    .stdout(Stdio::piped())
    .spawn()
    .unwrap();
    let start = Instant::now();
    loop {
        let sent = rt.block_on(graph.publish(topic, "std_msgs/String", json!({ "data": text })));
        if sent.is_ok() || start.elapsed() > Duration::from_secs(20) {
            sent.unwrap();
            break;
        }
    }
    let out = echo.wait_with_output().unwrap();
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A Debian ROS 1 command line tool's output (under a time limit).
fn ros_tool(home: &Path, args: &[&str]) -> String {
    let out = ros_env(Command::new("timeout").arg("30").args(args), home)
        .output()
        .unwrap_or_else(|e| panic!("{args:?}: {e} (.ci/setup installs Debian's ros-core)"));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `roscore` and the rospy robot, the graph showing the robot.
fn start_peers(home: &Path) -> Peers {
    std::fs::create_dir_all(home).unwrap();
    let mut peers = Peers(Vec::new());
    let spawn = |args: &[&str]| {
        ros_env(Command::new("timeout").arg("300").args(args), home)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("{args:?}: {e} (.ci/setup installs Debian's ros-core)"))
    };
    peers.0.push(spawn(&["roscore", "-p", "11311"]));
    let start = Instant::now();
    while !ros_tool(home, &["rosparam", "get", "/run_id"]).contains('-') {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "roscore did not start"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    let peer = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/peers/ros1_robot.py");
    peers.0.push(spawn(&["/usr/bin/python3", peer]));
    while !ros_tool(home, &["rostopic", "list"]).contains("/inspection/reading") {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the rospy robot did not start"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    peers
}

struct Approver;

impl ferrosa::tool::Confirm for Approver {
    fn confirm(&self, _: &ferrosa::tool::ToolCall) -> bool {
        true
    }
}

/// Everything the issue asks of ROS 1, against one roscore: Debian's tools read what
/// ferrosa publishes and sets, then the agent (one load of the default model) lists
/// nodes, topics and services, echoes and publishes a type nobody bundled, calls a
/// service, reads and sets a parameter, and reads `/rosout`; `rostopic pub /ferrosa/estop`
/// engages the e-stop; and the built-in sim served on ROS 1 moves on `rostopic pub` and
/// resets on `rosservice call`.
#[test]
#[ignore = "needs Debian's ROS 1, the model weights and a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn ros1_peers_and_the_agent_with_the_real_model() {
    if rerun_in_loopback_netns("ros1::ros1_peers_and_the_agent_with_the_real_model", 500) {
        return;
    }
    let home = std::env::temp_dir().join(format!("ferrosa-ros1-{}", std::process::id()));
    let mut peers = start_peers(&home);
    // Only this process's threads read these, before the graph starts.
    std::env::set_var("ROS_MASTER_URI", MASTER);
    std::env::set_var("ROS_HOSTNAME", "127.0.0.1");
    let link = connect(Robot::Ros1, false).unwrap();
    let graph = link.graph.clone().unwrap();
    let rt = crate::util::runtime();

    // `rostopic echo` (rospy, its generated std_msgs/String) receives what ferrosa sends.
    let echoed = echoed_by_rostopic(graph.as_ref(), &rt, &home, "/ferrosa_check", "over tcpros");
    assert!(echoed.contains("over tcpros"), "{echoed}");

    let args = crate::util::agent_args(Robot::Ros1, true);
    let estop = ferrosa::estop::EStop::new();
    let mut agent = build_with(&args, Arc::new(Approver), Some(graph.clone()), estop).unwrap();
    graph.set_fence(agent.fence().clone());
    let mut ask = |q: &str| crate::util::ask_shown(&mut agent, q);
    let ok =
        |steps: &[StepRecord], name: &str| steps.iter().find(|s| s.name == name && s.ok).cloned();

    for (q, tool, named) in [
        ("list the ROS nodes", "ros_node_list", "/turtlesim"),
        (
            "what topics are there?",
            "ros_topic_list",
            "/inspection/reading",
        ),
        (
            "list the services",
            "ros_service_list",
            "/turtle1/teleport_absolute",
        ),
    ] {
        let (r, why) = ask(q);
        ok(&r.steps, tool).unwrap_or_else(|| panic!("{why}"));
        assert!(r.answer.contains(named), "{why}");
    }

    // A type no one ships (field_msgs/Reading): learnt from its publisher's header.
    let (r, why) = ask("show me the latest reading from the inspection sensor");
    let echo = ok(&r.steps, "ros_topic_echo").unwrap_or_else(|| panic!("{why}"));
    assert_eq!(echo.output["messages"][0]["sensor"], "thermal_cam", "{why}");
    assert!(r.answer.contains("41.5"), "{why}");

    // And published (field_msgs/Command): learnt from the subscriber's header; the
    // robot keeps what it received in a parameter.
    let (r, why) = ask(r#"publish {"action": "scan", "level": 2} on /inspection/command"#);
    ok(&r.steps, "ros_topic_publish").unwrap_or_else(|| panic!("{why}"));
    assert_eq!(
        ros_tool(&home, &["rosparam", "get", "/turtlesim/last_command"]).trim(),
        "action=scan level=2.0",
        "{why}"
    );

    // A service call moves the turtle; its pose says so.
    let (r, why) = ask("teleport the turtle to x 2, y 3");
    ok(&r.steps, "ros_service_call").unwrap_or_else(|| panic!("{why}"));
    let pose = rt
        .block_on(graph.subscribe("/turtle1/pose", None, 1, Duration::from_secs(3)))
        .unwrap();
    assert_eq!(pose[0].message["x"], 2.0, "{why}");
    assert_eq!(pose[0].message["y"], 3.0, "{why}");

    // Parameters: read from the parameter server, and set there (rosparam sees it).
    let (r, why) = ask("what is the background_r parameter of /turtlesim?");
    ok(&r.steps, "ros_param_get").unwrap_or_else(|| panic!("{why}"));
    assert!(r.answer.contains("69"), "{why}");
    let (r, why) = ask("set the turtlesim background_r parameter to 10");
    ok(&r.steps, "ros_param_set").unwrap_or_else(|| panic!("{why}"));
    assert_eq!(
        ros_tool(&home, &["rosparam", "get", "/turtlesim/background_r"]).trim(),
        "10"
    );

    // /rosout: rosgraph_msgs/Log read as the log tool reads ROS 2's.
    let (r, why) = ask("read the ROS log");
    let log = ok(&r.steps, "ros_log_read").unwrap_or_else(|| panic!("{why}"));
    assert_eq!(log.output["entries"][0]["level"], "warn", "{why}");
    assert!(r.answer.contains("battery low"), "{why}");

    // The e-stop's ROS trigger works from a ROS 1 node too.
    assert!(agent.estop().engaged_by().is_none());
    ros_tool(
        &home,
        &[
            "rostopic",
            "pub",
            "-1",
            "/ferrosa/estop",
            "std_msgs/Bool",
            "data: true",
        ],
    );
    let start = Instant::now();
    while agent.estop().engaged_by().is_none() && start.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(50));
    }
    let engaged = agent
        .estop()
        .engaged_by()
        .expect("rostopic pub /ferrosa/estop engages the e-stop");
    eprintln!("e-stop engaged by {}", engaged.source);

    // The built-in sim served on ROS 1 in place of the rospy robot: Debian's tools
    // drive it through the bridge (a Twist passed on to the sim, a service served).
    peers.stop(1);
    let sim = connect(Robot::SimRos1, false).unwrap();
    let sim_graph = sim.graph.clone().unwrap();
    let x = |g: &std::sync::Arc<dyn ferrosa::ros::RosGraph>| {
        let pose = rt
            .block_on(g.subscribe("/turtle1/pose", None, 1, Duration::from_secs(3)))
            .unwrap();
        pose[0].message["x"].as_f64().unwrap()
    };
    let centre = ferrosa::ros::sim::CENTER;
    assert!((x(&sim_graph) - centre).abs() < 1e-3);
    ros_tool(
        &home,
        &[
            "rostopic",
            "pub",
            "-1",
            "/turtle1/cmd_vel",
            "geometry_msgs/Twist",
            "{linear: {x: 2.0}}",
        ],
    );
    assert!(x(&sim_graph) > 5.6, "the sim did not move on rostopic pub");
    ros_tool(&home, &["rosservice", "call", "/reset"]);
    assert!(
        (x(&sim_graph) - centre).abs() < 1e-3,
        "rosservice call /reset did not reach the sim"
    );
    drop(sim);
    let _ = std::fs::remove_dir_all(&home);
}
