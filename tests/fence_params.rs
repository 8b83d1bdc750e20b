//! Issue 41, the fence's holes: the deny-list covers node parameters (`/node/parameter`)
//! in listings, gets, sets and descriptions, and a name split by a format character
//! (zero-width, bidi, soft hyphen) is the name it shows. Driven through the real call
//! path (`tool::exec` over the stack the front ends build, `ui::agent::robot_tools`)
//! against the built-in sim on ROS 2, through the `ferrosa` binary against `ferrosa sim`,
//! and, as a property, through the same path over an in-memory robot whose names are
//! spelt every hidden way.

use std::io::Write;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

use ferrosa::estop::EStop;
use ferrosa::ros::fake::FakeGraph;
use ferrosa::ros::graph::{Durability, Graph, Qos, Reliability, ServiceEndpoint, TopicEndpoint};
use ferrosa::ros::RosGraph;
use ferrosa::tool::exec::{Executor, Outcome};
use ferrosa::tool::policy::NoOperator;
use ferrosa::tool::{Decision, ToolCall};
use ferrosa::ui::agent::{robot_tools, tools_and_policy, Robot};
use ferrosa::ui::term::clean;
use proptest::prelude::*;
use serde_json::{json, Value};

use crate::util::{agent_args, rerun_in_loopback_netns, runtime};

/// The deny-list of the sim cases: one parameter, and the first turtle.
const DENY: &str = r#"deny = ["^/turtlesim/background_r$", "^/turtle1"]"#;

fn policy_file(text: &str) -> tempfile::NamedTempFile {
    let mut f = tempfile::NamedTempFile::new().expect("a temporary policy file");
    f.write_all(text.as_bytes())
        .expect("writing the policy file");
    f
}

fn call(exec: &Executor, name: &str, arguments: Value) -> Outcome {
    let call = ToolCall {
        name: name.into(),
        arguments,
    };
    exec.call(&call, &Arc::new(AtomicBool::new(false)))
}

/// What the operator's terminal shows of an outcome.
fn shown(o: &Outcome) -> String {
    clean(&format!("{} {}", o.output, json!(o.decision)))
}

/// A parameter's value as the node itself answers it, past the fence.
fn raw_param(graph: &Arc<dyn RosGraph>, name: &str) -> Value {
    let r = runtime().block_on(graph.call_service(
        "/turtlesim/get_parameters",
        "rcl_interfaces/srv/GetParameters",
        json!({ "names": [name] }),
        Duration::from_secs(5),
    ));
    r.unwrap_or_else(|e| panic!("the sim's own get_parameters: {e}"))
        .response["values"][0]["integer_value"]
        .clone()
}

