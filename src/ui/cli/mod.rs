//! The command line: what `ferrosa` takes (clap's definitions; `opts`, the option groups
//! and what each becomes; `values`, the command line's names for the library's choices)
//! and `run`, which hands each command to its front end.
//! `main.rs` parses, sets up logging, calls `run` and maps its error to the exit code.

mod opts;
pub mod values;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

use crate::ui;
use opts::{AgentOpts, Common, EvalCommand, GenerateOpts, MemoryCommand, ModelsCommand};

#[derive(Parser)]
#[command(
    name = "ferrosa",
    version,
    about = "On-device agent for offline robots"
)]
pub struct Cli {
    /// Directory holding model weights (and an optional catalog.toml override); default:
    /// ./models in a checkout of ferrosa, else ~/.local/share/ferrosa/models
    /// ($XDG_DATA_HOME/ferrosa/models).
    #[arg(long, global = true, env = "FERROSA_MODELS_DIR")]
    models_dir: Option<PathBuf>,
    /// Keep the agent's stable prompt prefix (system prompt and tool specs) on disk and
    /// start from it: a cold start skips evaluating it (off: neither read nor write).
    #[arg(
        long,
        global = true,
        env = "FERROSA_PROMPT_CACHE",
        value_enum,
        default_value_t = Switch::On
    )]
    prompt_cache: Switch,
    /// Most tokens guessed ahead per forward pass by prompt-lookup drafting (copied from
    /// the conversation, kept only as far as the model chooses them); 0, the default,
    /// turns it off (on the agent's tool calls it measured no faster; 8 suits long
    /// copies).
    #[arg(long, global = true, env = "FERROSA_DRAFT", default_value_t = 0)]
    draft: usize,
    /// The tool chooser's LoRA adapter: default (the one the model's catalog entry
    /// names, if any), none, a built-in name (smollm2-135m-tools, trained for the default
    /// model), or a path to a GGUF LoRA file. On only while the chooser reads the tools'
    /// names; llama.cpp in this process only.
    #[arg(
        long,
        global = true,
        env = "FERROSA_ADAPTER",
        default_value = "default"
    )]
    adapter: String,
    /// candle's weights: quantized, as the file holds them (the least memory), or also
    /// dense, dequantized to 4 bytes a weight for prompts of 16 tokens or more (about
    /// 1.5× faster prompts, about 440 MiB more at peak for the default model). llama.cpp ignores it.
    #[arg(long, global = true, env = "FERROSA_CANDLE_WEIGHTS", value_enum, default_value_t = CandleWeightsArg::Quantized)]
    candle_weights: CandleWeightsArg,
    /// Where the model runs: local (in this process) or openai (a server with OpenAI's
    /// completions API, e.g. llama-server or vLLM, at --url; the model file given with
    /// --model is read here for its vocabulary and chat template only).
    #[arg(long, global = true, env = "FERROSA_ENGINE", value_enum, default_value_t = EngineArg::Local)]
    engine: EngineArg,
    /// The model server's address for --engine openai: http://HOST:PORT.
    #[arg(long, global = true, env = "FERROSA_ENGINE_URL")]
    url: Option<String>,
    /// The environment variable holding the server's API key (sent as a bearer token).
    #[arg(long, global = true)]
    api_key_env: Option<String>,
    /// The model name sent to the server (default: the first it lists).
    #[arg(long, global = true)]
    remote_model: Option<String>,
    /// The grammar form sent to the server: auto (Lark if it takes it, else JSON
    /// schema), lark (servers built with llguidance) or json-schema.
    #[arg(long, global = true, value_enum, default_value_t = GrammarArg::Auto)]
    grammar: GrammarArg,
    /// Seconds to wait for the server: to connect, to start answering, between pieces.
    #[arg(long, global = true, default_value_t = 120)]
    remote_timeout: u64,
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum CandleWeightsArg {
    Quantized,
    Dense,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum EngineArg {
    Local,
    Openai,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum GrammarArg {
    Auto,
    Lark,
    JsonSchema,
}

impl Cli {
    /// The remote engine's options, or why the flags do not make one.
    fn remote(&self) -> anyhow::Result<Option<crate::remote::RemoteOptions>> {
        match (self.engine, &self.url) {
            (EngineArg::Local, None) => Ok(None),
            (EngineArg::Local, Some(_)) => {
                anyhow::bail!("--url is the model server's address: add --engine openai to use it")
            }
            (EngineArg::Openai, None) => anyhow::bail!(
                "--engine openai needs the server's address: --url http://HOST:PORT (e.g. a llama-server started with --host 127.0.0.1 --port 8080)"
            ),
            (EngineArg::Openai, Some(url)) => Ok(Some(crate::remote::RemoteOptions {
                url: url.clone(),
                api_key_env: self.api_key_env.clone(),
                model: self.remote_model.clone(),
                grammar: match self.grammar {
                    GrammarArg::Auto => crate::remote::GrammarMode::Auto,
                    GrammarArg::Lark => crate::remote::GrammarMode::Lark,
                    GrammarArg::JsonSchema => crate::remote::GrammarMode::JsonSchema,
                },
                timeout: std::time::Duration::from_secs(self.remote_timeout.max(1)),
            })),
        }
    }
}

/// On or off.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Switch {
    On,
    Off,
}

#[derive(Subcommand)]
enum Command {
    /// Generate text from a local model, streamed to stdout.
    Generate(GenerateOpts),
    /// Ask the agent once: it reasons, calls tools and answers.
    Ask {
        query: String,
        /// Print {answer, steps:[{name, arguments, output, ms, decision}], timings}.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        agent: AgentOpts,
    },
    /// Talk to the agent (REPL): /stop (e-stop, also mid-run; so does Ctrl-C), /reset,
    /// /call, /tools, /clear, /trace, /quit.
    Chat {
        /// Continue the last conversation with this robot (its exchanges, from the
        /// memory file).
        #[arg(long)]
        resume: bool,
        #[command(flatten)]
        agent: AgentOpts,
    },
    /// Run one tool call through exactly the agent's policy path (deny-list, e-stop,
    /// limits, confirmation, the ROS boundary) and print {name, arguments, decision,
    /// output} as JSON. Without a terminal and without --yes, an actuating call is
    /// refused as unconfirmed.
    Call {
        /// The tool, e.g. ros_node_list.
        name: String,
        /// Its arguments, a JSON object.
        #[arg(default_value = "{}")]
        arguments: String,
        #[command(flatten)]
        agent: AgentOpts,
    },
    /// Serve the robot's tools to MCP clients (stdio, or streamable HTTP on loopback with
    /// --http), under the same policy; actuating calls need the operator's approval (MCP
    /// elicitation, or --yes). No model runs: the model options are unused.
    Mcp {
        /// Serve streamable HTTP on this loopback address (e.g. 127.0.0.1:8765; port 0
        /// picks one and prints it) instead of stdio.
        #[arg(long)]
        http: Option<std::net::SocketAddr>,
        #[command(flatten)]
        agent: AgentOpts,
    },
    /// The operator console in a web page: chat with the answer as it is written, the
    /// trace, approvals, the e-stop, the robot's pose. Loopback by default; any other
    /// address requires the token printed at start.
    Serve {
        /// The address to serve on (port 0 picks one and prints it).
        #[arg(long, default_value = "127.0.0.1:8080")]
        bind: std::net::SocketAddr,
        /// The topic the robot view reads the pose from (default: the sim's
        /// /turtle1/pose); turtlesim Pose, Pose2D, PoseStamped, Odometry and the like.
        #[arg(long)]
        pose_topic: Option<String>,
        #[command(flatten)]
        agent: AgentOpts,
    },
    /// Turn a recording (WAV) into text with the speech model (Whisper base.en by
    /// default; `ferrosa models fetch whisper-base-en`).
    Transcribe {
        file: PathBuf,
        /// Catalog name or path to a whisper.cpp ggml-*.bin file.
        #[arg(short, long)]
        model: Option<String>,
        /// Print the transcript with its timings as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Speak text with espeak-ng: play it, or write a WAV file.
    Say {
        text: String,
        /// Write the speech to this WAV file instead of playing it.
        #[arg(long)]
        out: Option<PathBuf>,
        /// A language code (en, es, fr, de, it, pt; en is the Piper voice when
        /// installed), piper, or an espeak-ng voice (en-gb, …).
        #[arg(long, default_value = "en")]
        voice: String,
        /// Words a minute (espeak-ng's default 175).
        #[arg(long)]
        wpm: Option<u32>,
    },
    /// The built-in robot and the default model: `chat --robot sim`.
    Demo {
        #[command(flatten)]
        agent: AgentOpts,
    },
    /// Run the built-in turtlesim-compatible robot over ROS 2 (DDS on this machine only,
    /// unless ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET) until Ctrl-C.
    Sim,
    /// Measure tool calling: BFCL files (one JSON object per line, answers in
    /// possible_answer/ beside them).
    Eval {
        #[command(subcommand)]
        command: EvalCommand,
    },
    /// List, fetch and verify model weights.
    Models {
        #[command(subcommand)]
        command: ModelsCommand,
    },
    /// What the robot keeps across sessions (taught places, facts, the request log):
    /// list, export or forget it.
    Memory {
        #[command(subcommand)]
        command: MemoryCommand,
    },
}

/// Run the command `cli` names.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    let common = Common {
        dir: cli
            .models_dir
            .clone()
            .unwrap_or_else(crate::models::models_dir),
        prompt_cache: cli.prompt_cache == Switch::On,
        draft: crate::decode::Draft::up_to(cli.draft),
        remote: cli.remote()?,
        adapter: cli.adapter.clone(),
        dense_weights: cli.candle_weights == CandleWeightsArg::Dense,
    };
    match cli.command {
        Command::Generate(g) => ui::generate::run(&g.into_args(&common)),
        Command::Ask { query, json, agent } => ui::agent::ask(&common.agent(agent), &query, json),
        Command::Chat { agent, resume } => ui::agent::chat(&common.agent(agent), resume),
        Command::Call {
            name,
            arguments,
            agent,
        } => ui::call::run(&common.agent(agent), &name, &arguments),
        Command::Mcp { http, agent } => ui::mcp::run(&ui::mcp::McpArgs {
            agent: common.agent(agent),
            http,
        }),
        Command::Serve {
            bind,
            pose_topic,
            agent,
        } => ui::console::run(&ui::console::ServeArgs {
            agent: common.agent(agent),
            bind,
            pose_topic,
        }),
        Command::Transcribe { file, model, json } => {
            ui::speech::transcribe(&common.dir, model.as_deref(), &file, json)
        }
        Command::Say {
            text,
            out,
            voice,
            wpm,
        } => ui::speech::say(&text, out.as_deref(), &voice, wpm),
        Command::Demo { agent } => {
            let mut args = common.agent(agent);
            if args.robot == ui::agent::Robot::None {
                args.robot = ui::agent::Robot::Sim;
            }
            ui::agent::chat(&args, false)
        }
        Command::Sim => ui::agent::sim(),
        Command::Eval { command } => command.run(&common),
        Command::Memory { command } => command.run(),
        Command::Models { command } => command.run(&common),
    }
}
