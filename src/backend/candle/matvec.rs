//! Matrix-vector products for the two weight formats of the default model, SmolLM2: its
//! layers' Q4_1 (which candle 0.11.1 computes with a scalar dot product, more than half
//! of a generated token's time) and the Q8_0 of its embedding, which is also its output
//! layer. Each input vector is quantized to 8-bit blocks as llama.cpp does (Q8_1 for
//! Q4_1, Q8_0 for Q8_0), then each weight row's AVX2 dot product with it (a scalar one
//! where AVX2 is missing), the rows shared out on candle's own thread pool (a second
//! pool would spin against it for the same cores).
//!
//! Several input vectors at once (`QRows::matvecs`): each weight row is read once and
//! dotted with every vector in turn, by the same function a single vector uses, so a
//! vector's product does not depend on what else is in the batch, bit for bit (the
//! rows pass, `rows`, relies on it).
//!
//! Block layouts are GGML's: Q4_1 is 32 weights as an f16 scale `d`, an f16 minimum `m`
//! and 16 bytes of nibbles (weight j in the low half of byte j, weight j + 16 in the high
//! half): w = d·q + m. Q8_0 is 32 weights as an f16 scale and 32 signed bytes: w = d·q.
//! Q8_1 is 32 values as a scale, the scale times the sum of the quantized values, and 32
//! signed bytes.

/// Weights per block.
const QK: usize = 32;
/// Bytes per Q4_1 block.
const Q4_1_BYTES: usize = 20;
/// Bytes per Q8_0 block.
const Q8_0_BYTES: usize = 34;
/// Input vectors a task dots its weight rows with before the next ones (a prompt's
/// 512 would not stay in cache beside the rows).
const VECTORS_AT_ONCE: usize = 8;

/// The weight formats these kernels compute.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    Q41,
    Q80,
}

impl Format {
    fn block_bytes(self) -> usize {
        match self {
            Format::Q41 => Q4_1_BYTES,
            Format::Q80 => Q8_0_BYTES,
        }
    }
}

/// A quantized matrix of `rows` × `cols`, as the file holds it.
pub(crate) struct QRows {
    data: Vec<u8>,
    rows: usize,
    cols: usize,
    format: Format,
    /// Whether this CPU runs the AVX2 dot products (checked at `new`).
    simd: bool,
}

/// One block of an input vector, quantized to 8 bits.
struct Q8 {
    d: f32,
    /// `d` times the sum of `qs` (Q8_1's; Q8_0 leaves it unread).
    s: f32,
    qs: [i8; QK],
}

impl QRows {
    /// `data` as GGML lays out a (rows, cols) tensor of `format`; None when its size is
    /// not that.
    pub fn new(format: Format, data: Vec<u8>, rows: usize, cols: usize) -> Option<QRows> {
        (cols % QK == 0 && data.len() == rows * cols / QK * format.block_bytes()).then_some(QRows {
            data,
            rows,
            cols,
            format,
            simd: simd_available(),
        })
    }

    /// Row `r`, dequantized into `out` (`cols` values); false when there is no row `r`.
    pub(crate) fn dequantize_row(&self, r: usize, out: &mut [f32]) -> bool {
        if r >= self.rows || out.len() != self.cols {
            return false;
        }
        let bytes = self.format.block_bytes();
        let row_bytes = self.cols / QK * bytes;
        let row = &self.data[r * row_bytes..(r + 1) * row_bytes];
        for (b, o) in row.chunks_exact(bytes).zip(out.chunks_exact_mut(QK)) {
            let d = half(&b[0..2]);
            match self.format {
                Format::Q41 => {
                    let m = half(&b[2..4]);
                    for j in 0..QK / 2 {
                        o[j] = d * f32::from(b[4 + j] & 0x0F) + m;
                        o[j + QK / 2] = d * f32::from(b[4 + j] >> 4) + m;
                    }
                }
                Format::Q80 => {
                    for (o, &q) in o.iter_mut().zip(&b[2..]) {
                        *o = d * f32::from(q as i8);
                    }
                }
            }
        }
        true
    }

