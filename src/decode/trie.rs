//! llguidance's view of a model's vocabulary: a token trie built from the backend's
//! `Vocab` (the same bytes whichever runtime loaded the model), with special tokens marked
//! so a grammar can name them (`<|im_end|>`) but never spell them as text, and the
//! model's own tokenizer for text the grammar forces, so fast-forwarded tokens are the
//! ones the model would have produced.

use std::sync::Arc;

use llguidance::toktrie::{TokEnv, TokRxInfo, TokTrie, TokenizerEnv};

use crate::backend::vocab::TokenKind;
use crate::backend::{TokenId, Tokenize, Vocab};

pub(crate) struct TokenEnv {
    trie: TokTrie,
    tokenizer: Arc<dyn Tokenize>,
}

impl TokenEnv {
    /// Build once per model (the trie costs ≈ 50 ms at a 49k vocabulary).
    pub fn shared(vocab: &Vocab, tokenizer: Arc<dyn Tokenize>) -> TokEnv {
        let words: Vec<Vec<u8>> = (0..vocab.len() as TokenId)
            .map(|id| {
                let piece = vocab.piece(id);
                if is_special(vocab, id) {
                    // toktrie's convention: 0xFF then the marker text.
                    let mut w = Vec::with_capacity(piece.len() + 1);
                    w.push(0xFF);
                    w.extend_from_slice(piece);
                    w
                } else {
                    piece.to_vec()
                }
            })
            .collect();
        let eog = vocab.eog();
        let info = TokRxInfo {
            vocab_size: vocab.len() as u32,
            tok_eos: eog.first().copied().unwrap_or(0),
            tok_bos: vocab.bos(),
            tok_pad: None,
            tok_unk: None,
            tok_end_of_turn: None,
        };
        let trie = TokTrie::from(&info, &words).with_eos_tokens(eog);
        Arc::new(TokenEnv { trie, tokenizer })
    }
}

/// Control tokens and marker-shaped added tokens are special: the grammar may require
/// them by name, but no text rule can produce them.
fn is_special(vocab: &Vocab, id: TokenId) -> bool {
    match vocab.kind(id) {
        TokenKind::Control => true,
        TokenKind::UserDefined | TokenKind::Unused => {
            let p = vocab.piece(id);
            p.len() > 2 && p.starts_with(b"<") && p.ends_with(b">")
        }
        _ => false,
    }
}

impl TokenizerEnv for TokenEnv {
    fn tok_trie(&self) -> &TokTrie {
        &self.trie
    }

    fn tokenize_bytes(&self, s: &[u8]) -> Vec<u32> {
        match std::str::from_utf8(s) {
            Ok(text) => self.tokenizer.tokenize(text, false),
            // Forced bytes that split a character cannot go through the real tokenizer;
            // the trie's greedy split is exact for bytes.
            Err(_) => self.trie.greedy_tokenize(s),
        }
    }

    fn tokenize_bytes_special(&self, s: &[u8]) -> Vec<u32> {
        match std::str::from_utf8(s) {
            Ok(text) => self.tokenizer.tokenize(text, true),
            Err(_) => self.trie.greedy_tokenize(s),
        }
    }
}
