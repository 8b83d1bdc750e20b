//! `policy_deny_add`: the model may add a name pattern to the deny-list for the rest of
//! the session (never remove one: there is no tool for that). It changes what every later
//! call may do, so the operator confirms it like any actuation (text injected in ROS data
//! cannot fence the robot off on its own), and a pattern that would cover names in
//! general is refused (`fence`).

use std::sync::Arc;

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use crate::tool::{Effect, Package, Policy, Tool, ToolContext, ToolError};

pub(crate) struct PolicyDenyAdd {
    policy: Arc<Policy>,
}

pub fn package(policy: Arc<Policy>) -> Package {
    Package::new("guard").with(PolicyDenyAdd { policy })
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct DenyArgs {
    /// A regular expression of ROS names to stay away from, e.g. "^/camera".
    pub pattern: String,
}

impl Tool for PolicyDenyAdd {
    type Args = DenyArgs;
    const NAME: &'static str = "policy_deny_add";
    const EFFECT: Effect = Effect::Actuates;

    fn description(&self) -> String {
        "Add a regex of ROS names that no tool may touch for the rest of this session (e.g. when the operator says to leave something alone). Patterns cannot be removed.".into()
    }

    async fn call(&self, a: DenyArgs, _: &ToolContext) -> Result<Value, ToolError> {
        self.policy
            .add_model_pattern(&a.pattern)
            .map_err(|e| ToolError::InvalidArguments(e.to_string()))?;
        Ok(json!({"added": true}))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn added_patterns_take_effect_and_bad_ones_are_errors() {
        let policy = Arc::new(Policy::default());
        let t = PolicyDenyAdd {
            policy: policy.clone(),
        };
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let cx = ToolContext::new(Duration::from_secs(1));
        rt.block_on(t.call(
            DenyArgs {
                pattern: "^/camera".into(),
            },
            &cx,
        ))
        .unwrap();
        assert!(policy.denied("/camera/image"));
        assert!(rt
            .block_on(t.call(
                DenyArgs {
                    pattern: "(".into()
                },
                &cx
            ))
            .is_err());
    }
}
