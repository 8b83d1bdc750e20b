//! The e-stop and the operator's override on the wire: `ferrosa chat --robot sim` driven
//! as an operator would (lines on stdin, Ctrl-C as SIGINT), an rclpy node pressing
//! `/ferrosa/estop`, and a teleop publisher on the sim's mux, with the turtle's pose
//! watched from another participant. One child, one peer, one namespace: every check
//! that needs them runs in the one test.

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use ferrosa::ros::ros2::{Ros2Graph, Ros2Options};
use ferrosa::ros::RosGraph;
use serde_json::{json, Value};

use crate::util::{rerun_in_loopback_netns, runtime};

/// The pose as the observer received it.
#[derive(Clone, Copy, Debug)]
struct Sample {
    /// Seconds since the epoch (the peer reports its press on the same clock).
    at: f64,
    x: f64,
    y: f64,
    theta: f64,
}

impl Sample {
    fn differs(&self, o: &Sample) -> bool {
        (self.x - o.x).abs() > 1e-6
            || (self.y - o.y).abs() > 1e-6
            || (self.theta - o.theta).abs() > 1e-6
    }
}

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// `ferrosa chat` under `timeout`: lines in, `/call` reports and stderr out.
struct Chat {
    child: Child,
    stdin: ChildStdin,
    reports: Receiver<String>,
    stderr: Arc<Mutex<String>>,
}

