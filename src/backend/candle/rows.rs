//! A few tokens at a time: the pass the agent's generation makes (the token just chosen,
//! the tokens the grammar forces after it, a drafted guess), row by row in plain
//! buffers, with the weights as the file holds them (`Linear::rows`: each weight read
//! once for the whole batch).
//!
//! Every row is computed exactly as if its token were evaluated alone after the ones
//! before it: the same kernels, each sum in the same order, a row attending to the keys
//! at or before its own position only. So the rows of a batch equal one-token steps bit
//! for bit, and a turn whose drafted guess is checked in one batch writes exactly what
//! it writes one token at a time (`decode::draft`). Prompts (`ROWS_UNTIL` tokens or
//! more) take the tensor pass (`model`), whose attention runs as matrix products.

use candle_core::{CpuStorage, InplaceOp1, Layout, Storage};

use super::super::TokenId;
use super::model::{Family, Layer, Model};

/// Batches shorter than this take the rows pass.
pub(crate) const ROWS_UNTIL: usize = 16;

/// The shape of a pass's attention: query heads, key/value heads, head size.
#[derive(Clone, Copy)]
struct Heads {
    nh: usize,
    nkv: usize,
    hd: usize,
}

/// Where a pass's rows sit: the first one's position and how many there are.
#[derive(Clone, Copy)]
struct Span {
    pos: usize,
    seq: usize,
}

impl Model {
    /// `tokens` at positions `pos..`, attending to the `pos` cached before them; the
    /// logits after each token from index `from` on, one row after another.
    pub(super) fn forward_rows(
        &mut self,
        tokens: &[TokenId],
        pos: usize,
        from: usize,
    ) -> candle_core::Result<Vec<f32>> {
        let span = Span {
            pos,
            seq: tokens.len(),
        };
        let heads = Heads {
            nh: self.n_head,
            nkv: self.n_kv_head,
            hd: self.head_dim,
        };
        let (n, eps, seq) = (self.n_embd, self.eps as f32, span.seq);
        let gemma = self.family == Family::Gemma3;
        // cos and sin at the rows' positions, per RoPE table.
        let angles = self
            .ropes
            .iter()
            .map(|(c, s)| {
                let at = |t: &candle_core::Tensor| t.narrow(0, pos, seq)?.flatten_all()?.to_vec1();
                Ok((at(c)?, at(s)?))
            })
            .collect::<candle_core::Result<Vec<(Vec<f32>, Vec<f32>)>>>()?;
        let mut x = self.embed(tokens)?;
        let ffn = self.layers.first().map_or(0, |l| l.gate.out_dim());
        let mut h = vec![0.0; seq * n];
        let mut o = vec![0.0; seq * n];
        let mut q = vec![0.0; seq * heads.nh * heads.hd];
        let mut att = vec![0.0; seq * heads.nh * heads.hd];
        let mut k = vec![0.0; seq * heads.nkv * heads.hd];
        let mut v = vec![0.0; seq * heads.nkv * heads.hd];
        let (mut g, mut u) = (vec![0.0; seq * ffn], vec![0.0; seq * ffn]);
        for layer in &mut self.layers {
            let _span = tracing::trace_span!("layer").entered();
            rms_norm(&x, &layer.attn_norm.values, eps, &mut h);
            layer.wq.rows(&h, seq, &mut q)?;
            layer.wk.rows(&h, seq, &mut k)?;
            layer.wv.rows(&h, seq, &mut v)?;
            if let (Some(qn), Some(kn)) = (&layer.q_norm, &layer.k_norm) {
                rms_norm_in_place(&mut q, &qn.values, eps);
                rms_norm_in_place(&mut k, &kn.values, eps);
            }
            let (cos, sin) = &angles[layer.rope];
            rope(&mut q, heads.hd, cos, sin, gemma);
            rope(&mut k, heads.hd, cos, sin, gemma);
            store_kv(layer, &k, &v, heads, span)?;
            attend(layer, &q, heads, span, &mut att)?;
            layer.wo.rows(&att, seq, &mut o)?;
            if let Some(norm) = &layer.post_attn_norm {
                rms_norm_in_place(&mut o, &norm.values, eps);
            }
            x.iter_mut().zip(&o).for_each(|(x, o)| *x += o);
            rms_norm(&x, &layer.ffn_norm.values, eps, &mut h);
            layer.gate.rows(&h, seq, &mut g)?;
            layer.up.rows(&h, seq, &mut u)?;
            for (g, u) in g.iter_mut().zip(&u) {
                *g = if gemma { gelu(*g) } else { silu(*g) } * u;
            }
            layer.down.rows(&g, seq, &mut o)?;
            if let Some(norm) = &layer.post_ffn_norm {
                rms_norm_in_place(&mut o, &norm.values, eps);
            }
            x.iter_mut().zip(&o).for_each(|(x, o)| *x += o);
        }
        let wanted = seq - from;
        let mut last = vec![0.0; wanted * n];
        rms_norm(&x[from * n..], &self.norm.values, eps, &mut last);
        let mut logits = vec![0.0; wanted * self.output.out_dim()];
        self.output.rows(&last, wanted, &mut logits)?;
        Ok(logits)
    }
}

