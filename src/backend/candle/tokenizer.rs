//! Tokenization for the candle runtime through the `tokenizers` crate, built from the
//! GGUF file's own vocabulary (no tokenizer.json needed), reproducing llama.cpp's
//! tokenizer for the two kinds of vocabulary ferrosa ships:
//!
//! - **byte-level BPE** ("gpt2", SmolLM2): the file's merges; the pre-tokenizer of its
//!   `tokenizer.ggml.pre` ("smollm": digits one by one, then GPT-2's word regex), then
//!   bytes as GPT-2's printable characters;
//! - **SentencePiece BPE** ("llama", Gemma 3): the file has scores, not merges. A merge of
//!   two pieces into a third is ranked by that third piece's score, highest first, which
//!   is the order llama.cpp's SentencePiece tokenizer merges in. Spaces become "▁" (and
//!   one leads the text when the file says `add_space_prefix`), and characters no piece
//!   holds fall back to byte tokens.
//!
//! As in llama.cpp, user-defined tokens are always matched as wholes, and control tokens
//! (`<|im_start|>`, `<start_of_turn>`) only when the text is a rendered template.
//! Checked against llama.cpp's ids on a corpus in the tests.

use std::collections::HashMap;

use tokenizers::models::bpe::BPE;
use tokenizers::normalizers::{Prepend, Replace, Sequence as Normalizers};
use tokenizers::pre_tokenizers::byte_level::ByteLevel;
use tokenizers::pre_tokenizers::sequence::Sequence;
use tokenizers::pre_tokenizers::split::{Split, SplitPattern};
use tokenizers::{
    AddedToken, NormalizerWrapper, PreTokenizerWrapper, SplitDelimiterBehavior, Tokenizer,
};

use super::super::bpe::pre_tokenizer;
use super::super::gguf::{Gguf, MetaValue};
use super::super::vocab::{TokenKind, Vocab};
use super::super::{TokenId, Tokenize};

/// A model's tokenizer: one that reads control-token texts as those tokens (for rendered
/// templates), one that reads them as plain text (for what anyone wrote).
pub struct HfTokenizer {
    special: Tokenizer,
    plain: Tokenizer,
}

impl HfTokenizer {
    pub fn from_gguf(g: &Gguf, vocab: &Vocab) -> Result<HfTokenizer, String> {
        let tokens = g
            .str_array("tokenizer.ggml.tokens")
            .ok_or("no tokenizer.ggml.tokens")?;
        let model = g.get_str("tokenizer.ggml.model").unwrap_or("");
        let mut plain = match model {
            "gpt2" => byte_level(g, &tokens)?,
            "llama" => sentencepiece(g, &tokens, vocab)?,
            other => return Err(format!("tokenizer model '{other}' is not supported")),
        };
        let added = |kind: TokenKind| -> Vec<AddedToken> {
            tokens
                .iter()
                .enumerate()
                .filter(|(i, t)| vocab.kind(*i as TokenId) == kind && !t.is_empty())
                .map(|(_, t)| {
                    AddedToken::from(t.to_string(), kind == TokenKind::Control).normalized(false)
                })
                .collect()
        };
        plain
            .add_tokens(added(TokenKind::UserDefined))
            .map_err(|e| e.to_string())?;
        let mut special = plain.clone();
        special
            .add_special_tokens(added(TokenKind::Control))
            .map_err(|e| e.to_string())?;
        Ok(HfTokenizer { special, plain })
    }

    /// Tokenize `text`; with `special`, control-token texts become their ids.
    pub fn encode(&self, text: &str, special: bool) -> Vec<TokenId> {
        let t = if special { &self.special } else { &self.plain };
        match t.encode_fast(text, false) {
            Ok(e) => e.get_ids().to_vec(),
            Err(e) => {
                tracing::warn!("tokenizer failed on {} bytes: {e}", text.len());
                Vec::new()
            }
        }
    }
}

impl Tokenize for HfTokenizer {
    fn tokenize(&self, text: &str, special: bool) -> Vec<TokenId> {
        self.encode(text, special)
    }
}