    /// W·x for each of the `n` vectors in `xs` (`n` × `cols`, one after another), into
    /// `out` (`n` × `rows`: vector i's product at `i * rows`).
    pub(crate) fn matvecs(&self, xs: &[f32], n: usize, out: &mut [f32]) {
        assert_eq!(xs.len(), n * self.cols, "inputs of the wrong size");
        assert_eq!(out.len(), n * self.rows, "outputs of the wrong size");
        let blocks = self.cols / QK;
        let xq: Vec<Q8> = xs.chunks_exact(QK).map(quantize).collect();
        let row_bytes = blocks * self.format.block_bytes();
        let (rows, format, simd) = (self.rows, self.format, self.simd);
        let dst = Rows(out.as_mut_ptr());
        candle_core::utils::barrier_pool().execute_chunked(rows, |range| {
            let dst = &dst;
            // A few vectors against the task's rows at a time, so that both stay in
            // the core's cache however many vectors a prompt has.
            for (v, group) in xq.chunks(blocks * VECTORS_AT_ONCE).enumerate() {
                for r in range.clone() {
                    let row = &self.data[r * row_bytes..(r + 1) * row_bytes];
                    for (j, x) in group.chunks_exact(blocks).enumerate() {
                        let i = v * VECTORS_AT_ONCE + j;
                        let value = dot(format, simd, row, x);
                        // SAFETY: `i < n` and `r < rows`, so the index is inside `out`
                        // (n × rows, asserted above), and each (i, r) is written by the
                        // one task row r's range went to.
                        unsafe { *dst.0.add(i * rows + r) = value };
                    }
                }
            }
        });
    }
}

/// `out`'s start, written at disjoint indices by the pool's tasks.
struct Rows(*mut f32);
// SAFETY: tasks write disjoint indices, and `matvecs` waits for all of them.
unsafe impl Sync for Rows {}

/// One weight row's dot product with a quantized vector.
fn dot(format: Format, simd: bool, row: &[u8], x: &[Q8]) -> f32 {
    match (format, simd) {
        // SAFETY: the CPU has AVX2, FMA and F16C (`simd`, checked at `QRows::new`).
        (Format::Q41, true) => unsafe { dot_q41_avx2(row, x) },
        (Format::Q80, true) => unsafe { dot_q80_avx2(row, x) },
        (Format::Q41, false) => dot_q41_scalar(row, x),
        (Format::Q80, false) => dot_q80_scalar(row, x),
    }
}

