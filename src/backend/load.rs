//! Loading a model file with the chosen runtime.

use super::options::{BackendKind, LoadOptions};
use super::{Backend, BackendError, Gguf};

/// Load `opts.path` with the chosen runtime. The file is validated first (GGUF magic,
/// version, tensor data present) so a bad file is a clear error, not a runtime crash.
pub fn load(kind: BackendKind, opts: &LoadOptions) -> Result<Box<dyn Backend>, BackendError> {
    let gguf = Gguf::open(&opts.path)?;
    match kind {
        #[cfg(feature = "llama")]
        BackendKind::Llama => Ok(Box::new(super::llama::LlamaCpp::load(&gguf, opts)?)),
        #[cfg(not(feature = "llama"))]
        BackendKind::Llama => Err(BackendError::NotCompiled("llama")),
        #[cfg(feature = "candle")]
        BackendKind::Candle => Ok(Box::new(super::candle::Candle::load(&gguf, opts)?)),
        #[cfg(not(feature = "candle"))]
        BackendKind::Candle => Err(BackendError::NotCompiled("candle")),
    }
}

/// Load only `opts.path`'s vocabulary and chat template (no weights): for rendering and
/// tokenizing prompts that a server evaluates.
pub fn load_vocabulary(opts: &LoadOptions) -> Result<Box<dyn Backend>, BackendError> {
    let gguf = Gguf::open(&opts.path)?;
    #[cfg(feature = "llama")]
    {
        Ok(Box::new(super::llama::LlamaVocab::load(&gguf, opts)?))
    }
    #[cfg(not(feature = "llama"))]
    {
        let _ = gguf;
        Err(BackendError::NotCompiled("llama"))
    }
}
