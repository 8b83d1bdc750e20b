//! The sentence encoder's network (Universal Sentence Encoder multilingual v3, the CNN
//! variant): each token's embedding (an 8-bit table, one scale and offset per row
//! group), three n-gram convolution branches (orders 2, 3 and 5, each two layers with a
//! residual), a layer norm over the token's features, the sum over tokens projected
//! and scaled by 1/√n, then a small feed-forward network with skip connections and tanh,
//! and the vector scaled to unit length. Plain loops over row-major matrices: a request
//! of twenty tokens takes about a millisecond on one core.

use std::collections::HashMap;

use super::npz::{Array, Data};

/// Row groups of the quantised table: row r is in group r % GROUPS.
const GROUPS: usize = 17;
pub(crate) const DIM: usize = 512;
const BRANCH: usize = 256;
/// (order, tokens to the left) of each convolution branch.
const ORDERS: [(usize, usize); 3] = [(2, 0), (3, 1), (5, 2)];
const FEATURES: usize = DIM + ORDERS.len() * BRANCH;

/// A row-major matrix.
pub(crate) struct Matrix {
    rows: usize,
    cols: usize,
    data: Vec<f32>,
}

impl Matrix {
    /// `out += v · self` (`v` has `rows` elements, `out` `cols`).
    fn mul_add(&self, v: &[f32], out: &mut [f32]) {
        debug_assert_eq!(v.len(), self.rows);
        for (x, row) in v.iter().zip(self.data.chunks_exact(self.cols)) {
            if *x == 0.0 {
                continue;
            }
            for (o, w) in out.iter_mut().zip(row) {
                *o += x * w;
            }
        }
    }
}

struct Branch {
    w1: Matrix,
    b1: Vec<f32>,
    w2: Matrix,
    b2: Vec<f32>,
}

pub(crate) struct Network {
    table: Vec<u8>,
    rows: usize,
    scale: Vec<f32>,
    lo: Vec<f32>,
    proj: Matrix,
    proj_b: Vec<f32>,
    ln_all: (Vec<f32>, Vec<f32>),
    branches: Vec<Branch>,
    ln: (Vec<f32>, Vec<f32>),
    cnn_w: Matrix,
    cnn_b: Vec<f32>,
    d0: Matrix,
    d1: Matrix,
    d2: Matrix,
    d3: Matrix,
    p1: Matrix,
    p3: Matrix,
    eps: f32,
}

/// Take an array out of the file's, checking its shape.
fn take(arrays: &mut HashMap<String, Array>, name: &str, shape: &[usize]) -> Result<Array, String> {
    let a = arrays
        .remove(name)
        .ok_or_else(|| format!("no array {name}"))?;
    if a.shape != shape {
        return Err(format!("{name} has shape {:?}, not {shape:?}", a.shape));
    }
    Ok(a)
}

fn floats(
    arrays: &mut HashMap<String, Array>,
    name: &str,
    shape: &[usize],
) -> Result<Vec<f32>, String> {
    match take(arrays, name, shape)?.data {
        Data::F32(v) => Ok(v),
        Data::U8(_) => Err(format!("{name} holds bytes, not numbers")),
    }
}

fn matrix(
    arrays: &mut HashMap<String, Array>,
    name: &str,
    rows: usize,
    cols: usize,
) -> Result<Matrix, String> {
    Ok(Matrix {
        rows,
        cols,
        data: floats(arrays, name, &[rows, cols])?,
    })
}

/// Concatenate matrices with the same rows side by side.
fn side_by_side(parts: Vec<Matrix>) -> Matrix {
    let rows = parts[0].rows;
    let cols: usize = parts.iter().map(|p| p.cols).sum();
    let mut data = Vec::with_capacity(rows * cols);
    for r in 0..rows {
        for p in &parts {
            data.extend_from_slice(&p.data[r * p.cols..(r + 1) * p.cols]);
        }
    }
    Matrix { rows, cols, data }
}

