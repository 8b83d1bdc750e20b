//! System tools: the robot's clock and a bounded wait.

use std::time::Duration;

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use crate::tool::{Effect, Package, Tool, ToolContext, ToolError};

pub fn package() -> Package {
    Package::new("system").with(SystemTime).with(SystemWait)
}

pub struct SystemTime;

#[derive(Deserialize, JsonSchema)]
pub struct NoArgs {}

impl Tool for SystemTime {
    type Args = NoArgs;
    const NAME: &'static str = "system_time";
    const EFFECT: Effect = Effect::Observes;

    fn description(&self) -> String {
        "The robot's current date and time (UTC) and Unix time in seconds.".into()
    }

    async fn call(&self, _: NoArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let now = crate::clock::unix_now();
        Ok(json!({
            "utc": crate::clock::Utc::from_unix(now.as_secs() as i64).iso(),
            "unix_s": now.as_secs_f64(),
        }))
    }
}

pub(crate) struct SystemWait;

#[derive(Deserialize, JsonSchema)]
pub(crate) struct WaitArgs {
    /// Seconds to wait, 0.1 to 60.
    #[schemars(range(min = 0.1, max = 60.0))]
    pub seconds: f64,
}

impl Tool for SystemWait {
    type Args = WaitArgs;
    const NAME: &'static str = "system_wait";
    const EFFECT: Effect = Effect::Observes;

    fn description(&self) -> String {
        "Wait a number of seconds (0.1 to 60) before the next step, e.g. to let the robot finish moving.".into()
    }

    async fn call(&self, a: WaitArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let want = Duration::from_secs_f64(a.seconds.clamp(0.0, 60.0));
        if want > cx.timeout {
            return Err(ToolError::InvalidArguments(format!(
                "{:.1} s is longer than this call's time limit of {:.1} s; wait less",
                a.seconds,
                cx.timeout.as_secs_f64()
            )));
        }
        tokio::time::sleep(want).await;
        Ok(json!({"waited_s": a.seconds}))
    }
}
