//! Model runtimes behind one trait: token ids in, next-token logits out.
//!
//! Owns the weights, the KV cache, tokenization, the vocabulary (bytes of every token,
//! special and end-of-generation tokens) and the chat template. Knows nothing of
//! grammars, tools or ROS: `decode` drives a `Backend`, `agent` sees only this trait.
//!
//! Layout:
//! - `gguf`: GGUF header and metadata reading, validation of truncated/foreign files
//! - `vocab`: the token table shared by every runtime, and streaming detokenization
//! - `template`: chat templates (minijinja), from the file or a per-family fallback
//! - `llama`: llama.cpp through `llama-cpp-2` (feature `llama`, default)
//! - `candle`: a pure-Rust runtime on candle (feature `candle`)
//! - `bpe`: a byte-level BPE tokenizer built from GGUF metadata, for runtimes without one
//! - `scripted`: replays a transcript through the real decode path (agent tests)
//! - `uniform`: a weightless backend with a real vocabulary (equal logits), for property
//!   tests and decoding benchmarks

pub mod gguf;
pub mod template;
pub mod vocab;

pub mod bpe;
#[cfg(feature = "candle")]
pub mod candle;
#[cfg(feature = "llama")]
pub mod llama;
pub mod scripted;
pub mod uniform;

use std::path::PathBuf;
use std::sync::Arc;

pub use gguf::{Gguf, GgufError};
pub use template::{ChatMessage, ChatTemplate, Role, TemplateError};
pub use vocab::{Detokenizer, TokenId, Vocab};

#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    #[error(transparent)]
    Gguf(#[from] GgufError),
    #[error(transparent)]
    Template(#[from] TemplateError),
    #[error("{backend} could not load {path}: {reason}")]
    Load {
        backend: &'static str,
        path: PathBuf,
        reason: String,
    },
    #[error("the {0} backend is not compiled into this binary; rebuild with `--features {0}`")]
    NotCompiled(&'static str),
    #[error("{backend} does not support architecture '{arch}' (supported: {supported})")]
    Architecture {
        backend: &'static str,
        arch: String,
        supported: &'static str,
    },
    #[error("context full: {needed} tokens do not fit in the {limit}-token context; raise --ctx or shorten the input")]
    ContextFull { needed: usize, limit: usize },
    #[error("token id {0} is outside the vocabulary")]
    BadToken(TokenId),
    #[error("{backend} failed to evaluate: {reason}")]
    Eval {
        backend: &'static str,
        reason: String,
    },
}

/// Which runtime to load.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
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
}

impl LoadOptions {
    pub fn new(path: PathBuf) -> LoadOptions {
        LoadOptions {
            path,
            family: None,
            threads: physical_cores(),
            max_context: 8192,
            batch: 512,
        }
    }
}

/// A model's tokenizer, shareable across threads (the constrained decoder keeps one to
/// tokenize forced text exactly as the model would).
pub trait Tokenize: Send + Sync {
    /// As `Backend::tokenize`.
    fn tokenize(&self, text: &str, special: bool) -> Vec<TokenId>;
}

/// The model runtime: token ids in, next-token logits out. Owns weights and KV cache.
pub trait Backend: Send {
    /// Short name for reports ("llama.cpp", "candle").
    fn name(&self) -> &'static str;
    fn vocab(&self) -> &Vocab;
    fn chat_template(&self) -> &ChatTemplate;
    /// Tokens the context holds (prompt and generated together).
    fn context_len(&self) -> usize;
    /// Text to tokens. With `special`, special-token texts such as `<|im_start|>` become
    /// their single ids (for rendered templates); without, they are plain text (for
    /// anything an operator or a tool wrote). Never adds BOS: see `Vocab::bos`.
    fn tokenize(&self, text: &str, special: bool) -> Result<Vec<TokenId>, BackendError>;
    /// The same tokenizer as a shareable handle.
    fn tokenizer(&self) -> Arc<dyn Tokenize>;
    /// Keep the first `keep` cached tokens, evaluate `tokens` after them in batches, and
    /// return the logits of the last one. `tokens` must not be empty.
    fn forward(&mut self, keep: usize, tokens: &[TokenId]) -> Result<&mut [f32], BackendError>;
}

/// Load `opts.path` with the chosen runtime. The file is validated first (GGUF magic,
/// version, tensor data present) so a bad file is a clear error, not a runtime crash.
pub fn load(kind: BackendKind, opts: &LoadOptions) -> Result<Box<dyn Backend>, BackendError> {
    let gguf = Gguf::open(&opts.path)?;
    match kind {
        #[cfg(feature = "llama")]
        BackendKind::Llama => Ok(Box::new(llama::LlamaCpp::load(&gguf, opts)?)),
        #[cfg(not(feature = "llama"))]
        BackendKind::Llama => Err(BackendError::NotCompiled("llama")),
        #[cfg(feature = "candle")]
        BackendKind::Candle => Ok(Box::new(candle::Candle::load(&gguf, opts)?)),
        #[cfg(not(feature = "candle"))]
        BackendKind::Candle => Err(BackendError::NotCompiled("candle")),
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
