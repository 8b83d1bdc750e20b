//! The robot the front ends act on: joining ROS 2 (and starting the built-in sim) or
//! ROS 1's master, the
//! guarded graph every tool goes through (`ros::boundary`: the deny-list, the e-stop, the
//! motion limits, the mux), the tools that come with it, and the e-stop's ROS trigger
//! (`/ferrosa/estop`, std_msgs/msg/Bool: `true` engages it, from any node or teleop).

use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::estop::EStop;
use crate::limits::Motion;
use crate::ros::boundary::Guarded;
use crate::ros::ros1::{Ros1Graph, Ros1Options};
use crate::ros::ros2::{Ros2Graph, Ros2Options};
use crate::ros::sim::{Sim, ARENA};
use crate::ros::RosGraph;
use crate::tool::{Policy, Registry};

/// The topic any node publishes `true` on to engage the e-stop.
pub(crate) const ESTOP_TOPIC: &str = "/ferrosa/estop";

/// Who engaged the e-stop when a node published on `ESTOP_TOPIC` (the e-stop's source).
pub(crate) fn estop_topic_source() -> String {
    format!("a ROS node on {ESTOP_TOPIC}")
}

/// Which tools a request's prompt lists (`AgentConfig::listing_budget_tokens`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Listing {
    /// Every tool, in one order, once: the prompt before the request is the same for
    /// every request and stays in the cache (the request is followed by the names of
    /// the tools that fit it; each step may still call only those).
    All,
    /// Only the tools offered for the request: a shorter prompt, evaluated anew for
    /// each request.
    Offered,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Robot {
    None,
    Sim,
    Ros2,
    Ros1,
    /// The built-in sim served on ROS 1 (a roscore at `ROS_MASTER_URI`), reached over
    /// ROS 1.
    SimRos1,
}

impl Robot {
    /// The built-in sim, over either ROS.
    pub(crate) fn is_sim(self) -> bool {
        matches!(self, Robot::Sim | Robot::SimRos1)
    }
}

/// What keeps the robot connection alive for the agent's lifetime.
pub struct RobotLink {
    pub graph: Option<Arc<dyn RosGraph>>,
    pub sim: Option<Sim>,
    /// ROS 1: unregisters from the master when the link goes.
    pub ros1: Option<crate::ros::ros1::Leave>,
    /// `sim-ros1`: the sim's node served on ROS 1.
    pub bridge: Option<crate::ros::ros1::bridge::Bridge>,
}

impl RobotLink {
    /// No robot.
    pub fn none() -> RobotLink {
        RobotLink {
            graph: None,
            sim: None,
            ros1: None,
            bridge: None,
        }
    }
}

