//! `cargo bench --bench agent`: the whole agent against the built-in sim robot with the
//! real default model, as an operator meets it.
//!
//! 1. End-to-end latency of a fixed set of operator requests (query → tool calls →
//!    answer): the first request after start (nothing cached), then each request N times
//!    after `/clear` (the system prompt stays cached), min / median / max, with the time to
//!    the first token (the call's opening, shown once the model has read it), to the
//!    first call written whole, the model's and the tools' share, and what was called.
//! 2. Cold start: the first request of a freshly built agent (model loaded, nothing in
//!    memory), with the prompt cache off, on but empty (the request stores its prefix),
//!    and on with the prefix kept by an earlier process; each N times, in a temporary
//!    cache directory. Parts 1 and 3 run with the prompt cache off.
//! 3. Memory across a long chat: resident memory after 1 turn and after 200 (history kept
//!    and trimmed by the agent), against the KV cache the context can fill. The turns are
//!    small talk the model answers without a tool (about 0.5 s each; a tool request costs
//!    several seconds once history builds up, too long for 200 of them here): they grow
//!    the history, the trace of prompts and the KV cache use as any turn does, while the
//!    tool paths are exercised by part 1.
//!
//! 4. The remote engine (when llama-server is built: `scripts/build-llama-cpp.sh
//!    llama-server`, or `LLAMA_SERVER`): the same requests with the same model in this
//!    process and on a llama-server on loopback with as many threads, alternated run by
//!    run (in process, then remote, N times for each request), so that drift of a noisy
//!    machine enters both sides alike; the ratio of their model time per turn is taken
//!    within each round and its median and spread printed, per request and over all;
//!    and what the remote path adds to each completion: its wall time here less the
//!    server's own prompt and generation time.
//!
//! 5. This build against main at 2065ce7 (before the answer step), side by side in one
//!    run: `VERSUS`, 37 requests of nine kinds (listing, state, count, field,
//!    definition, parameter, motion, two-step, small talk), typed into each build's
//!    `ferrosa chat` one at a time (`common/versus.rs`), each request's time to its
//!    first call and to its answer and the p50 / p95 of each; this build a second time
//!    with each request's prompt listing only its offered tools (`--listing offered`).
//!    The baseline binary comes
//!    from `scripts/build-baseline.sh`; without it the part says so and is skipped.
//!
//! 6. Prompt-lookup drafting off and on (`decode::draft`): `VERSUS` in this process,
//!    request by request with the setting alternating, time to the first call and to
//!    the answer, p50 / p95 of each, and how many requests made the same calls.
//!
//! The sim speaks DDS, so the bench re-runs itself in a network namespace with only
//! loopback (`unshare -n`, as root), under a time limit. Settings: FERROSA_BENCH_RUNS (3),
//! FERROSA_BENCH_TURNS (40), FERROSA_BENCH_THREADS (physical cores), FERROSA_BENCH_PARTS
//! (the parts to run, e.g. `2` or `1,4`; all by default), FERROSA_BENCH_BASELINE
//! (the baseline binary of part 5). Output: markdown on
//! stdout, target/bench/agent.json, target/bench/agent.svg.

#[path = "common/chart.rs"]
mod chart;
#[path = "common/header.rs"]
mod header;
#[path = "common/versus.rs"]
mod versus;

use std::path::PathBuf;
use std::sync::Arc;

#[path = "../tests/support/llama_server.rs"]
mod llama_server;
#[path = "../tests/support/netns.rs"]
mod netns;

use ferrosa::agent::{AnswerMode, RunResult};
use ferrosa::decode::Decoding;
use ferrosa::tool::{Confirm, ToolCall};
use ferrosa::ui::agent::{build_with, connect, AgentArgs, Robot};
use ferrosa::ui::ModelArgs;
use header::Spread;
use serde::Serialize;

/// The whole bench, inside the namespace, must end within this.
const LIMIT_S: u32 = 3600;

/// What an operator asks a turtle robot: listing, pose, topics, status, motion.
const REQUESTS: [&str; 5] = [
    "list the ROS nodes",
    "where is the turtle?",
    "what topics are there?",
    "what is the battery level?",
    "move the turtle forward 1 meter",
];

