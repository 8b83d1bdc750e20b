//! `cargo bench --bench runtime`: what the model runtime delivers on this machine, for
//! every catalog model present × compiled backend × decoding (plain, constrained), each
//! configuration in its own child process so load time and peak RSS are its own.
//!
//! Per configuration: load time; prompt tok/s at 512 tokens; generation tok/s for 128
//! tokens at depth 0 and 512 (under the agent's prose-or-call grammar when constrained);
//! on tool-call turns, tok/s with one sampled token per forward pass and (constrained)
//! the tool-call output rate with fast-forward, forced tokens included, and forward passes
//! per call; time to first token of an agent-sized prompt, cold and on a second turn with
//! the first one cached; peak RSS (VmHWM) against file + KV cache + 64 MiB.
//! min / median / max over N runs. With `LLAMA_BENCH=/path/to/llama-bench`, upstream's
//! pp512 / tg128 on the same files and threads are measured in rounds interleaved with
//! ours (upstream, then ferrosa, N times, each a process of its own), and the ratio is
//! taken within each round, so drift of a noisy machine between rounds does not enter
//! it: its median and spread are printed per configuration.
//!
//! Settings (environment): FERROSA_BENCH_RUNS (5), FERROSA_BENCH_THREADS (physical
//! cores), FERROSA_BENCH_CONTEXT (4096), FERROSA_BENCH_MODELS (the catalog's default model; a comma list, or `all` for
//! every model present), FERROSA_BENCH_BACKENDS / FERROSA_BENCH_DECODING (comma lists to
//! restrict). Output: a markdown table on stdout, target/bench/runtime.json and
//! target/bench/runtime.svg.

#[path = "common/chart.rs"]
mod chart;
#[path = "common/header.rs"]
mod header;

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use ferrosa::agent::prompt::RobotPrompt;
use ferrosa::backend::{self, Backend, BackendKind, LoadOptions, TokenId};
use ferrosa::chat::{ChatMessage, Role};
use ferrosa::decode::envelope::{Envelope, ToolChoice};
use ferrosa::decode::request::{render_prompt_split, with_tools, TurnRequest};
use ferrosa::decode::{
    generate, prompt_tokens, Constraint, Decoding, Draft, GenerationStats, Grammars, JsonScan,
    NoHook, Sampler, SamplerConfig, Session, Steering,
};
use ferrosa::models::Catalog;
use ferrosa::tool::{specs_from_json, ToolSpec};
use header::Spread;
use serde::{Deserialize, Serialize};

const CHILD_ENV: &str = "FERROSA_BENCH_CHILD";
/// candle with its layers' weights also held dense, for prompts.
const CANDLE_DENSE: &str = "candle-dense";
const PROMPT: usize = 512;
const GEN: usize = 128;
/// Room for the agent-sized prompt, a reply and a second turn.
const CONTEXT: usize = 4096;
/// What the process may hold beyond weights and KV cache: code, grammar, buffers.
const OVERHEAD_MIB: f64 = 64.0;

/// Tool-call turns, one per run in turn: what an operator asks a turtle robot.
/// The robot description the agent puts before the tools (the built-in sim's).
const ROBOT_PROMPT: &str = include_str!("../prompts/turtlesim.toml");

