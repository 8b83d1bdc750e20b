//! A pure-Rust runtime on candle: the llama architecture (SmolLM2) with quantized
//! weights read from GGUF, written here rather than taken from candle-transformers so the
//! KV cache can keep a prefix and drop the rest (as the llama.cpp backend does) and the
//! RoPE table is sized to the context actually used.
//!
//! Tokenization is `bpe` (from the file's metadata). Gemma 3 is not supported here:
//! candle-transformers' version is wrong for it (SiLU for GELU) and a correct one is
//! future work; load it with the llama.cpp backend.

use std::fs::File;
use std::io::BufReader;
use std::sync::{Arc, Once};

use candle_core::quantized::{gguf_file, QMatMul, QTensor};
use candle_core::{DType, Device, Module, Tensor};

use super::bpe::Bpe;
use super::vocab::Vocab;
use super::{Backend, BackendError, ChatTemplate, Gguf, LoadOptions, TokenId, Tokenize};

const NAME: &str = "candle";
/// Positions the KV cache grows by when full (amortises the copy).
const KV_GROW: usize = 256;

fn err(e: impl std::fmt::Display) -> BackendError {
    BackendError::Eval {
        backend: NAME,
        reason: e.to_string(),
    }
}

struct Layer {
    attn_norm: Tensor,
    wq: QMatMul,
    wk: QMatMul,
    wv: QMatMul,
    wo: QMatMul,
    ffn_norm: Tensor,
    gate: QMatMul,
    up: QMatMul,
    down: QMatMul,
    /// (1, n_kv_head, capacity, head_dim); the first `len` positions are valid.
    k_cache: Option<Tensor>,
    v_cache: Option<Tensor>,
}

struct Llama {
    embed: QTensor,
    layers: Vec<Layer>,
    norm: Tensor,
    output: QMatMul,
    n_head: usize,
    n_kv_head: usize,
    head_dim: usize,
    eps: f64,
    cos: Tensor,
    sin: Tensor,
}

pub struct Candle {
    model: Llama,
    bpe: Arc<Bpe>,
    vocab: Vocab,
    template: ChatTemplate,
    n_ctx: usize,
    n_past: usize,
    logits: Vec<f32>,
    device: Device,
}

impl Candle {
    pub fn load(gguf: &Gguf, opts: &LoadOptions) -> Result<Candle, BackendError> {
        let fail = |reason: String| BackendError::Load {
            backend: NAME,
            path: opts.path.clone(),
            reason,
        };
        let arch = gguf.architecture().unwrap_or("unknown");
        if arch != "llama" {
            return Err(BackendError::Architecture {
                backend: NAME,
                arch: arch.to_string(),
                supported: "llama (SmolLM2); use --backend llama for others",
            });
        }
        static THREADS: Once = Once::new();
        let threads = opts.threads.max(1);
        // candle's CPU kernels run on rayon's global pool, which can be sized only once.
        THREADS.call_once(|| {
            let _ = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build_global();
        });
        let vocab = Vocab::from_gguf(gguf).map_err(fail)?;
        let bpe = Arc::new(Bpe::from_gguf(gguf, &vocab).map_err(fail)?);
        let template = ChatTemplate::for_model(gguf, opts.family.as_deref())?;

        let device = Device::Cpu;
        let mut reader = BufReader::new(File::open(&opts.path).map_err(|e| fail(e.to_string()))?);
        let content = gguf_file::Content::read(&mut reader).map_err(|e| fail(e.to_string()))?;
        let get = |name: &str, r: &mut BufReader<File>| {
            content
                .tensor(r, name, &device)
                .map_err(|e| fail(format!("tensor {name}: {e}")))
        };
        let meta = |key: &str| {
            gguf.arch_u64(key)
                .ok_or_else(|| fail(format!("metadata llama.{key} missing")))
        };
        let n_head = meta("attention.head_count")? as usize;
        let n_kv_head = gguf
            .arch_u64("attention.head_count_kv")
            .unwrap_or(n_head as u64) as usize;
        let n_embd = meta("embedding_length")? as usize;
        let n_layer = meta("block_count")? as usize;
        let head_dim = n_embd / n_head;
        let eps = gguf
            .get("llama.attention.layer_norm_rms_epsilon")
            .and_then(|v| v.as_f64())
            .unwrap_or(1e-5);
        let freq_base = gguf
            .get("llama.rope.freq_base")
            .and_then(|v| v.as_f64())
            .unwrap_or(10_000.0) as f32;
        let train_ctx = gguf.context_length().unwrap_or(2048) as usize;
        let n_ctx = opts.max_context.min(train_ctx).max(16);

        let dequant = |t: QTensor| t.dequantize(&device).map_err(|e| fail(e.to_string()));
        let qmm = |t: QTensor| QMatMul::from_qtensor(t).map_err(|e| fail(e.to_string()));
        let embed = get("token_embd.weight", &mut reader)?;
        let output = match content.tensor(&mut reader, "output.weight", &device) {
            Ok(t) => qmm(t)?,
            // Tied embeddings (SmolLM2): the output layer is the embedding matrix.
            Err(_) => qmm(get("token_embd.weight", &mut reader)?)?,
        };
        let norm = dequant(get("output_norm.weight", &mut reader)?)?;
        let mut layers = Vec::with_capacity(n_layer);
        for i in 0..n_layer {
            let mut t = |s: &str| get(&format!("blk.{i}.{s}.weight"), &mut reader);
            layers.push(Layer {
                attn_norm: dequant(t("attn_norm")?)?,
                wq: qmm(t("attn_q")?)?,
                wk: qmm(t("attn_k")?)?,
                wv: qmm(t("attn_v")?)?,
                wo: qmm(t("attn_output")?)?,
                ffn_norm: dequant(t("ffn_norm")?)?,
                gate: qmm(t("ffn_gate")?)?,
                up: qmm(t("ffn_up")?)?,
                down: qmm(t("ffn_down")?)?,
                k_cache: None,
                v_cache: None,
            });
        }
        let (cos, sin) = rope_tables(head_dim, freq_base, n_ctx, &device).map_err(err)?;
        Ok(Candle {
            model: Llama {
                embed,
                layers,
                norm,
                output,
                n_head,
                n_kv_head,
                head_dim,
                eps,
                cos,
                sin,
            },
            bpe,
            logits: vec![0.0; vocab.len()],
            vocab,
            template,
            n_ctx,
            n_past: 0,
            device,
        })
    }
}

