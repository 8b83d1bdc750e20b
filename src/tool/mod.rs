//! Tools as the model sees them: a name, a description written for a small model, and a
//! JSON schema for the arguments that is the single source for both the prompt and the
//! grammar.
//!
//! Layout:
//! - `spec`: `ToolSpec`, its schema checks, and argument validation

pub mod spec;

pub use spec::{specs_from_json, SpecError, ToolCall, ToolSpec};
