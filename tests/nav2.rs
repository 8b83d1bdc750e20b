//! The place tools against a Nav2 navigator ferrosa did not write: an rclpy node
//! (`tests/peers/nav2_peer.py`) serving `/navigate_to_pose` with nav2_msgs' generated
//! types, over real DDS on loopback. nav2_msgs is not on PyPI: `.ci/setup` generates it
//! from ferrosa's bundled definition with ROS 2 Jazzy's own interface generators
//! (`scripts/build-nav2-msgs.sh`), and the test checks the hashes the navigator
//! announces against Jazzy's nav2_msgs. The navigator prints what reaches it, so the
//! goal, the feedback, a rejection and the cancel are read on both sides of the wire.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ferrosa::estop::EStop;
use ferrosa::ros::ros2::{Ros2Graph, Ros2Options};
use ferrosa::ros::RosGraph;
use ferrosa::tool::exec::Executor;
use ferrosa::tool::policy::NoOperator;
use ferrosa::tool::ToolCall;
use ferrosa::ui::agent::{tools_and_policy, Robot};
use serde_json::{json, Value};

use crate::places::call_reporting;
use crate::ros::Peer;
use crate::util::rerun_in_loopback_netns;

const NAV: &str = "/navigate_to_pose";
/// The RIHS01 hash of Jazzy's nav2_msgs/action/NavigateToPose_FeedbackMessage
/// (navigation2's `jazzy` branch at f4108e5b1, generated with rosidl 4.6.6). It covers
/// the whole action's fields: the feedback's own, and the pose and stamp types inside;
/// a definition that differs in any field hashes otherwise.
const JAZZY_FEEDBACK_HASH: &str =
    "RIHS01_9d1f6fa2eb975ce733b419ac2e97b134d8ff92b6478b6559feed9a50bdfd82b3";

/// The robot file of a mobile base the project has never tuned for: its places in `map`
/// (one in `odom`, which the navigator cannot transform), its pose on `/amcl_pose`.
const ROBOT_FILE: &str = r#"
embodiment_and_persona = "You are the on-board assistant of a warehouse base."
pose_topic = "/amcl_pose"

[[places]]
name = "dock"
x = 2.0
y = -1.0
yaw = 1.5707963
aliases = ["charger"]

[[places]]
name = "far bay"
x = 40.0
y = 0.0
yaw = 0.0

[[places]]
name = "odometry origin"
frame = "odom"
x = 0.0
y = 0.0
yaw = 0.0
"#;

/// The navigator's lines so far, read by a thread of its own.
struct Heard(Arc<Mutex<Vec<Value>>>);

impl Heard {
    fn events(&self, kind: &str) -> Vec<Value> {
        let lines = self.0.lock().unwrap();
        lines
            .iter()
            .filter(|e| e["event"] == kind)
            .cloned()
            .collect()
    }

    /// Waits up to `limit` for the `n`th line of `kind`.
    fn wait_for(&self, kind: &str, n: usize, limit: Duration) -> Vec<Value> {
        let start = Instant::now();
        loop {
            let seen = self.events(kind);
            if seen.len() >= n {
                return seen;
            }
            assert!(
                start.elapsed() < limit,
                "no {kind} line from the navigator within {limit:?}: {:?}",
                self.0.lock().unwrap()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// `nav2_peer.py`, under `timeout`, its stdout read line by line.
fn start_navigator(limit_s: u32) -> (Peer, Heard) {
    let mut child = Command::new("timeout")
        .args(["-k", "5", &limit_s.to_string()])
        .arg(crate::ros::rclpy_python())
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/peers/nav2_peer.py"
        ))
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("starting the Nav2 peer");
    let out = child.stdout.take().unwrap();
    let lines = Arc::new(Mutex::new(Vec::new()));
    let kept = lines.clone();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            if let Ok(v) = serde_json::from_str::<Value>(&line) {
                kept.lock().unwrap().push(v);
            }
        }
    });
    (Peer(child), Heard(lines))
}

