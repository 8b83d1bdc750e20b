//! Integration tests: one binary, a module per concern.
//!
//! Two tiers. Plain `cargo test --release` runs what needs neither model weights nor a
//! network namespace: synthetic vocabularies and scripted logits drive the real template,
//! grammar, decode loop, strategies, agent and policy. The tests marked `#[ignore]` need
//! the fetched weights (`ferrosa models fetch --all`), a ROS peer, or root for a
//! loopback-only network namespace; the README's test command and CI run them too
//! (`cargo test --release -- --include-ignored`, after `.ci/setup`).

mod support;
mod util;

mod agent;
mod alloc;
mod arm;
mod arrows;

#[global_allocator]
static COUNTING: alloc::Counting = alloc::Counting;

#[cfg(feature = "candle")]
mod candle_parity;
mod cli;
mod console;
mod declared;
mod decoding;
mod draft;
mod embed;
mod estop;
mod eval;
mod fence_params;
mod mcp;
mod nav2;
mod parsers;
mod places;
mod prompt_cache;
mod remote;
mod ros;
mod ros1;
mod ros1_trust;
mod runtime;
mod safety;
mod soak;
mod speech;
mod suite_leak;
mod trust;
