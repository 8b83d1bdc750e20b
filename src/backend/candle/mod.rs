//! A pure-Rust runtime on candle: llama (SmolLM2) and Gemma 3 with quantized weights
//! read from GGUF (`model`: prompts as tensors; `rows`: a few tokens at a time, each
//! row as if alone; `matvec`: the kernels for SmolLM2's weight formats, Q4_1 and Q8_0),
//! tokenized through the `tokenizers` crate built from the file's vocabulary
//! (`tokenizer`).

mod matvec;
mod model;
mod rows;
mod tokenizer;

use std::fs::File;
use std::io::BufReader;
use std::sync::{Arc, Once};

use candle_core::quantized::gguf_file;

use self::model::{Family, Model};
pub use self::tokenizer::HfTokenizer;
use super::vocab::Vocab;
use super::{Backend, BackendError, ChatTemplate, Gguf, LoadOptions, TokenId, Tokenize};

const NAME: &str = "candle";

fn err(e: impl std::fmt::Display) -> BackendError {
    BackendError::Eval {
        backend: NAME,
        reason: e.to_string(),
    }
}

pub struct Candle {
    model: Model,
    tokenizer: Arc<HfTokenizer>,
    vocab: Vocab,
    template: ChatTemplate,
    n_ctx: usize,
    n_past: usize,
    logits: Vec<f32>,
}

impl Candle {
    pub fn load(gguf: &Gguf, opts: &LoadOptions) -> Result<Candle, BackendError> {
        let fail = |reason: String| BackendError::Load {
            backend: NAME,
            path: opts.path.clone(),
            reason,
        };
        let arch = gguf.architecture().unwrap_or("unknown");
        let Some(family) = Family::of(arch) else {
            return Err(BackendError::Architecture {
                backend: NAME,
                arch: arch.to_string(),
                supported: "llama (SmolLM2), gemma3; use --backend llama for others",
            });
        };
        static THREADS: Once = Once::new();
        let threads = opts.threads.max(1);
        // candle's CPU kernels run on rayon's global pool, which can be sized only once.
        THREADS.call_once(|| {
            let _ = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build_global();
        });
        let vocab = Vocab::from_gguf(gguf).map_err(fail)?;
        let tokenizer = Arc::new(HfTokenizer::from_gguf(gguf, &vocab).map_err(fail)?);
        let template = ChatTemplate::for_model(gguf, opts.family.as_deref())?;
        let mut reader = BufReader::new(File::open(&opts.path).map_err(|e| fail(e.to_string()))?);
        let content = gguf_file::Content::read(&mut reader).map_err(|e| fail(e.to_string()))?;
        let train_ctx = gguf.context_length().unwrap_or(2048) as usize;
        let n_ctx = opts.max_context.min(train_ctx).max(16);
        let model = Model::load(
            family,
            gguf,
            &content,
            &mut reader,
            (n_ctx, opts.dense_weights),
        )
        .map_err(fail)?;
        Ok(Candle {
            model,
            tokenizer,
            logits: vec![0.0; vocab.len()],
            vocab,
            template,
            n_ctx,
            n_past: 0,
        })
    }
}

impl Backend for Candle {
    fn name(&self) -> &'static str {
        NAME
    }

    fn vocab(&self) -> &Vocab {
        &self.vocab
    }

    fn chat_template(&self) -> &ChatTemplate {
        &self.template
    }

    fn context_len(&self) -> usize {
        self.n_ctx
    }

    fn tokenize(&self, text: &str, special: bool) -> Result<Vec<TokenId>, BackendError> {
        Ok(self.tokenizer.encode(text, special))
    }

    fn tokenizer(&self) -> Arc<dyn Tokenize> {
        self.tokenizer.clone()
    }

    fn forward(&mut self, keep: usize, tokens: &[TokenId]) -> Result<&mut [f32], BackendError> {
        let _span = tracing::trace_span!("forward", n = tokens.len()).entered();
        super::forward_last(self, |b| &mut b.logits, keep, tokens)?;
        Ok(&mut self.logits)
    }

    fn exact_rows_below(&self) -> Option<usize> {
        Some(rows::ROWS_UNTIL)
    }

    fn forward_each(
        &mut self,
        keep: usize,
        tokens: &[TokenId],
        from: usize,
        each: &mut dyn FnMut(usize, &[f32]),
    ) -> Result<(), BackendError> {
        let _span = tracing::trace_span!("forward_each", n = tokens.len()).entered();
        if tokens.is_empty() {
            return Err(err("nothing to evaluate: no tokens given"));
        }
        let (held, limit, n_vocab) = (self.n_past, self.n_ctx, self.vocab.len());
        let keep = super::admit(keep, held, tokens.len(), tokens.iter(), limit, n_vocab)?;
        // Dropping the tail of the cache is just forgetting it: positions past `keep`
        // are overwritten by the next append.
        self.n_past = keep;
        for (c, chunk) in tokens.chunks(512).enumerate() {
            let offset = c * 512;
            // Rows from `from` on, or the last one only (no row wanted in this chunk).
            let first = from.saturating_sub(offset).min(chunk.len() - 1);
            let rows = match chunk.len() < rows::ROWS_UNTIL {
                true => self.model.forward_rows(chunk, self.n_past, first),
                false => self.model.forward(chunk, self.n_past, first),
            }
            .map_err(err)?;
            self.n_past += chunk.len();
            if offset + chunk.len() <= from {
                continue;
            }
            // The output's rows may be padded past the vocabulary.
            let width = rows.len() / (chunk.len() - first);
            for (r, row) in rows.chunks(width).enumerate() {
                each(offset + first + r, &row[..n_vocab]);
            }
        }
        Ok(())
    }
}
