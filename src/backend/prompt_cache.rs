//! The persistent prompt cache: the KV state of a prompt's stable prefix (the system
//! prompt with the tool specs, everything before the conversation) kept on disk, so a
//! process that starts cold does not evaluate it again.
//!
//! - An entry is one prefix in one file: a header (the key, the prefix's tokens, the
//!   payload's length and sha256) and the runtime's snapshot of its KV cache. The key is
//!   everything else that decides the snapshot: the model file's sha256 and the
//!   runtime's `snapshot_key` (runtime version, context and batch sizes, threads).
//! - An entry holds one stable prefix, evaluated on its own in batches from its start
//!   (`Session::prepare`), so restoring it gives exactly the state evaluating it does.
//!   A cold prompt whose stable prefix an entry holds takes all of it; otherwise the
//!   entry sharing the most whole batches with the prompt, the entry's tokens past
//!   those being dropped from the cache before the rest is evaluated, as with any
//!   reused prefix.
//! - Anything wrong with a file (truncated, corrupted, foreign, another key, refused by
//!   the runtime) is a miss: logged, the file removed, never an error or a wrong
//!   answer. The payload's hash is checked before the runtime reads a byte of it.
//! - A file is input, not trusted (issue 41): every length its header claims is checked
//!   against the file's real length and the directory's bound before anything is
//!   allocated for it, so a crafted header cannot abort a start (nor every start after).
//! - Entries are written on a thread of their own, to a temporary file renamed into
//!   place; the directory is bounded in bytes, the least recently used going first.

use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::SystemTime;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::{Backend, TokenId};

/// What starts every entry file.
const MAGIC: &[u8; 8] = b"FRSKV01\n";
/// An entry is worth reading only when it spares at least this many tokens of
/// evaluation (a file of ~40 MiB is read and hashed in about the time these take).
pub(crate) const MIN_GAIN: usize = 64;
/// The directory's default bound.
pub const DEFAULT_MAX_BYTES: u64 = 512 << 20;
/// Headers larger than this are not ours.
const MAX_HEADER: u32 = 4 << 20;
/// Bytes before the header: `MAGIC` and the header's length.
const PREAMBLE: u64 = MAGIC.len() as u64 + 4;

/// Why an entry file cannot be used: each is a miss (logged, the file removed).
#[derive(Debug, thiserror::Error)]
enum Unusable {
    #[error("cannot read it: {0}")]
    Io(#[from] std::io::Error),
    #[error("not a prompt cache entry")]
    NotOurs,
    #[error("its header claims {claimed} bytes, the file holds {holds} after the preamble")]
    Header { claimed: u32, holds: u64 },
    #[error("unreadable header: {0}")]
    Json(#[from] serde_json::Error),
    #[error("its header claims a payload of {claimed} bytes, the file holds {holds}")]
    Payload { claimed: u64, holds: u64 },
    #[error("a payload of {claimed} bytes is more than the cache keeps ({bound} bytes)")]
    TooLarge { claimed: u64, bound: u64 },
    #[error("made under another key")]
    OtherKey,
    #[error("its tokens changed since it was listed")]
    TokensChanged,
    #[error("its payload does not match its sha256")]
    Hash,
}

/// An entry's header, as written after `MAGIC` and its length.
#[derive(Serialize, Deserialize)]
struct Header {
    key: String,
    tokens: Vec<TokenId>,
    payload_len: u64,
    payload_sha256: String,
}

/// One entry of this cache's key.
#[derive(Debug, Clone)]
struct Entry {
    path: PathBuf,
    tokens: Vec<TokenId>,
}

/// What a `restore` did to the runtime's cache.
#[derive(Debug)]
pub enum Restored {
    /// The cache now holds these tokens (a prefix the prompt shares, and maybe more).
    Hit(Vec<TokenId>),
    /// Nothing worth reading: the cache is as it was.
    Miss,
    /// The runtime refused an entry it began to read: its cache is empty now.
    Cleared,
}

struct Shared {
    dir: PathBuf,
    key: String,
    max_bytes: u64,
    entries: Mutex<Vec<Entry>>,
}

/// `m` locked, even if a thread panicked holding it: what it guards (a list changed in
/// single steps, handles to join) is whole at every step.
fn locked<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The cache of one model under one runtime's settings (see the module header).
pub struct PromptCache {
    shared: Arc<Shared>,
    writes: Mutex<Vec<JoinHandle<()>>>,
    /// Tokens restored from disk and stored to it, by this process.
    restored: AtomicUsize,
    stored: AtomicUsize,
}

impl std::fmt::Debug for PromptCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PromptCache")
            .field("dir", &self.shared.dir)
            .field("key", &self.shared.key)
            .finish_non_exhaustive()
    }
}

