//! NumPy arrays from an `.npz` file (a zip of `.npy` members): the little-endian `u1`,
//! `i1`, `f4` and `f8` arrays in C order that the sentence encoder's weights use. Each
//! array is read whole and checked against its header before it is kept.

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

use super::error::EmbedError;

/// One array: its shape and its elements as `f32` (or raw bytes for `u1`).
#[derive(Debug)]
pub struct Array {
    pub shape: Vec<usize>,
    pub data: Data,
}

#[derive(Debug)]
pub enum Data {
    U8(Vec<u8>),
    F32(Vec<f32>),
}

/// Largest member read (the encoder's biggest is 3.9 MB): a corrupt size cannot make it
/// allocate more.
const MAX_MEMBER: u64 = 64 << 20;

/// Every array of the file, by name (the member's name without `.npy`).
pub fn read(path: &Path) -> Result<HashMap<String, Array>, EmbedError> {
    let bad = |message: String| EmbedError::Weights {
        path: path.display().to_string(),
        message,
    };
    let file = std::fs::File::open(path).map_err(|e| bad(e.to_string()))?;
    let mut zip = zip::ZipArchive::new(file).map_err(|e| bad(e.to_string()))?;
    let mut out = HashMap::new();
    for i in 0..zip.len() {
        let mut member = zip.by_index(i).map_err(|e| bad(e.to_string()))?;
        let name = member.name().to_string();
        let Some(key) = name.strip_suffix(".npy") else {
            continue;
        };
        if member.size() > MAX_MEMBER {
            return Err(bad(format!("{name} is {} bytes", member.size())));
        }
        let mut bytes = Vec::with_capacity(member.size() as usize);
        (&mut member)
            .take(MAX_MEMBER)
            .read_to_end(&mut bytes)
            .map_err(|e| bad(format!("{name}: {e}")))?;
        let array = parse(&bytes).map_err(|m| bad(format!("{name}: {m}")))?;
        out.insert(key.to_string(), array);
    }
    Ok(out)
}

/// One `.npy` file.
fn parse(bytes: &[u8]) -> Result<Array, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a .npy array".into());
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(format!(".npy version {v}")),
    };
    let header = bytes
        .get(start..start + header_len)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or("the header is cut short")?;
    let descr = field(header, "descr").ok_or("no descr in the header")?;
    let descr = descr.trim_matches(|c| c == '\'' || c == '"');
    if field(header, "fortran_order").map(str::trim) != Some("False") {
        return Err("Fortran order".into());
    }
    let shape_text = header
        .split_once("'shape':")
        .and_then(|(_, r)| r.split_once('('))
        .and_then(|(_, r)| r.split_once(')'))
        .map(|(s, _)| s)
        .ok_or("no shape in the header")?;
    let shape = shape_text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!("shape {shape_text:?}"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let n = shape
        .iter()
        .try_fold(1usize, |a, d| a.checked_mul(*d))
        .ok_or("shape overflows")?;
    let body = &bytes[start + header_len..];
    let width = match descr {
        "|u1" | "|i1" => 1,
        "<f4" => 4,
        "<f8" => 8,
        other => return Err(format!("element type {other}")),
    };
    if body.len() != n * width {
        return Err(format!(
            "{} bytes of data for shape {shape:?} of {descr}",
            body.len()
        ));
    }
    let data = match descr {
        "|u1" => Data::U8(body.to_vec()),
        "|i1" => Data::F32(body.iter().map(|b| *b as i8 as f32).collect()),
        "<f4" => Data::F32(
            body.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        ),
        _ => Data::F32(
            body.chunks_exact(8)
                .map(|c| {
                    f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]) as f32
                })
                .collect(),
        ),
    };
    Ok(Array { shape, data })
}

/// The text after `'key':` up to the next comma at depth 0 of the header dict.
fn field<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let (_, rest) = header.split_once(&format!("'{key}':"))?;
    let end = rest.find([',', '}']).unwrap_or(rest.len());
    Some(rest[..end].trim())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(descr: &str, shape: &str, body: &[u8]) -> Vec<u8> {
        let header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend((header.len() as u16).to_le_bytes());
        out.extend(header.as_bytes());
        out.extend(body);
        out
    }

    #[test]
    fn reads_floats_bytes_and_scalars() {
        let body: Vec<u8> = [1.5f32, -2.0]
            .iter()
            .flat_map(|f| f.to_le_bytes())
            .collect();
        let a = parse(&npy("<f4", "(2,)", &body)).unwrap();
        assert_eq!(a.shape, vec![2]);
        assert!(matches!(a.data, Data::F32(ref v) if v == &[1.5, -2.0]));
        let b = parse(&npy("|u1", "(2, 3)", &[1, 2, 3, 4, 5, 6])).unwrap();
        assert_eq!(b.shape, vec![2, 3]);
        let s = parse(&npy("<f8", "()", &1e-3f64.to_le_bytes())).unwrap();
        assert_eq!(s.shape.iter().product::<usize>(), 1);
    }

    #[test]
    fn refuses_a_body_that_does_not_fit_its_shape_or_an_unknown_type() {
        assert!(parse(&npy("<f4", "(3,)", &[0; 8])).is_err());
        assert!(parse(&npy("<c16", "(1,)", &[0; 16])).is_err());
        assert!(parse(&npy("<f4", "(99999999999, 99999999999)", &[])).is_err());
        assert!(parse(b"\x93NUMPY\x01\x00\xff\xff").is_err());
        assert!(parse(b"garbage").is_err());
    }
}
