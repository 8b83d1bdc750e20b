//! `robot_stop`: the e-stop, offered to the model as a tool. Always offered, never
//! confirmed, allowed read-only and behind the e-stop itself (it is `Effect::Stops`); it
//! engages the latch, which brakes the robot and refuses motion until the operator
//! resets it. The model can stop the robot, never release it.

use std::sync::Arc;

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use crate::estop::EStop;
use crate::tool::{Effect, Package, Tool, ToolContext, ToolError};

pub(crate) struct RobotStop {
    estop: Arc<EStop>,
}

pub fn package(estop: Arc<EStop>) -> Package {
    Package::new("stop").with(RobotStop { estop })
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct StopArgs {}

impl Tool for RobotStop {
    type Args = StopArgs;
    const NAME: &'static str = "robot_stop";
    const EFFECT: Effect = Effect::Stops;

    fn description(&self) -> String {
        "Stop the robot now (emergency stop): every motion halts and motion stays refused until the operator resets it. Use it whenever the operator says stop, halt, wait or freeze, in any language.".into()
    }

    async fn call(&self, _: StopArgs, _: &ToolContext) -> Result<Value, ToolError> {
        self.estop.trigger("the agent (robot_stop)");
        Ok(
            json!({"stopped": true, "summary": "The robot is stopped; motion stays refused until the operator resets the e-stop."}),
        )
    }
}