impl PromptCache {
    /// The cache in `dir` for the model whose file hashes to `model_sha256`, as
    /// `backend` runs it; None when the runtime cannot snapshot its cache or the
    /// directory cannot be made.
    pub fn open(
        dir: &Path,
        model_sha256: &str,
        backend: &dyn Backend,
        max_bytes: u64,
    ) -> Option<PromptCache> {
        let runtime = backend.snapshot_key()?;
        if let Err(e) = fs::create_dir_all(dir) {
            tracing::warn!(dir = %dir.display(), "no prompt cache: {e}");
            return None;
        }
        let key = format!("model sha256 {model_sha256}; {runtime}");
        let entries = read_index(dir, &key, max_bytes);
        Some(PromptCache {
            shared: Arc::new(Shared {
                dir: dir.to_path_buf(),
                key,
                max_bytes,
                entries: Mutex::new(entries),
            }),
            writes: Mutex::new(Vec::new()),
            restored: AtomicUsize::new(0),
            stored: AtomicUsize::new(0),
        })
    }

    pub fn dir(&self) -> &Path {
        &self.shared.dir
    }

    /// The entries of this key, as the token counts they hold.
    pub fn entries(&self) -> Vec<(PathBuf, usize)> {
        locked(&self.shared.entries)
            .iter()
            .map(|e| (e.path.clone(), e.tokens.len()))
            .collect()
    }

    /// Load into `backend`, whose cache is empty, the entry holding the stable prefix
    /// `stable` whole, or else the one sharing the most leading tokens with it in whole
    /// multiples of `batch` (at least `MIN_GAIN`): `Hit` holds that shared part (the
    /// runtime may hold more of the entry, which the next evaluation drops).
    pub fn restore(&self, backend: &mut dyn Backend, stable: &[TokenId], batch: usize) -> Restored {
        let batch = batch.max(1);
        let usable = |tokens: &[TokenId]| match shared_prefix(tokens, stable) {
            n if n == tokens.len() && n == stable.len() => n,
            n => n / batch * batch,
        };
        let best = {
            let entries = locked(&self.shared.entries);
            entries
                .iter()
                .map(|e| (usable(&e.tokens), e))
                .max_by_key(|(n, _)| *n)
                .filter(|(n, _)| *n >= MIN_GAIN)
                .map(|(n, e)| (n, e.clone()))
        };
        let Some((usable, entry)) = best else {
            return Restored::Miss;
        };
        let shared = &self.shared;
        let payload = match read_entry(&entry.path, &shared.key, &entry.tokens, shared.max_bytes) {
            Ok(p) => p,
            Err(why) => {
                self.drop_entry(&entry.path, &why.to_string());
                return Restored::Miss;
            }
        };
        if let Err(e) = backend.restore(&payload, entry.tokens.len()) {
            self.drop_entry(&entry.path, &e.to_string());
            return Restored::Cleared;
        }
        // Used now: the last to be evicted.
        if let Ok(f) = fs::File::options().append(true).open(&entry.path) {
            let _ = f.set_modified(SystemTime::now());
        }
        tracing::debug!(target: "ferrosa::prompt_cache", tokens = usable,
            path = %entry.path.display(), "restored");
        self.restored.fetch_add(usable, Ordering::Relaxed);
        Restored::Hit(entry.tokens[..usable].to_vec())
    }

    /// Keep what `backend` caches now, which is `tokens`, as an entry (unless one holds
    /// exactly these): the snapshot is taken here, hashed and written on a thread.
    pub fn store(&self, backend: &dyn Backend, tokens: &[TokenId]) {
        {
            let entries = locked(&self.shared.entries);
            if entries.iter().any(|e| e.tokens == tokens) {
                return;
            }
        }
        let payload = match backend.snapshot() {
            Ok(p) => p,
            Err(e) => {
                tracing::warn!(target: "ferrosa::prompt_cache", "cannot snapshot: {e}");
                return;
            }
        };
        self.stored.fetch_add(tokens.len(), Ordering::Relaxed);
        let shared = self.shared.clone();
        let tokens = tokens.to_vec();
        let write = std::thread::Builder::new()
            .name("prompt-cache".into())
            .spawn(move || shared.write(tokens, &payload));
        match write {
            Ok(handle) => locked(&self.writes).push(handle),
            Err(e) => tracing::warn!(target: "ferrosa::prompt_cache", "cannot write: {e}"),
        }
    }

