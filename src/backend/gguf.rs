//! GGUF container reading: header, metadata key/values and tensor directory.
//!
//! Owns the checks that turn a bad file into a clear error before a runtime touches it
//! (not GGUF, unsupported version, truncated tensor data) and the typed view of the
//! metadata every other part needs (architecture, context length, tokens, chat template).
//! It does not read tensor data: runtimes mmap the file themselves.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, BufReader, Read};
use std::path::{Path, PathBuf};

const MAGIC: [u8; 4] = *b"GGUF";
/// Longest string accepted in metadata; a larger length means a corrupt file, not a big one.
const MAX_STRING: u64 = 64 << 20;
/// Longest metadata array accepted (the largest vocabularies are ≈ 260k entries).
const MAX_ARRAY: u64 = 16 << 20;

#[derive(Debug, thiserror::Error)]
pub enum GgufError {
    #[error("cannot read {path}: {source}")]
    Io { path: PathBuf, source: io::Error },
    #[error("{path} is not a GGUF model file (it starts with {magic:?}, not \"GGUF\"); pass a .gguf file or a catalog name (see `ferrosa models list`)")]
    NotGguf { path: PathBuf, magic: String },
    #[error("{path} is GGUF version {version}; versions 2 and 3 are supported: re-convert it with a current llama.cpp")]
    Version { path: PathBuf, version: u32 },
    #[error("{path} is truncated: it ends at byte {actual} but its tensors need {expected} bytes; delete it and fetch it again (`ferrosa models fetch`)")]
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
    /// Bytes the tensor occupies, when its type is known.
    pub fn byte_len(&self) -> Option<u64> {
        let (block, size) = ggml_type_layout(self.ggml_type)?;
        let elems: u64 = self.dims.iter().product();
        Some(elems / block * size)
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

        let mut metadata = BTreeMap::new();
        for _ in 0..n_kv {
            let key = read_string(&mut cur).map_err(|e| map_read(e, &cur, path, file_size))?;
            let ty = cur.u32().map_err(|e| eof(e, cur.pos))?;
            let value =
                read_value(&mut cur, ty, 0).map_err(|e| map_read(e, &cur, path, file_size))?;
            metadata.insert(key, value);
        }

        let mut tensors = Vec::with_capacity(n_tensors as usize);
        for _ in 0..n_tensors {
            let name = read_string(&mut cur).map_err(|e| map_read(e, &cur, path, file_size))?;
            let n_dims = cur.u32().map_err(|e| eof(e, cur.pos))?;
            if n_dims > 8 {
                return Err(corrupt(format!("tensor {name} has {n_dims} dimensions")));
            }
            let mut dims = Vec::with_capacity(n_dims as usize);
            for _ in 0..n_dims {
                dims.push(cur.u64().map_err(|e| eof(e, cur.pos))?);
            }
            let ggml_type = cur.u32().map_err(|e| eof(e, cur.pos))?;
            let offset = cur.u64().map_err(|e| eof(e, cur.pos))?;
            tensors.push(TensorInfo {
                name,
                dims,
                ggml_type,
                offset,
            });
        }

        let alignment = metadata
            .get("general.alignment")
            .and_then(MetaValue::as_u64)
            .filter(|a| *a > 0)
            .unwrap_or(32);
        let data_offset = cur.pos.div_ceil(alignment) * alignment;
        let expected = tensors
            .iter()
            .filter_map(|t| t.byte_len().map(|len| data_offset + t.offset + len))
            .max()
            .unwrap_or(data_offset);
        if expected > file_size {
            return Err(GgufError::Truncated {
                path: path.to_path_buf(),
                expected,
                actual: file_size,
            });
        }
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

    pub fn get_str(&self, key: &str) -> Option<&str> {
        self.get(key).and_then(MetaValue::as_str)
    }

    pub fn get_u64(&self, key: &str) -> Option<u64> {
        self.get(key).and_then(MetaValue::as_u64)
    }

    /// `general.architecture`, e.g. "llama" or "gemma3".
    pub fn architecture(&self) -> Option<&str> {
        self.get_str("general.architecture")
    }

    /// A per-architecture key such as `llama.context_length`.
    pub fn arch_u64(&self, suffix: &str) -> Option<u64> {
        let arch = self.architecture()?;
        self.get_u64(&format!("{arch}.{suffix}"))
    }

    /// Bytes of an f16 K and V cache for `n_ctx` positions on every layer (the most a
    /// runtime keeps; sliding-window layers may keep less).
    pub fn kv_cache_bytes(&self, n_ctx: usize) -> Option<u64> {
        let layers = self.arch_u64("block_count")?;
        let heads = self.arch_u64("attention.head_count")?;
        let kv_heads = self.arch_u64("attention.head_count_kv").unwrap_or(heads);
        let head = self.arch_u64("embedding_length")? / heads.max(1);
        let k = self.arch_u64("attention.key_length").unwrap_or(head);
        let v = self.arch_u64("attention.value_length").unwrap_or(head);
        Some(n_ctx as u64 * layers * kv_heads * (k + v) * 2)
    }

    pub fn context_length(&self) -> Option<u64> {
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
    pub fn str_array(&self, key: &str) -> Option<Vec<&str>> {
        self.get(key)?
            .as_array()?
            .iter()
            .map(MetaValue::as_str)
            .collect()
    }

    /// Total parameter count, from the tensor directory.
    pub fn n_params(&self) -> u64 {
        self.tensors
            .iter()
            .map(|t| t.dims.iter().product::<u64>())
            .sum()
    }
}

enum ReadError {
    Io(io::Error),
    Corrupt(String),
}

impl From<io::Error> for ReadError {
    fn from(e: io::Error) -> Self {
        ReadError::Io(e)
    }
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
    }
}

fn read_string<R: Read>(cur: &mut Cursor<R>) -> Result<String, ReadError> {
    let len = cur.u64()?;
    if len > MAX_STRING {
        return Err(ReadError::Corrupt(format!(
            "a metadata string claims {len} bytes"
        )));
    }
    let mut buf = vec![0u8; len as usize];
    cur.inner.read_exact(&mut buf)?;
    cur.pos += len;
    // Token texts may hold invalid UTF-8 in old conversions; keep them readable, not fatal.
    Ok(String::from_utf8(buf)
        .unwrap_or_else(|e| String::from_utf8_lossy(e.as_bytes()).into_owned()))
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
        std::fs::write(&p, &b).unwrap();
        assert!(matches!(Gguf::open(&p), Err(GgufError::Corrupt { .. })));
    }
}
