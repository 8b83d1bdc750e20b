//! The decoder-only transformer candle runs, for the two families ferrosa ships: llama
//! (SmolLM2) and Gemma 3, from a GGUF file's quantized weights.
//!
//! Written here rather than taken from candle-transformers: its `quantized_gemma3` in
//! 0.11.1 applies SiLU where Gemma 3 has GELU and one RoPE base to every layer where
//! Gemma 3 has two, and its KV caches cannot keep a prefix and drop the rest (the
//! agent's turns and the weighed pick's branches need that). What Gemma 3 adds to llama,
//! as llama.cpp runs the same file:
//! - the embeddings scaled by √n_embd;
//! - RMS norms of each head's query and key, before RoPE;
//! - a norm after attention and one after the feed-forward, before each residual add;
//! - GELU (tanh form) gating the feed-forward;
//! - NeoX RoPE (halves, not interleaved pairs), base 10,000 on sliding-window layers and
//!   the file's base (10⁶) on the global ones, every sixth layer;
//! - on sliding-window layers a query sees the last `sliding_window` positions only;
//! - attention scaled by 1/√key_length.
//!
//! The KV cache keeps every position, so a prefix can be kept and its tail dropped.
//! This file holds the weights, the caches and the pass for prompts, as candle tensors
//! (attention as matrix products); a few tokens at a time go through `rows` instead.

use candle_core::quantized::{gguf_file, GgmlDType, QMatMul, QTensor};
use candle_core::{DType, Device, Module, Tensor};

use super::super::{Gguf, TokenId};
use super::matvec::{Format, QRows};

/// Positions the KV cache grows by when full (amortises the copy).
const KV_GROW: usize = 256;
/// Gemma 3: one layer in this many attends globally; the others in a sliding window.
const GEMMA3_GLOBAL_EVERY: usize = 6;
/// Gemma 3's RoPE base on sliding-window layers (not in the file; llama.cpp's value).
const GEMMA3_LOCAL_BASE: f32 = 10_000.0;

/// The model families this runtime knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Family {
    Llama,
    Gemma3,
}

impl Family {
    pub fn of(arch: &str) -> Option<Family> {
        match arch {
            "llama" => Some(Family::Llama),
            "gemma3" => Some(Family::Gemma3),
            _ => None,
        }
    }
}

/// A batch of at least this many tokens goes through the dense copy of each weight,
/// when there is one.
const DENSE_FROM: usize = 16;

/// A weight matrix, quantized as the file holds it; and, when the model is loaded with
/// them (`LoadOptions::dense_weights`), dequantized, for batches (compute bound: the
/// `gemm` crate's kernels outrun quantized dot products, at 4 bytes a weight instead
/// of about 0.6: about 440 MiB more at peak for SmolLM2, 677 against 240 MiB).
pub(super) struct Linear {
    quantized: Quantized,
    dense: Option<QMatMul>,
    rows: usize,
    cols: usize,
}

enum Quantized {
    Candle(QMatMul),
    /// Q4_1 and Q8_0, which `matvec` computes (candle computes Q4_1 with a scalar loop).
    Own(QRows),
}

impl Linear {
    fn new(t: QTensor, dense: bool, device: &Device) -> candle_core::Result<Linear> {
        let (rows, cols) = t.shape().dims2()?;
        let dense = match dense {
            true => Some(QMatMul::Tensor(t.dequantize(device)?)),
            false => None,
        };
        let format = match t.dtype() {
            GgmlDType::Q4_1 => Some(Format::Q41),
            GgmlDType::Q8_0 => Some(Format::Q80),
            _ => None,
        };
        let quantized = match format {
            Some(format) => {
                let q =
                    QRows::new(format, t.data()?.into_owned(), rows, cols).ok_or_else(|| {
                        candle_core::Error::Msg(format!("a {format:?} tensor of the wrong size"))
                    })?;
                Quantized::Own(q)
            }
            None => Quantized::Candle(QMatMul::from_qtensor(t)?),
        };
        Ok(Linear {
            quantized,
            dense,
            rows,
            cols,
        })
    }