/// cos/sin of position × inverse frequency, `n_ctx` rows of `head_dim / 2`.
fn rope_tables(
    head_dim: usize,
    base: f32,
    n_ctx: usize,
    device: &Device,
) -> candle_core::Result<(Tensor, Tensor)> {
    let inv: Vec<f32> = (0..head_dim)
        .step_by(2)
        .map(|i| 1.0 / base.powf(i as f32 / head_dim as f32))
        .collect();
    let inv = Tensor::new(inv.as_slice(), device)?.reshape((1, head_dim / 2))?;
    let pos = Tensor::arange(0u32, n_ctx as u32, device)?
        .to_dtype(DType::F32)?
        .reshape((n_ctx, 1))?;
    let angles = pos.matmul(&inv)?;
    Ok((angles.cos()?, angles.sin()?))
}

impl Llama {
    /// Evaluate `tokens` at positions `pos..`, attending to the first `pos` cached ones;
    /// returns the logits of the last token.
    fn forward(&mut self, tokens: &[TokenId], pos: usize) -> candle_core::Result<Tensor> {
        let device = self.embed.device();
        let seq = tokens.len();
        let ids = Tensor::new(tokens, &device)?;
        let mut x = self.embed.embedding(&ids)?.unsqueeze(0)?; // (1, seq, n_embd)
        let cos = self.cos.narrow(0, pos, seq)?;
        let sin = self.sin.narrow(0, pos, seq)?;
        let kv_len = pos + seq;
        let mask = if seq > 1 {
            // Query i (at pos + i) sees keys 0..=pos + i.
            let m: Vec<f32> = (0..seq)
                .flat_map(|i| {
                    (0..kv_len).map(move |j| if j > pos + i { f32::NEG_INFINITY } else { 0.0 })
                })
                .collect();
            Some(Tensor::from_vec(m, (seq, kv_len), &device)?)
        } else {
            None
        };
        let (nh, nkv, hd) = (self.n_head, self.n_kv_head, self.head_dim);
        for layer in &mut self.layers {
            let _span = tracing::trace_span!("layer").entered();
            let h = candle_nn::ops::rms_norm(&x, &layer.attn_norm, self.eps as f32)?;
            let q = layer
                .wq
                .forward(&h)?
                .reshape((1, seq, nh, hd))?
                .transpose(1, 2)?;
            let k = layer
                .wk
                .forward(&h)?
                .reshape((1, seq, nkv, hd))?
                .transpose(1, 2)?;
            let v = layer
                .wv
                .forward(&h)?
                .reshape((1, seq, nkv, hd))?
                .transpose(1, 2)?;
            let q = candle_nn::rotary_emb::rope_i(&q.contiguous()?, &cos, &sin)?;
            let k = candle_nn::rotary_emb::rope_i(&k.contiguous()?, &cos, &sin)?;
            let v = v.contiguous()?;
            let (k_all, v_all) = layer.append_kv(&k, &v, pos)?;
            // Grouped-query attention: each KV head serves nh / nkv query heads.
            let rep = nh / nkv;
            let q = q.reshape((nkv, rep * seq, hd))?;
            // Views into the cache (rows contiguous, heads `capacity` apart): no copy.
            let k_all = k_all.squeeze(0)?;
            let v_all = v_all.squeeze(0)?;
            let att = (q.matmul(&k_all.t()?)? / (hd as f64).sqrt())?; // (nkv, rep*seq, kv)
            let att = match &mask {
                Some(m) => att
                    .reshape((nkv, rep, seq, kv_len))?
                    .broadcast_add(m)?
                    .reshape((nkv, rep * seq, kv_len))?,
                None => att,
            };
            let att = candle_nn::ops::softmax_last_dim(&att)?;
            let y = att.matmul(&v_all)?; // (nkv, rep*seq, hd)
            let y = y
                .reshape((1, nh, seq, hd))?
                .transpose(1, 2)?
                .reshape((1, seq, nh * hd))?;
            x = (x + layer.wo.forward(&y)?)?;
            let h = candle_nn::ops::rms_norm(&x, &layer.ffn_norm, self.eps as f32)?;
            let g = layer.gate.forward(&h)?.silu()?;
            let u = layer.up.forward(&h)?;
            x = (x + layer.down.forward(&(g * u)?)?)?;
        }
        let last = x.narrow(1, seq - 1, 1)?;
        let last = candle_nn::ops::rms_norm(&last, &self.norm, self.eps as f32)?;
        self.output.forward(&last)?.flatten_all()
    }
}