/// llama.cpp's `quantize_row_q8_1` for one block (its scale and values are also
/// `quantize_row_q8_0`'s).
fn quantize(x: &[f32]) -> Q8 {
    let amax = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let d = amax / 127.0;
    let id = if d != 0.0 { 1.0 / d } else { 0.0 };
    let mut qs = [0i8; QK];
    let mut sum = 0i32;
    for (q, v) in qs.iter_mut().zip(x) {
        *q = (v * id).round() as i8;
        sum += i32::from(*q);
    }
    Q8 {
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

fn half(b: &[u8]) -> f32 {
    f16_to_f32(u16::from_le_bytes([b[0], b[1]]))
}

fn dot_q41_scalar(row: &[u8], xq: &[Q8]) -> f32 {
    let mut sum = 0.0f32;
    for (b, y) in row.chunks_exact(Q4_1_BYTES).zip(xq) {
        let (d, m) = (half(&b[0..2]), half(&b[2..4]));
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

fn dot_q80_scalar(row: &[u8], xq: &[Q8]) -> f32 {
    let mut sum = 0.0f32;
    for (b, y) in row.chunks_exact(Q8_0_BYTES).zip(xq) {
        let sumi: i32 = b[2..]
            .iter()
            .zip(&y.qs)
            .map(|(&w, &x)| i32::from(w as i8) * i32::from(x))
            .sum();
        sum += half(&b[0..2]) * y.d * sumi as f32;
    }
    sum
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn dot_q41_avx2(row: &[u8], xq: &[Q8]) -> f32 {
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
    hsum(acc) + mins
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn dot_q80_avx2(row: &[u8], xq: &[Q8]) -> f32 {
    use std::arch::x86_64::*;
    let ones = _mm256_set1_epi16(1);
    let mut acc = _mm256_setzero_ps();
    for (b, y) in row.chunks_exact(Q8_0_BYTES).zip(xq) {
        let d = f16_to_f32(u16::from_le_bytes([b[0], b[1]]));
        let qw = _mm256_loadu_si256(b.as_ptr().add(2) as *const __m256i);
        let qy = _mm256_loadu_si256(y.qs.as_ptr() as *const __m256i);
        // i8 × i8 as u8 × i8: |w| times y with w's sign.
        let prod = _mm256_maddubs_epi16(_mm256_sign_epi8(qw, qw), _mm256_sign_epi8(qy, qw));
        let prod = _mm256_madd_epi16(prod, ones);
        let scale = _mm256_set1_ps(d * y.d);
        acc = _mm256_fmadd_ps(_mm256_cvtepi32_ps(prod), scale, acc);
    }
    hsum(acc)
}

/// The sum of an AVX register's eight lanes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn hsum(acc: std::arch::x86_64::__m256) -> f32 {
    use std::arch::x86_64::*;
    let hi = _mm256_extractf128_ps(acc, 1);
    let s = _mm_add_ps(_mm256_castps256_ps128(acc), hi);
    let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
    let s = _mm_add_ss(s, _mm_shuffle_ps(s, s, 1));
    _mm_cvtss_f32(s)
}

#[cfg(not(target_arch = "x86_64"))]
unsafe fn dot_q41_avx2(row: &[u8], xq: &[Q8]) -> f32 {
    dot_q41_scalar(row, xq)
}

#[cfg(not(target_arch = "x86_64"))]
unsafe fn dot_q80_avx2(row: &[u8], xq: &[Q8]) -> f32 {
    dot_q80_scalar(row, xq)
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

    /// A matrix of `format` whose weights are exactly representable, and its float copy.
    fn matrix(format: Format, rows: usize, cols: usize) -> (QRows, Vec<f32>) {
        let mut data = Vec::new();
        let mut dense = Vec::new();
        for r in 0..rows {
            for blk in 0..cols / QK {
                let d = 0.5 * (1 + (r + blk) % 3) as f32;
                data.extend_from_slice(&f32_to_f16(d).to_le_bytes());
                match format {
                    Format::Q41 => {
                        let m = -2.0 + (r % 5) as f32;
                        data.extend_from_slice(&f32_to_f16(m).to_le_bytes());
                        let q: Vec<u8> = (0..QK)
                            .map(|j| ((r * 7 + j * 3 + blk) % 16) as u8)
                            .collect();
                        for j in 0..QK / 2 {
                            data.push(q[j] | (q[j + QK / 2] << 4));
                        }
                        dense.extend(q.iter().map(|&q| d * f32::from(q) + m));
                    }
                    Format::Q80 => {
                        let q: Vec<i8> = (0..QK)
                            .map(|j| ((r * 7 + j * 3 + blk) % 255) as i32 - 127)
                            .map(|v| v as i8)
                            .collect();
                        data.extend(q.iter().map(|&v| v as u8));
                        dense.extend(q.iter().map(|&q| d * f32::from(q)));
                    }
                }
            }
        }
        (QRows::new(format, data, rows, cols).unwrap(), dense)
    }

    #[test]
    fn products_equal_the_float_ones_and_do_not_depend_on_the_batch() {
        let (rows, cols) = (70, 64);
        for format in [Format::Q41, Format::Q80] {
            let (w, dense) = matrix(format, rows, cols);
            let xs: Vec<f32> = (0..3 * cols)
                .map(|i| ((i * 13) % 17) as f32 - 8.0)
                .collect();
            let mut all = vec![0.0; 3 * rows];
            w.matvecs(&xs, 3, &mut all);
            let mut row = vec![0.0; cols];
            assert!(w.dequantize_row(rows - 1, &mut row));
            assert_eq!(row, dense[(rows - 1) * cols..], "{format:?}: the last row");
            assert!(!w.dequantize_row(rows, &mut row));
            for (i, x) in xs.chunks_exact(cols).enumerate() {
                let mut alone = vec![0.0; rows];
                w.matvecs(x, 1, &mut alone);
                assert_eq!(
                    alone,
                    all[i * rows..(i + 1) * rows],
                    "{format:?}: vector {i}"
                );
                let xq: Vec<Q8> = x.chunks_exact(QK).map(quantize).collect();
                let row_bytes = cols / QK * format.block_bytes();
                for r in 0..rows {
                    let want: f32 = (0..cols).map(|c| dense[r * cols + c] * x[c]).sum();
                    // x's quantization to 8 bits is the only rounding: at most half a step
                    // (its largest magnitude / 127) per value, times the weight.
                    let step = 8.0 / 127.0;
                    let tol = (0..cols)
                        .map(|c| dense[r * cols + c].abs() * step / 2.0)
                        .sum::<f32>()
                        + 1e-3;
                    assert!(
                        (alone[r] - want).abs() < tol,
                        "{format:?} row {r}: {} vs {want}",
                        alone[r]
                    );
                    let row = &w.data[r * row_bytes..(r + 1) * row_bytes];
                    let scalar = dot(format, false, row, &xq);
                    assert!(
                        (alone[r] - scalar).abs() < 1e-3 * scalar.abs().max(1.0),
                        "{format:?} row {r}: simd {} scalar {scalar}",
                        alone[r]
                    );
                }
            }
        }
        assert!(QRows::new(Format::Q41, vec![0; 19], 1, 32).is_none());
        assert!(QRows::new(Format::Q80, vec![0; 34], 1, 32).is_some());
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
