//! One token's matrix-vector product for Q4_1 weights (SmolLM2's format), which candle
//! 0.11.1 computes with a scalar dot product (more than half of a generated token's
//! time on the default model). Here: the vector quantized to Q8_1 blocks as llama.cpp
//! does, then per weight row an AVX2 dot product of 4-bit and 8-bit blocks (a scalar one
//! where AVX2 is missing), the rows shared out on candle's own thread pool (a second
//! pool would spin against it for the same cores).
//!
//! Block layouts are GGML's: Q4_1 is 32 weights as an f16 scale `d`, an f16 minimum `m`
//! and 16 bytes of nibbles (weight j in the low half of byte j, weight j + 16 in the high
//! half): w = d·q + m. Q8_1 is 32 values as a scale, the scale times the sum of the
//! quantized values, and 32 signed bytes.

/// Weights per block.
const QK: usize = 32;
/// Bytes per Q4_1 block.
const Q4_1_BYTES: usize = 20;

/// A Q4_1 matrix of `rows` × `cols`, as the file holds it.
pub(crate) struct Q41 {
    data: Vec<u8>,
    rows: usize,
    cols: usize,
    /// Whether this CPU runs `dot_avx2`.
    simd: bool,
}

struct Q81 {
    d: f32,
    /// `d` times the sum of `qs`.
    s: f32,
    qs: [i8; QK],
}

