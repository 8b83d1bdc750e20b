//! Front ends: what the operator runs. Each command here wires library parts together
//! and prints; none holds logic another front end would need.
//!
//! Layout:
//! - `agent`: `ferrosa ask` and `ferrosa chat` (the REPL)
//! - `call`: `ferrosa call`, one tool call through the policy
//! - `robot`: joining ROS 2, the sim, the guarded graph, the e-stop's ROS trigger
//! - `speech`: `ferrosa transcribe` and `ferrosa say`
//! - `term`: cleaning what is printed, the input thread, terminal confirmation
//! - `cli`: the command line (clap's definitions) and `run`, which hands each command
//!   to its front end
//! - `console`: `ferrosa serve`, the operator console in a web page
//! - `secret`: the secret every client of a local surface (console, MCP over HTTP) holds
//! - `eval`: `ferrosa eval bfcl`
//! - `generate`: `ferrosa generate`, streaming text from a model, with `--stats`
//! - `models`: `ferrosa models list|fetch|verify`
//! - `memory`: `ferrosa memory list|export|forget`, what the robot keeps
//! - `mcp`: `ferrosa mcp`, the robot's tools for an MCP client (stdio or HTTP)

pub mod agent;
pub mod call;
pub mod cli;
pub mod console;
pub mod eval;
pub mod generate;
pub mod mcp;
pub mod memory;
pub mod models;
pub mod progress;
pub mod robot;
pub mod secret;
pub mod speech;
pub mod term;

use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;

use crate::backend::{self, Backend, BackendKind, LoadOptions};
use crate::models::ResolvedModel;

/// What every command that runs a model takes from the command line.
#[derive(Debug, Clone)]
pub struct ModelArgs {
    pub models_dir: PathBuf,
    pub model: Option<String>,
    pub backend: BackendKind,
    pub threads: Option<usize>,
    pub max_context: usize,
    /// Keep and reuse stable prompt prefixes on disk (`backend::prompt_cache`).
    pub prompt_cache: bool,
    /// How far local decoding guesses ahead (`decode::draft`).
    pub draft: crate::decode::Draft,
    /// Run the model on a server (`--engine openai`): only its vocabulary is loaded here.
    pub remote: Option<crate::remote::RemoteOptions>,
    /// `--adapter`: `default` (the catalog's for the model), `none`, a built-in name or a
    /// path to a GGUF LoRA file (`models::adapter`).
    pub adapter: String,
    /// candle: hold each layer's weights dequantized too (`LoadOptions::dense_weights`).
    pub dense_weights: bool,
}

impl ModelArgs {
    /// Resolve `-m`, check the file, and load it with the chosen runtime.
    pub fn load(&self) -> anyhow::Result<(ResolvedModel, LoadOptions, Box<dyn Backend>)> {
        let resolved = crate::models::resolve(self.model.as_deref(), &self.models_dir)?;
        use crate::models::ModelKind;
        match resolved.entry.as_ref() {
            Some(e) if e.kind == ModelKind::Speech => anyhow::bail!(
                "{} is a speech recogniser, not a language model: use it with `ferrosa transcribe -m {}`, and pick the agent's model with -m (see `ferrosa models list`)",
                e.name,
                e.name
            ),
            Some(e) if e.kind == ModelKind::Encoder => anyhow::bail!(
                "{} is the sentence encoder tool choice reads requests with, not a language model: pick the agent's model with -m (see `ferrosa models list`)",
                e.name
            ),
            _ => {}
        }
        let mut opts = LoadOptions::new(resolved.path.clone());
        opts.family = resolved.family().map(str::to_string);
        opts.max_context = self.max_context;
        if let Some(t) = self.threads {
            opts.threads = t;
        }
        opts.adapter = self.adapter(&resolved)?;
        opts.dense_weights = self.dense_weights;
        let model = match &self.remote {
            Some(_) => backend::load_vocabulary(&opts)?,
            None => backend::load(self.backend, &opts)?,
        };
        Ok((resolved, opts, model))
    }

    /// The adapter to apply, when this runtime applies one: llama.cpp in this process.
    /// The catalog's default is left out, with a note, where it cannot apply; an adapter
    /// the operator named is an error there.
    fn adapter(&self, resolved: &ResolvedModel) -> anyhow::Result<Option<PathBuf>> {
        use crate::models::adapter;
        let named = !matches!(self.adapter.as_str(), adapter::DEFAULT | adapter::NONE | "");
        let elsewhere = if self.remote.is_some() {
            Some("the model server")
        } else if self.backend == BackendKind::Candle {
            Some("candle")
        } else {
            None
        };
        match (elsewhere, named) {
            (Some(runtime), true) => anyhow::bail!(
                "--adapter {}: {runtime} does not apply adapters; use the local llama.cpp runtime (--backend llama, --engine local) or leave --adapter out",
                self.adapter
            ),
            (Some(runtime), false) => {
                let listed = resolved.entry.as_ref().and_then(|e| e.adapter.as_deref());
                if let (Some(name), adapter::DEFAULT) = (listed, self.adapter.as_str()) {
                    tracing::info!("{runtime} does not apply adapters: the model runs without {name}");
                }
                Ok(None)
            }
            (None, _) => Ok(adapter::resolve(&self.adapter, &resolved.path, resolved.entry.as_ref())?),
        }
    }

    /// With `--engine openai`, the server reached and checked against `model` (the
    /// vocabulary `load` read from `resolved`).
    pub fn connect(
        &self,
        resolved: &ResolvedModel,
        model: &dyn Backend,
    ) -> anyhow::Result<Option<crate::remote::Remote>> {
        let Some(opts) = &self.remote else {
            return Ok(None);
        };
        let name = resolved.path.file_name().map_or_else(
            || resolved.path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        Ok(Some(crate::remote::Remote::connect(opts, model, &name)?))
    }

    /// The prompt cache of `model` (loaded from `resolved`), unless it is off, the
    /// runtime cannot snapshot its cache or this machine has no cache directory.
    pub fn prompt_cache(
        &self,
        resolved: &ResolvedModel,
        model: &dyn Backend,
    ) -> Option<Arc<crate::backend::PromptCache>> {
        if !self.prompt_cache || self.remote.is_some() {
            return None;
        }
        let dir = crate::dirs::prompt_cache_dir()?;
        let sha = match resolved.sha256() {
            Ok(sha) => sha,
            Err(e) => {
                tracing::warn!(path = %resolved.path.display(), "no prompt cache: cannot hash the model: {e}");
                return None;
            }
        };
        let max = std::env::var("FERROSA_PROMPT_CACHE_MB")
            .ok()
            .and_then(|v| v.parse::<u64>().ok())
            .map_or(crate::backend::prompt_cache::DEFAULT_MAX_BYTES, |mb| {
                mb << 20
            });
        crate::backend::PromptCache::open(&dir, &sha, model, max).map(Arc::new)
    }
}

/// Run `task` on a thread of its own (named `name`) with its own runtime: listeners that
/// must react while the main thread is busy (Ctrl-C, the e-stop topic).
pub(crate) fn on_own_thread<F>(name: &'static str, task: impl FnOnce() -> F + Send + 'static)
where
    F: Future<Output = ()>,
{
    std::thread::Builder::new()
        .name(name.into())
        .spawn(move || {
            match tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
            {
                Ok(rt) => rt.block_on(task()),
                Err(e) => tracing::error!("cannot start {name}'s runtime: {e}"),
            }
        })
        .unwrap_or_else(|e| panic!("spawning {name}: {e}"));
}