const TOOL_QUERIES: [&str; 5] = [
    "read 3 messages from /turtle1/pose",
    "move the turtle forward 2 meters",
    "list the topics under /turtle1",
    "turn right 45 degrees",
    "what is the mean of 3, 5 and 10?",
];

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Config {
    model: String,
    path: PathBuf,
    family: String,
    backend: String,
    decoding: String,
    threads: usize,
    runs: usize,
    /// Prompt and generation throughput only (an interleaved round).
    #[serde(default)]
    throughput_only: bool,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Measured {
    config: Config,
    load_ms: f64,
    prompt_tps: Spread,
    gen_tps_d0: Spread,
    gen_tps_d512: Spread,
    /// Tool-call turns: forward passes per second, one sampled token each.
    tool_turn_tps: Spread,
    /// Constrained with fast-forward: call tokens emitted per second, forced included.
    call_output_tps: Option<Spread>,
    forwards_per_call: Option<f64>,
    /// Constrained: the same call turns with prompt-lookup drafting off and on.
    #[serde(default)]
    drafting: Option<Drafting>,
    valid_calls: usize,
    tool_turns: usize,
    ttft_cold_ms: Spread,
    ttft_cached_ms: Spread,
    agent_prompt_tokens: usize,
    second_turn_new_tokens: usize,
    peak_rss_mib: f64,
    /// Resident right after the model loaded, and what the grammar set-up added.
    loaded_rss_mib: f64,
    grammars_mib: f64,
    file_mib: f64,
    kv_mib: f64,
    context: usize,
    /// Resident at the end of the run, by what backs it: the weights' file, the
    /// executable and its libraries, anonymous memory (KV cache, compute buffers, heap).
    #[serde(default)]
    resident: Resident,
}

/// Tool-call turns written with drafting off and on, alternating turn by turn.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Drafting {
    /// Call tokens emitted per second (forced included), off / on.
    output_tps: (Spread, Spread),
    /// Forward passes per call (the prompt's included), off / on.
    forwards: (f64, f64),
    /// From the turn's start to the call written whole (prompt and generation), off / on.
    call_ms: (Spread, Spread),
    /// Guessed tokens the turns kept, of those guessed.
    accepted: usize,
    drafted: usize,
    /// Turns whose tokens were the same off and on, of all.
    same: usize,
    turns: usize,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct Resident {
    model_mib: f64,
    code_mib: f64,
    anonymous_mib: f64,
    other_mib: f64,
}

impl Resident {
    fn now(model: &Path) -> Resident {
        let model = std::fs::canonicalize(model).unwrap_or_else(|_| model.to_path_buf());
        let exe = std::env::current_exe().unwrap_or_default();
        let mut r = Resident::default();
        for (path, bytes) in ferrosa::metrics::resident_parts().unwrap_or_default() {
            let mib = ferrosa::metrics::mib(bytes);
            let slot = if Path::new(&path) == model {
                &mut r.model_mib
            } else if path == "anonymous" {
                &mut r.anonymous_mib
            } else if path.contains(".so") || exe == Path::new(&path) {
                &mut r.code_mib
            } else {
                &mut r.other_mib
            };
            *slot += mib;
        }
        r
    }
}

impl Measured {
    fn budget_mib(&self) -> f64 {
        self.file_mib + self.kv_mib + OVERHEAD_MIB
    }
}

/// Interleaved rounds against llama-bench: ferrosa / upstream within each round.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct Interleaved {
    rounds: usize,
    prompt: Spread,
    gen_d0: Spread,
    gen_d512: Spread,
    /// Upstream's own figures over the rounds.
    upstream: [Spread; 3],
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct Upstream {
    prompt_tps: Option<f64>,
    gen_tps_d0: Option<f64>,
    gen_tps_d512: Option<f64>,
}

fn main() {
    if let Ok(cfg) = std::env::var(CHILD_ENV) {
        let cfg: Config = serde_json::from_str(&cfg).expect("child config");
        let m = measure(&cfg);
        println!("{}", serde_json::to_string(&m).expect("serialise"));
        return;
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let dir = header::models_dir();
    let catalog = Catalog::load(&dir).expect("catalog");
    let runs = header::env_usize("FERROSA_BENCH_RUNS", 5).max(1);
    let threads = header::env_usize("FERROSA_BENCH_THREADS", backend::physical_cores());

    header::print(
        "ferrosa runtime benchmark",
        &root,
        &format!("threads: {threads} | runs: {runs}"),
    );
    println!(
        "prompt: {PROMPT} tokens in one batch; generation: {GEN} tokens, greedy, at depth 0 and {PROMPT}; context {CONTEXT}; figures min / **median** / max"
    );
    println!();
    let mut rows = Vec::new();
    for e in &catalog.model {
        let path = dir.join(&e.file);
        // The default model unless FERROSA_BENCH_MODELS names others (or says "all").
        let chosen = match std::env::var("FERROSA_BENCH_MODELS") {
            Ok(v) if v.trim() == "all" => true,
            Ok(_) => header::wanted("FERROSA_BENCH_MODELS", &e.name),
            Err(_) => e.name == catalog.default,
        };
        // Language models only: not the speech recogniser nor the sentence encoder.
        let language = !matches!(
            e.kind,
            ferrosa::models::ModelKind::Speech | ferrosa::models::ModelKind::Encoder
        );
        if !path.exists() || !chosen || !language {
            continue;
        }
        let arch = backend::Gguf::open(&path)
            .ok()
            .and_then(|g| g.architecture().map(str::to_string))
            .unwrap_or_default();
        let upstream_bin = std::env::var_os("LLAMA_BENCH").map(PathBuf::from);
        // candle twice: with its weights as the file holds them (its default), and
        // also dense for prompts (`--candle-weights dense`).
        for (kind, name) in [
            (BackendKind::Llama, "llama"),
            (BackendKind::Candle, "candle"),
            (BackendKind::Candle, CANDLE_DENSE),
        ] {
            let compiled = match kind {
                BackendKind::Llama => cfg!(feature = "llama"),
                BackendKind::Candle => {
                    cfg!(feature = "candle") && matches!(arch.as_str(), "llama" | "gemma3")
                }
            };
            if !compiled || !header::wanted("FERROSA_BENCH_BACKENDS", name) {
                continue;
            }
            for decoding in ["plain", "constrained"] {
                if !header::wanted("FERROSA_BENCH_DECODING", decoding) {
                    continue;
                }
                let cfg = Config {
                    model: e.name.clone(),
                    path: path.clone(),
                    family: e.family.clone(),
                    backend: name.to_string(),
                    decoding: decoding.to_string(),
                    threads,
                    runs,
                    throughput_only: false,
                };
                eprintln!("measuring {} / {name} / {decoding} …", e.name);
                let paired = upstream_bin
                    .as_deref()
                    .map(|bin| interleave(bin, &cfg))
                    .unwrap_or_default();
                match run_child(&cfg) {
                    Ok(m) => rows.push((m, paired)),
                    Err(err) => eprintln!("{} / {name} / {decoding}: {err}", e.name),
                }
            }
        }
    }
    print_table(&rows);
    let out = root.join("target").join("bench");
    let _ = std::fs::create_dir_all(&out);
    let json: Vec<_> = rows
        .iter()
        .map(|(m, u)| serde_json::json!({"ferrosa": m, "llama_bench": u}))
        .collect();
    let file = out.join("runtime.json");
    std::fs::write(&file, serde_json::to_string_pretty(&json).expect("json")).expect("write json");
    let svg = out.join("runtime.svg");
    match draw(&rows, &svg) {
        Ok(()) => eprintln!("wrote {} and {}", file.display(), svg.display()),
        Err(e) => eprintln!("wrote {}; chart failed: {e}", file.display()),
    }
}

/// `cfg.runs` rounds of upstream llama-bench then a ferrosa child, each measuring pp512
/// and tg128 at depth 0 and 512 once: the ratio of each round's pair.
fn interleave(bin: &Path, cfg: &Config) -> Interleaved {
    let one = Config {
        runs: 1,
        throughput_only: true,
        ..cfg.clone()
    };
    let (mut ratios, mut upstream) = ([vec![], vec![], vec![]], [vec![], vec![], vec![]]);
    for round in 0..cfg.runs {
        eprintln!(
            "  round {} of {}: llama-bench, then ferrosa",
            round + 1,
            cfg.runs
        );
        let up = llama_bench(bin, &cfg.path, cfg.threads, 1);
        let ours = match run_child(&one) {
            Ok(m) => m,
            Err(e) => {
                eprintln!("  round {}: {e}", round + 1);
                continue;
            }
        };
        let pairs = [
            (ours.prompt_tps.median, up.prompt_tps),
            (ours.gen_tps_d0.median, up.gen_tps_d0),
            (ours.gen_tps_d512.median, up.gen_tps_d512),
        ];
        for (i, (o, u)) in pairs.into_iter().enumerate() {
            if let Some(u) = u.filter(|u| *u > 0.0) {
                ratios[i].push(o / u);
                upstream[i].push(u);
            }
        }
    }
    let [p, g0, g512] = ratios;
    Interleaved {
        rounds: p.len(),
        prompt: Spread::of(p),
        gen_d0: Spread::of(g0),
        gen_d512: Spread::of(g512),
        upstream: upstream.map(Spread::of),
    }
}

/// Tool-call turns with prompt-lookup drafting off and on, per constrained configuration.
fn drafting_table(rows: &[(Measured, Interleaved)]) {
    let fmt = |s: &Spread| format!("{:.0} / **{:.0}** / {:.0}", s.min, s.median, s.max);
    println!();
    println!("## Tool calls with prompt-lookup drafting (off → on, each query's turn alternating)");
    println!();
    println!("| model | backend | call output tok/s | forwards / call | turn to whole call ms | guesses kept | same tokens |");
    println!("|---|---|---|---|---|---|---|");
    for (m, _) in rows {
        let Some(d) = &m.drafting else { continue };
        println!(
            "| {} | {} | {} → {} | {:.1} → {:.1} | {} → {} | {} / {} | {} / {} |",
            m.config.model,
            m.config.backend,
            fmt(&d.output_tps.0),
            fmt(&d.output_tps.1),
            d.forwards.0,
            d.forwards.1,
            fmt(&d.call_ms.0),
            fmt(&d.call_ms.1),
            d.accepted,
            d.drafted,
            d.same,
            d.turns,
        );
    }
}

fn run_child(cfg: &Config) -> Result<Measured, String> {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let out = Command::new(exe)
        .env(CHILD_ENV, serde_json::to_string(cfg).expect("config json"))
        .output()
        .map_err(|e| e.to_string())?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).into_owned());
    }
    let line = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(line.trim().lines().last().unwrap_or_default()).map_err(|e| e.to_string())
}

