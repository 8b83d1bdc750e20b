//! How to load a model: which runtime, the file, threads, context and batch sizes.

use std::path::PathBuf;

/// Which runtime to load.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BackendKind {
    /// llama.cpp (llama-cpp-2)
    #[default]
    Llama,
    /// candle, pure Rust
    Candle,
}

impl BackendKind {
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Llama => "llama",
            BackendKind::Candle => "candle",
        }
    }
}

/// How to load a model.
#[derive(Debug, Clone)]
pub struct LoadOptions {
    pub path: PathBuf,
    /// Model family from the catalog ("smollm2", "gemma3"); picks the fallback template.
    pub family: Option<String>,
    /// Threads for generation and batch evaluation; default: physical cores.
    pub threads: usize,
    /// Upper bound on the context; the file's own length is used when smaller.
    pub max_context: usize,
    /// Prompt tokens evaluated per forward pass.
    pub batch: usize,
    /// The tool chooser's LoRA adapter (GGUF, `models::adapter`), on only while it reads
    /// (`Backend::chooser_branches`); llama.cpp only.
    pub adapter: Option<PathBuf>,
    /// candle: also hold each layer's weights dequantized (4 bytes a weight: 560 MiB
    /// more for SmolLM2), which prompts of 16 tokens or more are evaluated through,
    /// faster than through the quantized weights (see docs/performance.md).
    pub dense_weights: bool,
}

impl LoadOptions {
    pub fn new(path: PathBuf) -> LoadOptions {
        LoadOptions {
            path,
            family: None,
            threads: physical_cores(),
            max_context: 8192,
            batch: 512,
            adapter: None,
            dense_weights: false,
        }
    }
}

/// Physical cores (SMT siblings share one core's execution units, so llama.cpp runs
/// fastest with one thread per physical core); falls back to the logical count.
pub fn physical_cores() -> usize {
    let logical = std::thread::available_parallelism().map_or(1, |n| n.get());
    let Ok(info) = std::fs::read_to_string("/proc/cpuinfo") else {
        return logical;
    };
    let mut cores = std::collections::BTreeSet::new();
    let mut phys = "";
    for line in info.lines() {
        let mut kv = line.splitn(2, ':').map(str::trim);
        match (kv.next(), kv.next()) {
            (Some("physical id"), Some(v)) => phys = v,
            (Some("core id"), Some(v)) => {
                cores.insert((phys.to_string(), v.to_string()));
            }
            _ => {}
        }
    }
    // A container may see fewer CPUs than /proc/cpuinfo lists.
    if cores.is_empty() {
        logical
    } else {
        cores.len().min(logical)
    }
}