/// Byte-level BPE from the file's merges and its pre-tokenizer.
fn byte_level(g: &Gguf, tokens: &[&str]) -> Result<Tokenizer, String> {
    let merges = g
        .str_array("tokenizer.ggml.merges")
        .ok_or("no tokenizer.ggml.merges")?;
    let merges: Vec<(String, String)> = merges
        .iter()
        .filter_map(|m| m.split_once(' '))
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    let patterns = pre_tokenizer(g)?;
    let bpe = BPE::builder()
        .vocab_and_merges(ids(tokens), merges)
        .build()
        .map_err(|e| e.to_string())?;
    let mut stages = Vec::new();
    for p in patterns {
        let split = Split::new(
            SplitPattern::Regex(p.to_string()),
            SplitDelimiterBehavior::Isolated,
            false,
        )
        .map_err(|e| e.to_string())?;
        stages.push(PreTokenizerWrapper::Split(split));
    }
    stages.push(PreTokenizerWrapper::ByteLevel(ByteLevel::new(
        false, false, false,
    )));
    let mut t = Tokenizer::new(bpe);
    t.with_pre_tokenizer(Some(Sequence::new(stages)));
    Ok(t)
}

/// SentencePiece BPE: merges ranked by the merged piece's score, byte fallback.
fn sentencepiece(g: &Gguf, tokens: &[&str], vocab: &Vocab) -> Result<Tokenizer, String> {
    let scores: Vec<f64> = g
        .get("tokenizer.ggml.scores")
        .and_then(|v| v.as_array())
        .and_then(|a| a.iter().map(|v| v.as_f64()).collect())
        .ok_or("no tokenizer.ggml.scores")?;
    if scores.len() != tokens.len() {
        return Err(format!(
            "{} scores for {} tokens",
            scores.len(),
            tokens.len()
        ));
    }
    // Pieces a merge may make or join: the normal ones (not control, byte or
    // user-defined tokens, which are matched whole or are the fallback).
    let normal = |i: usize| vocab.kind(i as TokenId) == TokenKind::Normal;
    let piece_ids: HashMap<&str, usize> = tokens
        .iter()
        .enumerate()
        .filter(|(i, _)| normal(*i))
        .map(|(i, t)| (*t, i))
        .collect();
    let mut ranked: Vec<(f64, usize, usize, usize)> = Vec::new();
    for (i, piece) in tokens.iter().enumerate().filter(|(i, _)| normal(*i)) {
        for (at, _) in piece.char_indices().skip(1) {
            let (a, b) = piece.split_at(at);
            if let (Some(&ia), Some(&ib)) = (piece_ids.get(a), piece_ids.get(b)) {
                ranked.push((scores[i], i, ia, ib));
            }
        }
    }
    // Highest score first; among one piece's splits, the left part's id decides.
    ranked.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    let merges: Vec<(String, String)> = ranked
        .iter()
        .map(|&(_, _, a, b)| (tokens[a].to_string(), tokens[b].to_string()))
        .collect();
    let unk = g
        .get("tokenizer.ggml.unknown_token_id")
        .and_then(|v| v.as_u64())
        .and_then(|i| tokens.get(i as usize))
        .map(|t| t.to_string());
    let mut builder = BPE::builder()
        .vocab_and_merges(ids(tokens), merges)
        .byte_fallback(true);
    if let Some(unk) = unk {
        builder = builder.unk_token(unk);
    }
    let bpe = builder.build().map_err(|e| e.to_string())?;
    let mut normalizers = Vec::new();
    let prefix = g
        .get("tokenizer.ggml.add_space_prefix")
        .is_none_or(|v| *v == MetaValue::Bool(true));
    if prefix {
        normalizers.push(NormalizerWrapper::Prepend(Prepend::new("▁".into())));
    }
    let replace = Replace::new(" ", "▁").map_err(|e| e.to_string())?;
    normalizers.push(NormalizerWrapper::Replace(replace));
    let mut t = Tokenizer::new(bpe);
    t.with_normalizer(Some(Normalizers::new(normalizers)))
        .map_err(|e| e.to_string())?;
    Ok(t)
}

fn ids(tokens: &[&str]) -> tokenizers::models::bpe::Vocab {
    tokens
        .iter()
        .enumerate()
        .map(|(i, t)| (t.to_string(), i as u32))
        .collect()
}
