//! The console's speech: recordings from the page transcribed with Whisper (loaded at the
//! first one, kept after), answers read aloud with espeak-ng.
//!
//! A recording is whatever a client sends: `speech::recogniser` checks it and keeps one
//! bad recording (a crafted header, a panic in the model) from breaking speech for the
//! requests after it.

use std::path::PathBuf;

use serde_json::Value;

use crate::speech::{voice, wav};

/// Why speech failed, and whose fault it was.
pub(crate) enum SpeechFailure {
    /// The request's audio or text.
    Input(String),
    /// What the machine lacks (the model, espeak-ng, the feature).
    Unavailable(String),
}

pub(crate) struct Ears {
    #[cfg(feature = "candle")]
    recogniser: crate::speech::recogniser::Recogniser,
}

impl Ears {
    pub fn new(models_dir: PathBuf) -> Ears {
        #[cfg(not(feature = "candle"))]
        let _ = models_dir;
        Ears {
            #[cfg(feature = "candle")]
            recogniser: crate::speech::recogniser::Recogniser::new(move || {
                super::super::speech::load_whisper(&models_dir, None).map_err(|e| format!("{e:#}"))
            }),
        }
    }

    /// The words in a WAV recording, with the time it took.
    pub fn transcribe(&self, bytes: &[u8]) -> Result<Value, SpeechFailure> {
        #[cfg(feature = "candle")]
        {
            let t = self.recogniser.transcribe_wav(bytes).map_err(|e| {
                if e.is_input() {
                    SpeechFailure::Input(e.to_string())
                } else {
                    SpeechFailure::Unavailable(e.to_string())
                }
            })?;
            Ok(serde_json::json!({"text": t.text, "audio_s": t.audio_s, "ms": t.total_ms()}))
        }
        #[cfg(not(feature = "candle"))]
        {
            wav::read(bytes).map_err(|e| SpeechFailure::Input(e.to_string()))?;
            Err(SpeechFailure::Unavailable(
                "this ferrosa was built without the candle feature, which runs Whisper".into(),
            ))
        }
    }

    /// `text` spoken in `language` (a code, or an espeak-ng voice), as WAV bytes.
    pub fn say(&self, text: &str, language: &str) -> Result<Vec<u8>, SpeechFailure> {
        match voice::speak(text, language, None) {
            Ok(audio) => Ok(wav::write(&audio)),
            Err(e @ voice::VoiceError::Missing) | Err(e @ voice::VoiceError::Failed(_)) => {
                Err(SpeechFailure::Unavailable(e.to_string()))
            }
            Err(e) => Err(SpeechFailure::Input(e.to_string())),
        }
    }
}
