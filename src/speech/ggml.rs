//! whisper.cpp's model file (the legacy `ggml` format the Whisper weights ship in): the
//! hyper-parameters, the mel filter bank, the vocabulary (each token's bytes) and the
//! tensors, renamed from OpenAI's names to those `candle-transformers`' Whisper reads.
//!
//! Layout, little-endian: magic `ggml`; eleven i32 (n_vocab, n_audio_ctx,
//! n_audio_state, n_audio_head, n_audio_layer, n_text_ctx, n_text_state, n_text_head,
//! n_text_layer, n_mels, ftype); the filters (i32 n_mel, i32 n_fft, then f32s); the
//! vocabulary (i32 count, then per token a u32 length and its bytes); then tensors to
//! the end (i32 n_dims, i32 name length, i32 type (0 f32, 1 f16), n_dims i32 extents
//! innermost first, the name, the data).
//!
//! Every count and size the file gives is checked against the bytes left before it is
//! used or allocated for: a file that claims more than it holds is cut short, never an
//! abort.

use std::collections::HashMap;

use candle_core::{DType, Device, Tensor};

#[derive(Debug, thiserror::Error)]
pub enum GgmlError {
    #[error("not a whisper.cpp model file (magic {0:#x}); use a ggml-*.bin Whisper model, e.g. `ferrosa models fetch whisper-base-en`")]
    Magic(u32),
    #[error("the model file is cut short at byte {0}: fetch it again (`ferrosa models fetch whisper-base-en --force`)")]
    Truncated(usize),
    #[error("tensor {name}: type {kind} is not supported (f32 and f16 are)")]
    Type { name: String, kind: i32 },
    #[error("tensor {0} has no counterpart in the model this reads")]
    Unknown(String),
    #[error("the model file is corrupt at byte {at}: {what}; fetch it again (`ferrosa models fetch whisper-base-en --force`)")]
    Corrupt { at: usize, what: &'static str },
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// Whisper's hyper-parameters as the file gives them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Hparams {
    pub n_vocab: usize,
    pub n_audio_ctx: usize,
    pub n_audio_state: usize,
    pub n_audio_head: usize,
    pub n_audio_layer: usize,
    pub n_text_ctx: usize,
    pub n_text_state: usize,
    pub n_text_head: usize,
    pub n_text_layer: usize,
    pub n_mels: usize,
}

/// A whisper.cpp model file, read.
pub struct GgmlWhisper {
    pub hparams: Hparams,
    /// `n_mels` × `n_fft` (201 for a 400-point FFT), row-major.
    pub filters: Vec<f32>,
    /// Each token's bytes, by id.
    pub vocab: Vec<Vec<u8>>,
    /// By candle-transformers' names, as f32.
    pub tensors: HashMap<String, Tensor>,
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], GgmlError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len());
        let end = end.ok_or(GgmlError::Truncated(self.at))?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn i32(&mut self) -> Result<i32, GgmlError> {
        Ok(i32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }

    fn count(&mut self) -> Result<usize, GgmlError> {
        let at = self.at;
        usize::try_from(self.i32()?).map_err(|_| GgmlError::Truncated(at))
    }

    /// Bytes not read yet.
    fn left(&self) -> usize {
        self.b.len() - self.at
    }

    /// `a * b` bytes, or the file is cut short (no size that large fits in it).
    fn size(&self, a: usize, b: usize) -> Result<usize, GgmlError> {
        a.checked_mul(b).ok_or(GgmlError::Truncated(self.at))
    }
}

/// Read a whisper.cpp model file's bytes.
pub fn read(bytes: &[u8]) -> Result<GgmlWhisper, GgmlError> {
    let mut r = Reader { b: bytes, at: 0 };
    let magic = u32::from_le_bytes(r.take(4)?.try_into().expect("4 bytes"));
    if magic != 0x6767_6d6c {
        return Err(GgmlError::Magic(magic));
    }
    let mut h = [0usize; 11];
    for v in &mut h {
        *v = r.count()?;
    }
    let hparams = Hparams {
        n_vocab: h[0],
        n_audio_ctx: h[1],
        n_audio_state: h[2],
        n_audio_head: h[3],
        n_audio_layer: h[4],
        n_text_ctx: h[5],
        n_text_state: h[6],
        n_text_head: h[7],
        n_text_layer: h[8],
        n_mels: h[9],
    };
    let (n_mel, n_fft) = (r.count()?, r.count()?);
    let filter_bytes = r.size(r.size(n_mel, n_fft)?, 4)?;
    let filters = r
        .take(filter_bytes)?
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect();
    let n = r.count()?;
    // Each token takes at least its 4-byte length.
    if n > r.left() / 4 {
        return Err(GgmlError::Truncated(r.at));
    }
    let mut vocab = Vec::with_capacity(n);
    for _ in 0..n {
        let len = r.count()?;
        vocab.push(r.take(len)?.to_vec());
    }
    let mut tensors = HashMap::new();
    while r.at < bytes.len() {
        let at = r.at;
        let (n_dims, name_len, kind) = (r.count()?, r.count()?, r.i32()?);
        if n_dims > 4 {
            return Err(GgmlError::Corrupt {
                at,
                what: "a tensor of more than 4 dimensions",
            });
        }
        let mut dims = (0..n_dims)
            .map(|_| r.count())
            .collect::<Result<Vec<_>, _>>()?;
        let name = String::from_utf8_lossy(r.take(name_len)?).into_owned();
        let (dtype, width) = match kind {
            0 => (DType::F32, 4),
            1 => (DType::F16, 2),
            _ => return Err(GgmlError::Type { name, kind }),
        };
        dims.reverse();
        let count = dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
        let bytes = count
            .and_then(|c| c.checked_mul(width))
            .ok_or(GgmlError::Truncated(r.at))?;
        let data = r.take(bytes)?;
        let t = Tensor::from_raw_buffer(data, dtype, &dims, &Device::Cpu)?.to_dtype(DType::F32)?;
        let hf = hf_name(&name).ok_or_else(|| GgmlError::Unknown(name.clone()))?;
        // The converter keeps conv biases as (n, 1).
        let t = if name.ends_with("conv1.bias") || name.ends_with("conv2.bias") {
            t.flatten_all()?
        } else {
            t
        };
        tensors.insert(hf, t);
    }
    Ok(GgmlWhisper {
        hparams,
        filters,
        vocab,
        tensors,
    })
}

