//! The remote engine (`--engine openai`) against a real llama-server (built from the
//! llama.cpp tree in the llama-cpp-python sdist by `scripts/build-llama-cpp.sh`, started on
//! loopback with the default model), and against deliberately broken servers: one that
//! ignores the grammar, one that answers with what is not JSON, one that never answers.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpListener;
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use ferrosa::remote::{GrammarMode, Remote, RemoteError, RemoteOptions};

use crate::support::llama_server::{self, Server};
use crate::util::{model_path, models_dir};

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// llama-server with the default model, as the README's fleet set-up starts it.
fn start_server() -> Server {
    let bin = llama_server::binary().expect(
        "no llama-server: build it with scripts/build-llama-cpp.sh llama-server (.ci/setup does), or set LLAMA_SERVER",
    );
    Server::start(&bin, &model_path("smollm2-135m"), 2, 8192)
}

fn options(url: &str, grammar: GrammarMode) -> RemoteOptions {
    RemoteOptions {
        url: url.to_string(),
        api_key_env: None,
        model: None,
        grammar,
        timeout: Duration::from_secs(120),
    }
}

/// The vocabulary-only load of a catalog model, as `--engine openai` does.
fn vocabulary(name: &str) -> Box<dyn ferrosa::backend::Backend> {
    let mut opts = ferrosa::backend::LoadOptions::new(model_path(name));
    opts.family = ferrosa::models::Catalog::load(&models_dir())
        .ok()
        .and_then(|c| c.get(name).map(|e| e.family.clone()));
    ferrosa::backend::load_vocabulary(&opts).unwrap()
}

fn ferrosa(args: &[&str]) -> std::process::Output {
    Command::new("timeout")
        .args(["600", env!("CARGO_BIN_EXE_ferrosa")])
        .args(args)
        .env("FERROSA_MODELS_DIR", models_dir())
        .output()
        .unwrap()
}

/// `ferrosa eval bfcl` over a slice of four BFCL categories through `url` with `args`;
/// the report, and checks that every call the server wrote is valid for its schema (and
/// that at least `min_calls` questions made one).
fn bfcl_through(url: &str, args: &[&str], limit: usize, min_calls: usize) -> String {
    let d = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/bfcl");
    let out = tempfile::tempdir().unwrap();
    let files: Vec<String> = ["simple_python", "multiple", "parallel", "irrelevance"]
        .iter()
        .map(|c| d.join(format!("BFCL_v4_{c}.json")).display().to_string())
        .collect();
    let out_dir = out.path().display().to_string();
    let limit = limit.to_string();
    let mut all = vec!["eval", "bfcl"];
    all.extend(files.iter().map(String::as_str));
    all.extend([
        "--engine", "openai", "--url", url, "--limit", &limit, "--out", &out_dir,
    ]);
    all.extend(args);
    let o = ferrosa(&all);
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    eprintln!("{stdout}");
    let cases = std::fs::read_to_string(out.path().join("bfcl_cases.jsonl")).unwrap();
    let (mut calls, mut total) = (0, 0);
    for line in cases.lines() {
        let c: serde_json::Value = serde_json::from_str(line).unwrap();
        total += 1;
        if c["attempted_call"] == true {
            calls += 1;
            assert_eq!(
                c["valid_call"], true,
                "an invalid call through the server: {c}"
            );
        }
    }
    assert_eq!(total, 4 * limit.parse::<usize>().unwrap());
    assert!(
        calls >= min_calls,
        "only {calls} of {total} questions made a call"
    );
    stdout
}

