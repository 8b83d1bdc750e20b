//! The built-in robot: a turtlesim-compatible node over real DDS, so the agent (and any
//! ROS 2 tool) has something to act on with no ROS installed.
//!
//! Node `/turtlesim` with what turtlesim offers: per turtle `<t>/cmd_vel`
//! (geometry_msgs/Twist, held for 1 s as turtlesim does), `<t>/pose` (turtlesim/Pose),
//! `<t>/color_sensor` (turtlesim/Color), `<t>/set_pen`, `<t>/teleport_absolute`,
//! `<t>/teleport_relative`, the `<t>/rotate_absolute` action; `/spawn`, `/kill`,
//! `/reset`, `/clear`; parameters
//! `background_r/g/b`; the same kinematics in the same 11.09 × 11.09 arena, with a log
//! line on `/rosout` when a turtle hits the wall. And what a field robot has for status
//! questions: `/battery_state` (sensor_msgs/BatteryState, draining faster while moving)
//! and `/diagnostics` (diagnostic_msgs/DiagnosticArray). And what a Nav2 robot offers
//! for going places: the `/navigate_to_pose` action (`navigate`), driving turtle1.
//!
//! Messages are built as JSON and encoded by `cdr`, the same codec the tools use.

mod navigate;
mod rotate;
mod world;

pub use navigate::{ACTION as NAVIGATE_ACTION, FRAME as NAVIGATE_FRAME};
use world::{normalize_angle, Command, Shared, Turtle, World, INPUTS, PUBLISH_AFTER, STEP};
pub use world::{ARENA, CENTER};

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ros2_client::log::LogLevel;
use ros2_client::parameters::ParameterValue;
use ros2_client::qos::{Durability as QDurability, Reliability as QReliability};
use ros2_client::{
    Context, MessageTypeName, Node, NodeName, NodeOptions, ServiceMapping, ServiceTypeName,
};
use serde_json::{json, Value};
use tokio::task::JoinHandle;

use super::cdr;
use super::graph::Graph;
use super::ros2::{background, context, reliable_qos, ros_name, split_type, Raw, Ros2Options};
use super::{Interfaces, RosError};

/// A running sim; dropping it stops the robot.
pub struct Sim {
    shared: Arc<Shared>,
    tasks: Vec<JoinHandle<()>>,
    _context: Context,
}

impl Drop for Sim {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
        for ts in self.shared.world.lock().expect("world").tasks.values() {
            for t in ts {
                t.abort();
            }
        }
    }
}

fn err(what: &str, e: impl std::fmt::Debug) -> RosError {
    RosError::Other(format!("sim: {what}: {e:?}"))
}

impl Sim {
    /// Start `/turtlesim` with `turtle1` at the centre.
    pub fn start(opts: &Ros2Options) -> Result<Sim, RosError> {
        let context = context(opts)?;
        let node_name = NodeName::new("/", "turtlesim").map_err(|e| err("node name", e))?;
        let options = NodeOptions::new()
            .enable_rosout(true)
            .declare_parameter("background_r", ParameterValue::Integer(69))
            .declare_parameter("background_g", ParameterValue::Integer(86))
            .declare_parameter("background_b", ParameterValue::Integer(255));
        let mut node = context
            .new_node(node_name, options)
            .map_err(|e| err("node", e))?;
        let rt = background();
        let spinner = node.spinner().map_err(|e| err("spinner", e))?;
        let mut tasks = vec![rt.spawn(async move {
            let _ = spinner.spin().await;
        })];
        let log = node.logging_handle();
        let shared = Arc::new(Shared {
            world: Mutex::new(World {
                turtles: BTreeMap::new(),
                rotations: BTreeMap::new(),
                navigations: BTreeMap::new(),
                battery: 0.87,
                tasks: BTreeMap::new(),
            }),
            interfaces: Interfaces::bundled(),
            log,
            node: tokio::sync::Mutex::new(node),
            background: Mutex::new([69, 86, 255]),
        });
        {
            let mut node = shared.node.try_lock().expect("new node is free");
            for (service, ty) in [
                ("/spawn", "turtlesim/srv/Spawn"),
                ("/kill", "turtlesim/srv/Kill"),
                ("/reset", "std_srvs/srv/Empty"),
                ("/clear", "std_srvs/srv/Empty"),
            ] {
                tasks.push(serve(&rt, &shared, &mut node, service, ty, None)?);
            }
            add_turtle(
                &rt,
                &shared,
                &mut node,
                "turtle1",
                Turtle::at(CENTER, CENTER, 0.0),
            )?;
            tasks.push(status_publishers(&rt, &shared, &mut node)?);
            tasks.extend(navigate::serve(&rt, &shared, &mut node)?);
        }
        tasks.push(rt.spawn(physics(shared.clone())));
        shared.log(
            LogLevel::Info,
            "Starting turtlesim with node name /turtlesim",
        );
        shared.log(
            LogLevel::Info,
            &format!("Spawning turtle [turtle1] at x=[{CENTER}], y=[{CENTER}], theta=[0.0]"),
        );
        Ok(Sim {
            shared,
            tasks,
            _context: context,
        })
    }

