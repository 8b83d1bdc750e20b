//! `ferrosa ask` (one shot) and `ferrosa chat` (REPL): build an agent from the command
//! line (model, tools, policy, robot prompt, trace directory), run it, and show the event
//! stream as it happens. Ctrl-C cancels the current run; in the REPL it does not exit.
//! `--robot sim` starts the built-in robot in this process and gives the agent the ROS
//! and turtle tools; `--robot ros2` joins the ROS 2 graph already running here.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::Context;
use serde_json::json;

use super::progress::View;
use super::robot;
pub use super::robot::{connect, Listing, Robot, RobotLink};
use super::term::{clean, Input, TerminalConfirm};
use crate::agent::prompt::RobotPrompt;
use crate::agent::trace::Trace;
use crate::agent::{Agent, AgentConfig, AnswerMode, Journal, NameSource, RunResult};
use crate::decode::Decoding;
use crate::estop::EStop;
use crate::reading::meaning::Meaning;
use crate::ros::ros2::Ros2Options;
use crate::ros::sim::Sim;
use crate::ros::RosGraph;
use crate::store::{NewRun, Store};
use crate::tool::policy::{NoOperator, PolicyFile};
use crate::tool::{Confirm, Package, Policy, Registry};

const TURTLESIM_PROMPT: &str = include_str!("../../prompts/turtlesim.toml");

