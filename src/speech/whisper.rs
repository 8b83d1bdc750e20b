//! Speech to text with Whisper on candle: the weights from whisper.cpp's file (`ggml`),
//! the model from `candle-transformers`, greedy decoding without timestamps.
//!
//! Audio is resampled to 16 kHz and turned into an 80-band log-mel spectrogram. The
//! encoder sees the whole 30-second window Whisper was trained on (a short request is
//! padded with silence, as in whisper.cpp and OpenAI's reference; cut to the speech,
//! the model drops or invents words on short requests). The decoder starts from
//! "start of transcript" (and, on a multilingual model, English and "transcribe") and
//! "no timestamps", and writes text tokens until "end of text".

use std::path::Path;
use std::time::Instant;

use candle_core::{DType, Device, IndexOp, Tensor, D};
use candle_nn::VarBuilder;
use candle_transformers::models::whisper::{self as m, audio, model::Whisper as Model};

use super::ggml::{self, GgmlError};
use super::wav::{resample, Audio, RATES};

#[derive(Debug, thiserror::Error)]
pub enum WhisperError {
    #[error("cannot read the Whisper model {path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error(transparent)]
    File(#[from] GgmlError),
    #[error("the Whisper model runtime failed: {0}")]
    Candle(#[from] candle_core::Error),
    #[error("the recording is {0:.1} s long; requests up to 30 s are transcribed (split longer recordings)")]
    TooLong(f64),
    #[error("the recording's sample rate is {0} Hz, outside {lo}–{hi} Hz: resample it", lo = RATES.start(), hi = RATES.end())]
    Rate(u32),
    #[error("the recording holds no samples")]
    Empty,
}

impl WhisperError {
    /// Whether the recording, not the model or the machine, is at fault.
    pub fn is_input(&self) -> bool {
        matches!(
            self,
            WhisperError::TooLong(_) | WhisperError::Rate(_) | WhisperError::Empty
        )
    }
}

/// Tokens with a meaning of their own, where the file's vocabulary puts them.
#[derive(Debug, Clone, Copy)]
struct Special {
    eot: u32,
    sot: u32,
    /// `<|en|>` and `<|transcribe|>` (multilingual models only).
    english: Option<(u32, u32)>,
    no_timestamps: u32,
}

impl Special {
    /// whisper.cpp's layout: English-only vocabularies (51,864 tokens) put end-of-text
    /// at 50256; multilingual ones one later, with the language tokens after
    /// start-of-transcript.
    fn of(n_vocab: usize) -> Special {
        let shift = u32::from(n_vocab >= 51865);
        Special {
            eot: 50256 + shift,
            sot: 50257 + shift,
            english: (shift == 1).then_some((50259, 50359)),
            no_timestamps: 50362 + shift,
        }
    }
}

/// What a transcription gives: the text, and where the time went.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Transcript {
    pub text: String,
    pub audio_s: f64,
    pub mel_ms: f64,
    pub encode_ms: f64,
    pub decode_ms: f64,
    pub tokens: usize,
}

impl Transcript {
    pub fn total_ms(&self) -> f64 {
        self.mel_ms + self.encode_ms + self.decode_ms
    }
}

/// A Whisper model, loaded.
pub struct Whisper {
    model: Model,
    filters: Vec<f32>,
    vocab: Vec<Vec<u8>>,
    special: Special,
    /// Added to the logits: text tokens only (every special token but end-of-text masked).
    text_only: Tensor,
}

/// The most tokens a transcript may take (Whisper's own limit is half its context).
const MAX_TOKENS: usize = 224;

impl Whisper {
    pub fn load(path: &Path) -> Result<Whisper, WhisperError> {
        let bytes = std::fs::read(path).map_err(|source| WhisperError::Read {
            path: path.display().to_string(),
            source,
        })?;
        let file = ggml::read(&bytes)?;
        drop(bytes);
        let h = file.hparams;
        let config = m::Config {
            num_mel_bins: h.n_mels,
            max_source_positions: h.n_audio_ctx,
            d_model: h.n_audio_state,
            encoder_attention_heads: h.n_audio_head,
            encoder_layers: h.n_audio_layer,
            vocab_size: h.n_vocab,
            max_target_positions: h.n_text_ctx,
            decoder_attention_heads: h.n_text_head,
            decoder_layers: h.n_text_layer,
            suppress_tokens: Vec::new(),
        };
        let vb = VarBuilder::from_tensors(file.tensors, DType::F32, &Device::Cpu);
        let model = Model::load(&vb, config)?;
        let special = Special::of(h.n_vocab);
        let mask: Vec<f32> = (0..h.n_vocab as u32)
            .map(|i| {
                if i <= special.eot {
                    0.0
                } else {
                    f32::NEG_INFINITY
                }
            })
            .collect();
        Ok(Whisper {
            model,
            filters: file.filters,
            vocab: file.vocab,
            special,
            text_only: Tensor::new(mask.as_slice(), &Device::Cpu)?,
        })
    }