/// On the sim, through the agent's call path: a denied parameter is not set (by the
/// parameter tool, by a raw service call, spelt with a zero-width character or in
/// capitals), not read, not described and not listed, while its siblings are; and a
/// topic name split by a zero-width character is refused and never shown whole.
#[test]
#[ignore = "opens DDS in a loopback-only network namespace (root): cargo test --release -- --include-ignored"]
fn the_fence_covers_parameters_and_split_names_on_the_sim() {
    if rerun_in_loopback_netns(
        "fence_params::the_fence_covers_parameters_and_split_names_on_the_sim",
        180,
    ) {
        return;
    }
    let file = policy_file(DENY);
    let mut args = agent_args(Robot::Sim, true);
    args.policy = Some(file.path().to_path_buf());
    let (link, registry, policy) =
        robot_tools(&args, Arc::new(NoOperator), EStop::new()).expect("the sim and its tools");
    let raw = link.graph.clone().expect("the sim's graph");
    let exec = Executor::new(registry, policy).expect("an executor");
    let refused = |o: &Outcome| matches!(o.decision, Decision::Refused(_)) && !o.ok;

    // Its sibling is set: the path works, so a refusal below is the fence's.
    let o = call(
        &exec,
        "ros_param_set",
        json!({"node": "/turtlesim", "name": "background_g", "value": 7}),
    );
    assert!(o.ok, "{}", shown(&o));
    assert_eq!(raw_param(&raw, "background_g"), json!(7));

    for name in [
        "background_r",
        "background\u{200B}_r",
        "BACKGROUND_R",
        "/background_r",
    ] {
        let o = call(
            &exec,
            "ros_param_set",
            json!({"node": "/turtlesim", "name": name, "value": 5}),
        );
        assert!(refused(&o), "{name:?}: {}", shown(&o));
        let o = call(
            &exec,
            "ros_param_get",
            json!({"node": "turtlesim", "name": name}),
        );
        assert!(refused(&o), "{name:?}: {}", shown(&o));
    }
    // Any tool that builds a parameter request meets the fence at the ROS boundary.
    let set = json!({"service": "/turtlesim/set_parameters", "request": {"parameters": [
        {"name": "background_r", "value": {"type": 2, "integer_value": 5}}]}});
    let describe = json!({"service": "/turtlesim/describe_parameters",
                          "request": {"names": ["background_r"]}});
    let types = json!({"service": "/turtlesim/get_parameter_types",
                       "request": {"names": ["background_g", "background_r"]}});
    for args in [set, describe, types] {
        let o = call(&exec, "ros_service_call", args.clone());
        assert!(!o.ok, "{args}: {}", shown(&o));
        assert!(shown(&o).contains("off limits"), "{args}: {}", shown(&o));
    }
    assert_eq!(
        raw_param(&raw, "background_r"),
        json!(69),
        "a denied parameter was set"
    );

    // Listed without it, by the tool and by a raw listing; its siblings stay.
    let o = call(&exec, "ros_param_list", json!({"node": "/turtlesim"}));
    assert!(o.ok, "{}", shown(&o));
    let names = o.output["parameters"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    assert!(names.contains(&json!("background_g")), "{}", shown(&o));
    assert!(!names.contains(&json!("background_r")), "{}", shown(&o));
    assert_eq!(o.output["count"], json!(names.len()));
    let o = call(
        &exec,
        "ros_service_call",
        json!({"service": "/turtlesim/list_parameters"}),
    );
    assert!(o.ok, "{}", shown(&o));
    assert!(!shown(&o).contains("background_r"), "{}", shown(&o));
    assert!(shown(&o).contains("background_b"), "{}", shown(&o));

    // A denied topic split by a zero-width character: refused, and never shown whole.
    for (tool, args) in [
        (
            "ros_topic_publish",
            json!({"topic": "/turtle\u{200B}1/cmd_vel", "message": {"linear": {"x": 1.0}}}),
        ),
        ("ros_topic_echo", json!({"topic": "/turtle\u{2060}1/pose"})),
        ("ros_topic_echo", json!({"topic": "/Turtle\u{AD}1/pose"})),
    ] {
        let o = call(&exec, tool, args.clone());
        assert!(refused(&o), "{tool} {args}: {}", shown(&o));
        assert!(
            !shown(&o).to_lowercase().contains("/turtle1"),
            "{tool}: {}",
            shown(&o)
        );
    }
    let o = call(&exec, "ros_topic_list", json!({}));
    assert!(o.ok && !shown(&o).contains("/turtle1"), "{}", shown(&o));
}

/// The `ferrosa` binary, killed after `limit`.
fn ferrosa(args: &[&str], limit: Duration) -> (Value, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_ferrosa"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run ferrosa");
    let start = Instant::now();
    while child.try_wait().ok().flatten().is_none() && start.elapsed() < limit {
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = child.kill();
    let out = child.wait_with_output().expect("ferrosa's output");
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    let value = serde_json::from_str(&stdout).unwrap_or(Value::Null);
    (value, format!("{stdout}\n{stderr}"))
}

/// Kills `ferrosa sim` however the test ends.
struct Sim(Child);

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `ferrosa call` against `ferrosa sim` over ROS 2, as an operator scripts it: under a
/// policy file denying `/turtlesim/background_r`, setting it is refused and leaves it as
/// it was, and listing the node's parameters leaves it out.
#[test]
#[ignore = "opens DDS in a loopback-only network namespace (root): cargo test --release -- --include-ignored"]
fn ferrosa_call_neither_sets_nor_lists_a_denied_parameter() {
    if rerun_in_loopback_netns(
        "fence_params::ferrosa_call_neither_sets_nor_lists_a_denied_parameter",
        240,
    ) {
        return;
    }
    let file = policy_file(DENY);
    let policy = file.path().to_str().expect("a UTF-8 temporary path");
    let _sim = Sim(Command::new(env!("CARGO_BIN_EXE_ferrosa"))
        .arg("sim")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("ferrosa sim"));
    let limit = Duration::from_secs(40);
    let on_ros2 = |tool: &str, args: Value, policy: Option<&str>| {
        let args = args.to_string();
        let mut argv = vec!["call", tool, args.as_str(), "--robot", "ros2", "--yes"];
        if let Some(p) = policy {
            argv.extend(["--policy", p]);
        }
        ferrosa(&argv, limit)
    };
    let param = |name: &str| json!({"node": "/turtlesim", "name": name});
    // Wait until the sim answers (the set of a sibling: the path works).
    let start = Instant::now();
    loop {
        let mut set = param("background_g");
        set["value"] = json!(7);
        let (out, text) = on_ros2("ros_param_set", set, Some(policy));
        if out["ok"] == json!(true) {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(90),
            "the sim never answered: {text}"
        );
        std::thread::sleep(Duration::from_millis(500));
    }

    let mut set = param("background_r");
    set["value"] = json!(5);
    let (out, text) = on_ros2("ros_param_set", set, Some(policy));
    assert_eq!(out["decision"]["decision"], json!("refused"), "{text}");
    assert_eq!(out["ok"], json!(false), "{text}");

    let (out, text) = on_ros2(
        "ros_param_list",
        json!({"node": "/turtlesim"}),
        Some(policy),
    );
    assert_eq!(out["ok"], json!(true), "{text}");
    let listed = out["output"]["parameters"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    assert!(listed.contains(&json!("background_b")), "{text}");
    assert!(!text.contains("background_r"), "{text}");

    // Without the policy the parameter is read as the sim started it, the sibling as set.
    let (out, text) = on_ros2("ros_param_get", param("background_r"), None);
    assert_eq!(
        out["output"]["value"],
        json!(69),
        "a denied parameter was set: {text}"
    );
    let (out, text) = on_ros2("ros_param_get", param("background_g"), None);
    assert_eq!(out["output"]["value"], json!(7), "{text}");
}

// ---------------------------------------------------------------------------------------
// The property: no listing shows a denied name, however a peer spells it.

fn endpoint(topic: &str, node: &str) -> TopicEndpoint {
    TopicEndpoint {
        topic: topic.into(),
        type_name: "std_msgs/msg/String".into(),
        node: Some(node.into()),
        qos: Qos {
            reliability: Reliability::Reliable,
            durability: Durability::Volatile,
        },
        type_hash: None,
    }
}

fn server(service: &str, ty: &str, node: &str) -> ServiceEndpoint {
    ServiceEndpoint {
        service: service.into(),
        type_name: ty.into(),
        node: Some(node.into()),
    }
}

/// A robot whose peer spells the denied `secret` (a namespace: a node, a topic and a
/// service under it, and a message naming it) and the denied parameter `param` of
/// `/turtlesim` as `spell` gives them, beside ordinary names.
fn spelt_robot(secret: &str, param: &str) -> FakeGraph {
    let graph = Graph {
        nodes: vec!["/turtlesim".into(), secret.into()],
        publishers: vec![
            endpoint("/chatter", "/turtlesim"),
            endpoint(&format!("{secret}/data"), "/turtlesim"),
            endpoint("/talk", secret),
        ],
        subscribers: vec![endpoint(secret, "/turtlesim")],
        servers: vec![
            server(
                "/turtlesim/list_parameters",
                "rcl_interfaces/srv/ListParameters",
                "/turtlesim",
            ),
            server("/clear", "std_srvs/srv/Empty", "/turtlesim"),
            server(&format!("{secret}/open"), "std_srvs/srv/Empty", secret),
        ],
        clients: vec![],
    };
    let listing = json!({"result": {"names": ["background_g", param], "prefixes": []}});
    FakeGraph::new()
        .with_graph(graph)
        .with_service("/turtlesim/list_parameters", listing)
        .with_messages(
            "/chatter",
            vec![json!({ "data": format!("saw {secret}/data") })],
        )
}

/// Format characters of every kind, and `name` spelt with some of them inserted and
/// some letters in capitals.
const FORMAT: &[char] = &[
    '\u{AD}',
    '\u{600}',
    '\u{61C}',
    '\u{180E}',
    '\u{200B}',
    '\u{200C}',
    '\u{200D}',
    '\u{200E}',
    '\u{202A}',
    '\u{202E}',
    '\u{2060}',
    '\u{2064}',
    '\u{2066}',
    '\u{FEFF}',
    '\u{FFFB}',
    '\u{110CD}',
    '\u{1BCA0}',
    '\u{E0001}',
    '\u{E007F}',
];

fn spell(name: String) -> impl Strategy<Value = (String, String)> {
    let n = name.chars().count();
    (
        prop::collection::vec((1..=n, prop::sample::select(FORMAT)), 1..4),
        prop::collection::vec(any::<bool>(), n),
    )
        .prop_map(move |(inserts, upper)| {
            let mut chars: Vec<String> = name
                .chars()
                .zip(upper)
                .map(|(c, u)| if u { c.to_ascii_uppercase() } else { c }.to_string())
                .collect();
            chars.push(String::new());
            for (at, c) in inserts {
                chars[at].insert(0, c);
            }
            (name.clone(), chars.concat())
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Listings (nodes, topics, services, a node's parameters) and an echo, through the
    /// agent's call path, never show a denied name once the terminal has cleaned them:
    /// neither the denied namespace nor the denied parameter, however the peer spelt
    /// them, and the ordinary names stay listed.
    #[test]
    fn listings_never_show_a_denied_name_however_it_is_spelt(
        (secret, secret_spelt) in "zq[a-z]{2,5}".prop_map(|s| format!("/{s}")).prop_flat_map(spell),
        (param, param_spelt) in "zp[a-z]{2,5}".prop_flat_map(spell),
    ) {
        let deny = format!(r#"deny = ["^{secret}", "^/turtlesim/{param}$"]"#);
        let file = policy_file(&deny);
        let mut args = agent_args(Robot::Sim, true);
        args.policy = Some(file.path().to_path_buf());
        let raw: Arc<dyn RosGraph> = Arc::new(spelt_robot(&secret_spelt, &param_spelt));
        let (registry, policy, _) =
            tools_and_policy(&args, Arc::new(NoOperator), Some(raw), EStop::new()).unwrap();
        let exec = Executor::new(registry, policy).unwrap();
        let mut all = String::new();
        for (tool, args, keeps) in [
            ("ros_node_list", json!({}), "/turtlesim"),
            ("ros_topic_list", json!({}), "/chatter"),
            ("ros_service_list", json!({}), "/clear"),
            ("ros_param_list", json!({"node": "/turtlesim"}), "background_g"),
            ("ros_topic_echo", json!({"topic": "/chatter", "count": 1}), "saw"),
            ("ros_topic_echo", json!({"topic": format!("{secret_spelt}/data")}), "off limits"),
        ] {
            let o = call(&exec, tool, args);
            let text = shown(&o);
            prop_assert!(text.contains(keeps), "{}: {}", tool, text);
            all.push_str(&text);
        }
        let all = all.to_lowercase();
        prop_assert!(!all.contains(&secret), "{} shown: {}", secret, all);
        prop_assert!(!all.contains(&param), "{} shown: {}", param, all);
    }
}

/// The model's streamed answer, redacted a word at a time as the terminal and the console
/// print it (each piece cleaned on its own): a denied name split by a format character
/// across pieces is held back whole and redacted, never joined on screen.
#[test]
fn a_streamed_name_split_by_a_format_character_is_redacted_whole() {
    for pieces in [
        &["I will drive /turtle\u{200B}", "1/cmd_vel now."][..],
        &["see /tur", "tle\u{2060}", "1/pose", " and stop"],
        &["/Turtle\u{AD}", "1 ", "done"],
    ] {
        let mut words = ferrosa::agent::event::WordStream::new(Arc::new(
            ferrosa::fence::Fence::new(&["^/turtle1".to_string()]).unwrap(),
        ));
        let mut screen = String::new();
        for p in pieces {
            screen.push_str(&clean(&words.push(p)));
        }
        screen.push_str(&clean(&words.finish()));
        assert!(
            !screen.to_lowercase().contains("/turtle1"),
            "{pieces:?} showed {screen:?}"
        );
        assert!(screen.contains(ferrosa::fence::REDACTED), "{screen:?}");
    }
}