impl Network {
    pub fn new(mut a: HashMap<String, Array>) -> Result<Network, String> {
        let a = &mut a;
        let first = a.get("q1").map(|q| q.shape.clone()).ok_or("no array q1")?;
        let per_group = first.first().copied().ok_or("q1 has no rows")?;
        let rows = per_group * GROUPS;
        let mut table = vec![0u8; rows * DIM];
        for g in 0..GROUPS {
            let q = take(a, &format!("q{}", g + 1), &[per_group, DIM])?;
            let Data::U8(bytes) = q.data else {
                return Err(format!("q{} is not bytes", g + 1));
            };
            for (i, row) in bytes.chunks_exact(DIM).enumerate() {
                let r = i * GROUPS + g;
                table[r * DIM..(r + 1) * DIM].copy_from_slice(row);
            }
        }
        let mut proj = Vec::new();
        let mut proj_b = Vec::new();
        let mut ln_g = Vec::new();
        let mut ln_b = Vec::new();
        let mut branches = Vec::new();
        for (n, _) in ORDERS {
            proj.push(matrix(a, &format!("proj{n}"), DIM, BRANCH)?);
            proj_b.extend(floats(a, &format!("proj_b{n}"), &[BRANCH])?);
            ln_g.extend(floats(a, &format!("ln_g{n}"), &[BRANCH])?);
            ln_b.extend(floats(a, &format!("ln_b{n}"), &[BRANCH])?);
            branches.push(Branch {
                w1: matrix(a, &format!("w1_{n}"), n * BRANCH, BRANCH)?,
                b1: floats(a, &format!("b1_{n}"), &[BRANCH])?,
                w2: matrix(a, &format!("w2_{n}"), n * BRANCH, BRANCH)?,
                b2: floats(a, &format!("b2_{n}"), &[BRANCH])?,
            });
        }
        let eps = floats(a, "eps", &[])?[0];
        Ok(Network {
            table,
            rows,
            scale: floats(a, "scale", &[GROUPS])?,
            lo: floats(a, "lo", &[GROUPS])?,
            proj: side_by_side(proj),
            proj_b,
            ln_all: (ln_g, ln_b),
            branches,
            ln: (
                floats(a, "ln_g", &[FEATURES])?,
                floats(a, "ln_b", &[FEATURES])?,
            ),
            cnn_w: matrix(a, "cnn_W", FEATURES, DIM)?,
            cnn_b: floats(a, "cnn_b", &[DIM])?,
            d0: matrix(a, "d0", DIM, 320)?,
            d1: matrix(a, "d1", 320, 320)?,
            p1: matrix(a, "p1", DIM, 320)?,
            d2: matrix(a, "d2", 320, DIM)?,
            p3: matrix(a, "p3", 320, DIM)?,
            d3: matrix(a, "d3", DIM, DIM)?,
            eps,
        })
    }