    /// `x`: (1, seq, in).
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let seq = x.dim(1)?;
        if let (Some(dense), true) = (&self.dense, seq >= DENSE_FROM) {
            return dense.forward(x);
        }
        match &self.quantized {
            Quantized::Candle(q) => q.forward(x),
            Quantized::Own(q) => {
                let xs = x.flatten_all()?.to_vec1::<f32>()?;
                let mut out = vec![0.0; seq * self.rows];
                q.matvecs(&xs, seq, &mut out);
                Tensor::from_vec(out, (1, seq, self.rows), x.device())
            }
        }
    }

    /// W·x for `n` vectors one after another in `xs`, into `out` (`n` × out): each
    /// vector's product as it would be alone, bit for bit (the rows pass).
    pub(super) fn rows(&self, xs: &[f32], n: usize, out: &mut [f32]) -> candle_core::Result<()> {
        match &self.quantized {
            Quantized::Own(q) => q.matvecs(xs, n, out),
            Quantized::Candle(q) => {
                // candle's kernels take another path for several vectors than for one:
                // one at a time, so that none depends on the others.
                for (x, o) in xs
                    .chunks_exact(self.cols)
                    .zip(out.chunks_exact_mut(self.rows))
                {
                    let x = Tensor::from_slice(x, (1, 1, self.cols), &Device::Cpu)?;
                    o.copy_from_slice(&q.forward(&x)?.flatten_all()?.to_vec1::<f32>()?);
                }
            }
        }
        Ok(())
    }

    pub(super) fn out_dim(&self) -> usize {
        self.rows
    }

    /// Row `r` of the matrix, dequantized, when `matvec` holds it (an embedding
    /// shared with the output layer).
    fn row(&self, r: usize, out: &mut [f32]) -> bool {
        match &self.quantized {
            Quantized::Own(q) => q.dequantize_row(r, out),
            Quantized::Candle(_) => false,
        }
    }
}

pub(super) struct Layer {
    pub(super) attn_norm: Norm,
    pub(super) wq: Linear,
    pub(super) wk: Linear,
    pub(super) wv: Linear,
    pub(super) wo: Linear,
    pub(super) ffn_norm: Norm,
    pub(super) gate: Linear,
    pub(super) up: Linear,
    pub(super) down: Linear,
    /// Gemma 3: per-head query and key norms, and the norms after attention and after
    /// the feed-forward.
    pub(super) q_norm: Option<Norm>,
    pub(super) k_norm: Option<Norm>,
    pub(super) post_attn_norm: Option<Norm>,
    pub(super) post_ffn_norm: Option<Norm>,
    /// Positions a query sees on this layer (itself included); None: all before it.
    pub(super) window: Option<usize>,
    /// Which RoPE table this layer uses.
    pub(super) rope: usize,
    /// (1, n_kv_head, capacity, head_dim); the first `len` positions are valid.
    pub(super) k_cache: Option<Tensor>,
    pub(super) v_cache: Option<Tensor>,
}

pub struct Model {
    pub(super) family: Family,
    /// The token embedding, when the output layer does not hold it (`Linear::row`).
    embed: Option<QTensor>,
    pub(super) layers: Vec<Layer>,
    pub(super) norm: Norm,
    pub(super) output: Linear,
    pub(super) n_embd: usize,
    pub(super) n_head: usize,
    pub(super) n_kv_head: usize,
    pub(super) head_dim: usize,
    pub(super) eps: f64,
    /// cos and sin per RoPE base, `n_ctx` rows of `head_dim / 2`.
    pub(super) ropes: Vec<(Tensor, Tensor)>,
}

/// An RMS norm's weights, as the tensor pass and the rows pass read them.
pub(super) struct Norm {
    pub(super) tensor: Tensor,
    pub(super) values: Vec<f32>,
}

impl Norm {
    fn new(t: Tensor) -> candle_core::Result<Norm> {
        let values = t.flatten_all()?.to_vec1::<f32>()?;
        Ok(Norm { tensor: t, values })
    }
}

