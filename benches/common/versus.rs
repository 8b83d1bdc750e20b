//! Two builds of `ferrosa` side by side on one set of requests: each binary runs as an
//! operator runs it (`ferrosa chat --robot sim --yes`, its own built-in sim on its own
//! ROS domain, its own empty prompt cache), the requests typed one after another with
//! `/clear` between them, and each request's times read back from the session's trace
//! (`--trace-dir`): query to the first call written whole, and query to the answer. The
//! trace format is the one every build since the agent's first has written, so an older
//! commit's binary is measured by the same reading.

#![allow(dead_code)] // the agent bench uses it; nothing else does

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde::Serialize;
use serde_json::Value;

/// One request as one build answered it.
#[derive(Debug, Clone, Serialize)]
pub struct Timed {
    pub request: String,
    /// Query to the first call written whole; `None` when no call was made.
    pub first_call_ms: Option<f64>,
    /// Query to the answer.
    pub answer_ms: f64,
    pub calls: Vec<String>,
    pub answer: String,
}

/// Run `requests` through `bin`'s chat, after one `warm_up` request that is not
/// measured (it evaluates the system prompt into an empty prompt cache), within
/// `limit_s` seconds. `domain`: the ROS domain of its sim, one no other sim uses;
/// `env`: settings of the run.
pub fn chat(
    bin: &Path,
    root: &Path,
    warm_up: &str,
    requests: &[&str],
    domain: u32,
    limit_s: u32,
    extra: &[&str],
) -> Result<Vec<Timed>, String> {
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let traces = dir.path().join("trace");
    let mut child = Command::new("timeout")
        .args(["-k", "5", &limit_s.to_string()])
        .arg(bin)
        .args(["chat", "--robot", "sim", "--yes"])
        .args(extra)
        .arg("--trace-dir")
        .arg(&traces)
        .current_dir(root)
        .env("ROS_DOMAIN_ID", domain.to_string())
        .env("FERROSA_CACHE_DIR", dir.path().join("cache"))
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot start {}: {e}", bin.display()))?;
    // One request at a time, as an operator types them: the chat's input is read as it
    // comes (a stop typed while a run goes on is taken at once), so the next line is
    // written only once the trace holds the last one's times.
    let mut stdin = child.stdin.take().expect("piped stdin");
    for (i, q) in std::iter::once(&warm_up).chain(requests).enumerate() {
        writeln!(stdin, "{q}").map_err(|e| format!("{}: {e}", bin.display()))?;
        stdin.flush().map_err(|e| e.to_string())?;
        let since = Instant::now();
        while finished(&traces) <= i {
            if since.elapsed() > PER_REQUEST || child.try_wait().ok().flatten().is_some() {
                let _ = child.kill();
                return Err(format!("{}: no answer to {q:?}", bin.display()));
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        writeln!(stdin, "/clear").map_err(|e| e.to_string())?;
    }
    writeln!(stdin, "/quit").map_err(|e| e.to_string())?;
    drop(stdin);
    let out = child.wait_with_output().map_err(|e| e.to_string())?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let tail: String = err
            .chars()
            .rev()
            .take(600)
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        return Err(format!(
            "{} exited with {}: {tail}",
            bin.display(),
            out.status
        ));
    }
    let mut runs = read_traces(&traces)?;
    if runs.len() != requests.len() + 1 {
        return Err(format!(
            "{}: {} requests in its trace, {} typed",
            bin.display(),
            runs.len(),
            requests.len() + 1
        ));
    }
    runs.remove(0);
    Ok(runs)
}

/// How long one request may take before the run is given up.
const PER_REQUEST: Duration = Duration::from_secs(180);

/// How many requests the session files under `dir` hold the times of.
fn finished(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    entries
        .filter_map(|e| std::fs::read_to_string(e.ok()?.path()).ok())
        .map(|text| {
            text.lines()
                .filter(|l| l.contains("\"kind\":\"timings\""))
                .count()
        })
        .sum()
}

/// Every request of the session files under `dir`, in order.
fn read_traces(dir: &Path) -> Result<Vec<Timed>, String> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| format!("no trace in {}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    files.sort();
    let mut runs: Vec<Timed> = Vec::new();
    for f in files {
        let text = std::fs::read_to_string(&f).map_err(|e| e.to_string())?;
        for line in text.lines() {
            let Ok(r) = serde_json::from_str::<Value>(line) else {
                continue;
            };
            match (r["kind"].as_str(), r["event"].as_str()) {
                (Some("query"), _) => runs.push(Timed {
                    request: r["query"].as_str().unwrap_or_default().to_string(),
                    first_call_ms: None,
                    answer_ms: 0.0,
                    calls: Vec::new(),
                    answer: String::new(),
                }),
                (Some("event"), Some("tool_call")) => {
                    if let Some(run) = runs.last_mut() {
                        run.calls
                            .push(r["name"].as_str().unwrap_or_default().to_string());
                    }
                }
                (Some("event"), Some("answer")) => {
                    if let Some(run) = runs.last_mut() {
                        run.answer = r["text"].as_str().unwrap_or_default().to_string();
                    }
                }
                (Some("timings"), _) => {
                    if let Some(run) = runs.last_mut() {
                        run.first_call_ms = r["first_call_ms"].as_f64();
                        run.answer_ms = r["total_ms"].as_f64().unwrap_or_default();
                    }
                }
                _ => {}
            }
        }
    }
    Ok(runs)
}

/// The value at fraction `q` of `v` (nearest rank); 0 for none.
pub fn quantile(v: &[f64], q: f64) -> f64 {
    let mut v = v.to_vec();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[rank - 1]
}
