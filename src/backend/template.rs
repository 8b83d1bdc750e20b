//! Chat templates: the Jinja template a GGUF file carries (`tokenizer.chat_template`),
//! rendered with minijinja, or a fallback per model family from `prompts/templates/` for
//! files that carry none (base models such as Gemma 3 270M).
//!
//! Renders system, user, assistant (with tool calls) and tool-result messages. It does not
//! decide how tools are described to the model: that is the prompt's job.

use minijinja::{Environment, ErrorKind, Value};
use serde::Serialize;

use super::gguf::Gguf;

/// Fallback templates compiled in, by family.
const FALLBACKS: &[(&str, &str)] = &[
    (
        "gemma3",
        include_str!("../../prompts/templates/gemma3.jinja"),
    ),
    (
        "chatml",
        include_str!("../../prompts/templates/chatml.jinja"),
    ),
];

const NAME: &str = "chat";

#[derive(Debug, thiserror::Error)]
pub enum TemplateError {
    #[error("the model's chat template does not parse: {0}; pass a model with a valid template or fix it with a GGUF editor")]
    Parse(String),
    #[error("the chat template failed to render: {0}")]
    Render(String),
}

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
}

/// Where a template came from, for `models list` and traces.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TemplateOrigin {
    File,
    Fallback(&'static str),
}

pub struct ChatTemplate {
    env: Environment<'static>,
    origin: TemplateOrigin,
    bos: String,
    eos: String,
}

impl std::fmt::Debug for ChatTemplate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ChatTemplate")
            .field("origin", &self.origin)
            .finish_non_exhaustive()
    }
}

impl ChatTemplate {
    /// Compile `source`; `bos`/`eos` are the texts templates see as `bos_token`/`eos_token`.
    pub fn new(
        source: &str,
        origin: TemplateOrigin,
        bos: &str,
        eos: &str,
    ) -> Result<ChatTemplate, TemplateError> {
        let mut env = Environment::new();
        // Hugging Face templates are written for Python's Jinja: keep their whitespace
        // control and string methods (`.strip()`, `.startswith()`, …).
        env.set_trim_blocks(true);
        env.set_lstrip_blocks(true);
        env.set_unknown_method_callback(minijinja_contrib::pycompat::unknown_method_callback);
        env.add_function(
            "raise_exception",
            |msg: String| -> Result<Value, minijinja::Error> {
                Err(minijinja::Error::new(ErrorKind::InvalidOperation, msg))
            },
        );
        env.add_function("strftime_now", strftime_now);
        env.add_template_owned(NAME, source.to_string())
            .map_err(|e| TemplateError::Parse(e.to_string()))?;
        Ok(ChatTemplate {
            env,
            origin,
            bos: bos.to_string(),
            eos: eos.to_string(),
        })
    }

    /// The file's own template, else the family's fallback, else ChatML.
    pub fn for_model(g: &Gguf, family: Option<&str>) -> Result<ChatTemplate, TemplateError> {
        let token_text = |key: &str| -> String {
            let id = g.get_u64(key);
            let tokens = g.get("tokenizer.ggml.tokens").and_then(|v| v.as_array());
            match (id, tokens) {
                (Some(id), Some(t)) => t
                    .get(id as usize)
                    .and_then(|v| v.as_str())
                    .unwrap_or_default()
                    .to_string(),
                _ => String::new(),
            }
        };
        let bos = token_text("tokenizer.ggml.bos_token_id");
        let eos = token_text("tokenizer.ggml.eos_token_id");
        if let Some(src) = g.chat_template() {
            return ChatTemplate::new(src, TemplateOrigin::File, &bos, &eos);
        }
        let family = family.or_else(|| g.architecture()).unwrap_or("chatml");
        let (name, src) = FALLBACKS
            .iter()
            .find(|(f, _)| family.starts_with(f))
            .copied()
            .unwrap_or(FALLBACKS[FALLBACKS.len() - 1]);
        ChatTemplate::new(src, TemplateOrigin::Fallback(name), &bos, &eos)
    }

    pub fn origin(&self) -> &TemplateOrigin {
        &self.origin
    }