impl Model {
    /// The model of `family` in `content` (the file `reader` reads), for contexts up
    /// to `n_ctx` positions.
    /// With `dense`, each layer's weights are also held dequantized, for batches.
    pub fn load<R: std::io::Read + std::io::Seek>(
        family: Family,
        gguf: &Gguf,
        content: &gguf_file::Content,
        reader: &mut R,
        (n_ctx, dense): (usize, bool),
    ) -> Result<Model, String> {
        let device = Device::Cpu;
        let arch = match family {
            Family::Llama => "llama",
            Family::Gemma3 => "gemma3",
        };
        let mut get = |name: &str| {
            content
                .tensor(reader, name, &device)
                .map_err(|e| format!("tensor {name}: {e}"))
        };
        let meta = |key: &str| {
            gguf.arch_u64(key)
                .ok_or_else(|| format!("metadata {arch}.{key} missing"))
        };
        let n_head = meta("attention.head_count")? as usize;
        let n_kv_head = gguf
            .arch_u64("attention.head_count_kv")
            .unwrap_or(n_head as u64) as usize;
        let n_embd = meta("embedding_length")? as usize;
        let n_layer = meta("block_count")? as usize;
        let head_dim = gguf
            .arch_u64("attention.key_length")
            .map_or(n_embd / n_head, |d| d as usize);
        let eps = gguf
            .get(&format!("{arch}.attention.layer_norm_rms_epsilon"))
            .and_then(|v| v.as_f64())
            .unwrap_or(1e-5);
        let base = gguf
            .get(&format!("{arch}.rope.freq_base"))
            .and_then(|v| v.as_f64())
            .unwrap_or(10_000.0) as f32;
        let scale = gguf
            .get(&format!("{arch}.rope.scaling.factor"))
            .and_then(|v| v.as_f64())
            .filter(|f| *f > 0.0)
            .unwrap_or(1.0) as f32;
        let window = gguf
            .arch_u64("attention.sliding_window")
            .map(|w| w as usize);

        let e = |e: candle_core::Error| e.to_string();
        let norm = |t: QTensor| t.dequantize(&device).and_then(Norm::new).map_err(e);
        let linear = |t: QTensor| Linear::new(t, false, &device).map_err(e);
        // Tied embeddings (SmolLM2, Gemma 3): the output layer is the embedding matrix,
        // and its rows are read from there when our kernels hold it.
        let tied = !content.tensor_infos.contains_key("output.weight");
        let output = linear(get(if tied {
            "token_embd.weight"
        } else {
            "output.weight"
        })?)?;
        let embed = match tied && output.row(0, &mut vec![0.0; n_embd]) {
            true => None,
            false => Some(get("token_embd.weight")?),
        };
        let norm = norm(get("output_norm.weight")?)?;
        let gemma = family == Family::Gemma3;
        let mut layers = Vec::with_capacity(n_layer);
        for i in 0..n_layer {
            let global = !gemma || i % GEMMA3_GLOBAL_EVERY == GEMMA3_GLOBAL_EVERY - 1;
            let mut t = |s: &str| get(&format!("blk.{i}.{s}.weight"));
            let local = (!global).then_some(window);
            layers.push(Layer::load(&mut t, (gemma, dense), local, &device)?);
        }
        let mut ropes = vec![rope_tables(head_dim, base, scale, n_ctx, &device).map_err(e)?];
        if gemma {
            ropes.push(rope_tables(head_dim, GEMMA3_LOCAL_BASE, 1.0, n_ctx, &device).map_err(e)?);
        }
        Ok(Model {
            family,
            embed,
            layers,
            norm,
            output,
            n_embd,
            n_head,
            n_kv_head,
            head_dim,
            eps,
            ropes,
        })
    }

