//! `ferrosa ask` (one shot) and `ferrosa chat` (REPL): build an agent from the command
//! line (model, tools, policy, robot prompt, trace directory), run it, and show the event
//! stream as it happens. Ctrl-C cancels the current run; in the REPL it does not exit.
//! `--robot sim` starts the built-in robot in this process and gives the agent the ROS
//! and turtle tools; `--robot ros2` joins the ROS 2 graph already running here.

use std::io::{BufRead, IsTerminal, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use serde_json::json;

use crate::agent::prompt::RobotPrompt;
use crate::agent::trace::Trace;
use crate::agent::{Agent, AgentConfig, AnswerMode, Event};
use crate::decode::Decoding;
use crate::ros::ros2::{Ros2Graph, Ros2Options};
use crate::ros::sim::Sim;
use crate::ros::RosGraph;
use crate::tool::policy::{NoOperator, PolicyFile};
use crate::tool::{Confirm, Policy, Registry, ToolCall};

#[derive(Debug, Clone)]
pub struct AgentArgs {
    pub model: super::ModelArgs,
    pub yes: bool,
    pub read_only: bool,
    pub policy: Option<PathBuf>,
    pub prompt: Option<PathBuf>,
    pub trace_dir: Option<PathBuf>,
    pub log_dirs: Vec<PathBuf>,
    pub max_steps: usize,
    pub decoding: Decoding,
    pub answer_mode: AnswerMode,
    pub robot: Robot,
    pub copy_bias: f32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Robot {
    None,
    Sim,
    Ros2,
}

/// What keeps the robot connection alive for the agent's lifetime.
pub struct RobotLink {
    pub graph: Option<Arc<Ros2Graph>>,
    pub sim: Option<Sim>,
}

const TURTLESIM_PROMPT: &str = include_str!("../../prompts/turtlesim.toml");

/// Join ROS 2 (and start the sim first when asked), then wait until the graph shows it;
/// `verbose` reports the discovery on stderr.
pub fn connect(robot: Robot, verbose: bool) -> anyhow::Result<RobotLink> {
    if robot == Robot::None {
        return Ok(RobotLink {
            graph: None,
            sim: None,
        });
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
        graph: Some(graph),
        sim,
    })
}

/// `ferrosa sim`: the robot alone, until Ctrl-C.
pub fn sim() -> anyhow::Result<()> {
    let opts = Ros2Options::from_env()?;
    let _sim = Sim::start(&opts)?;
    eprintln!(
        "ferrosa sim: /turtlesim on ROS 2 domain {} ({:?}); Ctrl-C stops it",
        opts.domain_id, opts.range
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(tokio::signal::ctrl_c())?;
    Ok(())
}

/// Asks on the terminal: "run turtle_move {...}? [y/N]".
struct TerminalConfirm;

impl Confirm for TerminalConfirm {
    fn confirm(&self, call: &ToolCall) -> bool {
        eprint!(
            "\nallow {} {}? [y/N] ",
            call.name,
            serde_json::to_string(&call.arguments).unwrap_or_default()
        );
        let _ = std::io::stderr().flush();
        let mut line = String::new();
        std::io::stdin().lock().read_line(&mut line).is_ok()
            && matches!(line.trim(), "y" | "Y" | "yes")
    }
}

pub fn build(args: &AgentArgs) -> anyhow::Result<(Agent, RobotLink)> {
    let confirm: Arc<dyn Confirm> = if std::io::stdin().is_terminal() {
        Arc::new(TerminalConfirm)
    } else {
        Arc::new(NoOperator)
    };
    let link = connect(args.robot, true)?;
    let graph = link.graph.clone().map(|g| g as Arc<dyn RosGraph>);
    Ok((build_with(args, confirm, graph)?, link))
}

/// The agent over `graph` (the ROS tools, and the turtle's with `--robot sim`), with
/// `confirm` asking about actuating calls.
pub fn build_with(
    args: &AgentArgs,
    confirm: Arc<dyn Confirm>,
    graph: Option<Arc<dyn RosGraph>>,
) -> anyhow::Result<Agent> {
    let mut policy = match &args.policy {
        Some(p) => Policy::load(p, confirm)?,
        None => Policy::from_file(PolicyFile::default(), confirm)?,
    };
    policy.auto_approve |= args.yes;
    policy.read_only |= args.read_only;

    let policy = Arc::new(policy);
    let mut registry = Registry::new();
    for p in crate::tools::standard() {
        registry.add(p);
    }
    registry.add(crate::tools::guard::package(policy.clone()));
    if !args.log_dirs.is_empty() {
        registry.add(crate::tools::logs(args.log_dirs.clone()));
    }
    let prompt = match &args.prompt {
        Some(p) => RobotPrompt::load(p)?,
        None if args.robot == Robot::Sim => {
            RobotPrompt::parse(TURTLESIM_PROMPT, "prompts/turtlesim.toml")?
        }
        None => RobotPrompt::default_robot(),
    };
    if let Some(graph) = graph {
        registry.add(crate::tools::ros::package(graph.clone()));
        if args.robot == Robot::Sim {
            registry.add(crate::tools::turtle::package(graph, "turtle1"));
        }
    }
    // Configuration errors first: loading the model is the slow part.
    let (resolved, _, model) = args.model.load()?;
    let family = resolved.family().unwrap_or("chatml").to_string();
    let mut config = AgentConfig::for_family(&family);
    config.max_steps = args.max_steps;
    config.decoding = args.decoding;
    config.answer_mode = args.answer_mode;
    config.copy_bias = args.copy_bias;
    let mut agent = Agent::new(model, registry, policy, prompt.render(), config)?;
    if let Some(dir) = &args.trace_dir {
        let trace = Trace::create(dir)
            .with_context(|| format!("cannot create a trace in {}", dir.display()))?;
        agent = agent.with_trace(trace);
    }
    Ok(agent)
}

/// Ctrl-C sets the agent's cancel flag instead of killing the process.
fn install_ctrl_c(flag: Arc<AtomicBool>) {
    std::thread::spawn(move || {
        let Ok(rt) = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        else {
            return;
        };
        rt.block_on(async {
            while tokio::signal::ctrl_c().await.is_ok() {
                flag.store(true, Ordering::SeqCst);
            }
        });
    });
}

fn show(e: &Event, stream: bool) {
    let mut err = std::io::stderr();
    match e {
        Event::Token { text } if stream => {
            let _ = write!(err, "{text}");
            let _ = err.flush();
        }
        Event::ToolCall {
            name,
            arguments,
            decision,
            ..
        } => {
            let _ = writeln!(
                err,
                "\n→ {name} {arguments} [{}]",
                serde_json::to_value(decision)
                    .map(|d| d["decision"].clone())
                    .unwrap_or_default()
            );
        }
        Event::ToolResult {
            name,
            output,
            ms,
            ok,
            ..
        } => {
            let text = output.to_string();
            let short: String = text.chars().take(300).collect();
            let mark = if *ok { "←" } else { "✗" };
            let _ = writeln!(err, "{mark} {name} ({ms:.0} ms): {short}");
        }
        Event::Error { message } => {
            let _ = writeln!(err, "\n! {message}");
        }
        _ => {}
    }
}

pub fn ask(args: &AgentArgs, query: &str, as_json: bool) -> anyhow::Result<()> {
    let (mut agent, _robot) = build(args)?;
    install_ctrl_c(agent.cancel_flag());
    let result = agent.ask(query, &mut |e| {
        if !as_json {
            show(e, false);
        }
    })?;
    if as_json {
        let steps: Vec<_> = result
            .steps
            .iter()
            .map(|s| {
                json!({"name": s.name, "arguments": s.arguments, "output": s.output, "ms": s.ms,
                       "decision": s.decision, "ok": s.ok, "step": s.step})
            })
            .collect();
        let out = json!({
            "answer": result.answer,
            "finish": result.finish,
            "steps": steps,
            "timings": result.timings,
            "tools_offered": result.tools_offered,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!("{}", result.answer);
    }
    Ok(())
}

pub fn chat(args: &AgentArgs) -> anyhow::Result<()> {
    let (mut agent, _robot) = build(args)?;
    let cancel = agent.cancel_flag();
    install_ctrl_c(cancel.clone());
    eprintln!(
        "ferrosa chat: {} tools. /tools lists them, /clear forgets the conversation, /trace shows the trace file, /quit leaves. Ctrl-C stops a run.",
        agent.registry().len()
    );
    let stdin = std::io::stdin();
    loop {
        eprint!("\n> ");
        let _ = std::io::stderr().flush();
        let mut line = String::new();
        if stdin.lock().read_line(&mut line)? == 0 {
            break;
        }
        cancel.store(false, Ordering::SeqCst);
        let q = line.trim();
        match q {
            "" => continue,
            "/quit" | "/exit" => break,
            "/tools" => {
                for t in agent.registry().tools() {
                    let s = t.spec();
                    eprintln!("{:<16} {:?}  {}", s.name, t.effect(), s.description);
                }
                continue;
            }
            "/clear" => {
                agent.clear();
                eprintln!("conversation cleared");
                continue;
            }
            "/trace" => {
                match agent.trace_path() {
                    Some(p) => eprintln!("{}", p.display()),
                    None => eprintln!("no trace (start with --trace-dir DIR)"),
                }
                continue;
            }
            _ => {}
        }
        let result = agent.ask(q, &mut |e| show(e, false))?;
        println!("{}", result.answer);
    }
    Ok(())
}
