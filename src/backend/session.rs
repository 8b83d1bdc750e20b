//! What the backend's KV cache holds (`Session`): the token sequence, so a prompt
//! sharing a prefix evaluates only its tail, and the persistent prompt cache behind it,
//! whose stable prefixes a cold start restores instead of evaluating.

use std::sync::Arc;

use super::prompt_cache::{PromptCache, Restored, MIN_GAIN};
use super::{Backend, BackendError, TokenId};

/// The token sequence the backend's KV cache holds, and the persistent prompt cache
/// behind it (if any).
#[derive(Debug, Default, Clone)]
pub struct Session {
    tokens: Vec<TokenId>,
    cache: Option<Arc<PromptCache>>,
    /// The leading tokens of this turn's prompts that do not depend on the conversation
    /// (the system prompt with the tool specs): what the prompt cache keeps.
    stable: Vec<TokenId>,
}

impl Session {
    pub fn new() -> Session {
        Session::default()
    }

    /// A session whose stable prefixes are kept in, and taken from, `cache`.
    pub fn with_cache(cache: Arc<PromptCache>) -> Session {
        Session {
            cache: Some(cache),
            ..Session::default()
        }
    }

    pub fn cache(&self) -> Option<&Arc<PromptCache>> {
        self.cache.as_ref()
    }

    /// How many leading tokens of the prompts are the stable prefix (0 when none is set).
    pub fn stable_len(&self) -> usize {
        self.stable.len()
    }

    /// Prompts starting with `prefix` start with what does not depend on the
    /// conversation: the prompt cache may keep it, and serve it to a later process.
    pub fn set_stable(&mut self, prefix: &[TokenId]) {
        if self.stable != prefix {
            self.stable = prefix.to_vec();
        }
    }

    /// Bring the backend's cache into `prompt` as far as memory holds it, or, starting
    /// cold (memory holds none of it), through its stable prefix: a cold prompt's stable
    /// prefix is evaluated on its own, in batches from the prompt's start, the last one
    /// ending where the prefix does, with or without a prompt cache. So a restored
    /// prefix (the whole stable prefix an entry holds, or the whole batches one shares
    /// with it) holds exactly the state evaluating it gives: the cache changes no logit.
    /// A stable prefix no entry holds is kept once evaluated. Returns how many tokens
    /// were held without evaluating them, and how many are held now (both leave at least
    /// one token of `prompt` to evaluate).
    pub fn prepare(
        &mut self,
        backend: &mut dyn Backend,
        prompt: &[TokenId],
    ) -> Result<(usize, usize), BackendError> {
        let keep = self.reusable(prompt);
        let stable = if prompt.starts_with(&self.stable) {
            self.stable.len().min(prompt.len().saturating_sub(1))
        } else {
            0
        };
        if keep > 0 || stable == 0 {
            return Ok((keep, keep));
        }
        // An entry worth reading, and one worth writing, spares `MIN_GAIN` tokens.
        let cache = self.cache.clone().filter(|_| stable >= MIN_GAIN);
        if let Some(cache) = &cache {
            let batch = backend.batch_len().max(1);
            match cache.restore(backend, &prompt[..stable], batch) {
                Restored::Hit(tokens) => self.tokens = tokens,
                Restored::Cleared | Restored::Miss => self.clear(),
            }
        }
        let reused = self.tokens.len();
        if reused < stable {
            if let Err(e) = backend.forward(reused, &prompt[reused..stable]) {
                self.clear();
                return Err(e);
            }
            self.tokens.extend_from_slice(&prompt[reused..stable]);
            if let Some(cache) = &cache {
                cache.store(backend, &prompt[..stable]);
            }
        }
        Ok((reused, stable))
    }

    pub fn tokens(&self) -> &[TokenId] {
        &self.tokens
    }

    /// The cache now holds only the first `n` tokens it held.
    pub fn truncate(&mut self, n: usize) {
        self.tokens.truncate(n);
    }

    /// Room for `n` more tokens without reallocating.
    pub(crate) fn reserve(&mut self, n: usize) {
        self.tokens.reserve(n);
    }

    /// The cache now also holds `tokens`, after what it held.
    pub fn extend(&mut self, tokens: &[TokenId]) {
        self.tokens.extend_from_slice(tokens);
    }

    /// Forget the cache contents (the next prompt is evaluated in full).
    pub fn clear(&mut self) {
        self.tokens.clear();
    }

    /// How many leading tokens of `prompt` are cached, leaving at least one to evaluate
    /// (the backend returns logits only for tokens it evaluates).
    pub(crate) fn reusable(&self, prompt: &[TokenId]) -> usize {
        let common = self
            .tokens
            .iter()
            .zip(prompt)
            .take_while(|(a, b)| a == b)
            .count();
        common.min(prompt.len().saturating_sub(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reusable_prefix_leaves_one_token_to_evaluate() {
        let mut s = Session::new();
        s.extend(&[1, 2, 3, 4]);
        assert_eq!(s.reusable(&[1, 2, 3, 4, 5]), 4);
        assert_eq!(s.reusable(&[1, 2, 3, 4]), 3);
        assert_eq!(s.reusable(&[1, 9]), 1);
        assert_eq!(s.reusable(&[7]), 0);
    }
}