    /// Whether a graph shows the sim as a client sees it once discovery settles: the node,
    /// its pose topic and `/spawn` service, and the rotate action attributed to the node
    /// (its endpoints and the node's entity list arrive separately, in either order).
    pub fn discovered_in(g: &Graph) -> bool {
        let attributed = |e: &Option<String>| e.as_deref() == Some("/turtlesim");
        g.nodes.iter().any(|n| n == "/turtlesim")
            && g.publishers
                .iter()
                .any(|p| p.topic == "/turtle1/pose" && attributed(&p.node))
            && g.servers
                .iter()
                .any(|s| s.service == "/spawn" && attributed(&s.node))
            && g.actions().iter().any(|a| {
                a.action == "/turtle1/rotate_absolute"
                    && a.servers.iter().any(|n| n == "/turtlesim")
            })
    }

    /// A turtle's pose as `turtle/msg/Pose` JSON, read directly (tests, benches).
    pub fn pose(&self, turtle: &str) -> Option<Value> {
        self.shared
            .world
            .lock()
            .expect("world")
            .turtles
            .get(turtle)
            .map(Turtle::pose)
    }
}

/// The integrator: turtlesim's update loop at 62.5 Hz.
/// Follow one velocity input of `name`'s mux (`<name>/<topic>`, geometry_msgs/Twist).
fn follow_velocity(
    rt: &tokio::runtime::Handle,
    shared: &Arc<Shared>,
    node: &mut Node,
    name: &str,
    topic: &str,
    input: usize,
) -> Result<JoinHandle<()>, RosError> {
    let qos = reliable_qos(QDurability::Volatile, 10);
    let t = node
        .create_topic(
            &ros_name(&format!("/{name}/{topic}"))?,
            message_type("geometry_msgs/msg/Twist")?,
            &qos,
        )
        .map_err(|e| err(topic, e))?;
    // Best effort reads what reliable and best-effort writers (teleop tools) both send.
    let sub = node
        .create_subscription::<Raw>(&t, Some(qos.reliability(QReliability::BestEffort)))
        .map_err(|e| err(topic, e))?;
    let (s, who) = (shared.clone(), name.to_string());
    Ok(rt.spawn(async move {
        loop {
            let Ok((raw, _)) = sub.async_take().await else {
                continue;
            };
            let Ok(twist) = cdr::decode(&s.interfaces, "geometry_msgs/msg/Twist", &raw.0, 0) else {
                continue;
            };
            let mut world = s.world.lock().expect("world");
            let Some(t) = world.turtles.get_mut(&who) else {
                break;
            };
            t.inputs[input] = Some(Command {
                linear: twist["linear"]["x"].as_f64().unwrap_or(0.0),
                angular: twist["angular"]["z"].as_f64().unwrap_or(0.0),
                at: Instant::now(),
            });
        }
    }))
}

