//! The token table every runtime exposes: the bytes each token stands for, which tokens
//! are control tokens, which end a generation, and whether BOS is prepended.
//!
//! Also streaming detokenization: token bytes are appended to a pending buffer and only
//! complete UTF-8 is emitted, so a character split across byte tokens prints once, whole.
//! Building a `Vocab` from GGUF metadata lives here too, so a runtime without its own
//! tokenizer library (candle) reads the same table llama.cpp does.

use super::gguf::{Gguf, MetaValue};

pub type TokenId = u32;

/// GGUF token types (`tokenizer.ggml.token_type`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TokenKind {
    Normal,
    Unknown,
    /// Markers such as `<|im_start|>`: never shown as text.
    Control,
    /// Added tokens that are still text (e.g. `<tool_call>` in some families).
    UserDefined,
    Unused,
    /// `<0x0A>`-style raw bytes (SentencePiece).
    Byte,
}

impl TokenKind {
    fn from_gguf(v: u64) -> TokenKind {
        match v {
            2 => TokenKind::Unknown,
            3 => TokenKind::Control,
            4 => TokenKind::UserDefined,
            5 => TokenKind::Unused,
            6 => TokenKind::Byte,
            _ => TokenKind::Normal,
        }
    }
}

/// Texts that end a turn in the families llama.cpp knows; a control token with one of
/// these texts ends generation even when the metadata names only one EOS id.
const EOG_TEXTS: &[&str] = &[
    "<|eot_id|>",
    "<|im_end|>",
    "<|end|>",
    "<end_of_turn>",
    "<|endoftext|>",
    "<|eom_id|>",
    "<EOT>",
    "<|end_of_text|>",
    "<|return|>",
    "<|call|>",
    // Fill-in-the-middle padding, repository and file separators also end a generation
    // in llama.cpp (they only appear where a code model starts a new document).
    "<|fim_pad|>",
    "<fim-pad>",
    "<PAD>",
    "<|fim_repo|>",
    "<|repo_name|>",
    "<fim-repo>",
    "<REPO>",
    "<reponame>",
    "<|file_sep|>",
];

/// The token table. Cheap to clone (shared): the decode loop keeps one beside the
/// backend it drives.
#[derive(Debug, Clone)]
pub struct Vocab {
    table: std::sync::Arc<Table>,
}

#[derive(Debug)]
struct Table {
    /// Every token's bytes one after another; token i's are
    /// `bytes[starts[i]..starts[i + 1]]`, `starts` having one entry more than there are
    /// tokens (one buffer, not a vector per token: 0.5 MiB for SmolLM2's 49k instead of
    /// 2.7, 2.6 instead of 15 for Gemma 3's 262k).
    bytes: Vec<u8>,
    starts: Vec<u32>,
    kinds: Vec<TokenKind>,
    eog: Vec<TokenId>,
    bos: Option<TokenId>,
    add_bos: bool,
}

impl Vocab {
    pub fn new(
        pieces: Vec<Vec<u8>>,
        kinds: Vec<TokenKind>,
        mut eog: Vec<TokenId>,
        bos: Option<TokenId>,
        add_bos: bool,
    ) -> Vocab {
        assert_eq!(pieces.len(), kinds.len(), "one kind per token");
        eog.sort_unstable();
        eog.dedup();
        let mut bytes = Vec::with_capacity(pieces.iter().map(Vec::len).sum());
        let mut starts = Vec::with_capacity(pieces.len() + 1);
        starts.push(0);
        for p in &pieces {
            bytes.extend_from_slice(p);
            starts.push(u32::try_from(bytes.len()).expect("a vocabulary under 4 GiB of text"));
        }
        Vocab {
            table: std::sync::Arc::new(Table {
                bytes,
                starts,
                kinds,
                eog,
                bos,
                add_bos,
            }),
        }
    }

    /// A vocabulary of plain text pieces and nothing else (no end token): for tests of
    /// what reads token pieces.
    pub fn from_pieces(pieces: &[&str]) -> Vocab {
        Vocab::new(
            pieces.iter().map(|p| p.as_bytes().to_vec()).collect(),
            vec![TokenKind::Normal; pieces.len()],
            Vec::new(),
            None,
            false,
        )
    }

