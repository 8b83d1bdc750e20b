//! Calling a service.

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Map, Value};

use super::base::{absolute, failed, service_type, typed_by_name, with_note, Ros};
use crate::tool::{Effect, Tool, ToolContext, ToolError};

#[derive(Deserialize, JsonSchema)]
pub(crate) struct CallArgs {
    /// Service name, e.g. "/turtle1/teleport_absolute".
    pub service: String,
    /// Request fields, e.g. {"x": 2.0, "y": 3.0}; absent fields are zero.
    #[serde(default)]
    pub request: Option<Map<String, Value>>,
}

pub(crate) struct ServiceCall(pub(super) Ros);

impl Tool for ServiceCall {
    type Args = CallArgs;
    const NAME: &'static str = "ros_service_call";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Call a ROS service with a request and return its response. May act on the robot.".into()
    }
    async fn call(&self, a: CallArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let service = absolute(&a.service);
        let g = self.0.snapshot().await?;
        let ty = service_type(&g, &service)?;
        let request = Value::Object(a.request.unwrap_or_default());
        let reply = self
            .0
            .graph
            .call_service(&service, &ty, request, cx.timeout)
            .await
            .map_err(failed)?;
        Ok(with_note(
            json!({"service": service, "type": ty, "response": reply.response}),
            reply.note,
        ))
    }

    /// One branch per service the robot offers, its request typed by the service's
    /// type (a small model otherwise fills a free request with the schema's own words),
    /// and one for a service the robot lacks (`reading::bound` holds its name to those
    /// the operator wrote; the call then reports it missing).
    fn live_parameters(&self) -> Option<Value> {
        let g = crate::ros::graph_now(self.0.graph.as_ref())?;
        let open = json!({
            "type": "object",
            "properties": {"service": {"type": "string"},
                           "request": {"type": "object", "additionalProperties": true}},
            "required": ["service"],
            "additionalProperties": false,
        });
        // A node's own parameter and type-description services are the parameter
        // tools' (`boundary::node_machinery`): a request that writes one still reaches
        // it through the open branch.
        let mut services = g.services();
        services.retain(|_, types| {
            !types
                .iter()
                .any(|t| crate::ros::boundary::node_machinery(t))
        });
        typed_by_name(
            &self.0,
            services,
            ("service", "request", "_Request"),
            false,
            open,
        )
    }
}
