//! GGUF container reading: header, metadata key/values and tensor directory.
//!
//! Owns the checks that turn a bad file into a clear error before a runtime touches it
//! (not GGUF, unsupported version, truncated tensor data) and the typed view of the
//! metadata every other part needs (architecture, context length, tokens, chat template).
//! It does not read tensor data: runtimes mmap the file themselves.
//!
//! A file is input, not trusted (issue 41): every count, string length, array length and
//! tensor extent it claims is checked against the bytes the file has left before anything
//! is allocated for it, and sizes are computed with checked arithmetic, so a crafted
//! header is `Truncated` (it claims more than the file holds) or `Corrupt` (more than any
//! file could), never an abort or a wrapped size.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, BufReader, Read};
use std::path::{Path, PathBuf};

const MAGIC: [u8; 4] = *b"GGUF";
/// Longest string accepted in metadata; a larger length means a corrupt file, not a big one.
const MAX_STRING: u64 = 64 << 20;
/// Longest metadata array accepted (the largest vocabularies are ≈ 260k entries).
const MAX_ARRAY: u64 = 16 << 20;
/// Largest alignment accepted for the tensor data (GGUF writes 32).
const MAX_ALIGNMENT: u64 = 1 << 20;
/// Fewest bytes a metadata key and value take (an empty key, a type, a one-byte value).
const MIN_KV: u64 = 8 + 4 + 1;
/// Fewest bytes a tensor's directory entry takes (an empty name, no dimensions).
const MIN_TENSOR: u64 = 8 + 4 + 4 + 8;

#[derive(Debug, thiserror::Error)]
pub enum GgufError {
    #[error("cannot read {path}: {source}")]
    Io { path: PathBuf, source: io::Error },
    #[error("{path} is not a GGUF model file (it starts with {magic:?}, not \"GGUF\"); pass a .gguf file or a catalog name (see `ferrosa models list`)")]
    NotGguf { path: PathBuf, magic: String },
    #[error("{path} is GGUF version {version}; versions 2 and 3 are supported: re-convert it with a current llama.cpp")]
    Version { path: PathBuf, version: u32 },
    #[error("{path} is truncated: it ends at byte {actual} but what it describes needs {expected} bytes; delete it and fetch it again (`ferrosa models fetch`)")]
    Truncated {
        path: PathBuf,
        expected: u64,
        actual: u64,
    },
    #[error("{path} is corrupt: {what}; delete it and fetch it again (`ferrosa models fetch`)")]
    Corrupt { path: PathBuf, what: String },
}

/// One metadata value, as typed in the file.
#[derive(Debug, Clone, PartialEq)]
pub enum MetaValue {
    U8(u8),
    I8(i8),
    U16(u16),
    I16(i16),
    U32(u32),
    I32(i32),
    F32(f32),
    Bool(bool),
    Str(String),
    Array(Vec<MetaValue>),
    U64(u64),
    I64(i64),
    F64(f64),
}

impl MetaValue {
    /// Any integer type as u64 (negative values are not lengths or ids: `None`).
    pub fn as_u64(&self) -> Option<u64> {
        match *self {
            MetaValue::U8(v) => Some(v.into()),
            MetaValue::U16(v) => Some(v.into()),
            MetaValue::U32(v) => Some(v.into()),
            MetaValue::U64(v) => Some(v),
            MetaValue::I8(v) => u64::try_from(v).ok(),
            MetaValue::I16(v) => u64::try_from(v).ok(),
            MetaValue::I32(v) => u64::try_from(v).ok(),
            MetaValue::I64(v) => u64::try_from(v).ok(),
            _ => None,
        }
    }

    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            MetaValue::F32(v) => Some(v.into()),
            MetaValue::F64(v) => Some(v),
            _ => self.as_u64().map(|v| v as f64),
        }
    }

    pub fn as_str(&self) -> Option<&str> {
        match self {
            MetaValue::Str(s) => Some(s),
            _ => None,
        }
    }

    pub fn as_array(&self) -> Option<&[MetaValue]> {
        match self {
            MetaValue::Array(v) => Some(v),
            _ => None,
        }
    }
}

/// One entry of the tensor directory.
#[derive(Debug, Clone)]
pub struct TensorInfo {
    pub name: String,
    pub dims: Vec<u64>,
    pub ggml_type: u32,
    /// Offset from the start of the data section.
    pub offset: u64,
}

