//! `ferrosa transcribe` (a recording to text, with Whisper) and `ferrosa say` (text to
//! speech, with espeak-ng), and the speech model the console loads.

use std::path::Path;

use anyhow::Context;

use crate::speech::{voice, wav};

/// The catalog's speech recogniser, unless `-m` names another.
pub const DEFAULT_SPEECH_MODEL: &str = "whisper-base-en";

/// Resolve `model` (a catalog name or a path to a whisper.cpp `ggml-*.bin`) and load it.
#[cfg(feature = "candle")]
pub(crate) fn load_whisper(
    models_dir: &Path,
    model: Option<&str>,
) -> anyhow::Result<crate::speech::whisper::Whisper> {
    let spec = model.unwrap_or(DEFAULT_SPEECH_MODEL);
    let path = if spec.ends_with(".bin") && Path::new(spec).is_file() {
        std::path::PathBuf::from(spec)
    } else {
        let resolved = crate::models::resolve(Some(spec), models_dir).with_context(|| {
            format!("the speech model {spec}: fetch it with `ferrosa models fetch {DEFAULT_SPEECH_MODEL}`")
        })?;
        if let Some(e) = resolved
            .entry
            .as_ref()
            .filter(|e| e.kind != crate::models::ModelKind::Speech)
        {
            anyhow::bail!(
                "{} is a language model, not a speech recogniser: use -m {DEFAULT_SPEECH_MODEL}",
                e.name
            );
        }
        resolved.path
    };
    Ok(crate::speech::whisper::Whisper::load(&path)?)
}

/// `ferrosa transcribe FILE`: print what was said (or, with `json`, the transcript and
/// its timings).
pub fn transcribe(
    models_dir: &Path,
    model: Option<&str>,
    file: &Path,
    json: bool,
) -> anyhow::Result<()> {
    let bytes = std::fs::read(file).with_context(|| format!("reading {}", file.display()))?;
    let audio = wav::read(&bytes).with_context(|| file.display().to_string())?;
    #[cfg(feature = "candle")]
    {
        let t = std::time::Instant::now();
        let mut whisper = load_whisper(models_dir, model)?;
        let load_ms = t.elapsed().as_secs_f64() * 1e3;
        let heard = whisper.transcribe(&audio)?;
        if json {
            let mut v = serde_json::to_value(&heard)?;
            v["load_ms"] = serde_json::json!(load_ms);
            println!("{}", serde_json::to_string_pretty(&v)?);
        } else {
            println!("{}", super::term::clean(&heard.text));
        }
        Ok(())
    }
    #[cfg(not(feature = "candle"))]
    {
        let _ = (models_dir, model, json, audio);
        anyhow::bail!("this ferrosa was built without the candle feature, which runs Whisper: build with default features")
    }
}

/// `ferrosa say TEXT`: write the speech to `out`, or play it (with `aplay`).
pub fn say(
    text: &str,
    out: Option<&Path>,
    voice_name: &str,
    wpm: Option<u32>,
) -> anyhow::Result<()> {
    let audio = voice::speak(text, voice_name, wpm)?;
    let bytes = wav::write(&audio);
    match out {
        Some(path) => {
            std::fs::write(path, &bytes).with_context(|| format!("writing {}", path.display()))?;
            eprintln!("{}: {:.1} s of speech", path.display(), audio.seconds());
            Ok(())
        }
        None => {
            use std::io::Write;
            let mut player = std::process::Command::new("aplay")
                .args(["-q", "-"])
                .stdin(std::process::Stdio::piped())
                .spawn()
                .context("playing needs aplay (alsa-utils); or write a file with --out FILE.wav")?;
            player
                .stdin
                .take()
                .expect("piped stdin")
                .write_all(&bytes)?;
            let status = player.wait()?;
            anyhow::ensure!(
                status.success(),
                "aplay failed ({status}); write a file with --out FILE.wav instead"
            );
            Ok(())
        }
    }
}

/// The spoken requests `ferrosa eval speech` uses unless given a file.
const SPOKEN: &str = include_str!("../../tests/eval/spoken.txt");

/// `ferrosa eval speech`: the word error rate per voice and speed, and the time a
/// transcription takes.
pub fn eval(
    models_dir: &Path,
    model: Option<&str>,
    requests: Option<&Path>,
    voices: &[String],
    speeds: &[u32],
) -> anyhow::Result<()> {
    let text = match requests {
        Some(p) => {
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?
        }
        None => SPOKEN.to_string(),
    };
    #[cfg(feature = "candle")]
    {
        use crate::eval::speech;
        let requests = speech::requests(&text);
        anyhow::ensure!(!requests.is_empty(), "no requests to speak: one a line");
        let voices: Vec<String> = voices
            .iter()
            .filter(|v| {
                let there = v.as_str() != "piper" || voice::piper().is_some();
                if !there {
                    eprintln!("skipping the piper voice: not installed (scripts/install-piper.sh)");
                }
                there
            })
            .cloned()
            .collect();
        let voices = voices.as_slice();
        let mut whisper = load_whisper(models_dir, model)?;
        println!(
            "speech model {} | {} requests × {} voices × {} speeds | {}, {} threads",
            model.unwrap_or(DEFAULT_SPEECH_MODEL),
            requests.len(),
            voices.len(),
            speeds.len(),
            crate::metrics::cpu_model().unwrap_or_else(|| "unknown CPU".into()),
            std::thread::available_parallelism().map_or(1, |n| n.get())
        );
        let cases = speech::run(&mut whisper, &requests, voices, speeds, &mut |h| {
            if h.errors > 0 {
                eprintln!(
                    "  {} {} wpm: {:?} → {:?} ({} of {} words wrong)",
                    h.voice, h.wpm, h.said, h.heard, h.errors, h.words
                );
            }
        })?;
        println!(
            "{:<8} {:>4} {:>7} {:>9} {:>14}",
            "voice", "wpm", "WER", "audio s", "transcribe ms"
        );
        for v in voices {
            for &wpm in speeds {
                let these: Vec<_> = cases
                    .iter()
                    .filter(|h| &h.voice == v && h.wpm == wpm)
                    .collect();
                let n = these.len().max(1) as f64;
                println!(
                    "{:<8} {:>4} {:>6.1}% {:>9.2} {:>14.0}",
                    v,
                    wpm,
                    100.0 * speech::rate(these.iter().copied()),
                    these.iter().map(|h| h.audio_s).sum::<f64>() / n,
                    these.iter().map(|h| h.transcribe_ms).sum::<f64>() / n
                );
            }
        }
        println!(
            "{:<8} {:>4} {:>6.1}%",
            "all",
            "",
            100.0 * speech::rate(&cases)
        );
        Ok(())
    }
    #[cfg(not(feature = "candle"))]
    {
        let _ = (models_dir, model, voices, speeds, text);
        anyhow::bail!("this ferrosa was built without the candle feature, which runs Whisper: build with default features")
    }
}