    pub fn len(&self) -> usize {
        self.table.starts.len() - 1
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The bytes a token stands for; control tokens give their marker text.
    pub fn piece(&self, id: TokenId) -> &[u8] {
        let t = &self.table;
        match (t.starts.get(id as usize), t.starts.get(id as usize + 1)) {
            (Some(&start), Some(&end)) => &t.bytes[start as usize..end as usize],
            _ => &[],
        }
    }

    pub fn kind(&self, id: TokenId) -> TokenKind {
        self.table
            .kinds
            .get(id as usize)
            .copied()
            .unwrap_or(TokenKind::Unknown)
    }

    pub fn is_eog(&self, id: TokenId) -> bool {
        self.table.eog.binary_search(&id).is_ok()
    }

    pub fn eog(&self) -> &[TokenId] {
        &self.table.eog
    }

    /// The token to prepend to a fresh context, if the model wants one.
    pub fn bos(&self) -> Option<TokenId> {
        self.table.bos.filter(|_| self.table.add_bos)
    }

    /// Id of the token whose text is exactly `text`, if any (linear: not for hot paths).
    pub fn find(&self, text: &str) -> Option<TokenId> {
        (0..self.len() as TokenId).find(|&id| self.piece(id) == text.as_bytes())
    }

    /// Bytes of a token sequence, control tokens included (for logs and tests).
    pub fn decode_lossy(&self, ids: &[TokenId]) -> String {
        let bytes: Vec<u8> = ids.iter().flat_map(|&t| self.piece(t).to_vec()).collect();
        String::from_utf8_lossy(&bytes).into_owned()
    }

    /// The table a GGUF file describes (`tokenizer.ggml.*`), for byte-level BPE ("gpt2")
    /// and SentencePiece ("llama") vocabularies.
    pub fn from_gguf(g: &Gguf) -> Result<Vocab, String> {
        let tokens = g
            .str_array("tokenizer.ggml.tokens")
            .ok_or("no tokenizer.ggml.tokens")?;
        let model = g.get_str("tokenizer.ggml.model").unwrap_or("gpt2");
        let kinds: Vec<TokenKind> = match g.get("tokenizer.ggml.token_type") {
            Some(MetaValue::Array(a)) if a.len() == tokens.len() => a
                .iter()
                .map(|v| TokenKind::from_gguf(v.as_u64().unwrap_or(1)))
                .collect(),
            _ => vec![TokenKind::Normal; tokens.len()],
        };
        let byte_decoder = gpt2_byte_decoder();
        let pieces = tokens
            .iter()
            .zip(&kinds)
            .map(|(t, k)| match (model, k) {
                (_, TokenKind::Control | TokenKind::UserDefined | TokenKind::Unused) => {
                    t.as_bytes().to_vec()
                }
                ("gpt2", _) => t
                    .chars()
                    .map(|c| byte_decoder.get(c as usize).copied().flatten())
                    .collect::<Option<Vec<u8>>>()
                    .unwrap_or_else(|| t.as_bytes().to_vec()),
                (_, TokenKind::Byte) => parse_byte_token(t)
                    .map(|b| vec![b])
                    .unwrap_or_else(|| t.as_bytes().to_vec()),
                _ => t.replace('\u{2581}', " ").into_bytes(),
            })
            .collect::<Vec<_>>();
        let id = |key: &str| g.get_u64(key).map(|v| v as TokenId);
        let mut eog: Vec<TokenId> = ["eos", "eot", "eom"]
            .iter()
            .filter_map(|k| id(&format!("tokenizer.ggml.{k}_token_id")))
            .collect();
        for (i, (t, k)) in tokens.iter().zip(&kinds).enumerate() {
            if matches!(k, TokenKind::Control | TokenKind::UserDefined) && EOG_TEXTS.contains(t) {
                eog.push(i as TokenId);
            }
        }
        let add_bos = g
            .get("tokenizer.ggml.add_bos_token")
            .map(|v| matches!(v, MetaValue::Bool(true)))
            .unwrap_or(model == "llama");
        Ok(Vocab::new(
            pieces,
            kinds,
            eog,
            id("tokenizer.ggml.bos_token_id"),
            add_bos,
        ))
    }
}

fn parse_byte_token(t: &str) -> Option<u8> {
    let hex = t.strip_prefix("<0x")?.strip_suffix('>')?;
    u8::from_str_radix(hex, 16).ok()
}

/// GPT-2's byte-level BPE writes every byte as a printable char: printable Latin-1 bytes
/// as themselves, the rest shifted to U+0100 and up. Index: char code, value: the byte.
pub(crate) fn gpt2_byte_decoder() -> Vec<Option<u8>> {
    let mut table = vec![None; 512];
    let mut shifted = 0u32;
    for b in 0u32..256 {
        let printable = (0x21..=0x7e).contains(&b) || (0xa1..=0xac).contains(&b) || b >= 0xae;
        let c = if printable {
            b
        } else {
            shifted += 1;
            255 + shifted
        };
        table[c as usize] = Some(b as u8);
    }
    table
}

/// Turns a token stream into text, holding back bytes of an incomplete UTF-8 character.
#[derive(Debug, Default)]
pub struct Detokenizer {
    pending: Vec<u8>,
    show_control: bool,
}

impl Detokenizer {
    pub fn new(show_control: bool) -> Detokenizer {
        Detokenizer {
            pending: Vec::with_capacity(16),
            show_control,
        }
    }