/// Everything against one real server (its start is the costly part): the grammar form
/// it takes, a model it does not run, a BFCL slice in both grammar forms whose every call
/// must be valid, and the agent answering through it.
#[test]
#[ignore = "needs the model weights and llama-server: cargo test --release -- --include-ignored"]
fn the_remote_engine_against_llama_server() {
    let server = start_server();
    let vocab = vocabulary("smollm2-135m");

    // This build has llguidance: auto settles on Lark; JSON schemas when asked.
    let r = Remote::connect(
        &options(&server.url, GrammarMode::Auto),
        vocab.as_ref(),
        "smollm2",
    )
    .unwrap();
    assert_eq!(
        r.grammar(),
        ferrosa::remote::Grammar::Lark,
        "{}",
        r.describe()
    );
    let r = Remote::connect(
        &options(&server.url, GrammarMode::JsonSchema),
        vocab.as_ref(),
        "smollm2",
    )
    .unwrap();
    assert_eq!(r.grammar(), ferrosa::remote::Grammar::JsonSchema);
    // Another model's vocabulary would send ids that mean other text.
    let gemma = vocabulary("gemma3-270m");
    match Remote::connect(
        &options(&server.url, GrammarMode::Auto),
        gemma.as_ref(),
        "gemma",
    ) {
        Err(RemoteError::OtherModel { .. }) => {}
        other => panic!(
            "gemma's vocabulary against smollm2: {:?}",
            other.map(|r| r.describe())
        ),
    }

    // BFCL slices through the CLI, in each grammar form (the form named in the report),
    // and prose-or-call turns (`--answer-mode prose`) under JSON schemas.
    let report = bfcl_through(&server.url, &[], 3, 6);
    assert!(report.contains("Lark grammar"), "{report}");
    let report = bfcl_through(&server.url, &["--grammar", "json-schema"], 3, 6);
    assert!(report.contains("JSON schema"), "{report}");
    bfcl_through(
        &server.url,
        &["--grammar", "json-schema", "--answer-mode", "prose"],
        2,
        1,
    );

    // The agent, its tools and its policy, with the model on the server.
    let trace = tempfile::tempdir().unwrap();
    let o = ferrosa(&[
        "ask",
        "--engine",
        "openai",
        "--url",
        &server.url,
        "--json",
        "--trace-dir",
        &trace.path().display().to_string(),
        "convert 3 meters to feet",
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let run: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(run["answer"].as_str().unwrap().contains("9.84"), "{run}");
    let file = std::fs::read_dir(trace.path())
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let text = std::fs::read_to_string(file).unwrap();
    assert!(
        text.contains(&format!("openai-compatible server {}", server.url))
            && text.contains("Lark grammar"),
        "the trace says where the model ran: {text}"
    );
}

/// A server of scripted answers on loopback: each connection gets the answer the
/// request's path picks.
fn scripted(answer: fn(&str) -> Option<String>) -> String {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            std::thread::spawn(move || {
                let mut reader = BufReader::new(stream.try_clone().unwrap());
                let mut line = String::new();
                reader.read_line(&mut line).unwrap();
                let path = line.split_whitespace().nth(1).unwrap_or("/").to_string();
                let mut length = 0;
                loop {
                    let mut h = String::new();
                    reader.read_line(&mut h).unwrap();
                    if h.trim().is_empty() {
                        break;
                    }
                    if let Some(v) = h.to_ascii_lowercase().strip_prefix("content-length:") {
                        length = v.trim().parse().unwrap();
                    }
                }
                let mut body = vec![0; length];
                reader.read_exact(&mut body).unwrap();
                let mut stream = stream;
                match answer(&path) {
                    Some(a) => {
                        let _ = stream.write_all(a.as_bytes());
                    }
                    // Never answer (the connection stays open until the test ends).
                    None => std::thread::sleep(Duration::from_secs(30)),
                }
            });
        }
    });
    url
}

fn http(status: &str, content_type: &str, body: &str) -> String {
    format!("HTTP/1.1 {status}\r\nContent-Type: {content_type}\r\nConnection: close\r\n\r\n{body}")
}

fn models(path: &str) -> Option<String> {
    match path {
        "/v1/models" => Some(http(
            "200 OK",
            "application/json",
            r#"{"data": [{"id": "m"}]}"#,
        )),
        _ => Some(http(
            "404 Not Found",
            "application/json",
            r#"{"error": {"message": "no such path"}}"#,
        )),
    }
}

