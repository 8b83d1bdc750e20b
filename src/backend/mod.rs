//! Model runtimes behind one trait: token ids in, next-token logits out.
//!
//! Owns the weights, the KV cache, tokenization, the vocabulary (bytes of every token,
//! special and end-of-generation tokens) and the chat template. Knows nothing of
//! grammars, tools or ROS: `decode` drives a `Backend`, `agent` sees only this trait.
//!
//! Layout:
//! - `gguf`: GGUF header and metadata reading, validation of truncated/foreign files
//! - `vocab`: the token table shared by every runtime, and streaming detokenization
//! - `template`: chat templates (minijinja), from the file or a per-family fallback
//! - `llama`: llama.cpp through `llama-cpp-2` (feature `llama`, default)
//! - `candle`: a pure-Rust runtime on candle (feature `candle`): SmolLM2 and Gemma 3
//! - `bpe`: a byte-level BPE tokenizer built from GGUF metadata, for runtimes without one
//!   (the tests' scripted runtimes; candle tokenizes through the `tokenizers` crate)
//! - `session`: what the KV cache holds (`Session`), reused across prompts
//! - `prompt_cache`: stable prompt prefixes' KV state on disk, for a cold start

pub mod gguf;
pub mod template;
pub mod vocab;

pub mod bpe;
#[cfg(feature = "candle")]
pub mod candle;
#[cfg(feature = "llama")]
pub mod llama;
mod load;
mod options;
pub mod prompt_cache;
mod session;

use std::path::PathBuf;
use std::sync::Arc;

pub use gguf::{Gguf, GgufError};
pub use load::{load, load_vocabulary};
pub use options::{physical_cores, BackendKind, LoadOptions};
pub use prompt_cache::PromptCache;
pub use session::Session;
pub use template::{ChatTemplate, Part, Rendered, TemplateError};
pub use vocab::{Detokenizer, TokenId, Vocab};

