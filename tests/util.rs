//! Shared test helpers: where the real weights are, and loading them.

use std::path::PathBuf;

use ferrosa::backend::{self, Backend, BackendKind, LoadOptions};

pub fn models_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models")
}

pub fn model_path(name: &str) -> PathBuf {
    let resolved = ferrosa::models::resolve(Some(name), &models_dir()).unwrap_or_else(|e| {
        panic!(
            "{e}\n(the tests need real weights: run `cargo run --release -- models fetch --all`)"
        )
    });
    resolved.path
}

pub fn load(name: &str, kind: BackendKind, max_context: usize) -> Box<dyn Backend> {
    let path = model_path(name);
    let mut opts = LoadOptions::new(path);
    opts.max_context = max_context;
    opts.family = ferrosa::models::Catalog::load(&models_dir())
        .ok()
        .and_then(|c| c.get(name).map(|e| e.family.clone()));
    backend::load(kind, &opts).unwrap_or_else(|e| panic!("loading {name} with {kind:?}: {e}"))
}

/// Greedy continuation of `prompt` (tokenized with special tokens), `n` tokens.
pub fn greedy(model: &mut dyn Backend, prompt: &str, n: usize) -> Vec<u32> {
    let mut ids: Vec<u32> = model.vocab().bos().into_iter().collect();
    ids.extend(model.tokenize(prompt, true).unwrap());
    greedy_after(model, &mut ferrosa::decode::Session::new(), &ids, n)
}

/// Greedy continuation of the prompt `ids` through `session`, `n` tokens.
pub fn greedy_after(
    model: &mut dyn Backend,
    session: &mut ferrosa::decode::Session,
    ids: &[u32],
    n: usize,
) -> Vec<u32> {
    use ferrosa::decode::{generate, JsonScan, NoHook, Sampler, SamplerConfig, Steering};
    let mut sampler = Sampler::new(SamplerConfig::default(), model.vocab().len());
    let mut out = Vec::new();
    generate(
        model,
        session,
        ids,
        n,
        Steering {
            sampler: &mut sampler,
            constraint: None,
            hook: &mut NoHook,
            scan: &mut JsonScan::new(),
            draft: ferrosa::decode::Draft::OFF,
        },
        |t, _| {
            out.push(t);
            std::ops::ControlFlow::Continue(())
        },
    )
    .unwrap();
    out
}

/// Tests that open a DDS participant run inside a network namespace with only loopback,
/// so no DDS traffic can leave the machine, under a hard time limit.
///
/// Call first in such a test: outside the namespace it re-runs this one test inside
/// one (`unshare -n`, `ip link set lo up`, `timeout`) and returns true (the caller
/// returns); inside, it returns false and the test body runs.
pub fn rerun_in_loopback_netns(test: &str, limit_s: u32) -> bool {
    if crate::support::netns::inside() {
        return false;
    }
    let exe = std::env::current_exe().expect("the test binary");
    // The tests that need a namespace are in the ignored tier: the child must run it.
    let status = crate::support::netns::loopback_netns(
        &exe,
        [
            "--exact",
            test,
            "--nocapture",
            "--test-threads=1",
            "--include-ignored",
        ],
        limit_s,
    )
    .status()
    .expect("unshare (util-linux) and ip (iproute2) are needed for the ROS tests; run as root");
    assert!(
        status.success(),
        "{test} inside the loopback-only namespace: {status}"
    );
    true
}

/// A multi-threaded tokio runtime for async tests.
pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("tokio runtime")
}

/// The agent's arguments as an operator's defaults give them, on `robot` with the
/// default model on 2 threads; `yes` approves every actuating call.
pub fn agent_args(robot: ferrosa::ui::agent::Robot, yes: bool) -> ferrosa::ui::agent::AgentArgs {
    ferrosa::ui::agent::AgentArgs {
        model: ferrosa::ui::ModelArgs {
            models_dir: models_dir(),
            model: None,
            backend: ferrosa::backend::BackendKind::Llama,
            threads: Some(2),
            max_context: 8192,
            prompt_cache: true,
            draft: ferrosa::decode::Draft::default(),
            remote: None,
            adapter: "default".into(),
            dense_weights: false,
        },
        yes,
        read_only: false,
        policy: None,
        prompt: None,
        trace_dir: None,
        log_dirs: Vec::new(),
        tools: Vec::new(),
        max_steps: 6,
        decoding: ferrosa::decode::Decoding::Constrained,
        answer_mode: Default::default(),
        robot,
        copy_bias: ferrosa::ui::agent::DEFAULT_COPY_BIAS,
        pick: Default::default(),
        language: None,
        verbose: false,
        listing: ferrosa::ui::agent::Listing::All,
        memory: None,
    }
}

/// Ask `q` afresh, print the steps and the answer, and return the run with that text
/// (for assertion messages).
pub fn ask_shown(
    agent: &mut ferrosa::agent::Agent,
    q: &str,
) -> (ferrosa::agent::RunResult, String) {
    agent.clear();
    let r = agent.ask(q, &mut |_| {}).unwrap();
    let shown: Vec<String> = r
        .steps
        .iter()
        .map(|s| format!("{} {} ok={} {}", s.name, s.arguments, s.ok, s.output))
        .collect();
    eprintln!("{q}\n  {}\n  → {}", shown.join("\n  "), r.answer);
    let why = format!("{q}: {shown:#?} → {:?}", r.answer);
    (r, why)
}

/// Stop a child started under `timeout` as a terminal would: TERM, which `timeout`
/// passes on (a KILL would end `timeout` alone and leave its child running), then KILL
/// if it has not ended after 5 s.
pub fn stop(child: &mut std::process::Child) {
    let _ = std::process::Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    let start = std::time::Instant::now();
    while matches!(child.try_wait(), Ok(None))
        && start.elapsed() < std::time::Duration::from_secs(5)
    {
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let _ = child.kill();
    let _ = child.wait();
}

/// Start `cmd` with its stderr piped and read that until a line starts with `prefix`
/// (within `limit`); the rest of that line. Later lines are echoed as `label: line`.
pub fn spawn_until(
    cmd: &mut std::process::Command,
    prefix: &str,
    label: &'static str,
    limit: std::time::Duration,
) -> (std::process::Child, String) {
    use std::io::BufRead;
    let mut child = cmd
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("running {label}: {e}"));
    let mut lines = std::io::BufReader::new(child.stderr.take().unwrap()).lines();
    let start = std::time::Instant::now();
    let rest = loop {
        let line = lines
            .next()
            .unwrap_or_else(|| panic!("{label} ended before printing {prefix:?}"))
            .unwrap();
        eprintln!("{label}: {line}");
        if let Some(rest) = line.strip_prefix(prefix) {
            break rest.to_string();
        }
        assert!(start.elapsed() < limit, "no {prefix:?} yet: {line}");
    };
    std::thread::spawn(move || lines.for_each(|l| eprintln!("{label}: {}", l.unwrap_or_default())));
    (child, rest)
}