    /// Evaluate `tokens` at positions `pos..`, attending to the first `pos` cached ones;
    /// returns the logits after each token from index `from` on (`from` below the
    /// length), one row per token, flattened.
    pub fn forward(
        &mut self,
        tokens: &[TokenId],
        pos: usize,
        from: usize,
    ) -> candle_core::Result<Vec<f32>> {
        let device = Device::Cpu;
        let seq = tokens.len();
        let gemma = self.family == Family::Gemma3;
        let mut x = Tensor::from_vec(self.embed(tokens)?, (1, seq, self.n_embd), &device)?;
        let ropes: Vec<(Tensor, Tensor)> = self
            .ropes
            .iter()
            .map(|(c, s)| Ok((c.narrow(0, pos, seq)?, s.narrow(0, pos, seq)?)))
            .collect::<candle_core::Result<_>>()?;
        let pass = Pass {
            ropes: &ropes,
            pos,
            seq,
            heads: (self.n_head, self.n_kv_head, self.head_dim),
            eps: self.eps as f32,
            gemma,
        };
        let mut masks: Vec<(Option<usize>, Option<Tensor>)> = Vec::new();
        for layer in &mut self.layers {
            let _span = tracing::trace_span!("layer").entered();
            let mask = if seq > 1 {
                let window = layer.window;
                match masks.iter().find(|(w, _)| *w == window) {
                    Some((_, m)) => m.clone(),
                    None => {
                        let m = Some(mask(seq, pos, window, &device)?);
                        masks.push((window, m.clone()));
                        m
                    }
                }
            } else {
                None
            };
            let h = candle_nn::ops::rms_norm(&x, &layer.attn_norm.tensor, pass.eps)?;
            let mut a = layer.attention(&h, &pass, mask.as_ref())?;
            if let Some(n) = &layer.post_attn_norm {
                a = candle_nn::ops::rms_norm(&a, &n.tensor, pass.eps)?;
            }
            x = (x + a)?;
            let f = layer.feed_forward(&x, &pass)?;
            x = (x + f)?;
        }
        let rows = x.narrow(1, from, seq - from)?;
        let rows = candle_nn::ops::rms_norm(&rows, &self.norm.tensor, pass.eps)?;
        self.output.forward(&rows)?.flatten_all()?.to_vec1::<f32>()
    }

    /// The embeddings of `tokens`, one after another (Gemma 3's scaled by √n_embd).
    pub(super) fn embed(&self, tokens: &[TokenId]) -> candle_core::Result<Vec<f32>> {
        let n = self.n_embd;
        let mut x = vec![0.0f32; tokens.len() * n];
        match &self.embed {
            None => {
                for (&t, row) in tokens.iter().zip(x.chunks_exact_mut(n)) {
                    self.output.row(t as usize, row);
                }
            }
            Some(embed) => {
                let ids = Tensor::new(tokens, &Device::Cpu)?;
                x = embed.embedding(&ids)?.flatten_all()?.to_vec1::<f32>()?;
            }
        }
        if self.family == Family::Gemma3 {
            let scale = (n as f32).sqrt();
            x.iter_mut().for_each(|v| *v *= scale);
        }
        Ok(x)
    }
}

impl Layer {
    /// A layer's weights, `t` giving each by its name within the layer ("attn_q").
    /// `local`: a sliding-window layer (Gemma 3's local ones) with its window, which
    /// uses the second RoPE table; otherwise a global layer with the first.
    fn load(
        t: &mut dyn FnMut(&str) -> Result<QTensor, String>,
        (gemma, dense): (bool, bool),
        local: Option<Option<usize>>,
        device: &Device,
    ) -> Result<Layer, String> {
        let e = |e: candle_core::Error| e.to_string();
        let norm = |t: QTensor| t.dequantize(device).and_then(Norm::new).map_err(e);
        let mut gemma_norm = |s: &str| -> Result<Option<Norm>, String> {
            if gemma {
                Ok(Some(norm(t(s)?)?))
            } else {
                Ok(None)
            }
        };
        let q_norm = gemma_norm("attn_q_norm")?;
        let k_norm = gemma_norm("attn_k_norm")?;
        let post_attn_norm = gemma_norm("post_attention_norm")?;
        let post_ffn_norm = gemma_norm("post_ffw_norm")?;
        let mut lin =
            |s: &str| -> Result<Linear, String> { Linear::new(t(s)?, dense, device).map_err(e) };
        let (wq, wk, wv, wo) = (
            lin("attn_q")?,
            lin("attn_k")?,
            lin("attn_v")?,
            lin("attn_output")?,
        );
        let (gate, up, down) = (lin("ffn_gate")?, lin("ffn_up")?, lin("ffn_down")?);
        Ok(Layer {
            attn_norm: norm(t("attn_norm")?)?,
            wq,
            wk,
            wv,
            wo,
            ffn_norm: norm(t("ffn_norm")?)?,
            gate,
            up,
            down,
            q_norm,
            k_norm,
            post_attn_norm,
            post_ffn_norm,
            window: local.flatten(),
            rope: usize::from(local.is_some()),
            k_cache: None,
            v_cache: None,
        })
    }
}