impl TensorInfo {
    /// Elements of the tensor, `None` when its extents overflow.
    pub fn elements(&self) -> Option<u64> {
        self.dims.iter().try_fold(1u64, |n, &d| n.checked_mul(d))
    }

    /// Bytes the tensor occupies, when its type is known (and its size fits a u64).
    pub fn byte_len(&self) -> Option<u64> {
        let (block, size) = ggml_type_layout(self.ggml_type)?;
        (self.elements()? / block).checked_mul(size)
    }
}

/// (elements per block, bytes per block) of the ggml tensor types, from ggml's type table.
fn ggml_type_layout(t: u32) -> Option<(u64, u64)> {
    Some(match t {
        0 => (1, 4),     // F32
        1 => (1, 2),     // F16
        2 => (32, 18),   // Q4_0
        3 => (32, 20),   // Q4_1
        6 => (32, 22),   // Q5_0
        7 => (32, 24),   // Q5_1
        8 => (32, 34),   // Q8_0
        9 => (32, 36),   // Q8_1
        10 => (256, 84), // Q2_K
        11 => (256, 110),
        12 => (256, 144),
        13 => (256, 176),
        14 => (256, 210),
        15 => (256, 292),
        16 => (256, 66),
        17 => (256, 74),
        18 => (256, 98),
        19 => (256, 50),
        20 => (32, 18),
        21 => (256, 110),
        22 => (256, 82),
        23 => (256, 136),
        24 => (1, 1),
        25 => (1, 2),
        26 => (1, 4),
        27 => (1, 8),
        28 => (1, 8),
        29 => (256, 56),
        30 => (1, 2), // BF16
        34 => (256, 54),
        35 => (256, 66),
        39 => (32, 17), // MXFP4
        _ => return None,
    })
}

/// A parsed GGUF header: everything but the tensor data.
#[derive(Debug, Clone)]
pub struct Gguf {
    pub path: PathBuf,
    pub version: u32,
    pub metadata: BTreeMap<String, MetaValue>,
    pub tensors: Vec<TensorInfo>,
    /// Absolute file offset of the (aligned) tensor data section.
    pub data_offset: u64,
    pub file_size: u64,
}

struct Cursor<R> {
    inner: R,
    pos: u64,
    /// The file's length: what is left bounds every count read.
    len: u64,
}

impl<R: Read> Cursor<R> {
    fn bytes<const N: usize>(&mut self) -> io::Result<[u8; N]> {
        let mut b = [0u8; N];
        self.inner.read_exact(&mut b)?;
        self.pos += N as u64;
        Ok(b)
    }
    fn u32(&mut self) -> io::Result<u32> {
        self.bytes::<4>().map(u32::from_le_bytes)
    }
    fn u64(&mut self) -> io::Result<u64> {
        self.bytes::<8>().map(u64::from_le_bytes)
    }
    /// Bytes of the file after the cursor.
    fn left(&self) -> u64 {
        self.len.saturating_sub(self.pos)
    }
}

impl Gguf {
    /// Read the header of `path` and check that the tensor data it describes is all there.
    pub fn open(path: &Path) -> Result<Gguf, GgufError> {
        let io_err = |source| GgufError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = File::open(path).map_err(io_err)?;
        let file_size = file.metadata().map_err(io_err)?.len();
        let mut cur = Cursor {
            inner: BufReader::with_capacity(1 << 16, file),
            pos: 0,
            len: file_size,
        };
        let corrupt = |what: String| GgufError::Corrupt {
            path: path.to_path_buf(),
            what,
        };
        // A file shorter than the header reads as "not GGUF" or "truncated", never as io.
        let eof = |e: io::Error, pos: u64| {
            if e.kind() == io::ErrorKind::UnexpectedEof {
                GgufError::Truncated {
                    path: path.to_path_buf(),
                    expected: pos + 1,
                    actual: file_size,
                }
            } else {
                io_err(e)
            }
        };

        let magic = match cur.bytes::<4>() {
            Ok(m) => m,
            Err(_) => {
                return Err(GgufError::NotGguf {
                    path: path.to_path_buf(),
                    magic: String::from("<shorter than 4 bytes>"),
                })
            }
        };
        if magic != MAGIC {
            return Err(GgufError::NotGguf {
                path: path.to_path_buf(),
                magic: String::from_utf8_lossy(&magic).into_owned(),
            });
        }
        let version = cur.u32().map_err(|e| eof(e, 4))?;
        if !(2..=3).contains(&version) {
            return Err(GgufError::Version {
                path: path.to_path_buf(),
                version,
            });
        }
        let n_tensors = cur.u64().map_err(|e| eof(e, 8))?;
        let n_kv = cur.u64().map_err(|e| eof(e, 16))?;
        if n_tensors > 1 << 20 || n_kv > 1 << 20 {
            return Err(corrupt(format!(
                "header claims {n_tensors} tensors and {n_kv} metadata keys"
            )));
        }
        // Within those bounds neither product overflows.
        let need = n_kv * MIN_KV + n_tensors * MIN_TENSOR;
        if need > cur.left() {
            return Err(GgufError::Truncated {
                path: path.to_path_buf(),
                expected: cur.pos + need,
                actual: file_size,
            });
        }

        let mut metadata = BTreeMap::new();
        for _ in 0..n_kv {
            let key = read_string(&mut cur).map_err(|e| map_read(e, &cur, path, file_size))?;
            let ty = cur.u32().map_err(|e| eof(e, cur.pos))?;
            let value =
                read_value(&mut cur, ty, 0).map_err(|e| map_read(e, &cur, path, file_size))?;
            metadata.insert(key, value);
        }

        let tensors = read_tensors(&mut cur, n_tensors, path)?;
        let data_offset = data_offset(&metadata, &tensors, cur.pos, path, file_size)?;
        Ok(Gguf {
            path: path.to_path_buf(),
            version,
            metadata,
            tensors,
            data_offset,
            file_size,
        })
    }