fn tool_specs() -> Vec<ToolSpec> {
    specs_from_json(include_str!("../tests/data/robot_tools.json")).expect("tool specs")
}

/// The tools the agent would offer for a turtle query (it offers a handful, not all).
fn offered(all: &[ToolSpec]) -> Vec<ToolSpec> {
    let names = [
        "ros_topic_echo",
        "ros_topic_list",
        "ros_node_list",
        "turtle_move",
        "turtle_rotate",
        "turtle_pose",
        "calc_stats",
    ];
    all.iter()
        .filter(|s| names.contains(&s.name.as_str()))
        .cloned()
        .collect()
}

struct Child {
    model: Box<dyn Backend>,
    grammars: Option<Grammars>,
    session: Session,
    envelope: Envelope,
}

impl Child {
    /// Generate up to `max` tokens after `prompt` (greedy), under `lark` when constrained.
    fn run(
        &mut self,
        prompt: &[TokenId],
        max: usize,
        lark: &str,
        fast_forward: bool,
        draft: Draft,
    ) -> (GenerationStats, Vec<TokenId>) {
        let mut c: Option<Constraint> = self.grammars.as_ref().map(|g| {
            let mut c = g.compile(lark).expect("grammar");
            c.set_fast_forward(fast_forward);
            c
        });
        let mut sampler = Sampler::new(SamplerConfig::default(), self.model.vocab().len());
        let mut out = Vec::new();
        let (_, stats) = generate(
            self.model.as_mut(),
            &mut self.session,
            prompt,
            max,
            Steering {
                sampler: &mut sampler,
                constraint: c.as_mut(),
                hook: &mut NoHook,
                scan: &mut JsonScan::new(),
                draft,
            },
            |t, _| {
                out.push(t);
                ControlFlow::Continue(())
            },
        )
        .expect("generate");
        (stats, out)
    }

