//! The sentence encoder against its reference: token ids and vectors of sentences of
//! several languages and scripts, as the Python package the weights come from gives them
//! (tests/data/embed_reference.json).

use serde_json::Value;

use ferrosa::embed::{cosine, Encoder};

#[test]
#[ignore = "needs the sentence encoder (ferrosa models fetch use-multilingual-v3 use-multilingual-v3-vocab)"]
fn the_encoder_gives_the_reference_tokens_and_vectors() {
    let enc = Encoder::load(&crate::util::models_dir()).expect("the sentence encoder");
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/embed_reference.json"),
    )
    .unwrap();
    let reference: Value = serde_json::from_str(&text).unwrap();
    let sentences = reference["sentences"].as_array().unwrap();
    assert!(sentences.len() >= 8);
    for s in sentences {
        let sentence = s["text"].as_str().unwrap();
        let ids: Vec<u32> = serde_json::from_value(s["ids"].clone()).unwrap();
        assert_eq!(enc.tokens(sentence), ids, "tokens of {sentence:?}");
        let want: Vec<f32> = serde_json::from_value(s["vector"].clone()).unwrap();
        let got = enc.encode(sentence);
        assert_eq!(got.len(), want.len());
        let c = cosine(&got, &want);
        assert!(
            c > 0.9999,
            "vector of {sentence:?}: cosine {c} with the reference"
        );
    }
    // Meaning across languages: a question and its translation are closer than two
    // unrelated questions in one language.
    let a = enc.encode("How warm is the motor?");
    let b = enc.encode("Wie warm ist der Motor?");
    let c = enc.encode("How many joints does the arm have?");
    assert!(cosine(&a, &b) > cosine(&a, &c) + 0.2);
}

/// Tool choice by meaning (`reading::meaning`) on tools nobody shipped examples for: a
/// declared-style tool set whose examples are written in English only, asked in other
/// words and other languages; a robot prompt file's examples join a tool's own; the
/// robot's names count for the tools that take them.
#[test]
#[ignore = "needs the sentence encoder (ferrosa models fetch use-multilingual-v3 use-multilingual-v3-vocab)"]
fn tools_are_found_by_the_meaning_of_their_examples_in_any_language() {
    use ferrosa::reading::meaning::Meaning;
    use ferrosa::tool::ToolSpec;
    use serde_json::json;
    use std::collections::BTreeMap;
    use std::sync::Arc;

    let enc = Arc::new(Encoder::load(&crate::util::models_dir()).expect("the sentence encoder"));
    let tool = |name: &str, examples: &[&str]| {
        let mut s =
            ToolSpec::new(name, "A tool.", json!({"type": "object", "properties": {}})).unwrap();
        s.examples = examples.iter().map(|e| e.to_string()).collect();
        s
    };
    let specs = vec![
        tool("lamp_on", &["switch the light on", "turn on the lamp"]),
        tool("lamp_off", &["switch the light off", "turn off the lamp"]),
        tool(
            "tank_level",
            &["how full is the water tank?", "how much water is left?"],
        ),
        tool("small_talk", &["hello", "thanks a lot"]),
    ];
    let meaning = Meaning::new(enc.clone(), BTreeMap::new(), "");
    meaning.prepare(&specs);
    let best = |m: &Meaning, q: &str, specs: &[ToolSpec], names: &[(String, String)]| {
        let s = m.similarities(q, specs, names);
        let i = (0..s.len()).max_by(|a, b| s[*a].total_cmp(&s[*b])).unwrap();
        specs[i].name.clone()
    };
    for (q, want) in [
        ("could you light the place up", "lamp_on"),
        ("enciende la luz, por favor", "lamp_on"),
        ("wie viel Wasser ist noch im Tank?", "tank_level"),
        ("quanta acqua c'è ancora nel serbatoio?", "tank_level"),
        ("bonjour !", "small_talk"),
    ] {
        assert_eq!(best(&meaning, q, &specs, &[]), want, "{q}");
    }
    // A prompt file's examples: a tool with none of its own is found by them.
    let mut bare = specs.clone();
    bare.push(tool("pump_prime", &[]));
    let extra = BTreeMap::from([(
        "pump_prime".to_string(),
        vec![
            "prime the pump".to_string(),
            "fill the pump with water before starting".to_string(),
        ],
    )]);
    let with_prompt = Meaning::new(enc.clone(), extra, "");
    assert_eq!(
        best(&with_prompt, "get the pump primed", &bare, &[]),
        "pump_prime"
    );
    // The robot's names: of two tools alike in their examples, the one that takes the
    // kind of name the request is near (one of that kind standing out from the others).
    let call = |name: &str, key: &str| {
        let mut s = ToolSpec::new(
            name,
            "A tool.",
            json!({"type": "object", "properties": {key: {"type": "string"}}}),
        )
        .unwrap();
        s.examples = vec!["do it".to_string(), "run it now".to_string()];
        s
    };
    let pair = vec![call("by_service", "service"), call("by_topic", "topic")];
    let names: Vec<(String, String)> = [
        ("service", "/conveyor/start_belt"),
        ("service", "/lights/dim"),
        ("service", "/door/lock"),
        ("topic", "/camera/image"),
        ("topic", "/battery_state"),
    ]
    .iter()
    .map(|(k, n)| (k.to_string(), n.to_string()))
    .collect();
    let plain = Meaning::new(enc, BTreeMap::new(), "");
    assert_eq!(
        best(&plain, "start the conveyor belt", &pair, &names),
        "by_service"
    );
}
