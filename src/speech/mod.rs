//! Speech in and out, offline: Whisper on candle turns an operator's recording into a
//! request, espeak-ng or the Piper voice reads an answer aloud.
//!
//! Layout:
//! - `wav`: WAV files in and out, resampling
//! - `ggml`: whisper.cpp's model file, read into candle tensors
//! - `whisper`: speech to text (needs the `candle` feature)
//! - `recogniser`: one Whisper shared by many requests, never left poisoned by one
//! - `voice`: text to speech with espeak-ng and Piper
//! - `wer`: word error rate, for measuring the recogniser
//!
//! Depends on nothing else in the crate but `dirs` (where the Piper voice is installed).

#[cfg(feature = "candle")]
pub mod ggml;
#[cfg(feature = "candle")]
pub mod recogniser;
pub mod voice;
pub mod wav;
pub mod wer;
#[cfg(feature = "candle")]
pub mod whisper;

pub use wav::Audio;