/// What every layer of one forward pass shares.
struct Pass<'a> {
    /// cos and sin per RoPE base, at the pass's positions.
    ropes: &'a [(Tensor, Tensor)],
    pos: usize,
    seq: usize,
    /// Query heads, key/value heads, head size.
    heads: (usize, usize, usize),
    eps: f32,
    gemma: bool,
}

impl Layer {
    /// Self-attention of the normed input `h` over the cached keys and this pass's,
    /// through the output projection.
    fn attention(
        &mut self,
        h: &Tensor,
        pass: &Pass,
        mask: Option<&Tensor>,
    ) -> candle_core::Result<Tensor> {
        let (nh, nkv, hd) = pass.heads;
        let (seq, pos, eps) = (pass.seq, pass.pos, pass.eps);
        let kv_len = pos + seq;
        let heads = |w: &Linear, n: usize| -> candle_core::Result<Tensor> {
            w.forward(h)?
                .reshape((1, seq, n, hd))?
                .transpose(1, 2)?
                .contiguous()
        };
        let (mut q, mut k, v) = (
            heads(&self.wq, nh)?,
            heads(&self.wk, nkv)?,
            heads(&self.wv, nkv)?,
        );
        if let (Some(qn), Some(kn)) = (&self.q_norm, &self.k_norm) {
            q = candle_nn::ops::rms_norm(&q, &qn.tensor, eps)?;
            k = candle_nn::ops::rms_norm(&k, &kn.tensor, eps)?;
        }
        let (cos, sin) = &pass.ropes[self.rope];
        let (q, k) = if pass.gemma {
            (
                candle_nn::rotary_emb::rope(&q, cos, sin)?,
                candle_nn::rotary_emb::rope(&k, cos, sin)?,
            )
        } else {
            (
                candle_nn::rotary_emb::rope_i(&q, cos, sin)?,
                candle_nn::rotary_emb::rope_i(&k, cos, sin)?,
            )
        };
        let (k_all, v_all) = self.append_kv(&k, &v, pos)?;
        // A single query on a sliding-window layer needs only the window's keys.
        let from = match self.window {
            Some(w) if seq == 1 => kv_len.saturating_sub(w),
            _ => 0,
        };
        let (k_all, v_all) = (
            k_all.narrow(2, from, kv_len - from)?,
            v_all.narrow(2, from, kv_len - from)?,
        );
        // Grouped-query attention: each KV head serves nh / nkv query heads.
        let rep = nh / nkv;
        let q = q.reshape((nkv, rep * seq, hd))?;
        let k_all = k_all.squeeze(0)?;
        let v_all = v_all.squeeze(0)?;
        let keys = kv_len - from;
        let att = (q.matmul(&k_all.t()?)? / (hd as f64).sqrt())?; // (nkv, rep*seq, keys)
        let att = match mask {
            Some(m) => att
                .reshape((nkv, rep, seq, keys))?
                .broadcast_add(m)?
                .reshape((nkv, rep * seq, keys))?,
            None => att,
        };
        let att = candle_nn::ops::softmax_last_dim(&att)?;
        let y = att.matmul(&v_all)?; // (nkv, rep*seq, hd)
        let y = y
            .reshape((1, nh, seq, hd))?
            .transpose(1, 2)?
            .reshape((1, seq, nh * hd))?;
        self.wo.forward(&y)
    }