    pub fn get(&self, key: &str) -> Option<&MetaValue> {
        self.metadata.get(key)
    }

    pub(crate) fn get_str(&self, key: &str) -> Option<&str> {
        self.get(key).and_then(MetaValue::as_str)
    }

    pub(crate) fn get_u64(&self, key: &str) -> Option<u64> {
        self.get(key).and_then(MetaValue::as_u64)
    }

    /// `general.architecture`, e.g. "llama" or "gemma3".
    pub fn architecture(&self) -> Option<&str> {
        self.get_str("general.architecture")
    }

    /// A per-architecture key such as `llama.context_length`.
    pub(crate) fn arch_u64(&self, suffix: &str) -> Option<u64> {
        let arch = self.architecture()?;
        self.get_u64(&format!("{arch}.{suffix}"))
    }

    /// Bytes of an f16 K and V cache for `n_ctx` positions on every layer (the most a
    /// runtime keeps; sliding-window layers may keep less). `None` when the metadata is
    /// missing or its product overflows.
    pub fn kv_cache_bytes(&self, n_ctx: usize) -> Option<u64> {
        let layers = self.arch_u64("block_count")?;
        let heads = self.arch_u64("attention.head_count")?;
        let kv_heads = self.arch_u64("attention.head_count_kv").unwrap_or(heads);
        let head = self.arch_u64("embedding_length")? / heads.max(1);
        let k = self.arch_u64("attention.key_length").unwrap_or(head);
        let v = self.arch_u64("attention.value_length").unwrap_or(head);
        [layers, kv_heads, k.checked_add(v)?, 2]
            .into_iter()
            .try_fold(n_ctx as u64, u64::checked_mul)
    }

    pub(crate) fn context_length(&self) -> Option<u64> {
        self.arch_u64("context_length")
    }

    pub fn vocab_size(&self) -> Option<usize> {
        self.get("tokenizer.ggml.tokens")
            .and_then(MetaValue::as_array)
            .map(<[MetaValue]>::len)
    }

    pub fn chat_template(&self) -> Option<&str> {
        self.get_str("tokenizer.chat_template")
    }

    /// Strings of an array-of-strings key (tokens, merges); `None` if absent or mistyped.
    pub(crate) fn str_array(&self, key: &str) -> Option<Vec<&str>> {
        self.get(key)?
            .as_array()?
            .iter()
            .map(MetaValue::as_str)
            .collect()
    }

    /// Total parameter count, from the tensor directory (extents checked by `open`).
    pub fn n_params(&self) -> u64 {
        self.tensors
            .iter()
            .map(|t| t.elements().unwrap_or(u64::MAX))
            .fold(0, u64::saturating_add)
    }
}

enum ReadError {
    Io(io::Error),
    Corrupt(String),
    /// What was claimed needs this many bytes past the cursor, more than the file has.
    Short(u64),
}

impl From<io::Error> for ReadError {
    fn from(e: io::Error) -> Self {
        ReadError::Io(e)
    }
}