#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    #[error(transparent)]
    Gguf(#[from] GgufError),
    #[error(transparent)]
    Template(#[from] TemplateError),
    #[error("{backend} could not load {path}: {reason}")]
    Load {
        backend: &'static str,
        path: PathBuf,
        reason: String,
    },
    #[error("the {0} backend is not compiled into this binary; rebuild with `--features {0}`")]
    NotCompiled(&'static str),
    #[error("{backend} does not support architecture '{arch}' (supported: {supported})")]
    Architecture {
        backend: &'static str,
        arch: String,
        supported: &'static str,
    },
    #[error("context full: {needed} tokens do not fit in the {limit}-token context; raise --ctx or shorten the input")]
    ContextFull { needed: usize, limit: usize },
    #[error("token id {0} is outside the vocabulary")]
    BadToken(TokenId),
    #[error("{backend} failed to evaluate: {reason}")]
    Eval {
        backend: &'static str,
        reason: String,
    },
}

/// What every runtime checks before evaluating `more` new tokens (`tokens`) after the
/// first `keep` of the `held` it caches: that they fit its `limit`-token context and its
/// `n_vocab`-token vocabulary. Returns `keep` as the cache can hold it.
/// `Backend::forward` through `forward_each`: only the last row's logits, copied into
/// the backend's own buffer (`slot`, taken out while the batch runs).
pub(crate) fn forward_last<B: Backend>(
    backend: &mut B,
    slot: fn(&mut B) -> &mut Vec<f32>,
    keep: usize,
    tokens: &[TokenId],
) -> Result<(), BackendError> {
    let mut logits = std::mem::take(slot(backend));
    let last = tokens.len().saturating_sub(1);
    let done = backend.forward_each(keep, tokens, last, &mut |_, row| {
        logits.copy_from_slice(row)
    });
    *slot(backend) = logits;
    done
}

pub(crate) fn admit<'t>(
    keep: usize,
    held: usize,
    more: usize,
    mut tokens: impl Iterator<Item = &'t TokenId>,
    limit: usize,
    n_vocab: usize,
) -> Result<usize, BackendError> {
    let keep = keep.min(held);
    let needed = keep + more;
    if needed > limit {
        return Err(BackendError::ContextFull { needed, limit });
    }
    if let Some(&bad) = tokens.find(|&&t| t as usize >= n_vocab) {
        return Err(BackendError::BadToken(bad));
    }
    Ok(keep)
}

/// `Backend::branches` one token per forward pass: `shared` first, then each branch,
/// sharing the leading tokens a branch has in common with the one before it.
pub(crate) fn branches_one_by_one<B: Backend + ?Sized>(
    backend: &mut B,
    keep: usize,
    shared: &[TokenId],
    branches: &[&[TokenId]],
    each: &mut dyn FnMut(usize, usize, &[f32]),
) -> Result<Vec<f32>, BackendError> {
    let root = backend.forward(keep, shared)?.to_vec();
    let keep = keep + shared.len();
    // The logits after each token of the branch before, while the next shares them.
    let mut path: Vec<(TokenId, Vec<f32>)> = Vec::new();
    for (b, tokens) in branches.iter().enumerate() {
        let common = path
            .iter()
            .zip(tokens.iter())
            .take_while(|((p, _), t)| p == *t)
            .count();
        path.truncate(common);
        for (j, &t) in tokens.iter().enumerate() {
            if j >= path.len() {
                let logits = backend.forward(keep + j, &[t])?;
                path.push((t, logits.to_vec()));
            }
            each(b, j, &path[j].1);
        }
    }
    Ok(root)
}

/// A model's tokenizer, shareable across threads (the constrained decoder keeps one to
/// tokenize forced text exactly as the model would).
pub trait Tokenize: Send + Sync {
    /// As `Backend::tokenize`.
    fn tokenize(&self, text: &str, special: bool) -> Vec<TokenId>;
}

/// The model runtime: token ids in, next-token logits out. Owns weights and KV cache.
pub trait Backend: Send {
    /// Short name for reports ("llama.cpp", "candle").
    fn name(&self) -> &'static str;
    fn vocab(&self) -> &Vocab;
    fn chat_template(&self) -> &ChatTemplate;
    /// Tokens the context holds (prompt and generated together).
    fn context_len(&self) -> usize;
    /// Text to tokens. With `special`, special-token texts such as `<|im_start|>` become
    /// their single ids (for rendered templates); without, they are plain text (for
    /// anything an operator or a tool wrote). Never adds BOS: see `Vocab::bos`.
    fn tokenize(&self, text: &str, special: bool) -> Result<Vec<TokenId>, BackendError>;
    /// The same tokenizer as a shareable handle.
    fn tokenizer(&self) -> Arc<dyn Tokenize>;
    /// Keep the first `keep` cached tokens, evaluate `tokens` after them in batches, and
    /// return the logits of the last one. `tokens` must not be empty.
    fn forward(&mut self, keep: usize, tokens: &[TokenId]) -> Result<&mut [f32], BackendError>;
    /// Batches shorter than this are evaluated row by row exactly as one-token steps
    /// would be, bit for bit (candle's rows pass); None where a batch's rows may differ
    /// from them in their last bits (llama.cpp's batched kernels sum in another order
    /// than its one-token ones). Drafting keeps its batches below it, so that a drafted
    /// turn writes exactly what the turn writes without.
    fn exact_rows_below(&self) -> Option<usize> {
        None
    }
    /// Keep the first `keep` cached tokens and evaluate `tokens` after them, as `forward`
    /// does, handing `each(i, logits)` the logits after token `i` for every `i` from
    /// `from` on, in order: to check a guess of several tokens in one pass. The default
    /// evaluates one token per pass; a runtime that batches gives every row at once.
    fn forward_each(
        &mut self,
        keep: usize,
        tokens: &[TokenId],
        from: usize,
        each: &mut dyn FnMut(usize, &[f32]),
    ) -> Result<(), BackendError> {
        if tokens.is_empty() {
            return Err(BackendError::Eval {
                backend: self.name(),
                reason: "nothing to evaluate: no tokens given".into(),
            });
        }
        let first = from.min(tokens.len() - 1);
        let logits = self.forward(keep, &tokens[..=first])?;
        if from <= first {
            each(first, logits);
        }
        for (i, &t) in tokens.iter().enumerate().skip(first + 1) {
            each(i, self.forward(keep + i, &[t])?);
        }
        Ok(())
    }
    /// Keep the first `keep` cached tokens and evaluate `shared` after them, as `forward`
    /// would (the cache holds them after), then each of `branches` after those as if it
    /// alone followed, handing `each(branch, j, logits)` the logits after its token `j`.
    /// Returns the logits after `shared`'s last token (`shared` must not be empty).
    /// Afterwards the cache holds `keep` and `shared`, and maybe one branch's tokens past
    /// them (which the next `forward` from there drops). The default evaluates `shared`,
    /// then the branches one token per forward pass, sharing the leading tokens a branch
    /// has in common with the one before it; a runtime with sequences side by side
    /// evaluates them all in one batch.
    fn branches(
        &mut self,
        keep: usize,
        shared: &[TokenId],
        branches: &[&[TokenId]],
        each: &mut dyn FnMut(usize, usize, &[f32]),
    ) -> Result<Vec<f32>, BackendError> {
        branches_one_by_one(self, keep, shared, branches, each)
    }
    /// The tool chooser's reading (`strategy::likelihood`): each branch read after the
    /// cache's first `keep` cells with the chooser's adapter (`LoadOptions::adapter`) on,
    /// the cache itself left the base model's. A branch starts with the token at `keep`
    /// read again (the one whose logits give a name's first token). `each(b, j, logits)`
    /// as in `branches`. False, having evaluated nothing, when this runtime has no
    /// adapter loaded (`has_chooser`) or cannot take these branches: the caller reads
    /// without it.
    fn has_chooser(&self) -> bool {
        false
    }
    fn chooser_branches(
        &mut self,
        keep: usize,
        branches: &[&[TokenId]],
        each: &mut dyn FnMut(usize, usize, &[f32]),
    ) -> Result<bool, BackendError> {
        let _ = (keep, branches, each);
        Ok(false)
    }
    /// Most tokens one evaluation step takes (`forward` cuts longer input into such
    /// batches, from its first token): what keeps a restored prefix's state the one
    /// evaluating it gives (`Session::prepare`).
    fn batch_len(&self) -> usize {
        usize::MAX
    }
    /// What, besides the weights and the tokens, decides the bytes of a `snapshot`
    /// (runtime and its version, context and batch sizes, threads): part of a
    /// persistent prompt cache's key. None when this runtime cannot snapshot its cache.
    fn snapshot_key(&self) -> Option<String> {
        None
    }
    /// The KV cache's contents (every cached token), as bytes `restore` takes back.
    fn snapshot(&self) -> Result<Vec<u8>, BackendError> {
        Err(BackendError::Eval {
            backend: self.name(),
            reason: "this runtime cannot snapshot its cache".into(),
        })
    }
    /// Replace the KV cache with a `snapshot` of `tokens` cached tokens, made by this
    /// runtime under the same `snapshot_key`. On error the cache is empty.
    fn restore(&mut self, snapshot: &[u8], tokens: usize) -> Result<(), BackendError> {
        let _ = (snapshot, tokens);
        Err(BackendError::Eval {
            backend: self.name(),
            reason: "this runtime cannot restore a cache".into(),
        })
    }
}