/// candle-transformers' (Hugging Face's) name for an OpenAI Whisper tensor name; `None`
/// for one it does not read.
fn hf_name(name: &str) -> Option<String> {
    let (side, rest) = name.split_once('.')?;
    if !matches!(side, "encoder" | "decoder") {
        return None;
    }
    let prefix = format!("model.{side}");
    if let Some(block) = rest.strip_prefix("blocks.") {
        let (i, part) = block.split_once('.')?;
        let (module, leaf) = part.rsplit_once('.')?;
        let module = match module {
            "attn.query" => "self_attn.q_proj",
            "attn.key" => "self_attn.k_proj",
            "attn.value" => "self_attn.v_proj",
            "attn.out" => "self_attn.out_proj",
            "attn_ln" => "self_attn_layer_norm",
            "cross_attn.query" => "encoder_attn.q_proj",
            "cross_attn.key" => "encoder_attn.k_proj",
            "cross_attn.value" => "encoder_attn.v_proj",
            "cross_attn.out" => "encoder_attn.out_proj",
            "cross_attn_ln" => "encoder_attn_layer_norm",
            "mlp.0" => "fc1",
            "mlp.2" => "fc2",
            "mlp_ln" => "final_layer_norm",
            _ => return None,
        };
        return Some(format!("{prefix}.layers.{i}.{module}.{leaf}"));
    }
    let mapped = match rest {
        "positional_embedding" => "embed_positions.weight".to_string(),
        "token_embedding.weight" => "embed_tokens.weight".to_string(),
        r if r.starts_with("conv1.") || r.starts_with("conv2.") => r.to_string(),
        r => {
            let (module, leaf) = r.rsplit_once('.')?;
            match module {
                "ln_post" | "ln" => format!("layer_norm.{leaf}"),
                _ => return None,
            }
        }
    };
    Some(format!("{prefix}.{mapped}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn openai_names_map_to_the_ones_candle_reads() {
        for (from, to) in [
            ("encoder.conv1.weight", "model.encoder.conv1.weight"),
            (
                "encoder.positional_embedding",
                "model.encoder.embed_positions.weight",
            ),
            (
                "encoder.blocks.3.attn.query.bias",
                "model.encoder.layers.3.self_attn.q_proj.bias",
            ),
            (
                "encoder.blocks.0.mlp.2.weight",
                "model.encoder.layers.0.fc2.weight",
            ),
            ("encoder.ln_post.bias", "model.encoder.layer_norm.bias"),
            (
                "decoder.token_embedding.weight",
                "model.decoder.embed_tokens.weight",
            ),
            (
                "decoder.positional_embedding",
                "model.decoder.embed_positions.weight",
            ),
            (
                "decoder.blocks.5.cross_attn_ln.weight",
                "model.decoder.layers.5.encoder_attn_layer_norm.weight",
            ),
            (
                "decoder.blocks.5.cross_attn.key.weight",
                "model.decoder.layers.5.encoder_attn.k_proj.weight",
            ),
            ("decoder.ln.weight", "model.decoder.layer_norm.weight"),
        ] {
            assert_eq!(hf_name(from).as_deref(), Some(to), "{from}");
        }
        assert_eq!(hf_name("decoder.blocks.1.attn.rotary"), None);
        assert_eq!(hf_name("alignment_heads"), None);
    }

    #[test]
    fn a_foreign_or_cut_file_is_an_error() {
        assert!(matches!(read(b"GGUF\x03\0\0\0"), Err(GgmlError::Magic(_))));
        let mut cut = b"lmgg".to_vec();
        cut.extend_from_slice(&5i32.to_le_bytes());
        assert!(matches!(read(&cut), Err(GgmlError::Truncated(8))));
    }

    /// A header of eleven `h`s, then `rest` (little-endian i32s).
    fn file(h: i32, rest: &[i32]) -> Vec<u8> {
        let mut b = b"lmgg".to_vec();
        for v in std::iter::repeat_n(h, 11).chain(rest.iter().copied()) {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b
    }

    #[test]
    fn counts_claiming_more_than_the_file_holds_are_refused_before_allocating() {
        // Filters of i32::MAX × i32::MAX floats.
        let e = read(&file(1, &[i32::MAX, i32::MAX])).err().unwrap();
        assert!(matches!(e, GgmlError::Truncated(_)), "{e}");
        // 2^31 - 1 tokens in a file of 60 bytes.
        let e = read(&file(1, &[0, 0, i32::MAX])).err().unwrap();
        assert!(matches!(e, GgmlError::Truncated(_)), "{e}");
        // A tensor of a billion dimensions, and one whose extents overflow.
        let e = read(&file(1, &[0, 0, 0, 1_000_000_000, 1, 0]))
            .err()
            .unwrap();
        assert!(matches!(e, GgmlError::Corrupt { .. }), "{e}");
        let big = i32::MAX;
        let e = read(&file(1, &[0, 0, 0, 4, 1, 0, big, big, big, big, 0]))
            .err()
            .unwrap();
        assert!(matches!(e, GgmlError::Truncated(_)), "{e}");
    }
}
