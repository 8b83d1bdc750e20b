//! Robot system prompts: ROSA's fields in a TOML file per robot (`prompts/`), rendered
//! into one short system message. Empty fields are left out; environment variables are
//! rendered too (ROSA defines the field but never renders it).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

pub(crate) const DEFAULT: &str = include_str!("../../prompts/default.toml");

#[derive(Debug, thiserror::Error)]
#[error("robot prompt {origin}: {message}")]
pub struct PromptError {
    origin: String,
    message: String,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotPrompt {
    #[serde(default)]
    pub embodiment_and_persona: String,
    #[serde(default)]
    pub about_your_operators: String,
    #[serde(default)]
    pub critical_instructions: String,
    #[serde(default)]
    pub constraints_and_guardrails: String,
    #[serde(default)]
    pub about_your_environment: String,
    #[serde(default)]
    pub about_your_capabilities: String,
    #[serde(default)]
    pub nuance_and_assumptions: String,
    #[serde(default)]
    pub mission_and_objectives: String,
    #[serde(default)]
    pub environment_variables: BTreeMap<String, String>,
    /// Files of declared robot tools (`tools::declared`) this robot has, relative to
    /// the prompt file's directory. Not part of the rendered prompt.
    #[serde(default)]
    pub tools: Vec<PathBuf>,
    /// Requests `ferrosa models warm` prepares the prompt cache for (the operators'
    /// usual first requests). Not part of the rendered prompt.
    #[serde(default)]
    pub warm: Vec<String>,
    /// Requests this robot's operators make, by the tool that answers each: they join
    /// the tool's own examples for tool choice (`meaning`).
    #[serde(default)]
    pub examples: BTreeMap<String, Vec<String>>,
    /// Named places the robot can be sent to (`tools::place`), each with its frame,
    /// coordinates, heading, aliases and description. Not part of the rendered prompt.
    #[serde(default)]
    pub places: Vec<crate::store::Place>,
    /// The topic the robot's pose is read from when a place is taught; found by its
    /// type on the graph when unset. Not part of the rendered prompt.
    #[serde(default)]
    pub pose_topic: Option<String>,
}

impl RobotPrompt {
    pub fn parse(text: &str, origin: &str) -> Result<RobotPrompt, PromptError> {
        toml::from_str(text).map_err(|e| PromptError {
            origin: origin.to_string(),
            message: e.message().to_string(),
        })
    }

    pub fn load(path: &Path) -> Result<RobotPrompt, PromptError> {
        let text = std::fs::read_to_string(path).map_err(|e| PromptError {
            origin: path.display().to_string(),
            message: e.to_string(),
        })?;
        let mut prompt = RobotPrompt::parse(&text, &path.display().to_string())?;
        let dir = path.parent().unwrap_or(Path::new(""));
        for t in &mut prompt.tools {
            *t = dir.join(&*t);
        }
        Ok(prompt)
    }

    pub(crate) fn default_robot() -> RobotPrompt {
        RobotPrompt::parse(DEFAULT, "built-in").expect("built-in prompt parses")
    }

    /// The system message text.
    pub fn render(&self) -> String {
        let mut parts: Vec<String> = [
            &self.embodiment_and_persona,
            &self.about_your_operators,
            &self.critical_instructions,
            &self.constraints_and_guardrails,
            &self.about_your_environment,
            &self.about_your_capabilities,
            &self.nuance_and_assumptions,
            &self.mission_and_objectives,
        ]
        .iter()
        .map(|s| s.trim())
        .filter(|s| !s.is_empty())
        .map(str::to_string)
        .collect();
        if !self.environment_variables.is_empty() {
            let vars: Vec<String> = self
                .environment_variables
                .iter()
                .map(|(k, v)| format!("{k}={v}"))
                .collect();
            parts.push(format!("Environment: {}", vars.join(", ")));
        }
        parts.join("\n")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_renders_without_empty_fields_and_with_env() {
        let mut p = RobotPrompt::default_robot();
        let text = p.render();
        assert!(text.starts_with("You are the on-board assistant"));
        assert!(!text.contains("\n\n"));
        p.environment_variables
            .insert("ROS_DOMAIN_ID".into(), "7".into());
        assert!(p.render().ends_with("Environment: ROS_DOMAIN_ID=7"));
    }

    #[test]
    fn unknown_fields_are_errors() {
        let err = RobotPrompt::parse("persona = \"x\"", "t").unwrap_err();
        assert!(err.to_string().contains("persona"), "{err}");
    }
}
