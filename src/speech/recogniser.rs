//! The speech recogniser as a service many requests share (the console's): one model,
//! loaded at the first request and kept, behind a lock that no request can leave
//! poisoned.
//!
//! A recording is input from whoever reaches the console (issue 41). It is read and
//! checked (`wav`, then `Whisper::transcribe`'s own checks) before the model sees it;
//! and should the model still panic on one, the panic is caught where it happens, inside
//! the lock: that request fails with a reason, the model it may have left half-way is
//! dropped (the next request loads it again), and every later request works. It does not
//! decide what a failure means to a caller (an HTTP status, a message): `HearError` says
//! whose fault it was.

use std::any::Any;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Mutex, MutexGuard, PoisonError};

use super::wav::{self, Audio, WavError};
use super::whisper::{Transcript, Whisper, WhisperError};

/// A loaded speech model: Whisper, or a stand-in in tests.
pub trait Recognise: Send {
    fn transcribe(&mut self, audio: &Audio) -> Result<Transcript, WhisperError>;
}

impl Recognise for Whisper {
    fn transcribe(&mut self, audio: &Audio) -> Result<Transcript, WhisperError> {
        Whisper::transcribe(self, audio)
    }
}

/// Why a recording gave no text.
#[derive(Debug, thiserror::Error)]
pub enum HearError {
    /// The recording is not one to transcribe (not WAV, a crafted header, too long).
    #[error(transparent)]
    Recording(#[from] WavError),
    #[error(transparent)]
    Refused(WhisperError),
    /// The model cannot be had (not fetched, unreadable).
    #[error("no speech model: {0}")]
    Unavailable(String),
    /// The model failed while running.
    #[error(transparent)]
    Failed(WhisperError),
    /// The model panicked on this recording: caught, the model dropped and loaded again
    /// for the next request.
    #[error("the speech model failed on this recording ({0}); other recordings still work")]
    Crashed(String),
}

impl HearError {
    /// Whether the recording, not the model or the machine, is at fault.
    pub fn is_input(&self) -> bool {
        match self {
            HearError::Recording(_) | HearError::Refused(_) | HearError::Crashed(_) => true,
            HearError::Unavailable(_) | HearError::Failed(_) => false,
        }
    }
}

/// Loads the model at the first request.
type Loader<M> = Box<dyn Fn() -> Result<M, String> + Send + Sync>;

/// One model shared by every request (see the module header).
pub struct Recogniser<M: Recognise = Whisper> {
    model: Mutex<Option<M>>,
    load: Loader<M>,
}

impl<M: Recognise> Recogniser<M> {
    /// A recogniser that loads its model with `load` when first asked.
    pub fn new(load: impl Fn() -> Result<M, String> + Send + Sync + 'static) -> Recogniser<M> {
        Recogniser {
            model: Mutex::new(None),
            load: Box::new(load),
        }
    }

    /// The words in the WAV recording `bytes`.
    pub fn transcribe_wav(&self, bytes: &[u8]) -> Result<Transcript, HearError> {
        let audio = wav::read(bytes)?;
        self.transcribe(&audio)
    }

    /// The words in `audio`.
    pub fn transcribe(&self, audio: &Audio) -> Result<Transcript, HearError> {
        let mut slot = self.slot();
        let model = match &mut *slot {
            Some(model) => model,
            empty => {
                let loaded = catch_unwind(AssertUnwindSafe(|| (self.load)()))
                    .map_err(|p| HearError::Unavailable(panic_text(&p)))?
                    .map_err(HearError::Unavailable)?;
                empty.insert(loaded)
            }
        };
        match catch_unwind(AssertUnwindSafe(|| model.transcribe(audio))) {
            Ok(Ok(t)) => Ok(t),
            Ok(Err(e)) if e.is_input() => Err(HearError::Refused(e)),
            Ok(Err(e)) => Err(HearError::Failed(e)),
            Err(panic) => {
                *slot = None;
                let why = panic_text(&panic);
                tracing::warn!(target: "ferrosa::speech", "the speech model panicked on a recording (dropped, reloaded at the next): {why}");
                Err(HearError::Crashed(why))
            }
        }
    }

    /// Whether the model is loaded now.
    pub fn is_loaded(&self) -> bool {
        self.slot().is_some()
    }

    /// The model's slot, locked. A panic is caught inside the lock (see `transcribe`), so
    /// the lock is never poisoned by one; were it, the slot is still whole (a model or
    /// none), so it is taken as it is.
    fn slot(&self) -> MutexGuard<'_, Option<M>> {
        self.model.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// A panic's message.
fn panic_text(panic: &Box<dyn Any + Send>) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;

    /// Hears "ok", and panics on a recording of exactly 3 samples.
    struct Fragile;

    impl Recognise for Fragile {
        fn transcribe(&mut self, audio: &Audio) -> Result<Transcript, WhisperError> {
            assert!(audio.samples.len() != 3, "a recording it cannot take");
            Ok(Transcript {
                text: "ok".into(),
                audio_s: audio.seconds(),
                mel_ms: 0.0,
                encode_ms: 0.0,
                decode_ms: 0.0,
                tokens: 1,
            })
        }
    }

    fn audio(n: usize) -> Audio {
        Audio {
            rate: 16000,
            samples: vec![0.0; n],
        }
    }

    #[test]
    fn a_panic_fails_one_request_and_the_next_works() {
        let loads = Arc::new(AtomicUsize::new(0));
        let counted = loads.clone();
        let ears = Arc::new(Recogniser::new(move || {
            counted.fetch_add(1, Ordering::Relaxed);
            Ok(Fragile)
        }));
        assert_eq!(ears.transcribe(&audio(10)).unwrap().text, "ok");
        // On another thread, as the console's requests come.
        let other = ears.clone();
        let crashed = std::thread::spawn(move || other.transcribe(&audio(3)))
            .join()
            .expect("the panic did not leave the request");
        assert!(matches!(crashed, Err(HearError::Crashed(ref m)) if m.contains("cannot take")));
        assert!(crashed.unwrap_err().is_input());
        assert!(!ears.model.is_poisoned());
        assert!(!ears.is_loaded(), "the model it left is dropped");
        assert_eq!(ears.transcribe(&audio(10)).unwrap().text, "ok");
        assert_eq!(loads.load(Ordering::Relaxed), 2, "loaded again once");
    }

    #[test]
    fn bad_recordings_and_a_missing_model_say_so() {
        let ears: Recogniser<Fragile> = Recogniser::new(|| Err("not fetched".into()));
        let e = ears.transcribe_wav(b"OggS....").unwrap_err();
        assert!(matches!(e, HearError::Recording(WavError::NotWav)), "{e}");
        let e = ears.transcribe(&audio(10)).unwrap_err();
        assert!(matches!(e, HearError::Unavailable(ref m) if m == "not fetched"));
        assert!(!e.is_input());
        let panicky: Recogniser<Fragile> = Recogniser::new(|| panic!("a loader that panics"));
        let e = panicky.transcribe(&audio(10)).unwrap_err();
        assert!(matches!(e, HearError::Unavailable(ref m) if m.contains("loader")));
    }
}
