//! Choosing the next token from logits: greedy, or temperature with top-k and top-p from a
//! seeded generator, so a run can be repeated exactly.
//!
//! The per-token path allocates nothing: the candidate buffer is sized to the vocabulary
//! once. Logits masked to −∞ (by a grammar) are never chosen.

use crate::backend::TokenId;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SamplerConfig {
    /// 0 means greedy.
    pub temperature: f32,
    /// Keep the k most likely tokens (0: all).
    pub top_k: usize,
    /// Keep the smallest set whose probability reaches p (1.0: all).
    pub top_p: f32,
    pub seed: u64,
}

impl Default for SamplerConfig {
    fn default() -> Self {
        SamplerConfig {
            temperature: 0.0,
            top_k: 40,
            top_p: 0.95,
            seed: 0x5eed,
        }
    }
}

/// xoshiro256** seeded through splitmix64: small, fast, and the same on every platform.
#[derive(Debug, Clone)]
pub struct Rng([u64; 4]);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        let mut x = seed;
        let mut next = || {
            x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = x;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        Rng([next(), next(), next(), next()])
    }

    pub(crate) fn next_u64(&mut self) -> u64 {
        let s = &mut self.0;
        let out = s[1].wrapping_mul(5).rotate_left(7).wrapping_mul(9);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        out
    }

    /// Uniform in [0, 1).
    pub(crate) fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in [0, n).
    pub fn below(&mut self, n: usize) -> usize {
        (((self.next_u64() >> 32) * n as u64) >> 32) as usize
    }
}

#[derive(Debug, Clone)]
pub struct Sampler {
    cfg: SamplerConfig,
    rng: Rng,
    candidates: Vec<(f32, TokenId)>,
}

impl Sampler {
    pub fn new(cfg: SamplerConfig, vocab_size: usize) -> Sampler {
        Sampler {
            cfg,
            rng: Rng::new(cfg.seed),
            candidates: Vec::with_capacity(vocab_size),
        }
    }

    pub fn config(&self) -> &SamplerConfig {
        &self.cfg
    }

    /// The next token; `None` only if every logit is −∞ or NaN.
    pub fn sample(&mut self, logits: &[f32]) -> Option<TokenId> {
        let _span = tracing::trace_span!("sample").entered();
        if self.cfg.temperature <= 0.0 {
            return argmax(logits);
        }
        self.candidates.clear();
        self.candidates.extend(
            logits
                .iter()
                .enumerate()
                .filter(|(_, l)| l.is_finite())
                .map(|(i, &l)| (l, i as TokenId)),
        );
        if self.candidates.is_empty() {
            return None;
        }
        let by_logit_desc = |a: &(f32, TokenId), b: &(f32, TokenId)| b.0.total_cmp(&a.0);
        let k = match self.cfg.top_k {
            0 => self.candidates.len(),
            k => k.min(self.candidates.len()),
        };
        if k < self.candidates.len() {
            self.candidates.select_nth_unstable_by(k - 1, by_logit_desc);
            self.candidates.truncate(k);
        }
        self.candidates.sort_unstable_by(by_logit_desc);
        let max = self.candidates[0].0;
        let inv_t = 1.0 / self.cfg.temperature;
        let mut total = 0.0f32;
        for c in self.candidates.iter_mut() {
            c.0 = ((c.0 - max) * inv_t).exp();
            total += c.0;
        }
        // Top-p on the sorted probabilities.
        let mut keep = self.candidates.len();
        if self.cfg.top_p < 1.0 {
            let mut acc = 0.0;
            for (i, c) in self.candidates.iter().enumerate() {
                acc += c.0 / total;
                if acc >= self.cfg.top_p {
                    keep = i + 1;
                    break;
                }
            }
        }
        let kept_total: f32 = self.candidates[..keep].iter().map(|c| c.0).sum();
        let mut r = self.rng.next_f32() * kept_total;
        for c in &self.candidates[..keep] {
            r -= c.0;
            if r <= 0.0 {
                return Some(c.1);
            }
        }
        Some(self.candidates[keep - 1].1)
    }
}

pub fn argmax(logits: &[f32]) -> Option<TokenId> {
    let mut best: Option<(f32, usize)> = None;
    for (i, &l) in logits.iter().enumerate() {
        if l.is_nan() || l == f32::NEG_INFINITY {
            continue;
        }
        if best.is_none_or(|(b, _)| l > b) {
            best = Some((l, i));
        }
    }
    best.map(|(_, i)| i as TokenId)
}