/// Write the rows' keys and values (`seq` × `nkv` × `hd` each) into the layer's caches
/// at their positions, the caches grown if need be.
fn store_kv(
    layer: &mut Layer,
    k: &[f32],
    v: &[f32],
    heads: Heads,
    span: Span,
) -> candle_core::Result<()> {
    layer.reserve_kv((heads.nkv, heads.hd), span.pos + span.seq, span.pos)?;
    for (cache, values) in [(&layer.k_cache, k), (&layer.v_cache, v)] {
        let cache = cache.as_ref().expect("reserve_kv allocates both caches");
        cache.inplace_op1(&Store {
            values,
            heads,
            span,
        })?;
    }
    Ok(())
}

/// Rows of keys or values written into a cache of (1, nkv, capacity, hd).
struct Store<'a> {
    values: &'a [f32],
    heads: Heads,
    span: Span,
}

impl InplaceOp1 for Store<'_> {
    fn name(&self) -> &'static str {
        "kv-store"
    }

    fn cpu_fwd(&self, storage: &mut CpuStorage, layout: &Layout) -> candle_core::Result<()> {
        let CpuStorage::F32(data) = storage else {
            candle_core::bail!("the KV cache is not f32")
        };
        let (Heads { nkv, hd, .. }, Span { pos, seq }) = (self.heads, self.span);
        let cap = layout.dims()[2];
        if !layout.is_contiguous() || cap < pos + seq {
            candle_core::bail!("the KV cache has not the room or the layout to write");
        }
        let base = layout.start_offset();
        for (s, row) in self.values.chunks_exact(nkv * hd).enumerate() {
            for (g, head) in row.chunks_exact(hd).enumerate() {
                let at = base + (g * cap + pos + s) * hd;
                data[at..at + hd].copy_from_slice(head);
            }
        }
        Ok(())
    }
}

/// Each row's attention (`q`: `seq` × `nh` × `hd`) over the cached keys at or before
/// its position (within the layer's window), into `out` (the same shape); the rows and
/// heads shared out on candle's thread pool.
fn attend(
    layer: &Layer,
    q: &[f32],
    heads: Heads,
    span: Span,
    out: &mut [f32],
) -> candle_core::Result<()> {
    let cached = |c: &Option<candle_core::Tensor>| c.clone().expect("store_kv ran first");
    let (k_cache, v_cache) = (cached(&layer.k_cache), cached(&layer.v_cache));
    let (k_store, k_layout) = k_cache.storage_and_layout();
    let (v_store, v_layout) = v_cache.storage_and_layout();
    let (Storage::Cpu(CpuStorage::F32(keys)), Storage::Cpu(CpuStorage::F32(values))) =
        (&*k_store, &*v_store)
    else {
        candle_core::bail!("the KV cache is not f32 on the CPU")
    };
    let (keys, values) = (
        &keys[k_layout.start_offset()..],
        &values[v_layout.start_offset()..],
    );
    let Heads { nh, nkv, hd } = heads;
    let cap = k_layout.dims()[2];
    let (rep, window) = (nh / nkv, layer.window);
    let scale = 1.0 / (hd as f32).sqrt();
    let dst = Dst(out.as_mut_ptr());
    candle_core::utils::barrier_pool().execute_chunked(span.seq * nh, |items| {
        let dst = &dst;
        let mut scores = Vec::new();
        let mut acc = vec![0.0f32; hd];
        for item in items {
            let (s, head) = (item / nh, item % nh);
            let p = span.pos + s;
            let first = window.map_or(0, |w| (p + 1).saturating_sub(w));
            let g = head / rep;
            let query = &q[item * hd..(item + 1) * hd];
            let key = |j: usize| &keys[(g * cap + j) * hd..(g * cap + j + 1) * hd];
            scores.clear();
            scores.extend((first..=p).map(|j| dot(query, key(j)) * scale));
            let max = scores.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
            let mut sum = 0.0f32;
            for v in scores.iter_mut() {
                *v = (*v - max).exp();
                sum += *v;
            }
            acc.iter_mut().for_each(|a| *a = 0.0);
            for (j, &w) in (first..=p).zip(scores.iter()) {
                let value = &values[(g * cap + j) * hd..(g * cap + j + 1) * hd];
                let w = w / sum;
                acc.iter_mut().zip(value).for_each(|(a, v)| *a += w * v);
            }
            // SAFETY: `item < seq * nh`, so the head's `hd` values lie inside `out`
            // (seq × nh × hd), and each item is written by the one task it went to.
            unsafe { std::ptr::copy_nonoverlapping(acc.as_ptr(), dst.0.add(item * hd), hd) };
        }
    });
    Ok(())
}

