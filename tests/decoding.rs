//! Constrained decoding: every call valid by construction, on the real SmolLM2
//! vocabulary (property test with a uniform sampler over allowed tokens) and with the real
//! model (50 operator requests over 28 robot tools).

use std::ops::ControlFlow;

use ferrosa::backend::uniform::Uniform;
use ferrosa::backend::{Backend, BackendKind, ChatMessage, Detokenizer, Gguf, Role};
use ferrosa::decode::envelope::{Envelope, ToolChoice};
use ferrosa::decode::sample::Rng;
use ferrosa::decode::turn::{assistant_turn, TurnRequest, TurnResult};
use ferrosa::decode::{generate, Decoding, Finish, Grammars, Sampler, SamplerConfig, Session};
use ferrosa::tool::{ToolCall, ToolSpec};
use serde_json::{json, Map, Value};

use crate::util::{load, model_path};

const UNIFORM: SamplerConfig = SamplerConfig {
    temperature: 1.0,
    top_k: 0,
    top_p: 1.0,
    seed: 0,
};

/// A random JSON schema for a value, `depth` levels of nesting left.
fn random_schema(rng: &mut Rng, depth: u32) -> Value {
    let kinds = if depth == 0 { 6 } else { 8 };
    match rng.below(kinds) {
        0 => {
            let mut s = json!({"type": "string", "maxLength": 1 + rng.below(12)});
            if rng.below(3) == 0 {
                s["minLength"] = json!(1);
            }
            s
        }
        1 => {
            let mut s = json!({"type": "integer"});
            if rng.below(2) == 0 {
                let lo = rng.below(50) as i64 - 25;
                s["minimum"] = json!(lo);
                s["maximum"] = json!(lo + rng.below(1000) as i64);
            }
            s
        }
        2 => {
            let mut s = json!({"type": "number"});
            if rng.below(2) == 0 {
                s["minimum"] = json!(-1.5);
                s["maximum"] = json!(rng.below(100) as f64 + 0.25);
            }
            s
        }
        3 => json!({"type": "boolean"}),
        4 => {
            let n = 1 + rng.below(4);
            let vals: Vec<String> = (0..n)
                .map(|i| format!("opt{i}_{}", rng.below(99)))
                .collect();
            json!({"type": "string", "enum": vals})
        }
        5 => json!({"enum": [1, "two", null, true]}),
        6 => json!({
            "type": "array",
            "items": random_schema(rng, depth - 1),
            "maxItems": 1 + rng.below(3),
        }),
        _ => random_object(rng, depth - 1),
    }
}

fn random_object(rng: &mut Rng, depth: u32) -> Value {
    let mut props = Map::new();
    let mut required = Vec::new();
    for i in 0..rng.below(5) {
        let name = format!(
            "{}_{i}",
            ["speed", "topic", "x", "mode", "count", "name"][rng.below(6)]
        );
        props.insert(name.clone(), random_schema(rng, depth));
        if rng.below(2) == 0 {
            required.push(name);
        }
    }
    json!({"type": "object", "properties": props, "required": required})
}

fn random_tools(rng: &mut Rng) -> Vec<ToolSpec> {
    (0..1 + rng.below(4))
        .map(|i| {
            ToolSpec::new(
                format!("tool_{i}_{}", rng.below(1000)),
                "random",
                random_object(rng, 2),
            )
            .expect("generated schemas are valid")
        })
        .collect()
}

/// Decode one turn with uniform sampling among allowed tokens; return the text.
fn uniform_turn(
    backend: &mut dyn Backend,
    grammars: &Grammars,
    lark: &str,
    seed: u64,
) -> (String, Finish) {
    let mut c = grammars
        .compile(lark)
        .unwrap_or_else(|e| panic!("{e}\n{lark}"));
    let mut sampler = Sampler::new(SamplerConfig { seed, ..UNIFORM }, backend.vocab().len());
    let vocab = backend.vocab().clone();
    let mut detok = Detokenizer::new(false);
    let mut text = String::new();
    let (finish, _) = generate(
        backend,
        &mut Session::new(),
        &[0],
        2000,
        &mut sampler,
        Some(&mut c),
        |t| {
            detok.push(&vocab, t, &mut text);
            ControlFlow::Continue(())
        },
    )
    .unwrap();
    detok.finish(&mut text);
    (text, finish)
}