/// Publish which mux input drives `name` (`<name>/cmd_vel_mux/active`, std_msgs/String:
/// "teleop", "agent" or "none"; latched), whenever it changes.
fn report_mux(
    rt: &tokio::runtime::Handle,
    shared: &Arc<Shared>,
    node: &mut Node,
    name: &str,
) -> Result<JoinHandle<()>, RosError> {
    let qos = reliable_qos(QDurability::TransientLocal, 1);
    let topic = format!("/{name}/cmd_vel_mux/active");
    let t = node
        .create_topic(
            &ros_name(&topic)?,
            message_type("std_msgs/msg/String")?,
            &qos,
        )
        .map_err(|e| err("mux status", e))?;
    let publisher = node
        .create_publisher::<Raw>(&t, Some(qos))
        .map_err(|e| err("mux status", e))?;
    let (s, who) = (shared.clone(), name.to_string());
    Ok(rt.spawn(async move {
        let mut last: Option<&str> = None;
        let mut tick = tokio::time::interval(STEP);
        loop {
            tick.tick().await;
            let active = {
                let world = s.world.lock().expect("world");
                let Some(t) = world.turtles.get(&who) else {
                    break;
                };
                t.active(Instant::now()).map_or("none", |i| INPUTS[i].1)
            };
            if last != Some(active) {
                last = Some(active);
                let msg = encode(&s, "std_msgs/msg/String", &json!({"data": active}));
                let _ = publisher.async_publish(msg).await;
            }
        }
    }))
}

async fn physics(shared: Arc<Shared>) {
    let mut tick = tokio::time::interval(STEP);
    let mut last = Instant::now();
    loop {
        tick.tick().await;
        let now = Instant::now();
        let dt = now.duration_since(last).as_secs_f64();
        last = now;
        let mut hits = Vec::new();
        {
            let mut world = shared.world.lock().expect("world");
            let mut moving = 0.0;
            for (name, t) in world.turtles.iter_mut() {
                if t.step(dt, now) {
                    hits.push(name.clone());
                }
                moving += t.linear.abs() + t.angular.abs();
            }
            // About 3 hours idle, faster while moving.
            world.battery = (world.battery - dt * (1.0e-4 + 4.0e-4 * moving.min(4.0))).max(0.0);
        }
        for name in hits {
            shared.log(
                LogLevel::Warn,
                &format!("Oh no! I hit the wall! (Clamping from [{name}])"),
            );
        }
    }
}

fn message_type(ty: &str) -> Result<MessageTypeName, RosError> {
    let (pkg, _, short) = split_type(ty)?;
    Ok(MessageTypeName::new(&pkg, &short))
}

fn publisher(
    node: &mut Node,
    topic: &str,
    ty: &str,
) -> Result<ros2_client::Publisher<Raw>, RosError> {
    let qos = reliable_qos(QDurability::Volatile, 10);
    let t = node
        .create_topic(&ros_name(topic)?, message_type(ty)?, &qos)
        .map_err(|e| err(topic, e))?;
    node.create_publisher::<Raw>(&t, Some(qos))
        .map_err(|e| err(topic, e))
}

fn encode(shared: &Shared, ty: &str, v: &Value) -> Raw {
    Raw(cdr::encode(&shared.interfaces, ty, v, 0).expect("the sim's own messages encode"))
}

/// Pose, colour sensor and cmd_vel for one turtle, and its three services.
fn add_turtle(
    rt: &tokio::runtime::Handle,
    shared: &Arc<Shared>,
    node: &mut Node,
    name: &str,
    turtle: Turtle,
) -> Result<(), RosError> {
    // In the world before its tasks start: each ends when it finds the turtle gone.
    shared
        .world
        .lock()
        .expect("world")
        .turtles
        .insert(name.to_string(), turtle);
    match turtle_tasks(rt, shared, node, name) {
        Ok(tasks) => {
            let mut world = shared.world.lock().expect("world");
            world.tasks.insert(name.to_string(), tasks);
            Ok(())
        }
        Err(e) => {
            shared.world.lock().expect("world").turtles.remove(name);
            Err(e)
        }
    }
}

