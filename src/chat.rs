//! The conversation: who said what. Every layer may use these types (the template
//! renders them, decoding builds prompts from them, the agent keeps its history in them);
//! they depend on nothing else in the crate.
//!
//! A message's `content` is always data: it is tokenized as plain text, never parsed for
//! special tokens (see `backend::template::Rendered`), so a tool result or an operator's
//! words cannot open or close a role.

use serde::Serialize;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    System,
    User,
    Assistant,
    Tool,
}

/// One message, shaped as Hugging Face chat templates expect it.
#[derive(Debug, Clone, Serialize)]
pub struct ChatMessage {
    pub role: Role,
    pub content: String,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub tool_calls: Vec<serde_json::Value>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tool_call_id: Option<String>,
}

impl ChatMessage {
    pub fn new(role: Role, content: impl Into<String>) -> ChatMessage {
        ChatMessage {
            role,
            content: content.into(),
            tool_calls: Vec::new(),
            name: None,
            tool_call_id: None,
        }
    }

    /// A tool's result, named after the tool.
    pub fn tool(name: &str, content: impl Into<String>) -> ChatMessage {
        ChatMessage {
            name: Some(name.to_string()),
            ..ChatMessage::new(Role::Tool, content)
        }
    }
}
