//! A backend with a real vocabulary and no weights: every forward pass returns equal
//! logits, so a sampler at temperature 1 picks uniformly among whatever a grammar allows.
//! Property tests and decoding benchmarks use it to drive the real constrained-decoding
//! path over a real tokenizer without running a model.

use std::sync::Arc;

use super::bpe::Bpe;
use super::template::{ChatTemplate, TemplateOrigin};
use super::vocab::{TokenKind, Vocab};
use super::{Backend, BackendError, Gguf, TokenId, Tokenize};

pub struct Uniform {
    vocab: Vocab,
    tokenizer: Arc<dyn Tokenize>,
    template: ChatTemplate,
    logits: Vec<f32>,
    context: usize,
}

/// Greedy longest-match tokenization over the vocabulary: exact for synthetic byte-level
/// vocabularies, where every byte is a token.
struct Greedy(Vocab);

impl Tokenize for Greedy {
    fn tokenize(&self, text: &str, special: bool) -> Vec<TokenId> {
        let bytes = text.as_bytes();
        let mut out = Vec::new();
        let mut i = 0;
        while i < bytes.len() {
            let mut best: Option<(usize, TokenId)> = None;
            for id in 0..self.0.len() as TokenId {
                let p = self.0.piece(id);
                let is_special = self.0.kind(id) == TokenKind::Control;
                if p.is_empty() || (is_special && !special) {
                    continue;
                }
                if bytes[i..].starts_with(p) && best.is_none_or(|(l, _)| p.len() > l) {
                    best = Some((p.len(), id));
                }
            }
            match best {
                Some((l, id)) => {
                    out.push(id);
                    i += l;
                }
                None => i += 1,
            }
        }
        out
    }
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
            logits: vec![0.0; vocab.len()],
            vocab,
            tokenizer: Arc::new(bpe),
            template,
            context: 1 << 20,
        })
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
        self.logits.fill(0.0);
        Ok(&mut self.logits)
    }
}
