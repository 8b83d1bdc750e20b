//! Sentences as vectors of meaning: the multilingual sentence encoder tool choice reads
//! requests with (Universal Sentence Encoder multilingual v3, 16 languages). Two
//! sentences that say the same thing, in the same or another language, get vectors
//! close in cosine ("how many topics does it have?" and "wie viele Topics gibt es?": 0.82;
//! either and "hello, how are you?": under 0.2).
//!
//! Layout:
//! - `spm`: the SentencePiece tokenizer, read from the vocabulary file
//! - `npz`: the weights, read from NumPy's `.npz`
//! - `cnn`: the network
//! - `error`: what goes wrong loading it, and what to do
//!
//! The files are two catalog entries (`ferrosa models fetch use-multilingual-v3
//! use-multilingual-v3-vocab`); loading them takes about half a second and 70 MB.

pub mod cnn;
mod error;
pub mod npz;
pub mod spm;

pub use error::{EmbedError, VOCAB_MODEL, WEIGHTS_MODEL};

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

/// The encoder: tokenizer and network.
pub struct Encoder {
    tokenizer: spm::Tokenizer,
    network: cnn::Network,
}

/// Longest text encoded, in bytes: the rest is not read (a request, an example or a
/// description is far shorter).
const MAX_TEXT: usize = 2000;

impl Encoder {
    /// Load the two files from the models directory, checking each against the catalog.
    pub fn load(models_dir: &Path) -> Result<Encoder, EmbedError> {
        let file = |name: &str| -> Result<PathBuf, EmbedError> {
            crate::models::resolve(Some(name), models_dir)
                .map(|r| r.path)
                .map_err(|e| EmbedError::Missing {
                    path: format!("{}: {e}", models_dir.display()),
                })
        };
        let weights = file(WEIGHTS_MODEL)?;
        let vocab = file(VOCAB_MODEL)?;
        Encoder::from_files(&weights, &vocab)
    }

    /// Load from the two files as they are (no catalog check).
    pub(crate) fn from_files(weights: &Path, vocab: &Path) -> Result<Encoder, EmbedError> {
        let bytes = std::fs::read(vocab).map_err(|e| EmbedError::Vocabulary {
            path: vocab.display().to_string(),
            message: e.to_string(),
        })?;
        let tokenizer = spm::Tokenizer::from_bytes(&bytes, &vocab.display().to_string())?;
        let network =
            cnn::Network::new(npz::read(weights)?).map_err(|message| EmbedError::Weights {
                path: weights.display().to_string(),
                message,
            })?;
        Ok(Encoder { tokenizer, network })
    }

    /// The token ids of `text` (BOS and EOS included).
    pub fn tokens(&self, text: &str) -> Vec<u32> {
        self.tokenizer.encode(clip(text))
    }

    /// The unit vector of `text`.
    pub fn encode(&self, text: &str) -> Vec<f32> {
        self.network.forward(&self.tokens(text))
    }
}

fn clip(text: &str) -> &str {
    if text.len() <= MAX_TEXT {
        return text;
    }
    let mut end = MAX_TEXT;
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    &text[..end]
}

/// Cosine of two unit vectors.
pub fn cosine(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The process's encoder, loaded once from `models_dir` on first use (and shared by
/// every agent the process runs); the error, if loading failed, is kept and given to
/// each caller.
pub fn shared(models_dir: &Path) -> Result<Arc<Encoder>, EmbedError> {
    static SHARED: OnceLock<Result<Arc<Encoder>, EmbedError>> = OnceLock::new();
    SHARED
        .get_or_init(|| Encoder::load(models_dir).map(Arc::new))
        .clone()
}
