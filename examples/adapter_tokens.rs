//! The tool-choice adapter's training samples as the runtime tokenizes them
//! (`scripts/adapter/`): each sample's system message and request rendered through the
//! model's chat template exactly as the agent renders a first turn (`render_prompt`),
//! the call's opening the grammar forces, and each listed tool's name as the gate scores
//! it (`turn::Gate`: the name and its closing quote, tokenized as plain text).
//!
//!     cargo run --release --example adapter_tokens -- MODEL.gguf FAMILY IN.jsonl OUT.jsonl
//!
//! IN: one JSON object per line with `system`, `user` and `tool` (data.py). OUT: the same
//! objects with `prompt`, `stable` (how many of its tokens the system message decides),
//! `opening` and `names` (tool name -> token ids) added.

use std::io::{BufRead, Write};

use ferrosa::backend::{load_vocabulary, LoadOptions};
use ferrosa::chat::{ChatMessage, Role};
use ferrosa::decode::envelope::Envelope;
use ferrosa::decode::request::render_prompt_split;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [model, family, input, output] = args.as_slice() else {
        return Err("usage: adapter_tokens MODEL.gguf FAMILY IN.jsonl OUT.jsonl".into());
    };
    let mut opts = LoadOptions::new(model.into());
    opts.family = Some(family.clone());
    let backend = load_vocabulary(&opts)?;
    let envelope = Envelope::for_family(family);
    // The call's opening up to the name's opening quote (what the grammar forces), and
    // the name with its closing quote (what the gate scores).
    let opening_of = |name: &str| -> (String, String) {
        let text = envelope.call_opening(name);
        let at = text.len() - name.len() - 1;
        (text[..at].to_string(), text[at..].to_string())
    };
    let mut out = std::io::BufWriter::new(std::fs::File::create(output)?);
    let mut n = 0;
    for line in std::io::BufReader::new(std::fs::File::open(input)?).lines() {
        let mut sample: serde_json::Value = serde_json::from_str(&line?)?;
        let field = |k: &str| sample[k].as_str().unwrap_or_default().to_string();
        let messages = [
            ChatMessage::new(Role::System, field("system")),
            ChatMessage::new(Role::User, field("user")),
        ];
        let (prompt, stable) = render_prompt_split(backend.as_ref(), &messages, envelope)?;
        let (opening, _) = opening_of(&field("tool"));
        let mut names = serde_json::Map::new();
        for l in field("system").lines() {
            let Some(name) = l
                .strip_prefix("{\"name\": \"")
                .and_then(|r| r.split('"').next())
            else {
                continue;
            };
            let (_, rest) = opening_of(name);
            names.insert(name.into(), backend.tokenize(&rest, false)?.into());
        }
        sample["prompt"] = prompt.into();
        sample["stable"] = stable.into();
        sample["opening"] = backend.tokenize(&opening, true)?.into();
        sample["names"] = names.into();
        serde_json::to_writer(&mut out, &sample)?;
        out.write_all(b"\n")?;
        n += 1;
    }
    out.flush()?;
    eprintln!("{n} samples tokenized");
    Ok(())
}
