//! `ferrosa serve`: the operator's console in a web page, served by this process (the
//! page's files are built into the binary; nothing is fetched from elsewhere).
//!
//! The agent runs on a thread of its own, one request at a time; every client sees the
//! same session: the requests, the answer as it is written, the trace (each call with
//! its arguments, decision, result and time), the approvals the policy asks for, the
//! e-stop's state and the robot's pose. The e-stop button reaches the same e-stop as the
//! REPL, the ROS topic and the model's `robot_stop`.
//!
//! Served on loopback by default. Every address needs the console's secret, loopback
//! included (`ui::secret`: any local process can reach loopback, and only the operator
//! may drive the robot): drawn at start (or taken from `FERROSA_CONSOLE_TOKEN`), kept in
//! a file only the user can read, sent as a bearer token or kept by the browser as an
//! HttpOnly cookie once the printed address (its login code works once) was opened;
//! requests without it are refused. A request that asks to stop engages the e-stop the
//! moment it arrives, whatever the agent is doing.
//!
//! Layout:
//! - `ears`: speech: recordings transcribed, answers spoken
//! - `hub`: the shared session (events, approvals, trail, busy)
//! - `http`: the routes, the SSE stream, the request checks (host, origin, token)
//! - `memory`: the memory panel (places, facts, latest requests) and what it deletes
//! - `pose`: the robot view's pose, read from a topic
//! - `worker`: the agent's thread and the jobs it takes

mod ears;
mod http;
pub mod hub;
mod memory;
pub mod pose;
mod worker;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use serde_json::{json, Value};

use super::agent::{build_with, connect, AgentArgs};
use crate::agent::Agent;
use crate::estop::EStop;
use crate::reading::language::Language;
use crate::ui::secret::Secret;
use hub::Hub;
use pose::View;

/// The environment variable that sets the console's secret (else one is drawn at start).
pub(crate) const TOKEN_ENV: &str = "FERROSA_CONSOLE_TOKEN";

#[derive(Debug, Clone)]
pub struct ServeArgs {
    pub agent: AgentArgs,
    pub bind: SocketAddr,
    /// The topic the robot view reads the pose from (the sim's by default).
    pub pose_topic: Option<String>,
}

