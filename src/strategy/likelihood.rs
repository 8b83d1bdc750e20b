//! Scoring continuations: the log-probability a model gives each of several token
//! sequences after a shared context, under its full distribution (no grammar). Calibrated
//! choices (`strategy::choice`) compare these with and without the request.
//!
//! Cost: the context's tail and the candidates' tokens as branches after it
//! (`Backend::branches`): one batch on llama.cpp; elsewhere the tail, then one forward
//! pass per distinct token prefix.

use crate::backend::{Backend, BackendError, TokenId};
use crate::decode::Session;

/// The log-probability of each continuation after `context`. Leaves `session` describing
/// what the KV cache holds.
pub(crate) fn continuation_logprobs(
    backend: &mut dyn Backend,
    session: &mut Session,
    context: &[TokenId],
    continuations: &[Vec<TokenId>],
) -> Result<Vec<f64>, BackendError> {
    let (_, keep) = session.prepare(backend, context)?;
    session.truncate(keep);
    // Every token but a continuation's last is evaluated, in branches.
    let inputs: Vec<&[TokenId]> = continuations
        .iter()
        .map(|c| &c[..c.len().saturating_sub(1)])
        .collect();
    let (branches, served) = tree(&inputs);
    // The context's tail and the branches after it, together.
    let mut scores = vec![0.0; continuations.len()];
    let root = backend.branches(keep, &context[keep..], &branches, &mut |b, j, logits| {
        let next = served[b]
            .iter()
            .filter_map(|&i| continuations[i].get(j + 1).map(|&t| (i, t)));
        add_logprobs(&mut scores, logits, next);
    })?;
    session.extend(&context[keep..]);
    let root = log_softmax(&root);
    for (score, c) in scores.iter_mut().zip(continuations) {
        *score += c.first().map_or(0.0, |&t| f64::from(root[t as usize]));
    }
    Ok(scores)
}

/// The branches that read `inputs`: the distinct inputs no other input begins with (in
/// sorted order, an input begins its successor if it begins any other), and the inputs
/// each branch serves (empty inputs are served by none).
fn tree<'a>(inputs: &[&'a [TokenId]]) -> (Vec<&'a [TokenId]>, Vec<Vec<usize>>) {
    let mut sorted: Vec<&[TokenId]> = inputs.iter().copied().filter(|i| !i.is_empty()).collect();
    sorted.sort();
    sorted.dedup();
    let branches: Vec<&[TokenId]> = (0..sorted.len())
        .filter(|&k| k + 1 == sorted.len() || !sorted[k + 1].starts_with(sorted[k]))
        .map(|k| sorted[k])
        .collect();
    let mut served: Vec<Vec<usize>> = vec![Vec::new(); branches.len()];
    for (i, input) in inputs.iter().enumerate().filter(|(_, i)| !i.is_empty()) {
        if let Some(b) = branches.iter().position(|b| b.starts_with(input)) {
            served[b].push(i);
        }
    }
    (branches, served)
}

/// As `continuation_logprobs`, read by the tool chooser's adapter where the runtime has
/// one (`Backend::chooser_branches`; the default model's is trained for this reading,
/// `scripts/adapter/`): the context goes into the cache as the base model reads it, then
/// each continuation is read after the context's last token, that token read again, all
/// with the adapter. The cache, and so every later token the turn writes (the call's
/// arguments, the answer), stays the base model's. Without an adapter, exactly
/// `continuation_logprobs`.
pub(crate) fn chooser_logprobs(
    backend: &mut dyn Backend,
    session: &mut Session,
    context: &[TokenId],
    continuations: &[Vec<TokenId>],
) -> Result<Vec<f64>, BackendError> {
    let Some(&last) = context.last() else {
        return continuation_logprobs(backend, session, context, continuations);
    };
    if !backend.has_chooser() || continuations.iter().any(|c| c.is_empty()) {
        return continuation_logprobs(backend, session, context, continuations);
    }
    let (_, keep) = session.prepare(backend, context)?;
    session.truncate(keep);
    backend.forward(keep, &context[keep..])?;
    session.extend(&context[keep..]);
    // Each continuation's input: the context's last token, then all its tokens but its last.
    let rows: Vec<Vec<TokenId>> = continuations
        .iter()
        .map(|c| {
            std::iter::once(last)
                .chain(c[..c.len() - 1].iter().copied())
                .collect()
        })
        .collect();
    let inputs: Vec<&[TokenId]> = rows.iter().map(Vec::as_slice).collect();
    let (branches, served) = tree(&inputs);
    let mut scores = vec![0.0; continuations.len()];
    let read = backend.chooser_branches(context.len() - 1, &branches, &mut |b, j, logits| {
        let next = served[b]
            .iter()
            .filter_map(|&i| continuations[i].get(j).map(|&t| (i, t)));
        add_logprobs(&mut scores, logits, next);
    });
    let read = match read {
        Ok(read) => read,
        Err(e) => {
            // The base model's reading still answers: the turn goes on without the adapter.
            tracing::warn!("the tool chooser's adapter failed ({e}); reading the names without it");
            session.truncate(context.len() - 1);
            false
        }
    };
    if !read {
        return continuation_logprobs(backend, session, context, continuations);
    }
    Ok(scores)
}

/// Adds to each continuation's score (`i`) the log-probability `logits` give its next
/// token (`t`); the normalizer is computed once, and only when some continuation wants it.
fn add_logprobs(scores: &mut [f64], logits: &[f32], next: impl Iterator<Item = (usize, TokenId)>) {
    let mut norm = None;
    for (i, t) in next {
        let norm = *norm.get_or_insert_with(|| log_sum_exp(logits));
        scores[i] += f64::from(logits[t as usize] - norm);
    }
}

fn log_sum_exp(logits: &[f32]) -> f32 {
    let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let sum: f32 = logits.iter().map(|&l| (l - max).exp()).sum();
    max + sum.ln()
}

pub(crate) fn log_softmax(logits: &[f32]) -> Vec<f32> {
    let norm = log_sum_exp(logits);
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