    fn render(&self, messages: &[ChatMessage], specs: &[ToolSpec]) -> Vec<TokenId> {
        let req = TurnRequest {
            messages,
            specs,
            allowed: None,
            envelope: self.envelope,
            choice: ToolChoice::Required,
            parallel: false,
            decoding: Decoding::Constrained,
            max_tokens: 64,
        };
        let text = self
            .model
            .chat_template()
            .render(&with_tools(&req), None, true)
            .expect("template");
        prompt_tokens(self.model.as_ref(), &text, true).expect("tokenize")
    }
}

/// The drafting measured: `Draft::up_to(SUGGESTED_TOKENS)`, or FERROSA_BENCH_DRAFT as
/// `max_tokens,longest_match,shortest_match`.
fn bench_draft() -> Draft {
    let Ok(v) = std::env::var("FERROSA_BENCH_DRAFT") else {
        return Draft::up_to(Draft::SUGGESTED_TOKENS);
    };
    let n: Vec<usize> = v.split(',').filter_map(|x| x.trim().parse().ok()).collect();
    match n[..] {
        [max_tokens, longest_match, shortest_match] => Draft {
            max_tokens,
            longest_match,
            shortest_match,
        },
        _ => panic!("FERROSA_BENCH_DRAFT is max_tokens,longest_match,shortest_match"),
    }
}