/// A turn through a connected scripted server, as the agent asks it.
fn one_turn(
    url: &str,
) -> Result<ferrosa::decode::request::TurnResult, ferrosa::decode::DecodeError> {
    use ferrosa::chat::{ChatMessage, Role};
    use ferrosa::decode::request::TurnRequest;
    use ferrosa::decode::{Decoding, Envelope, ToolChoice};
    let vocab = vocabulary("smollm2-135m");
    let mut opts = options(url, GrammarMode::JsonSchema);
    opts.timeout = Duration::from_secs(2);
    let mut remote = Remote::connect(&opts, vocab.as_ref(), "smollm2").unwrap();
    let specs = vec![ferrosa::tool::ToolSpec::new(
        "calc_convert",
        "Convert a value between units.",
        serde_json::json!({"type": "object", "properties": {"value": {"type": "number"}}, "required": ["value"]}),
    )
    .unwrap()];
    let messages = [ChatMessage::new(Role::User, "convert 3 meters to feet")];
    let req = TurnRequest {
        messages: &messages,
        specs: &specs,
        allowed: None,
        envelope: Envelope::Smollm2,
        choice: ToolChoice::Required,
        parallel: true,
        decoding: Decoding::Constrained,
        max_tokens: 64,
    };
    remote.turn(vocab.as_ref(), &req, &mut |_| {
        std::ops::ControlFlow::Continue(())
    })
}

fn remote_error(e: ferrosa::decode::DecodeError) -> RemoteError {
    match e {
        ferrosa::decode::DecodeError::Engine(e) => *e.downcast::<RemoteError>().unwrap(),
        other => panic!("not the engine's error: {other}"),
    }
}