/// `out`'s start, written at disjoint heads by the pool's tasks.
struct Dst(*mut f32);
// SAFETY: tasks write disjoint ranges, and `attend` waits for all of them.
unsafe impl Sync for Dst {}

/// A dot product summed in eight lanes, then the lanes in a fixed order (the compiler
/// turns the lanes into one vector register).
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0.0f32; 8];
    let (a8, b8) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = a8
        .remainder()
        .iter()
        .zip(b8.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in a8.zip(b8) {
        for l in 0..8 {
            lanes[l] += x[l] * y[l];
        }
    }
    ((lanes[0] + lanes[4]) + (lanes[1] + lanes[5]))
        + ((lanes[2] + lanes[6]) + (lanes[3] + lanes[7]))
        + tail
}

/// Each row of `x` (rows of `w.len()` values) RMS-normed and scaled by `w`, into `out`.
fn rms_norm(x: &[f32], w: &[f32], eps: f32, out: &mut [f32]) {
    for (row, o) in x.chunks_exact(w.len()).zip(out.chunks_exact_mut(w.len())) {
        let inv = 1.0 / (dot(row, row) / w.len() as f32 + eps).sqrt();
        for ((o, x), w) in o.iter_mut().zip(row).zip(w) {
            *o = x * inv * w;
        }
    }
}

/// `rms_norm` of each `w.len()` values of `x` (a row, or one head of one), in place.
fn rms_norm_in_place(x: &mut [f32], w: &[f32], eps: f32) {
    for row in x.chunks_exact_mut(w.len()) {
        let inv = 1.0 / (dot(row, row) / w.len() as f32 + eps).sqrt();
        for (x, w) in row.iter_mut().zip(w) {
            *x = *x * inv * w;
        }
    }
}

/// RoPE on each head of `hd` values of the rows in `x`, row s at the angles of row s
/// of `cos` and `sin` (`hd / 2` each): llama's rotates adjacent pairs, Gemma 3's (NeoX)
/// the two halves of a head.
fn rope(x: &mut [f32], hd: usize, cos: &[f32], sin: &[f32], halves: bool) {
    let half = hd / 2;
    let per_row = x.len() / (cos.len() / half);
    for (s, row) in x.chunks_exact_mut(per_row).enumerate() {
        let (c, sn) = (
            &cos[s * half..(s + 1) * half],
            &sin[s * half..(s + 1) * half],
        );
        for head in row.chunks_exact_mut(hd) {
            for i in 0..half {
                let (a, b) = if halves {
                    (i, i + half)
                } else {
                    (2 * i, 2 * i + 1)
                };
                let (x0, x1) = (head[a], head[b]);
                head[a] = x0 * c[i] - x1 * sn[i];
                head[b] = x0 * sn[i] + x1 * c[i];
            }
        }
    }
}

fn silu(x: f32) -> f32 {
    x / (1.0 + (-x).exp())
}

/// GELU in its tanh form, as Gemma uses it.
fn gelu(x: f32) -> f32 {
    const SQRT_2_OVER_PI: f32 = 0.797_884_6;
    0.5 * x * (1.0 + (SQRT_2_OVER_PI * (x + 0.044_715 * x * x * x)).tanh())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dot_product_sums_every_value_and_a_norm_scales_to_unit_rms() {
        let a: Vec<f32> = (0..19).map(|i| i as f32).collect();
        assert_eq!(dot(&a, &a), (0..19).map(|i| (i * i) as f32).sum::<f32>());
        let mut out = vec![0.0; 19];
        rms_norm(&a, &[2.0; 19], 0.0, &mut out);
        let rms = (dot(&out, &out) / 19.0).sqrt();
        assert!((rms - 2.0).abs() < 1e-5, "{rms}");
    }

    #[test]
    fn rope_turns_pairs_or_halves_by_the_angle() {
        let (cos, sin) = ([0.0f32, 1.0], [1.0f32, 0.0]);
        // Pairs: the first pair turned a quarter, the second not at all.
        let mut x = vec![1.0, 0.0, 3.0, 4.0];
        rope(&mut x, 4, &cos, &sin, false);
        assert_eq!(x, [0.0, 1.0, 3.0, 4.0]);
        // Halves: (x0, x2) turned a quarter, (x1, x3) not.
        let mut x = vec![1.0, 3.0, 0.0, 4.0];
        rope(&mut x, 4, &cos, &sin, true);
        assert_eq!(x, [0.0, 3.0, 1.0, 4.0]);
    }

    #[test]
    fn activations_match_their_definitions() {
        assert!((silu(1.0) - 0.731_058_6).abs() < 1e-6);
        assert!((gelu(1.0) - 0.841_192).abs() < 1e-5);
        assert_eq!(silu(0.0), 0.0);
    }
}
