//! ROS 1 peers cannot redefine the robot: shipped types and the e-stop's type are fixed,
//! definitions are checked by their md5sum and bounded, against a real roscore.
//!
//! Issue 41. Each hole has a test through the real surface, in a loopback-only network
//! namespace with Debian's `roscore`: hostile peers are raw sockets (XML-RPC and TCPROS
//! over `std::net`, written here byte by byte), honest ones are rospy (`rostopic pub`, a
//! rospy driver). Crashes are tested on the `ferrosa` binary as a child process
//! (`ferrosa mcp --robot ros1`): it must still be alive and answer its node API after.
//! The property tests at the end feed arbitrary and adversarial input to the XML-RPC
//! reader, the TCPROS header reader and the definition parser, and measure the largest
//! allocation each makes (`alloc::largest_allocation`).

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ferrosa::ros::msg::{check_extent, parse_message, Interfaces, MAX_DEPTH};
use ferrosa::ros::ros1::wire::{self, WireError};
use ferrosa::ros::ros1::xmlrpc::{self, XValue, XmlRpcError};
use ferrosa::ros::RosGraph;
use proptest::prelude::*;
use serde_json::json;

use crate::ros1::ros_env;
use crate::util::rerun_in_loopback_netns;

const MASTER: &str = "http://127.0.0.1:11311/";

/// md5sums of ROS 1's own types (from rospy's generated code).
const BOOL_MD5: &str = "8b94c1b53db61fb6aed406028ad6332a";
const STRING_MD5: &str = "992ce8a1687cec8c8bd883ec73ca41d1";
const VECTOR3_MD5: &str = "4a842b65f413084dc2b10fb484ea7f17";

// ------------------------------------------------------------ peers and processes

/// The children of one test, stopped when it ends (passing or not).
struct Children(Vec<Child>);

impl Drop for Children {
    fn drop(&mut self) {
        for c in self.0.iter_mut().rev() {
            crate::util::stop(c);
        }
    }
}

fn home(test: &str) -> PathBuf {
    let home = std::env::temp_dir().join(format!("ferrosa-{test}-{}", std::process::id()));
    std::fs::create_dir_all(&home).unwrap();
    home
}

