//! Where ferrosa keeps files of its own, in the platform's directories (XDG on Linux),
//! so an installed binary works from any working directory:
//!
//! - the cache (`$FERROSA_CACHE_DIR`, else `$XDG_CACHE_HOME/ferrosa`, else
//!   `~/.cache/ferrosa`): the prompt cache; a machine without a home gets no cache,
//!   never an error;
//! - the data directory (`$XDG_DATA_HOME/ferrosa`, else `~/.local/share/ferrosa`): the
//!   weights, unless `$FERROSA_MODELS_DIR` or a checkout's `models/` says otherwise
//!   (`models::models_dir`), and the console's session traces.

use std::path::PathBuf;

/// Environment variable naming the cache directory outright.
pub(crate) const CACHE_DIR_ENV: &str = "FERROSA_CACHE_DIR";

/// The cache directory, if this machine has one.
pub(crate) fn cache_dir() -> Option<PathBuf> {
    let set = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty());
    if let Some(dir) = set(CACHE_DIR_ENV) {
        return Some(PathBuf::from(dir));
    }
    xdg("XDG_CACHE_HOME", &[".cache"])
}

/// `$VAR/ferrosa` when `VAR` holds an absolute path (the XDG spec: a relative one is
/// invalid and ignored), else `~/<under…>/ferrosa`.
fn xdg(var: &str, under: &[&str]) -> Option<PathBuf> {
    let set = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty());
    if let Some(dir) = set(var).map(PathBuf::from) {
        if dir.is_absolute() {
            return Some(dir.join("ferrosa"));
        }
    }
    let mut dir = PathBuf::from(set("HOME")?);
    dir.extend(under);
    Some(dir.join("ferrosa"))
}

/// The data directory, if this machine has one.
pub(crate) fn data_dir() -> Option<PathBuf> {
    xdg("XDG_DATA_HOME", &[".local", "share"])
}

/// Where prompt cache entries go (`backend::prompt_cache`).
pub(crate) fn prompt_cache_dir() -> Option<PathBuf> {
    cache_dir().map(|d| d.join("prompts"))
}

/// Where `ferrosa serve` keeps session traces unless `--trace-dir` says otherwise.
pub(crate) fn traces_dir() -> Option<PathBuf> {
    data_dir().map(|d| d.join("traces"))
}