    /// Append the text of `id` to `out`: whatever complete characters are now available.
    pub fn push(&mut self, vocab: &Vocab, id: TokenId, out: &mut String) {
        if !self.show_control && vocab.kind(id) == TokenKind::Control {
            return;
        }
        self.pending.extend_from_slice(vocab.piece(id));
        self.drain(out, false);
    }

    /// Emit whatever is left, invalid tails as U+FFFD.
    pub fn finish(&mut self, out: &mut String) {
        self.drain(out, true);
    }

    fn drain(&mut self, out: &mut String, last: bool) {
        let mut start = 0;
        loop {
            match std::str::from_utf8(&self.pending[start..]) {
                Ok(s) => {
                    out.push_str(s);
                    start = self.pending.len();
                    break;
                }
                Err(e) => {
                    let valid = e.valid_up_to();
                    // Safe: `valid_up_to` bytes were just checked to be UTF-8.
                    out.push_str(
                        std::str::from_utf8(&self.pending[start..start + valid])
                            .unwrap_or_default(),
                    );
                    start += valid;
                    match e.error_len() {
                        Some(bad) => {
                            out.push('\u{FFFD}');
                            start += bad;
                        }
                        None if last => {
                            out.push('\u{FFFD}');
                            start = self.pending.len();
                            break;
                        }
                        None => break,
                    }
                }
            }
        }
        self.pending.drain(..start);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vocab() -> Vocab {
        let pieces = vec![
            b"<|im_end|>".to_vec(),
            "h\u{e9}".as_bytes().to_vec(),
            vec![0xF0, 0x9F],
            vec![0x98, 0x80],
            vec![0xFF],
        ];
        let kinds = vec![
            TokenKind::Control,
            TokenKind::Normal,
            TokenKind::Byte,
            TokenKind::Byte,
            TokenKind::Byte,
        ];
        Vocab::new(pieces, kinds, vec![0], None, false)
    }

    #[test]
    fn split_characters_are_emitted_once_whole() {
        let v = vocab();
        let mut d = Detokenizer::new(false);
        let mut out = String::new();
        d.push(&v, 1, &mut out);
        assert_eq!(out, "h\u{e9}");
        d.push(&v, 2, &mut out);
        assert_eq!(out, "h\u{e9}", "half an emoji must wait");
        d.push(&v, 3, &mut out);
        assert_eq!(out, "h\u{e9}\u{1F600}");
        d.push(&v, 0, &mut out);
        assert_eq!(out, "h\u{e9}\u{1F600}", "control tokens are not text");
    }

    #[test]
    fn invalid_bytes_become_replacement_chars() {
        let v = vocab();
        let mut d = Detokenizer::new(true);
        let mut out = String::new();
        d.push(&v, 4, &mut out);
        d.push(&v, 2, &mut out);
        d.finish(&mut out);
        assert_eq!(out, "\u{FFFD}\u{FFFD}");
    }

    #[test]
    fn gpt2_byte_table_is_a_bijection() {
        let t = gpt2_byte_decoder();
        let mut seen = [false; 256];
        for b in t.iter().flatten() {
            assert!(!seen[*b as usize]);
            seen[*b as usize] = true;
        }
        assert!(seen.iter().all(|s| *s));
        assert_eq!(t['\u{120}' as usize], Some(b' '));
        assert_eq!(t['\u{10a}' as usize], Some(b'\n'));
    }
}