    /// Tokens this process restored from disk, and stored to it (entries of tokens
    /// already on disk are not stored again).
    pub fn counts(&self) -> (usize, usize) {
        (
            self.restored.load(Ordering::Relaxed),
            self.stored.load(Ordering::Relaxed),
        )
    }

    /// Wait until every entry stored so far is on disk.
    pub fn flush(&self) {
        let writes = std::mem::take(&mut *locked(&self.writes));
        for w in writes {
            let _ = w.join();
        }
    }

    fn drop_entry(&self, path: &Path, why: &str) {
        tracing::warn!(target: "ferrosa::prompt_cache", path = %path.display(),
            "prompt cache entry unusable, removed (a miss): {why}");
        let _ = fs::remove_file(path);
        locked(&self.shared.entries).retain(|e| e.path != path);
    }
}

impl Drop for PromptCache {
    fn drop(&mut self) {
        self.flush();
    }
}

impl Shared {
    /// Write one entry and keep the directory within its bound.
    fn write(&self, tokens: Vec<TokenId>, payload: &[u8]) {
        let name = entry_name(&self.key, &tokens);
        let path = self.dir.join(format!("{name}.kv"));
        let tmp = self.dir.join(format!(".{name}.{}.tmp", std::process::id()));
        let header = Header {
            key: self.key.clone(),
            tokens: tokens.clone(),
            payload_len: payload.len() as u64,
            payload_sha256: hex(&Sha256::digest(payload)),
        };
        let done = serde_json::to_vec(&header)
            .map_err(std::io::Error::other)
            .and_then(|h| {
                let mut out = Vec::with_capacity(MAGIC.len() + 4 + h.len() + payload.len());
                out.extend_from_slice(MAGIC);
                out.extend_from_slice(&(h.len() as u32).to_le_bytes());
                out.extend_from_slice(&h);
                out.extend_from_slice(payload);
                fs::write(&tmp, out)?;
                fs::rename(&tmp, &path)
            });
        if let Err(e) = done {
            let _ = fs::remove_file(&tmp);
            tracing::warn!(target: "ferrosa::prompt_cache", path = %path.display(),
                "cannot write a prompt cache entry: {e}");
            return;
        }
        tracing::debug!(target: "ferrosa::prompt_cache", tokens = tokens.len(),
            path = %path.display(), "stored");
        {
            let mut entries = locked(&self.entries);
            entries.retain(|e| e.path != path);
            entries.push(Entry { path, tokens });
        }
        self.evict();
    }

    /// Remove the least recently used files (of any key) until the directory fits its
    /// bound, and temporary files an interrupted write left an hour ago or more.
    fn evict(&self) {
        let Ok(dir) = fs::read_dir(&self.dir) else {
            return;
        };
        let now = SystemTime::now();
        let mut files: Vec<(SystemTime, u64, PathBuf)> = Vec::new();
        for e in dir.flatten() {
            let path = e.path();
            let Ok(md) = e.metadata() else { continue };
            let used = md.modified().unwrap_or(SystemTime::UNIX_EPOCH);
            let name = e.file_name().to_string_lossy().into_owned();
            if name.ends_with(".tmp") {
                let age = now.duration_since(used).unwrap_or_default();
                if age.as_secs() >= 3600 {
                    let _ = fs::remove_file(&path);
                }
            } else if name.ends_with(".kv") {
                files.push((used, md.len(), path));
            }
        }
        files.sort();
        let mut total: u64 = files.iter().map(|f| f.1).sum();
        for (_, len, path) in files {
            if total <= self.max_bytes {
                break;
            }
            if fs::remove_file(&path).is_ok() {
                total -= len;
                locked(&self.entries).retain(|e| e.path != path);
            }
        }
    }
}

/// How many leading tokens `a` and `b` share.
fn shared_prefix(a: &[TokenId], b: &[TokenId]) -> usize {
    a.iter().zip(b).take_while(|(x, y)| x == y).count()
}

