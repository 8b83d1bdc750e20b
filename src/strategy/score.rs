//! Scoring continuations: the log-probability a model gives each of several token
//! sequences after a shared context, under its full distribution (no grammar). Calibrated
//! choices (`strategy::choice`) compare these with and without the request.
//!
//! Cost: one forward pass per distinct token prefix of the candidates; candidates that
//! share a prefix share the cache.

use crate::backend::{Backend, BackendError, TokenId};
use crate::decode::Session;

/// The log-probability of each continuation after `context`. Leaves `session` describing
/// what the KV cache holds.
pub fn continuation_logprobs(
    backend: &mut dyn Backend,
    session: &mut Session,
    context: &[TokenId],
    continuations: &[Vec<TokenId>],
) -> Result<Vec<f64>, BackendError> {
    let (_, keep) = session.prepare(backend, context)?;
    session.truncate(keep);
    let root = log_softmax(backend.forward(keep, &context[keep..])?);
    session.extend(&context[keep..]);
    // Visit continuations in token order so neighbours share the longest prefix.
    let mut order: Vec<usize> = (0..continuations.len()).collect();
    order.sort_by(|&a, &b| continuations[a].cmp(&continuations[b]));
    let mut scores = vec![0.0; continuations.len()];
    // The distribution after each prefix of the current continuation ([0]: the root).
    // The cache holds the context and the longest of these prefixes.
    let mut path: Vec<(Vec<TokenId>, Vec<f32>)> = vec![(Vec::new(), root)];
    let base = context.len();
    for i in order {
        let cont = &continuations[i];
        let shared = path.iter().take_while(|(p, _)| cont.starts_with(p)).count();
        path.truncate(shared);
        let mut total = 0.0;
        for (j, &tok) in cont.iter().enumerate() {
            if j >= path.len() {
                let next = log_softmax(backend.forward(base + j - 1, &cont[j - 1..j])?);
                session.truncate(base + j - 1);
                session.extend(&cont[j - 1..j]);
                path.push((cont[..j].to_vec(), next));
            }
            total += f64::from(path[j].1[tok as usize]);
        }
        scores[i] = total;
    }
    Ok(scores)
}

pub fn log_softmax(logits: &[f32]) -> Vec<f32> {
    let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let sum: f32 = logits.iter().map(|&l| (l - max).exp()).sum();
    let norm = max + sum.ln();
    logits.iter().map(|&l| l - norm).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_softmax_normalises() {
        let l = log_softmax(&[1.0, 2.0, 3.0]);
        let total: f32 = l.iter().map(|x| x.exp()).sum();
        assert!((total - 1.0).abs() < 1e-5);
        assert!(l[2] > l[1] && l[1] > l[0]);
    }
}