#[test]
#[ignore = "needs root for a loopback-only network namespace and the rclpy virtualenv: cargo test --release -- --include-ignored"]
fn goals_feedback_rejection_and_cancel_reach_an_rclpy_nav2_navigator() {
    if rerun_in_loopback_netns(
        "nav2::goals_feedback_rejection_and_cancel_reach_an_rclpy_nav2_navigator",
        150,
    ) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let robot_file = dir.path().join("base.toml");
    std::fs::write(&robot_file, ROBOT_FILE).unwrap();
    let (_peer, heard) = start_navigator(140);

    let opts = Ros2Options::default();
    let graph: Arc<dyn RosGraph> = Arc::new(Ros2Graph::start(&opts, "_ferrosa_test").unwrap());
    // The action with its type, and the navigator's hash for it, as discovered.
    let start = Instant::now();
    let feedback_hash = loop {
        let g = ferrosa::ros::graph_now(graph.as_ref());
        let hash = g.as_ref().and_then(|g| {
            g.actions()
                .iter()
                .any(|a| a.action == NAV && a.type_name == "nav2_msgs/action/NavigateToPose")
                .then(|| {
                    g.publishers
                        .iter()
                        .find(|p| p.topic == format!("{NAV}/_action/feedback"))
                        .and_then(|p| p.type_hash.clone())
                })
                .flatten()
        });
        if let Some(hash) = hash {
            break hash;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the navigator's action was not discovered: {g:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(
        feedback_hash, JAZZY_FEEDBACK_HASH,
        "the navigator's nav2_msgs differ from Jazzy's"
    );

    let estop = EStop::new();
    let mut args = crate::util::agent_args(Robot::Ros2, true);
    args.prompt = Some(robot_file);
    args.memory = Some(dir.path().join("memory.sqlite"));
    let (registry, policy, _) = tools_and_policy(
        &args,
        Arc::new(NoOperator),
        Some(graph.clone()),
        estop.clone(),
    )
    .expect("the tools and the policy");
    graph.set_fence(policy.fence().clone());
    let exec = Executor::new(registry, policy).expect("the executor");

    // A goal by alias: the pose on the wire is the robot file's, the feedback comes back
    // as the distance left (to a tenth of a metre), going down, and the navigator's
    // success is the call's.
    let (went, said) = call_reporting(&exec, "place_go", json!({"place": "the charger"}));
    assert_eq!(went["status"], "succeeded", "{went}");
    let goal = &heard.wait_for("goal", 1, Duration::from_secs(5))[0];
    assert_eq!(goal["frame"], "map", "{goal}");
    let near = |k: &str, v: f64| (goal[k].as_f64().unwrap() - v).abs() < 1e-3;
    assert!(
        near("x", 2.0) && near("y", -1.0) && near("yaw", std::f64::consts::FRAC_PI_2),
        "{goal}"
    );
    let sent: Vec<f64> = heard
        .events("feedback")
        .iter()
        .map(|e| e["distance_remaining"].as_f64().unwrap())
        .collect();
    let shown: Vec<f64> = said
        .iter()
        .filter_map(|s| {
            s.rsplit(": ")
                .next()?
                .strip_suffix(" m to go")?
                .parse()
                .ok()
        })
        .collect();
    assert!(
        shown.len() >= 2 && shown.windows(2).all(|w| w[1] <= w[0]),
        "the distance left as the operator saw it: {said:?}"
    );
    assert!(
        shown
            .iter()
            .all(|d| sent.iter().any(|s| (s - d).abs() <= 0.05 + 1e-9)),
        "shown {shown:?}, sent {sent:?}"
    );
    heard.wait_for("succeeded", 1, Duration::from_secs(5));

    // A goal the navigator rejects is reported as rejected, not as reached.
    let (rejected, _) = call_reporting(&exec, "place_go", json!({"place": "odometry origin"}));
    assert_eq!(rejected["status"], "rejected", "{rejected}");
    assert!(
        rejected["summary"].as_str().unwrap().contains("refused"),
        "{rejected}"
    );
    assert_eq!(
        heard.wait_for("rejected", 1, Duration::from_secs(5))[0]["frame"],
        "odom"
    );

    // The e-stop mid-way: the cancel reaches the navigator, which stops where it is.
    let go = std::thread::spawn(move || {
        exec.call(
            &ToolCall {
                name: "place_go".into(),
                arguments: json!({"place": "far bay"}),
            },
            &Arc::new(AtomicBool::new(false)),
        )
    });
    heard.wait_for("goal", 2, Duration::from_secs(10));
    let before = heard.events("feedback").len();
    heard.wait_for("feedback", before + 5, Duration::from_secs(10));
    estop.trigger("test");
    let stopped = go.join().unwrap();
    heard.wait_for("cancel_requested", 1, Duration::from_secs(10));
    let canceled = &heard.wait_for("canceled", 1, Duration::from_secs(10))[0];
    let x = canceled["x"].as_f64().unwrap();
    assert!(x > 2.0 && x < 39.0, "it stopped at {canceled}");
    assert!(
        !stopped.ok || stopped.output["status"] != "succeeded",
        "{:?}",
        stopped.output
    );
    assert!(heard.events("succeeded").len() == 1, "{:?}", heard.0);
}