/// Check every call independently of ferrosa's parser: serde_json and jsonschema only.
fn check_calls(calls: &[Value], specs: &[ToolSpec], text: &str) {
    assert!(!calls.is_empty(), "no calls in {text}");
    for call in calls {
        let name = call["name"]
            .as_str()
            .unwrap_or_else(|| panic!("no name: {text}"));
        let spec = specs
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("unknown {name}: {text}"));
        let keys: Vec<&String> = call.as_object().unwrap().keys().collect();
        assert_eq!(keys, ["name", "arguments"], "{text}");
        let v = jsonschema::validator_for(&spec.parameters).unwrap();
        let errs: Vec<String> = v
            .iter_errors(&call["arguments"])
            .map(|e| e.to_string())
            .collect();
        assert!(
            errs.is_empty(),
            "{errs:?}\nschema {}\ncall {call}",
            spec.parameters
        );
    }
}

#[test]
fn random_schemas_always_decode_to_valid_calls_on_the_smollm2_vocabulary() {
    let g = Gguf::open(&model_path("smollm2-135m")).unwrap();
    let mut backend = Uniform::from_gguf(&g).unwrap();
    let grammars = Grammars::new(backend.vocab(), backend.tokenizer()).unwrap();
    let mut rng = Rng::new(2026);
    let cases = 300;
    for case in 0..cases {
        let mut specs = random_tools(&mut rng);
        if rng.below(3) == 0 {
            specs.push(ferrosa::agent::answer_spec());
        }
        let parallel = rng.below(2) == 0;
        for env in [Envelope::Smollm2, Envelope::Json] {
            let lark = env.grammar(&specs, ToolChoice::Required, parallel);
            let (text, finish) = uniform_turn(&mut backend, &grammars, &lark, case);
            assert_eq!(
                finish,
                Finish::EndOfGeneration,
                "case {case} {env:?}: {text}"
            );
            let calls: Vec<Value> = match env {
                Envelope::Smollm2 => {
                    let body = text
                        .strip_prefix("<tool_call>")
                        .and_then(|t| t.strip_suffix("</tool_call>"))
                        .unwrap_or_else(|| panic!("envelope: {text}"));
                    serde_json::from_str(body).unwrap_or_else(|e| panic!("{e}: {text}"))
                }
                _ => {
                    let v: Value =
                        serde_json::from_str(&text).unwrap_or_else(|e| panic!("{e}: {text}"));
                    v["tool_calls"].as_array().cloned().unwrap_or_default()
                }
            };
            if !parallel || calls.iter().any(|c| c["name"] == "reply") {
                assert_eq!(calls.len(), 1, "{text}");
            }
            check_calls(&calls, &specs, &text);
            // ferrosa's own parser agrees (keeping the first of word-for-word repeats).
            let turn = env.parse(&text, &specs).unwrap();
            let mut distinct: Vec<&Value> = Vec::new();
            for c in &calls {
                if !distinct.contains(&c) {
                    distinct.push(c);
                }
            }
            assert_eq!(turn.calls.len(), distinct.len(), "{text}");
        }
    }
}

#[test]
fn qwen_envelope_with_special_marker_tokens_decodes_valid_calls() {
    let mut backend =
        Uniform::bytes_with_specials(&["<|im_end|>"], &["<tool_call>", "</tool_call>"]);
    let grammars = Grammars::new(backend.vocab(), backend.tokenizer()).unwrap();
    let mut rng = Rng::new(7);
    for case in 0..60 {
        let specs = random_tools(&mut rng);
        let lark = Envelope::Qwen.grammar(&specs, ToolChoice::Required, case % 2 == 0);
        let (text, finish) = uniform_turn(&mut backend, &grammars, &lark, case);
        assert_eq!(finish, Finish::EndOfGeneration, "{text}");
        let turn = Envelope::Qwen
            .parse(&text, &specs)
            .unwrap_or_else(|e| panic!("{e}: {text}"));
        let raw: Vec<Value> = turn
            .calls
            .iter()
            .map(|c| json!({"name": c.name, "arguments": c.arguments}))
            .collect();
        check_calls(&raw, &specs, &text);
    }
}

