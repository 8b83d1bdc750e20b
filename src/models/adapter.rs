//! Adapters over a model's weights: LoRA files in GGUF that llama.cpp loads beside the
//! model, for the tool chooser alone.
//!
//! The project ships one, built into the binary: `smollm2-135m-tools`, trained over the
//! default model's own quantized weights to raise the name of the tool a request asks
//! for, on requests made from the tools' examples and the robot prompt files' (no suite's
//! requests; `scripts/adapter/`). It is opt-in (`--adapter smollm2-135m-tools`): on the
//! suites it chose better on the report halves and worse on the tune halves, about even
//! in all (docs/results.md, The tool chooser's adapter), so no catalog entry names it.
//! The runtime switches an adapter on only while the chooser reads the candidate names
//! (`strategy::likelihood::chooser_logprobs`): the prompt's cache, the arguments and the
//! answer stay the base model's, and so does the prompt cache on disk. A built-in
//! adapter names the sha256 of the weights it was trained over and is applied to no
//! other file. A catalog entry may name one (`adapter = ...`) to apply it by default;
//! the operator may name any GGUF LoRA file by path instead, or turn adapters off.
//!
//! llama.cpp reads adapters from files: a built-in one is written to a new file in the
//! cache directory, opened and unlinked at once, and read through `/proc/self/fd`, so no
//! file another process planted or swapped is ever loaded in its place.

use std::path::{Path, PathBuf};

use super::catalog::Entry;
use super::checksum;

/// What `--adapter` may say besides a built-in name or a path.
pub const DEFAULT: &str = "default";
pub const NONE: &str = "none";

/// An adapter shipped in the binary.
pub struct Builtin {
    pub name: &'static str,
    /// The sha256 of the model file it was trained over.
    pub base_sha256: &'static str,
    bytes: &'static [u8],
}

pub const BUILTIN: &[Builtin] = &[Builtin {
    name: "smollm2-135m-tools",
    base_sha256: "b179c9523d0e6a0f98a330c7562b682750a6f8c8c15e5bc70ea373728110db53",
    bytes: include_bytes!("../../data/adapters/smollm2-135m-tools.gguf"),
}];

#[derive(Debug, thiserror::Error)]
pub enum AdapterError {
    #[error("unknown adapter '{0}': pass a built-in adapter ({known}), a path to a GGUF LoRA file, 'default' or 'none'", known = builtin_names())]
    Unknown(String),
    #[error("the adapter {name} was trained over another model file ({base}…); this model's sha256 is {model}…: pass --adapter none, or an adapter trained for this model")]
    OtherModel {
        name: String,
        base: String,
        model: String,
    },
    #[error("no adapter file at {0}: check the path, or pass a built-in adapter ({known}) or 'none'", known = builtin_names())]
    NoFile(PathBuf),
    #[error("the catalog names adapter '{0}', which this build does not have (built in: {known}): fix the catalog entry, or pass --adapter none", known = builtin_names())]
    NotBuiltIn(String),
    #[error("cannot read the adapter {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write the built-in adapter {name} to {path}: {source}; set FERROSA_CACHE_DIR to a writable directory, or pass --adapter none")]
    Write {
        name: String,
        path: PathBuf,
        source: std::io::Error,
    },
}

fn builtin_names() -> String {
    BUILTIN
        .iter()
        .map(|b| b.name)
        .collect::<Vec<_>>()
        .join(", ")
}

impl Builtin {
    pub fn find(name: &str) -> Option<&'static Builtin> {
        BUILTIN.iter().find(|b| b.name == name)
    }

    /// The adapter as a file only this process can reach: written to a new file in `dir`
    /// (created exclusively, under a name no other file has, so nothing planted there is
    /// written through or read), opened, and unlinked; llama.cpp reads it through
    /// `/proc/self/fd`. The descriptor stays open for the process's life (one file of a
    /// few MiB), so the path stays valid for any later load.
    fn materialize(&self, dir: &Path) -> Result<PathBuf, AdapterError> {
        use std::io::Write;
        let fail = |path: &Path| {
            let path = path.to_path_buf();
            move |source| AdapterError::Write {
                name: self.name.into(),
                path: path.clone(),
                source,
            }
        };
        std::fs::create_dir_all(dir).map_err(fail(dir))?;
        let stamp = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let mut last = None;
        for attempt in 0..8 {
            let path = dir.join(format!(
                ".{}-{}-{stamp:x}-{attempt}.gguf",
                self.name,
                std::process::id()
            ));
            let mut file = match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&path)
            {
                Ok(f) => f,
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    last = Some(e);
                    continue;
                }
                Err(e) => return Err(fail(&path)(e)),
            };
            let written = file.write_all(self.bytes).and_then(|()| file.flush());
            let reader = written.and_then(|()| std::fs::File::open(&path));
            let _ = std::fs::remove_file(&path);
            let reader = reader.map_err(fail(&path))?;
            use std::os::unix::io::IntoRawFd;
            let fd = reader.into_raw_fd();
            return Ok(PathBuf::from(format!("/proc/self/fd/{fd}")));
        }
        Err(fail(dir)(last.unwrap_or_else(|| {
            std::io::Error::other("no free file name")
        })))
    }
}