/// The tasks that serve one turtle (already in the world).
fn turtle_tasks(
    rt: &tokio::runtime::Handle,
    shared: &Arc<Shared>,
    node: &mut Node,
    name: &str,
) -> Result<Vec<JoinHandle<()>>, RosError> {
    let pose = publisher(node, &format!("/{name}/pose"), "turtlesim/msg/Pose")?;
    let color = publisher(
        node,
        &format!("/{name}/color_sensor"),
        "turtlesim/msg/Color",
    )?;
    let mut tasks = Vec::new();
    let (s, who) = (shared.clone(), name.to_string());
    tasks.push(rt.spawn(async move {
        // Poses at 31 Hz (turtlesim sends one per update; half is plenty on 2 cores).
        // RustDDS (0.15.1) peers that receive a writer's data before its discovery
        // announcement may never list that writer: give discovery a head start.
        tokio::time::sleep(PUBLISH_AFTER).await;
        let mut tick = tokio::time::interval(STEP * 2);
        loop {
            tick.tick().await;
            let p = s
                .world
                .lock()
                .expect("world")
                .turtles
                .get(&who)
                .map(Turtle::pose);
            let Some(p) = p else { break };
            let _ = pose
                .async_publish(encode(&s, "turtlesim/msg/Pose", &p))
                .await;
            let [r, g, b] = *s.background.lock().expect("background");
            let color_msg = encode(&s, "turtlesim/msg/Color", &json!({"r": r, "g": g, "b": b}));
            let _ = color.async_publish(color_msg).await;
        }
    }));
    for (input, (topic, _)) in INPUTS.iter().enumerate() {
        tasks.push(follow_velocity(rt, shared, node, name, topic, input)?);
    }
    tasks.push(report_mux(rt, shared, node, name)?);
    for (svc, ty) in [
        ("set_pen", "turtlesim/srv/SetPen"),
        ("teleport_absolute", "turtlesim/srv/TeleportAbsolute"),
        ("teleport_relative", "turtlesim/srv/TeleportRelative"),
    ] {
        tasks.push(serve(
            rt,
            shared,
            node,
            &format!("/{name}/{svc}"),
            ty,
            Some(name),
        )?);
    }
    tasks.extend(rotate::serve(rt, shared, node, name)?);
    Ok(tasks)
}

/// Battery and diagnostics at 1 Hz.
fn status_publishers(
    rt: &tokio::runtime::Handle,
    shared: &Arc<Shared>,
    node: &mut Node,
) -> Result<JoinHandle<()>, RosError> {
    let battery = publisher(node, "/battery_state", "sensor_msgs/msg/BatteryState")?;
    let diagnostics = publisher(node, "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")?;
    let s = shared.clone();
    Ok(rt.spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        loop {
            tick.tick().await;
            let (pct, turtles) = {
                let w = s.world.lock().expect("world");
                (w.battery, w.turtles.len())
            };
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap_or_default();
            let stamp = json!({"sec": now.as_secs(), "nanosec": now.subsec_nanos()});
            let _ = battery.async_publish(encode(&s, "sensor_msgs/msg/BatteryState", &json!({
                "header": {"stamp": stamp, "frame_id": "base_link"},
                "voltage": 10.5 + 2.1 * pct, "current": -1.2, "charge": 5.2 * pct, "capacity": 5.2,
                "design_capacity": 5.2, "percentage": pct, "power_supply_status": 2,
                "power_supply_health": 1, "power_supply_technology": 3, "present": true,
                "location": "base", "serial_number": "TS-0001"
            }))).await;
            let (level, message) = if pct < 0.2 { (1, "battery low") } else { (0, "ok") };
            let _ = diagnostics.async_publish(encode(&s, "diagnostic_msgs/msg/DiagnosticArray", &json!({
                "header": {"stamp": stamp},
                "status": [
                    {"level": level, "name": "turtlesim: battery", "message": message, "hardware_id": "battery0",
                     "values": [{"key": "percentage", "value": format!("{:.1}", pct * 100.0)}]},
                    {"level": 0, "name": "turtlesim: motors", "message": "ok", "hardware_id": "motors",
                     "values": [{"key": "turtles", "value": turtles.to_string()}]}
                ]
            }))).await;
        }
    }))
}

