//! A byte-level BPE tokenizer ("gpt2" in GGUF) built from the file's own metadata
//! (`tokenizer.ggml.tokens`, `.merges`, `.pre`), for runtimes with no tokenizer library.
//!
//! It reproduces llama.cpp's pre-tokenization for the families ferrosa ships (SmolLM2's
//! "smollm": digits split one by one, then GPT-2's word regex) and is checked against
//! llama.cpp's tokenizer in the tests. SentencePiece vocabularies are not handled here.

use std::collections::HashMap;

use fancy_regex::Regex;

use super::gguf::Gguf;
use super::vocab::{gpt2_byte_decoder, TokenKind, Vocab};
use super::TokenId;

const GPT2_WORDS: &str =
    r"'s|'t|'re|'ve|'m|'ll|'d| ?\p{L}+| ?\p{N}+| ?[^\s\p{L}\p{N}]+|\s+(?!\S)|\s+";

pub struct Bpe {
    /// Pre-tokenizer stages, applied in order; each splits the pieces of the previous one.
    stages: Vec<Regex>,
    ids: HashMap<String, TokenId>,
    ranks: HashMap<(String, String), usize>,
    /// Byte → the printable char GPT-2 writes it as.
    byte_chars: [char; 256],
    /// Special-token texts (control and user-defined), longest first.
    specials: Vec<(String, TokenId)>,
}

/// The regexes llama.cpp splits text with before byte-level BPE, in order (each splits
/// the pieces of the one before, keeping matches and gaps), for the file's
/// `tokenizer.ggml.pre`.
pub(crate) fn pre_tokenizer(g: &Gguf) -> Result<&'static [&'static str], String> {
    match g.get_str("tokenizer.ggml.pre").unwrap_or("default") {
        "smollm" | "starcoder" | "refact" | "command-r" | "codeshell" | "exaone" | "minerva-7b" => {
            Ok(&[r"\p{N}", GPT2_WORDS])
        }
        "gpt-2" | "gpt2" | "default" | "phi-2" => Ok(&[GPT2_WORDS]),
        other => Err(format!("pre-tokenizer '{other}' is not supported")),
    }
}

impl Bpe {
    pub fn from_gguf(g: &Gguf, vocab: &Vocab) -> Result<Bpe, String> {
        let model = g.get_str("tokenizer.ggml.model").unwrap_or("");
        if model != "gpt2" {
            return Err(format!(
                "tokenizer model '{model}' is not byte-level BPE; only 'gpt2' vocabularies are supported by this tokenizer"
            ));
        }
        let tokens = g
            .str_array("tokenizer.ggml.tokens")
            .ok_or("no tokenizer.ggml.tokens")?;
        let merges = g
            .str_array("tokenizer.ggml.merges")
            .ok_or("no tokenizer.ggml.merges")?;
        let stages = pre_tokenizer(g)?
            .iter()
            .map(|p| Regex::new(p).map_err(|e| e.to_string()))
            .collect::<Result<Vec<_>, _>>()?;
        let ids = tokens
            .iter()
            .enumerate()
            .map(|(i, t)| (t.to_string(), i as TokenId))
            .collect();
        let ranks = merges
            .iter()
            .enumerate()
            .filter_map(|(i, m)| {
                let (a, b) = m.split_once(' ')?;
                Some(((a.to_string(), b.to_string()), i))
            })
            .collect();
        let mut byte_chars = ['\0'; 256];
        for (c, b) in gpt2_byte_decoder().iter().enumerate() {
            if let Some(b) = b {
                byte_chars[*b as usize] = char::from_u32(c as u32).unwrap_or('\0');
            }
        }
        let mut specials: Vec<(String, TokenId)> = tokens
            .iter()
            .enumerate()
            .filter(|(i, _)| {
                matches!(
                    vocab.kind(*i as TokenId),
                    TokenKind::Control | TokenKind::UserDefined
                )
            })
            .map(|(i, t)| (t.to_string(), i as TokenId))
            .filter(|(t, _)| !t.is_empty())
            .collect();
        specials.sort_by_key(|(t, _)| std::cmp::Reverse(t.len()));
        Ok(Bpe {
            stages,
            ids,
            ranks,
            byte_chars,
            specials,
        })
    }