/// A uniform model over SmolLM2's vocabulary and the grammars for it.
fn smollm2_uniform() -> (Uniform, Grammars) {
    let g = Gguf::open(&model_path("smollm2-135m")).unwrap();
    let backend = Uniform::from_gguf(&g).unwrap();
    let grammars = Grammars::new(backend.vocab(), backend.tokenizer()).unwrap();
    (backend, grammars)
}

/// An object that requires names it never declares (as some BFCL functions do) still
/// gives a grammar once closed, alone or beside the answer tool, and what it decodes
/// validates.
#[test]
fn required_but_undeclared_properties_still_give_a_grammar() {
    let (mut backend, grammars) = smollm2_uniform();
    let spec = ToolSpec::new(
        "waste",
        "Waste of a household.",
        json!({"type": "object", "properties": {
            "population": {"type": "object", "properties": {}, "required": ["adults", "children"]}
        }, "required": ["population"]}),
    )
    .unwrap();
    for specs in [
        vec![spec.clone()],
        vec![spec, ferrosa::agent::answer_spec()],
    ] {
        for seed in 0..8 {
            let lark = Envelope::Smollm2.grammar(&specs, ToolChoice::Required, false);
            let (text, finish) = uniform_turn(&mut backend, &grammars, &lark, seed);
            assert_eq!(finish, Finish::EndOfGeneration, "{text}");
            let turn = Envelope::Smollm2
                .parse(&text, &specs)
                .unwrap_or_else(|e| panic!("{e}: {text}"));
            assert_eq!(turn.calls.len(), 1, "{text}");
        }
    }
}

/// The answer tool is called alone: the first call of a list, and then the list closes;
/// after another call it is not offered at all. Every envelope, calls written as each
/// envelope writes them.
#[test]
fn a_tool_called_alone_is_the_only_call_of_its_turn() {
    let specs = vec![
        ToolSpec::new(
            "system_time",
            "Current time.",
            json!({"type": "object", "properties": {}}),
        )
        .unwrap(),
        ferrosa::agent::answer_spec(),
    ];
    let time = r#"{"name": "system_time", "arguments": {}}"#;
    let reply = r#"{"name": "reply", "arguments": {"text": "It is noon"}}"#;
    let (smol, smol_grammars) = smollm2_uniform();
    let qwen = Uniform::bytes_with_specials(&["<|im_end|>"], &["<tool_call>", "</tool_call>"]);
    let qwen_grammars = Grammars::new(qwen.vocab(), qwen.tokenizer()).unwrap();
    let qwen_block = |call: &str| format!("<tool_call>\n{call}\n</tool_call>");
    let cases: [(Envelope, &Uniform, &Grammars, Vec<String>, Vec<String>); 3] = [
        (
            Envelope::Smollm2,
            &smol,
            &smol_grammars,
            vec![
                format!("<tool_call>[\n{reply}\n]</tool_call>"),
                format!("<tool_call>[\n{time},\n{time}\n]</tool_call>"),
            ],
            vec![
                format!("<tool_call>[\n{reply},\n"),
                format!("<tool_call>[\n{time},\n{{\"name\": \"reply"),
            ],
        ),
        (
            Envelope::Json,
            &smol,
            &smol_grammars,
            vec![
                format!("{{\"tool_calls\": [{reply}]}}"),
                format!("{{\"tool_calls\": [{time}, {time}]}}"),
            ],
            vec![
                format!("{{\"tool_calls\": [{reply}, "),
                format!("{{\"tool_calls\": [{time}, {{\"name\": \"reply"),
            ],
        ),
        (
            Envelope::Qwen,
            &qwen,
            &qwen_grammars,
            vec![
                qwen_block(reply),
                format!("{}\n{}", qwen_block(time), qwen_block(time)),
            ],
            vec![
                format!("{}\n<tool_call>", qwen_block(reply)),
                format!("{}\n<tool_call>\n{{\"name\": \"reply", qwen_block(time)),
            ],
        ),
    ];
    for (env, backend, grammars, allowed, refused) in cases {
        let lark = env.grammar(&specs, ToolChoice::Required, true);
        for text in &allowed {
            let mut c = grammars.compile(&lark).unwrap();
            let toks = backend.tokenize(text, true).unwrap();
            assert!(c.allows(&toks), "{env:?} refuses {text}");
            for &t in &toks {
                c.advance(t).unwrap();
            }
            assert!(
                c.is_stopped() || c.is_accepting(),
                "{env:?} does not end at {text}"
            );
            assert!(env.parse(text, &specs).is_ok(), "{env:?}: {text}");
        }
        for text in &refused {
            let mut c = grammars.compile(&lark).unwrap();
            let toks = backend.tokenize(text, true).unwrap();
            assert!(!c.allows(&toks), "{env:?} allows {text}");
        }
    }
}