/// Every tool query's call turn with drafting off, then on, `runs` times.
fn drafting(c: &mut Child, specs: &[ToolSpec], lark: &str, runs: usize) -> Drafting {
    let (mut tps, mut ms) = ((Vec::new(), Vec::new()), (Vec::new(), Vec::new()));
    let (mut forwards, mut accepted, mut drafted, mut same, mut turns) = ((0, 0), 0, 0, 0, 0);
    for _ in 0..runs {
        for q in TOOL_QUERIES {
            let messages = [
                ChatMessage::new(Role::System, "You control a turtle robot."),
                ChatMessage::new(Role::User, q),
            ];
            // As the agent renders a turn: the system part is the stable prefix, which
            // drafting does not copy from.
            let req = TurnRequest {
                messages: &messages,
                specs,
                allowed: None,
                envelope: c.envelope,
                choice: ToolChoice::Required,
                parallel: false,
                decoding: Decoding::Constrained,
                max_tokens: 128,
            };
            let (prompt, stable) =
                render_prompt_split(c.model.as_ref(), &with_tools(&req), c.envelope)
                    .expect("render");
            let mut outs = Vec::new();
            for (on, draft) in [(false, Draft::OFF), (true, bench_draft())] {
                c.session.clear();
                c.session.set_stable(&prompt[..stable]);
                let (s, out) = c.run(&prompt, 128, lark, true, draft);
                let whole = (s.prompt_time + s.gen_time).as_secs_f64() * 1e3;
                let (t, m, f) = if on {
                    (&mut tps.1, &mut ms.1, &mut forwards.1)
                } else {
                    (&mut tps.0, &mut ms.0, &mut forwards.0)
                };
                t.push(s.output_tok_per_s());
                m.push(whole);
                *f += s.gen_forwards + 1;
                accepted += s.draft_accepted;
                drafted += s.drafted_tokens;
                outs.push(out);
            }
            same += usize::from(outs[0] == outs[1]);
            turns += 1;
        }
    }
    let per = |n: usize| n as f64 / turns.max(1) as f64;
    Drafting {
        output_tps: (Spread::of(tps.0), Spread::of(tps.1)),
        forwards: (per(forwards.0), per(forwards.1)),
        call_ms: (Spread::of(ms.0), Spread::of(ms.1)),
        accepted,
        drafted,
        same,
        turns,
    }
}

