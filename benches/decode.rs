//! `cargo bench --bench decode`: the cost of constrained decoding.
//!
//! 1. Mask time per token (mean, p99) when llguidance computes the full allowed-token
//!    mask, replaying a realistic tool call (JSON) and a prose answer (free text) token by
//!    token, on the vocabulary of each catalog model present (SmolLM2 49k, Gemma 3 262k).
//!    The criterion groups `mask/*` time the same replays.
//! 2. Generation on the real default model, same prompt and depth: plain tok/s (one
//!    sampled token per forward pass), constrained tok/s (sampled tokens per second with
//!    the grammar checking every one), and the tool-call output rate (JSON tokens per
//!    second, forced ones included), with forward passes per call.
//!
//! No wall-clock assertion anywhere: this prints figures and the machine.

#[path = "common/header.rs"]
mod header;

use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use criterion::{BatchSize, Criterion, Throughput};
use ferrosa::backend::{self, Backend, BackendKind, LoadOptions, TokenId};
use ferrosa::chat::{ChatMessage, Role};
use ferrosa::decode::envelope::{Envelope, ToolChoice};
use ferrosa::decode::request::{with_tools, TurnRequest};
use ferrosa::decode::{
    generate, Constraint, Decoding, Grammars, JsonScan, NoHook, Sampler, SamplerConfig, Session,
    Steering,
};
use ferrosa::models::Catalog;
use ferrosa::tool::{specs_from_json, ToolCall, ToolSpec};
use serde_json::json;

struct Case {
    label: String,
    lark: String,
    tokens: Vec<TokenId>,
}

fn specs() -> Vec<ToolSpec> {
    specs_from_json(include_str!("../tests/data/robot_tools.json")).expect("tool specs")
}

/// Replay `tokens` under `lark`, timing the full mask at every step.
fn replay(grammars: &Grammars, case: &Case) -> Vec<Duration> {
    replay_with(grammars.compile(&case.lark).expect("grammar"), case)
}

fn replay_with(mut c: Constraint, case: &Case) -> Vec<Duration> {
    let mut times = Vec::with_capacity(case.tokens.len());
    for &t in &case.tokens {
        let start = Instant::now();
        let mask = c.compute_mask().expect("mask");
        times.push(start.elapsed());
        assert!(
            mask.is_allowed(t),
            "{}: replayed token {t} not allowed",
            case.label
        );
        c.advance(t).expect("advance");
    }
    times
}

fn cases(model: &dyn Backend, family: &str) -> Vec<Case> {
    let specs = specs();
    let env = Envelope::for_family(family);
    let call = ToolCall {
        name: "ros_topic_echo".into(),
        arguments: json!({"topic": "/turtle1/pose", "count": 3, "timeout_s": 2.5}),
    };
    let json_text = env.render_calls(&[call]);
    let prose = "The turtle is at x 5.54 and y 5.54, facing east. Its battery is at 87 percent \
                 and no errors were logged in the last minute, so it is ready to move.";
    let tok = |s: &str| model.tokenize(s, false).expect("tokenize");
    vec![
        Case {
            label: format!("{family}/tool_json"),
            lark: env.grammar(&specs, ToolChoice::Required, true),
            tokens: tok(&json_text),
        },
        Case {
            label: format!("{family}/free_text"),
            lark: env.grammar(&specs, ToolChoice::Auto, true),
            tokens: tok(prose),
        },
    ]
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    sorted[((sorted.len() as f64 - 1.0) * p).round() as usize]
}

fn main() {
    let dir = header::models_dir();
    let catalog = Catalog::load(&dir).expect("catalog");
    println!("# ferrosa decode benchmark");
    println!(
        "CPU: {} | threads for the model: {}",
        ferrosa::metrics::cpu_model().unwrap_or_default(),
        backend::physical_cores()
    );
    println!();
    println!("## Mask time per token (full mask computed at every step, one thread)");
    println!();
    println!("| vocabulary | trace | steps | mean µs | p99 µs | max µs | set-up ms |");
    println!("|---|---|---|---|---|---|---|");
    for e in &catalog.model {
        let path = dir.join(&e.file);
        if !path.exists() {
            continue;
        }
        let mut opts = LoadOptions::new(path);
        opts.family = Some(e.family.clone());
        opts.max_context = 4096;
        let model = backend::load(BackendKind::Llama, &opts).expect("load");
        let t = Instant::now();
        let grammars = Grammars::new(model.vocab(), model.tokenizer()).expect("grammars");
        let setup = t.elapsed();
        let traces = cases(model.as_ref(), &e.family);
        for case in &traces {
            let mut all = Vec::new();
            for _ in 0..20 {
                all.extend(replay(&grammars, case));
            }
            all.sort();
            let mean = all.iter().sum::<Duration>() / all.len() as u32;
            println!(
                "| {} ({}) | {} | {} | {:.1} | {:.1} | {:.1} | {:.0} |",
                e.name,
                model.vocab().len(),
                case.label,
                case.tokens.len(),
                mean.as_secs_f64() * 1e6,
                percentile(&all, 0.99).as_secs_f64() * 1e6,
                all.last().map_or(0.0, |d| d.as_secs_f64() * 1e6),
                setup.as_secs_f64() * 1e3,
            );
        }
        if e.name == catalog.default {
            generation(model, &grammars);
        }
        let mut c = Criterion::default()
            .configure_from_args()
            .measurement_time(Duration::from_secs(3))
            .warm_up_time(Duration::from_secs(1));
        let mut group = c.benchmark_group(format!("mask/{}", e.name));
        for case in &traces {
            group.throughput(Throughput::Elements(case.tokens.len() as u64));
            // Compile outside the timed part: this times masks, not grammar compilation.
            group.bench_function(case.label.clone(), |b| {
                b.iter_batched(
                    || grammars.compile(&case.lark).expect("grammar"),
                    |c| replay_with(c, case),
                    BatchSize::SmallInput,
                )
            });
        }
        group.finish();
    }
}