#[derive(Debug, Clone)]
pub struct AgentArgs {
    pub model: super::ModelArgs,
    pub yes: bool,
    pub read_only: bool,
    pub policy: Option<PathBuf>,
    pub prompt: Option<PathBuf>,
    pub trace_dir: Option<PathBuf>,
    pub log_dirs: Vec<PathBuf>,
    /// Files of declared robot tools (`tools::declared`), after the prompt file's.
    pub tools: Vec<PathBuf>,
    pub max_steps: usize,
    pub decoding: Decoding,
    pub answer_mode: AnswerMode,
    pub robot: Robot,
    pub copy_bias: f32,
    pub pick: crate::agent::config::Pick,
    /// The language answers are written in; `None`: each request's own.
    pub language: Option<crate::reading::language::Language>,
    /// Show the model's text as it writes it and each call's arguments and result
    /// (`progress`).
    pub verbose: bool,
    /// Which tools a request's prompt lists.
    pub listing: Listing,
    /// The memory file (`store`); `None`: `memory.sqlite` in the data directory.
    pub memory: Option<PathBuf>,
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

/// The tools, the policy and the robot prompt of `args`, over `graph` (raw: it is
/// guarded here) with `confirm` asking about actuating calls and `estop` the process's
/// e-stop. What `ask`, `chat` and `call` share.
pub fn tools_and_policy(
    args: &AgentArgs,
    confirm: Arc<dyn Confirm>,
    graph: Option<Arc<dyn RosGraph>>,
    estop: Arc<EStop>,
) -> anyhow::Result<(Registry, Arc<Policy>, RobotPrompt)> {
    let mut policy = match &args.policy {
        Some(p) => Policy::load(p, confirm)?,
        None => Policy::from_file(PolicyFile::default(), confirm)?,
    }
    .with_estop(estop.clone());
    policy.auto_approve |= args.yes;
    policy.read_only |= args.read_only;
    let policy = Arc::new(policy);
    let mut registry = Registry::new();
    for p in crate::tools::standard() {
        registry.add(p);
    }
    registry.add(crate::tools::deny::package(policy.clone()));
    registry.add(crate::tools::stop::package(estop));
    if !args.log_dirs.is_empty() {
        registry.add(crate::tools::logs(args.log_dirs.clone()));
    }
    if let Ok(store) = open_memory(args) {
        registry.add(crate::tools::memory::package(store));
    }
    let prompt = robot_prompt(args)?;
    let files: Vec<PathBuf> = prompt.tools.iter().chain(&args.tools).cloned().collect();
    match graph {
        Some(raw) => {
            let guarded = robot::guard(raw, &policy, args.robot);
            robot::add_ros_tools(&mut registry, guarded.clone(), args.robot);
            if has_places(args, &prompt, guarded.as_ref()) {
                registry.add(place_tools(args, &prompt, guarded.clone()));
            }
            // Declared tools act through the same guarded graph, and may not take a
            // name a tool already has.
            for f in &files {
                let taken = registry.specs().into_iter().map(|s| s.name).collect();
                registry.add(crate::tools::declared::load(f, guarded.clone(), &taken)?);
            }
        }
        None if !files.is_empty() => anyhow::bail!(
            "declared tools ({}) act on a ROS robot: add --robot sim, --robot ros2 or --robot ros1",
            files
                .iter()
                .map(|f| f.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
        None => {}
    }
    Ok((registry, policy, prompt))
}

/// Whether the robot gets the place tools: its robot file names places or a pose topic,
/// it is the sim, or it serves Nav2's `navigate_to_pose` as discovery first sees it.
fn has_places(args: &AgentArgs, prompt: &RobotPrompt, graph: &dyn RosGraph) -> bool {
    let navigates = || {
        crate::ros::graph_now(graph).is_some_and(|g| {
            g.actions().iter().any(|a| {
                crate::ros::msg::normalize_type(&a.type_name) == crate::tools::place::NAVIGATE_TYPE
            })
        })
    };
    !prompt.places.is_empty() || prompt.pose_topic.is_some() || args.robot.is_sim() || navigates()
}

/// The place tools over `graph`: the robot file's places, and its memory (or why it has
/// none).
fn place_tools(args: &AgentArgs, prompt: &RobotPrompt, graph: Arc<dyn RosGraph>) -> Package {
    crate::tools::place::package(
        graph,
        prompt.places.clone(),
        open_memory(args),
        prompt.pose_topic.clone(),
    )
}

/// The memory file `args` use: `--memory`, else `memory.sqlite` in the data directory.
pub(crate) fn memory_path(args: &AgentArgs) -> Option<PathBuf> {
    args.memory.clone().or_else(crate::store::default_path)
}

/// The facts the robot's memory keeps (none when it has no memory).
fn remembered(args: &AgentArgs) -> Vec<String> {
    open_memory(args)
        .ok()
        .and_then(|s| s.facts().ok())
        .map(|facts| facts.into_iter().map(|f| f.text).collect())
        .unwrap_or_default()
}

/// The robot's memory, opened once per process for each file and robot (the tools,
/// the journal and tool choice share it); why there is none is said once per process.
pub(crate) fn open_memory(args: &AgentArgs) -> Result<Arc<Store>, String> {
    static OPEN: std::sync::Mutex<Vec<(PathBuf, String, Arc<Store>)>> =
        std::sync::Mutex::new(Vec::new());
    let Some(path) = memory_path(args) else {
        return Err(said_once(
            "this machine has no data directory (set HOME or XDG_DATA_HOME, or give --memory FILE)"
                .to_string(),
        ));
    };
    let key = memory_key(args);
    let mut open = OPEN.lock().unwrap_or_else(|p| p.into_inner());
    if let Some((_, _, store)) = open.iter().find(|(p, k, _)| *p == path && *k == key) {
        return Ok(store.clone());
    }
    let store = Arc::new(Store::open(&path, &key).map_err(|e| said_once(e.to_string()))?);
    open.push((path, key, store.clone()));
    Ok(store)
}

/// `why` there is no memory, said on stderr the first time.
fn said_once(why: String) -> String {
    static SAID: std::sync::Once = std::sync::Once::new();
    SAID.call_once(|| eprintln!("ferrosa: nothing is remembered this session: {why}"));
    why
}

/// A journal that logs each run of `session` in `store`: the request, the calls (with
/// their decisions) and the answer, every name off limits redacted by `fence`.
pub(crate) fn journal(
    store: Arc<Store>,
    session: String,
    fence: Arc<crate::fence::Fence>,
) -> Journal {
    Box::new(move |request: &str, result: &RunResult| {
        let calls: Vec<String> = result
            .steps
            .iter()
            .map(|s| {
                let mut arguments = s.arguments.clone();
                fence.redact_json(&mut arguments);
                let came = if s.ok { "ok" } else { "failed or refused" };
                format!("{}({arguments}) {came}", s.name)
            })
            .collect();
        let logged = store.log_run(&NewRun {
            session: &session,
            request: &fence.redact(request),
            calls: &calls.join("\n"),
            answer: &result.answer,
            finish: &format!("{:?}", result.finish).to_lowercase(),
        });
        if let Err(e) = logged {
            eprintln!("ferrosa: this request was not logged: {e}");
        }
    })
}

/// A new session's name: when it began, and this process.
pub(crate) fn new_session() -> String {
    format!("{}-{}", crate::clock::Utc::now().iso(), std::process::id())
}

/// Whose memory this is: the robot kind, and its robot file's name when one is given
/// (places taught to one robot are not another's).
pub(crate) fn memory_key(args: &AgentArgs) -> String {
    let kind = match args.robot {
        Robot::Sim | Robot::SimRos1 => "sim",
        Robot::Ros2 => "ros2",
        Robot::Ros1 => "ros1",
        Robot::None => "none",
    };
    match args.prompt.as_ref().and_then(|p| p.file_stem()) {
        Some(stem) => format!("{kind}/{}", stem.to_string_lossy()),
        None => kind.to_string(),
    }
}

/// The places the robot file names (the console draws them).
pub(crate) fn robot_places(args: &AgentArgs) -> anyhow::Result<Vec<crate::store::Place>> {
    Ok(robot_prompt(args)?.places)
}

/// The robot's prompt file: `--prompt`, else the sim's or the default robot's.
fn robot_prompt(args: &AgentArgs) -> anyhow::Result<RobotPrompt> {
    Ok(match &args.prompt {
        Some(p) => RobotPrompt::load(p)?,
        None if args.robot.is_sim() => {
            RobotPrompt::parse(TURTLESIM_PROMPT, "prompts/turtlesim.toml")?
        }
        None => RobotPrompt::default_robot(),
    })
}

/// `ferrosa models warm`: fill the prompt cache with the stable prefix of each of
/// `requests` (default: the robot prompt's `warm` list), exactly as `ask` and `chat`
/// with the same options will render it, so their first request starts warm.
pub fn warm(args: &AgentArgs, requests: &[String]) -> anyhow::Result<()> {
    let listed = robot_prompt(args)?.warm;
    let requests = if requests.is_empty() {
        &listed
    } else {
        requests
    };
    anyhow::ensure!(
        !requests.is_empty(),
        "nothing to warm: name the requests (ferrosa models warm --robot sim \"show every ROS node\"), or list them under `warm` in the robot prompt file"
    );
    anyhow::ensure!(
        args.model.prompt_cache,
        "the prompt cache is off (--prompt-cache off or FERROSA_PROMPT_CACHE=off): nothing to warm"
    );
    let robot = connect(args.robot, false)?;
    let mut agent = build_with(
        args,
        Arc::new(NoOperator),
        robot.graph.clone(),
        EStop::new(),
    )?;
    for q in requests {
        let t = std::time::Instant::now();
        match agent.warm(q)? {
            Some(n) => println!("{n:>6} tokens  {:>6.0} ms  {q}", t.elapsed().as_secs_f64() * 1e3),
            None => anyhow::bail!(
                "no prompt cache: the {} runtime cannot keep one, or this machine has no cache directory (set FERROSA_CACHE_DIR)",
                agent.backend().name()
            ),
        }
    }
    if let Some(cache) = agent.prompt_cache() {
        cache.flush();
        let entries = cache.entries();
        let bytes: u64 = entries
            .iter()
            .filter_map(|(p, _)| std::fs::metadata(p).ok())
            .map(|m| m.len())
            .sum();
        println!(
            "prompt cache: {} ({} entries of this model and these settings, {:.0} MiB)",
            cache.dir().display(),
            entries.len(),
            bytes as f64 / f64::from(1 << 20)
        );
    }
    Ok(())
}

/// The robot joined, and its tools and policy over it, the fence set on the graph: what
/// `call` and `mcp` run calls with, without a model.
pub fn robot_tools(
    args: &AgentArgs,
    confirm: Arc<dyn Confirm>,
    estop: Arc<EStop>,
) -> anyhow::Result<(RobotLink, Registry, Arc<Policy>)> {
    let robot = connect(args.robot, false)?;
    let graph = robot.graph.clone();
    let (registry, policy, _) = tools_and_policy(args, confirm, graph, estop)?;
    if let Some(g) = &robot.graph {
        g.set_fence(policy.fence().clone());
    }
    Ok((robot, registry, policy))
}

/// A front end's agent and what it runs with: the robot link, the e-stop, the cancel
/// flag, and the operator's input (when there is a terminal).
pub struct Running {
    pub agent: Agent,
    pub robot: RobotLink,
    pub estop: Arc<EStop>,
    pub cancel: Arc<AtomicBool>,
    pub input: Option<Arc<Input>>,
}

/// Connect to the robot and build the agent: confirmations are asked on the terminal
/// (refused without one), `/stop` and Ctrl-C engage the e-stop.
pub fn start(args: &AgentArgs) -> anyhow::Result<Running> {
    let estop = EStop::new();
    let cancel = Arc::new(AtomicBool::new(false));
    let input = std::io::stdin()
        .is_terminal()
        .then(|| Input::start(estop.clone(), cancel.clone()));
    let confirm: Arc<dyn Confirm> = match &input {
        Some(input) => Arc::new(TerminalConfirm {
            input: input.clone(),
        }),
        None => Arc::new(NoOperator),
    };
    let robot = connect(args.robot, true)?;
    let graph = robot.graph.clone();
    let mut agent = build_with(args, confirm, graph, estop.clone())?.with_cancel(cancel.clone());
    if let Ok(store) = open_memory(args) {
        agent.set_journal(journal(store, new_session(), agent.fence().clone()));
    }
    if let Some(g) = &robot.graph {
        g.set_fence(agent.fence().clone());
    }
    install_ctrl_c(cancel.clone(), robot.graph.as_ref().map(|_| estop.clone()));
    Ok(Running {
        agent,
        robot,
        estop,
        cancel,
        input,
    })
}

/// The agent over `graph` (the ROS tools, and the turtle's with `--robot sim`), with
/// `confirm` asking about actuating calls and `estop` its e-stop.
pub fn build_with(
    args: &AgentArgs,
    confirm: Arc<dyn Confirm>,
    graph: Option<Arc<dyn RosGraph>>,
    estop: Arc<EStop>,
) -> anyhow::Result<Agent> {
    let (registry, policy, prompt) = tools_and_policy(args, confirm, graph.clone(), estop)?;
    // Configuration errors first: loading the model is the slow part.
    let (resolved, _, model) = args.model.load()?;
    let family = resolved.family().unwrap_or("chatml").to_string();
    let mut config = AgentConfig::for_family(&family);
    config.max_steps = args.max_steps;
    config.decoding = args.decoding;
    config.answer_mode = args.answer_mode;
    config.copy_bias = args.copy_bias;
    config.pick = args.pick;
    config.language = args.language;
    config.draft = args.model.draft;
    if args.listing == Listing::All {
        config.listing_budget_tokens = LISTING_BUDGET_TOKENS;
    }
    let cache = args.model.prompt_cache(&resolved, model.as_ref());
    let remote = args.model.connect(&resolved, model.as_ref())?;
    let sampler = config.sampler;
    let mut agent = Agent::new(model, registry, policy, prompt.render(), config)?;
    if let Some(meaning) = meaning(&args.model.models_dir, &prompt, &remembered(args)) {
        agent = agent.with_meaning(meaning);
    }
    if let Some(cache) = cache {
        agent = agent.with_prompt_cache(cache);
    }
    if let Some(remote) = remote {
        agent = agent.with_remote(remote.with_sampler(sampler));
    }
    if let Some(g) = graph {
        let fence = agent.fence().clone();
        agent = agent.with_names(robot_names(g, fence));
    }
    if let Some(dir) = &args.trace_dir {
        let trace = Trace::create(dir)
            .with_context(|| format!("cannot create a trace in {}", dir.display()))?;
        agent = agent.with_trace(trace);
    }
    Ok(agent)
}

/// Tool choice by meaning, the default: the sentence encoder, the tools' examples and
/// the prompt file's (README, Understanding requests). `FERROSA_TOOL_CHOICE=words`
/// reads words alone, as before the encoder. Without the encoder's files it says so
/// once and tool choice reads words.
///
/// `remembered`: facts the robot's memory keeps, each an example of `memory_recall` (a
/// request about the charger is near a fact about it).
fn meaning(models_dir: &Path, prompt: &RobotPrompt, remembered: &[String]) -> Option<Arc<Meaning>> {
    if std::env::var("FERROSA_TOOL_CHOICE").is_ok_and(|v| v.trim() == "words") {
        return None;
    }
    match crate::embed::shared(models_dir) {
        Ok(encoder) => {
            let mut examples = prompt.examples.clone();
            if !remembered.is_empty() {
                examples
                    .entry("memory_recall".to_string())
                    .or_default()
                    .extend(remembered.iter().cloned());
            }
            Some(Arc::new(Meaning::new(encoder, examples, &prompt.render())))
        }
        Err(e) => {
            static SAID: std::sync::Once = std::sync::Once::new();
            SAID.call_once(|| eprintln!("ferrosa: tool choice reads words, not meaning: {e}"));
            None
        }
    }
}

/// The robot's nodes, topics, services, actions and their types, keyed by the argument
/// that takes each, the fenced ones left out. The graph is a snapshot of what discovery
/// has seen: a graph that cannot answer at once gives no names (the bias is a nudge; a
/// run never waits for it).
pub fn robot_names(graph: Arc<dyn RosGraph>, fence: Arc<crate::fence::Fence>) -> NameSource {
    Arc::new(move || {
        let Some(g) = crate::ros::graph_now(graph.as_ref()) else {
            return Vec::new();
        };
        let mut out = std::collections::BTreeSet::new();
        for n in &g.nodes {
            out.insert(("node", n.clone()));
        }
        for (kind, entries) in [("topic", g.topics()), ("service", g.services())] {
            for (name, types) in entries {
                out.insert((kind, name));
                out.extend(types.into_iter().map(|t| ("type", t)));
            }
        }
        for a in g.actions() {
            out.insert(("action", a.action));
            out.insert(("type", a.type_name));
        }
        out.into_iter()
            .filter(|(_, name)| !fence.denies(name))
            .map(|(k, name)| (k.to_string(), name))
            .collect()
    })
}

/// The agent's copy bias unless told otherwise (see `strategy::copy`; the README has
/// the ROS suite with it and without).
pub const DEFAULT_COPY_BIAS: f32 = 3.0;

/// Ctrl-C cancels the current run and, with a robot, engages the e-stop (everything
/// running is aborted and the robot braked); the process goes on.
fn install_ctrl_c(flag: Arc<AtomicBool>, estop: Option<Arc<EStop>>) {
    super::on_own_thread("ctrl-c", move || async move {
        while tokio::signal::ctrl_c().await.is_ok() {
            flag.store(true, Ordering::SeqCst);
            if let Some(e) = &estop {
                e.trigger("Ctrl-C");
            }
        }
    });
}

pub fn ask(args: &AgentArgs, query: &str, as_json: bool) -> anyhow::Result<()> {
    let mut run = start(args)?;
    let mut view = View::new(args.verbose);
    let result = run.agent.ask(query, &mut |e| {
        if !as_json {
            view.event(e);
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
        if args.verbose {
            eprintln!();
        }
        println!("{}", clean(&result.answer));
    }
    Ok(())
}

/// The listing budget `--listing all` sets: a robot whose tools take more is listed
/// the tools offered for each request, and the prompt before a request is no longer
/// the same for all (the prompt cache then holds less). The sim's 39 tools (the place
/// and memory tools among them) take about 5,030 tokens; with the robot prompt, about
/// 5,350 of the default 8,192-token context, leaving some 2,800 for the history, the
/// run and its answer (the history is trimmed to fit).
const LISTING_BUDGET_TOKENS: usize = 5400;

/// The request the chat prepares the prompt with: any does, the listing is the same for
/// every request.
const CHAT_WARM: &str = "hello";

const CHAT_HELP: &str = "/stop engages the e-stop (also while a run goes on; so does Ctrl-C), /reset releases it, /call NAME {json} runs one tool call through the policy, /tools lists the tools, /clear forgets the conversation, /trace shows the trace file, /quit leaves.";

/// How many of the last session's exchanges `chat --resume` brings back (the history
/// is trimmed to the context as always).
const RESUMED: usize = 20;

pub fn chat(args: &AgentArgs, resume: bool) -> anyhow::Result<()> {
    let mut run = start(args)?;
    if resume {
        resume_last(args, &mut run.agent)?;
    }
    // Without a terminal the chat still reads its input on its own thread.
    let input = match run.input.clone() {
        Some(i) => i,
        None => Input::start(run.estop.clone(), run.cancel.clone()),
    };
    let (agent, estop, cancel) = (&mut run.agent, run.estop.clone(), run.cancel.clone());
    eprintln!(
        "ferrosa chat: {} tools. {CHAT_HELP}",
        agent.registry().len()
    );
    // Every request's prompt starts the same (the robot prompt and the tools' listing):
    // have it ready before the operator's first request, restored from the prompt cache
    // or, on the first start, evaluated and kept there.
    if args.model.prompt_cache && agent.lists_every_tool() {
        super::progress::begin(
            "preparing the robot prompt (the first start evaluates it, later ones restore it)"
                .into(),
        );
        let ready = agent.warm(CHAT_WARM);
        let took = super::progress::hold();
        match ready {
            Ok(_) if took.is_some_and(|t| t.as_secs() >= 2) => {
                eprintln!(
                    "robot prompt ready ({:.0} s, kept for later starts)",
                    took.unwrap_or_default().as_secs_f64()
                );
            }
            Ok(_) => {}
            Err(e) => eprintln!("the robot prompt was not prepared ahead: {e}"),
        }
    }
    loop {
        if let Some(e) = estop.engaged_by() {
            eprintln!(
                "\n[E-STOP engaged by {}: motion refused; /reset to release]",
                clean(&e.source)
            );
        }
        eprint!("\n> ");
        let _ = std::io::stderr().flush();
        let Some(line) = input.next_line() else {
            break;
        };
        cancel.store(false, Ordering::SeqCst);
        if !chat_command(agent, line.trim(), args.verbose) {
            break;
        }
    }
    Ok(())
}

/// `chat --resume`: the last session's exchanges become the history, and its log goes
/// on in that session.
fn resume_last(args: &AgentArgs, agent: &mut Agent) -> anyhow::Result<()> {
    let store =
        open_memory(args).map_err(|why| anyhow::anyhow!("nothing to resume from: {why}"))?;
    let runs = store.last_session(RESUMED)?;
    let Some(last) = runs.last() else {
        eprintln!(
            "nothing to resume: no conversation is logged for this robot; starting a new one"
        );
        return Ok(());
    };
    let answered: Vec<(&str, &str)> = runs
        .iter()
        .filter(|r| r.finish == "answer")
        .map(|r| (r.request.as_str(), r.answer.as_str()))
        .collect();
    agent.resume(answered.iter().copied());
    let session = last.session.clone();
    eprintln!(
        "resumed the conversation of {}: {} exchanges, the last \"{}\"",
        super::memory::short_time(&runs[0].at),
        answered.len(),
        clean(&last.request)
    );
    agent.set_journal(journal(store, session, agent.fence().clone()));
    Ok(())
}

/// One REPL line: a command, or a request for the agent. `false` to leave.
fn chat_command(agent: &mut Agent, q: &str, verbose: bool) -> bool {
    let mut view = View::new(verbose);
    match q {
        "" => {}
        "/quit" | "/exit" => return false,
        // Engaged by the input thread the moment it was typed.
        "/stop" | "/estop" => eprintln!("e-stop engaged: the robot is braked and motion refused"),
        "/reset" => {
            if agent.estop().reset() {
                eprintln!("e-stop released: motion allowed again");
            } else {
                eprintln!("the e-stop was not engaged");
            }
        }
        "/help" => eprintln!("{CHAT_HELP}"),
        "/tools" => {
            for t in agent.registry().tools() {
                let s = t.spec();
                eprintln!("{:<20} {:?}  {}", s.name, t.effect(), s.description);
            }
        }
        "/clear" => {
            agent.clear();
            eprintln!("conversation cleared");
        }
        "/trace" => match agent.trace_path() {
            Some(p) => eprintln!("{}", p.display()),
            None => eprintln!("no trace (start with --trace-dir DIR)"),
        },
        _ if q.starts_with("/call ") => {
            match super::term::parse_call(q.trim_start_matches("/call ")) {
                Ok(call) => {
                    let o = agent.call(&call);
                    let mut shown = call.clone();
                    agent.fence().redact_json(&mut shown.arguments);
                    println!(
                        "{}",
                        clean(&super::term::report_call(&shown, &o).to_string())
                    );
                }
                Err(e) => eprintln!("{e}"),
            }
        }
        _ if q.starts_with('/') => eprintln!("unknown command {}; {CHAT_HELP}", clean(q)),
        _ => match agent.ask(q, &mut |e| view.event(e)) {
            Ok(r) => {
                if verbose {
                    eprintln!();
                }
                println!("{}", clean(&r.answer));
            }
            Err(e) => eprintln!("error: {e}"),
        },
    }
    true
}
