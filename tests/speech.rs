//! Speech, with the real parts: espeak-ng and Piper speak, Whisper base.en (on candle)
//! hears.
//! The round trip an operator makes by voice (spoken request → `ferrosa transcribe` →
//! the agent answers it on the sim), and the word error rate over the spoken operator
//! requests in one voice at two speeds (`ferrosa eval speech` reports all of them).

use std::process::Command;

use crate::util::{models_dir, rerun_in_loopback_netns};

fn ferrosa(args: &[&str]) -> (bool, String, String) {
    let out = Command::new("timeout")
        .args(["-k", "5", "300", env!("CARGO_BIN_EXE_ferrosa")])
        .args(args)
        .env("FERROSA_MODELS_DIR", models_dir())
        .output()
        .expect("running ferrosa");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
#[ignore = "needs espeak-ng and the Whisper weights (.ci/setup), and a loopback-only network namespace: cargo test --release -- --include-ignored"]
fn a_spoken_request_is_transcribed_and_answered() {
    if rerun_in_loopback_netns("speech::a_spoken_request_is_transcribed_and_answered", 600) {
        return;
    }
    let wav = std::env::temp_dir().join(format!("ferrosa-spoken-{}.wav", std::process::id()));
    let (ok, _, err) = ferrosa(&[
        "say",
        "--voice",
        "en-us",
        "list the ROS nodes",
        "--out",
        wav.to_str().unwrap(),
    ]);
    assert!(ok, "ferrosa say: {err}");
    let (ok, heard, err) = ferrosa(&["transcribe", wav.to_str().unwrap()]);
    assert!(ok, "ferrosa transcribe: {err}");
    let heard = heard.trim().to_string();
    eprintln!("heard: {heard:?}");
    assert!(heard.to_lowercase().contains("nodes"), "heard {heard:?}");
    let (ok, answer, err) = ferrosa(&["ask", "--robot", "sim", &heard]);
    assert!(ok, "ferrosa ask {heard:?}: {err}");
    eprintln!("answer: {answer:?}");
    assert!(
        answer.contains("/turtlesim"),
        "{heard:?} → {answer:?}\n{err}"
    );

    // The Piper voice, as the console speaks English answers: "ROS" comes through.
    let (ok, _, err) = ferrosa(&[
        "say",
        "--voice",
        "piper",
        "list the ROS nodes",
        "--out",
        wav.to_str().unwrap(),
    ]);
    assert!(
        ok,
        "ferrosa say --voice piper (scripts/install-piper.sh, run by .ci/setup): {err}"
    );
    let (ok, heard, err) = ferrosa(&["transcribe", wav.to_str().unwrap()]);
    assert!(ok, "ferrosa transcribe: {err}");
    assert!(
        heard.to_lowercase().contains("ros nodes"),
        "piper: heard {heard:?}"
    );
    let _ = std::fs::remove_file(&wav);

    // Bad input: a file that is not WAV says what to do.
    let (ok, _, err) = ferrosa(&["transcribe", "Cargo.toml"]);
    assert!(!ok);
    assert!(err.contains("not a WAV file"), "{err}");
}

#[cfg(feature = "candle")]
#[test]
#[ignore = "needs espeak-ng and the Whisper weights (.ci/setup): cargo test --release -- --include-ignored"]
fn the_word_error_rate_on_spoken_operator_requests() {
    use ferrosa::eval::speech;
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/eval/spoken.txt"
    ))
    .unwrap();
    let requests = speech::requests(&text);
    let path = models_dir().join("ggml-base.en.bin");
    let mut whisper = ferrosa::speech::whisper::Whisper::load(&path)
        .unwrap_or_else(|e| panic!("{e}: run .ci/setup (ferrosa models fetch whisper-base-en)"));
    let cases = speech::run(
        &mut whisper,
        &requests,
        &["en-us".to_string(), "piper".to_string()],
        &[175],
        &mut |h| {
            eprintln!(
                "{} {} wpm: {:?} → {:?} ({}/{})",
                h.voice, h.wpm, h.said, h.heard, h.errors, h.words
            );
        },
    )
    .unwrap();
    let wer = speech::rate(&cases);
    eprintln!(
        "word error rate {:.1}% over {} requests",
        100.0 * wer,
        cases.len()
    );
    // Measured about 10% (README); a recogniser or an audio path gone wrong is far above.
    assert!(wer < 0.30, "word error rate {:.1}%", 100.0 * wer);
    // Most requests come through whole.
    let whole = cases.iter().filter(|h| h.errors == 0).count();
    assert!(
        whole * 2 >= cases.len(),
        "{whole} of {} heard without an error",
        cases.len()
    );
}
