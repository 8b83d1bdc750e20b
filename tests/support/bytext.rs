//! A backend whose next-token logits are a function of the text so far: a test writes
//! the "model" as a rule from context to preferred continuations, and the real template,
//! grammar, decode loop and strategies run over it (scripted logits, no weights).

use std::sync::Arc;

use ferrosa::backend::{Backend, BackendError, ChatTemplate, TokenId, Tokenize, Vocab};

use super::synthetic::Synthetic;

/// From the whole context (prompt and what the turn wrote, special tokens spelled out) to
/// continuations the model likes and how much (a log-probability-like score); every
/// other token gets `floor`.
pub type Rule = dyn Fn(&str) -> Vec<(String, f32)> + Send;

pub struct ByText {
    vocab: Vocab,
    tokenizer: Arc<dyn Tokenize>,
    template: ChatTemplate,
    history: Vec<TokenId>,
    logits: Vec<f32>,
    rule: Box<Rule>,
    floor: f32,
}

impl ByText {
    pub fn new(rule: impl Fn(&str) -> Vec<(String, f32)> + Send + 'static) -> ByText {
        let s = Synthetic::chatml();
        ByText {
            logits: vec![0.0; s.vocab.len()],
            vocab: s.vocab,
            tokenizer: s.tokenizer,
            template: s.template,
            history: Vec::new(),
            rule: Box::new(rule),
            floor: -20.0,
        }
    }
}

impl Backend for ByText {
    fn name(&self) -> &'static str {
        "by-text"
    }
    fn vocab(&self) -> &Vocab {
        &self.vocab
    }
    fn chat_template(&self) -> &ChatTemplate {
        &self.template
    }
    fn context_len(&self) -> usize {
        1 << 16
    }
    fn tokenize(&self, text: &str, special: bool) -> Result<Vec<TokenId>, BackendError> {
        Ok(self.tokenizer.tokenize(text, special))
    }
    fn tokenizer(&self) -> Arc<dyn Tokenize> {
        self.tokenizer.clone()
    }
    fn forward(&mut self, keep: usize, tokens: &[TokenId]) -> Result<&mut [f32], BackendError> {
        self.history.truncate(keep);
        self.history.extend_from_slice(tokens);
        let text = self.vocab.decode_lossy(&self.history);
        self.logits.fill(self.floor);
        for (cont, score) in (self.rule)(&text) {
            let cont = cont.as_bytes();
            // The longest token that starts the continuation carries its score; shorter
            // ones a little less, so the continuation is written as a BPE would.
            for id in 0..self.vocab.len() as TokenId {
                let p = self.vocab.piece(id);
                if !p.is_empty() && cont.starts_with(p) {
                    let s = score - 0.01 * (cont.len() - p.len()) as f32;
                    let l = &mut self.logits[id as usize];
                    *l = l.max(s);
                }
            }
        }
        Ok(&mut self.logits)
    }
}