/// Serve one service; requests and responses go through the codec as JSON.
fn serve(
    rt: &tokio::runtime::Handle,
    shared: &Arc<Shared>,
    node: &mut Node,
    service: &str,
    ty: &str,
    turtle: Option<&str>,
) -> Result<JoinHandle<()>, RosError> {
    let (pkg, _, short) = split_type(ty)?;
    let qos = reliable_qos(QDurability::Volatile, 10);
    let server = node
        .create_server::<Raw, Raw>(
            ServiceMapping::Enhanced,
            &ros_name(service)?,
            &ServiceTypeName::new(&pkg, &short),
            qos.clone(),
            qos,
        )
        .map_err(|e| err(service, e))?;
    let (s, ty, service, turtle) = (
        shared.clone(),
        ty.to_string(),
        service.to_string(),
        turtle.map(str::to_string),
    );
    let rt2 = rt.clone();
    Ok(rt.spawn(async move {
        loop {
            let Ok((id, raw)) = server.async_receive_request().await else {
                continue;
            };
            let request = cdr::decode(&s.interfaces, &format!("{ty}_Request"), &raw.0, 0)
                .unwrap_or(json!({}));
            let response = handle(&rt2, &s, &service, turtle.as_deref(), &request).await;
            let bytes = cdr::encode(&s.interfaces, &format!("{ty}_Response"), &response, 0)
                .expect("the sim's own responses encode");
            let _ = server.async_send_response(id, Raw(bytes)).await;
        }
    }))
}

fn f(v: &Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or(0.0)
}

async fn handle(
    rt: &tokio::runtime::Handle,
    s: &Arc<Shared>,
    service: &str,
    turtle: Option<&str>,
    req: &Value,
) -> Value {
    let name = service.rsplit('/').next().unwrap_or_default();
    if let Some(who) = turtle {
        turtle_service(s, who, name, req);
        return json!({});
    }
    match name {
        "spawn" => spawn(rt, s, req).await,
        "kill" => {
            let who = req["name"].as_str().unwrap_or("");
            let removed = {
                let mut world = s.world.lock().expect("world");
                world.turtles.remove(who);
                world.tasks.remove(who)
            };
            match removed {
                Some(tasks) => tasks.iter().for_each(JoinHandle::abort),
                None => s.log(
                    LogLevel::Error,
                    &format!("Tried to kill turtle [{who}], which does not exist"),
                ),
            }
            json!({})
        }
        "reset" => reset(rt, s).await,
        "clear" => {
            s.log(LogLevel::Info, "Clearing turtlesim.");
            json!({})
        }
        _ => json!({}),
    }
}

/// A turtle's own service (`/<turtle>/set_pen`, `teleport_absolute`, `teleport_relative`).
fn turtle_service(s: &Shared, who: &str, name: &str, req: &Value) {
    let mut world = s.world.lock().expect("world");
    let Some(t) = world.turtles.get_mut(who) else {
        return;
    };
    match name {
        "set_pen" => t.pen_on = req["off"].as_u64().unwrap_or(0) == 0,
        "teleport_absolute" => {
            t.x = f(req, "x").clamp(0.0, ARENA);
            t.y = f(req, "y").clamp(0.0, ARENA);
            t.theta = normalize_angle(f(req, "theta"));
        }
        "teleport_relative" => {
            t.theta = normalize_angle(t.theta + f(req, "angular"));
            t.x = (t.x + t.theta.cos() * f(req, "linear")).clamp(0.0, ARENA);
            t.y = (t.y + t.theta.sin() * f(req, "linear")).clamp(0.0, ARENA);
        }
        _ => {}
    }
}

/// `/spawn`: a new turtle (named, or the first free `turtleN`); an empty name when the
/// name is taken.
async fn spawn(rt: &tokio::runtime::Handle, s: &Arc<Shared>, req: &Value) -> Value {
    let mut who = req["name"].as_str().unwrap_or("").to_string();
    {
        let world = s.world.lock().expect("world");
        if who.is_empty() {
            who = (2..)
                .map(|i| format!("turtle{i}"))
                .find(|n| !world.turtles.contains_key(n))
                .expect("a free name");
        } else if world.turtles.contains_key(&who) {
            drop(world);
            s.log(
                LogLevel::Error,
                &format!("A turtle named [{who}] already exists"),
            );
            return json!({"name": ""});
        }
    }
    let turtle = Turtle::at(
        f(req, "x").clamp(0.0, ARENA),
        f(req, "y").clamp(0.0, ARENA),
        f(req, "theta"),
    );
    let mut node = s.node.lock().await;
    if let Err(e) = add_turtle(rt, s, &mut node, &who, turtle) {
        s.log(LogLevel::Error, &format!("spawn {who}: {e}"));
        return json!({"name": ""});
    }
    s.log(
        LogLevel::Info,
        &format!(
            "Spawning turtle [{who}] at x=[{}], y=[{}], theta=[{}]",
            f(req, "x"),
            f(req, "y"),
            f(req, "theta")
        ),
    );
    json!({"name": who})
}