/// Part 5's requests, by kind: none of them is in a suite, and each kind has several
/// wordings, so a build fitted to one wording gains little here.
const VERSUS: [(&str, &str); 37] = [
    ("listing", "show me every node that is running"),
    ("listing", "what services are offered here?"),
    ("listing", "give me the list of topics"),
    ("listing", "what actions does the robot offer?"),
    ("state", "where is the turtle right now?"),
    ("state", "which way is the turtle facing?"),
    ("state", "what charge does the battery hold?"),
    ("state", "any faults on the robot?"),
    ("count", "how many nodes are up?"),
    ("count", "count the services"),
    ("count", "how many topics exist on this robot?"),
    ("count", "how many parameters does the turtlesim node have?"),
    ("field", "what is the turtle's x coordinate?"),
    ("field", "how fast is the turtle going?"),
    ("field", "what is the battery percentage?"),
    ("field", "what is the background red value?"),
    ("definition", "what fields does a turtlesim/msg/Pose have?"),
    (
        "definition",
        "what is inside a geometry_msgs/msg/Twist message?",
    ),
    (
        "definition",
        "describe the turtlesim/srv/Spawn service type",
    ),
    ("definition", "what does the /turtle1/pose topic carry?"),
    (
        "parameter",
        "show the parameters the turtlesim node exposes",
    ),
    ("parameter", "what is background_g set to?"),
    ("parameter", "set background_r to 100"),
    ("parameter", "read the background blue value"),
    ("motion", "drive the turtle forward half a meter"),
    ("motion", "turn the turtle 90 degrees to the left"),
    ("motion", "teleport the turtle to x 3 y 3"),
    ("motion", "put the pen up"),
    ("two-step", "move forward 1 meter and then tell me the pose"),
    ("two-step", "list the nodes and then the topics"),
    ("two-step", "turn left 45 degrees and then read the pose"),
    ("two-step", "count the topics, then list the services"),
    (
        "two-step",
        "put the pen down and then drive forward half a meter",
    ),
    (
        "two-step",
        "what is background_r set to, and what is background_b set to?",
    ),
    ("small talk", "hi there!"),
    ("small talk", "thank you, that will be all"),
    ("small talk", "what are you?"),
];

/// The build part 5 measures this one against: main before the answer step
/// (`scripts/build-baseline.sh` builds it into `target/bench/baseline-2065ce7/`).
const BASELINE_REV: &str = "2065ce7";

/// The long chat's turn.
const SMALL_TALK: &str = "hello, are you there?";

/// The operator at the keyboard says yes to every motion the requests ask for.
struct Yes;

impl Confirm for Yes {
    fn confirm(&self, _: &ToolCall) -> bool {
        true
    }
}

#[derive(Debug, Serialize)]
struct RequestRow {
    request: String,
    total_ms: Spread,
    first_token_ms: Spread,
    /// Query to the first call written whole (when the robot could first act).
    first_call_ms: Spread,
    model_ms: Spread,
    /// The model's time per turn (a turn: the model writing one step's calls or answer).
    turn_ms: Spread,
    turns: Spread,
    tools_ms: Spread,
    steps: Spread,
    tools: Vec<String>,
    answer: String,
}

/// One request `runs` times after `/clear`, as a row.
fn request_row(agent: &mut ferrosa::agent::Agent, q: &str, runs: usize) -> RequestRow {
    let results: Vec<RunResult> = (0..runs).map(|_| cleared_run(agent, q)).collect();
    row_of(q, &results)
}

/// `q` asked once after `/clear`.
fn cleared_run(agent: &mut ferrosa::agent::Agent, q: &str) -> RunResult {
    agent.clear();
    agent.ask(q, &mut |_| {}).expect("the agent runs")
}

/// The model's time per turn of a run (a turn: the model writing one step's calls or
/// answer).
fn per_turn_ms(r: &RunResult) -> f64 {
    r.timings.model_ms / r.timings.prompt_tokens.len().max(1) as f64
}

/// A request's runs as a row.
fn row_of(q: &str, results: &[RunResult]) -> RequestRow {
    let spread = |f: &dyn Fn(&RunResult) -> f64| Spread::of(results.iter().map(f).collect());
    let turns = |r: &RunResult| r.timings.prompt_tokens.len().max(1) as f64;
    let last = results.last().expect("runs ≥ 1");
    RequestRow {
        request: q.to_string(),
        total_ms: spread(&|r| r.timings.total_ms),
        first_token_ms: spread(&|r| r.timings.first_token_ms.unwrap_or(0.0)),
        first_call_ms: spread(&|r| r.timings.first_call_ms.unwrap_or(0.0)),
        model_ms: spread(&|r| r.timings.model_ms),
        turn_ms: spread(&per_turn_ms),
        turns: spread(&turns),
        tools_ms: spread(&|r| r.timings.tools_ms),
        steps: spread(&|r| r.steps.len() as f64),
        tools: last.steps.iter().map(|s| s.name.clone()).collect(),
        answer: last.answer.clone(),
    }
}