    /// Render a conversation; `tools` (JSON schemas) are passed for templates that list them.
    pub fn render(
        &self,
        messages: &[ChatMessage],
        tools: Option<&[serde_json::Value]>,
        add_generation_prompt: bool,
    ) -> Result<String, TemplateError> {
        let tmpl = self
            .env
            .get_template(NAME)
            .map_err(|e| TemplateError::Render(e.to_string()))?;
        let ctx = minijinja::context! {
            messages => Value::from_serialize(messages),
            tools => tools.map(Value::from_serialize),
            add_generation_prompt => add_generation_prompt,
            bos_token => self.bos.as_str(),
            eos_token => self.eos.as_str(),
        };
        tmpl.render(ctx)
            .map_err(|e| TemplateError::Render(e.to_string()))
    }
}

/// `strftime_now(fmt)` as templates call it (Llama 3 puts today's date in the system
/// prompt); supports %Y %m %d %b %B %H %M, in UTC.
fn strftime_now(fmt: String) -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs()) as i64;
    let (y, m, d) = civil_from_days(secs.div_euclid(86_400));
    let tod = secs.rem_euclid(86_400);
    const MONTHS: [&str; 12] = [
        "January",
        "February",
        "March",
        "April",
        "May",
        "June",
        "July",
        "August",
        "September",
        "October",
        "November",
        "December",
    ];
    let month = MONTHS[(m - 1) as usize];
    fmt.replace("%Y", &y.to_string())
        .replace("%m", &format!("{m:02}"))
        .replace("%d", &format!("{d:02}"))
        .replace("%B", month)
        .replace("%b", &month[..3])
        .replace("%H", &format!("{:02}", tod / 3600))
        .replace("%M", &format!("{:02}", tod % 3600 / 60))
}

/// Days since 1970-01-01 to (year, month, day), proleptic Gregorian (H. Hinnant's method).
/// Also used by `system_time`, so the project carries one calendar, not two.
pub fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn convo() -> Vec<ChatMessage> {
        vec![
            ChatMessage::new(Role::System, "You are a robot."),
            ChatMessage::new(Role::User, "Hi"),
        ]
    }

    #[test]
    fn chatml_fallback_renders_generation_prompt() {
        let t =
            ChatTemplate::new(FALLBACKS[1].1, TemplateOrigin::Fallback("chatml"), "", "").unwrap();
        let out = t.render(&convo(), None, true).unwrap();
        assert_eq!(
            out,
            "<|im_start|>system\nYou are a robot.<|im_end|>\n<|im_start|>user\nHi<|im_end|>\n<|im_start|>assistant\n"
        );
    }

    #[test]
    fn gemma_fallback_folds_system_into_first_user_turn() {
        let t = ChatTemplate::new(
            FALLBACKS[0].1,
            TemplateOrigin::Fallback("gemma3"),
            "<bos>",
            "<eos>",
        )
        .unwrap();
        let out = t.render(&convo(), None, true).unwrap();
        assert_eq!(
            out,
            "<bos><start_of_turn>user\nYou are a robot.\n\nHi<end_of_turn>\n<start_of_turn>model\n"
        );
    }

    #[test]
    fn tool_calls_and_results_render() {
        let t =
            ChatTemplate::new(FALLBACKS[1].1, TemplateOrigin::Fallback("chatml"), "", "").unwrap();
        let mut call = ChatMessage::new(Role::Assistant, "");
        call.tool_calls =
            vec![serde_json::json!({"name": "calc_mean", "arguments": {"values": [1, 2]}})];
        let mut result = ChatMessage::new(Role::Tool, "{\"mean\": 1.5}");
        result.name = Some("calc_mean".into());
        let out = t.render(&[call, result], None, false).unwrap();
        assert!(out.contains("<tool_call>\n{\"arguments\":{\"values\":[1,2]},\"name\":\"calc_mean\"}\n</tool_call>")
            || out.contains("\"name\":\"calc_mean\""), "{out}");
        assert!(
            out.contains("<|im_start|>tool\n{\"mean\": 1.5}<|im_end|>"),
            "{out}"
        );
    }

    #[test]
    fn raise_exception_is_a_render_error() {
        let t = ChatTemplate::new(
            "{{ raise_exception('no system role') }}",
            TemplateOrigin::File,
            "",
            "",
        )
        .unwrap();
        let err = t.render(&convo(), None, true).unwrap_err();
        assert!(err.to_string().contains("no system role"), "{err}");
    }

    #[test]
    fn civil_dates() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(20_413), (2025, 11, 21));
    }
}
