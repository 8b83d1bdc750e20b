//! `ferrosa eval bfcl PATH...`: run BFCL files through the model, print a markdown
//! summary (both decoding modes side by side with `--decoding both`) and write every
//! case as JSONL so failures can be read.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;

use crate::agent::AnswerMode;
use crate::decode::envelope::Envelope;
use crate::decode::{Decoding, Grammars, Session};
use crate::eval::{self, bfcl, CaseResult};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DecodingChoice {
    Constrained,
    Free,
    Both,
}

pub struct BfclArgs {
    pub model: super::ModelArgs,
    pub paths: Vec<PathBuf>,
    pub decoding: DecodingChoice,
    pub limit: Option<usize>,
    pub out: PathBuf,
    pub envelope: Option<Envelope>,
    pub answer_mode: AnswerMode,
}

pub fn bfcl(args: &BfclArgs) -> anyhow::Result<()> {
    let mut cases = Vec::new();
    for p in &args.paths {
        cases.extend(bfcl::load(p, args.limit)?);
    }
    let (resolved, _, mut model) = args.model.load()?;
    let envelope = args
        .envelope
        .unwrap_or_else(|| Envelope::for_family(resolved.family().unwrap_or("chatml")));
    let grammars = Grammars::new(model.vocab(), model.tokenizer())?;
    let modes: &[Decoding] = match args.decoding {
        DecodingChoice::Constrained => &[Decoding::Constrained],
        DecodingChoice::Free => &[Decoding::Free],
        DecodingChoice::Both => &[Decoding::Constrained, Decoding::Free],
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let jsonl = args.out.join("bfcl_cases.jsonl");
    let mut file = std::fs::File::create(&jsonl)
        .with_context(|| format!("cannot write {}", jsonl.display()))?;
    let mut results: Vec<CaseResult> = Vec::new();
    let mut session = Session::new();
    let total = cases.len() * modes.len();
    for &mode in modes {
        for case in &cases {
            let r = eval::run_case(
                model.as_mut(),
                &mut session,
                &grammars,
                envelope,
                mode,
                args.answer_mode,
                case,
            )?;
            writeln!(file, "{}", serde_json::to_string(&r)?)?;
            results.push(r);
            eprint!("\r{} / {total}", results.len());
        }
    }
    eprintln!();
    let summaries = eval::summarize(&results);
    println!(
        "model {} | envelope {envelope:?} | answer mode {:?} | {} cases per mode\n",
        resolved.path.display(),
        args.answer_mode,
        cases.len()
    );
    print!("{}", eval::markdown(&summaries));
    std::fs::write(
        args.out.join("bfcl_summary.json"),
        serde_json::to_string_pretty(&summaries)?,
    )?;
    eprintln!("per-case results: {}", jsonl.display());
    Ok(())
}
