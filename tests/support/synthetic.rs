//! A synthetic model's text side, so tests run the real tokenizer-facing code (templates,
//! grammars, fast-forward, the agent loop) without any weights: every byte is a token,
//! ChatML's markers are control tokens, and a few multi-byte pieces make tokenization
//! merge as a BPE's does. Tokenization is greedy longest match (exact for this kind of
//! vocabulary).

use std::sync::Arc;

use ferrosa::backend::template::TemplateOrigin;
use ferrosa::backend::vocab::TokenKind;
use ferrosa::backend::{ChatTemplate, TokenId, Tokenize, Vocab};

const CHATML: &str = include_str!("../../prompts/templates/chatml.jinja");

/// Multi-byte pieces beside the 256 bytes: JSON and envelope fragments and a few words.
const PIECES: &[&str] = &[
    "<tool_call>",
    "</tool_call>",
    "{\"name\": \"",
    "\", \"arguments\": {",
    "\": ",
    ", \"",
    "\"}",
    "}}",
    "}]",
    "\n]",
    ",\n",
    "the",
    " the",
    " turtle",
    "turtle",
    "ros_",
    "_list",
    "reply",
    "text",
    " is",
    " at",
];

/// The vocabulary, tokenizer and template of the synthetic model.
pub struct Synthetic {
    pub vocab: Vocab,
    pub tokenizer: Arc<dyn Tokenize>,
    pub template: ChatTemplate,
}

impl Synthetic {
    pub fn chatml() -> Synthetic {
        let mut pieces: Vec<Vec<u8>> = (0..=255u8).map(|b| vec![b]).collect();
        let mut kinds = vec![TokenKind::Byte; 256];
        for s in ["<|endoftext|>", "<|im_start|>", "<|im_end|>"] {
            pieces.push(s.as_bytes().to_vec());
            kinds.push(TokenKind::Control);
        }
        for p in PIECES {
            pieces.push(p.as_bytes().to_vec());
            kinds.push(TokenKind::Normal);
        }
        let vocab = Vocab::new(pieces, kinds, vec![256, 258], None, false);
        let template = ChatTemplate::new(CHATML, TemplateOrigin::Fallback("chatml"), "", "")
            .expect("the ChatML template compiles");
        Synthetic {
            tokenizer: Arc::new(Greedy(vocab.clone())),
            vocab,
            template,
        }
    }
}

/// Greedy longest-match tokenization over the vocabulary: exact for vocabularies where
/// every byte is a token.
pub struct Greedy(pub Vocab);

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