/// `/reset`: turtle1 alone, at the centre; goals under way end.
async fn reset(rt: &tokio::runtime::Handle, s: &Arc<Shared>) -> Value {
    let others: Vec<String> = {
        let mut world = s.world.lock().expect("world");
        let others: Vec<String> = world
            .turtles
            .keys()
            .filter(|n| *n != "turtle1")
            .cloned()
            .collect();
        for n in &others {
            world.turtles.remove(n);
            if let Some(tasks) = world.tasks.remove(n) {
                tasks.iter().for_each(JoinHandle::abort);
            }
        }
        world
            .turtles
            .insert("turtle1".into(), Turtle::at(CENTER, CENTER, 0.0));
        // Goals under way end (aborted) with the turtles they turned.
        world.rotations.clear();
        world.navigations.clear();
        others
    };
    let turtle1_running = s.world.lock().expect("world").tasks.contains_key("turtle1");
    if !turtle1_running {
        let mut node = s.node.lock().await;
        let _ = add_turtle(rt, s, &mut node, "turtle1", Turtle::at(CENTER, CENTER, 0.0));
    }
    s.log(
        LogLevel::Info,
        &format!("Resetting turtlesim (removed {} turtles)", others.len()),
    );
    json!({})
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_second_at_one_metre_per_second_moves_one_metre() {
        let start = Instant::now();
        let mut t = Turtle::at(CENTER, CENTER, 0.0);
        t.inputs[1] = Some(Command {
            linear: 1.0,
            angular: 0.0,
            at: start,
        });
        let mut now = start;
        for _ in 0..62 {
            now += STEP;
            t.step(STEP.as_secs_f64(), now);
        }
        assert!((t.x - (CENTER + 0.992)).abs() < 1e-9, "{}", t.x);
        // The command expires after a second.
        now += Duration::from_millis(200);
        t.step(0.2, now);
        assert_eq!(t.linear, 0.0);
    }

    #[test]
    fn the_operators_input_wins_over_the_agents() {
        let now = Instant::now();
        let mut t = Turtle::at(CENTER, CENTER, 0.0);
        let command = |linear: f64, at: Instant| {
            Some(Command {
                linear,
                angular: 0.0,
                at,
            })
        };
        t.inputs[1] = command(1.0, now);
        t.inputs[0] = command(-0.5, now);
        t.step(0.1, now);
        assert_eq!((t.active(now), t.linear), (Some(0), -0.5));
        // Once the operator's command is older than the hold, the agent's drives again.
        t.inputs[1] = command(1.0, now + Duration::from_millis(1100));
        let later = now + Duration::from_millis(1200);
        t.step(0.1, later);
        assert_eq!((t.active(later), t.linear), (Some(1), 1.0));
    }

    #[test]
    fn turning_wraps_and_walls_clamp() {
        let now = Instant::now();
        let mut t = Turtle::at(CENTER, CENTER, 3.0);
        t.inputs[1] = Some(Command {
            linear: 0.0,
            angular: 1.0,
            at: now,
        });
        t.step(0.5, now);
        assert!((t.theta - (3.5 - 2.0 * std::f64::consts::PI)).abs() < 1e-9);
        let mut t = Turtle::at(11.0, CENTER, 0.0);
        t.inputs[0] = Some(Command {
            linear: 2.0,
            angular: 0.0,
            at: now,
        });
        assert!(t.step(0.5, now));
        assert_eq!(t.x, ARENA);
    }
}