impl Chat {
    fn start() -> Chat {
        let mut child = Command::new("timeout")
            .arg("170")
            .arg(env!("CARGO_BIN_EXE_ferrosa"))
            // No prompt cache: the chat then evaluates nothing ahead of the first line, so
            // no call here waits on the model (a `/call` and a stop never need it), however
            // busy the cores are with another test's model.
            .args(["chat", "--robot", "sim", "--yes", "--threads", "2"])
            .args(["--prompt-cache", "off"])
            .env("FERROSA_MODELS_DIR", crate::util::models_dir())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("running ferrosa chat");
        let stdin = child.stdin.take().unwrap();
        let (tx, reports) = std::sync::mpsc::channel();
        let out = child.stdout.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let stderr = Arc::new(Mutex::new(String::new()));
        let err = child.stderr.take().unwrap();
        let sink = stderr.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(err).lines().map_while(Result::ok) {
                let mut s = sink.lock().unwrap();
                s.push_str(&line);
                s.push('\n');
            }
        });
        let chat = Chat {
            child,
            stdin,
            reports,
            stderr,
        };
        chat.wait_for("ferrosa chat:", Duration::from_secs(60));
        chat
    }

    fn log(&self) -> String {
        self.stderr.lock().unwrap().clone()
    }

    /// Wait until stderr shows `text`.
    fn wait_for(&self, text: &str, limit: Duration) {
        let start = Instant::now();
        while !self.log().contains(text) {
            assert!(
                start.elapsed() < limit,
                "no {text:?} from ferrosa chat within {limit:?}:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Wait until standard output shows a line starting with `start` (an answer).
    fn wait_for_line(&self, start: &str, limit: Duration) {
        let begun = Instant::now();
        loop {
            let left = limit.saturating_sub(begun.elapsed());
            match self.reports.recv_timeout(left) {
                Ok(line) if line.trim_start().starts_with(start) => return,
                Ok(_) => continue,
                Err(e) => panic!("no line starting {start:?} ({e}):\n{}", self.log()),
            }
        }
    }

    fn send(&mut self, line: &str) {
        writeln!(self.stdin, "{line}").unwrap();
        self.stdin.flush().unwrap();
    }

    /// The next `/call` report (a JSON line; an answer's lines in between are passed
    /// over).
    fn report(&self, limit: Duration) -> Value {
        let start = Instant::now();
        loop {
            let left = limit.saturating_sub(start.elapsed());
            match self.reports.recv_timeout(left) {
                Ok(line) if !line.trim_start().starts_with('{') => continue,
                Ok(line) => {
                    return serde_json::from_str(&line)
                        .unwrap_or_else(|e| panic!("{e}: {line}\n{}", self.log()))
                }
                Err(RecvTimeoutError::Timeout) => {
                    panic!("no /call report within {limit:?}:\n{}", self.log())
                }
                Err(e) => panic!("{e}:\n{}", self.log()),
            }
        }
    }

    /// Run one call and return its report.
    fn call(&mut self, name: &str, args: Value) -> Value {
        self.send(&format!("/call {name} {args}"));
        // The first also waits for the chat to load the model and start.
        self.report(Duration::from_secs(60))
    }

    /// Ctrl-C: SIGINT to `timeout`, which passes it on.
    fn interrupt(&self) {
        let ok = Command::new("kill")
            .args(["-INT", &self.child.id().to_string()])
            .status()
            .unwrap()
            .success();
        assert!(ok, "kill -INT");
    }
}

impl Drop for Chat {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .arg(self.child.id().to_string())
            .status();
        let _ = self.child.wait();
    }
}

/// Poses seen so far, from the observer's participant.
type Poses = Arc<Mutex<Vec<Sample>>>;

fn last(poses: &Poses) -> Sample {
    *poses.lock().unwrap().last().expect("no pose received")
}

/// Wait until `cond` holds for the newest pose.
fn until(poses: &Poses, what: &str, cond: impl Fn(&Sample) -> bool) {
    let start = Instant::now();
    loop {
        if poses.lock().unwrap().last().is_some_and(&cond) {
            return;
        }
        assert!(
            start.elapsed() < Duration::from_secs(15),
            "{what}: pose {:?}",
            poses.lock().unwrap().last()
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// After a trigger at `t0` (epoch seconds): the time from `t0` to the first pose of the
/// still run that follows (the pose stopped changing at or before it: an upper bound,
/// within one pose period), once the pose has been still for `settle`. Asserts the
/// turtle was moving up to the trigger.
fn stop_latency(chat: &Chat, poses: &Poses, t0: f64, settle: Duration) -> f64 {
    std::thread::sleep(settle);
    let samples = poses.lock().unwrap().clone();
    let moving_before = samples
        .windows(2)
        .any(|w| w[1].at <= t0 && w[1].at > t0 - 0.1 && w[1].differs(&w[0]));
    assert!(
        moving_before,
        "the turtle was not moving when the e-stop was triggered"
    );
    let last_change = samples
        .windows(2)
        .rposition(|w| w[1].differs(&w[0]))
        .map(|i| i + 1)
        .unwrap();
    let still_from = samples.get(last_change + 1).map_or(f64::MAX, |s| s.at);
    let last_change = samples[last_change].at;
    let newest = samples.last().unwrap().at;
    assert!(
        newest - last_change > settle.as_secs_f64() * 0.8,
        "the pose was still changing {:.0} ms before the end: {:?}\n{}",
        (newest - last_change) * 1e3,
        samples
            .iter()
            .rev()
            .step_by(10)
            .take(12)
            .map(|s| (((s.at - t0) * 1e3).round(), s.x, s.theta))
            .collect::<Vec<_>>(),
        chat.log()
    );
    still_from - t0
}

/// Teleport home (x 1, y 5.5, heading 0) and start a slow 5 m drive; returns once the
/// turtle is seen moving.
fn start_drive(chat: &mut Chat, poses: &Poses) {
    let r = chat.call("turtle_teleport", json!({"x": 1.0, "y": 5.5}));
    assert_eq!(r["ok"], true, "{r}");
    until(poses, "teleported home", |p| {
        (p.x - 1.0).abs() < 1e-3 && p.theta.abs() < 1e-3
    });
    chat.send(&format!(
        "/call turtle_move {}",
        json!({"distance": 5.0, "speed": 0.5})
    ));
    until(poses, "driving", |p| p.x > 1.15);
}

/// After a trigger: the running call was aborted, motion is refused while latched, and
/// the operator's `/reset` releases it.
fn refused_until_reset(chat: &mut Chat) {
    let aborted = chat.report(Duration::from_secs(10));
    assert_eq!(
        aborted["ok"], false,
        "the running call was aborted: {aborted}"
    );
    refused_until_reset_after_report(chat);
}

/// `refused_until_reset` once the aborted call's report is read.
fn refused_until_reset_after_report(chat: &mut Chat) {
    let refused = chat.call("turtle_move", json!({"distance": 1.0}));
    assert_eq!(refused["ok"], false, "{refused}");
    assert!(
        refused.to_string().to_lowercase().contains("e-stop"),
        "{refused}"
    );
    chat.send("/reset");
    chat.wait_for("e-stop released", Duration::from_secs(5));
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn e_stop_and_override_on_the_wire() {
    if rerun_in_loopback_netns("estop::e_stop_and_override_on_the_wire", 200) {
        return;
    }
    let rt = runtime();
    let observer =
        Arc::new(Ros2Graph::start(&Ros2Options::default(), "_ferrosa_observer").unwrap());
    let mut chat = Chat::start();
    let poses: Poses = Arc::new(Mutex::new(Vec::new()));
    {
        let (observer, poses) = (observer.clone(), poses.clone());
        rt.spawn(async move {
            let mut rx = observer
                .watch("/turtle1/pose", "turtlesim/msg/Pose")
                .await
                .unwrap();
            while let Some(p) = rx.recv().await {
                let f = |k: &str| p[k].as_f64().unwrap_or(f64::NAN);
                poses.lock().unwrap().push(Sample {
                    at: now(),
                    x: f("x"),
                    y: f("y"),
                    theta: f("theta"),
                });
            }
        });
    }
    until(&poses, "the sim's pose", |_| true);
    let mut figures = Vec::new();

    // 1. `/stop` typed while a move runs.
    start_drive(&mut chat, &poses);
    let t0 = now();
    chat.send("/stop");
    let ms = stop_latency(&chat, &poses, t0, Duration::from_millis(1200)) * 1e3;
    figures.push(("REPL /stop", ms));
    let aborted = chat.report(Duration::from_secs(10));
    assert_eq!(
        aborted["ok"], false,
        "the running move was aborted: {aborted}"
    );
    // Latched: actuation is refused, observing still works, until reset.
    let still = last(&poses);
    let refused = chat.call("turtle_move", json!({"distance": 1.0}));
    assert_eq!(refused["ok"], false, "{refused}");
    assert!(
        refused.to_string().to_lowercase().contains("e-stop"),
        "{refused}"
    );
    let teleport = chat.call("turtle_teleport", json!({"x": 8.0, "y": 8.0}));
    assert_eq!(teleport["ok"], false, "{teleport}");
    let pose = chat.call("turtle_pose", json!({}));
    assert_eq!(pose["ok"], true, "{pose}");
    std::thread::sleep(Duration::from_millis(300));
    assert!(
        !last(&poses).differs(&still),
        "the turtle moved while the e-stop was engaged"
    );
    chat.send("/reset");
    chat.wait_for("e-stop released", Duration::from_secs(5));

    // 2. Ctrl-C while a move runs.
    start_drive(&mut chat, &poses);
    let t0 = now();
    chat.interrupt();
    let ms = stop_latency(&chat, &poses, t0, Duration::from_millis(1200)) * 1e3;
    figures.push(("Ctrl-C", ms));
    refused_until_reset(&mut chat);

    // 3. An rclpy node presses the ROS e-stop.
    start_drive(&mut chat, &poses);
    let out = Command::new("timeout")
        .arg("40")
        .arg(crate::ros::rclpy_python())
        .arg(crate::ros::peer_script())
        .arg("estop")
        .output()
        .expect("running the rclpy e-stop button");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "rclpy estop: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    let pressed: Value = serde_json::from_str(stdout.lines().last().unwrap_or("")).unwrap();
    assert!(pressed["subscribers"].as_u64().unwrap() >= 1, "{pressed}");
    let t0 = pressed["published_at"].as_f64().unwrap();
    let ms = stop_latency(&chat, &poses, t0, Duration::from_millis(1200)) * 1e3;
    figures.push(("rclpy /ferrosa/estop", ms));
    refused_until_reset(&mut chat);

    // 4. A running action goal is cancelled: the turtle stops turning and stays still
    // (the goal, left running, would turn it on).
    let r = chat.call(
        "turtle_teleport",
        json!({"x": 5.0, "y": 5.0, "theta_deg": 0.0}),
    );
    assert_eq!(r["ok"], true, "{r}");
    until(&poses, "teleported", |p| {
        (p.x - 5.0).abs() < 1e-3 && p.theta.abs() < 1e-3
    });
    chat.send(&format!(
        "/call ros_action_send_goal {}",
        json!({"action": "/turtle1/rotate_absolute", "goal": {"theta": 3.0}, "wait_s": 20})
    ));
    until(&poses, "rotating", |p| p.theta > 0.3);
    let t0 = now();
    chat.send("/stop");
    let ms = stop_latency(&chat, &poses, t0, Duration::from_millis(2000)) * 1e3;
    figures.push(("action goal, REPL /stop", ms));
    assert!(
        last(&poses).theta < 2.5,
        "the goal ran on: {:?}",
        last(&poses)
    );
    let aborted = chat.report(Duration::from_secs(10));
    assert_eq!(aborted["ok"], false, "{aborted}");
    chat.send("/reset");
    chat.wait_for("e-stop released", Duration::from_secs(5));

    // 4b. "stop", typed in words while the robot drives to a named place: the drive's
    // navigation goal is cancelled and the turtle stays where it stopped.
    let from = last(&poses);
    chat.send(&format!("/call place_go {}", json!({"place": "pond"})));
    until(&poses, "driving to the pond", |p| {
        (p.x - from.x).hypot(p.y - from.y) > 0.2
    });
    let t0 = now();
    chat.send("stop");
    let ms = stop_latency(&chat, &poses, t0, Duration::from_millis(2000)) * 1e3;
    figures.push(("place_go drive, typed stop", ms));
    // Aborted, saying where the drive had got to.
    let aborted = chat.report(Duration::from_secs(10));
    assert_eq!(aborted["ok"], false, "the drive was aborted: {aborted}");
    assert!(
        aborted["output"]
            .to_string()
            .contains("it had last reported: to pond (at "),
        "{aborted}"
    );
    // The typed line is then a request of its own: the agent says it stopped.
    chat.wait_for_line("Stopped", Duration::from_secs(30));
    refused_until_reset_after_report(&mut chat);

    // 5. The operator's teleop overrides a running turtle_move: while it publishes on
    // /turtle1/cmd_vel (turning in place), the agent's drive is dropped and the tool
    // says so.
    start_drive(&mut chat, &poses);
    let before = last(&poses);
    rt.block_on(async {
        for _ in 0..20 {
            observer
                .publish(
                    "/turtle1/cmd_vel",
                    "geometry_msgs/msg/Twist",
                    json!({"angular": {"z": 1.0}}),
                )
                .await
                .unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    });
    let moved = chat.report(Duration::from_secs(15));
    assert_eq!(moved["ok"], true, "{moved}");
    assert!(
        moved["output"]["overridden"].is_string(),
        "the tool reports the override: {moved}\n{}",
        chat.log()
    );
    let requested = moved["output"]["requested_m"].as_f64().unwrap();
    let driven = moved["output"]["moved_m"].as_f64().unwrap();
    assert!(driven < requested - 1.0, "the drive ended early: {moved}");
    std::thread::sleep(Duration::from_millis(1200));
    let after = last(&poses);
    assert!(
        after.theta - before.theta > 0.5,
        "teleop turned the turtle: {before:?} → {after:?}"
    );
    assert!(
        after.x - before.x < 0.5,
        "the agent's drive went on under teleop: {before:?} → {after:?}"
    );

    for (what, ms) in &figures {
        eprintln!("e-stop {what}: the pose stopped changing {ms:.0} ms after the trigger");
    }
    for (what, ms) in &figures {
        assert!(
            *ms < 100.0,
            "{what}: {ms:.0} ms (the bound is 100 ms)\n{}",
            chat.log()
        );
    }
}
