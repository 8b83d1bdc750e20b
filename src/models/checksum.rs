//! sha256 checks of model files, remembered in a stamp file beside the model so a load
//! hashes a file only after it changed (size or mtime), not every time.

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use sha2::{Digest, Sha256};

use super::catalog::Entry;

/// A model file that is not what the catalog says.
#[derive(Debug, thiserror::Error)]
pub enum VerifyError {
    #[error("{path} does not match the catalog's sha256 (expected {expected}, found {found}); run `ferrosa models fetch {name} --force` to replace it")]
    HashMismatch {
        name: String,
        path: PathBuf,
        expected: String,
        found: String,
    },
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// Hex sha256 of a file, calling `progress` with the bytes read so far.
pub(crate) fn sha256_file(path: &Path, mut progress: impl FnMut(u64)) -> std::io::Result<String> {
    let mut f = File::open(path)?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut done = 0u64;
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
        done += n as u64;
        progress(done);
    }
    Ok(to_hex(&h.finalize()))
}

pub(crate) fn to_hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn stamp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.verified"))
}

/// "sha256 size mtime_ns" of the file as it is now.
fn fingerprint(path: &Path, sha: &str) -> std::io::Result<String> {
    let md = std::fs::metadata(path)?;
    let mtime = md
        .modified()?
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    Ok(format!("{sha} {} {mtime}", md.len()))
}

/// Record that `path` was hashed and matched `sha`.
pub(crate) fn remember(path: &Path, sha: &str) {
    // The stamp is only a cache: failing to write it costs a re-hash next time, nothing more.
    if let Ok(fp) = fingerprint(path, sha) {
        let _ = std::fs::write(stamp_path(path), fp);
    }
}

/// Check `path` against the catalog entry, hashing only if it changed since the last check.
/// The sha256 of `path`, read from its stamp when the file's size and modification
/// time still match it, else computed (and the stamp written, where it can be).
pub fn sha256_remembered(path: &Path) -> std::io::Result<String> {
    if let Ok(stamp) = std::fs::read_to_string(stamp_path(path)) {
        if let Some(sha) = stamp.split(' ').next() {
            if fingerprint(path, sha)? == stamp {
                return Ok(sha.to_string());
            }
        }
    }
    let sha = sha256_file(path, |_| {})?;
    remember(path, &sha);
    Ok(sha)
}

pub fn check(entry: &Entry, path: &Path) -> Result<(), VerifyError> {
    let io = |source| VerifyError::Io {
        path: path.to_path_buf(),
        source,
    };
    let expected = entry.sha256.to_ascii_lowercase();
    let current = fingerprint(path, &expected).map_err(io)?;
    if std::fs::read_to_string(stamp_path(path)).ok().as_deref() == Some(current.as_str()) {
        return Ok(());
    }
    let found = sha256_file(path, |_| {}).map_err(io)?;
    if found != expected {
        return Err(VerifyError::HashMismatch {
            name: entry.name.clone(),
            path: path.to_path_buf(),
            expected,
            found,
        });
    }
    remember(path, &found);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sha256_of_known_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x");
        std::fs::write(&p, b"abc").unwrap();
        assert_eq!(
            sha256_file(&p, |_| {}).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn stamp_is_invalidated_by_a_change() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.gguf");
        std::fs::write(&p, b"abc").unwrap();
        let mut entry: Entry = toml::from_str(
            r#"name = "t"
family = "smollm2"
kind = "instruct"
file = "m.gguf"
sha256 = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
size = 3
licence = "x"
source = [{ package = "p", version = "1", member = "m" }]"#,
        )
        .unwrap();
        check(&entry, &p).unwrap();
        assert!(stamp_path(&p).exists());
        std::fs::write(&p, b"abd").unwrap();
        let err = check(&entry, &p).unwrap_err();
        assert!(matches!(err, VerifyError::HashMismatch { .. }), "{err}");
        assert!(err.to_string().contains("models fetch t --force"));
        entry.sha256 = sha256_file(&p, |_| {}).unwrap();
        check(&entry, &p).unwrap();
    }
}
