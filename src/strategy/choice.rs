//! Calibrated choice: which tool a turn calls, and whether a list of calls goes on,
//! decided by what the request changed in the model's likelihoods.
//!
//! A small model calls whichever tool is listed, whatever was asked, and stops after one
//! call whatever was asked: its likeliest next step says as much about the tool list as
//! about the request. So the model is asked twice, once with the request and once with a
//! content-free one ("N/A") in its place (contextual calibration, Zhao et al. 2021):
//!
//! - **which tool**: the fallback (the tool that answers in words) when it is the
//!   likeliest name; otherwise the tool whose name the request raised most,
//!   `log P(name | request) - log P(name | content-free)` over the name's tokens, when it
//!   raised one at all, and the fallback when it raised none. Without a fallback (a call
//!   is forced) the most raised tool is called;
//! - **one more call**: after a call of a list, another follows when the request raised
//!   the odds of the list going on over closing it, against the same calls written after
//!   the content-free request.
//!
//! On BFCL with SmolLM2-135M (first 40 simple and irrelevance questions) the likeliest
//! name's log-probability rose with the request in 37 of 40 relevant questions and in 16
//! of 40 irrelevant ones.
//!
//! Cost per turn: two prompt tails (the request's and the content-free one) and one
//! forward pass per distinct prefix of the candidate names' tokens, twice; per closed
//! call of a list, the two endings scored twice. Nothing per token.
//!
//! The weighed choice (`Weighed`) asks the model once and adds a prior over the
//! candidates (the agent's tool retrieval) to its log-probabilities.

use super::{Scorer, Strategy};
use crate::backend::TokenId;
use crate::decode::DecodeError;

/// What stands in for the request in the baseline prompt.
pub(crate) const CONTENT_FREE: &str = "N/A";

/// The calibrated choice as a strategy (see the module header).
#[derive(Debug, Default)]
pub struct Calibrated {
    /// Whether to decide lists too (turns that may make several calls).
    pub lists: bool,
}

impl Strategy for Calibrated {
    fn name(&self) -> &'static str {
        "calibrated-choice"
    }

    fn decides(&self) -> bool {
        true
    }

    fn choose(
        &mut self,
        scorer: &mut Scorer,
        written: &[TokenId],
        names: &[Vec<TokenId>],
        fallback: Option<usize>,
    ) -> Result<Option<usize>, DecodeError> {
        let scores = scorer.scores(written, names)?;
        let chosen = calibrated_choice(&scores.real, &scores.base, fallback);
        tracing::debug!(target: "ferrosa::gate", ?chosen, ?scores, "tool chosen");
        Ok(chosen)
    }

    fn go_on(
        &mut self,
        scorer: &mut Scorer,
        written: &[TokenId],
        options: &[Vec<TokenId>; 2],
    ) -> Result<Option<bool>, DecodeError> {
        if !self.lists {
            return Ok(None);
        }
        let s = scorer.scores(written, options)?;
        let margin = (s.real[0] - s.real[1]) - (s.base[0] - s.base[1]);
        tracing::debug!(target: "ferrosa::gate", go_on = margin > 0.0, margin, "list");
        Ok(Some(margin > 0.0))
    }
}

/// The candidate to take. `fallback` (the way to answer without a tool) when it is the
/// likeliest; otherwise the tool the request raised most over the content-free
/// baseline, if the request raised it at all, else `fallback`. Without a fallback, the
/// most raised tool. `None` with no tools.
///
/// Plain decoding would take the likeliest tool; the most raised one is the calibrated
/// choice. On BFCL multiple with SmolLM2-135M the expected function is the likeliest in
/// 41 of questions 51-110 and the most raised in 48.
pub(crate) fn calibrated_choice(
    with_request: &[f64],
    baseline: &[f64],
    fallback: Option<usize>,
) -> Option<usize> {
    let n = with_request.len();
    let likeliest = argmax(n, |i| with_request[i], None)?;
    if Some(likeliest) == fallback {
        return fallback;
    }
    let shift = |i: usize| with_request[i] - baseline[i];
    let raised = argmax(n, shift, fallback)?;
    match fallback {
        Some(f) if shift(raised) <= 0.0 => Some(f),
        _ => Some(raised),
    }
}

