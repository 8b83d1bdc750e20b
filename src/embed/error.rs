//! What goes wrong loading the sentence encoder, each with what to do next, and the
//! catalog names of its two files.

/// The catalog names of the weights and the vocabulary.
pub const WEIGHTS_MODEL: &str = "use-multilingual-v3";
pub const VOCAB_MODEL: &str = "use-multilingual-v3-vocab";

#[derive(Debug, Clone, thiserror::Error)]
pub enum EmbedError {
    #[error("the sentence encoder is not installed ({path}): run `ferrosa models fetch {WEIGHTS_MODEL} {VOCAB_MODEL}`")]
    Missing { path: String },
    #[error("the sentence encoder's weights {path} are unusable ({message}): fetch them again with `ferrosa models fetch --force {WEIGHTS_MODEL}`")]
    Weights { path: String, message: String },
    #[error("the sentence encoder's vocabulary {path} is unusable ({message}): fetch it again with `ferrosa models fetch --force {VOCAB_MODEL}`")]
    Vocabulary { path: String, message: String },
}