/// `ferrosa serve` (see the module header).
pub fn run(args: &ServeArgs) -> anyhow::Result<()> {
    let mut agent_args = args.agent.clone();
    if agent_args.trace_dir.is_none() {
        agent_args.trace_dir = crate::dirs::traces_dir();
    }
    let estop = EStop::new();
    let cancel = Arc::new(AtomicBool::new(false));
    let hub = Hub::new(estop.clone(), cancel.clone());
    let robot = connect(agent_args.robot, true)?;
    let mut agent = build_with(&agent_args, hub.clone(), robot.graph.clone(), estop.clone())?
        .with_cancel(cancel.clone());
    if let Ok(store) = super::agent::open_memory(&agent_args) {
        let session = super::agent::new_session();
        agent.set_journal(super::agent::journal(store, session, agent.fence().clone()));
    }
    if let Some(g) = &robot.graph {
        g.set_fence(agent.fence().clone());
    }
    hub.set_fence(agent.fence().clone());
    let memory = memory::Memory::new(
        super::agent::open_memory(&agent_args),
        super::agent::robot_places(&agent_args)?,
        agent.fence().clone(),
    );
    let view = view(args, &agent)?;
    let info = info(&agent, &agent_args, view.as_ref());
    let trace = agent.trace_path().map(PathBuf::from);
    let (jobs, queue) = std::sync::mpsc::channel();
    let worker = {
        let hub = hub.clone();
        std::thread::Builder::new()
            .name("agent".into())
            .spawn(move || worker::work(agent, &hub, &queue))?
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let served = rt.block_on(async {
        let listener = tokio::net::TcpListener::bind(args.bind)
            .await
            .with_context(|| format!("binding {}: is another console running there? choose another with --bind", args.bind))?;
        let addr = listener.local_addr()?;
        let secret = Arc::new(Secret::create(TOKEN_ENV, &format!("console-{}", addr.port()))?);
        let login = crate::ui::secret::random_hex(16)
            .context("drawing the console's login code from /dev/urandom")?;
        let ears = ears::Ears::new(args.agent.model.models_dir.clone());
        let where_kept = secret.where_kept();
        let sign_in = http::SignIn {
            secret,
            login: login.clone(),
        };
        let app = http::App::new(hub.clone(), jobs, info, sign_in, addr, trace, ears)
            .with_memory(memory);
        let reach = match addr.ip().is_loopback() {
            true => "",
            false => "; this address is reachable from other machines",
        };
        eprintln!(
            "ferrosa serve: console on http://{addr}/?login={login} (open it once to sign in; {where_kept}{reach})"
        );
        if let (Some(g), Some(v)) = (robot.graph.clone(), view) {
            tokio::spawn(pose::follow(g, hub.clone(), v));
        }
        tokio::spawn(follow_estop(hub.clone()));
        // Not a graceful shutdown: the event streams of open pages never end by themselves.
        tokio::select! {
            served = axum::serve(listener, app.router()) => served.context("serving the console"),
            _ = shutdown() => Ok(()),
        }
    });
    // Leaving: nothing the agent started may go on moving the robot.
    cancel.store(true, Ordering::SeqCst);
    estop.halt("the console was shut down");
    rt.shutdown_timeout(Duration::from_secs(2));
    drop(worker);
    drop(robot);
    served
}

/// Ctrl-C, or the TERM a service manager sends.
async fn shutdown() {
    crate::ui::term::interrupted().await;
    eprintln!("ferrosa serve: shutting down (the robot is braked)");
}

/// The robot view's topic: `--pose-topic`, or the sim's turtle; none for another robot
/// unless named. A fenced topic is refused.
fn view(args: &ServeArgs, agent: &Agent) -> anyhow::Result<Option<View>> {
    let (topic, bounds) = match (&args.pose_topic, args.agent.robot.is_sim()) {
        (Some(t), _) => (t.clone(), None),
        (None, true) => (
            "/turtle1/pose".to_string(),
            Some([0.0, 0.0, crate::ros::sim::ARENA, crate::ros::sim::ARENA]),
        ),
        (None, false) => return Ok(None),
    };
    anyhow::ensure!(
        args.agent.robot != super::agent::Robot::None,
        "--pose-topic {topic} needs a robot: add --robot sim, ros2 or ros1"
    );
    anyhow::ensure!(
        !agent.fence().denies(&topic),
        "--pose-topic {topic}: the policy's deny-list covers this topic; the console does not read it"
    );
    Ok(Some(View { topic, bounds }))
}

/// What the page shows of this console at start.
fn info(agent: &Agent, args: &AgentArgs, view: Option<&View>) -> Value {
    let languages: Vec<Value> = crate::reading::language::ALL
        .iter()
        .map(|l| json!({"code": l.code(), "name": l.name()}))
        .collect();
    json!({
        "engine": agent.engine(),
        "robot": format!("{:?}", args.robot).to_lowercase(),
        "languages": languages,
        "language": args.language.map(Language::code),
        "view": view,
    })
}

/// Tell every client when the e-stop is engaged or released, whoever did it (a ROS
/// node, the model's `robot_stop`, this page), and end the run in progress when it is
/// engaged. Presses while engaged change nothing and are not told.
async fn follow_estop(hub: Arc<Hub>) {
    let mut rx = hub.estop.subscribe();
    let mut told = None;
    loop {
        let state = rx.borrow_and_update().clone();
        let now = state.as_ref().map(|e| e.source.clone());
        if now.is_some() {
            hub.cancel.store(true, Ordering::SeqCst);
        }
        if told.as_ref() != Some(&now) {
            hub.publish("estop", &hub::estop_json(state.as_ref()), true);
            told = Some(now);
        }
        if rx.changed().await.is_err() {
            return;
        }
    }
}