/// One configuration, in this (child) process.
fn measure(cfg: &Config) -> Measured {
    let kind = match cfg.backend.as_str() {
        "candle" | CANDLE_DENSE => BackendKind::Candle,
        _ => BackendKind::Llama,
    };
    let mut opts = LoadOptions::new(cfg.path.clone());
    opts.dense_weights = cfg.backend == CANDLE_DENSE;
    opts.family = Some(cfg.family.clone());
    opts.threads = cfg.threads;
    opts.max_context = header::env_usize("FERROSA_BENCH_CONTEXT", CONTEXT);
    let t = Instant::now();
    let model = backend::load(kind, &opts).expect("load");
    let rss_model = ferrosa::metrics::rss_bytes().unwrap_or(0);
    let constrained = cfg.decoding == "constrained";
    let grammars =
        constrained.then(|| Grammars::new(model.vocab(), model.tokenizer()).expect("grammars"));
    let load_ms = t.elapsed().as_secs_f64() * 1e3;
    let rss_grammars = ferrosa::metrics::rss_bytes()
        .unwrap_or(0)
        .saturating_sub(rss_model);
    let envelope = Envelope::for_family(&cfg.family);
    let mut c = Child {
        model,
        grammars,
        session: Session::new(),
        envelope,
    };

    let specs = offered(&tool_specs());
    let robot = RobotPrompt::parse(ROBOT_PROMPT, "prompts/turtlesim.toml")
        .expect("robot prompt")
        .render();
    let prose_lark = envelope.grammar(&specs, ToolChoice::Auto, false);
    let call_lark = envelope.grammar(&specs, ToolChoice::Required, false);

    let text = "The rover drove slowly across the rocky plain, stopping every few metres \
                to photograph the ground, measure the temperature and report its battery. "
        .repeat(64);
    let mut rover = prompt_tokens(c.model.as_ref(), &text, false).expect("tokenize");
    rover.truncate(PROMPT);
    assert_eq!(rover.len(), PROMPT, "benchmark text too short");
    // Warm-up: page in the weights and let the thread pool spin up.
    c.run(&rover[..16], 4, &prose_lark, false, Draft::OFF);

    let (mut pp, mut tg0, mut tg512) = (Vec::new(), Vec::new(), Vec::new());
    let (mut tool_tps, mut call_tps) = (Vec::new(), Vec::new());
    let (mut forwards, mut valid) = (0usize, 0usize);
    let (mut cold, mut cached) = (Vec::new(), Vec::new());
    let (mut agent_tokens, mut second_new) = (0, 0);
    for run in 0..cfg.runs {
        // Prompt: 512 tokens in one batch, nothing cached.
        c.session.clear();
        let (s, _) = c.run(&rover, 1, &prose_lark, true, Draft::OFF);
        pp.push(s.prompt_tok_per_s());
        // Depth 512: that prompt stays cached; depth 0: one token from the start.
        tg512.push(
            c.run(&rover, GEN, &prose_lark, false, Draft::OFF)
                .0
                .gen_tok_per_s(),
        );
        tg0.push(
            c.run(&rover[..1], GEN, &prose_lark, false, Draft::OFF)
                .0
                .gen_tok_per_s(),
        );
        if cfg.throughput_only {
            continue;
        }

        // A tool-call turn with the agent's handful of tools.
        let q = TOOL_QUERIES[run % TOOL_QUERIES.len()];
        let messages = [
            ChatMessage::new(Role::System, "You control a turtle robot."),
            ChatMessage::new(Role::User, q),
        ];
        let prompt = c.render(&messages, &specs);
        if constrained {
            let (s, out) = c.run(&prompt, 128, &call_lark, true, Draft::OFF);
            call_tps.push(s.output_tok_per_s());
            forwards += s.gen_forwards + 1;
            let text = c.model.vocab().decode_lossy(&out);
            valid += envelope
                .parse(&text, &specs)
                .map_or(0, |t| usize::from(!t.calls.is_empty()));
        }
        // One sampled token per forward: the grammar's cost alone when constrained.
        let (s, out) = c.run(&prompt, 64, &call_lark, false, Draft::OFF);
        tool_tps.push(s.gen_tok_per_s());
        if !constrained {
            let text = c.model.vocab().decode_lossy(&out);
            valid += envelope
                .parse(&text, &specs)
                .map_or(0, |t| usize::from(!t.calls.is_empty()));
        }

        // Time to first token: the robot's instructions and the offered tools (an
        // agent-sized prompt), cold, then a second turn with the first one (and its
        // reply) cached.
        c.session.clear();
        let agent = [
            ChatMessage::new(Role::System, robot.clone()),
            messages[1].clone(),
        ];
        let first = c.render(&agent, &specs);
        let (s, out) = c.run(&first, 48, &call_lark, true, Draft::OFF);
        cold.push(s.time_to_first_token.as_secs_f64() * 1e3);
        let reply = c.model.vocab().decode_lossy(&out);
        let reply = reply
            .trim_end_matches(|ch: char| !ch.is_ascii_graphic())
            .to_string();
        let messages2 = [
            agent[0].clone(),
            agent[1].clone(),
            ChatMessage::new(Role::Assistant, reply),
            ChatMessage::new(Role::User, "and then list the ROS nodes"),
        ];
        let second = c.render(&messages2, &specs);
        let (s, _) = c.run(&second, 48, &call_lark, true, Draft::OFF);
        cached.push(s.time_to_first_token.as_secs_f64() * 1e3);
        agent_tokens = first.len();
        second_new = s.prompt_tokens - s.reused_tokens;
    }
    let file = std::fs::metadata(&cfg.path).map_or(0, |m| m.len());
    let kv = backend::Gguf::open(&cfg.path)
        .ok()
        .and_then(|g| g.kv_cache_bytes(c.model.context_len()))
        .unwrap_or(0);
    Measured {
        config: cfg.clone(),
        load_ms,
        prompt_tps: Spread::of(pp),
        gen_tps_d0: Spread::of(tg0),
        gen_tps_d512: Spread::of(tg512),
        tool_turn_tps: Spread::of(tool_tps),
        call_output_tps: constrained.then(|| Spread::of(call_tps)),
        drafting: constrained.then(|| drafting(&mut c, &specs, &call_lark, cfg.runs)),
        forwards_per_call: constrained.then(|| forwards as f64 / cfg.runs as f64),
        valid_calls: valid,
        tool_turns: cfg.runs,
        ttft_cold_ms: Spread::of(cold),
        ttft_cached_ms: Spread::of(cached),
        agent_prompt_tokens: agent_tokens,
        second_turn_new_tokens: second_new,
        peak_rss_mib: ferrosa::metrics::peak_rss_bytes().map_or(0.0, ferrosa::metrics::mib),
        loaded_rss_mib: ferrosa::metrics::mib(rss_model),
        grammars_mib: ferrosa::metrics::mib(rss_grammars),
        file_mib: ferrosa::metrics::mib(file),
        kv_mib: ferrosa::metrics::mib(kv),
        context: c.model.context_len(),
        resident: Resident::now(&cfg.path),
    }
}

