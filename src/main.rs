//! The `ferrosa` command: parse arguments, run the command (`ui::cli`), map its error
//! to an exit code (1 for any failure, 2 for bad usage, which clap reports itself).

use std::process::ExitCode;

use clap::Parser;
use ferrosa::ui::cli::{run, Cli};

fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("FERROSA_LOG").unwrap_or_else(|_| {
                tracing_subscriber::EnvFilter::new("warn,llama-cpp-2=error,rustdds=error")
            }),
        )
        .with_writer(std::io::stderr)
        .init();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