    /// Tokenize `text`; with `special`, special-token texts become their ids.
    pub fn encode(&self, text: &str, special: bool) -> Vec<TokenId> {
        let mut out = Vec::with_capacity(text.len() / 3 + 1);
        let mut rest = text;
        while !rest.is_empty() {
            let next = if special {
                self.next_special(rest)
            } else {
                None
            };
            match next {
                Some((at, tok, len)) => {
                    self.encode_plain(&rest[..at], &mut out);
                    out.push(tok);
                    rest = &rest[at + len..];
                }
                None => {
                    self.encode_plain(rest, &mut out);
                    break;
                }
            }
        }
        out
    }

    /// The first special-token occurrence in `s`: (byte offset, id, byte length).
    fn next_special(&self, s: &str) -> Option<(usize, TokenId, usize)> {
        let mut best: Option<(usize, TokenId, usize)> = None;
        for (t, id) in &self.specials {
            if let Some(at) = s.find(t.as_str()) {
                // Earliest wins; at the same offset the longest (sorted first) wins.
                if best.is_none_or(|(b, _, _)| at < b) {
                    best = Some((at, *id, t.len()));
                }
            }
        }
        best
    }

    fn encode_plain(&self, text: &str, out: &mut Vec<TokenId>) {
        if text.is_empty() {
            return;
        }
        let mut pieces = vec![text];
        for re in &self.stages {
            let mut next = Vec::with_capacity(pieces.len() * 2);
            for p in pieces {
                split_keep(re, p, &mut next);
            }
            pieces = next;
        }
        for p in pieces {
            self.encode_word(p, out);
        }
    }

    fn encode_word(&self, word: &str, out: &mut Vec<TokenId>) {
        let mapped: String = word.bytes().map(|b| self.byte_chars[b as usize]).collect();
        if let Some(&id) = self.ids.get(&mapped) {
            out.push(id);
            return;
        }
        let mut symbols: Vec<String> = mapped.chars().map(String::from).collect();
        loop {
            let best = symbols
                .windows(2)
                .enumerate()
                .filter_map(|(i, w)| {
                    self.ranks
                        .get(&(w[0].clone(), w[1].clone()))
                        .map(|&r| (r, i))
                })
                .min();
            let Some((_, i)) = best else { break };
            let merged = format!("{}{}", symbols[i], symbols[i + 1]);
            symbols[i] = merged;
            symbols.remove(i + 1);
        }
        for s in symbols {
            match self.ids.get(&s) {
                Some(&id) => out.push(id),
                // Every single byte char is in a byte-level vocabulary; a symbol missing
                // from it means an inconsistent file, so fall back to its bytes' chars.
                None => out.extend(
                    s.chars()
                        .filter_map(|c| self.ids.get(&c.to_string()).copied()),
                ),
            }
        }
    }
}

impl super::Tokenize for Bpe {
    fn tokenize(&self, text: &str, special: bool) -> Vec<TokenId> {
        self.encode(text, special)
    }
}

/// Split `s` by the matches of `re`, keeping matches and the text between them as pieces.
fn split_keep<'a>(re: &Regex, s: &'a str, out: &mut Vec<&'a str>) {
    let mut last = 0;
    let mut pos = 0;
    while pos < s.len() {
        let Ok(Some(m)) = re.find_from_pos(s, pos) else {
            break;
        };
        if m.start() > last {
            out.push(&s[last..m.start()]);
        }
        if m.end() > m.start() {
            out.push(m.as_str());
            last = m.end();
            pos = m.end();
        } else {
            // An empty match: step past one char so the search advances.
            pos = m.start() + s[m.start()..].chars().next().map_or(1, char::len_utf8);
        }
    }
    if last < s.len() {
        out.push(&s[last..]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_keeps_matches_and_gaps() {
        let re = Regex::new(r"\p{N}").unwrap();
        let mut out = Vec::new();
        split_keep(&re, "ab12 c3", &mut out);
        assert_eq!(out, vec!["ab", "1", "2", " c", "3"]);
        let re = Regex::new(GPT2_WORDS).unwrap();
        let mut out = Vec::new();
        split_keep(&re, "Hello, world  it's", &mut out);
        assert_eq!(out, vec!["Hello", ",", " world", " ", " it", "'s"]);
    }
}