/// Join ROS 2 (and start the sim first when asked), then wait until the graph shows it;
/// `verbose` reports the discovery on stderr.
pub fn connect(robot: Robot, verbose: bool) -> anyhow::Result<RobotLink> {
    if robot == Robot::None {
        return Ok(RobotLink::none());
    }
    if robot == Robot::Ros1 {
        return connect_ros1(verbose);
    }
    if robot == Robot::SimRos1 {
        return connect_sim_ros1(verbose);
    }
    let opts = Ros2Options::from_env()?;
    let start = Instant::now();
    // The agent's participant first: RustDDS peers discover a publishing sim late.
    let graph = Arc::new(Ros2Graph::start(
        &opts,
        &format!("_ferrosa_{}", std::process::id()),
    )?);
    let sim = if robot == Robot::Sim {
        Some(Sim::start(&opts)?)
    } else {
        None
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()?;
    let limit = Duration::from_secs(if robot == Robot::Sim { 15 } else { 4 });
    let found = rt.block_on(async {
        loop {
            let g = graph.graph().await.unwrap_or_default();
            let ready = match robot {
                Robot::Sim => Sim::discovered_in(&g),
                _ => !g.nodes.is_empty() && start.elapsed() > Duration::from_secs(2),
            };
            if ready || start.elapsed() > limit {
                return (ready, g.nodes.len());
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    });
    match found {
        (true, _) if !verbose => {}
        (true, n) => eprintln!("robot: {n} ROS node(s) discovered in {} ms (domain {}, {:?})", start.elapsed().as_millis(), opts.domain_id, opts.range),
        (false, _) if robot == Robot::Sim => anyhow::bail!("the built-in sim did not appear on ROS 2 within {limit:?}; run with FERROSA_LOG=rustdds=warn to see why"),
        (false, _) => eprintln!("robot: no ROS 2 node found within {limit:?} (domain {}, {:?}); check ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE", opts.domain_id, opts.range),
    }
    Ok(RobotLink {
        graph: Some(graph as Arc<dyn RosGraph>),
        sim,
        ros1: None,
        bridge: None,
    })
}

/// Register with ROS 1's master (`ROS_MASTER_URI`): an error when it cannot be reached.
fn connect_ros1(verbose: bool) -> anyhow::Result<RobotLink> {
    let opts = Ros1Options::from_env();
    let start = Instant::now();
    let graph = Ros1Graph::start(&opts, "ferrosa")?;
    if verbose {
        let nodes = crate::ros::graph_now(&graph).map_or(0, |g| g.nodes.len());
        eprintln!(
            "robot: {nodes} ROS 1 node(s) from the master at {} in {} ms",
            opts.master_uri,
            start.elapsed().as_millis()
        );
    }
    Ok(RobotLink {
        ros1: Some(graph.leave_on_drop()),
        graph: Some(Arc::new(graph)),
        sim: None,
        bridge: None,
    })
}

/// Start the sim (ROS 2, in this process), serve its node on ROS 1, and join ROS 1 to
/// reach it; ready when ROS 1's graph shows the sim's pose topic and `/spawn`.
fn connect_sim_ros1(verbose: bool) -> anyhow::Result<RobotLink> {
    let start = Instant::now();
    let source = connect(Robot::Sim, false)?;
    let ros2 = source.graph.clone().expect("the sim has a graph");
    let opts = Ros1Options::from_env();
    let bridge = crate::ros::ros1::bridge::Bridge::start(ros2, "/turtlesim", &opts)?;
    let graph = Ros1Graph::start(&opts, "ferrosa")?;
    let ready = |g: &crate::ros::Graph| {
        let by_sim = |n: &Option<String>| n.as_deref() == Some("/turtlesim");
        g.publishers
            .iter()
            .any(|p| p.topic == "/turtle1/pose" && by_sim(&p.node))
            && g.servers
                .iter()
                .any(|s| s.service == "/spawn" && by_sim(&s.node))
    };
    while !crate::ros::graph_now(&graph).is_some_and(|g| ready(&g)) {
        if start.elapsed() > Duration::from_secs(20) {
            anyhow::bail!(
                "the sim did not appear on ROS 1 at {} within 20 s",
                opts.master_uri
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    if verbose {
        eprintln!(
            "robot: the sim on ROS 1 at {} in {} ms",
            opts.master_uri,
            start.elapsed().as_millis()
        );
    }
    Ok(RobotLink {
        ros1: Some(graph.leave_on_drop()),
        graph: Some(Arc::new(graph)),
        sim: source.sim,
        bridge: Some(bridge),
    })
}

/// The built-in sim's motion wiring, where the policy file says nothing: its velocity
/// topic goes through its mux (the operator's `/turtle1/cmd_vel` over the agent's
/// `/turtle1/cmd_vel_agent`), and absolute teleports stay in the arena.
pub(crate) fn sim_motion(mut m: Motion) -> Motion {
    if m.velocity_topics.is_empty() {
        m.velocity_topics = vec!["/turtle1/cmd_vel".into()];
    }
    if m.mux.is_empty() {
        m.mux
            .insert("/turtle1/cmd_vel".into(), "/turtle1/cmd_vel_agent".into());
    }
    if m.mux_status.is_none() {
        m.mux_status = Some("/turtle1/cmd_vel_mux/active".into());
    }
    if m.workspace.is_none() {
        m.workspace = Some([0.0, 0.0, ARENA, ARENA]);
    }
    m
}

/// The graph the tools get: `raw` behind the policy's fence, e-stop and motion limits
/// (with the sim's wiring when it is the sim). The ROS e-stop trigger is followed on
/// `raw` from here on.
pub fn guard(raw: Arc<dyn RosGraph>, policy: &Policy, robot: Robot) -> Arc<dyn RosGraph> {
    let motion = match robot {
        r if r.is_sim() => sim_motion(policy.motion.clone()),
        _ => policy.motion.clone(),
    };
    follow_estop_topic(raw.clone(), policy.estop().clone());
    Guarded::new(raw, policy.fence().clone(), policy.estop().clone(), motion)
}

/// Engage `estop` whenever a node publishes `true` on `/ferrosa/estop`.
fn follow_estop_topic(raw: Arc<dyn RosGraph>, estop: Arc<EStop>) {
    super::on_own_thread("estop-topic", move || async move {
        let mut rx = match raw.watch(ESTOP_TOPIC, "std_msgs/msg/Bool").await {
            Ok(rx) => rx,
            Err(e) => {
                tracing::error!("cannot follow {ESTOP_TOPIC}: {e}");
                return;
            }
        };
        while let Some(v) = rx.recv().await {
            if v["data"] == true {
                estop.trigger(&estop_topic_source());
            }
        }
    });
}

/// The ROS tools over `graph` (already guarded), and the turtle's own for the sim.
pub(crate) fn add_ros_tools(registry: &mut Registry, graph: Arc<dyn RosGraph>, robot: Robot) {
    registry.add(crate::tools::ros::package(graph.clone()));
    if robot.is_sim() {
        registry.add(crate::tools::turtle::package(graph, "turtle1"));
    }
}
