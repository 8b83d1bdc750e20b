//! Speech recognition on operator requests: each request spoken by espeak-ng voices or
//! Piper at several speeds, transcribed by Whisper, scored by word error rate
//! (`speech::wer`).
//! The voices are synthetic: the figures say how the recogniser hears clear, accented
//! machine speech, not how it hears a person in a noisy field.

use serde::Serialize;

use crate::speech::voice;
use crate::speech::wer;
use crate::speech::whisper::{Whisper, WhisperError};

#[derive(Debug, thiserror::Error)]
pub enum SpeechEvalError {
    #[error(transparent)]
    Voice(#[from] voice::VoiceError),
    #[error(transparent)]
    Whisper(#[from] WhisperError),
}

/// One request, spoken and heard.
#[derive(Debug, Clone, Serialize)]
pub struct Heard {
    pub voice: String,
    pub wpm: u32,
    pub said: String,
    pub heard: String,
    pub errors: usize,
    pub words: usize,
    pub audio_s: f64,
    pub transcribe_ms: f64,
}

/// The requests of a file: one a line, `#` comments and blank lines skipped.
pub fn requests(text: &str) -> Vec<String> {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(str::to_string)
        .collect()
}

/// Every request in every voice at every speed; `each` sees each as it is heard.
pub fn run(
    whisper: &mut Whisper,
    requests: &[String],
    voices: &[String],
    speeds: &[u32],
    each: &mut dyn FnMut(&Heard),
) -> Result<Vec<Heard>, SpeechEvalError> {
    let mut out = Vec::new();
    for v in voices {
        for &wpm in speeds {
            for said in requests {
                let audio = voice::speak(said, v, Some(wpm))?;
                let heard = whisper.transcribe(&audio)?;
                let transcribe_ms = heard.total_ms();
                let (errors, words) = wer::errors(said, &heard.text);
                let h = Heard {
                    voice: v.clone(),
                    wpm,
                    said: said.clone(),
                    heard: heard.text,
                    errors,
                    words,
                    audio_s: audio.seconds(),
                    transcribe_ms,
                };
                each(&h);
                out.push(h);
            }
        }
    }
    Ok(out)
}

/// Word error rate over `cases`.
pub fn rate<'a>(cases: impl IntoIterator<Item = &'a Heard>) -> f64 {
    let (e, n) = cases
        .into_iter()
        .fold((0, 0), |(e, n), h| (e + h.errors, n + h.words));
    e as f64 / n.max(1) as f64
}