/// The file name of the entry of `tokens` under `key`.
fn entry_name(key: &str, tokens: &[TokenId]) -> String {
    let mut h = Sha256::new();
    h.update(key.as_bytes());
    for t in tokens {
        h.update(t.to_le_bytes());
    }
    hex(&h.finalize()[..16])
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The header of the entry file at `path`, the file open after it, and how many bytes
/// the file holds after the header. The header's length is checked against the file's
/// before it is read.
fn read_header(path: &Path) -> Result<(Header, fs::File, u64), Unusable> {
    let mut f = fs::File::open(path)?;
    let len = f.metadata()?.len();
    let mut start = [0u8; PREAMBLE as usize];
    f.read_exact(&mut start).map_err(|_| Unusable::NotOurs)?;
    if &start[..MAGIC.len()] != MAGIC {
        return Err(Unusable::NotOurs);
    }
    let mut claimed = [0u8; 4];
    claimed.copy_from_slice(&start[MAGIC.len()..]);
    let claimed = u32::from_le_bytes(claimed);
    let holds = len.saturating_sub(PREAMBLE);
    if claimed > MAX_HEADER || u64::from(claimed) > holds {
        return Err(Unusable::Header { claimed, holds });
    }
    let mut header = vec![0u8; claimed as usize];
    f.read_exact(&mut header)?;
    let header: Header = serde_json::from_slice(&header)?;
    Ok((header, f, holds - u64::from(claimed)))
}

/// The payload `header` claims fits what the file holds after it, exactly, and the
/// directory's bound.
fn check_payload(header: &Header, holds: u64, bound: u64) -> Result<(), Unusable> {
    let claimed = header.payload_len;
    if claimed != holds {
        return Err(Unusable::Payload { claimed, holds });
    }
    if claimed > bound {
        return Err(Unusable::TooLarge { claimed, bound });
    }
    Ok(())
}

/// The entries of `key` in `dir` (files of other keys are left alone; files of this
/// key whose sizes do not add up are removed).
fn read_index(dir: &Path, key: &str, bound: u64) -> Vec<Entry> {
    let Ok(files) = fs::read_dir(dir) else {
        return Vec::new();
    };
    files
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "kv"))
        .filter_map(|path| match read_header(&path) {
            Ok((h, _, holds)) if h.key == key => match check_payload(&h, holds, bound) {
                Ok(()) => Some(Entry {
                    path,
                    tokens: h.tokens,
                }),
                Err(why) => {
                    tracing::warn!(target: "ferrosa::prompt_cache", path = %path.display(),
                        "prompt cache entry unusable, removed: {why}");
                    let _ = fs::remove_file(&path);
                    None
                }
            },
            _ => None,
        })
        .collect()
}