impl Layer {
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
        for (cache, new) in [(&mut self.k_cache, k), (&mut self.v_cache, v)] {
            let cap = cache.as_ref().map_or(0, |c| c.dim(2).unwrap_or(0));
            if cap < need {
                let grown = need.div_ceil(KV_GROW) * KV_GROW;
                let fresh = Tensor::zeros((1, nkv, grown, hd), DType::F32, k.device())?;
                if let Some(old) = cache.as_ref() {
                    fresh.slice_set(&old.narrow(2, 0, pos.min(cap))?.contiguous()?, 2, 0)?;
                }
                *cache = Some(fresh);
            }
            // Unwrap: set just above when missing.
            cache
                .as_ref()
                .expect("cache allocated")
                .slice_set(new, 2, pos)?;
        }
        let k_all = self
            .k_cache
            .as_ref()
            .expect("cache allocated")
            .narrow(2, 0, need)?;
        let v_all = self
            .v_cache
            .as_ref()
            .expect("cache allocated")
            .narrow(2, 0, need)?;
        Ok((k_all, v_all))
    }
}

impl Backend for Candle {
    fn name(&self) -> &'static str {
        NAME
    }

    fn vocab(&self) -> &Vocab {
        &self.vocab
    }

    fn chat_template(&self) -> &ChatTemplate {
        &self.template
    }

    fn context_len(&self) -> usize {
        self.n_ctx
    }

    fn tokenize(&self, text: &str, special: bool) -> Result<Vec<TokenId>, BackendError> {
        Ok(self.bpe.encode(text, special))
    }

    fn tokenizer(&self) -> Arc<dyn Tokenize> {
        self.bpe.clone()
    }

    fn forward(&mut self, keep: usize, tokens: &[TokenId]) -> Result<&mut [f32], BackendError> {
        let _span = tracing::trace_span!("forward", n = tokens.len()).entered();
        if tokens.is_empty() {
            return Err(err("forward called with no tokens"));
        }
        let keep = keep.min(self.n_past);
        let needed = keep + tokens.len();
        if needed > self.n_ctx {
            return Err(BackendError::ContextFull {
                needed,
                limit: self.n_ctx,
            });
        }
        if let Some(&bad) = tokens.iter().find(|&&t| t as usize >= self.vocab.len()) {
            return Err(BackendError::BadToken(bad));
        }
        // Dropping the tail of the cache is just forgetting it: positions past `keep`
        // are overwritten by the next append.
        self.n_past = keep;
        let mut last = None;
        for chunk in tokens.chunks(512) {
            last = Some(self.model.forward(chunk, self.n_past).map_err(err)?);
            self.n_past += chunk.len();
        }
        let logits = last
            .expect("tokens is not empty")
            .to_device(&self.device)
            .and_then(|t| t.to_vec1::<f32>())
            .map_err(err)?;
        self.logits.copy_from_slice(&logits[..self.vocab.len()]);
        Ok(&mut self.logits)
    }
}