#[derive(Debug, Serialize)]
struct MemoryRow {
    turns: usize,
    rss_after_1_mib: f64,
    rss_after_n_mib: f64,
    peak_rss_mib: f64,
    kv_cache_mib: f64,
    context: usize,
    history_kept_at_end: usize,
    seconds: f64,
}

fn mib_now() -> f64 {
    ferrosa::metrics::rss_bytes().map_or(0.0, ferrosa::metrics::mib)
}

fn main() {
    if !netns::inside() {
        rerun_in_loopback_netns();
        return;
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let runs = header::env_usize("FERROSA_BENCH_RUNS", 3).max(1);
    let turns = header::env_usize("FERROSA_BENCH_TURNS", 40).max(2);
    let threads = header::env_usize("FERROSA_BENCH_THREADS", ferrosa::backend::physical_cores());
    let parts = std::env::var("FERROSA_BENCH_PARTS").unwrap_or_else(|_| "1,2,3,4,5,6".into());
    let part = |n: &str| parts.split(',').any(|p| p.trim() == n);
    let args = AgentArgs {
        model: ModelArgs {
            models_dir: header::models_dir(),
            model: None,
            backend: ferrosa::backend::BackendKind::Llama,
            threads: Some(threads),
            max_context: 8192,
            prompt_cache: false,
            draft: ferrosa::decode::Draft::default(),
            remote: None,
            adapter: "default".into(),
            dense_weights: false,
        },
        yes: true,
        read_only: false,
        policy: None,
        prompt: None,
        trace_dir: None,
        log_dirs: Vec::new(),
        tools: Vec::new(),
        max_steps: 10,
        decoding: Decoding::Constrained,
        answer_mode: AnswerMode::Tool,
        robot: Robot::Sim,
        copy_bias: ferrosa::ui::agent::DEFAULT_COPY_BIAS,
        pick: Default::default(),
        language: None,
        verbose: false,
        listing: ferrosa::ui::agent::Listing::All,
        memory: None,
    };
    header::print(
        "ferrosa agent benchmark",
        &root,
        &format!("threads: {threads} | runs: {runs} | chat turns: {turns} | default model, llama.cpp, constrained, built-in sim"),
    );

    let t = std::time::Instant::now();
    let link = connect(Robot::Sim, false).expect("start the sim");
    let discovered_ms = t.elapsed().as_secs_f64() * 1e3;
    let graph = link
        .graph
        .clone()
        .map(|g| g as Arc<dyn ferrosa::ros::RosGraph>);
    let t = std::time::Instant::now();
    let mut agent = build_with(
        &args,
        Arc::new(Yes),
        graph.clone(),
        ferrosa::estop::EStop::new(),
    )
    .expect("build the agent");
    let load_ms = t.elapsed().as_secs_f64() * 1e3;
    println!("sim discovered in {discovered_ms:.0} ms; agent (model, grammars, tools) built in {load_ms:.0} ms");
    println!();

    let ask = |agent: &mut ferrosa::agent::Agent, q: &str| -> RunResult {
        agent.ask(q, &mut |_| {}).expect("the agent runs")
    };

    // 1. Latency.
    let f = |s: &Spread| format!("{:.0} / **{:.0}** / {:.0}", s.min, s.median, s.max);
    let first = part("1").then(|| ask(&mut agent, REQUESTS[0]));
    let rows: Vec<RequestRow> = REQUESTS
        .iter()
        .filter(|_| first.is_some())
        .map(|q| request_row(&mut agent, q, runs))
        .collect();
    if let Some(first) = &first {
        println!(
            "## Requests against the sim (ms, min / **median** / max over {runs}, after /clear)"
        );
        println!();
        println!(
        "First request after start, nothing cached: \"{}\" {:.0} ms (first token {:.0} ms, prompt {} tokens), answer: {}",
        REQUESTS[0],
        first.timings.total_ms,
        first.timings.first_token_ms.unwrap_or(0.0),
        first.timings.prompt_tokens.first().copied().unwrap_or(0),
        first.answer
    );
        println!();
        println!("| request | total | first token | first call | model | tools | steps | calls (last run) | answer (last run) |");
        println!("|---|---|---|---|---|---|---|---|---|");
        for r in &rows {
            println!(
                "| {} | {} | {} | {} | {} | {} | {:.0}–{:.0} | {} | {} |",
                r.request,
                f(&r.total_ms),
                f(&r.first_token_ms),
                f(&r.first_call_ms),
                f(&r.model_ms),
                f(&r.tools_ms),
                r.steps.min,
                r.steps.max,
                r.tools.join(" → "),
                r.answer.replace('|', "\\|"),
            );
        }
        println!();
    }

    // 2. Cold start, with and without the prompt cache.
    let cold = if part("2") {
        cold_start(&args, graph.clone(), runs)
    } else {
        Vec::new()
    };
    if !cold.is_empty() {
        println!("## Cold start: the first request of a new agent (\"{}\"), ms, min / **median** / max over {runs}", REQUESTS[0]);
        println!();
        println!("| prompt cache | agent built | first token | first call | total | prompt tokens restored | answer (last run) |");
        println!("|---|---|---|---|---|---|---|");
    }
    for c in &cold {
        println!(
            "| {} | {} | {} | {} | {} | {} | {} |",
            c.cache,
            f(&c.build_ms),
            f(&c.first_token_ms),
            f(&c.first_call_ms),
            f(&c.total_ms),
            c.restored_tokens,
            c.answer.replace('|', "\\|")
        );
    }
    println!();

    // 3. Memory over a long chat: the history grows until the agent trims it.
    let memory = part("3").then(|| {
    agent.clear();
    let t = std::time::Instant::now();
    ask(&mut agent, SMALL_TALK);
    let after_1 = mib_now();
    for turn in 2..=turns {
        let r = ask(&mut agent, SMALL_TALK);
        if turn % 20 == 0 || turn <= 3 {
            eprintln!(
                "turn {turn}: {:.0} ms, prompt tokens {:?} (cached {:?}), {} exchanges remembered, RSS {:.0} MiB",
                r.timings.total_ms,
                r.timings.prompt_tokens,
                r.timings.reused_tokens,
                agent.history_len(),
                mib_now()
            );
        }
    }
    let after_n = mib_now();
    let kv = ferrosa::backend::Gguf::open(
        &ferrosa::models::resolve(None, &args.model.models_dir)
            .expect("default model")
            .path,
    )
    .ok()
    .and_then(|g| g.kv_cache_bytes(agent.backend().context_len()))
    .map_or(0.0, ferrosa::metrics::mib);
    let memory = MemoryRow {
        turns,
        rss_after_1_mib: after_1,
        rss_after_n_mib: after_n,
        peak_rss_mib: ferrosa::metrics::peak_rss_bytes().map_or(0.0, ferrosa::metrics::mib),
        kv_cache_mib: kv,
        context: agent.backend().context_len(),
        history_kept_at_end: agent.history_len(),
        seconds: t.elapsed().as_secs_f64(),
    };
    println!("## Memory over {turns} chat turns of \"{SMALL_TALK}\" (history kept, trimmed by the agent)");
    println!();
    println!("| RSS after 1 turn MiB | after {turns} MiB | growth MiB | KV cache at full context MiB | peak RSS MiB | exchanges kept | wall s |");
    println!("|---|---|---|---|---|---|---|");
    println!(
        "| {:.0} | {:.0} | {:+.0} | {:.0} ({} tokens) | {:.0} | {} | {:.0} |",
        memory.rss_after_1_mib,
        memory.rss_after_n_mib,
        memory.rss_after_n_mib - memory.rss_after_1_mib,
        memory.kv_cache_mib,
        memory.context,
        memory.peak_rss_mib,
        memory.history_kept_at_end,
        memory.seconds,
    );
    println!();
    memory
    });

    // 6. Drafting off and on, request by request, in this process.
    let drafting = part("6").then(|| drafting_off_on(&mut agent));

    // 4. The remote engine, on a llama-server with the same model, alternated with
    // this process's.
    let wanted = part("4");
    let remote = match llama_server::binary().filter(|_| wanted) {
        Some(bin) => Some(remote_engine(
            &mut agent,
            &args,
            graph.clone(),
            &bin,
            (threads, runs),
        )),
        None if !wanted => None,
        None => {
            println!("## Remote engine: skipped (no llama-server: scripts/build-llama-cpp.sh llama-server, or LLAMA_SERVER)");
            println!();
            None
        }
    };

    // 5. This build and the baseline side by side, each as its own chat process.
    drop(agent);
    drop(link);
    let versus = part("5").then(|| side_by_side(&root)).flatten();

    let out = root.join("target").join("bench");
    let _ = std::fs::create_dir_all(&out);
    let file = out.join("agent.json");
    let json = serde_json::json!({"requests": rows, "memory": memory, "first": first.map(|f| f.timings), "cold_start": cold, "remote": remote, "versus": versus, "drafting": drafting});
    std::fs::write(&file, serde_json::to_string_pretty(&json).expect("json")).expect("write json");
    let mut latency = chart::Bars::new("ms (median)", &["total", "first token", "tools"]);
    for r in &rows {
        latency.group(
            &r.request,
            &[
                r.total_ms.median,
                r.first_token_ms.median,
                r.tools_ms.median,
            ],
        );
    }
    let mut mem = chart::Bars::new(
        "MiB",
        &["RSS after 1 turn", "RSS after N turns", "KV cache"],
    );
    if let Some(memory) = &memory {
        mem.group(
            &format!("{turns} turns"),
            &[
                memory.rss_after_1_mib,
                memory.rss_after_n_mib,
                memory.kv_cache_mib,
            ],
        );
    }
    let svg = out.join("agent.svg");
    match chart::draw(
        &svg,
        "ferrosa agent on the built-in sim, 2 CPU threads",
        &[latency, mem],
    ) {
        Ok(()) => eprintln!("wrote {} and {}", file.display(), svg.display()),
        Err(e) => eprintln!("wrote {}; chart failed: {e}", file.display()),
    }
}

/// Part 6: `VERSUS` asked in whole passes with prompt-lookup drafting off and on, A B B
/// A (after `/clear`, the system prompt cached): the time to the first call written
/// whole and to the answer, p50 / p95 by setting, and how many requests made the same
/// calls both ways.
fn drafting_off_on(agent: &mut ferrosa::agent::Agent) -> serde_json::Value {
    use ferrosa::decode::Draft;
    let was = agent.config.draft;
    let on = Draft::up_to(Draft::SUGGESTED_TOKENS);
    let (mut calls, mut answers) = ([Vec::new(), Vec::new()], [Vec::new(), Vec::new()]);
    // Whole passes, off and on in the order A B B A: consecutive asks are different
    // requests (no ask finds its own prompt cached), and drift of the machine falls on
    // both settings alike.
    let mut made: [Vec<String>; 2] = [Vec::new(), Vec::new()];
    for i in [0, 1, 1, 0] {
        agent.config.draft = if i == 0 { Draft::OFF } else { on };
        for (_, q) in VERSUS {
            agent.clear();
            let r = agent.ask(q, &mut |_| {}).expect("the agent runs");
            if let Some(ms) = r.timings.first_call_ms {
                calls[i].push(ms);
            }
            answers[i].push(r.timings.total_ms);
            let steps: Vec<_> = r.steps.iter().map(|s| (&s.name, &s.arguments)).collect();
            made[i].push(serde_json::to_string(&steps).unwrap_or_default());
        }
    }
    // Each request's calls in its first pass with each setting.
    let n = VERSUS.len();
    let same = (0..n).filter(|&k| made[0][k] == made[1][k]).count();
    let asked = n;
    agent.config.draft = was;
    println!(
        "## Prompt-lookup drafting off and on ({asked} requests, two passes each, A B B A; ms)",
    );
    println!();
    println!(
        "| drafting | first call p50 | first call p95 | answer p50 | answer p95 | answer mean |"
    );
    println!("|---|---|---|---|---|---|");
    let mut rows = Vec::new();
    for (i, name) in ["off", "on"].into_iter().enumerate() {
        let mean = answers[i].iter().sum::<f64>() / answers[i].len().max(1) as f64;
        let row = serde_json::json!({
            "drafting": name,
            "first_call_p50": versus::quantile(&calls[i], 0.5),
            "first_call_p95": versus::quantile(&calls[i], 0.95),
            "answer_p50": versus::quantile(&answers[i], 0.5),
            "answer_p95": versus::quantile(&answers[i], 0.95),
            "answer_mean": mean,
        });
        println!(
            "| {name} | {:.0} | {:.0} | {:.0} | {:.0} | {mean:.0} |",
            row["first_call_p50"].as_f64().unwrap_or(0.0),
            row["first_call_p95"].as_f64().unwrap_or(0.0),
            row["answer_p50"].as_f64().unwrap_or(0.0),
            row["answer_p95"].as_f64().unwrap_or(0.0),
        );
        rows.push(row);
    }
    println!();
    println!("Same calls (names and arguments) with drafting off and on, first pass of each: {same} of {asked}.");
    println!();
    serde_json::json!({"rows": rows, "same_calls": same, "asked": asked})
}

/// Part 5: `VERSUS` through the baseline's chat and this build's, one after the other
/// (never two models at once), each request's time to its first call and to its answer,
/// and the p50 / p95 of each by build; `None` when the baseline is not built.
fn side_by_side(root: &std::path::Path) -> Option<serde_json::Value> {
    let baseline = std::env::var_os("FERROSA_BENCH_BASELINE")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join(format!("target/bench/baseline-{BASELINE_REV}/ferrosa")));
    if !baseline.exists() {
        println!(
            "## This build against {BASELINE_REV}: skipped (no {}: scripts/build-baseline.sh builds it)",
            baseline.display()
        );
        println!();
        return None;
    }
    let this = PathBuf::from(env!("CARGO_BIN_EXE_ferrosa"));
    let requests: Vec<&str> = VERSUS.iter().map(|(_, q)| *q).collect();
    // Each binary runs where it finds its own model catalog.
    let run = |bin: &std::path::Path, domain: u32, extra: &[&str]| {
        let home = bin
            .parent()
            .filter(|d| d.join("models/catalog.toml").exists())
            .unwrap_or(root);
        versus::chat(bin, home, SMALL_TALK, &requests, domain, 900, extra)
            .unwrap_or_else(|e| panic!("{e}"))
    };
    let old = run(&baseline, 61, &[]);
    let new = run(&this, 62, &[]);
    let offered = run(&this, 63, &["--listing", "offered"]);
    let ms = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.0}"));
    println!(
        "## This build against {BASELINE_REV}: {} requests on the sim, each after /clear (ms)",
        requests.len()
    );
    println!();
    println!("\"this\": this build as it starts (every tool listed once); \"offered\": the same with `--listing offered` (each request's prompt lists the tools offered it).");
    println!();
    println!("| kind | request | {BASELINE_REV} first call | {BASELINE_REV} answer | offered first call | offered answer | this first call | this answer | this calls | this answer |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for ((((kind, q), o), n), l) in VERSUS.iter().zip(&old).zip(&offered).zip(&new) {
        println!(
            "| {kind} | {q} | {} | {:.0} | {} | {:.0} | {} | {:.0} | {} | {} |",
            ms(o.first_call_ms),
            o.answer_ms,
            ms(n.first_call_ms),
            n.answer_ms,
            ms(l.first_call_ms),
            l.answer_ms,
            l.calls.join(" → "),
            l.answer
                .chars()
                .take(80)
                .collect::<String>()
                .replace('|', "\\|")
                .replace('\n', " "),
        );
    }
    println!();
    println!("| build | requests | first call p50 | first call p95 | answer p50 | answer p95 | answer mean | one-step answer p50 | two-step answer p50 |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let summary = |name: &str, runs: &[versus::Timed]| {
        let calls: Vec<f64> = runs.iter().filter_map(|r| r.first_call_ms).collect();
        let answers: Vec<f64> = runs.iter().map(|r| r.answer_ms).collect();
        let by_steps = |two: bool| -> Vec<f64> {
            VERSUS
                .iter()
                .zip(runs)
                .filter(|((kind, _), _)| (*kind == "two-step") == two && *kind != "small talk")
                .map(|(_, r)| r.answer_ms)
                .collect()
        };
        let mean = answers.iter().sum::<f64>() / answers.len().max(1) as f64;
        println!(
            "| {name} | {} | {:.0} | {:.0} | {:.0} | {:.0} | {mean:.0} | {:.0} | {:.0} |",
            runs.len(),
            versus::quantile(&calls, 0.5),
            versus::quantile(&calls, 0.95),
            versus::quantile(&answers, 0.5),
            versus::quantile(&answers, 0.95),
            versus::quantile(&by_steps(false), 0.5),
            versus::quantile(&by_steps(true), 0.5),
        );
        serde_json::json!({
            "first_call_p50": versus::quantile(&calls, 0.5),
            "first_call_p95": versus::quantile(&calls, 0.95),
            "answer_p50": versus::quantile(&answers, 0.5),
            "answer_p95": versus::quantile(&answers, 0.95),
            "answer_mean": mean,
            "requests": runs,
        })
    };
    let old = summary(BASELINE_REV, &old);
    let offered = summary("this build, --listing offered", &offered);
    let new = summary("this build", &new);
    println!();
    let kinds: Vec<_> = VERSUS
        .iter()
        .map(|(k, q)| serde_json::json!({"kind": k, "request": q}))
        .collect();
    Some(
        serde_json::json!({"baseline": BASELINE_REV, "kinds": kinds, BASELINE_REV: old, "this": new, "offered": offered}),
    )
}