/// `roscore` on 11311, answering.
fn roscore(home: &Path) -> Children {
    let core = ros_env(
        Command::new("timeout").args(["300", "roscore", "-p", "11311"]),
        home,
    )
    .stdin(Stdio::null())
    .stdout(Stdio::null())
    .stderr(Stdio::null())
    .spawn()
    .unwrap_or_else(|e| panic!("roscore: {e} (.ci/setup installs Debian's ros-core)"));
    let children = Children(vec![core]);
    let start = Instant::now();
    while master("getSystemState", &[s("/probe")]).is_err() {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "roscore did not start"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    children
}

/// A Debian ROS 1 tool, run to its end (under a time limit); its stdout.
fn ros_tool(home: &Path, args: &[&str]) -> String {
    let out = ros_env(Command::new("timeout").arg("30").args(args), home)
        .output()
        .unwrap_or_else(|e| panic!("{args:?}: {e}"));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Lines a child writes on a pipe, kept as they come.
#[derive(Clone, Default)]
struct Lines(Arc<Mutex<Vec<String>>>);

impl Lines {
    fn follow(pipe: impl Read + Send + 'static, label: &'static str) -> Lines {
        let lines = Lines::default();
        let kept = lines.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(pipe).lines() {
                let Ok(line) = line else { return };
                eprintln!("{label}: {line}");
                kept.0.lock().unwrap().push(line);
            }
        });
        lines
    }

    fn all(&self) -> Vec<String> {
        self.0.lock().unwrap().clone()
    }

    /// Wait (at most `limit`) for a line holding every one of `words`.
    fn wait_for(&self, words: &[&str], limit: Duration) -> Option<String> {
        let start = Instant::now();
        loop {
            let found = self
                .all()
                .into_iter()
                .find(|l| words.iter().all(|w| l.contains(w)));
            if found.is_some() || start.elapsed() > limit {
                return found;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

/// `ferrosa mcp --robot ros1` (no model runs), its warnings on stderr.
fn ferrosa(home: &Path) -> (Child, Lines) {
    let mut child = ros_env(
        Command::new("timeout").args(["200", env!("CARGO_BIN_EXE_ferrosa")]),
        home,
    )
    .args(["--prompt-cache", "off", "mcp", "--robot", "ros1"])
    .env("FERROSA_LOG", "warn")
    .stdin(Stdio::piped())
    .stdout(Stdio::null())
    .stderr(Stdio::piped())
    .spawn()
    .expect("the ferrosa binary");
    let lines = Lines::follow(child.stderr.take().unwrap(), "ferrosa");
    (child, lines)
}

/// The name ferrosa's node has on the master, once it shows (it subscribes to
/// `/ferrosa/estop` at start); `None` when it never does.
fn ferrosa_node() -> Option<String> {
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(20) {
        if let Ok(doc) = master("getSystemState", &[s("/probe")]) {
            if let Some(n) = strings(&doc)
                .into_iter()
                .find(|s| s.starts_with("/ferrosa_"))
            {
                return Some(n);
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    None
}

/// A node's API URI, from the master.
fn lookup_node(node: &str) -> String {
    let doc = master("lookupNode", &[s("/probe"), s(node)]).unwrap();
    strings(&doc)
        .into_iter()
        .find(|s| s.starts_with("http://"))
        .unwrap_or_else(|| panic!("lookupNode {node}: {doc}"))
}

/// Whether the process answers `getPid` on its node API.
fn answers_get_pid(api: &str) -> bool {
    xmlrpc_post(api, &call_doc("getPid", &[s("/probe")]))
        .is_ok_and(|doc| doc.contains("<i4>") || doc.contains("<int>"))
}

// ------------------------------------------------------------ raw XML-RPC

fn escape(t: &str) -> String {
    t.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn s(t: &str) -> String {
    format!("<value><string>{}</string></value>", escape(t))
}

fn int(i: i64) -> String {
    format!("<value><i4>{i}</i4></value>")
}

fn array(items: &[String]) -> String {
    format!(
        "<value><array><data>{}</data></array></value>",
        items.concat()
    )
}

fn call_doc(method: &str, params: &[String]) -> String {
    let params: String = params
        .iter()
        .map(|p| format!("<param>{p}</param>"))
        .collect();
    format!("<?xml version=\"1.0\"?><methodCall><methodName>{method}</methodName><params>{params}</params></methodCall>")
}

fn response_doc(value: &str) -> String {
    format!("<?xml version=\"1.0\"?><methodResponse><params><param>{value}</param></params></methodResponse>")
}

/// POST `body` to `uri` (`http://host:port/`) over HTTP/1.0: the answer's body.
fn xmlrpc_post(uri: &str, body: &str) -> std::io::Result<String> {
    let addr = uri
        .trim_start_matches("http://")
        .trim_end_matches('/')
        .to_string();
    let mut stream = TcpStream::connect(&addr)?;
    stream.set_read_timeout(Some(Duration::from_secs(30)))?;
    stream.set_write_timeout(Some(Duration::from_secs(30)))?;
    write!(
        stream,
        "POST / HTTP/1.0\r\nHost: {addr}\r\nContent-Type: text/xml\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )?;
    let mut answer = String::new();
    stream.read_to_string(&mut answer)?;
    match answer.split_once("\r\n\r\n") {
        Some((_, body)) => Ok(body.to_string()),
        None => Err(std::io::Error::other(format!("no HTTP answer: {answer:?}"))),
    }
}

fn master(method: &str, params: &[String]) -> std::io::Result<String> {
    xmlrpc_post(MASTER, &call_doc(method, params))
}

/// Every `<string>` text of a document, in order.
fn strings(doc: &str) -> Vec<String> {
    doc.split("<string>")
        .skip(1)
        .filter_map(|p| {
            p.split_once("</string>")
                .map(|(t, _)| t.replace("&amp;", "&"))
        })
        .collect()
}

/// Every integer of a document, in order.
fn ints(doc: &str) -> Vec<i64> {
    doc.split("<i4>")
        .chain(doc.split("<int>"))
        .skip(1)
        .filter_map(|p| p.split(['<']).next()?.trim().parse().ok())
        .collect()
}

/// Serve XML-RPC on `listener`: `answer(method, document)` gives each response's value.
fn serve_xmlrpc(listener: TcpListener, answer: impl Fn(&str, &str) -> String + Send + 'static) {
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut stream) = stream else { return };
            let _ = stream.set_read_timeout(Some(Duration::from_secs(10)));
            let mut reader = BufReader::new(stream.try_clone().unwrap());
            let mut length = 0;
            loop {
                let mut line = String::new();
                if reader.read_line(&mut line).unwrap_or(0) == 0 {
                    break;
                }
                if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
                    length = v.trim().parse().unwrap_or(0);
                }
                if line == "\r\n" {
                    break;
                }
            }
            let mut body = vec![0; length.min(1 << 20)];
            let _ = reader.read_exact(&mut body);
            let doc = String::from_utf8_lossy(&body).to_string();
            let method = doc
                .split("<methodName>")
                .nth(1)
                .and_then(|m| m.split('<').next())
                .unwrap_or("")
                .to_string();
            let out = response_doc(&answer(&method, &doc));
            let _ = write!(
                stream,
                "HTTP/1.0 200 OK\r\nContent-Type: text/xml\r\nContent-Length: {}\r\n\r\n{out}",
                out.len()
            );
        }
    });
}

// ------------------------------------------------------------ raw TCPROS

fn header(fields: &[(&str, &str)]) -> Vec<u8> {
    let mut body = Vec::new();
    for (k, v) in fields {
        let f = format!("{k}={v}");
        body.extend_from_slice(&(f.len() as u32).to_le_bytes());
        body.extend_from_slice(f.as_bytes());
    }
    let mut out = (body.len() as u32).to_le_bytes().to_vec();
    out.extend(body);
    out
}

fn read_header(stream: &mut TcpStream) -> std::io::Result<BTreeMap<String, String>> {
    let mut len = [0u8; 4];
    stream.read_exact(&mut len)?;
    let n = u32::from_le_bytes(len) as usize;
    if n > 1 << 20 {
        return Err(std::io::Error::other(format!("a header of {n} bytes")));
    }
    let mut body = vec![0; n];
    stream.read_exact(&mut body)?;
    let mut out = BTreeMap::new();
    let mut at = 0;
    while at + 4 <= n {
        let m = u32::from_le_bytes(body[at..at + 4].try_into().unwrap()) as usize;
        let f = String::from_utf8_lossy(&body[at + 4..(at + 4 + m).min(n)]).to_string();
        if let Some((k, v)) = f.split_once('=') {
            out.insert(k.to_string(), v.to_string());
        }
        at += 4 + m;
    }
    Ok(out)
}

/// A publisher written byte by byte: it registers `topic` as `master_type` with the
/// master, answers `requestTopic` with its TCPROS port, and sends every subscriber
/// `fields` as its connection header, then `frames`.
struct RawPublisher {
    api: String,
    /// The connection headers subscribers sent it.
    seen: Arc<Mutex<Vec<BTreeMap<String, String>>>>,
}

impl RawPublisher {
    fn start(
        name: &str,
        topic: &str,
        master_type: &str,
        fields: &[(&str, &str)],
        frames: Vec<Vec<u8>>,
    ) -> RawPublisher {
        let tcpros = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = tcpros.local_addr().unwrap().port();
        let hello = header(fields);
        let seen: Arc<Mutex<Vec<BTreeMap<String, String>>>> = Arc::default();
        let kept = seen.clone();
        std::thread::spawn(move || {
            let mut open = Vec::new();
            for stream in tcpros.incoming() {
                let Ok(mut stream) = stream else { return };
                let _ = stream.set_read_timeout(Some(Duration::from_secs(10)));
                if let Ok(h) = read_header(&mut stream) {
                    kept.lock().unwrap().push(h);
                }
                let _ = stream.write_all(&hello);
                for f in &frames {
                    let _ = stream.write_all(&(f.len() as u32).to_le_bytes());
                    let _ = stream.write_all(f);
                }
                open.push(stream);
            }
        });
        let api = TcpListener::bind("127.0.0.1:0").unwrap();
        let uri = format!("http://127.0.0.1:{}/", api.local_addr().unwrap().port());
        serve_xmlrpc(api, move |method, _| match method {
            "requestTopic" => array(&[
                int(1),
                s("ready"),
                array(&[s("TCPROS"), s("127.0.0.1"), int(port.into())]),
            ]),
            _ => array(&[int(1), s(""), int(0)]),
        });
        master(
            "registerPublisher",
            &[s(name), s(topic), s(master_type), s(&uri)],
        )
        .unwrap();
        RawPublisher { api: uri, seen }
    }

    /// Wait (at most 20 s) until a subscriber has connected.
    fn connected(&self) -> bool {
        let start = Instant::now();
        while self.seen.lock().unwrap().is_empty() {
            if start.elapsed() > Duration::from_secs(20) {
                return false;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        true
    }
}

/// The md5sum genmsg gives `Vector3 lin / Vector3 ang` (a Twist renamed), and that
/// definition as a connection carries it.
fn renamed_twist() -> (String, String) {
    let md5 = format!(
        "{:x}",
        md5::compute(format!("{VECTOR3_MD5} lin\n{VECTOR3_MD5} ang"))
    );
    let text = format!(
        "Vector3 lin\nVector3 ang\n{}\nMSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n",
        "=".repeat(80)
    );
    (md5, text)
}

/// Warnings the process logs (tracing), kept for the assertions (a test in a namespace
/// of its own runs alone in its process, so one global subscriber is its own).
fn capture_warnings() -> Arc<Mutex<Vec<u8>>> {
    #[derive(Clone)]
    struct Sink(Arc<Mutex<Vec<u8>>>);
    impl Write for Sink {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            std::io::stderr().write_all(b)?;
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let buf = Arc::new(Mutex::new(Vec::new()));
    let sink = Sink(buf.clone());
    let _ = tracing_subscriber::fmt()
        .with_max_level(tracing::Level::WARN)
        .with_ansi(false)
        .with_writer(move || sink.clone())
        .try_init();
    buf
}

// ------------------------------------------------------------ the holes

/// Hole 1: a peer's definition replaced the shipped one, so the limits read a Twist with
/// renamed fields and let 5 m/s through to the driver. Now a subscriber with a renamed
/// Twist (its md5sum honest for its text) and a publisher with one under md5sum `*` are
/// both refused and reported; ferrosa's Twist stays the shipped one; and what the rospy
/// driver receives never exceeds the limit.
#[test]
#[ignore = "needs Debian's ROS 1 and root for a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn issue_41_ros1_peers_cannot_redefine_a_shipped_velocity_type() {
    if rerun_in_loopback_netns(
        "ros1_trust::issue_41_ros1_peers_cannot_redefine_a_shipped_velocity_type",
        300,
    ) {
        return;
    }
    let warnings = capture_warnings();
    let home = home("redefine");
    let mut peers = roscore(&home);
    let driver = r#"
import rospy
from geometry_msgs.msg import Twist
rospy.init_node("driver", disable_signals=True)
rospy.Subscriber("/turtle1/cmd_vel", Twist, lambda t: print("linear %.6f %.6f %.6f" % (t.linear.x, t.linear.y, t.linear.z), flush=True))
print("ready", flush=True)
rospy.spin()
"#;
    let mut child = ros_env(
        Command::new("timeout").args(["200", "/usr/bin/python3", "-c", driver]),
        &home,
    )
    .stdout(Stdio::piped())
    .stderr(Stdio::null())
    .spawn()
    .unwrap();
    let said = Lines::follow(child.stdout.take().unwrap(), "driver");
    peers.0.push(child);
    assert!(
        said.wait_for(&["ready"], Duration::from_secs(30)).is_some(),
        "the rospy driver did not start"
    );

    std::env::set_var("ROS_MASTER_URI", MASTER);
    std::env::set_var("ROS_HOSTNAME", "127.0.0.1");
    let raw: Arc<dyn RosGraph> = Arc::new(
        ferrosa::ros::ros1::Ros1Graph::start(
            &ferrosa::ros::ros1::Ros1Options::from_env(),
            "ferrosa",
        )
        .unwrap(),
    );
    let policy = ferrosa::tool::Policy::default();
    let graph = ferrosa::ui::robot::guard(raw, &policy, ferrosa::ui::robot::Robot::Ros1);
    let rt = crate::util::runtime();
    let publish = |msg: serde_json::Value| {
        rt.block_on(graph.publish("/turtle1/cmd_vel", "geometry_msgs/Twist", msg))
    };
    // An honest command first: the driver is connected and hears it.
    let start = Instant::now();
    while publish(json!({"linear": {"x": 0.5}})).is_err() {
        assert!(start.elapsed() < Duration::from_secs(20), "no publication");
    }
    assert!(said
        .wait_for(&["linear 0.500000"], Duration::from_secs(10))
        .is_some());

    // A subscriber of the same topic sends a renamed Twist, with the md5sum its text
    // hashes to.
    let node = strings(&master("getSystemState", &[s("/probe")]).unwrap())
        .into_iter()
        .find(|n| n.starts_with("/ferrosa_"))
        .expect("ferrosa's node");
    let api = lookup_node(&node);
    let offer = xmlrpc_post(
        &api,
        &call_doc(
            "requestTopic",
            &[
                s("/hostile"),
                s("/turtle1/cmd_vel"),
                array(&[array(&[s("TCPROS")])]),
            ],
        ),
    )
    .unwrap();
    let port = *ints(&offer).last().expect("a TCPROS port");
    let (md5, text) = renamed_twist();
    let mut hostile = TcpStream::connect(("127.0.0.1", port as u16)).unwrap();
    hostile
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    hostile
        .write_all(&header(&[
            ("callerid", "/hostile"),
            ("topic", "/turtle1/cmd_vel"),
            ("type", "geometry_msgs/Twist"),
            ("md5sum", &md5),
            ("message_definition", &text),
        ]))
        .unwrap();
    let answer = read_header(&mut hostile).unwrap();
    // A publisher of the same type under md5sum `*`, read when a tool echoes its topic.
    let sneaky = RawPublisher::start(
        "/sneaky",
        "/sneaky",
        "geometry_msgs/Twist",
        &[
            ("callerid", "/sneaky"),
            ("topic", "/sneaky"),
            ("type", "geometry_msgs/Twist"),
            ("md5sum", "*"),
            ("message_definition", &text),
        ],
        vec![],
    );
    // As a tool's echo reads it, once the graph shows it.
    let start = Instant::now();
    while sneaky.seen.lock().unwrap().is_empty() && start.elapsed() < Duration::from_secs(20) {
        let _ = rt.block_on(graph.subscribe("/sneaky", None, 1, Duration::from_millis(500)));
    }
    assert!(sneaky.connected(), "ferrosa never read /sneaky");

    // The same 5 m/s, as the renamed Twist and as the shipped one.
    let renamed = publish(json!({"lin": {"x": 5.0}, "ang": {"z": 0.0}}));
    let shipped = publish(json!({"linear": {"x": 5.0}}));
    // A last command, so everything before it has arrived when it has.
    let marker = publish(json!({"linear": {"x": 0.25}}));
    let arrived = said.wait_for(&["linear 0.250000"], Duration::from_secs(10));
    let heard: Vec<f64> = said
        .all()
        .iter()
        .filter_map(|l| l.strip_prefix("linear "))
        .map(|l| {
            let xyz: Vec<f64> = l.split(' ').map(|v| v.parse().unwrap()).collect();
            xyz.iter().map(|v| v * v).sum::<f64>().sqrt()
        })
        .collect();
    eprintln!("hostile subscriber's answer {answer:?}; renamed {renamed:?}; shipped {shipped:?}; driver heard {heard:?}");
    assert!(
        heard.iter().all(|v| *v <= 1.0 + 1e-6),
        "the driver received {heard:?} m/s, past the 1 m/s limit"
    );
    assert!(renamed.is_err(), "a Twist with renamed fields went out");
    assert!(
        marker.is_ok() && arrived.is_some(),
        "a plain Twist no longer goes out: {marker:?}"
    );
    assert!(
        answer
            .get("error")
            .is_some_and(|e| e.contains("cannot redefine")),
        "the renamed Twist's subscriber was not refused: {answer:?}"
    );
    let fields: Vec<String> = graph
        .interfaces()
        .message("geometry_msgs/Twist")
        .unwrap()
        .fields
        .iter()
        .map(|f| f.name.clone())
        .collect();
    assert_eq!(fields, ["linear", "angular"]);
    let warned = String::from_utf8_lossy(&warnings.lock().unwrap()).to_string();
    for who in ["/hostile", &sneaky.api] {
        assert!(
            warned
                .lines()
                .any(|l| l.contains("WARN") && l.contains("refused") && l.contains(who)),
            "no warning about {who}: {warned}"
        );
    }
    drop(graph);
    drop(peers);
    let _ = std::fs::remove_dir_all(&home);
}

/// Hole 2: a node that merely advertised `/ferrosa/estop` with another type stopped the
/// e-stop topic, silently. Now one advertising `std_msgs/String` before ferrosa starts,
/// and one advertising `std_msgs/Bool` under md5sum `*` with a string's definition, are
/// refused and reported, and `rostopic pub /ferrosa/estop std_msgs/Bool 'data: true'`
/// still engages the e-stop of the `ferrosa` binary.
#[test]
#[ignore = "needs Debian's ROS 1 and root for a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn issue_41_ros1_estop_topic_keeps_its_type_whatever_peers_advertise() {
    if rerun_in_loopback_netns(
        "ros1_trust::issue_41_ros1_estop_topic_keeps_its_type_whatever_peers_advertise",
        300,
    ) {
        return;
    }
    let home = home("estop");
    let mut peers = roscore(&home);
    let string_true = [&4u32.to_le_bytes()[..], b"true"].concat();
    let before = RawPublisher::start(
        "/spoof_string",
        "/ferrosa/estop",
        "std_msgs/String",
        &[
            ("callerid", "/spoof_string"),
            ("topic", "/ferrosa/estop"),
            ("type", "std_msgs/String"),
            ("md5sum", STRING_MD5),
            ("message_definition", "string data\n"),
        ],
        vec![string_true.clone()],
    );
    let (child, said) = ferrosa(&home);
    peers.0.push(child);
    let node = ferrosa_node();
    eprintln!("ferrosa's node: {node:?}");
    let after = RawPublisher::start(
        "/spoof_bool",
        "/ferrosa/estop",
        "std_msgs/Bool",
        &[
            ("callerid", "/spoof_bool"),
            ("topic", "/ferrosa/estop"),
            ("type", "std_msgs/Bool"),
            ("md5sum", "*"),
            ("message_definition", "string data\n"),
        ],
        vec![string_true],
    );
    assert!(
        node.is_some() && after.connected(),
        "ferrosa never subscribed to /ferrosa/estop"
    );
    let md5 = after.seen.lock().unwrap()[0].get("md5sum").cloned();
    assert_eq!(
        md5.as_deref(),
        Some(BOOL_MD5),
        "ferrosa asked for another type"
    );
    assert!(
        said.wait_for(&["e-stop engaged"], Duration::from_secs(2))
            .is_none(),
        "a string engaged the e-stop"
    );
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
    let engaged = said.wait_for(&["e-stop engaged"], Duration::from_secs(15));
    for who in [&before.api, &after.api] {
        assert!(
            said.wait_for(&["WARN", "refused", who], Duration::from_secs(1))
                .is_some(),
            "ferrosa did not report refusing {who}"
        );
    }
    assert!(
        engaged.is_some(),
        "rostopic pub /ferrosa/estop did not engage the e-stop"
    );
    drop(peers);
    let _ = std::fs::remove_dir_all(&home);
}

/// Hole 3: a self-referential definition crashed the process (stack overflow) without
/// anything being called: the graph's refresh learns every topic's type. Now a
/// publisher of a type that contains itself, and one of two types that contain each
/// other, are refused and reported, and the `ferrosa` binary lives on and answers.
#[test]
#[ignore = "needs Debian's ROS 1 and root for a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn issue_41_ros1_recursive_definitions_are_refused_not_a_crash() {
    if rerun_in_loopback_netns(
        "ros1_trust::issue_41_ros1_recursive_definitions_are_refused_not_a_crash",
        300,
    ) {
        return;
    }
    let home = home("recursive");
    let mut peers = roscore(&home);
    let (child, said) = ferrosa(&home);
    peers.0.push(child);
    let node = ferrosa_node().expect("ferrosa's node");
    let api = lookup_node(&node);
    let md5 = "0123456789abcdef0123456789abcdef";
    let mutual = format!("B b\n{}\nMSG: evil_msgs/B\nA a\n", "=".repeat(80));
    let publishers: Vec<RawPublisher> = [
        ("/loop", "evil_msgs/Loop", "Loop next\n".to_string()),
        ("/mutual", "evil_msgs/A", mutual),
    ]
    .iter()
    .map(|(topic, ty, text)| {
        RawPublisher::start(
            topic,
            topic,
            ty,
            &[
                ("callerid", topic),
                ("topic", topic),
                ("type", ty),
                ("md5sum", md5),
                ("message_definition", text),
            ],
            vec![],
        )
    })
    .collect();
    let asked: Vec<bool> = publishers.iter().map(RawPublisher::connected).collect();
    let refused = said.wait_for(&["contains itself"], Duration::from_secs(10));
    let alive = matches!(peers.0[1].try_wait(), Ok(None));
    assert!(alive, "ferrosa ended: {:?}", peers.0[1].try_wait());
    assert_eq!(asked, [true, true], "ferrosa never asked for the types");
    assert!(answers_get_pid(&api), "ferrosa's node API does not answer");
    assert!(refused.is_some(), "no report of the recursive type");
    drop(peers);
    let _ = std::fs::remove_dir_all(&home);
}

/// Hole 4: nested XML-RPC on the node API aborted the process (stack overflow). Now a
/// call nested 20,000 deep is answered with an error, one of 13 MB is refused on its
/// size, a connection that sends nothing is closed, and the `ferrosa` binary lives on
/// and answers.
#[test]
#[ignore = "needs Debian's ROS 1 and root for a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn issue_41_ros1_node_api_survives_nested_and_endless_xmlrpc() {
    if rerun_in_loopback_netns(
        "ros1_trust::issue_41_ros1_node_api_survives_nested_and_endless_xmlrpc",
        300,
    ) {
        return;
    }
    let home = home("xmlrpc");
    let mut peers = roscore(&home);
    let (child, _said) = ferrosa(&home);
    peers.0.push(child);
    let node = ferrosa_node().expect("ferrosa's node");
    let api = lookup_node(&node);
    assert!(answers_get_pid(&api));
    let nested = |depth: usize| {
        call_doc(
            "publisherUpdate",
            &[
                s("/master"),
                s("/ferrosa/estop"),
                format!(
                    "{}{}{}",
                    "<value><array><data>".repeat(depth),
                    s("http://127.0.0.1:1/"),
                    "</data></array></value>".repeat(depth)
                ),
            ],
        )
    };
    // Under the request size bound: answered, with the reason.
    let deep = xmlrpc_post(&api, &nested(20_000));
    // Over it: refused on its size, unread.
    let huge = xmlrpc_post(&api, &nested(300_000));
    // A connection that never sends its request.
    let closed = TcpStream::connect(api.trim_start_matches("http://").trim_end_matches('/'))
        .and_then(|mut idle| {
            idle.set_read_timeout(Some(Duration::from_secs(60)))?;
            idle.read(&mut [0u8; 16])
        });
    eprintln!(
        "deep: {:?}; huge: {:?}; idle: {closed:?}",
        deep.as_ref()
            .map(|d| d.chars().take(300).collect::<String>()),
        huge.as_ref().map(|d| d.len())
    );
    let alive = matches!(peers.0[1].try_wait(), Ok(None));
    assert!(alive, "ferrosa ended: {:?}", peers.0[1].try_wait());
    assert!(answers_get_pid(&api), "ferrosa's node API does not answer");
    assert!(
        deep.is_ok_and(|d| d.contains("nested more than")),
        "the nested call was not answered with its reason"
    );
    assert!(
        matches!(closed, Ok(0))
            || closed
                .as_ref()
                .is_err_and(|e| e.kind() == std::io::ErrorKind::ConnectionReset),
        "an idle connection was kept open: {closed:?}"
    );
    drop(peers);
    let _ = std::fs::remove_dir_all(&home);
}

/// The peak resident memory of this process, in bytes.
fn peak_rss() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let kb: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap();
    kb * 1024
}

/// Hole 4, TCPROS: a connection header's declared length was taken on the peer's word up
/// to 64 MiB (allocated whole before a byte came). Now eight subscribers each declaring
/// 60 MiB and sending it, and one declaring 2^31, are refused on the length: the node's
/// peak memory grows by less than 32 MiB. A subscriber that never reads cannot hold up
/// publishing, and the publication still serves a rospy subscriber.
#[test]
#[ignore = "needs Debian's ROS 1 and root for a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn issue_41_ros1_tcpros_lengths_are_bounded_before_allocation() {
    if rerun_in_loopback_netns(
        "ros1_trust::issue_41_ros1_tcpros_lengths_are_bounded_before_allocation",
        300,
    ) {
        return;
    }
    let home = home("tcpros");
    let peers = roscore(&home);
    std::env::set_var("ROS_MASTER_URI", MASTER);
    std::env::set_var("ROS_HOSTNAME", "127.0.0.1");
    let graph = ferrosa::ros::ros1::Ros1Graph::start(
        &ferrosa::ros::ros1::Ros1Options::from_env(),
        "ferrosa",
    )
    .unwrap();
    let rt = crate::util::runtime();
    rt.block_on(graph.advertise("/chatter", "std_msgs/String"))
        .unwrap();
    let doc = master("getSystemState", &[s("/probe")]).unwrap();
    let node = strings(&doc)
        .into_iter()
        .find(|n| n.starts_with("/ferrosa_"))
        .unwrap();
    let api = lookup_node(&node);
    let offer = xmlrpc_post(
        &api,
        &call_doc(
            "requestTopic",
            &[s("/probe"), s("/chatter"), array(&[array(&[s("TCPROS")])])],
        ),
    )
    .unwrap();
    let port = *ints(&offer).last().unwrap() as u16;
    let before = peak_rss();
    let chunk = Arc::new(vec![b'a'; 1 << 20]);
    let floods: Vec<_> = (0..9)
        .map(|i| {
            let chunk = chunk.clone();
            std::thread::spawn(move || {
                let mut c = TcpStream::connect(("127.0.0.1", port)).unwrap();
                c.set_write_timeout(Some(Duration::from_secs(20))).unwrap();
                let declared: u32 = if i == 0 { 1 << 31 } else { 60 << 20 };
                let _ = c.write_all(&declared.to_le_bytes());
                for _ in 0..60 {
                    if c.write_all(&chunk).is_err() {
                        return;
                    }
                }
            })
        })
        .collect();
    for f in floods {
        f.join().unwrap();
    }
    let grown = peak_rss().saturating_sub(before);
    eprintln!("peak memory grew by {} KiB", grown / 1024);
    assert!(
        grown < 32 << 20,
        "peak memory grew by {} MiB on declared lengths",
        grown >> 20
    );
    // A subscriber that connects and never reads: once its socket is full, it is
    // dropped, not waited on (the publishes below end).
    let mut stalled = TcpStream::connect(("127.0.0.1", port)).unwrap();
    stalled
        .write_all(&header(&[
            ("callerid", "/stalled"),
            ("topic", "/chatter"),
            ("type", "std_msgs/String"),
            ("md5sum", STRING_MD5),
        ]))
        .unwrap();
    let graph = Arc::new(graph);
    let (done, finished) = std::sync::mpsc::channel();
    let g = graph.clone();
    std::thread::spawn(move || {
        let rt = crate::util::runtime();
        let big = "x".repeat(1 << 20);
        for _ in 0..32 {
            let _ = rt.block_on(g.publish_now("/chatter", "std_msgs/String", json!({"data": big})));
        }
        let _ = done.send(());
    });
    assert!(
        finished.recv_timeout(Duration::from_secs(120)).is_ok(),
        "publishing hangs on a subscriber that does not read"
    );
    drop(stalled);
    let echoed =
        crate::ros1::echoed_by_rostopic(graph.as_ref(), &rt, &home, "/chatter", "still here");
    assert!(echoed.contains("still here"), "{echoed}");
    drop(graph);
    drop(peers);
    let _ = std::fs::remove_dir_all(&home);
}

// ------------------------------------------------------------ property tests

/// An XML-RPC value of at most `depth` levels that writes and reads back exactly.
fn xvalue() -> impl Strategy<Value = XValue> {
    let leaf = prop_oneof![
        any::<i32>().prop_map(|i| XValue::Int(i.into())),
        any::<bool>().prop_map(XValue::Bool),
        (-1e12f64..1e12).prop_map(XValue::Double),
        ".{0,12}".prop_map(XValue::Str),
    ];
    leaf.prop_recursive(4, 48, 6, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..6).prop_map(XValue::Array),
            prop::collection::vec(("[a-z_]{1,8}", inner), 0..6).prop_map(XValue::Struct),
        ]
    })
}

