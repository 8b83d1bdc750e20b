//! `cargo bench --bench runtime`: prompt and generation tok/s, load time and peak RSS of
//! every catalog model present × every compiled backend, at a fixed thread count, each
//! configuration in its own child process so one cannot inflate the next one's memory.
//! With `LLAMA_BENCH=/path/to/llama-bench`, upstream's figures on the same files and
//! threads are printed beside ours, with the ratio.
//!
//! Settings (environment): FERROSA_BENCH_RUNS (5), FERROSA_BENCH_THREADS (physical
//! cores), FERROSA_BENCH_MODELS / FERROSA_BENCH_BACKENDS (comma lists to restrict).
//! Output: a markdown table on stdout, JSON in target/bench/runtime.json.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use ferrosa::backend::{self, BackendKind, LoadOptions, TokenId};
use ferrosa::decode::sample::argmax;
use ferrosa::models::Catalog;
use serde::{Deserialize, Serialize};

const CHILD_ENV: &str = "FERROSA_BENCH_CHILD";
const PROMPT: usize = 512;
const GEN: usize = 128;

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Config {
    model: String,
    path: PathBuf,
    family: String,
    backend: String,
    threads: usize,
    runs: usize,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct Spread {
    min: f64,
    median: f64,
    max: f64,
}

impl Spread {
    fn of(mut v: Vec<f64>) -> Spread {
        v.sort_by(f64::total_cmp);
        Spread {
            min: v[0],
            median: v[v.len() / 2],
            max: v[v.len() - 1],
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Measured {
    config: Config,
    load_ms: f64,
    prompt_tps: Spread,
    gen_tps_d0: Spread,
    gen_tps_d512: Spread,
    peak_rss_mib: f64,
    file_mib: f64,
    context: usize,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct Upstream {
    prompt_tps: Option<f64>,
    gen_tps_d0: Option<f64>,
    gen_tps_d512: Option<f64>,
}

fn env_usize(key: &str, default: usize) -> usize {
    std::env::var(key)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    if let Ok(cfg) = std::env::var(CHILD_ENV) {
        let cfg: Config = serde_json::from_str(&cfg).expect("child config");
        let m = measure(&cfg);
        println!("{}", serde_json::to_string(&m).expect("serialise"));
        return;
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let dir = std::env::var_os("FERROSA_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("models"));
    let catalog = Catalog::load(&dir).expect("catalog");
    let runs = env_usize("FERROSA_BENCH_RUNS", 5).max(1);
    let threads = env_usize("FERROSA_BENCH_THREADS", backend::physical_cores());
    let want = |key: &str, name: &str| {
        std::env::var(key)
            .map(|v| v.split(',').any(|x| x.trim() == name))
            .unwrap_or(true)
    };

    print_header(&root, threads, runs);
    let mut rows = Vec::new();
    for e in &catalog.model {
        let path = dir.join(&e.file);
        if !path.exists() || !want("FERROSA_BENCH_MODELS", &e.name) {
            continue;
        }
        let arch = backend::Gguf::open(&path)
            .ok()
            .and_then(|g| g.architecture().map(str::to_string))
            .unwrap_or_default();
        let upstream = std::env::var_os("LLAMA_BENCH")
            .map(|b| llama_bench(Path::new(&b), &path, threads, runs))
            .unwrap_or_default();
        for kind in [BackendKind::Llama, BackendKind::Candle] {
            let compiled = match kind {
                BackendKind::Llama => cfg!(feature = "llama"),
                BackendKind::Candle => cfg!(feature = "candle") && arch == "llama",
            };
            if !compiled || !want("FERROSA_BENCH_BACKENDS", kind.name()) {
                continue;
            }
            let cfg = Config {
                model: e.name.clone(),
                path: path.clone(),
                family: e.family.clone(),
                backend: kind.name().to_string(),
                threads,
                runs,
            };
            match run_child(&cfg) {
                Ok(m) => rows.push((m, upstream.clone())),
                Err(err) => eprintln!("{} / {}: {err}", e.name, kind.name()),
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
    eprintln!("wrote {}", file.display());
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

/// One configuration, in this (child) process.
fn measure(cfg: &Config) -> Measured {
    let kind = match cfg.backend.as_str() {
        "candle" => BackendKind::Candle,
        _ => BackendKind::Llama,
    };
    let mut opts = LoadOptions::new(cfg.path.clone());
    opts.family = Some(cfg.family.clone());
    opts.threads = cfg.threads;
    // Prompt plus generation, as llama-bench sizes its context.
    opts.max_context = PROMPT + GEN + 16;
    let t = Instant::now();
    let mut model = backend::load(kind, &opts).expect("load");
    let load_ms = t.elapsed().as_secs_f64() * 1e3;

    let text = "The rover drove slowly across the rocky plain, stopping every few metres \
                to photograph the ground, measure the temperature and report its battery. "
        .repeat(64);
    let mut prompt: Vec<TokenId> = model.vocab().bos().into_iter().collect();
    prompt.extend(model.tokenize(&text, false).expect("tokenize"));
    prompt.truncate(PROMPT);
    assert_eq!(prompt.len(), PROMPT, "benchmark text too short");

    // Warm-up: page in the weights and let the thread pool spin up.
    model.forward(0, &prompt[..16]).expect("warm-up");
    let gen = |model: &mut Box<dyn backend::Backend>, start: usize| -> f64 {
        let first = argmax(
            model
                .forward(start, &prompt[start..start + 1])
                .expect("forward"),
        )
        .expect("a token");
        let t = Instant::now();
        let mut tok = first;
        for i in 0..GEN {
            let logits = model.forward(start + 1 + i, &[tok]).expect("forward");
            tok = argmax(logits).expect("a token");
        }
        GEN as f64 / t.elapsed().as_secs_f64()
    };
    let mut pp = Vec::new();
    let mut tg0 = Vec::new();
    let mut tg512 = Vec::new();
    for _ in 0..cfg.runs {
        let t = Instant::now();
        model.forward(0, &prompt).expect("prompt");
        pp.push(PROMPT as f64 / t.elapsed().as_secs_f64());
        // Depth 512: the prompt just evaluated stays in the cache.
        tg512.push(gen(&mut model, PROMPT - 1));
        tg0.push(gen(&mut model, 0));
    }
    Measured {
        config: cfg.clone(),
        load_ms,
        prompt_tps: Spread::of(pp),
        gen_tps_d0: Spread::of(tg0),
        gen_tps_d512: Spread::of(tg512),
        peak_rss_mib: ferrosa::metrics::peak_rss_bytes().map_or(0.0, ferrosa::metrics::mib),
        file_mib: std::fs::metadata(&cfg.path).map_or(0.0, |m| ferrosa::metrics::mib(m.len())),
        context: model.context_len(),
    }
}

/// Upstream llama-bench on the same file: pp512, tg128 at depth 0 and at depth 512.
fn llama_bench(bin: &Path, model: &Path, threads: usize, runs: usize) -> Upstream {
    let out = Command::new(bin)
        .arg("-m")
        .arg(model)
        .args(["-t", &threads.to_string(), "-p", &PROMPT.to_string()])
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

fn print_header(root: &Path, threads: usize, runs: usize) {
    let git = Command::new("git")
        .args(["rev-parse", "--short", "HEAD"])
        .current_dir(root)
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default();
    let lock = std::fs::read_to_string(root.join("Cargo.lock")).unwrap_or_default();
    let version = |name: &str| {
        let needle = format!("name = \"{name}\"\nversion = \"");
        lock.find(&needle)
            .map(|i| {
                let rest = &lock[i + needle.len()..];
                rest[..rest.find('"').unwrap_or(0)].to_string()
            })
            .unwrap_or_else(|| "?".into())
    };
    println!("# ferrosa runtime benchmark");
    println!();
    println!(
        "CPU: {} | logical CPUs: {} | physical cores: {} | threads: {threads} | runs: {runs}",
        ferrosa::metrics::cpu_model().unwrap_or_default(),
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        backend::physical_cores(),
    );
    println!(
        "ferrosa {} (git {git}) | llama-cpp-2 {} | candle-core {}",
        env!("CARGO_PKG_VERSION"),
        version("llama-cpp-2"),
        version("candle-core"),
    );
    println!(
        "prompt: {PROMPT} tokens in one batch; generation: {GEN} tokens, greedy, at depth 0 and {PROMPT}; figures min / median / max tok/s"
    );
    println!();
}

fn print_table(rows: &[(Measured, Upstream)]) {
    println!("| model | backend | load ms | pp{PROMPT} tok/s | tg{GEN} @0 tok/s | tg{GEN} @{PROMPT} tok/s | peak RSS MiB (file) | llama-bench pp / tg@0 / tg@{PROMPT} | ratio pp / tg@0 / tg@{PROMPT} |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let fmt = |s: &Spread| format!("{:.0} / **{:.0}** / {:.0}", s.min, s.median, s.max);
    let opt = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.0}"));
    let ratio =
        |ours: f64, up: Option<f64>| up.map_or("-".to_string(), |u| format!("{:.2}", ours / u));
    for (m, u) in rows {
        println!(
            "| {} | {} | {:.0} | {} | {} | {} | {:.0} ({:.0}) | {} / {} / {} | {} / {} / {} |",
            m.config.model,
            m.config.backend,
            m.load_ms,
            fmt(&m.prompt_tps),
            fmt(&m.gen_tps_d0),
            fmt(&m.gen_tps_d512),
            m.peak_rss_mib,
            m.file_mib,
            opt(u.prompt_tps),
            opt(u.gen_tps_d0),
            opt(u.gen_tps_d512),
            ratio(m.prompt_tps.median, u.prompt_tps),
            ratio(m.gen_tps_d0.median, u.gen_tps_d0),
            ratio(m.gen_tps_d512.median, u.gen_tps_d512),
        );
    }
}
