//! `ferrosa generate`: load a model, optionally wrap the prompt in its chat template (and
//! with `--tools`, describe the tools and decode one turn under the tool-call grammar),
//! stream the continuation to stdout, and with `--stats` report load time, prompt and
//! generation tok/s, forced tokens and peak RSS on stderr.

use std::io::Write;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;

use crate::backend::{Backend, Detokenizer};
use crate::chat::{ChatMessage, Role};
use crate::decode::envelope::{Envelope, ToolChoice};
use crate::decode::request::{render_prompt, TurnRequest};
use crate::decode::{
    self, Decoding, Finish, GenerationStats, Grammars, JsonScan, NoHook, Sampler, SamplerConfig,
    Session, Steering,
};
use crate::metrics;
use crate::strategy::Pipeline;
use crate::tool::specs_from_json;
use crate::turn::Engine;

#[derive(Debug, Clone)]
pub struct GenerateArgs {
    pub model: super::ModelArgs,
    pub prompt: String,
    pub system: Option<String>,
    pub max_tokens: usize,
    pub chat: bool,
    pub sampler: SamplerConfig,
    pub stats: bool,
    /// A JSON file of tool specs: decode one assistant turn that may call them.
    pub tools: Option<PathBuf>,
    pub tool_choice: ToolChoice,
    pub decoding: Decoding,
    /// Override the family's envelope.
    pub envelope: Option<Envelope>,
    pub parallel: bool,
}

pub fn run(args: &GenerateArgs) -> anyhow::Result<()> {
    let t_load = Instant::now();
    if args.model.remote.is_some() {
        anyhow::bail!(
            "`ferrosa generate` runs the model in this process; --engine openai serves ask, chat, demo and eval"
        );
    }
    let (resolved, opts, mut model) = args.model.load()?;
    let load_time = t_load.elapsed();

    let stdout = std::io::stdout();
    let mut lock = stdout.lock();
    let (finish, stats) = match &args.tools {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read tools file {}", path.display()))?;
            let specs =
                specs_from_json(&text).with_context(|| format!("tools file {}", path.display()))?;
            let family = resolved.family().unwrap_or("chatml");
            let envelope = args
                .envelope
                .unwrap_or_else(|| Envelope::for_family(family));
            let grammars = Grammars::new(model.vocab(), model.tokenizer())?;
            let mut messages = Vec::new();
            if let Some(s) = &args.system {
                messages.push(ChatMessage::new(Role::System, s.clone()));
            }
            messages.push(ChatMessage::new(Role::User, args.prompt.clone()));
            let req = TurnRequest {
                messages: &messages,
                specs: &specs,
                allowed: None,
                envelope,
                choice: args.tool_choice,
                parallel: args.parallel,
                decoding: args.decoding,
                max_tokens: args.max_tokens,
            };
            let mut sampler = Sampler::new(args.sampler, model.vocab().len());
            let mut engine = Engine {
                backend: model.as_mut(),
                session: &mut Session::new(),
                grammars: &grammars,
                sampler: &mut sampler,
                remote: None,
                draft: args.model.draft,
            };
            // No strategy: the model alone writes the turn.
            let r = crate::turn::run(
                &mut engine,
                &req,
                &mut Pipeline::new(),
                None,
                &mut |piece| {
                    let _ = lock.write_all(piece.as_bytes()).and_then(|_| lock.flush());
                    ControlFlow::Continue(())
                },
            )?;
            let _ = writeln!(lock);
            match &r.turn {
                Ok(turn) if turn.calls.is_empty() => eprintln!("no tool call (a plain answer)"),
                Ok(turn) => eprintln!(
                    "{} valid tool call(s): {}",
                    turn.calls.len(),
                    serde_json::to_string(&turn.calls).unwrap_or_default()
                ),
                Err(e) => eprintln!("invalid tool call: {e}"),
            }
            (r.finish, r.stats)
        }
        None => plain(model.as_mut(), args, &mut lock)?,
    };
    drop(lock);

    if args.stats {
        print_stats(
            model.as_ref(),
            &resolved.path,
            opts.threads,
            load_time,
            finish,
            &stats,
        );
    }
    Ok(())
}

fn plain(
    model: &mut dyn Backend,
    args: &GenerateArgs,
    out: &mut impl Write,
) -> anyhow::Result<(Finish, GenerationStats)> {
    // The template's own markers are special tokens; the prompt itself is taken
    // literally either way.
    let prompt = if args.chat {
        let mut messages = Vec::new();
        if let Some(s) = &args.system {
            messages.push(ChatMessage::new(Role::System, s.clone()));
        }
        messages.push(ChatMessage::new(Role::User, args.prompt.clone()));
        render_prompt(model, &messages, Envelope::Json)?
    } else {
        decode::prompt_tokens(model, &args.prompt, false)?
    };

    let mut sampler = Sampler::new(args.sampler, model.vocab().len());
    let mut detok = Detokenizer::new(false);
    let mut piece = String::with_capacity(64);
    let vocab = model.vocab().clone();
    let result = decode::generate(
        model,
        &mut Session::new(),
        &prompt,
        args.max_tokens,
        Steering {
            sampler: &mut sampler,
            constraint: None,
            hook: &mut NoHook,
            scan: &mut JsonScan::new(),
            draft: args.model.draft,
        },
        |tok, _| {
            piece.clear();
            detok.push(&vocab, tok, &mut piece);
            // A closed stdout (`| head`) ends the run instead of panicking.
            if out
                .write_all(piece.as_bytes())
                .and_then(|_| out.flush())
                .is_err()
            {
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(())
        },
    )
    .context("generation failed")?;
    piece.clear();
    detok.finish(&mut piece);
    let _ = writeln!(out, "{piece}");
    Ok(result)
}

fn print_stats(
    model: &dyn Backend,
    path: &std::path::Path,
    threads: usize,
    load_time: std::time::Duration,
    finish: Finish,
    stats: &GenerationStats,
) {
    let finish = match finish {
        Finish::EndOfGeneration => "end of generation",
        Finish::Length => "token limit",
        Finish::ContextFull => "context full",
        Finish::Stopped => "stopped",
        Finish::NoCandidate => "no candidate token",
    };
    eprintln!(
        "model {} | backend {} | threads {threads} | context {}",
        path.display(),
        model.name(),
        model.context_len()
    );
    eprintln!("load: {:.0} ms", load_time.as_secs_f64() * 1e3);
    eprintln!(
        "prompt: {} tokens in {:.1} ms = {:.1} tok/s",
        stats.prompt_tokens - stats.reused_tokens,
        stats.prompt_time.as_secs_f64() * 1e3,
        stats.prompt_tok_per_s()
    );
    eprintln!(
        "generation: {} tokens ({} forced by the grammar), {} forwards in {:.1} ms = {:.1} forwards/s, {:.1} tokens/s out (stopped: {finish})",
        stats.generated_tokens,
        stats.forced_tokens,
        stats.gen_forwards,
        stats.gen_time.as_secs_f64() * 1e3,
        stats.gen_tok_per_s(),
        stats.output_tok_per_s(),
    );
    if stats.constraint_time > std::time::Duration::ZERO {
        eprintln!(
            "grammar: {:.1} ms ({} full masks)",
            stats.constraint_time.as_secs_f64() * 1e3,
            stats.masks_computed
        );
    }
    eprintln!(
        "time to first token: {:.1} ms",
        stats.time_to_first_token.as_secs_f64() * 1e3
    );
    if let Some(peak) = metrics::peak_rss_bytes() {
        eprintln!("peak RSS: {:.1} MiB", metrics::mib(peak));
    }
}
