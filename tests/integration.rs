//! Integration tests: one binary, a module per concern. Tests that need model weights
//! read them from `models/` (installed by `ferrosa models fetch --all`, which the README's
//! test command and CI run first) and fail with that instruction when they are missing.

mod util;

mod agent;
mod alloc;

#[global_allocator]
static COUNTING: alloc::Counting = alloc::Counting;

#[cfg(feature = "candle")]
mod candle_parity;
mod cli;
mod decoding;
mod eval;
mod ros;
mod runtime;
