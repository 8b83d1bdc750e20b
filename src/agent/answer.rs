//! How a run ends in words: the `reply` pseudo-tool the model calls to answer, the
//! answer as the operator reads it, and what is said when a run ends without one.

use serde_json::json;

use crate::reading::language::{Language, Phrase};
use crate::tool::ToolSpec;

/// Name of the pseudo-tool the model calls to give its final answer.
pub const ANSWER_TOOL: &str = "reply";
/// Longest answer text the grammar allows.
pub(crate) const ANSWER_CHARS: usize = 240;

/// The `reply` pseudo-tool: how the model gives its final answer in `AnswerMode::Tool`.
pub fn answer_spec() -> ToolSpec {
    ToolSpec::new(
        ANSWER_TOOL,
        "Reply to the operator in one sentence, using the summary or the values the last tool returned.",
        // Bounded, so a model that rambles still ends its answer (see `tidy`). No braces
        // or angle brackets: a small model that "closes" the call inside the string
        // (`}}]</tool_call>`) is steered to close the string instead.
        json!({"type": "object", "properties": {"text": {"type": "string", "maxLength": ANSWER_CHARS, "pattern": "^[^{}<>]*[^{}<>:\\s]$"}}, "required": ["text"]}),
    )
    .expect("static spec is valid")
    .called_alone()
}

/// Whether `text` writes a call (or JSON) rather than answering: prose a small model
/// wrote in place of a call, which the `reply` tool's pattern keeps out of its text.
pub(crate) fn writes_a_call(text: &str) -> bool {
    text.contains("<tool_call>") || text.contains("{\"")
}

/// The answer as the operator reads it: when the model ran into the length cap, cut
/// back to its last complete sentence.
pub(crate) fn tidy(text: &str, cap: usize) -> String {
    let t = text.trim();
    if t.chars().count() < cap {
        return t.to_string();
    }
    match t.rfind(['.', '!', '?']) {
        Some(i) if i > 0 => t[..=i].to_string(),
        _ => t.to_string(),
    }
}

/// What the last observation said, for a run that ends without an answer, in
/// `language`.
pub(crate) fn last_result(last: &str, language: Language) -> String {
    if last.is_empty() {
        language.say(Phrase::NothingYet)
    } else {
        format!(
            "{}: {}",
            language.say(Phrase::LastResult),
            super::history::truncate_output(last, 300)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_capped_answer_ends_at_its_last_sentence() {
        assert_eq!(tidy("  Short. ", 240), "Short.");
        let long = format!("First. {}", "x".repeat(300));
        assert_eq!(tidy(&long, 240), "First.");
    }
}
