//! A 1,000-turn soak of the agent against the sim with faults injected.
//!
//! The real agent (template, grammar, decode loop, guards, policy, executor) with the
//! scripted model over the synthetic vocabulary, the stack `ferrosa chat --robot sim`
//! builds (`ui::agent::connect` and `tools_and_policy`: the sim and the agent's
//! participant over real DDS, the guarded graph, every tool, the e-stop following
//! `/ferrosa/estop`), in a loopback-only network namespace. Foreign rclpy nodes
//! (`peers/soak_peer.py`, run by `support::faults`) inject the faults from outside: a
//! server killed in the middle of a call (and started again), a service that never
//! answers, and a node flooding a topic and the e-stop topic itself.
//!
//! A thousand requests cycle through listings, echoes, parameter gets and sets, service
//! calls, motion (approved, refused by the operator, refused by a limit, refused while
//! the e-stop is latched), calls with bad arguments, names behind the fence and the
//! typed stop. Each must end with an answer, every call that did not run well carrying
//! its reason; VmRSS and the thread count (`/proc/self/status`) are printed every 100
//! turns and must stay flat; at the end a foreign node presses the e-stop during a move
//! and the sim's turtle must stand still with motion refused. Figures are printed, never
//! asserted as times.

use std::io::Write;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use ferrosa::agent::{Agent, AgentConfig, Finish, RunResult, StepRecord, ANSWER_TOOL};
use ferrosa::decode::envelope::Envelope;
use ferrosa::estop::EStop;
use ferrosa::ros::RosGraph;
use ferrosa::tool::{Confirm, Decision, ToolCall};
use ferrosa::ui::agent::{connect, tools_and_policy, AgentArgs, Robot};
use serde_json::{json, Value};

use crate::support::faults::{Crashing, Peer};
use crate::support::scripted::Scripted;
use crate::util::rerun_in_loopback_netns;

const TURNS: usize = 1000;

/// The policy the soak runs under: a service and a parameter fenced off, a short time
/// limit (what bounds a call to a server that hangs or died), and a limit on how far one
/// move may go.
const POLICY: &str = r#"
deny = ["^/soak_peer/secret", "^/turtlesim/background_g$"]
timeout_s = 1.5
[[limit]]
tool = "^turtle_move$"
paths = ["/distance"]
min = -2.0
max = 2.0
"#;

/// The ways the operator types stop, one per cycle (the issue's list among them): each
/// must engage the e-stop without the model.
const STOPS: [&str; 10] = [
    "stop the turtle",
    "hold on",
    "don't move",
    "stand still",
    "hey robot, kill the motors",
    "abort",
    "cancel that",
    "no te muevas",
    "arrête la tortue",
    "fermati",
];

/// Messages a second the flooding node publishes on each of its two topics.
const FLOOD_HZ: &str = "1000";

// ---------------------------------------------------------------------------------------
// The operator, the stack, the model's script.

/// The operator at the terminal: approves an actuating call when told to for this turn.
#[derive(Default)]
struct Operator {
    approves: AtomicBool,
    asked: AtomicUsize,
}

impl Confirm for Operator {
    fn confirm(&self, _: &ToolCall) -> bool {
        self.asked.fetch_add(1, Ordering::SeqCst);
        self.approves.load(Ordering::SeqCst)
    }
}

fn call(name: &str, args: Value) -> String {
    Envelope::Smollm2.render_calls(&[ToolCall {
        name: name.into(),
        arguments: args,
    }])
}

fn answer(text: &str) -> String {
    call(ANSWER_TOOL, json!({"text": text}))
}