/// The `n` tensor descriptions after the metadata.
fn read_tensors<R: Read>(
    cur: &mut Cursor<R>,
    n: u64,
    path: &Path,
) -> Result<Vec<TensorInfo>, GgufError> {
    let file_size = cur.len;
    let corrupt = |what: String| GgufError::Corrupt {
        path: path.to_path_buf(),
        what,
    };
    let mut tensors = Vec::with_capacity(n as usize);
    for _ in 0..n {
        let name = read_string(cur).map_err(|e| map_read(e, cur, path, file_size))?;
        let n_dims = cur
            .u32()
            .map_err(|e| map_read(ReadError::Io(e), cur, path, file_size))?;
        if n_dims > 8 {
            return Err(corrupt(format!("tensor {name} has {n_dims} dimensions")));
        }
        let mut dims = Vec::with_capacity(n_dims as usize);
        for _ in 0..n_dims {
            dims.push(
                cur.u64()
                    .map_err(|e| map_read(ReadError::Io(e), cur, path, file_size))?,
            );
        }
        let ggml_type = cur
            .u32()
            .map_err(|e| map_read(ReadError::Io(e), cur, path, file_size))?;
        let offset = cur
            .u64()
            .map_err(|e| map_read(ReadError::Io(e), cur, path, file_size))?;
        let tensor = TensorInfo {
            name,
            dims,
            ggml_type,
            offset,
        };
        if tensor.elements().is_none() {
            return Err(corrupt(format!(
                "tensor {} has dimensions {:?}, more elements than can be",
                tensor.name, tensor.dims
            )));
        }
        tensors.push(tensor);
    }
    Ok(tensors)
}

/// Where the tensor data starts (the header's end `pos`, aligned), checked to hold every
/// tensor within the file.
fn data_offset(
    metadata: &BTreeMap<String, MetaValue>,
    tensors: &[TensorInfo],
    pos: u64,
    path: &Path,
    file_size: u64,
) -> Result<u64, GgufError> {
    let corrupt = |what: String| GgufError::Corrupt {
        path: path.to_path_buf(),
        what,
    };
    let alignment = metadata
        .get("general.alignment")
        .and_then(MetaValue::as_u64)
        .filter(|a| *a > 0)
        .unwrap_or(32);
    if alignment > MAX_ALIGNMENT {
        return Err(corrupt(format!("an alignment of {alignment} bytes")));
    }
    let data_offset = pos.div_ceil(alignment) * alignment;
    let mut expected = data_offset;
    for t in tensors {
        let Some(len) = t.byte_len() else { continue };
        let end = data_offset
            .checked_add(t.offset)
            .and_then(|start| start.checked_add(len))
            .ok_or_else(|| {
                corrupt(format!(
                    "tensor {} at offset {} of {len} bytes ends past any file",
                    t.name, t.offset
                ))
            })?;
        expected = expected.max(end);
    }
    if expected > file_size {
        return Err(GgufError::Truncated {
            path: path.to_path_buf(),
            expected,
            actual: file_size,
        });
    }
    Ok(data_offset)
}

fn map_read<R>(e: ReadError, cur: &Cursor<R>, path: &Path, file_size: u64) -> GgufError {
    match e {
        ReadError::Io(e) if e.kind() == io::ErrorKind::UnexpectedEof => GgufError::Truncated {
            path: path.to_path_buf(),
            expected: cur.pos + 1,
            actual: file_size,
        },
        ReadError::Io(source) => GgufError::Io {
            path: path.to_path_buf(),
            source,
        },
        ReadError::Corrupt(what) => GgufError::Corrupt {
            path: path.to_path_buf(),
            what,
        },
        ReadError::Short(need) => GgufError::Truncated {
            path: path.to_path_buf(),
            expected: cur.pos.saturating_add(need),
            actual: file_size,
        },
    }
}

fn read_string<R: Read>(cur: &mut Cursor<R>) -> Result<String, ReadError> {
    let len = cur.u64()?;
    if len > MAX_STRING {
        return Err(ReadError::Corrupt(format!(
            "a metadata string claims {len} bytes"
        )));
    }
    if len > cur.left() {
        return Err(ReadError::Short(len));
    }
    let mut buf = vec![0u8; len as usize];
    cur.inner.read_exact(&mut buf)?;
    cur.pos += len;
    // Token texts may hold invalid UTF-8 in old conversions; keep them readable, not fatal.
    Ok(String::from_utf8(buf)
        .unwrap_or_else(|e| String::from_utf8_lossy(e.as_bytes()).into_owned()))
}

