//! `cargo bench --bench speech`: how long speech takes on this machine.
//!
//! 1. Transcription of a 3-second spoken request (espeak-ng, padded with silence to
//!    3.0 s) with Whisper base.en on candle: load time, then mel / encoder / decoder /
//!    total per run (min / median / max over `RUNS`, default 5, after one warm-up), and
//!    the process's memory after loading.
//! 2. Speech out: espeak-ng's time to speak a typical answer.
//!
//! No wall-clock assertion anywhere: this prints figures and the machine.

#[path = "common/header.rs"]
mod header;

use std::time::Instant;

use ferrosa::speech::whisper::Whisper;
use ferrosa::speech::{voice, Audio};
use header::Spread;

const REQUEST: &str = "move the turtle forward two meters, then turn left";

fn main() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let runs = header::env_usize("RUNS", 5);
    header::print("speech", &root, &format!("RUNS={runs}"));
    let path = header::models_dir().join("ggml-base.en.bin");
    if !path.exists() {
        println!(
            "no Whisper model at {}: ferrosa models fetch whisper-base-en",
            path.display()
        );
        return;
    }
    let spoken = voice::speak(REQUEST, "en-us", None).expect("espeak-ng");
    let mut samples = spoken.samples.clone();
    samples.resize((spoken.rate as usize) * 3, 0.0);
    let audio = Audio {
        rate: spoken.rate,
        samples,
    };
    println!(
        "request: {REQUEST:?}, spoken in {:.2} s, fitted to {:.1} s (silence cut or added at the end)",
        spoken.seconds(),
        audio.seconds()
    );
    let rss0 = ferrosa::metrics::rss_bytes().unwrap_or(0);
    let t = Instant::now();
    let mut whisper = Whisper::load(&path).expect("Whisper");
    let load_ms = t.elapsed().as_secs_f64() * 1e3;
    let rss = ferrosa::metrics::rss_bytes().unwrap_or(0);
    println!(
        "load {load_ms:.0} ms; memory +{:.0} MiB ({:.0} MiB resident)",
        ferrosa::metrics::mib(rss.saturating_sub(rss0)),
        ferrosa::metrics::mib(rss)
    );
    let heard = whisper.transcribe(&audio).expect("warm-up");
    println!("heard: {:?}", heard.text);
    let (mut mel, mut enc, mut dec, mut total) = (vec![], vec![], vec![], vec![]);
    for _ in 0..runs {
        let t = whisper.transcribe(&audio).expect("transcribe");
        mel.push(t.mel_ms);
        enc.push(t.encode_ms);
        dec.push(t.decode_ms);
        total.push(t.total_ms());
    }
    println!("\n| part | min ms | median ms | max ms |\n|---|---|---|---|");
    for (name, v) in [
        ("mel", mel),
        ("encoder", enc),
        ("decoder", dec),
        ("total", total),
    ] {
        let s = Spread::of(v);
        println!("| {name} | {:.0} | {:.0} | {:.0} |", s.min, s.median, s.max);
    }
    let answer = "The turtle is at x 5.5, y 5.5, facing east.";
    let mut said = vec![];
    for _ in 0..runs {
        let t = Instant::now();
        voice::speak(answer, "en", None).expect("espeak-ng");
        said.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let s = Spread::of(said);
    println!(
        "\nspeech out (espeak-ng, {answer:?}): min {:.0} / median {:.0} / max {:.0} ms",
        s.min, s.median, s.max
    );
}
