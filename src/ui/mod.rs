//! Front ends: what the operator runs. Each command here wires library parts together
//! and prints; none holds logic another front end would need.
//!
//! Layout:
//! - `agent`: `ferrosa ask` and `ferrosa chat`
//! - `choice`: the command line's names for the library's choices
//! - `eval`: `ferrosa eval bfcl`
//! - `generate`: `ferrosa generate`, streaming text from a model, with `--stats`
//! - `models`: `ferrosa models list|fetch|verify`

pub mod agent;
pub mod choice;
pub mod eval;
pub mod generate;
pub mod models;

use std::path::PathBuf;

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
}

impl ModelArgs {
    /// Resolve `-m`, check the file, and load it with the chosen runtime.
    pub fn load(&self) -> anyhow::Result<(ResolvedModel, LoadOptions, Box<dyn Backend>)> {
        let resolved = crate::models::resolve(self.model.as_deref(), &self.models_dir)?;
        let mut opts = LoadOptions::new(resolved.path.clone());
        opts.family = resolved.family().map(str::to_string);
        opts.max_context = self.max_context;
        if let Some(t) = self.threads {
            opts.threads = t;
        }
        let model = backend::load(self.backend, &opts)?;
        Ok((resolved, opts, model))
    }
}