/// XML-RPC-shaped text: tags, entities and words in any order.
fn xmlish() -> impl Strategy<Value = String> {
    let piece = prop_oneof![
        Just("<value>".to_string()),
        Just("</value>".to_string()),
        Just("<array><data>".to_string()),
        Just("</data></array>".to_string()),
        Just("<struct><member><name>".to_string()),
        Just("</name>".to_string()),
        Just("</member></struct>".to_string()),
        Just("<i4>".to_string()),
        Just("</i4>".to_string()),
        Just("<string/>".to_string()),
        Just("<methodCall><methodName>m</methodName><params><param>".to_string()),
        Just("<methodResponse><params><param>".to_string()),
        Just("&amp;".to_string()),
        Just("&#x110000;".to_string()),
        Just("&#;".to_string()),
        Just("&".to_string()),
        Just("<".to_string()),
        Just(">".to_string()),
        Just("<?xml?>".to_string()),
        "[a-z0-9 ]{0,6}",
    ];
    prop::collection::vec(piece, 0..300).prop_map(|v| v.concat())
}

/// The largest allocation `f` may make for `input_len` bytes of input: a constant
/// slack plus a small multiple of what was sent, never of what was declared.
fn bounded(input_len: usize) -> usize {
    4 * input_len + wire::FIRST_READ + (16 << 10)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn xmlrpc_reader_takes_any_text_without_panic_or_unbounded_memory(
        text in prop_oneof![xmlish(), any::<Vec<u8>>().prop_map(|b| String::from_utf8_lossy(&b).into_owned())]
    ) {
        let (_, largest) = crate::alloc::largest_allocation(|| {
            let _ = xmlrpc::parse_call(&text);
            let _ = xmlrpc::parse_response(&text);
        });
        prop_assert!(largest <= bounded(text.len()), "{largest} bytes for {} of input", text.len());
    }

    #[test]
    fn xmlrpc_values_read_back_as_written(params in prop::collection::vec(xvalue(), 0..4)) {
        let doc = xmlrpc::call_document("m", &params);
        prop_assert_eq!(xmlrpc::parse_call(&doc).unwrap(), ("m".to_string(), params));
    }

    #[test]
    fn xmlrpc_nesting_is_refused_past_its_bound_at_any_depth(depth in 0usize..3000) {
        let doc = format!(
            "<methodResponse><params><param>{}<value><i4>7</i4></value>{}</param></params></methodResponse>",
            "<value><array><data>".repeat(depth),
            "</data></array></value>".repeat(depth)
        );
        let (parsed, largest) = crate::alloc::largest_allocation(|| xmlrpc::parse_response(&doc));
        if depth <= xmlrpc::MAX_DEPTH {
            prop_assert!(parsed.is_ok(), "{parsed:?}");
        } else {
            prop_assert_eq!(parsed, Err(XmlRpcError::TooDeep));
        }
        prop_assert!(largest <= bounded(doc.len()));
    }

    #[test]
    fn tcpros_headers_of_any_bytes_and_any_declared_length_are_bounded(
        declared in prop_oneof![any::<u32>(), 0u32..4096, 4096u32..(128 << 20), Just(u32::MAX), Just(1 << 31)],
        body in prop::collection::vec(any::<u8>(), 0..4096),
    ) {
        let rt = tokio::runtime::Builder::new_current_thread().enable_time().build().unwrap();
        let bytes = [&declared.to_le_bytes()[..], &body].concat();
        let (read, largest) = crate::alloc::largest_allocation(|| {
            let mut input = &bytes[..];
            rt.block_on(wire::read_header(&mut input))
        });
        prop_assert!(largest <= bounded(bytes.len()), "{largest} bytes for a declared {declared}");
        match read {
            Ok(fields) => {
                prop_assert!(declared as usize <= body.len());
                prop_assert!(fields.len() <= wire::MAX_HEADER_FIELDS);
            }
            Err(WireError::TooLong { len, .. }) => prop_assert!(len > wire::MAX_HEADER),
            Err(_) => {}
        }
        let _ = wire::decode_header(&body);
    }

    #[test]
    fn tcpros_headers_read_back_as_written(
        fields in prop::collection::btree_map("[a-z_]{1,12}", ".{0,40}", 0..12)
    ) {
        let pairs: Vec<(&str, &str)> = fields.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
        let bytes = wire::encode_header(&pairs);
        prop_assert_eq!(wire::decode_header(&bytes[4..]).unwrap(), fields);
    }

    #[test]
    fn definitions_of_any_text_parse_or_fail_cleanly(text in ".{0,2000}", md5 in "[0-9a-f*]{0,32}") {
        let table = wire::table();
        let (_, largest) = crate::alloc::largest_allocation(|| {
            let _ = parse_message("p/msg/T", &text);
            let learnt = wire::learn(&table, "p/T", &text, &md5, &|n| table.has(n));
            if learnt.is_ok() {
                // Only what hashes to the md5sum sent is kept.
                assert_eq!(wire::md5sum(&table, "p/T").unwrap(), md5);
            }
        });
        prop_assert!(largest <= bounded(text.len()));
    }

    /// Types that nest each other at random (cycles, long chains, huge fixed arrays):
    /// learnt exactly when they are within the bounds and hash to the md5sum sent,
    /// refused otherwise, and never a stack overflow.
    #[test]
    fn adversarial_type_graphs_are_learnt_only_within_bounds(
        edges in prop::collection::vec(
            prop::collection::vec((0usize..48, prop_oneof![Just(""), Just("[]"), Just("[3]"), Just("[65536]"), Just("[4000000000]")]), 0..4),
            1..48,
        ),
        chain in 0usize..80,
    ) {
        // Type i nests the types its edges name; a chain of `chain` more types hangs
        // below the first.
        let n = edges.len();
        let mut sections = Vec::new();
        for (i, nested) in edges.iter().enumerate() {
            let mut body = String::from("int32 v\n");
            for (k, (j, shape)) in nested.iter().enumerate() {
                body.push_str(&format!("T{}{shape} f{k}\n", j % n));
            }
            if i == 0 && chain > 0 {
                body.push_str("C0 c\n");
            }
            sections.push((format!("evil/msg/T{i}"), body));
        }
        for k in 0..chain {
            let next = if k + 1 < chain { format!("C{} c\n", k + 1) } else { "int8 end\n".into() };
            sections.push((format!("evil/msg/C{k}"), next));
        }
        let text = sections
            .iter()
            .enumerate()
            .map(|(i, (name, body))| {
                if i == 0 {
                    body.clone()
                } else {
                    format!("{}\nMSG: {}\n{body}", "=".repeat(80), name.replace("/msg/", "/"))
                }
            })
            .collect::<Vec<_>>()
            .join("");
        // The md5sum an honest sender would give (the walk itself is bounded), else any.
        let plain: Vec<(&str, &str)> = sections.iter().map(|(a, b)| (a.as_str(), b.as_str())).collect();
        let scratch = Interfaces::of(&plain);
        let honest = scratch.as_ref().ok().and_then(|t| wire::md5sum(t, "evil/msg/T0").ok());
        let within = scratch.as_ref().is_ok_and(|t| {
            check_extent("evil/msg/T0", &|name: &str| t.message(name).ok()).is_ok()
        });
        let md5 = honest.clone().unwrap_or_else(|| "0123456789abcdef0123456789abcdef".into());
        let table = wire::table();
        let (learnt, largest) = crate::alloc::largest_allocation(|| {
            wire::learn(&table, "evil/T0", &text, &md5, &|name| table.has(name))
        });
        prop_assert_eq!(learnt.is_ok(), within && honest.is_some(), "{:?}", learnt);
        if learnt.is_err() {
            prop_assert!(!table.has("evil/msg/T0"), "a refused type was kept");
        }
        prop_assert!(largest <= bounded(text.len()));
        if chain + 1 > MAX_DEPTH {
            prop_assert!(learnt.is_err());
        }
    }
}
