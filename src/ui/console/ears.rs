//! The console's speech: recordings from the page transcribed with Whisper (loaded at the
//! first one, kept after), answers read aloud with espeak-ng.

use std::path::PathBuf;

use serde_json::Value;

use crate::speech::{voice, wav};

/// Why speech failed, and whose fault it was.
pub enum SpeechFailure {
    /// The request's audio or text.
    Input(String),
    /// What the machine lacks (the model, espeak-ng, the feature).
    Unavailable(String),
}

pub struct Ears {
    models_dir: PathBuf,
    #[cfg(feature = "candle")]
    whisper: std::sync::Mutex<Option<crate::speech::whisper::Whisper>>,
}

impl Ears {
    pub fn new(models_dir: PathBuf) -> Ears {
        Ears {
            models_dir,
            #[cfg(feature = "candle")]
            whisper: std::sync::Mutex::new(None),
        }
    }

    /// The words in a WAV recording, with the time it took.
    pub fn transcribe(&self, bytes: &[u8]) -> Result<Value, SpeechFailure> {
        let audio = wav::read(bytes).map_err(|e| SpeechFailure::Input(e.to_string()))?;
        #[cfg(feature = "candle")]
        {
            let mut slot = self.whisper.lock().expect("whisper lock");
            if slot.is_none() {
                let w = super::super::speech::load_whisper(&self.models_dir, None)
                    .map_err(|e| SpeechFailure::Unavailable(format!("{e:#}")))?;
                *slot = Some(w);
            }
            let whisper = slot.as_mut().expect("loaded above");
            let t = whisper.transcribe(&audio).map_err(|e| match e {
                crate::speech::whisper::WhisperError::TooLong(_) => {
                    SpeechFailure::Input(e.to_string())
                }
                e => SpeechFailure::Unavailable(e.to_string()),
            })?;
            Ok(serde_json::json!({"text": t.text, "audio_s": t.audio_s, "ms": t.total_ms()}))
        }
        #[cfg(not(feature = "candle"))]
        {
            let _ = (&self.models_dir, audio);
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