#[test]
#[ignore = "needs the model weights (the vocabulary): cargo test --release -- --include-ignored"]
fn a_server_that_ignores_the_grammar_or_breaks_the_api_is_reported() {
    // Text no call list schema allows: reported, nothing of it used.
    let url = scripted(|path| {
        match path {
        "/v1/completions" => Some(http(
            "200 OK",
            "text/event-stream",
            "data: {\"choices\": [{\"text\": \"[{\\\"name\\\": \\\"calc_convert\\\", \\\"arguments\\\": {\\\"value\\\": \", \"finish_reason\": null}]}\n\n\
             data: {\"choices\": [{\"text\": \"three}}]\", \"finish_reason\": \"stop\"}]}\n\ndata: [DONE]\n\n",
        )),
        p => models(p),
    }
    });
    let e = remote_error(one_turn(&url).unwrap_err());
    assert!(matches!(e, RemoteError::IgnoredGrammar { .. }), "{e}");
    assert!(e.to_string().contains("nothing it wrote was used"), "{e}");

    // A valid call of a tool that was not offered is as much a breach.
    let url = scripted(|path| {
        match path {
        "/v1/completions" => Some(http(
            "200 OK",
            "text/event-stream",
            "data: {\"choices\": [{\"text\": \"[{\\\"name\\\": \\\"turtle_teleport\\\", \\\"arguments\\\": {}}]\", \"finish_reason\": \"stop\"}]}\n\ndata: [DONE]\n\n",
        )),
        p => models(p),
    }
    });
    let e = remote_error(one_turn(&url).unwrap_err());
    assert!(matches!(e, RemoteError::IgnoredGrammar { .. }), "{e}");

    // However the server says the completion ended ("length" here), and a list longer
    // than allowed (4 calls at most).
    let url = scripted(|path| {
        match path {
        "/v1/completions" => Some(http(
            "200 OK",
            "text/event-stream",
            "data: {\"choices\": [{\"text\": \"[{\\\"name\\\": \\\"turtle_teleport\\\", \\\"arguments\\\": {}}]\", \"finish_reason\": \"length\"}]}\n\ndata: [DONE]\n\n",
        )),
        p => models(p),
    }
    });
    let e = remote_error(one_turn(&url).unwrap_err());
    assert!(matches!(e, RemoteError::IgnoredGrammar { .. }), "{e}");
    let url = scripted(|path| match path {
        "/v1/completions" => {
            let list: Vec<String> = (1..=5)
                .map(|v| {
                    format!(r#"{{\"name\": \"calc_convert\", \"arguments\": {{\"value\": {v}}}}}"#)
                })
                .collect();
            let list = list.join(", ");
            Some(http(
                "200 OK",
                "text/event-stream",
                &format!("data: {{\"choices\": [{{\"text\": \"[{list}]\", \"finish_reason\": \"stop\"}}]}}\n\ndata: [DONE]\n\n"),
            ))
        }
        p => models(p),
    });
    let e = remote_error(one_turn(&url).unwrap_err());
    assert!(e.to_string().contains("at most 4"), "{e}");

    // What is not the API's JSON.
    let url = scripted(|path| match path {
        "/v1/completions" => Some(http(
            "200 OK",
            "text/event-stream",
            "data: {\"choices\": [{\"text\": \"[\"\n\n",
        )),
        p => models(p),
    });
    let e = remote_error(one_turn(&url).unwrap_err());
    assert!(matches!(e, RemoteError::BadAnswer { .. }), "{e}");
    let url = scripted(|_| {
        Some(http(
            "200 OK",
            "application/json",
            "<html>proxy login</html>",
        ))
    });
    let vocab = vocabulary("smollm2-135m");
    match Remote::connect(&options(&url, GrammarMode::Auto), vocab.as_ref(), "smollm2") {
        Err(e @ RemoteError::BadAnswer { .. }) => {
            assert!(e.to_string().contains("not JSON"), "{e}")
        }
        other => panic!("{:?}", other.map(|r| r.describe())),
    }

    // The server's own error, passed on.
    let url = scripted(|path| match path {
        "/v1/completions" => Some(http(
            "400 Bad Request",
            "application/json",
            r#"{"error": {"code": 400, "message": "the request exceeds the available context size"}}"#,
        )),
        p => models(p),
    });
    let e = remote_error(one_turn(&url).unwrap_err());
    assert!(
        e.to_string().contains("exceeds the available context"),
        "{e}"
    );

    // A server that never answers: a time-out, not a hang.
    let url = scripted(|path| match path {
        "/v1/completions" => None,
        p => models(p),
    });
    let e = remote_error(one_turn(&url).unwrap_err());
    assert!(matches!(e, RemoteError::Timeout { .. }), "{e}");

    // A server without llguidance (llama-server's own words): Lark is refused with its
    // reason when asked for; auto settles on JSON schemas.
    let url = scripted(|path| match path {
        "/v1/completions" => Some(http(
            "400 Bad Request",
            "application/json",
            r#"{"error": {"code": 400, "message": "Failed to initialize samplers: failed to parse grammar: llguidance is not enabled"}}"#,
        )),
        p => models(p),
    });
    match Remote::connect(&options(&url, GrammarMode::Lark), vocab.as_ref(), "m") {
        Err(e @ RemoteError::NoLark { .. }) => {
            assert!(e.to_string().contains("llguidance is not enabled"), "{e}")
        }
        other => panic!("{:?}", other.map(|r| r.describe())),
    }
    let r = Remote::connect(&options(&url, GrammarMode::Auto), vocab.as_ref(), "m").unwrap();
    assert_eq!(r.grammar(), ferrosa::remote::Grammar::JsonSchema);

    // Nothing listening.
    let port = free_port();
    match Remote::connect(
        &options(&format!("http://127.0.0.1:{port}"), GrammarMode::Auto),
        vocab.as_ref(),
        "m",
    ) {
        Err(e @ RemoteError::Connect { .. }) => {
            assert!(e.to_string().contains("is it running"), "{e}")
        }
        other => panic!("{:?}", other.map(|r| r.describe())),
    }
}
