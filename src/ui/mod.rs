//! Front ends: what the operator runs. Each command here wires library parts together
//! and prints; none holds logic another front end would need.
//!
//! Layout:
//! - `agent`: `ferrosa ask` and `ferrosa chat`
//! - `generate`: `ferrosa generate`, streaming text from a model, with `--stats`
//! - `models`: `ferrosa models list|fetch|verify`

pub mod agent;
pub mod generate;
pub mod models;