impl Q41 {
    /// `data` as GGML lays out a (rows, cols) Q4_1 tensor; None when its size is not that.
    pub fn new(data: Vec<u8>, rows: usize, cols: usize) -> Option<Q41> {
        (cols % QK == 0 && data.len() == rows * cols / QK * Q4_1_BYTES).then_some(Q41 {
            data,
            rows,
            cols,
            simd: simd_available(),
        })
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    /// W·x, with `x` of `cols` values.
    pub(crate) fn matvec(&self, x: &[f32]) -> Vec<f32> {
        debug_assert_eq!(x.len(), self.cols);
        let xq: Vec<Q81> = x.chunks_exact(QK).map(quantize).collect();
        let row_bytes = self.cols / QK * Q4_1_BYTES;
        let mut out = vec![0.0f32; self.rows];
        let simd = self.simd;
        let dst = Rows(out.as_mut_ptr());
        candle_core::utils::barrier_pool().execute_chunked(self.rows, |range| {
            let dst = &dst;
            for r in range {
                let row = &self.data[r * row_bytes..(r + 1) * row_bytes];
                let v = if simd {
                    // SAFETY: the CPU has AVX2, FMA and F16C (checked at `new`).
                    unsafe { dot_avx2(row, &xq) }
                } else {
                    dot_scalar(row, &xq)
                };
                // SAFETY: `r < rows`, the length of `out`, and each row is written by
                // the one task its range went to.
                unsafe { *dst.0.add(r) = v };
            }
        });
        out
    }
}

/// `out`'s start, written at disjoint rows by the pool's tasks.
struct Rows(*mut f32);
// SAFETY: tasks write disjoint indices, and `matvec` waits for all of them.
unsafe impl Sync for Rows {}

/// llama.cpp's `quantize_row_q8_1` for one block.
fn quantize(x: &[f32]) -> Q81 {
    let amax = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let d = amax / 127.0;
    let id = if d != 0.0 { 1.0 / d } else { 0.0 };
    let mut qs = [0i8; QK];
    let mut sum = 0i32;
    for (q, v) in qs.iter_mut().zip(x) {
        *q = (v * id).round() as i8;
        sum += i32::from(*q);
    }
    Q81 {
        d,
        s: d * sum as f32,
        qs,
    }
}

fn simd_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        is_x86_feature_detected!("avx2")
            && is_x86_feature_detected!("fma")
            && is_x86_feature_detected!("f16c")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

fn dot_scalar(row: &[u8], xq: &[Q81]) -> f32 {
    let mut sum = 0.0f32;
    for (b, y) in row.chunks_exact(Q4_1_BYTES).zip(xq) {
        let d = f16_to_f32(u16::from_le_bytes([b[0], b[1]]));
        let m = f16_to_f32(u16::from_le_bytes([b[2], b[3]]));
        let mut sumi = 0i32;
        for j in 0..QK / 2 {
            let q = b[4 + j];
            sumi += i32::from(q & 0x0F) * i32::from(y.qs[j]);
            sumi += i32::from(q >> 4) * i32::from(y.qs[j + QK / 2]);
        }
        sum += d * y.d * sumi as f32 + m * y.s;
    }
    sum
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn dot_avx2(row: &[u8], xq: &[Q81]) -> f32 {
    use std::arch::x86_64::*;
    let low = _mm256_set1_epi8(0x0F);
    let ones = _mm256_set1_epi16(1);
    let mut acc = _mm256_setzero_ps();
    let mut mins = 0.0f32;
    for (b, y) in row.chunks_exact(Q4_1_BYTES).zip(xq) {
        // d and m: two f16 at the block's start.
        let dm = _mm_cvtph_ps(_mm_cvtsi32_si128(i32::from_le_bytes([
            b[0], b[1], b[2], b[3],
        ])));
        let d = _mm_cvtss_f32(dm);
        let m = _mm_cvtss_f32(_mm_shuffle_ps(dm, dm, 1));
        // 16 bytes of nibbles → 32 bytes: weights 0..15 (low halves), 16..31 (high).
        let packed = _mm_loadu_si128(b.as_ptr().add(4) as *const __m128i);
        let both = _mm256_set_m128i(_mm_srli_epi16(packed, 4), packed);
        let qx = _mm256_and_si256(both, low);
        let qy = _mm256_loadu_si256(y.qs.as_ptr() as *const __m256i);
        // u8 × i8 pairs summed to i16, then pairs of those to i32.
        let prod = _mm256_madd_epi16(_mm256_maddubs_epi16(qx, qy), ones);
        let scale = _mm256_set1_ps(d * y.d);
        acc = _mm256_fmadd_ps(_mm256_cvtepi32_ps(prod), scale, acc);
        mins += m * y.s;
    }
    let hi = _mm256_extractf128_ps(acc, 1);
    let s = _mm_add_ps(_mm256_castps256_ps128(acc), hi);
    let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
    let s = _mm_add_ss(s, _mm_shuffle_ps(s, s, 1));
    _mm_cvtss_f32(s) + mins
}

#[cfg(not(target_arch = "x86_64"))]
unsafe fn dot_avx2(row: &[u8], xq: &[Q81]) -> f32 {
    dot_scalar(row, xq)
}

/// IEEE half to single precision.
fn f16_to_f32(h: u16) -> f32 {
    let sign = u32::from(h >> 15) << 31;
    let exp = u32::from((h >> 10) & 0x1F);
    let frac = u32::from(h & 0x3FF);
    let bits = match (exp, frac) {
        (0, 0) => sign,
        (0, f) => {
            // Subnormal: normalise.
            let shift = f.leading_zeros() - 21;
            sign | ((127 - 15 + 1 - shift) << 23) | ((f << shift) & 0x3FF) << 13
        }
        (0x1F, f) => sign | 0x7F80_0000 | (f << 13),
        (e, f) => sign | ((e + 127 - 15) << 23) | (f << 13),
    };
    f32::from_bits(bits)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f32_to_f16(v: f32) -> u16 {
        // Exact for the values used here (small integers and halves).
        let bits = v.to_bits();
        let sign = ((bits >> 31) as u16) << 15;
        if v == 0.0 {
            return sign;
        }
        let exp = ((bits >> 23) & 0xFF) as i32 - 127 + 15;
        let frac = ((bits >> 13) & 0x3FF) as u16;
        sign | ((exp as u16) << 10) | frac
    }

    /// A Q4_1 matrix from weights that are exactly d·q + m, and its product.
    #[test]
    fn simd_and_scalar_products_equal_the_float_one() {
        let (rows, cols) = (70, 64);
        let mut data = Vec::new();
        let mut dense = Vec::new();
        for r in 0..rows {
            for blk in 0..cols / QK {
                let (d, m) = (0.5 * (1 + (r + blk) % 3) as f32, -2.0 + (r % 5) as f32);
                data.extend_from_slice(&f32_to_f16(d).to_le_bytes());
                data.extend_from_slice(&f32_to_f16(m).to_le_bytes());
                let q: Vec<u8> = (0..QK)
                    .map(|j| ((r * 7 + j * 3 + blk) % 16) as u8)
                    .collect();
                for j in 0..QK / 2 {
                    data.push(q[j] | (q[j + QK / 2] << 4));
                }
                dense.extend(q.iter().map(|&q| d * f32::from(q) + m));
            }
        }
        let w = Q41::new(data, rows, cols).unwrap();
        let x: Vec<f32> = (0..cols).map(|i| ((i * 13) % 17) as f32 - 8.0).collect();
        let want: Vec<f32> = (0..rows)
            .map(|r| (0..cols).map(|c| dense[r * cols + c] * x[c]).sum())
            .collect();
        let got = w.matvec(&x);
        let xq: Vec<Q81> = x.chunks_exact(QK).map(quantize).collect();
        let row_bytes = cols / QK * Q4_1_BYTES;
        for r in 0..rows {
            let scalar = dot_scalar(&w.data[r * row_bytes..(r + 1) * row_bytes], &xq);
            // x's quantization to 8 bits is the only rounding: at most half a step
            // (its largest magnitude / 127) per value, times the weight.
            let step = 8.0 / 127.0;
            let tol = (0..cols)
                .map(|c| dense[r * cols + c].abs() * step / 2.0)
                .sum::<f32>()
                + 1e-3;
            assert!(
                (got[r] - want[r]).abs() < tol,
                "row {r}: {} vs {}",
                got[r],
                want[r]
            );
            assert!(
                (got[r] - scalar).abs() < 1e-3 * scalar.abs().max(1.0),
                "row {r}"
            );
        }
        assert_eq!(Q41::new(vec![0; 19], 1, 32).map(|w| w.rows()), None);
    }

    #[test]
    fn halves_convert() {
        for v in [0.0f32, 1.0, -2.5, 0.000061035156, 65504.0, 0.5] {
            assert_eq!(f16_to_f32(f32_to_f16(v)), v, "{v}");
        }
        assert_eq!(f16_to_f32(0x0001), 5.9604645e-8, "the smallest subnormal");
        assert!(f16_to_f32(0x7C00).is_infinite());
    }
}