    /// The words spoken in `audio`, which is checked first (any `Audio` may come here,
    /// not only what `wav::read` let through).
    pub fn transcribe(&mut self, audio: &Audio) -> Result<Transcript, WhisperError> {
        if !RATES.contains(&audio.rate) {
            return Err(WhisperError::Rate(audio.rate));
        }
        if audio.samples.is_empty() {
            return Err(WhisperError::Empty);
        }
        if audio.seconds() > m::CHUNK_LENGTH as f64 {
            return Err(WhisperError::TooLong(audio.seconds()));
        }
        // A transcription that failed half-way may have left its cache behind.
        self.model.reset_kv_cache();
        let t = Instant::now();
        let pcm = resample(audio, m::SAMPLE_RATE as u32);
        let cfg = &self.model.config;
        let mel = audio::pcm_to_mel(cfg, &pcm.samples, &self.filters);
        let frames = mel.len() / cfg.num_mel_bins;
        let mel = Tensor::from_vec(mel, (1, cfg.num_mel_bins, frames), &Device::Cpu)?.narrow(
            2,
            0,
            frames.min(m::N_FRAMES),
        )?;
        let mel_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let features = self.model.encoder.forward(&mel, true)?;
        let encode_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let s = self.special;
        let mut tokens = vec![s.sot];
        if let Some((en, transcribe)) = s.english {
            tokens.extend([en, transcribe]);
        }
        tokens.push(s.no_timestamps);
        let prompt = tokens.len();
        for i in 0..MAX_TOKENS {
            let input = Tensor::new(tokens.as_slice(), &Device::Cpu)?.unsqueeze(0)?;
            let hidden = self.model.decoder.forward(&input, &features, i == 0)?;
            let last = hidden.i((.., hidden.dim(1)? - 1..))?;
            let logits = self.model.decoder.final_linear(&last)?.i((0, 0))?;
            let next = logits
                .broadcast_add(&self.text_only)?
                .argmax(D::Minus1)?
                .to_scalar::<u32>()?;
            if next == s.eot {
                break;
            }
            tokens.push(next);
        }
        self.model.reset_kv_cache();
        let decode_ms = t.elapsed().as_secs_f64() * 1e3;
        let bytes: Vec<u8> = tokens[prompt..]
            .iter()
            .filter_map(|&id| self.vocab.get(id as usize))
            .flatten()
            .copied()
            .collect();
        Ok(Transcript {
            text: String::from_utf8_lossy(&bytes).trim().to_string(),
            audio_s: audio.seconds(),
            mel_ms,
            encode_ms,
            decode_ms,
            tokens: tokens.len() - prompt,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn special_tokens_follow_the_vocabulary_size() {
        let en = Special::of(51864);
        assert_eq!(
            (en.eot, en.sot, en.no_timestamps, en.english),
            (50256, 50257, 50362, None)
        );
        let multi = Special::of(51865);
        assert_eq!(
            (multi.eot, multi.sot, multi.no_timestamps),
            (50257, 50258, 50363)
        );
        assert_eq!(multi.english, Some((50259, 50359)));
    }
}