#[derive(Debug, Serialize)]
struct ColdRow {
    cache: &'static str,
    build_ms: Spread,
    first_token_ms: Spread,
    first_call_ms: Spread,
    total_ms: Spread,
    /// Prompt tokens restored from disk in the last run.
    restored_tokens: usize,
    answer: String,
}

/// The first request of `runs` new agents each: prompt cache off; on, empty (its own
/// directory each run); on, holding what an earlier agent kept.
fn cold_start(
    args: &AgentArgs,
    graph: Option<Arc<dyn ferrosa::ros::RosGraph>>,
    runs: usize,
) -> Vec<ColdRow> {
    let sha = ferrosa::models::resolve(None, &args.model.models_dir)
        .expect("the default model")
        .sha256()
        .expect("the default model's sha256");
    let kept = tempfile::tempdir().expect("a cache directory");
    let mut rows = Vec::new();
    for cache in ["off", "on, empty", "on, kept"] {
        let (mut build, mut first, mut call, mut total) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut restored, mut answer) = (0, String::new());
        // "kept" starts from what an agent kept before it.
        let runs = if cache == "on, kept" { runs + 1 } else { runs };
        for run in 0..runs {
            let empty = tempfile::tempdir().expect("a cache directory");
            let t = std::time::Instant::now();
            let mut agent = build_with(
                args,
                Arc::new(Yes),
                graph.clone(),
                ferrosa::estop::EStop::new(),
            )
            .expect("build the agent");
            let dir = match cache {
                "off" => None,
                "on, empty" => Some(empty.path()),
                _ => Some(kept.path()),
            };
            let pc = dir.map(|d| {
                Arc::new(
                    ferrosa::backend::PromptCache::open(
                        d,
                        &sha,
                        agent.backend(),
                        ferrosa::backend::prompt_cache::DEFAULT_MAX_BYTES,
                    )
                    .expect("llama.cpp keeps a prompt cache"),
                )
            });
            if let Some(pc) = &pc {
                agent = agent.with_prompt_cache(pc.clone());
            }
            let built = t.elapsed().as_secs_f64() * 1e3;
            let r = agent.ask(REQUESTS[0], &mut |_| {}).expect("the agent runs");
            if let Some(pc) = &pc {
                pc.flush();
                restored = pc.counts().0;
            }
            if cache == "on, kept" && run == 0 {
                continue;
            }
            build.push(built);
            first.push(r.timings.first_token_ms.unwrap_or(0.0));
            call.push(r.timings.first_call_ms.unwrap_or(0.0));
            total.push(r.timings.total_ms);
            answer = r.answer;
        }
        rows.push(ColdRow {
            cache,
            build_ms: Spread::of(build),
            first_token_ms: Spread::of(first),
            first_call_ms: Spread::of(call),
            total_ms: Spread::of(total),
            restored_tokens: restored,
            answer,
        });
    }
    rows
}