/// Fewest bytes a metadata value of type `ty` takes in the file (an unknown type is
/// refused when read).
fn min_value_len(ty: u32) -> u64 {
    match ty {
        0 | 1 | 7 => 1,
        2 | 3 => 2,
        4..=6 => 4,
        8 | 10..=12 => 8,
        9 => 12,
        _ => 1,
    }
}

fn read_value<R: Read>(cur: &mut Cursor<R>, ty: u32, depth: u32) -> Result<MetaValue, ReadError> {
    Ok(match ty {
        0 => MetaValue::U8(cur.bytes::<1>()?[0]),
        1 => MetaValue::I8(cur.bytes::<1>()?[0] as i8),
        2 => MetaValue::U16(u16::from_le_bytes(cur.bytes()?)),
        3 => MetaValue::I16(i16::from_le_bytes(cur.bytes()?)),
        4 => MetaValue::U32(cur.u32()?),
        5 => MetaValue::I32(i32::from_le_bytes(cur.bytes()?)),
        6 => MetaValue::F32(f32::from_le_bytes(cur.bytes()?)),
        7 => MetaValue::Bool(cur.bytes::<1>()?[0] != 0),
        8 => MetaValue::Str(read_string(cur)?),
        9 => {
            if depth > 2 {
                return Err(ReadError::Corrupt("metadata arrays nested too deep".into()));
            }
            let item_ty = cur.u32()?;
            let len = cur.u64()?;
            if len > MAX_ARRAY {
                return Err(ReadError::Corrupt(format!(
                    "a metadata array claims {len} items"
                )));
            }
            // Within that bound the product does not overflow.
            let need = len * min_value_len(item_ty);
            if need > cur.left() {
                return Err(ReadError::Short(need));
            }
            let mut items = Vec::with_capacity(len as usize);
            for _ in 0..len {
                items.push(read_value(cur, item_ty, depth + 1)?);
            }
            MetaValue::Array(items)
        }
        10 => MetaValue::U64(cur.u64()?),
        11 => MetaValue::I64(i64::from_le_bytes(cur.bytes()?)),
        12 => MetaValue::F64(f64::from_le_bytes(cur.bytes()?)),
        other => {
            return Err(ReadError::Corrupt(format!(
                "unknown metadata value type {other}"
            )))
        }
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::io::Write;

    /// Writes a minimal, valid GGUF: two metadata keys and one F32 tensor of `n` floats.
    pub(crate) fn write_tiny_gguf(path: &Path, n: u64) {
        let mut b = Vec::new();
        b.extend_from_slice(b"GGUF");
        b.extend_from_slice(&3u32.to_le_bytes());
        b.extend_from_slice(&1u64.to_le_bytes());
        b.extend_from_slice(&2u64.to_le_bytes());
        let s = |b: &mut Vec<u8>, s: &str| {
            b.extend_from_slice(&(s.len() as u64).to_le_bytes());
            b.extend_from_slice(s.as_bytes());
        };
        s(&mut b, "general.architecture");
        b.extend_from_slice(&8u32.to_le_bytes());
        s(&mut b, "llama");
        s(&mut b, "llama.context_length");
        b.extend_from_slice(&4u32.to_le_bytes());
        b.extend_from_slice(&256u32.to_le_bytes());
        s(&mut b, "w");
        b.extend_from_slice(&1u32.to_le_bytes());
        b.extend_from_slice(&n.to_le_bytes());
        b.extend_from_slice(&0u32.to_le_bytes());
        b.extend_from_slice(&0u64.to_le_bytes());
        while b.len() % 32 != 0 {
            b.push(0);
        }
        b.extend(std::iter::repeat_n(0u8, (n * 4) as usize));
        File::create(path).unwrap().write_all(&b).unwrap();
    }

    #[test]
    fn reads_header_metadata_and_tensors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.gguf");
        write_tiny_gguf(&p, 64);
        let g = Gguf::open(&p).unwrap();
        assert_eq!(g.architecture(), Some("llama"));
        assert_eq!(g.context_length(), Some(256));
        assert_eq!(g.tensors.len(), 1);
        assert_eq!(g.tensors[0].byte_len(), Some(256));
        assert_eq!(g.n_params(), 64);
    }

    #[test]
    fn truncated_data_is_reported_with_sizes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.gguf");
        write_tiny_gguf(&p, 64);
        let len = std::fs::metadata(&p).unwrap().len();
        let f = std::fs::OpenOptions::new().write(true).open(&p).unwrap();
        f.set_len(len - 10).unwrap();
        match Gguf::open(&p) {
            Err(GgufError::Truncated {
                expected, actual, ..
            }) => {
                assert_eq!(expected, len);
                assert_eq!(actual, len - 10);
            }
            other => panic!("expected Truncated, got {other:?}"),
        }
    }

    #[test]
    fn truncated_header_is_truncated_not_io() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.gguf");
        write_tiny_gguf(&p, 64);
        let f = std::fs::OpenOptions::new().write(true).open(&p).unwrap();
        f.set_len(40).unwrap();
        assert!(matches!(Gguf::open(&p), Err(GgufError::Truncated { .. })));
    }

    #[test]
    fn other_files_are_not_gguf() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.gguf");
        std::fs::write(&p, b"<html>not a model</html>").unwrap();
        let err = Gguf::open(&p).unwrap_err();
        assert!(matches!(err, GgufError::NotGguf { .. }), "{err}");
        assert!(err.to_string().contains("not a GGUF"));
        std::fs::write(&p, b"GG").unwrap();
        assert!(matches!(Gguf::open(&p), Err(GgufError::NotGguf { .. })));
    }

    /// GGUF bytes: the header, `body` as written.
    fn header(n_tensors: u64, n_kv: u64, body: &[u8]) -> Vec<u8> {
        let mut b = b"GGUF".to_vec();
        b.extend_from_slice(&3u32.to_le_bytes());
        b.extend_from_slice(&n_tensors.to_le_bytes());
        b.extend_from_slice(&n_kv.to_le_bytes());
        b.extend_from_slice(body);
        b
    }

    fn open_bytes(bytes: &[u8]) -> Result<Gguf, GgufError> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.gguf");
        std::fs::write(&p, bytes).unwrap();
        Gguf::open(&p)
    }

    #[test]
    fn claims_past_the_files_end_are_corrupt_before_allocating() {
        let key = |b: &mut Vec<u8>| {
            b.extend_from_slice(&1u64.to_le_bytes());
            b.push(b'k');
        };
        // A string of 60 MiB, arrays of 16M items nested three deep, in a few bytes.
        let mut s = Vec::new();
        key(&mut s);
        s.extend_from_slice(&8u32.to_le_bytes());
        s.extend_from_slice(&(60u64 << 20).to_le_bytes());
        let mut a = Vec::new();
        key(&mut a);
        a.extend_from_slice(&9u32.to_le_bytes());
        for item in [9u32, 9, 0] {
            a.extend_from_slice(&item.to_le_bytes());
            a.extend_from_slice(&(16u64 << 20).to_le_bytes());
        }
        for (what, bytes) in [
            ("a string", header(0, 1, &s)),
            ("arrays", header(0, 1, &a)),
            ("a million keys", header(0, 1 << 20, &[])),
            ("a million tensors", header(1 << 20, 0, &[])),
        ] {
            let e = open_bytes(&bytes).unwrap_err();
            assert!(matches!(e, GgufError::Truncated { .. }), "{what}: {e}");
        }
        // Extents whose product overflows, and an offset past any file.
        let tensor = |dims: &[u64], offset: u64| {
            let mut b = Vec::new();
            key(&mut b);
            b.extend_from_slice(&(dims.len() as u32).to_le_bytes());
            for d in dims {
                b.extend_from_slice(&d.to_le_bytes());
            }
            b.extend_from_slice(&0u32.to_le_bytes());
            b.extend_from_slice(&offset.to_le_bytes());
            header(1, 0, &b)
        };
        let e = open_bytes(&tensor(&[1 << 20; 4], 0)).unwrap_err();
        assert!(matches!(e, GgufError::Corrupt { .. }), "{e}");
        let e = open_bytes(&tensor(&[4], u64::MAX - 2)).unwrap_err();
        assert!(matches!(e, GgufError::Corrupt { .. }), "{e}");
    }

    #[test]
    fn absurd_lengths_are_corrupt_not_oom() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.gguf");
        let mut b = Vec::new();
        b.extend_from_slice(b"GGUF");
        b.extend_from_slice(&3u32.to_le_bytes());
        b.extend_from_slice(&0u64.to_le_bytes());
        b.extend_from_slice(&1u64.to_le_bytes());
        b.extend_from_slice(&u64::MAX.to_le_bytes());
        // Bytes for a key and a value after it: the length itself is what is absurd.
        b.extend_from_slice(&[0; 8]);
        std::fs::write(&p, &b).unwrap();
        assert!(matches!(Gguf::open(&p), Err(GgufError::Corrupt { .. })));
    }
}
