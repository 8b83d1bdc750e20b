//! The `ferrosa` binary as an operator runs it: every bad input is one line on stderr
//! that names the fix, with a non-zero exit; the good path streams text.

use std::path::Path;
use std::process::{Command, Output};

use crate::util::models_dir;

fn ferrosa(args: &[&str], models: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ferrosa"))
        .args(args)
        .env("FERROSA_MODELS_DIR", models)
        .output()
        .expect("run ferrosa")
}

/// Exit non-zero with exactly one line on stderr containing every `needles`.
fn assert_one_line_error(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "succeeded; stderr: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} missing from: {err}");
    }
}

#[test]
fn unknown_model_name_lists_the_catalog() {
    let out = ferrosa(&["generate", "-m", "gpt-17", "-p", "hi"], &models_dir());
    assert_one_line_error(
        &out,
        &["unknown model 'gpt-17'", "smollm2-135m", "path to a .gguf"],
    );
}

#[test]
fn missing_model_file_names_the_fetch_command() {
    let empty = tempfile::tempdir().unwrap();
    let out = ferrosa(&["generate", "-p", "hi"], empty.path());
    assert_one_line_error(
        &out,
        &["not installed", "ferrosa models fetch smollm2-135m"],
    );
}

#[test]
fn wrong_sha256_names_the_force_fetch() {
    let dir = tempfile::tempdir().unwrap();
    // A catalog whose default model is present but not the file the catalog describes.
    let cat = ferrosa::models::catalog::BUILTIN;
    std::fs::write(dir.path().join("catalog.toml"), cat).unwrap();
    std::fs::write(
        dir.path().join("SmolLM2-135M-Instruct.Q4_1.gguf"),
        b"GGUF tampered",
    )
    .unwrap();
    let out = ferrosa(&["generate", "-p", "hi"], dir.path());
    assert_one_line_error(
        &out,
        &[
            "does not match the catalog's sha256",
            "models fetch smollm2-135m --force",
        ],
    );
    let out = ferrosa(&["models", "verify", "smollm2-135m"], dir.path());
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("MISMATCH"));
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn truncated_gguf_says_fetch_again() {
    let dir = tempfile::tempdir().unwrap();
    let real = std::fs::read(crate::util::model_path("smollm2-135m")).unwrap();
    let cut = dir.path().join("cut.gguf");
    std::fs::write(&cut, &real[..real.len() / 2]).unwrap();
    let out = ferrosa(
        &["generate", "-m", cut.to_str().unwrap(), "-p", "hi"],
        dir.path(),
    );
    assert_one_line_error(&out, &["is truncated", "fetch it again"]);
}

#[test]
fn non_gguf_file_is_named_as_such() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("notes.gguf");
    std::fs::write(&f, "these are my notes, not a model\n").unwrap();
    let out = ferrosa(
        &["generate", "-m", f.to_str().unwrap(), "-p", "hi"],
        dir.path(),
    );
    assert_one_line_error(&out, &["is not a GGUF model file", "models list"]);
    let out = ferrosa(
        &["generate", "-m", "no/such/file.gguf", "-p", "hi"],
        dir.path(),
    );
    assert_one_line_error(&out, &["no model file at no/such/file.gguf"]);
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn generate_streams_text_and_reports_stats() {
    let out = ferrosa(
        &[
            "generate",
            "--chat",
            "-p",
            "What is a robot?",
            "-n",
            "24",
            "--stats",
        ],
        &models_dir(),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stdout.split_whitespace().count() >= 8, "{stdout:?}");
    for k in ["load:", "prompt:", "generation:", "tok/s", "peak RSS:"] {
        assert!(stderr.contains(k), "{k} missing from {stderr}");
    }
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn models_list_shows_both_models_and_marks_the_base_one() {
    let out = ferrosa(&["models", "list"], &models_dir());
    let s = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success());
    assert!(
        s.contains("smollm2-135m") && s.contains("gemma3-270m"),
        "{s}"
    );
    assert!(s.contains("49152") && s.contains("262144"), "{s}");
    assert!(s.contains("BASE model"), "{s}");
    let out = ferrosa(&["models", "verify"], &models_dir());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn fetch_is_idempotent() {
    let out = ferrosa(&["models", "fetch"], &models_dir());
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("already installed"));
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn ask_json_answers_the_mean_with_a_calculation_tool_and_memory_keeps_it() {
    let dir = tempfile::tempdir().unwrap();
    let memory = dir.path().join("memory.sqlite");
    let memory = memory.to_str().unwrap();
    let out = ferrosa(
        &[
            "ask",
            "--json",
            "--memory",
            memory,
            "what is the mean of 3, 5 and 10?",
        ],
        &models_dir(),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout).expect("JSON on stdout");
    let steps = v["steps"].as_array().unwrap();
    assert!(
        steps
            .iter()
            .any(|s| s["name"].as_str().unwrap_or("").starts_with("calc_") && s["ok"] == true),
        "no calculation tool ran: {stdout}"
    );
    let answer = v["answer"].as_str().unwrap();
    assert!(answer.contains('6'), "answer without 6: {answer}");
    for key in ["total_ms", "prompt_tokens", "reused_tokens"] {
        assert!(v["timings"].get(key).is_some(), "timings.{key} missing");
    }
    memory_keeps_lists_resumes_exports_and_forgets(memory);
}

/// The request just asked is in the memory file: listed, resumed by the chat (whose
/// next request goes on in the same session), exported, and forgotten.
fn memory_keeps_lists_resumes_exports_and_forgets(memory: &str) {
    let models = models_dir();
    let out = ferrosa(&["memory", "list", "--memory", memory], &models);
    let listed = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{listed}");
    assert!(
        listed.contains("[none]") && listed.contains("what is the mean of 3, 5 and 10?"),
        "{listed}"
    );
    let mut chat = Command::new(env!("CARGO_BIN_EXE_ferrosa"))
        .args(["chat", "--resume", "--memory", memory])
        .env("FERROSA_MODELS_DIR", &models)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    {
        use std::io::Write;
        let mut stdin = chat.stdin.take().unwrap();
        stdin
            .write_all(b"and the mean of 2, 4 and 9?\n/quit\n")
            .unwrap();
    }
    let out = chat.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("resumed the conversation of") && err.contains("1 exchanges"),
        "{err}"
    );
    let out = ferrosa(&["memory", "export", "--memory", memory], &models);
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON export");
    let runs = doc["robots"]["none"]["requests"].as_array().unwrap();
    assert_eq!(runs.len(), 2, "{doc}");
    assert_eq!(runs[0]["session"], runs[1]["session"], "{doc}");
    assert!(
        runs[1]["answer"].as_str().unwrap().contains("mean 5"),
        "{doc}"
    );
    let out = ferrosa(&["memory", "forget", "--runs", "--memory", memory], &models);
    assert!(out.status.success());
    let out = ferrosa(&["memory", "list", "--memory", memory], &models);
    // Nothing else was kept for the robot: it is gone from the file.
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("nothing is kept"),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let out = ferrosa(
        &["memory", "forget", "--fact", "99", "--memory", memory],
        &models,
    );
    assert_one_line_error(&out, &["no fact #99", "ferrosa memory list"]);
}

#[test]
fn a_bad_policy_file_is_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("policy.toml");
    std::fs::write(&p, "deny = [\"(unclosed\"]\n").unwrap();
    let out = ferrosa(
        &["ask", "--policy", p.to_str().unwrap(), "hi"],
        &models_dir(),
    );
    assert_one_line_error(&out, &["invalid pattern", "(unclosed"]);
}