    /// The feed-forward block on `x` (normed here), its own post-norm applied.
    fn feed_forward(&self, x: &Tensor, pass: &Pass) -> candle_core::Result<Tensor> {
        let h = candle_nn::ops::rms_norm(x, &self.ffn_norm.tensor, pass.eps)?;
        let g = self.gate.forward(&h)?;
        let g = if pass.gemma { g.gelu()? } else { g.silu()? };
        let u = self.up.forward(&h)?;
        let mut f = self.down.forward(&(g * u)?)?;
        if let Some(n) = &self.post_ffn_norm {
            f = candle_nn::ops::rms_norm(&f, &n.tensor, pass.eps)?;
        }
        Ok(f)
    }
}

/// The additive mask of `seq` queries at `pos..` over keys `0..pos + seq`: a query at
/// p sees keys j ≤ p, and within `window` only those with p − j < window.
fn mask(
    seq: usize,
    pos: usize,
    window: Option<usize>,
    device: &Device,
) -> candle_core::Result<Tensor> {
    let kv_len = pos + seq;
    let m: Vec<f32> = (0..seq)
        .flat_map(|i| {
            let p = pos + i;
            (0..kv_len).map(move |j| {
                let seen = j <= p && window.is_none_or(|w| p - j < w);
                if seen {
                    0.0
                } else {
                    f32::NEG_INFINITY
                }
            })
        })
        .collect();
    Tensor::from_vec(m, (seq, kv_len), device)
}

/// cos/sin of position × inverse frequency (divided by a linear scaling `scale`),
/// `n_ctx` rows of `head_dim / 2`.
fn rope_tables(
    head_dim: usize,
    base: f32,
    scale: f32,
    n_ctx: usize,
    device: &Device,
) -> candle_core::Result<(Tensor, Tensor)> {
    let inv: Vec<f32> = (0..head_dim)
        .step_by(2)
        .map(|i| 1.0 / base.powf(i as f32 / head_dim as f32) / scale)
        .collect();
    let inv = Tensor::new(inv.as_slice(), device)?.reshape((1, head_dim / 2))?;
    let pos = Tensor::arange(0u32, n_ctx as u32, device)?
        .to_dtype(DType::F32)?
        .reshape((n_ctx, 1))?;
    let angles = pos.matmul(&inv)?;
    Ok((angles.cos()?, angles.sin()?))
}

impl Layer {
    /// Room in both caches for `need` positions of `nkv` heads of `hd` values, the
    /// first `keep` kept.
    pub(super) fn reserve_kv(
        &mut self,
        (nkv, hd): (usize, usize),
        need: usize,
        keep: usize,
    ) -> candle_core::Result<()> {
        for cache in [&mut self.k_cache, &mut self.v_cache] {
            let cap = cache.as_ref().map_or(0, |c| c.dim(2).unwrap_or(0));
            if cap < need {
                let grown = need.div_ceil(KV_GROW) * KV_GROW;
                let fresh = Tensor::zeros((1, nkv, grown, hd), DType::F32, &Device::Cpu)?;
                if let Some(old) = cache.as_ref() {
                    fresh.slice_set(&old.narrow(2, 0, keep.min(cap))?.contiguous()?, 2, 0)?;
                }
                *cache = Some(fresh);
            }
        }
        Ok(())
    }

    /// Write k/v at `pos..` into the cache (growing it if needed) and return views of the
    /// first `pos + seq` positions.
    fn append_kv(
        &mut self,
        k: &Tensor,
        v: &Tensor,
        pos: usize,
    ) -> candle_core::Result<(Tensor, Tensor)> {
        let (_, nkv, seq, hd) = k.dims4()?;
        let need = pos + seq;
        self.reserve_kv((nkv, hd), need, pos)?;
        let cached = |c: &Option<Tensor>| c.clone().expect("reserve_kv allocates both caches");
        let (k_cache, v_cache) = (cached(&self.k_cache), cached(&self.v_cache));
        k_cache.slice_set(k, 2, pos)?;
        v_cache.slice_set(v, 2, pos)?;
        Ok((k_cache.narrow(2, 0, need)?, v_cache.narrow(2, 0, need)?))
    }
}