/// The weighed choice as a strategy: the model's log-probability of each candidate
/// name plus `weight` times the candidate's log prior (in the candidates' order; the
/// agent's prior is the tool retrieval's share, `reading::select::prior`). A small model
/// reads a list of tools as much as the request: on the project's ROS suite the
/// retrieval's best tool was the expected first tool more often than the model's
/// likeliest, and the model still tells apart tools the retrieval scores alike.
///
/// Cost per turn: one prompt tail and one forward pass per distinct prefix of the
/// candidate names' tokens (no content-free prompt). Nothing per token.
#[derive(Debug)]
pub struct Weighed {
    pub prior: Vec<f64>,
    pub weight: f64,
}

impl Strategy for Weighed {
    fn name(&self) -> &'static str {
        "weighed-choice"
    }

    fn decides(&self) -> bool {
        true
    }

    fn choose(
        &mut self,
        scorer: &mut Scorer,
        written: &[TokenId],
        names: &[Vec<TokenId>],
        _fallback: Option<usize>,
    ) -> Result<Option<usize>, DecodeError> {
        if self.prior.len() != names.len() {
            return Ok(None);
        }
        let real = scorer.real(written, names)?;
        let chosen = weighed_choice(&real, &self.prior, self.weight);
        tracing::debug!(target: "ferrosa::gate", ?chosen, ?real, prior = ?self.prior, "tool chosen");
        Ok(chosen)
    }
}

/// The candidate with the best `logprob + weight * prior` (the first of equals);
/// `None` with no candidates.
pub(crate) fn weighed_choice(logprob: &[f64], prior: &[f64], weight: f64) -> Option<usize> {
    let n = logprob.len().min(prior.len());
    argmax(n, |i| logprob[i] + weight * prior[i], None)
}

/// The first of `0..n` (but `skip`) with the best `score`; `None` when there is none.
fn argmax(n: usize, score: impl Fn(usize) -> f64, skip: Option<usize>) -> Option<usize> {
    (0..n)
        .filter(|&i| Some(i) != skip)
        .fold(None, |best, i| match best {
            Some(b) if score(b) >= score(i) => best,
            _ => Some(i),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_prior_outweighs_the_model_by_its_weight() {
        // The model prefers 0; the prior prefers 1.
        let (lp, prior) = ([-1.0, -3.0, -2.0], [-1.0, 0.0, -7.0]);
        assert_eq!(weighed_choice(&lp, &prior, 0.0), Some(0));
        assert_eq!(weighed_choice(&lp, &prior, 1.0), Some(0));
        assert_eq!(weighed_choice(&lp, &prior, 3.0), Some(1));
        // Tools the prior holds equal: the model decides.
        assert_eq!(weighed_choice(&[-4.0, -2.0], &[0.0, 0.0], 8.0), Some(1));
        assert_eq!(weighed_choice(&[], &[], 8.0), None);
    }

    #[test]
    fn the_most_raised_tool_is_called_unless_none_was_raised() {
        // Candidate 0 is the likeliest and the request raised it: taken.
        assert_eq!(
            calibrated_choice(&[-1.0, -3.0], &[-2.0, -3.0], Some(1)),
            Some(0)
        );
        // Likeliest, but likelier still without the request: the fallback.
        assert_eq!(
            calibrated_choice(&[-1.0, -3.0], &[-0.5, -3.0], Some(1)),
            Some(1)
        );
        // Among tools the one raised most is taken, not the likeliest.
        assert_eq!(
            calibrated_choice(&[-1.0, -2.0, -5.0], &[-1.5, -9.0, -5.0], Some(2)),
            Some(1)
        );
        // A tool raised while the likeliest one was lowered still answers the request.
        assert_eq!(
            calibrated_choice(&[-1.0, -4.0, -5.0], &[-0.5, -6.0, -5.0], Some(2)),
            Some(1)
        );
        // No tool raised: the fallback.
        assert_eq!(
            calibrated_choice(&[-1.0, -4.0, -5.0], &[-0.5, -3.0, -9.0], Some(2)),
            Some(2)
        );
        // The fallback itself likeliest: taken whatever the baseline says.
        assert_eq!(
            calibrated_choice(&[-4.0, -1.0], &[-9.0, -0.1], Some(1)),
            Some(1)
        );
        // No fallback: the most raised tool, even when no tool was raised.
        assert_eq!(
            calibrated_choice(&[-1.0, -3.0], &[-0.5, -1.0], None),
            Some(0)
        );
        assert_eq!(
            calibrated_choice(&[-1.0, -3.0], &[-2.0, -8.0], None),
            Some(1)
        );
        assert_eq!(calibrated_choice(&[], &[], None), None);
        assert_eq!(calibrated_choice(&[-1.0], &[-1.0], Some(0)), Some(0));
    }
}
