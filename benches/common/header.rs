//! What every benchmark prints first (machine, versions, revision) and the small helpers
//! they share: settings from the environment and min / median / max summaries.

#![allow(dead_code)] // each bench uses its own share of these

use std::path::{Path, PathBuf};
use std::process::Command;

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Spread {
    pub min: f64,
    pub median: f64,
    pub max: f64,
}

impl Spread {
    /// Of at least one value; an empty list gives zeros.
    pub fn of(mut v: Vec<f64>) -> Spread {
        if v.is_empty() {
            return Spread::default();
        }
        v.sort_by(f64::total_cmp);
        Spread {
            min: v[0],
            median: v[v.len() / 2],
            max: v[v.len() - 1],
        }
    }
}

pub fn env_usize(key: &str, default: usize) -> usize {
    std::env::var(key)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Whether `name` passes the comma list in `key` (unset: everything passes).
pub fn wanted(key: &str, name: &str) -> bool {
    std::env::var(key)
        .map(|v| v.split(',').any(|x| x.trim() == name))
        .unwrap_or(true)
}

pub fn models_dir() -> PathBuf {
    std::env::var_os("FERROSA_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models"))
}

/// The version of `name` locked in Cargo.lock.
fn locked_version(lock: &str, name: &str) -> String {
    let needle = format!("name = \"{name}\"\nversion = \"");
    lock.find(&needle)
        .map(|i| {
            let rest = &lock[i + needle.len()..];
            rest[..rest.find('"').unwrap_or(0)].to_string()
        })
        .unwrap_or_else(|| "?".into())
}

/// Title, machine, crate versions and git revision, then `settings`.
pub fn print(title: &str, root: &Path, settings: &str) {
    let git = Command::new("git")
        .args(["describe", "--always", "--dirty"])
        .current_dir(root)
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default();
    let lock = std::fs::read_to_string(root.join("Cargo.lock")).unwrap_or_default();
    println!("# {title}");
    println!();
    println!(
        "CPU: {} | logical CPUs: {} | physical cores: {} | {settings}",
        ferrosa::metrics::cpu_model().unwrap_or_default(),
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        ferrosa::backend::physical_cores(),
    );
    println!(
        "ferrosa {} (git {git}) | llama-cpp-2 {} | candle-core {} | llguidance {} | ros2-client {}",
        env!("CARGO_PKG_VERSION"),
        locked_version(&lock, "llama-cpp-2"),
        locked_version(&lock, "candle-core"),
        locked_version(&lock, "llguidance"),
        locked_version(&lock, "ros2-client"),
    );
    println!();
}