#[derive(Debug, Serialize)]
struct RemoteReport {
    engine: String,
    requests: Vec<RemoteRow>,
    /// Remote model time per turn over in-process, every round of every request.
    per_turn_ratio: Spread,
    /// Per completion: wall time here less the server's own time (ms).
    overhead_ms: Spread,
    completions: usize,
}

#[derive(Debug, Serialize)]
struct RemoteRow {
    local: RequestRow,
    remote: RequestRow,
    /// Remote model time per turn over in-process, within each round.
    per_turn_ratio: Spread,
    ratios: Vec<f64>,
}

/// Part 4: each request in this process (`local`) and through a llama-server running
/// the same model with as many threads, alternated run by run, `runs` rounds each; the
/// ratio of their model time per turn within each round.
fn remote_engine(
    local: &mut ferrosa::agent::Agent,
    args: &AgentArgs,
    graph: Option<Arc<dyn ferrosa::ros::RosGraph>>,
    bin: &std::path::Path,
    (threads, runs): (usize, usize),
) -> RemoteReport {
    let model = ferrosa::models::resolve(None, &args.model.models_dir)
        .expect("default model")
        .path;
    let server = llama_server::Server::start(bin, &model, threads, 8192);
    let mut a = args.clone();
    a.model.remote = Some(ferrosa::remote::RemoteOptions {
        url: server.url.clone(),
        api_key_env: None,
        model: None,
        grammar: ferrosa::remote::GrammarMode::Auto,
        timeout: std::time::Duration::from_secs(120),
    });
    let mut remote = build_with(&a, Arc::new(Yes), graph, ferrosa::estop::EStop::new())
        .expect("build the agent on the server");
    let engine = remote.engine();
    // Both sides hold the system prompt before the first measured run.
    cleared_run(local, REQUESTS[0]);
    cleared_run(&mut remote, REQUESTS[0]);
    let skip = remote.remote().map_or(0, |r| r.times().len());
    // A side's threads may still spin for a moment after its run: let them settle, so
    // that neither starts beside the other's.
    let settle = || std::thread::sleep(std::time::Duration::from_millis(200));
    let rows: Vec<RemoteRow> = REQUESTS
        .iter()
        .map(|q| {
            let (mut here, mut there, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
            for _ in 0..runs {
                let l = cleared_run(local, q);
                settle();
                let r = cleared_run(&mut remote, q);
                settle();
                ratios.push(per_turn_ms(&r) / per_turn_ms(&l).max(1e-9));
                here.push(l);
                there.push(r);
            }
            RemoteRow {
                local: row_of(q, &here),
                remote: row_of(q, &there),
                per_turn_ratio: Spread::of(ratios.clone()),
                ratios,
            }
        })
        .collect();
    let times = remote
        .remote()
        .map(|r| r.times()[skip..].to_vec())
        .unwrap_or_default();
    let overhead: Vec<f64> = times
        .iter()
        .filter_map(|t| Some((t.wall.saturating_sub(t.server?)).as_secs_f64() * 1e3))
        .collect();
    let f = |s: &Spread| format!("{:.0} / **{:.0}** / {:.0}", s.min, s.median, s.max);
    let ratio = |s: &Spread| format!("**{:.2}** ({:.2}–{:.2})", s.median, s.min, s.max);
    println!("## Remote engine: the same requests, the model in this process and on llama-server ({engine}), {threads} threads, loopback, alternated run by run");
    println!();
    println!("Model time per turn, ms, min / **median** / max over {runs} (a turn: the model writing one step's calls or answer; the remote engine has no weighed pick or copy bias, so its turns and calls can differ); the ratio remote / in process within each round, median (min–max):");
    println!();
    println!("| request | in-process per turn | turns | remote per turn | turns | remote / in process | remote first token | remote calls (last run) | remote answer (last run) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for row in &rows {
        let (l, r) = (&row.local, &row.remote);
        println!(
            "| {} | {} | {:.0}–{:.0} | {} | {:.0}–{:.0} | {} | {} | {} | {} |",
            r.request,
            f(&l.turn_ms),
            l.turns.min,
            l.turns.max,
            f(&r.turn_ms),
            r.turns.min,
            r.turns.max,
            ratio(&row.per_turn_ratio),
            f(&r.first_token_ms),
            r.tools.join(" → "),
            r.answer.replace('|', "\\|"),
        );
    }
    let all: Vec<f64> = rows.iter().flat_map(|r| r.ratios.clone()).collect();
    let rounds = all.len();
    let all = Spread::of(all);
    let overhead_ms = Spread::of(overhead.clone());
    println!();
    println!(
        "Remote / in process, model time per turn, over all {rounds} rounds: {}",
        ratio(&all)
    );
    println!();
    println!(
        "What the remote path adds per completion (wall time here less the server's own prompt and generation time), ms over {} completions: {}",
        overhead.len(),
        f(&overhead_ms)
    );
    println!();
    drop(remote);
    drop(server);
    RemoteReport {
        engine,
        requests: rows,
        per_turn_ratio: all,
        overhead_ms,
        completions: overhead.len(),
    }
}

/// Run this bench again inside a network namespace with only loopback, under a limit.
fn rerun_in_loopback_netns() {
    let exe = std::env::current_exe().expect("the bench binary");
    let status = netns::loopback_netns(&exe, std::env::args_os().skip(1), LIMIT_S)
        .status()
        .expect("unshare (util-linux) and ip (iproute2) are needed: run as root after .ci/setup");
    assert!(
        status.success(),
        "agent bench in the loopback namespace: {status}"
    );
}
