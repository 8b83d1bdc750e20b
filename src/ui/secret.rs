//! The secret of a local surface (the web console, MCP over HTTP): the one rule that makes
//! a client the operator's. Every address needs it, loopback included: on a robot any
//! local process can reach 127.0.0.1, and only the operator's may drive the robot.
//!
//! The secret is drawn at start from the kernel's random source (or taken from an
//! environment variable the operator set) and written to a file only this user can read
//! (`$XDG_RUNTIME_DIR/ferrosa/NAME.token`, else the data directory's `run/`), so the
//! operator's own scripts and MCP client can read it and nobody else can; the file goes
//! when the surface stops. It is compared in time that does not depend on where a guess
//! differs.
//!
//! Owns drawing, keeping and comparing; which header or cookie carries it is the
//! surface's.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use anyhow::Context;

/// A surface's secret and the file it is kept in.
pub(crate) struct Secret {
    token: String,
    file: Option<PathBuf>,
}

impl Secret {
    /// The secret of surface `name` (e.g. `console-8080`): `$env` when set (at least 16
    /// letters, digits, '-' or '_'), else 128 random bits; kept in its file.
    pub fn create(env: &str, name: &str) -> anyhow::Result<Secret> {
        let token = match std::env::var_os(env) {
            Some(t) => {
                let t = t.to_string_lossy().into_owned();
                anyhow::ensure!(
                    t.len() >= 16
                        && t.bytes()
                            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_'),
                    "{env} must be at least 16 characters of letters, digits, '-' or '_'"
                );
                t
            }
            None => random_hex(16).with_context(|| {
                format!("drawing a secret from /dev/urandom; set {env} instead")
            })?,
        };
        let file = match token_dir() {
            Some(dir) => Some(keep(&dir, name, &token)?),
            None => None,
        };
        Ok(Secret { token, file })
    }

    /// Whether `given` is the secret.
    pub fn matches(&self, given: &str) -> bool {
        same(given, &self.token)
    }

    /// Where to find the secret, for a line the operator reads.
    pub(crate) fn where_kept(&self) -> String {
        match &self.file {
            Some(f) => format!("the token is in {}", f.display()),
            None => "no directory to keep the token in: set it yourself next time".into(),
        }
    }
}

impl Drop for Secret {
    fn drop(&mut self) {
        if let Some(f) = &self.file {
            let _ = std::fs::remove_file(f);
        }
    }
}

/// `$XDG_RUNTIME_DIR/ferrosa` (a per-user directory the system keeps private), else
/// the data directory's `run/`.
fn token_dir() -> Option<PathBuf> {
    let runtime = std::env::var_os("XDG_RUNTIME_DIR")
        .map(PathBuf::from)
        .filter(|d| d.is_absolute() && d.is_dir());
    match runtime {
        Some(d) => Some(d.join("ferrosa")),
        None => crate::dirs::data_dir().map(|d| d.join("run")),
    }
}

/// Write `token` to `dir/name.token`, readable by this user only (the directory too).
/// A file left by an earlier run is replaced, never written through (it may be a link).
fn keep(dir: &Path, name: &str, token: &str) -> anyhow::Result<PathBuf> {
    use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt, PermissionsExt};
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .with_context(|| format!("creating {} for the surface's token", dir.display()))?;
    std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700))
        .with_context(|| format!("making {} private", dir.display()))?;
    let path = dir.join(format!("{name}.token"));
    match std::fs::remove_file(&path) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(e).with_context(|| format!("replacing {}", path.display())),
    }
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(&path)
        .with_context(|| format!("writing the token to {}", path.display()))?;
    writeln!(f, "{token}").with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// `bytes` random bytes from the kernel, in hex.
pub(crate) fn random_hex(bytes: usize) -> std::io::Result<String> {
    let mut buf = vec![0u8; bytes];
    std::fs::File::open("/dev/urandom")?.read_exact(&mut buf)?;
    Ok(buf.iter().map(|b| format!("{b:02x}")).collect())
}

/// Equal, in time that does not depend on where they differ.
pub fn same(a: &str, b: &str) -> bool {
    a.len() == b.len()
        && a.bytes()
            .zip(b.bytes())
            .fold(0u8, |acc, (x, y)| acc | (x ^ y))
            == 0
}

/// The value of `Authorization: Bearer VALUE`, if the request has one.
pub fn bearer(headers: &hyper::http::HeaderMap) -> Option<&str> {
    headers
        .get(hyper::http::header::AUTHORIZATION)?
        .to_str()
        .ok()?
        .strip_prefix("Bearer ")
        .map(str::trim)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    #[test]
    fn the_file_is_the_users_alone_and_goes_with_the_secret() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("ferrosa");
        // A link left where the file goes is replaced, not written through.
        std::fs::create_dir_all(&d).unwrap();
        let target = dir.path().join("elsewhere");
        std::fs::write(&target, "keep").unwrap();
        std::os::unix::fs::symlink(&target, d.join("console-1.token")).unwrap();
        let path = keep(&d, "console-1", "abc").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "abc\n");
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep");
        let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode(&path), 0o600);
        assert_eq!(mode(&d), 0o700);
        let s = Secret {
            token: "abc".into(),
            file: Some(path.clone()),
        };
        assert!(s.matches("abc") && !s.matches("abd") && !s.matches("ab"));
        drop(s);
        assert!(!path.exists());
    }

    #[test]
    fn drawn_secrets_differ() {
        let a = random_hex(16).unwrap();
        assert_eq!(a.len(), 32);
        assert_ne!(a, random_hex(16).unwrap());
    }

    #[test]
    fn tokens_compare_whole() {
        assert!(same("abc", "abc"));
        assert!(!same("abc", "abd"));
        assert!(!same("abc", "abcd"));
        assert!(!same("", "a"));
    }
}
