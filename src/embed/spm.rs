//! A SentencePiece unigram tokenizer read from its `.model` file (a protobuf): the
//! `nmt_nfkc` normaliser from the model's precompiled character map (a darts-clone
//! double-array trie over UTF-8 bytes and a table of replacements), whitespace escaped as
//! U+2581 with a leading one added and runs collapsed, then the unigram lattice's best
//! path (Viterbi) over the vocabulary's pieces and scores. The same ids the reference
//! library gives for the sentence encoder's vocabulary.

use std::collections::HashMap;

use super::error::EmbedError;

const UNK: u32 = 0;
pub const BOS: u32 = 1;
pub const EOS: u32 = 2;
/// The escaped space.
const SPACE: &str = "\u{2581}";

pub(crate) struct Tokenizer {
    scores: Vec<f32>,
    /// Each piece and each prefix of one (in whole characters): the piece's id + 1, or
    /// 0 for a prefix that is no piece (the walk goes on past it).
    prefixes: HashMap<Box<str>, u32>,
    /// The longest piece, in characters.
    max_chars: usize,
    unk_score: f32,
    normaliser: Normaliser,
}

/// A protobuf field's payload.
enum Field<'a> {
    Bytes(&'a [u8]),
    Fixed32([u8; 4]),
    Other,
}

/// The fields of one protobuf message, in order, as (number, payload).
fn fields(mut data: &[u8]) -> Result<Vec<(u64, Field<'_>)>, String> {
    fn varint(data: &mut &[u8]) -> Result<u64, String> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let (&b, rest) = data.split_first().ok_or("a varint is cut short")?;
            *data = rest;
            v |= u64::from(b & 0x7f) << shift;
            if b & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err("a varint is too long".into())
    }
    let mut out = Vec::new();
    while !data.is_empty() {
        let tag = varint(&mut data)?;
        let field = match tag & 7 {
            0 => {
                varint(&mut data)?;
                Field::Other
            }
            1 => {
                data = data.get(8..).ok_or("a fixed64 is cut short")?;
                Field::Other
            }
            2 => {
                let len = varint(&mut data)? as usize;
                let bytes = data.get(..len).ok_or("a field is cut short")?;
                data = &data[len..];
                Field::Bytes(bytes)
            }
            5 => {
                let b = data.get(..4).ok_or("a fixed32 is cut short")?;
                data = &data[4..];
                Field::Fixed32([b[0], b[1], b[2], b[3]])
            }
            w => return Err(format!("wire type {w}")),
        };
        out.push((tag >> 3, field));
    }
    Ok(out)
}

impl Tokenizer {
    /// Read a `.model` file's bytes.
    pub(crate) fn from_bytes(data: &[u8], origin: &str) -> Result<Tokenizer, EmbedError> {
        let bad = |message: String| EmbedError::Vocabulary {
            path: origin.to_string(),
            message,
        };
        let top = fields(data).map_err(&bad)?;
        let mut pieces: Vec<String> = Vec::new();
        let mut scores = Vec::new();
        let mut charsmap: &[u8] = &[];
        for (number, field) in &top {
            match (number, field) {
                (1, Field::Bytes(b)) => {
                    let mut piece = None;
                    let mut score = 0.0;
                    for (n, f) in fields(b).map_err(&bad)? {
                        match (n, f) {
                            (1, Field::Bytes(p)) => {
                                piece = Some(String::from_utf8_lossy(p).into_owned())
                            }
                            (2, Field::Fixed32(s)) => score = f32::from_le_bytes(s),
                            _ => {}
                        }
                    }
                    if let Some(p) = piece {
                        pieces.push(p);
                        scores.push(score);
                    }
                }
                (3, Field::Bytes(b)) => {
                    for (n, f) in fields(b).map_err(&bad)? {
                        if let (2, Field::Bytes(m)) = (n, f) {
                            charsmap = m;
                        }
                    }
                }
                _ => {}
            }
        }
        if pieces.len() <= EOS as usize {
            return Err(bad(format!("{} pieces", pieces.len())));
        }
        let mut prefixes: HashMap<Box<str>, u32> = HashMap::new();
        let mut max_chars = 1;
        for (id, piece) in pieces.iter().enumerate() {
            let ends: Vec<usize> = piece.char_indices().map(|(i, _)| i).skip(1).collect();
            max_chars = max_chars.max(ends.len() + 1);
            for end in ends {
                prefixes.entry(piece[..end].into()).or_insert(0);
            }
            prefixes.insert(piece.as_str().into(), id as u32 + 1);
        }
        let unk_score = scores.iter().copied().fold(f32::INFINITY, f32::min) - 10.0;
        Ok(Tokenizer {
            scores,
            prefixes,
            max_chars,
            unk_score,
            normaliser: Normaliser::new(charsmap).map_err(bad)?,
        })
    }

    /// The ids of `text`, between BOS and EOS.
    pub fn encode(&self, text: &str) -> Vec<u32> {
        let normalised = self.normaliser.normalise(text);
        let mut ids = vec![BOS];
        if normalised.is_empty() {
            ids.push(UNK);
        } else {
            ids.extend(self.viterbi(&normalised));
        }
        ids.push(EOS);
        ids
    }

