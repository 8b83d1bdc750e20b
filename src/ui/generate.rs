//! `ferrosa generate`: load a model, optionally wrap the prompt in its chat template,
//! stream the continuation to stdout, and with `--stats` report load time, prompt and
//! generation tok/s and peak RSS on stderr.

use std::io::Write;
use std::ops::ControlFlow;
use std::time::Instant;

use anyhow::Context;

use crate::backend::{self, BackendKind, ChatMessage, Detokenizer, LoadOptions, Role};
use crate::decode::{self, Finish, Sampler, SamplerConfig, Session};
use crate::metrics;
use crate::models;

#[derive(Debug, Clone)]
pub struct GenerateArgs {
    pub models_dir: std::path::PathBuf,
    pub model: Option<String>,
    pub prompt: String,
    pub system: Option<String>,
    pub max_tokens: usize,
    pub chat: bool,
    pub backend: BackendKind,
    pub threads: Option<usize>,
    pub max_context: usize,
    pub sampler: SamplerConfig,
    pub stats: bool,
}

pub fn run(args: &GenerateArgs) -> anyhow::Result<()> {
    let resolved = models::resolve(args.model.as_deref(), &args.models_dir)?;
    let mut opts = LoadOptions::new(resolved.path.clone());
    opts.family = resolved.family().map(str::to_string);
    opts.max_context = args.max_context;
    if let Some(t) = args.threads {
        opts.threads = t;
    }
    let t_load = Instant::now();
    let mut model = backend::load(args.backend, &opts)?;
    let load_time = t_load.elapsed();

    let text = if args.chat {
        let mut messages = Vec::new();
        if let Some(s) = &args.system {
            messages.push(ChatMessage::new(Role::System, s.clone()));
        }
        messages.push(ChatMessage::new(Role::User, args.prompt.clone()));
        model.chat_template().render(&messages, None, true)?
    } else {
        args.prompt.clone()
    };
    // The rendered template holds special-token texts; a raw prompt is taken literally.
    let mut prompt = model.vocab().bos().into_iter().collect::<Vec<_>>();
    let body = model.tokenize(&text, args.chat)?;
    // Templates that write BOS themselves would otherwise get it twice.
    let skip = usize::from(!prompt.is_empty() && body.first() == prompt.first());
    prompt.extend_from_slice(&body[skip..]);

    let mut sampler = Sampler::new(args.sampler, model.vocab().len());
    let mut session = Session::new();
    let mut detok = Detokenizer::new(false);
    let mut out = String::with_capacity(64);
    let stdout = std::io::stdout();
    let mut lock = stdout.lock();
    let vocab = model.vocab().clone();
    let (finish, stats) = decode::generate(
        model.as_mut(),
        &mut session,
        &prompt,
        args.max_tokens,
        &mut sampler,
        None,
        |tok| {
            out.clear();
            detok.push(&vocab, tok, &mut out);
            // A closed stdout (`| head`) ends the run instead of panicking.
            if lock
                .write_all(out.as_bytes())
                .and_then(|_| lock.flush())
                .is_err()
            {
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(())
        },
    )
    .context("generation failed")?;
    out.clear();
    detok.finish(&mut out);
    let _ = writeln!(lock, "{out}");
    drop(lock);

    if args.stats {
        let finish = match finish {
            Finish::EndOfGeneration => "end of generation",
            Finish::Length => "token limit",
            Finish::ContextFull => "context full",
            Finish::Stopped => "stopped",
            Finish::NoCandidate => "no candidate token",
        };
        eprintln!(
            "model {} | backend {} | threads {} | context {}",
            resolved.path.display(),
            model.name(),
            opts.threads,
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
            "generation: {} tokens, {} forwards in {:.1} ms = {:.1} tok/s (stopped: {finish})",
            stats.generated_tokens,
            stats.gen_forwards,
            stats.gen_time.as_secs_f64() * 1e3,
            stats.gen_tok_per_s()
        );
        eprintln!(
            "time to first token: {:.1} ms",
            stats.time_to_first_token.as_secs_f64() * 1e3
        );
        if let Some(peak) = metrics::peak_rss_bytes() {
            eprintln!("peak RSS: {:.1} MiB", metrics::mib(peak));
        }
    }
    Ok(())
}