/// Upstream llama-bench on the same file: pp512, tg128 at depth 0 and at depth 512,
/// with the micro-batch ferrosa's llama.cpp runtime uses (`-ub`), so that the ratio
/// compares the runtimes at one setting.
fn llama_bench(bin: &Path, model: &Path, threads: usize, runs: usize) -> Upstream {
    eprintln!("running {} on {} …", bin.display(), model.display());
    let ubatch = upstream_ubatch();
    let out = Command::new(bin)
        .arg("-m")
        .arg(model)
        .args(["-t", &threads.to_string(), "-p", &PROMPT.to_string()])
        .args(["-ub", &ubatch.to_string()])
        .args([
            "-n",
            &GEN.to_string(),
            "-d",
            "0,512",
            "-r",
            &runs.to_string(),
        ])
        .args(["-o", "json"])
        .output();
    let Ok(out) = out else {
        eprintln!("LLAMA_BENCH={}: cannot run", bin.display());
        return Upstream::default();
    };
    let rows: Vec<serde_json::Value> = match serde_json::from_slice(&out.stdout) {
        Ok(r) => r,
        Err(e) => {
            eprintln!(
                "llama-bench output unreadable ({e}): {}",
                String::from_utf8_lossy(&out.stderr)
            );
            return Upstream::default();
        }
    };
    let pick = |np: u64, ng: u64, depth: u64| {
        rows.iter()
            .find(|r| {
                r["n_prompt"].as_u64() == Some(np)
                    && r["n_gen"].as_u64() == Some(ng)
                    && r["n_depth"].as_u64().unwrap_or(0) == depth
            })
            .and_then(|r| r["avg_ts"].as_f64())
    };
    Upstream {
        prompt_tps: pick(PROMPT as u64, 0, 0),
        gen_tps_d0: pick(0, GEN as u64, 0),
        gen_tps_d512: pick(0, GEN as u64, 512),
    }
}

/// The micro-batch llama-bench is given: the one ferrosa's llama.cpp runtime uses, or
/// llama-bench's own default (512) where that runtime is not built.
fn upstream_ubatch() -> usize {
    #[cfg(feature = "llama")]
    return backend::llama::UBATCH;
    #[cfg(not(feature = "llama"))]
    return 512;
}

/// candle's runtimes against llama.cpp's on the same model and decoding, each measured
/// against llama-bench in rounds of its own: the ratio of their median ratios.
fn candle_against_llama(rows: &[(Measured, Interleaved)]) {
    for (c, cu) in rows
        .iter()
        .filter(|(m, u)| m.config.backend != "llama" && u.rounds > 0)
    {
        let Some((_, lu)) = rows.iter().find(|(m, u)| {
            m.config.backend == "llama"
                && m.config.model == c.config.model
                && m.config.decoding == c.config.decoding
                && u.rounds > 0
        }) else {
            continue;
        };
        let r = |a: &Spread, b: &Spread| a.median / b.median.max(1e-9);
        println!();
        println!(
            "{} / {} / {}: {} ÷ llama.cpp (ratio of their median ratios to llama-bench): pp{PROMPT} **{:.2}**, tg{GEN} @0 **{:.2}**, tg{GEN} @{PROMPT} **{:.2}**",
            c.config.model,
            c.config.decoding,
            c.config.backend,
            c.config.backend,
            r(&cu.prompt, &lu.prompt),
            r(&cu.gen_d0, &lu.gen_d0),
            r(&cu.gen_d512, &lu.gen_d512),
        );
    }
}