#[test]
fn prose_mode_never_emits_the_marker_and_none_mode_never_calls() {
    let (backend, grammars) = smollm2_uniform();
    let specs = random_tools(&mut Rng::new(3));
    let lark = Envelope::Smollm2.grammar(&specs, ToolChoice::Auto, true);
    let mut c = grammars.compile(&lark).unwrap();
    // Prose may not spell the marker; after the marker only JSON is allowed.
    let prose = backend.tokenize("The robot is fine. ", false).unwrap();
    assert!(c.allows(&prose));
    let marker = backend.tokenize("<tool_call>", false).unwrap();
    let mut after: Vec<u32> = prose.clone();
    after.extend(&marker);
    assert!(c.allows(&after), "the marker opens a call");
    after.extend(backend.tokenize("hello", false).unwrap());
    assert!(!c.allows(&after), "text after the marker must be a call");
    let none = Envelope::Smollm2.grammar(&specs, ToolChoice::None, true);
    let mut c = grammars.compile(&none).unwrap();
    assert!(c.allows(&prose));
}

#[test]
fn decline_mode_allows_an_empty_call_list_and_required_mode_does_not() {
    let (backend, grammars) = smollm2_uniform();
    let specs = random_tools(&mut Rng::new(5));
    let empty = backend
        .tokenize("<tool_call>[]</tool_call>", false)
        .unwrap();
    let call = Envelope::Smollm2.render_calls(&[ToolCall {
        name: specs[0].name.clone(),
        arguments: json!({}),
    }]);
    let opening = backend
        .tokenize(&call[..call.find('{').unwrap()], false)
        .unwrap();
    for (choice, empty_ok) in [(ToolChoice::Decline, true), (ToolChoice::Required, false)] {
        let lark = Envelope::Smollm2.grammar(&specs, choice, true);
        assert_eq!(
            grammars.compile(&lark).unwrap().allows(&empty),
            empty_ok,
            "{choice:?}"
        );
        assert!(
            grammars.compile(&lark).unwrap().allows(&opening),
            "{choice:?}: a call list opens with one call per line: {call}"
        );
    }
    let turn = Envelope::Smollm2
        .parse("<tool_call>[]</tool_call>", &specs)
        .unwrap();
    assert!(turn.calls.is_empty() && turn.prose.is_empty());
    // JSON envelope: `{"tool_calls": []}` only when declining.
    let json_empty = backend.tokenize(r#"{"tool_calls": []}"#, false).unwrap();
    for (choice, ok) in [(ToolChoice::Decline, true), (ToolChoice::Required, false)] {
        let lark = Envelope::Json.grammar(&specs, choice, true);
        assert_eq!(
            grammars.compile(&lark).unwrap().allows(&json_empty),
            ok,
            "{choice:?}"
        );
    }
}

fn robot_tools() -> Vec<ToolSpec> {
    let raw: Vec<Value> =
        serde_json::from_str(include_str!("data/robot_tools.json")).expect("robot_tools.json");
    raw.into_iter()
        .map(|t| {
            ToolSpec::new(
                t["name"].as_str().unwrap(),
                t["description"].as_str().unwrap(),
                t["parameters"].clone(),
            )
            .unwrap()
        })
        .collect()
}

/// One assistant turn, greedy.
fn greedy_turn(
    model: &mut dyn Backend,
    session: &mut Session,
    grammars: &Grammars,
    req: &TurnRequest,
) -> TurnResult {
    let mut sampler = Sampler::new(SamplerConfig::default(), model.vocab().len());
    assistant_turn(model, session, grammars, &mut sampler, req, |_| {
        ControlFlow::Continue(())
    })
    .unwrap()
}

/// The real model, 50 requests, required mode: every turn is a schema-valid call. The
/// same requests decoded freely are parsed the same way and their validity printed (run
/// with `--nocapture` to see both rates).
#[test]
fn real_model_makes_only_valid_calls_when_constrained() {
    let mut model = load("smollm2-135m", BackendKind::Llama, 8192);
    let grammars = Grammars::new(model.vocab(), model.tokenizer()).unwrap();
    let specs = robot_tools();
    assert!(specs.len() >= 20);
    let requests: Vec<&str> = include_str!("data/operator_requests.txt").lines().collect();
    assert_eq!(requests.len(), 50);
    let system = ChatMessage::new(
        Role::System,
        "You are the control assistant of a small mobile robot. Use the tools to act.",
    );
    let mut valid = [0usize; 2];
    let mut forced = 0;
    let mut emitted = 0;
    for (i, decoding) in [Decoding::Constrained, Decoding::Free]
        .into_iter()
        .enumerate()
    {
        let mut session = Session::new();
        for q in &requests {
            let messages = [system.clone(), ChatMessage::new(Role::User, *q)];
            let req = TurnRequest {
                messages: &messages,
                specs: &specs,
                allowed: None,
                envelope: Envelope::Smollm2,
                choice: ToolChoice::Required,
                parallel: true,
                decoding,
                // Free decoding rambles (prose, code); 64 tokens is room for any call it
                // could make to these tools and keeps the test short.
                max_tokens: if decoding == Decoding::Free { 64 } else { 160 },
                relevance_gate: None,
                copy: None,
            };
            let r = greedy_turn(model.as_mut(), &mut session, &grammars, &req);
            let ok = matches!(&r.turn, Ok(t) if !t.calls.is_empty());
            if decoding == Decoding::Constrained {
                assert!(
                    ok,
                    "{q:?} gave no valid call: {:?} {:?} {}",
                    r.turn, r.finish, r.text
                );
                forced += r.stats.forced_tokens;
                emitted += r.stats.generated_tokens;
            }
            valid[i] += usize::from(ok);
        }
    }
    eprintln!(
        "valid calls on 50 requests: constrained {}/50, free {}/50; forced tokens {forced} of {emitted} emitted ({:.0}%)",
        valid[0],
        valid[1],
        100.0 * forced as f64 / emitted.max(1) as f64
    );
    assert_eq!(valid[0], 50);
}

/// BFCL's parallel_0 function: one tool a request asks for twice.
fn spotify_play() -> ToolSpec {
    ToolSpec::new(
        "spotify.play",
        "Play specific tracks from a given artist for a specific time duration.",
        json!({"type": "object", "properties": {
            "artist": {"type": "string", "description": "The artist whose songs you want to play."},
            "duration": {"type": "integer", "description": "The duration for which the songs should be played, in minutes."}},
            "required": ["artist", "duration"]}),
    )
    .unwrap()
}

/// The relevance gate on the real model: over operator requests (28 robot tools and a
/// `reply` tool to fall back on) every gated turn is still a schema-valid call; a
/// question no tool touches takes the fallback; a request for two plays of one tool gets
/// two different calls.
#[test]
fn relevance_gate_keeps_calls_valid_and_declines_unrelated_questions() {
    let mut model = load("smollm2-135m", BackendKind::Llama, 8192);
    let grammars = Grammars::new(model.vocab(), model.tokenizer()).unwrap();
    let mut specs = robot_tools();
    specs.push(ferrosa::agent::answer_spec());
    let system = ChatMessage::new(
        Role::System,
        "You are the control assistant of a small mobile robot. Use the tools to act.",
    );
    let mut session = Session::new();
    let mut turn = |specs: &[ToolSpec], q: &str| {
        let messages = [system.clone(), ChatMessage::new(Role::User, q)];
        let req = TurnRequest {
            messages: &messages,
            specs,
            allowed: None,
            envelope: Envelope::Smollm2,
            choice: ToolChoice::Required,
            parallel: true,
            decoding: Decoding::Constrained,
            max_tokens: 160,
            relevance_gate: Some(ferrosa::agent::ANSWER_TOOL),
            copy: None,
        };
        let r = greedy_turn(model.as_mut(), &mut session, &grammars, &req);
        match (&r.turn, r.finish) {
            (Ok(t), Finish::EndOfGeneration) if !t.calls.is_empty() => Some(t.calls.clone()),
            // A value that runs past the token limit is cut off, gate or not.
            (_, Finish::Length) => None,
            _ => panic!(
                "{q:?} gave no valid call: {:?} {:?} {}",
                r.turn, r.finish, r.text
            ),
        }
    };
    // A dozen of them: a gated turn over 29 tools costs several times a plain one.
    let requests: Vec<&str> = include_str!("data/operator_requests.txt")
        .lines()
        .take(12)
        .collect();
    let (mut declined, mut cut_off) = (0, 0);
    for q in &requests {
        match turn(&specs, q) {
            Some(calls) => declined += usize::from(calls[0].name == ferrosa::agent::ANSWER_TOOL),
            None => cut_off += 1,
        }
    }
    eprintln!(
        "gated: {declined} of {} operator requests answered without a tool, {cut_off} cut off at 160 tokens",
        requests.len()
    );
    for q in [
        "Who wrote the play Hamlet?",
        "What is the capital of France?",
    ] {
        let calls = turn(&specs, q).expect("a reply within 160 tokens");
        assert_eq!(
            calls[0].name,
            ferrosa::agent::ANSWER_TOOL,
            "{q:?}: {calls:?}"
        );
    }
    let music = [spotify_play(), ferrosa::agent::answer_spec()];
    let calls = turn(
        &music,
        "Play songs from the artists Taylor Swift and Maroon 5, with a play time of 20 minutes and 15 minutes respectively, on Spotify.",
    )
    .expect("two short calls within 160 tokens");
    assert_eq!(calls.len(), 2, "{calls:?}");
    assert!(calls.iter().all(|c| c.name == "spotify.play"), "{calls:?}");
}

/// Copy bias on the real model, gated: values come from the request as written (a name
/// of two words, a number with digit groups), a request for two plays gets exactly the
/// two it named, and a question no tool touches still takes the fallback.
#[test]
fn copy_bias_writes_the_values_the_request_spelled() {
    let mut model = load("smollm2-135m", BackendKind::Llama, 8192);
    let grammars = Grammars::new(model.vocab(), model.tokenizer()).unwrap();
    let mut session = Session::new();
    let tool = |name: &str, description: &str, parameters: Value| {
        ToolSpec::new(name, description, parameters).unwrap()
    };
    let specs = [
        spotify_play(),
        tool(
            "mortgage.monthly_payment",
            "Calculate the monthly payment of a fixed-rate mortgage.",
            json!({"type": "object", "properties": {
                "loan_amount": {"type": "integer", "description": "The amount borrowed."},
                "interest_rate": {"type": "number", "description": "Annual interest rate, in percent."},
                "years": {"type": "integer", "description": "Length of the loan in years."}},
                "required": ["loan_amount", "interest_rate", "years"]}),
        ),
        ferrosa::agent::answer_spec(),
    ];
    let mut turn = |q: &str| gated_copy_turn(model.as_mut(), &mut session, &grammars, &specs, q);
    let calls = turn(
        "Play songs from the artists Taylor Swift and Maroon 5, with a play time of 20 minutes and 15 minutes respectively, on Spotify.",
    );
    let mut played: Vec<(String, i64)> = calls
        .iter()
        .map(|(name, args)| {
            assert_eq!(name, "spotify.play", "{calls:?}");
            (
                args["artist"].as_str().unwrap().to_string(),
                args["duration"].as_i64().unwrap(),
            )
        })
        .collect();
    played.sort();
    assert_eq!(
        played,
        [
            ("Maroon 5".to_string(), 15),
            ("Taylor Swift".to_string(), 20)
        ]
    );

    let calls = turn("What is the monthly payment on a $400,000 mortgage at 3.5% over 30 years?");
    assert_eq!(calls.len(), 1, "{calls:?}");
    assert_eq!(calls[0].0, "mortgage.monthly_payment");
    assert_eq!(calls[0].1["loan_amount"], 400000, "{calls:?}");
    assert_eq!(calls[0].1["years"], 30, "{calls:?}");

    let calls = turn("Who painted the Mona Lisa?");
    assert_eq!(calls[0].0, ferrosa::agent::ANSWER_TOOL, "{calls:?}");
}

/// One gated turn with the copy bias (3) over `specs`, decoded greedily: its calls.
fn gated_copy_turn(
    model: &mut dyn ferrosa::backend::Backend,
    session: &mut Session,
    grammars: &Grammars,
    specs: &[ToolSpec],
    q: &str,
) -> Vec<(String, Value)> {
    let messages = [
        ChatMessage::new(Role::System, "You are a helpful assistant with tools."),
        ChatMessage::new(Role::User, q),
    ];
    let req = TurnRequest {
        messages: &messages,
        specs,
        allowed: None,
        envelope: Envelope::Smollm2,
        choice: ToolChoice::Required,
        parallel: true,
        decoding: Decoding::Constrained,
        max_tokens: 200,
        relevance_gate: Some(ferrosa::agent::ANSWER_TOOL),
        copy: Some(ferrosa::decode::turn::CopyFrom {
            sources: &[q],
            bonus: 3.0,
            exempt: Some(ferrosa::agent::ANSWER_TOOL),
        }),
    };
    let r = greedy_turn(model, session, grammars, &req);
    assert_eq!(r.finish, Finish::EndOfGeneration, "{q:?}: {}", r.text);
    let calls = r
        .turn
        .unwrap_or_else(|e| panic!("{q:?}: {e} in {}", r.text))
        .calls;
    calls.into_iter().map(|c| (c.name, c.arguments)).collect()
}

/// One question to `spec` (and the answer tool), on a freshly loaded model: the calls
/// of its gated copy turn.
fn gated_copy_calls(spec: ToolSpec, q: &str) -> Vec<(String, Value)> {
    let mut model = load("smollm2-135m", BackendKind::Llama, 8192);
    let grammars = Grammars::new(model.vocab(), model.tokenizer()).unwrap();
    let mut session = Session::new();
    let specs = [spec, ferrosa::agent::answer_spec()];
    gated_copy_turn(model.as_mut(), &mut session, &grammars, &specs, q)
}

/// A list of calls, gated with the copy bias on the real model: every value of "5,10 and
/// 15" gets its call (the 5 ends at its comma, and a repeat of 10 is refused without
/// refusing the "1" that starts 15).
#[test]
fn a_list_varies_the_value_the_request_lists() {
    let factorial = ToolSpec::new(
        "math.factorial",
        "Calculate the factorial of a given positive integer.",
        json!({"type": "object", "properties": {
            "number": {"type": "integer", "description": "The number for which factorial needs to be calculated."}},
            "required": ["number"]}),
    )
    .unwrap();
    let calls = gated_copy_calls(factorial, "Find the factorial of 5,10 and 15.");
    let numbers: Vec<i64> = calls
        .iter()
        .map(|(name, args)| {
            assert_eq!(name, "math.factorial", "{calls:?}");
            args["number"].as_i64().unwrap()
        })
        .collect();
    assert_eq!(numbers, [5, 10, 15], "{calls:?}");
}

/// A required flag the request says nothing of, on the real model, gated with the copy
/// bias: the default its description declares is offered to it, and is written (without
/// it the model writes `false` here).
#[test]
fn a_required_flag_the_request_leaves_unsaid_takes_its_default() {
    let factors = ToolSpec::new(
        "get_prime_factors",
        "Function to retrieve prime factors of a number.",
        json!({"type": "object", "properties": {
            "number": {"type": "integer", "description": "Number for which prime factors need to be calculated"},
            "formatted": {"type": "boolean", "description": "Return formatted string if true, array if false. Default is true."}},
            "required": ["number", "formatted"]}),
    )
    .unwrap();
    let calls = gated_copy_calls(factors, "Find the prime factors of 450");
    assert_eq!(calls.len(), 1, "{calls:?}");
    assert_eq!(calls[0].0, "get_prime_factors", "{calls:?}");
    assert_eq!(calls[0].1, json!({"number": 450, "formatted": true}));
}