    /// The unit vector of one tokenised sentence (BOS and EOS included).
    pub fn forward(&self, ids: &[u32]) -> Vec<f32> {
        let n = ids.len();
        let mut feats = vec![0f32; n * FEATURES];
        let mut x = vec![0f32; n * ORDERS.len() * BRANCH];
        for (t, &id) in ids.iter().enumerate() {
            let r = if (id as usize) < self.rows {
                id as usize
            } else {
                0
            };
            let (scale, lo) = (self.scale[r % GROUPS], self.lo[r % GROUPS]);
            let emb = &mut feats[t * FEATURES..t * FEATURES + DIM];
            for (e, q) in emb.iter_mut().zip(&self.table[r * DIM..(r + 1) * DIM]) {
                *e = f32::from(*q) * scale + lo;
            }
            let xt = &mut x[t * 3 * BRANCH..(t + 1) * 3 * BRANCH];
            xt.copy_from_slice(&self.proj_b);
            self.proj
                .mul_add(&feats[t * FEATURES..t * FEATURES + DIM], xt);
            layer_norm(xt, &self.ln_all.0, &self.ln_all.1, self.eps);
        }
        let mut window = Vec::new();
        for (i, ((order, left), b)) in ORDERS.iter().zip(&self.branches).enumerate() {
            let xs = |t: usize| &x[t * 3 * BRANCH + i * BRANCH..t * 3 * BRANCH + (i + 1) * BRANCH];
            // First layer: each token's window of the branch's projections.
            let mut h = vec![0f32; n * BRANCH];
            for t in 0..n {
                gather(&mut window, n, t, *order, *left, |s| xs(s));
                let ht = &mut h[t * BRANCH..(t + 1) * BRANCH];
                ht.copy_from_slice(&b.b1);
                b.w1.mul_add(&window, ht);
                for (v, r) in ht.iter_mut().zip(xs(t)) {
                    *v = v.max(0.0) + r;
                }
            }
            // Second layer over the first's outputs, into the token's features.
            for t in 0..n {
                gather(&mut window, n, t, *order, *left, |s| {
                    &h[s * BRANCH..(s + 1) * BRANCH]
                });
                let off = t * FEATURES + DIM + i * BRANCH;
                let out = &mut feats[off..off + BRANCH];
                out.copy_from_slice(&b.b2);
                b.w2.mul_add(&window, out);
                for (v, r) in out.iter_mut().zip(&h[t * BRANCH..(t + 1) * BRANCH]) {
                    *v = v.max(0.0) + r;
                }
            }
        }
        let mut sum = vec![0f32; FEATURES];
        for t in 0..n {
            let f = &mut feats[t * FEATURES..(t + 1) * FEATURES];
            layer_norm(f, &self.ln.0, &self.ln.1, self.eps);
            for (s, v) in sum.iter_mut().zip(f.iter()) {
                *s += v;
            }
        }
        let mut mean: Vec<f32> = self.cnn_b.iter().map(|b| b * n as f32).collect();
        self.cnn_w.mul_add(&sum, &mut mean);
        let root = (n as f32).sqrt();
        mean.iter_mut().for_each(|m| *m /= root);
        let relu = |v: &mut Vec<f32>| v.iter_mut().for_each(|x| *x = x.max(0.0));
        let mut y0 = vec![0f32; 320];
        self.d0.mul_add(&mean, &mut y0);
        relu(&mut y0);
        let mut y1 = vec![0f32; 320];
        self.p1.mul_add(&mean, &mut y1);
        self.d1.mul_add(&y0, &mut y1);
        relu(&mut y1);
        let mut y2 = vec![0f32; DIM];
        self.d2.mul_add(&y1, &mut y2);
        relu(&mut y2);
        let mut z = vec![0f32; DIM];
        self.p3.mul_add(&y1, &mut z);
        self.d3.mul_add(&y2, &mut z);
        z.iter_mut().for_each(|v| *v = v.tanh());
        let norm = z.iter().map(|v| v * v).sum::<f32>().max(self.eps).sqrt();
        z.iter_mut().for_each(|v| *v /= norm);
        z
    }
}

/// The window of `order` rows around token `t` (from `t - left`), rows outside the
/// sentence as zeros, laid end to end in `out`.
fn gather<'a>(
    out: &mut Vec<f32>,
    n: usize,
    t: usize,
    order: usize,
    left: usize,
    row: impl Fn(usize) -> &'a [f32],
) {
    out.clear();
    for k in 0..order {
        match (t + k).checked_sub(left).filter(|s| *s < n) {
            Some(s) => out.extend_from_slice(row(s)),
            None => out.extend(std::iter::repeat_n(0.0, BRANCH)),
        }
    }
}

fn layer_norm(x: &mut [f32], gamma: &[f32], beta: &[f32], eps: f32) {
    let n = x.len() as f32;
    let mean = x.iter().sum::<f32>() / n;
    x.iter_mut().for_each(|v| *v -= mean);
    let var = x.iter().map(|v| v * v).sum::<f32>() / n;
    let inv = 1.0 / (var + eps).sqrt();
    for ((v, g), b) in x.iter_mut().zip(gamma).zip(beta) {
        *v = *v * inv * g + b;
    }
}