/// What a turn must come to, beyond an answer with a reason for every call that did
/// not run well.
#[derive(Clone, Copy, Debug)]
enum Expect {
    /// The call ran and succeeded.
    Ran,
    /// The policy refused the call, saying this.
    Refused(&'static str),
    /// The call ran and failed, saying this.
    Failed(&'static str),
    /// The call did not succeed (a fault whose form depends on timing).
    NotOk,
    /// Anything with a reason (a peer that may be down or starting again).
    Any,
    /// The typed stop: no model call (the stop act's record only), the e-stop engaged.
    Stopped,
}

/// One kind of request: what the operator says, what the model writes, what the
/// operator answers when asked, what must come of it, and how many of every 100 turns
/// ask it.
struct Kind {
    name: &'static str,
    request: &'static str,
    /// The model's call (its answer follows); none for the typed stop.
    call: Option<(&'static str, Value)>,
    approves: bool,
    expect: Expect,
    per_100: usize,
}

/// Every kind of request. Most are quick reads, as an operator's are; motion, the
/// faults and the slow reads (the flood's rate, the status report) come a few times in
/// every hundred turns, so a thousand turns stay within a few minutes on two cores.
#[rustfmt::skip]
fn kinds() -> Vec<Kind> {
    use Expect::*;
    let k = |per_100, name, request, tool, args: Value, expect| Kind {
        name, request, call: Some((tool, args)), approves: true, expect, per_100,
    };
    let step = |d: f64| json!({"distance": d, "speed": 1.0});
    vec![
        // Listings and reads, of the sim and of the flooded topic.
        k(6, "nodes", "list the ROS nodes", "ros_node_list", json!({}), Ran),
        k(6, "topics", "list the ROS topics", "ros_topic_list", json!({}), Ran),
        k(6, "services", "list the ROS services", "ros_service_list", json!({}), Ran),
        k(6, "echo pose", "echo /turtle1/pose", "ros_topic_echo",
          json!({"topic": "/turtle1/pose"}), Ran),
        k(6, "echo flood", "echo 5 messages of /soak/flood", "ros_topic_echo",
          json!({"topic": "/soak/flood", "count": 5}), Ran),
        k(5, "pose", "where is the turtle?", "turtle_pose", json!({}), Ran),
        k(5, "calc", "what is 6 times 7", "calc_eval", json!({"expression": "6 * 7"}), Ran),
        // Parameters and services, of the sim and of the peer that is killed now and
        // then (its calls may fail while it is down: any outcome with a reason).
        k(4, "param get", "get the background_r parameter of /turtlesim", "ros_param_get",
          json!({"node": "/turtlesim", "name": "background_r"}), Ran),
        k(3, "param set", "set the background_r parameter of /turtlesim to 100", "ros_param_set",
          json!({"node": "/turtlesim", "name": "background_r", "value": 100}), Ran),
        k(3, "clear", "call the /clear service", "ros_service_call",
          json!({"service": "/clear"}), Ran),
        k(3, "peer param", "get the gain parameter of /soak_peer", "ros_param_get",
          json!({"node": "/soak_peer", "name": "gain"}), Any),
        k(3, "peer call", "call the /soak_peer/trigger service", "ros_service_call",
          json!({"service": "/soak_peer/trigger"}), Any),
        // Motion, approved; and refused by the operator and by a limit.
        k(2, "move", "move the turtle forward 0.1 meters at speed 1", "turtle_move",
          step(0.1), Ran),
        k(2, "move back", "move the turtle backward 0.1 meters at speed 1", "turtle_move",
          step(-0.1), Ran),
        k(1, "teleport", "teleport the turtle to x 5.5 y 5.5", "turtle_teleport",
          json!({"x": 5.5, "y": 5.5}), Ran),
        Kind { approves: false, ..k(4, "rotate refused", "rotate the turtle 90 degrees",
          "turtle_rotate", json!({"degrees": 90}), Refused("did not approve")) },
        k(4, "move too far", "move the turtle forward 4 meters", "turtle_move",
          json!({"distance": 4}), Refused("limit")),
        // Bad arguments: a broken expression, names the robot lacks, a wrong type, a
        // name behind the fence.
        k(5, "bad expression", "what is 2 +", "calc_eval", json!({"expression": "2 +"}),
          Failed("")),
        k(5, "no topic", "echo /nope", "ros_topic_echo", json!({"topic": "/nope"}),
          Failed("no topic")),
        k(3, "no node", "get the speed parameter of /nope_node", "ros_param_get",
          json!({"node": "/nope_node", "name": "speed"}), Failed("")),
        k(3, "wrong type", "set the background_r parameter of /turtlesim to blue",
          "ros_param_set", json!({"node": "/turtlesim", "name": "background_r", "value": "blue"}),
          Failed("")),
        k(4, "no service", "call the /nope service", "ros_service_call",
          json!({"service": "/nope"}), Failed("no service")),
        k(3, "fenced service", "call the /soak_peer/secret service", "ros_service_call",
          json!({"service": "/soak_peer/secret"}), Refused("off limits")),
        k(2, "fenced param", "set the background_g parameter of /turtlesim to 10",
          "ros_param_set", json!({"node": "/turtlesim", "name": "background_g", "value": 10}),
          Refused("off limits")),
        // The faults: the peer is killed once the call reached it; a server that never
        // answers. Both end at the policy's time limit.
        k(1, "peer killed mid-call", "call the /soak_peer/slow service", "ros_service_call",
          json!({"service": "/soak_peer/slow"}), NotOk),
        k(1, "hanging service", "call the /soak_hang/trigger service", "ros_service_call",
          json!({"service": "/soak_hang/trigger"}), Failed("")),
        // Slow reads.
        k(1, "flood rate", "measure the rate of /soak/flood over 0.5 seconds", "ros_topic_hz",
          json!({"topic": "/soak/flood", "window_s": 0.5}), Ran),
        k(1, "status", "give me a status report", "robot_status", json!({}), Ran),
        // The typed stop (in the words of `STOPS`, a different way each cycle), then a
        // move refused while it is latched (`cycle` keeps them together; the operator
        // resets after the refusal).
        Kind { name: "stop", request: "stop the turtle", call: None, approves: false,
               expect: Stopped, per_100: 1 },
        k(1, "move while stopped", "move the turtle forward 0.1 meters at speed 1",
          "turtle_move", step(0.1), Refused("e-stop")),
    ]
}

/// One cycle of 100 turns: each kind as often as it says, spread evenly.
fn cycle() -> Vec<Kind> {
    let mut placed: Vec<(f64, usize, Kind)> = Vec::new();
    for (i, k) in kinds().into_iter().enumerate() {
        let n = k.per_100;
        for j in 0..n {
            let at = (j as f64 + 0.5) * 100.0 / n as f64;
            placed.push((
                at,
                i,
                Kind {
                    call: k.call.clone(),
                    ..k
                },
            ));
        }
    }
    placed.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut out: Vec<Kind> = placed.into_iter().map(|(_, _, k)| k).collect();
    assert_eq!(out.len(), 100, "the kinds' shares add up to 100");
    // The refused move right after the stop.
    let refused = out
        .iter()
        .position(|k| k.name == "move while stopped")
        .expect("the refused move");
    let moved = out.remove(refused);
    let stop = out.iter().position(|k| k.name == "stop").expect("the stop");
    out.insert(stop + 1, moved);
    out
}

// ---------------------------------------------------------------------------------------
// Measuring and judging.

/// VmRSS (KiB) and the thread count of this process.
fn vitals() -> (u64, u64) {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |key: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(key))
            .and_then(|v| v.split_whitespace().next()?.parse().ok())
            .unwrap_or(0)
    };
    (field("VmRSS:"), field("Threads:"))
}

/// Why a call did not run well: the policy's reason, or the tool's error.
fn reason(s: &StepRecord) -> String {
    match &s.decision {
        Decision::Refused(why) => why.clone(),
        _ => s.output["error"].as_str().unwrap_or_default().to_string(),
    }
}

/// How a turn ended, for the tally.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Debug)]
enum Came {
    Ran,
    Refused,
    Failed,
    Stopped,
}

/// Judge one turn: an answer, a reason for every call that did not run well, and what
/// the kind expects.
fn judge(k: &Kind, r: &RunResult, estop: &EStop) -> Result<Came, String> {
    if r.finish != Finish::Answer || r.answer.trim().is_empty() {
        return Err(format!("no answer: {:?} {:?}", r.finish, r.answer));
    }
    if let Some(s) = r
        .steps
        .iter()
        .find(|s| !s.ok && reason(s).trim().is_empty())
    {
        return Err(format!(
            "{} did not run well and says no reason: {:?} {}",
            s.name, s.decision, s.output
        ));
    }
    let first = match (&k.call, r.steps.first()) {
        (None, None) => None,
        // The typed stop's record: the stop act, taken without the model.
        (None, Some(s)) if s.name == "robot_stop" && s.ok && r.steps.len() == 1 => None,
        (Some((tool, _)), Some(s)) if s.name == *tool && r.steps.len() == 1 => Some(s),
        _ => {
            return Err(format!(
                "calls made: {:?}",
                r.steps.iter().map(|s| &s.name).collect::<Vec<_>>()
            ))
        }
    };
    let refused = |s: &StepRecord| matches!(s.decision, Decision::Refused(_));
    let has = |s: &StepRecord, what: &str| reason(s).to_lowercase().contains(what);
    let came = match first {
        None => Came::Stopped,
        Some(s) if s.ok => Came::Ran,
        Some(s) if refused(s) => Came::Refused,
        Some(_) => Came::Failed,
    };
    let fits = match (k.expect, first) {
        (Expect::Ran, _) => came == Came::Ran,
        (Expect::Refused(w), Some(s)) => came == Came::Refused && has(s, w),
        (Expect::Failed(w), Some(s)) => came == Came::Failed && has(s, w),
        (Expect::NotOk, _) => came != Came::Ran,
        (Expect::Any, _) => true,
        (Expect::Stopped, _) => came == Came::Stopped && estop.is_engaged(),
        _ => false,
    };
    if fits {
        Ok(came)
    } else {
        Err(format!(
            "expected {:?}, came {came:?}: {:?}",
            k.expect,
            first.map(|s| (&s.decision, &s.output))
        ))
    }
}

/// The soak's script: the model's two replies (the call, the answer) for each of the
/// `turns` requests of `cycle`, then for the move the e-stop interrupts and the one
/// refused after it.
fn script(cycle: &[Kind], turns: usize) -> Vec<String> {
    (0..turns)
        .flat_map(|i| {
            let k = &cycle[i % cycle.len()];
            k.call
                .iter()
                .flat_map(|(tool, a)| {
                    [call(tool, a.clone()), answer(&format!("Done: {}.", k.name))]
                })
                .collect::<Vec<_>>()
        })
        .chain([
            // The e-stop is pressed during this move: its run ends there, with no
            // reply of the model's.
            call("turtle_move", json!({"distance": 2.0, "speed": 1.0})),
            call("turtle_move", json!({"distance": 0.2, "speed": 1.0})),
            answer("Done: the move after the e-stop."),
        ])
        .collect()
}

/// The agent `ferrosa chat --robot sim` builds (`ui::agent::build_with`), with the
/// scripted model for the real one: the tools and the policy over the raw `graph`
/// (guarded there, the e-stop following `/ferrosa/estop`), the robot's names for the
/// grammar, the fence set on the graph.
fn agent(
    graph: &Arc<dyn RosGraph>,
    operator: Arc<Operator>,
    estop: Arc<EStop>,
    policy: &std::path::Path,
    script: &[String],
) -> Agent {
    let mut args: AgentArgs = crate::util::agent_args(Robot::Sim, false);
    args.policy = Some(policy.to_path_buf());
    let (registry, policy, prompt) = tools_and_policy(&args, operator, Some(graph.clone()), estop)
        .expect("the tools and the policy");
    let replies: Vec<&str> = script.iter().map(String::as_str).collect();
    let backend = Scripted::synthetic(&replies).with_context(1 << 17);
    let mut config = AgentConfig::for_family("smollm2");
    config.max_steps = args.max_steps;
    // Tools are chosen per request as for the real model: SmolLM2's budget of 1,500
    // tokens in the synthetic vocabulary's (about four of its tokens to one of
    // SmolLM2's). Every scripted call is among the tools chosen for its request.
    config.tool_budget_tokens = 6000;
    // The scripted replies are the model's choices, taken as written.
    config.pick = ferrosa::agent::config::Pick::Likeliest;
    // The script gives every turn its answer.
    config.composed_answers = false;
    let fence = policy.fence().clone();
    graph.set_fence(fence.clone());
    Agent::new(Box::new(backend), registry, policy, prompt.render(), config)
        .expect("the agent")
        .with_names(ferrosa::ui::agent::robot_names(graph.clone(), fence))
}

/// Wait until the agent's participant sees every peer's endpoints.
fn discovered(graph: &Arc<dyn RosGraph>) {
    let start = Instant::now();
    loop {
        let g = ferrosa::ros::graph_now(graph.as_ref()).unwrap_or_default();
        let services = g.services();
        let wanted = [
            "/soak_peer/trigger",
            "/soak_peer/slow",
            "/soak_hang/trigger",
        ];
        if wanted.iter().all(|s| services.contains_key(*s))
            && g.topics().contains_key("/soak/flood")
        {
            return;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the peers were not discovered: {:?} {:?}",
            g.nodes,
            services.keys().collect::<Vec<_>>()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// What the turns came to.
#[derive(Default)]
struct Soak {
    /// (turn, VmRSS KiB, threads, seconds since the first turn), after turn 1 and every
    /// 100th.
    samples: Vec<(usize, u64, u64, f64)>,
    tally: std::collections::BTreeMap<(&'static str, Came), usize>,
    /// Per kind: turns, seconds in all, the longest.
    times: std::collections::BTreeMap<&'static str, (usize, f64, f64)>,
    wrong: Vec<String>,
    /// What `ros_topic_hz` measured on the flooded topic.
    rates: Vec<f64>,
    seconds: f64,
}

/// Ask the `turns` requests of `cycle`, judging and timing each, sampling VmRSS and
/// threads.
fn soak(
    agent: &mut Agent,
    operator: &Operator,
    estop: &EStop,
    cycle: &[Kind],
    turns: usize,
) -> Soak {
    let mut out = Soak::default();
    let start = Instant::now();
    for i in 0..turns {
        let k = &cycle[i % cycle.len()];
        operator.approves.store(k.approves, Ordering::SeqCst);
        let t = Instant::now();
        let request = match k.expect {
            Expect::Stopped => STOPS[i / cycle.len() % STOPS.len()],
            _ => k.request,
        };
        // An error here is the model leaving its script (or a broken runtime): the
        // turns after it would be off script too.
        let r = agent
            .ask(request, &mut |_| {})
            .unwrap_or_else(|e| panic!("turn {} ({}): the agent failed: {e}", i + 1, k.name));
        let took = t.elapsed().as_secs_f64();
        let time = out.times.entry(k.name).or_insert((0, 0.0, 0.0));
        *time = (time.0 + 1, time.1 + took, time.2.max(took));
        match judge(k, &r, estop) {
            Ok(came) => *out.tally.entry((k.name, came)).or_default() += 1,
            Err(why) => out
                .wrong
                .push(format!("turn {} ({}, {request:?}): {why}", i + 1, k.name)),
        }
        if k.name == "flood rate" {
            out.rates
                .extend(r.steps.iter().filter_map(|s| s.output["rate_hz"].as_f64()));
        }
        // The operator resets the e-stop once the move after the stop was refused;
        // nothing else may have engaged it (the flood publishes `false` on its topic).
        if k.name == "move while stopped" {
            estop.reset();
        } else if let (Some(e), false) = (estop.engaged_by(), matches!(k.expect, Expect::Stopped)) {
            out.wrong.push(format!(
                "turn {} ({}): the e-stop was engaged by {}",
                i + 1,
                k.name,
                e.source
            ));
            estop.reset();
        }
        if i == 0 || (i + 1) % 100 == 0 {
            let (rss, threads) = vitals();
            out.samples
                .push((i + 1, rss, threads, start.elapsed().as_secs_f64()));
        }
    }
    out.seconds = start.elapsed().as_secs_f64();
    out
}

/// What came of pressing the e-stop during a move.
struct Pressed {
    /// The press as the button reported it.
    button: String,
    /// The run of the move.
    moved: RunResult,
    /// Who engaged the e-stop.
    source: String,
    /// The turtle's x when it was first seen moving, when the button was told to press,
    /// 0.5 s after the move's run ended, 0.5 s later, and after a move was asked again.
    x: [f64; 5],
    /// From telling the button to press to the pose's last change.
    brake_ms: f64,
    /// The turtle's speed when the button was told to press.
    speed: f64,
    /// Linear and angular velocity 0.5 s after the move's run ended.
    velocity: (f64, f64),
    /// The move asked for after the e-stop.
    after: RunResult,
}

/// The e-stop at the end: a foreign node presses it through the flooded topic while
/// the agent moves the turtle; then motion is asked for again.
fn press_during_move(
    agent: &mut Agent,
    operator: &Operator,
    estop: &EStop,
    sim: &ferrosa::ros::sim::Sim,
) -> Pressed {
    operator.approves.store(true, Ordering::SeqCst);
    let home = agent.call(&ToolCall {
        name: "turtle_teleport".into(),
        arguments: json!({"x": 2.0, "y": 5.5, "theta_deg": 0.0}),
    });
    assert!(home.ok, "teleport home: {:?}", home.output);
    let mut button = Peer::start(&["press"]);
    let pose = |k: &str| {
        sim.pose("turtle1")
            .and_then(|p| p[k].as_f64())
            .unwrap_or(f64::NAN)
    };
    // The pose (x, speed) from the moment the turtle moves, every 2 ms until the run
    // ends; the button is told to press 200 ms into the move.
    let mut track: Vec<(Instant, f64, f64)> = Vec::new();
    let (moved, pressed_at) = std::thread::scope(|s| {
        let run = s.spawn(|| agent.ask("move the turtle forward 2 meters at speed 1", &mut |_| {}));
        let t = Instant::now();
        while pose("linear_velocity") <= 0.0 && t.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(2));
        }
        let mut pressed_at = None;
        while !run.is_finished() {
            track.push((Instant::now(), pose("x"), pose("linear_velocity")));
            if pressed_at.is_none() && track[0].0.elapsed() > Duration::from_millis(200) {
                let stdin = button.stdin.as_mut().expect("the button's stdin");
                writeln!(stdin, "go").expect("telling the button to press");
                pressed_at = Some(track.len() - 1);
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        (run.join().expect("the move's thread"), pressed_at)
    });
    let pressed = pressed_at.expect("the move ran 200 ms, and the button was told to press");
    let (pressed_at, at_press, speed) = track[pressed];
    // When the pose last changed, from the press (negative: before it): within one sim
    // step (16 ms) and one sample (2 ms) of when the brake took. A figure, not a bound.
    let brake_ms = track
        .windows(2)
        .rev()
        .find(|w| w[1].1 != w[0].1)
        .map_or(f64::NAN, |w| {
            let t = w[1].0;
            let (late, early) = (
                t.saturating_duration_since(pressed_at),
                pressed_at.saturating_duration_since(t),
            );
            (late.as_secs_f64() - early.as_secs_f64()) * 1e3
        });
    let first = track.first().map_or(f64::NAN, |p| p.1);
    let moved = moved.expect("the move's run");
    let pressed = button.out.next().and_then(Result::ok).unwrap_or_default();
    std::thread::sleep(Duration::from_millis(500));
    let (x, velocity) = (
        pose("x"),
        (pose("linear_velocity"), pose("angular_velocity")),
    );
    std::thread::sleep(Duration::from_millis(500));
    let still = pose("x");
    let source = estop.engaged_by().map(|e| e.source).unwrap_or_default();
    let after = agent
        .ask("move the turtle forward 0.2 meters at speed 1", &mut |_| {})
        .expect("a run after the e-stop");
    std::thread::sleep(Duration::from_millis(300));
    Pressed {
        button: pressed,
        moved,
        source,
        x: [first, at_press, x, still, pose("x")],
        brake_ms,
        speed,
        velocity,
        after,
    }
}

/// Print the figures: the VmRSS and thread table, time per kind, outcomes.
fn report(s: &Soak, kills: usize, asked: usize, p: &Pressed) {
    let turns = s.samples.last().map_or(0, |l| l.0);
    eprintln!(
        "\nsoak: {turns} turns in {:.1} s ({:.0} ms a turn); {kills} peer kills mid-call; the operator asked {asked} times; the flood measured at {:?} Hz",
        s.seconds,
        s.seconds * 1e3 / turns.max(1) as f64,
        s.rates
    );
    eprintln!(
        "{:>6} {:>11} {:>8} {:>9}",
        "turn", "VmRSS KiB", "threads", "seconds"
    );
    for (turn, rss, threads, at) in &s.samples {
        eprintln!("{turn:>6} {rss:>11} {threads:>8} {at:>9.1}");
    }
    for (name, (n, total, most)) in &s.times {
        eprintln!(
            "soak: {name:>22}: {n:>3} turns, {:>5.0} ms mean, {:>5.0} ms at most",
            total * 1e3 / *n as f64,
            most * 1e3
        );
    }
    for ((name, came), n) in &s.tally {
        eprintln!("soak: {n:>4} × {name}: {came:?}");
    }
    eprintln!(
        "soak: e-stop by {:?} ({}): x {:.4} moving, {:.4} at the press (speed {} m/s), {:.4} and {:.4} after, {:.4} after a move was asked; the pose last changed {:.0} ms after the button was told to press (a sim step is 16 ms); velocity {:?}; the move: {:?}",
        p.source,
        p.button,
        p.x[0], p.x[1], p.speed, p.x[2], p.x[3], p.x[4],
        p.brake_ms,
        p.velocity,
        p.moved.steps.iter().map(|s| (&s.name, s.ok, &s.output)).collect::<Vec<_>>()
    );
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn a_thousand_turns_with_faults_stay_flat_and_the_e_stop_still_works() {
    if rerun_in_loopback_netns(
        "soak::a_thousand_turns_with_faults_stay_flat_and_the_e_stop_still_works",
        420,
    ) {
        return;
    }
    // The robot and the agent's participant, as `ferrosa chat --robot sim` joins them,
    // and the faults.
    let link = connect(Robot::Sim, false).expect("the sim on ROS 2");
    let graph = link.graph.clone().expect("a graph");
    let sim = link.sim.as_ref().expect("the sim");
    let _flood = Peer::start(&["flood", FLOOD_HZ]);
    let _hang = Peer::start(&["hang"]);
    let mut crashing = Crashing::start();
    discovered(&graph);

    let mut policy = tempfile::NamedTempFile::new().expect("a temporary file");
    policy
        .write_all(POLICY.as_bytes())
        .expect("the policy file");
    let operator = Arc::new(Operator::default());
    let estop = EStop::new();
    let cycle = cycle();
    let script = script(&cycle, TURNS);
    let mut agent = agent(
        &graph,
        operator.clone(),
        estop.clone(),
        policy.path(),
        &script,
    );

    let s = soak(&mut agent, &operator, &estop, &cycle, TURNS);
    estop.reset();
    let p = press_during_move(&mut agent, &operator, &estop, sim);
    let kills = crashing.end();
    report(&s, kills, operator.asked.load(Ordering::SeqCst), &p);

    // Every turn an answer, every call that did not run well with its reason, each
    // kind as it must come.
    assert!(
        s.wrong.is_empty(),
        "{} turns wrong:\n{}",
        s.wrong.len(),
        s.wrong.join("\n")
    );
    // Memory: after the warm-up (caches filled, every peer discovered, the history at
    // its budget), 900 turns may add 8 MiB at most: a leak of 10 KiB a turn (a prompt's
    // text, a tool's result) would add 9 MiB.
    let (warm, end) = (s.samples[1], s.samples[s.samples.len() - 1]);
    assert_eq!((warm.0, end.0), (100, TURNS));
    assert!(
        end.1 < warm.1 + 8 * 1024,
        "VmRSS grew from {} KiB at turn 100 to {} KiB",
        warm.1,
        end.1
    );
    // Threads: the same pools at the end as after the warm-up, give or take the
    // short-lived ones (a parameter-name fetch, tokio's blocking threads).
    assert!(
        end.2 <= warm.2 + 4,
        "threads grew from {} at turn 100 to {}",
        warm.2,
        end.2
    );
    // The faults happened: the peer is up again long before the next call to its slow
    // service, so nearly every such call kills it; the flood was measured.
    let slow = s
        .tally
        .iter()
        .filter(|((n, _), _)| *n == "peer killed mid-call")
        .map(|(_, n)| n)
        .sum::<usize>();
    assert!(
        kills > 0 && kills * 2 >= slow,
        "the peer was killed mid-call {kills} times in {slow} calls"
    );
    assert!(
        s.rates.iter().any(|r| *r > 100.0),
        "the flood: {:?} Hz",
        s.rates
    );
    // The e-stop: pressed by the foreign node, the running move aborted, the turtle
    // braked and still, motion refused afterwards.
    assert!(
        p.button.starts_with("pressed"),
        "the button: {:?}",
        p.button
    );
    assert!(
        p.source.contains("/ferrosa/estop"),
        "engaged by {:?}",
        p.source
    );
    let step = p.moved.steps.first().expect("the move was called");
    assert!(
        !step.ok && reason(step).contains("e-stop"),
        "the move was not aborted: {:?}",
        step.output
    );
    assert!(
        p.moved.answer.contains("e-stop was engaged") && p.moved.steps.len() == 1,
        "the move's run went on after the e-stop: {:?}",
        p.moved.answer
    );
    assert_eq!(p.velocity, (0.0, 0.0), "the turtle still moves");
    assert!(
        p.speed > 0.0 && p.x[1] > p.x[0] + 0.05,
        "the turtle was not moving when the e-stop was pressed: {} m/s, {:?}",
        p.speed,
        p.x
    );
    assert!(
        p.x[3..].iter().all(|x| (x - p.x[2]).abs() < 1e-9),
        "the turtle moved after the e-stop: {:?}",
        p.x
    );
    let refused = p
        .after
        .steps
        .first()
        .expect("the move after the e-stop was called");
    assert!(
        matches!(&refused.decision, Decision::Refused(w) if w.contains("e-stop")),
        "motion after the e-stop: {:?}",
        refused.decision
    );
}