/// Plain vs constrained generation on the real model at the same prompt and depth.
fn generation(mut model: Box<dyn Backend>, grammars: &Grammars) {
    let specs: Vec<ToolSpec> = specs()
        .into_iter()
        .filter(|s| {
            [
                "ros_topic_echo",
                "ros_topic_list",
                "ros_node_list",
                "turtle_move",
                "turtle_rotate",
                "calc_stats",
            ]
            .contains(&s.name.as_str())
        })
        .collect();
    let queries = [
        "read 3 messages from /turtle1/pose",
        "move the turtle forward 2 meters",
        "what is the mean of 3, 5 and 10?",
        "list the topics under /turtle1",
        "turn right 45 degrees",
    ];
    let runs = std::env::var("FERROSA_BENCH_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(5usize);
    let (mut plain, mut constrained, mut output) = (Vec::new(), Vec::new(), Vec::new());
    let (mut forwards, mut calls, mut forced, mut emitted) = (0usize, 0usize, 0usize, 0usize);
    let n_vocab = model.vocab().len();
    for _ in 0..runs {
        for q in queries {
            let messages = [
                ChatMessage::new(Role::System, "You control a turtle robot."),
                ChatMessage::new(Role::User, q),
            ];
            let req = TurnRequest {
                messages: &messages,
                specs: &specs,
                allowed: None,
                envelope: Envelope::Smollm2,
                choice: ToolChoice::Required,
                parallel: false,
                decoding: Decoding::Constrained,
                max_tokens: 128,
            };
            let rendered = model
                .chat_template()
                .render(&with_tools(&req), None, true)
                .expect("template");
            let prompt = model.tokenize(&rendered, true).expect("tokenize");
            let lark = req.envelope.grammar(&specs, req.choice, req.parallel);
            let mut session = Session::new();
            let mut run = |model: &mut Box<dyn Backend>, ff: Option<bool>, max: usize| {
                let mut c = ff.map(|on| {
                    let mut c = grammars.compile(&lark).expect("grammar");
                    c.set_fast_forward(on);
                    c
                });
                let mut text = Vec::new();
                let mut sampler = Sampler::new(SamplerConfig::default(), n_vocab);
                let (_, s) = generate(
                    model.as_mut(),
                    &mut session,
                    &prompt,
                    max,
                    Steering {
                        sampler: &mut sampler,
                        constraint: c.as_mut(),
                        hook: &mut NoHook,
                        scan: &mut JsonScan::new(),
                        draft: ferrosa::decode::Draft::OFF,
                    },
                    |t, _| {
                        text.push(t);
                        ControlFlow::Continue(())
                    },
                )
                .expect("generate");
                (s, text)
            };
            // Tool-call output rate: fast-forward on.
            let (s, text) = run(&mut model, Some(true), 128);
            output.push(s.output_tok_per_s());
            forwards += s.gen_forwards + 1;
            forced += s.forced_tokens;
            emitted += s.generated_tokens;
            let text = model.vocab().decode_lossy(&text);
            calls += req
                .envelope
                .parse(&text, &specs)
                .map(|t| t.calls.len())
                .unwrap_or(0);
            // Grammar overhead alone: every token sampled and checked, one per forward.
            let (s, _) = run(&mut model, Some(false), 128);
            constrained.push(s.gen_tok_per_s());
            // Plain: the same prompt and the same number of single-token forwards.
            let (p, _) = run(&mut model, None, s.gen_forwards + 1);
            plain.push(p.gen_tok_per_s());
        }
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (p, c, o) = (median(plain), median(constrained), median(output));
    println!();
    println!(
        "## Generation, real model, same prompt and depth ({} turns)",
        queries.len() * runs
    );
    println!();
    println!("| mode | tok/s (median) | vs plain |");
    println!("|---|---|---|");
    println!("| plain (1 sampled token per forward) | {p:.1} | 1.00 |");
    println!(
        "| constrained, no fast-forward (every token sampled and checked) | {c:.1} | {:.2} |",
        c / p
    );
    println!(
        "| tool-call output rate, fast-forward on (forced tokens included) | {o:.1} | {:.2} |",
        o / p
    );
    println!();
    println!(
        "{calls} calls; {:.1} forward passes per call with fast-forward; {forced} of {emitted} tokens forced ({:.0}%)",
        forwards as f64 / calls.max(1) as f64,
        100.0 * forced as f64 / emitted.max(1) as f64
    );
    println!();
}