    /// The best segmentation: for each position, the best scoring way to reach it (the
    /// earliest start on ties, as the reference does); a character no piece starts
    /// with is an unknown piece.
    fn viterbi(&self, s: &str) -> Vec<u32> {
        let bounds: Vec<usize> = s.char_indices().map(|(i, _)| i).chain([s.len()]).collect();
        let n = bounds.len() - 1;
        let mut best = vec![f32::NEG_INFINITY; n + 1];
        best[0] = 0.0;
        let mut from = vec![0usize; n + 1];
        let mut piece = vec![UNK; n + 1];
        for i in 0..n {
            let base = best[i];
            let mut single = false;
            for j in i + 1..=(i + self.max_chars).min(n) {
                let Some(&v) = self.prefixes.get(&s[bounds[i]..bounds[j]]) else {
                    break;
                };
                if v == 0 {
                    continue;
                }
                let score = base + self.scores[v as usize - 1];
                if score > best[j] {
                    best[j] = score;
                    from[j] = i;
                    piece[j] = v - 1;
                }
                single |= j == i + 1;
            }
            if !single {
                let score = base + self.unk_score;
                if score > best[i + 1] {
                    best[i + 1] = score;
                    from[i + 1] = i;
                    piece[i + 1] = UNK;
                }
            }
        }
        let mut ids = Vec::new();
        let mut p = n;
        while p > 0 {
            ids.push(piece[p]);
            p = from[p];
        }
        ids.reverse();
        ids
    }
}

/// The precompiled character map: a double-array trie whose leaves index a table of
/// NUL-terminated replacements.
struct Normaliser {
    units: Vec<u32>,
    replacements: Vec<u8>,
}

impl Normaliser {
    fn new(charsmap: &[u8]) -> Result<Normaliser, String> {
        if charsmap.is_empty() {
            return Ok(Normaliser {
                units: Vec::new(),
                replacements: Vec::new(),
            });
        }
        let size = charsmap
            .get(..4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
            .ok_or("the character map is cut short")?;
        let trie = charsmap
            .get(4..4 + size)
            .filter(|t| t.len() % 4 == 0 && !t.is_empty())
            .ok_or("the character map's trie is cut short")?;
        Ok(Normaliser {
            units: trie
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
            replacements: charsmap[4 + size..].to_vec(),
        })
    }

    fn offset(unit: u32) -> usize {
        ((unit >> 10) << ((unit & 0x200) >> 6)) as usize
    }

    /// What the longest key at the start of `data` becomes, and how many bytes it
    /// takes; a byte sequence no key starts with stays itself (one character).
    fn prefix<'a>(&'a self, data: &'a [u8]) -> (&'a [u8], usize) {
        let mut best: Option<(usize, usize)> = None;
        if let Some(&root) = self.units.first() {
            let mut node = Self::offset(root);
            for (i, &c) in data.iter().enumerate() {
                node ^= c as usize;
                let Some(&unit) = self.units.get(node) else {
                    break;
                };
                if unit & 0x8000_00ff != u32::from(c) {
                    break;
                }
                node ^= Self::offset(unit);
                if unit & 0x100 != 0 {
                    if let Some(&leaf) = self.units.get(node) {
                        best = Some((i + 1, (leaf & 0x7fff_ffff) as usize));
                    }
                }
            }
        }
        if let Some((len, value)) = best.filter(|(_, v)| *v < self.replacements.len()) {
            let rest = &self.replacements[value..];
            let end = rest.iter().position(|b| *b == 0).unwrap_or(rest.len());
            return (&rest[..end], len);
        }
        let first = data[0];
        let mut len = match first {
            0x00..=0x7f => 1,
            _ if first >> 5 == 0x6 => 2,
            _ if first >> 4 == 0xe => 3,
            _ if first >> 3 == 0x1e => 4,
            _ => 1,
        };
        if (1..len).any(|k| data.get(k).is_none_or(|b| b & 0xc0 != 0x80)) {
            len = 1;
        }
        (&data[..len], len)
    }

    /// The normalised text, spaces escaped, one leading, none trailing, runs collapsed.
    fn normalise(&self, text: &str) -> String {
        let raw = text.as_bytes();
        let mut pos = 0;
        while pos < raw.len() {
            let (p, adv) = self.prefix(&raw[pos..]);
            if p != b" " {
                break;
            }
            pos += adv;
        }
        if pos >= raw.len() {
            return String::new();
        }
        let mut out: Vec<u8> = SPACE.as_bytes().to_vec();
        let mut prev_space = true;
        while pos < raw.len() {
            let (mut p, adv) = self.prefix(&raw[pos..]);
            pos += adv;
            if prev_space {
                while let Some(rest) = p.strip_prefix(b" ") {
                    p = rest;
                }
            }
            if p.is_empty() {
                continue;
            }
            for &b in p {
                if b == b' ' {
                    out.extend_from_slice(SPACE.as_bytes());
                } else {
                    out.push(b);
                }
            }
            prev_space = p.last() == Some(&b' ');
        }
        while out.ends_with(SPACE.as_bytes()) {
            out.truncate(out.len() - SPACE.len());
        }
        // Replacements are whole UTF-8 sequences and unmatched bytes are copied whole
        // characters (or a lone byte of a broken one): lossy only for broken input.
        String::from_utf8_lossy(&out).into_owned()
    }
}