fn print_table(rows: &[(Measured, Interleaved)]) {
    let fmt = |s: &Spread| format!("{:.0} / **{:.0}** / {:.0}", s.min, s.median, s.max);
    let up = |u: &Interleaved, s: &Spread| match u.rounds {
        0 => "-".to_string(),
        _ => format!("{:.0}", s.median),
    };
    let ratio = |u: &Interleaved, r: &Spread| match u.rounds {
        0 => "-".to_string(),
        _ => format!("**{:.2}** ({:.2}–{:.2})", r.median, r.min, r.max),
    };

    println!("## Throughput (tok/s)");
    println!();
    println!("| model | backend | decoding | load ms | pp{PROMPT} | tg{GEN} @0 | tg{GEN} @{PROMPT} | llama-bench pp / tg@0 / tg@{PROMPT} (interleaved, median) | ratio pp | ratio tg@0 | ratio tg@{PROMPT} | rounds |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (m, u) in rows {
        println!(
            "| {} | {} | {} | {:.0} | {} | {} | {} | {} / {} / {} | {} | {} | {} | {} |",
            m.config.model,
            m.config.backend,
            m.config.decoding,
            m.load_ms,
            fmt(&m.prompt_tps),
            fmt(&m.gen_tps_d0),
            fmt(&m.gen_tps_d512),
            up(u, &u.upstream[0]),
            up(u, &u.upstream[1]),
            up(u, &u.upstream[2]),
            ratio(u, &u.prompt),
            ratio(u, &u.gen_d0),
            ratio(u, &u.gen_d512),
            u.rounds,
        );
    }
    if rows.iter().any(|(_, u)| u.rounds > 0) {
        println!();
        println!(
            "Ratios: ferrosa / llama-bench (`-ub {}`) within each round (upstream, then ferrosa, each in a process of its own, one repetition each), **median** (min–max) over the rounds; ferrosa's own columns are from its separate run of {} repetitions.",
            upstream_ubatch(),
            rows[0].0.config.runs
        );
        candle_against_llama(rows);
    }
    println!();
    println!("## Tool calls, first token, memory");
    println!();
    println!("| model | backend | decoding | tool-turn tok/s (1 token / forward) | call output tok/s (fast-forward) | vs plain tool-turn | forwards / call | calls parsed | TTFT cold ms | TTFT 2nd turn ms | cold / 2nd | RSS after load (+ grammars) MiB | peak RSS MiB | file + KV + {OVERHEAD_MIB:.0} MiB |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (m, _) in rows {
        let plain = rows
            .iter()
            .find(|(p, _)| {
                p.config.decoding == "plain"
                    && p.config.model == m.config.model
                    && p.config.backend == m.config.backend
            })
            .map(|(p, _)| p.tool_turn_tps.median);
        let vs = match (&m.call_output_tps, plain) {
            (Some(c), Some(p)) => format!("{:.2}", c.median / p),
            _ => "-".into(),
        };
        println!(
            "| {} | {} | {} | {} | {} | {vs} | {} | {} / {} | {} | {} | {:.1} | {:.0} (+{:.0}) | {:.0} | {:.0} ({:.0} + {:.0} + {OVERHEAD_MIB:.0}) {} |",
            m.config.model,
            m.config.backend,
            m.config.decoding,
            fmt(&m.tool_turn_tps),
            m.call_output_tps.as_ref().map_or("-".into(), fmt),
            m.forwards_per_call.map_or("-".into(), |f| format!("{f:.1}")),
            m.valid_calls,
            m.tool_turns,
            fmt(&m.ttft_cold_ms),
            fmt(&m.ttft_cached_ms),
            m.ttft_cold_ms.median / m.ttft_cached_ms.median.max(1e-9),
            m.loaded_rss_mib,
            m.grammars_mib,
            m.peak_rss_mib,
            m.budget_mib(),
            m.file_mib,
            m.kv_mib,
            if m.peak_rss_mib <= m.budget_mib() { "within" } else { "**over**" },
        );
    }
    drafting_table(rows);
    if let Some((m, _)) = rows.first() {
        println!();
        println!(
            "Time to first token: a {}-token prompt (the sim's robot prompt file and the offered tools), nothing cached; then a second turn adding {} tokens to it. Context {} tokens; KV cache f16.",
            m.agent_prompt_tokens, m.second_turn_new_tokens, m.context
        );
    }
    println!();
    println!("## Where resident memory goes (MiB, at the end of each configuration's run)");
    println!();
    println!("| model | backend | decoding | weights file | code (executable, libraries) | anonymous (KV cache, compute buffers, heap) | other files | KV cache (computed) | peak RSS |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for (m, _) in rows {
        let r = &m.resident;
        println!(
            "| {} | {} | {} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} |",
            m.config.model,
            m.config.backend,
            m.config.decoding,
            r.model_mib,
            r.code_mib,
            r.anonymous_mib,
            r.other_mib,
            m.kv_mib,
            m.peak_rss_mib,
        );
    }
    println!();
}

fn draw(rows: &[(Measured, Interleaved)], path: &Path) -> Result<(), String> {
    let label = |m: &Measured| {
        format!(
            "{} {} {}",
            m.config.model, m.config.backend, m.config.decoding
        )
    };
    let mut speed = chart::Bars::new("tok/s (median)", &["pp512", "tg128 @0", "tool-call output"]);
    let mut memory = chart::Bars::new("MiB", &["peak RSS", "file + KV + 64 MiB"]);
    for (m, u) in rows {
        let out = m
            .call_output_tps
            .as_ref()
            .map_or(m.tool_turn_tps.median, |s| s.median);
        speed.group(&label(m), &[m.prompt_tps.median, m.gen_tps_d0.median, out]);
        memory.group(&label(m), &[m.peak_rss_mib, m.budget_mib()]);
        if m.config.decoding == "plain" && m.config.backend == "llama" && u.rounds > 0 {
            let [p, g, _] = &u.upstream;
            speed.group(
                &format!("{} llama-bench", m.config.model),
                &[p.median, g.median, 0.0],
            );
        }
    }
    chart::draw(path, "ferrosa runtime, 2 CPU threads", &[speed, memory])
}
