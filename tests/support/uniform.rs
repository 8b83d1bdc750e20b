//! A backend with a vocabulary and no weights: every forward pass returns the same
//! logits (equal, or with chosen tokens favoured), so a sampler at temperature 1 picks
//! among whatever a grammar allows. Property tests and decoding benchmarks use it to
//! drive the real constrained-decoding path without running a model.

use std::sync::Arc;

use ferrosa::backend::bpe::Bpe;
use ferrosa::backend::template::{ChatTemplate, TemplateOrigin};
use ferrosa::backend::vocab::{TokenKind, Vocab};
use ferrosa::backend::{Backend, BackendError, Gguf, TokenId, Tokenize};

use super::synthetic::{Greedy, Synthetic};

pub struct Uniform {
    vocab: Vocab,
    tokenizer: Arc<dyn Tokenize>,
    template: ChatTemplate,
    /// What every forward pass returns.
    base: Vec<f32>,
    logits: Vec<f32>,
    context: usize,
}

impl Uniform {
    /// The vocabulary and tokenizer of a GGUF file (byte-level BPE), without its weights.
    pub fn from_gguf(g: &Gguf) -> Result<Uniform, BackendError> {
        let fail = |reason: String| BackendError::Load {
            backend: "uniform",
            path: g.path.clone(),
            reason,
        };
        let vocab = Vocab::from_gguf(g).map_err(fail)?;
        let bpe = Bpe::from_gguf(g, &vocab).map_err(fail)?;
        let template = ChatTemplate::for_model(g, None)?;
        Ok(Uniform {
            base: vec![0.0; vocab.len()],
            logits: vec![0.0; vocab.len()],
            vocab,
            tokenizer: Arc::new(bpe),
            template,
            context: 1 << 20,
        })
    }

    /// The synthetic model's vocabulary and ChatML template (no weights, no file).
    pub fn synthetic() -> Uniform {
        let s = Synthetic::chatml();
        Uniform {
            base: vec![0.0; s.vocab.len()],
            logits: vec![0.0; s.vocab.len()],
            vocab: s.vocab,
            tokenizer: s.tokenizer,
            template: s.template,
            context: 1 << 20,
        }
    }

    /// Add `bonus` to the logit of every token whose bytes all satisfy `pick` (a model
    /// with a taste, e.g. for writing on and on).
    pub fn favouring(mut self, pick: impl Fn(&[u8]) -> bool, bonus: f32) -> Uniform {
        for id in 0..self.vocab.len() as TokenId {
            let p = self.vocab.piece(id);
            if !p.is_empty() && pick(p) {
                self.base[id as usize] += bonus;
            }
        }
        self
    }

    /// Every single byte as a token, then `control` tokens (the first is EOS), then
    /// `added` tokens (user-defined: markers that are still text, like Qwen's
    /// `<tool_call>`).
    pub fn bytes_with_specials(control: &[&str], added: &[&str]) -> Uniform {
        let mut pieces: Vec<Vec<u8>> = (0..=255u8).map(|b| vec![b]).collect();
        let mut kinds = vec![TokenKind::Byte; 256];
        for s in control {
            pieces.push(s.as_bytes().to_vec());
            kinds.push(TokenKind::Control);
        }
        for s in added {
            pieces.push(s.as_bytes().to_vec());
            kinds.push(TokenKind::UserDefined);
        }
        let eos = if control.is_empty() {
            vec![]
        } else {
            vec![256]
        };
        let vocab = Vocab::new(pieces, kinds, eos, None, false);
        let template = ChatTemplate::new(
            "{% for m in messages %}{{ m.content }}{% endfor %}",
            TemplateOrigin::Fallback("chatml"),
            "",
            "",
        )
        .expect("static template compiles");
        Uniform {
            base: vec![0.0; vocab.len()],
            logits: vec![0.0; vocab.len()],
            tokenizer: Arc::new(Greedy(vocab.clone())),
            vocab,
            template,
            context: 1 << 20,
        }
    }
}

impl Backend for Uniform {
    fn name(&self) -> &'static str {
        "uniform"
    }

    fn vocab(&self) -> &Vocab {
        &self.vocab
    }

    fn chat_template(&self) -> &ChatTemplate {
        &self.template
    }

    fn context_len(&self) -> usize {
        self.context
    }

    fn tokenize(&self, text: &str, special: bool) -> Result<Vec<TokenId>, BackendError> {
        Ok(self.tokenizer.tokenize(text, special))
    }

    fn tokenizer(&self) -> Arc<dyn Tokenize> {
        self.tokenizer.clone()
    }

    fn forward(&mut self, _keep: usize, tokens: &[TokenId]) -> Result<&mut [f32], BackendError> {
        if let Some(&bad) = tokens.iter().find(|&&t| t as usize >= self.vocab.len()) {
            return Err(BackendError::BadToken(bad));
        }
        self.logits.copy_from_slice(&self.base);
        Ok(&mut self.logits)
    }
}