/// The adapter `choice` (`--adapter`) names for the model file at `model` (its catalog
/// `entry`, when it has one): `default` is the entry's adapter, applied only over the
/// file it was trained over (a catalog overridden with other weights under the same name
/// gets none); `none` is none; a built-in name is that adapter, refused over another
/// file; anything else is a path to a GGUF LoRA file.
pub fn resolve(
    choice: &str,
    model: &Path,
    entry: Option<&Entry>,
) -> Result<Option<PathBuf>, AdapterError> {
    let dir = crate::dirs::cache_dir()
        .map(|d| d.join("adapters"))
        .unwrap_or_else(|| std::env::temp_dir().join("ferrosa-adapters"));
    match choice {
        NONE | "" => Ok(None),
        DEFAULT => {
            let Some(entry) = entry else {
                return Ok(None);
            };
            let Some(name) = entry.adapter.as_deref() else {
                return Ok(None);
            };
            let builtin =
                Builtin::find(name).ok_or_else(|| AdapterError::NotBuiltIn(name.to_string()))?;
            if !builtin.base_sha256.eq_ignore_ascii_case(&entry.sha256) {
                return Ok(None);
            }
            builtin.materialize(&dir).map(Some)
        }
        name => {
            if let Some(builtin) = Builtin::find(name) {
                let model_sha = match entry {
                    Some(e) => e.sha256.to_ascii_lowercase(),
                    None => {
                        checksum::sha256_remembered(model).map_err(|source| AdapterError::Read {
                            path: model.to_path_buf(),
                            source,
                        })?
                    }
                };
                if !builtin.base_sha256.eq_ignore_ascii_case(&model_sha) {
                    return Err(AdapterError::OtherModel {
                        name: name.into(),
                        base: builtin.base_sha256[..12].into(),
                        model: model_sha.chars().take(12).collect(),
                    });
                }
                return builtin.materialize(&dir).map(Some);
            }
            let path = PathBuf::from(name);
            let looks_like_path = name.contains('/') || name.ends_with(".gguf");
            if looks_like_path && !path.is_file() {
                return Err(AdapterError::NoFile(path));
            }
            if !path.is_file() {
                return Err(AdapterError::Unknown(name.into()));
            }
            Ok(Some(path))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::Gguf;

    #[test]
    fn each_builtin_is_a_lora_over_a_catalog_model() {
        let catalog =
            crate::models::Catalog::parse(crate::models::catalog::BUILTIN, "built-in").unwrap();
        for b in BUILTIN {
            let dir = tempfile::tempdir().unwrap();
            let a = b.materialize(dir.path()).unwrap();
            let g = Gguf::open(&a).unwrap();
            let text = |k: &str| g.get(k).and_then(|v| v.as_str()).map(str::to_string);
            assert_eq!(
                text("general.type").as_deref(),
                Some("adapter"),
                "{}",
                b.name
            );
            assert_eq!(text("adapter.type").as_deref(), Some("lora"), "{}", b.name);
            assert!(!g.tensors.is_empty() && g.tensors.len() % 2 == 0);
            assert!(
                catalog.model.iter().any(|e| e.sha256 == b.base_sha256),
                "{} was trained over no model of the catalog",
                b.name
            );
            // Nothing is left in the directory: the file is reached through the
            // descriptor alone, and holds exactly the built-in bytes.
            assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
            assert_eq!(std::fs::read(&a).unwrap(), b.bytes);
        }
    }

    #[test]
    fn a_builtin_is_refused_over_other_weights_and_default_skips_them() {
        let dir = tempfile::tempdir().unwrap();
        let other = dir.path().join("other.gguf");
        std::fs::write(&other, b"not the model").unwrap();
        let err = resolve(BUILTIN[0].name, &other, None).unwrap_err();
        assert!(matches!(err, AdapterError::OtherModel { .. }), "{err}");
        assert_eq!(resolve(DEFAULT, &other, None).unwrap(), None);
        assert_eq!(resolve(NONE, &other, None).unwrap(), None);
        let err = resolve("no-such-adapter", &other, None).unwrap_err();
        assert!(err.to_string().contains("smollm2-135m-tools"), "{err}");
    }
}