/// The payload of the entry at `path`, checked: its key, its tokens, its length (against
/// the file's, before a byte of it is read) and its hash. Any difference is the reason
/// it is unusable.
fn read_entry(path: &Path, key: &str, tokens: &[TokenId], bound: u64) -> Result<Vec<u8>, Unusable> {
    let (header, f, holds) = read_header(path)?;
    if header.key != key {
        return Err(Unusable::OtherKey);
    }
    if header.tokens != tokens {
        return Err(Unusable::TokensChanged);
    }
    check_payload(&header, holds, bound)?;
    // Checked above: the length is what the file holds, within the bound.
    let mut payload = Vec::with_capacity(holds as usize);
    f.take(holds).read_to_end(&mut payload)?;
    if payload.len() as u64 != holds {
        return Err(Unusable::Payload {
            claimed: header.payload_len,
            holds: payload.len() as u64,
        });
    }
    if hex(&Sha256::digest(&payload)) != header.payload_sha256 {
        return Err(Unusable::Hash);
    }
    Ok(payload)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::template::TemplateOrigin;
    use crate::backend::{BackendError, ChatTemplate, Tokenize, Vocab};

    /// A runtime whose "cache" is the token list itself, snapshot as bytes.
    struct Recorder {
        vocab: Vocab,
        template: ChatTemplate,
        cached: Vec<TokenId>,
        key: String,
    }

    impl Recorder {
        fn new(key: &str) -> Recorder {
            Recorder {
                vocab: Vocab::from_pieces(&["a"; 300]),
                template: ChatTemplate::new("", TemplateOrigin::File, "", "").unwrap(),
                cached: Vec::new(),
                key: key.into(),
            }
        }
    }

    struct NoTokens;
    impl Tokenize for NoTokens {
        fn tokenize(&self, _: &str, _: bool) -> Vec<TokenId> {
            Vec::new()
        }
    }

    impl Backend for Recorder {
        fn name(&self) -> &'static str {
            "recorder"
        }
        fn vocab(&self) -> &Vocab {
            &self.vocab
        }
        fn chat_template(&self) -> &ChatTemplate {
            &self.template
        }
        fn context_len(&self) -> usize {
            4096
        }
        fn tokenize(&self, _: &str, _: bool) -> Result<Vec<TokenId>, BackendError> {
            Ok(Vec::new())
        }
        fn tokenizer(&self) -> Arc<dyn Tokenize> {
            Arc::new(NoTokens)
        }
        fn forward(&mut self, keep: usize, t: &[TokenId]) -> Result<&mut [f32], BackendError> {
            self.cached.truncate(keep);
            self.cached.extend_from_slice(t);
            Err(BackendError::BadToken(0))
        }
        fn snapshot_key(&self) -> Option<String> {
            Some(self.key.clone())
        }
        fn snapshot(&self) -> Result<Vec<u8>, BackendError> {
            Ok(self.cached.iter().flat_map(|t| t.to_le_bytes()).collect())
        }
        fn restore(&mut self, bytes: &[u8], n: usize) -> Result<(), BackendError> {
            self.cached = bytes
                .chunks(4)
                .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
                .collect();
            assert_eq!(self.cached.len(), n);
            Ok(())
        }
    }

    fn prefix(n: u32) -> Vec<TokenId> {
        (0..n).map(|i| i % 250).collect()
    }

    /// A cache in `dir` holding one entry of `tokens`, and the entry's path.
    fn stored(dir: &Path, tokens: &[TokenId]) -> PathBuf {
        let mut rt = Recorder::new("k");
        rt.cached = tokens.to_vec();
        let cache = PromptCache::open(dir, "m", &rt, DEFAULT_MAX_BYTES).unwrap();
        cache.store(&rt, tokens);
        cache.flush();
        cache.entries()[0].0.clone()
    }

    fn fresh(dir: &Path) -> (PromptCache, Recorder) {
        let rt = Recorder::new("k");
        (
            PromptCache::open(dir, "m", &rt, DEFAULT_MAX_BYTES).unwrap(),
            rt,
        )
    }

    #[test]
    fn a_later_process_restores_the_longest_shared_prefix() {
        let dir = tempfile::tempdir().unwrap();
        stored(dir.path(), &prefix(100));
        stored(dir.path(), &prefix(300));
        let (cache, mut rt) = fresh(dir.path());
        let mut prompt = prefix(200);
        prompt.push(999);
        match cache.restore(&mut rt, &prompt, 1) {
            Restored::Hit(t) => assert_eq!(t, prefix(200), "the longer entry shares 200"),
            other => panic!("{other:?}"),
        }
        assert_eq!(rt.cached, prefix(300), "the runtime holds the whole entry");
        // In whole batches only: 200 shared is 192 in batches of 64, and nothing in
        // batches of 256.
        match cache.restore(&mut rt, &prompt, 64) {
            Restored::Hit(t) => assert_eq!(t, prefix(192)),
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            cache.restore(&mut rt, &prompt, 256),
            Restored::Miss
        ));
        // A stable prefix an entry holds whole is restored whole, batches or not; one
        // the entry only begins gets its whole batches.
        match cache.restore(&mut rt, &prefix(100), 64) {
            Restored::Hit(t) => assert_eq!(t, prefix(100)),
            other => panic!("{other:?}"),
        }
        match cache.restore(&mut rt, &prefix(101), 64) {
            Restored::Hit(t) => assert_eq!(t, prefix(64), "the 100-token entry, in batches"),
            other => panic!("{other:?}"),
        }
        // Another model or other settings: none of these entries is seen.
        let other = Recorder::new("k2");
        let c2 = PromptCache::open(dir.path(), "m", &other, DEFAULT_MAX_BYTES).unwrap();
        assert!(c2.entries().is_empty());
        let c3 = PromptCache::open(dir.path(), "m2", &rt, DEFAULT_MAX_BYTES).unwrap();
        assert!(c3.entries().is_empty());
    }

    #[test]
    fn a_corrupted_truncated_or_foreign_file_is_a_miss_and_removed() {
        let corrupt = |f: &dyn Fn(&mut Vec<u8>)| {
            let dir = tempfile::tempdir().unwrap();
            let path = stored(dir.path(), &prefix(200));
            let (cache, mut rt) = fresh(dir.path());
            let mut bytes = fs::read(&path).unwrap();
            f(&mut bytes);
            fs::write(&path, bytes).unwrap();
            let got = cache.restore(&mut rt, &prefix(200), 1);
            assert!(matches!(got, Restored::Miss), "{got:?}");
            assert!(rt.cached.is_empty(), "the runtime saw none of it");
            assert!(!path.exists(), "an unusable entry is removed");
            assert!(cache.entries().is_empty());
        };
        // A flipped bit in the payload.
        corrupt(&|b| {
            let n = b.len();
            b[n - 3] ^= 0x10;
        });
        // Truncated in the payload, and in the header.
        corrupt(&|b| b.truncate(b.len() - 10));
        corrupt(&|b| b.truncate(20));
        // The same key and tokens, but the header edited to another key.
        corrupt(&|b| {
            let s = String::from_utf8_lossy(b).replacen("model sha256 m;", "model sha256 x;", 1);
            *b = s.into_bytes();
        });
    }

    /// `path`'s entry with its header's `payload_len` replaced by `claim`.
    fn claim_payload(path: &Path, claim: u64) {
        let bytes = fs::read(path).unwrap();
        let len = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
        let mut header: serde_json::Value = serde_json::from_slice(&bytes[12..12 + len]).unwrap();
        header["payload_len"] = serde_json::json!(claim);
        let h = serde_json::to_vec(&header).unwrap();
        let mut out = MAGIC.to_vec();
        out.extend_from_slice(&(h.len() as u32).to_le_bytes());
        out.extend_from_slice(&h);
        out.extend_from_slice(&bytes[12 + len..]);
        fs::write(path, out).unwrap();
    }

    #[test]
    fn a_header_claiming_more_than_the_file_holds_is_a_miss_before_any_allocation() {
        for claim in [1u64 << 50, u64::MAX, 801, 799] {
            // Listed at start: the file is removed there.
            let dir = tempfile::tempdir().unwrap();
            let path = stored(dir.path(), &prefix(200));
            claim_payload(&path, claim);
            let (cache, mut rt) = fresh(dir.path());
            assert!(cache.entries().is_empty(), "claim {claim}");
            assert!(!path.exists(), "claim {claim}: removed at start");
            assert!(matches!(
                cache.restore(&mut rt, &prefix(200), 1),
                Restored::Miss
            ));
            // Changed after the start listed it: a miss when read, and removed.
            let path = stored(dir.path(), &prefix(200));
            let (cache, mut rt) = fresh(dir.path());
            claim_payload(&path, claim);
            let got = cache.restore(&mut rt, &prefix(200), 1);
            assert!(matches!(got, Restored::Miss), "claim {claim}: {got:?}");
            assert!(rt.cached.is_empty());
            assert!(!path.exists());
        }
        // More than the directory keeps, though the file holds it: a miss.
        let dir = tempfile::tempdir().unwrap();
        stored(dir.path(), &prefix(200));
        let rt = Recorder::new("k");
        let small = PromptCache::open(dir.path(), "m", &rt, 100).unwrap();
        assert!(small.entries().is_empty());
    }

    #[test]
    fn files_not_ours_are_ignored_and_the_bound_evicts_the_least_recent() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(dir.path().join("junk.kv"), b"not a cache file").unwrap();
        fs::write(dir.path().join("empty.kv"), b"").unwrap();
        let (cache, _) = fresh(dir.path());
        assert!(cache.entries().is_empty());
        // Each entry of 200 tokens is 800 bytes of payload plus its header.
        let mut rt = Recorder::new("k");
        let small = PromptCache::open(dir.path(), "m", &rt, 3000).unwrap();
        for n in [200, 201, 202] {
            rt.cached = prefix(n);
            small.store(&rt, &prefix(n));
            small.flush();
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let left: Vec<usize> = small.entries().iter().map(|e| e.1).collect();
        assert!(!left.contains(&200), "the oldest went first: {left:?}");
        assert!(left.contains(&202), "{left:?}");
    }
}
