//! The action tools: `ros_action_list`, `ros_action_send_goal` (follows the goal to its
//! result, with feedback, within a wait the model chooses and the policy's time limit
//! bounds) and `ros_action_cancel` (one goal by id, or all of an action's goals).

use std::time::Duration;

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Map, Value};

use super::base::{absolute, failed, not_found, typed_by_name, Filter, ListArgs, Ros};
use crate::ros::{GoalOutcome, GoalStatus, Graph, RosError, RosGraph};
use crate::tool::{Effect, Progress, Tool, ToolContext, ToolError};

/// Feedback messages shown in a goal's outcome (the newest; the count says how many came).
const FEEDBACK_SHOWN: usize = 5;
/// How long a goal is followed when the model does not say.
const DEFAULT_WAIT_S: f64 = 10.0;

/// The type of `action`, or a "no action" error with near names.
/// How often a goal's feedback is passed on to the operator.
const PROGRESS_EVERY: Duration = Duration::from_millis(500);

/// Send `goal` to `action` (of its type) and follow it for up to `wait`, as
/// `send_goal` does, telling `progress` what `say` makes of its feedback as it comes
/// (at most every `PROGRESS_EVERY`): a line, or a message the agent words.
pub(crate) async fn send_goal_reporting(
    graph: &dyn RosGraph,
    (action, ty): (&str, &str),
    goal: Value,
    wait: Duration,
    progress: &Progress,
    say: impl Fn(&Value) -> Option<Value>,
) -> Result<GoalOutcome, RosError> {
    let (sink, mut feedback) = tokio::sync::mpsc::unbounded_channel();
    let mut goal = std::pin::pin!(graph.send_goal_watched(action, ty, goal, wait, sink));
    let mut reported: Option<std::time::Instant> = None;
    loop {
        tokio::select! {
            outcome = &mut goal => return outcome,
            Some(f) = feedback.recv() => {
                if reported.is_none_or(|t| t.elapsed() >= PROGRESS_EVERY) {
                    // An action's feedback message, or the `feedback` field of one
                    // wrapped with its goal id.
                    if let Some(report) = say(f.get("feedback").unwrap_or(&f)) {
                        progress.report(report);
                        reported = Some(std::time::Instant::now());
                    }
                }
            }
        }
    }
}

fn action_type(g: &Graph, action: &str) -> Result<String, ToolError> {
    let actions = g.actions();
    actions
        .iter()
        .find(|a| a.action == action)
        .map(|a| a.type_name.clone())
        .ok_or_else(|| {
            let names: Vec<String> = actions.iter().map(|a| a.action.clone()).collect();
            not_found("action", action, names.iter(), "ros_action_list")
        })
}

pub(crate) struct ActionList(pub(super) Ros);

impl Tool for ActionList {
    type Args = ListArgs;
    const NAME: &'static str = "ros_action_list";
    const EFFECT: Effect = Effect::Observes;
    const LISTS: Option<&'static str> = Some("action");
    fn description(&self) -> String {
        "List ROS actions (long-running goals such as rotating to a heading) with their types and servers.".into()
    }
    async fn call(&self, a: ListArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let f = Filter::new(a.pattern, a.namespace)?;
        let g = self.0.snapshot().await?;
        let items = g
            .actions()
            .into_iter()
            .map(|a| (a.action.clone(), json!(a)))
            .collect();
        Ok(f.listing("actions", items))
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct GoalArgs {
    /// Action name, e.g. "/turtle1/rotate_absolute".
    pub action: String,
    /// Goal fields, e.g. {"theta": 1.57}; absent fields are zero.
    #[serde(default)]
    pub goal: Option<Map<String, Value>>,
    /// Seconds to follow the goal before returning (default 10); it keeps running after.
    #[serde(default)]
    #[schemars(range(min = 0.1, max = 120.0))]
    pub wait_s: Option<f64>,
}

pub(crate) struct ActionSendGoal(pub(super) Ros);

impl Tool for ActionSendGoal {
    type Args = GoalArgs;
    const NAME: &'static str = "ros_action_send_goal";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Send a goal to a ROS action and wait for its result, with its feedback. Moves or changes the robot.".into()
    }
    async fn call(&self, a: GoalArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let action = absolute(&a.action);
        let g = self.0.snapshot().await?;
        let ty = action_type(&g, &action)?;
        // Leave a second of the policy's time limit for the answer to come back.
        let limit = cx.timeout.saturating_sub(Duration::from_secs(1));
        let wait = Duration::from_secs_f64(a.wait_s.unwrap_or(DEFAULT_WAIT_S).clamp(0.1, 120.0))
            .min(limit.max(Duration::from_millis(100)));
        let goal = Value::Object(a.goal.unwrap_or_default());
        let outcome = send_goal_reporting(
            self.0.graph.as_ref(),
            (&action, &ty),
            goal.clone(),
            wait,
            &cx.progress,
            |f| Some(json!({ "feedback": f })),
        )
        .await
        .map_err(failed)?;
        let count = outcome.feedback.len();
        let shown = &outcome.feedback[count.saturating_sub(FEEDBACK_SHOWN)..];
        let summary = match outcome.status {
            GoalStatus::Rejected => format!("{action} rejected the goal"),
            GoalStatus::Running => format!(
                "the goal is still running after {:.1} s; cancel it with ros_action_cancel and goal_id {}",
                wait.as_secs_f64(),
                outcome.goal_id
            ),
            GoalStatus::Succeeded => format!(
                "the goal succeeded; result {}",
                outcome.result.as_ref().map(Value::to_string).unwrap_or_default()
            ),
            GoalStatus::Canceled => "the goal was canceled".to_string(),
            GoalStatus::Aborted => "the goal was aborted by the action server".to_string(),
        };
        Ok(json!({
            "summary": summary,
            "action": action,
            "type": ty,
            "goal": goal,
            "goal_id": outcome.goal_id,
            "status": outcome.status,
            "result": outcome.result,
            "feedback_count": count,
            "feedback": shown,
        }))
    }

    /// One branch per action the robot offers, its goal typed by the action's `_Goal`
    /// definition, and one for an action the robot lacks (`reading::bound` holds its name
    /// to those the operator wrote), as for `ros_service_call`.
    fn live_parameters(&self) -> Option<Value> {
        let g = crate::ros::graph_now(self.0.graph.as_ref())?;
        let open = json!({
            "type": "object",
            "properties": {"action": {"type": "string"},
                           "goal": {"type": "object", "additionalProperties": true}},
            "required": ["action"],
            "additionalProperties": false,
        });
        let actions = g
            .actions()
            .into_iter()
            .map(|a| (a.action, [a.type_name].into()))
            .collect();
        let mut live = typed_by_name(&self.0, actions, ("action", "goal", "_Goal"), false, open)?;
        // Every branch may say how long to follow the goal.
        let wait = json!({"type": "number", "minimum": 0.1, "maximum": 120.0});
        for b in live["anyOf"].as_array_mut()? {
            b["properties"]["wait_s"] = wait.clone();
        }
        Some(live)
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct CancelArgs {
    /// Action name, e.g. "/turtle1/rotate_absolute".
    pub action: String,
    /// The goal to cancel (from ros_action_send_goal); leave out to cancel all its goals.
    #[serde(default)]
    pub goal_id: Option<String>,
}

pub(crate) struct ActionCancel(pub(super) Ros);

impl Tool for ActionCancel {
    type Args = CancelArgs;
    const NAME: &'static str = "ros_action_cancel";
    const EFFECT: Effect = Effect::Stops;
    fn description(&self) -> String {
        "Cancel a running ROS action goal, or every goal of an action.".into()
    }
    async fn call(&self, a: CancelArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let action = absolute(&a.action);
        let g = self.0.snapshot().await?;
        let ty = action_type(&g, &action)?;
        let id = a.goal_id.filter(|s| !s.trim().is_empty());
        let outcome = self
            .0
            .graph
            .cancel_goals(&action, &ty, id.as_deref(), cx.timeout)
            .await
            .map_err(failed)?;
        Ok(json!({
            "action": action,
            "goal_id": id,
            "return_code": outcome.return_code,
            "canceling_count": outcome.canceling.len(),
            "canceling": outcome.canceling,
        }))
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::ros::fake::{FakeGraph, Sent};
    use crate::ros::{GoalOutcome, RosGraph, Sample};
    use crate::tools::ros::tests::run;

    /// `/turtlesim` serving `/turtle1/rotate_absolute`.
    fn graph() -> Graph {
        crate::tools::ros::tests::serving(
            "rq/turtle1/rotate_absolute/_action/send_goalRequest",
            "turtlesim::action::dds_::RotateAbsolute_SendGoal_Request_",
        )
    }

    fn outcome(status: GoalStatus) -> GoalOutcome {
        GoalOutcome {
            goal_id: "00112233445566778899aabbccddeeff".into(),
            status,
            result: Some(json!({"delta": -1.5})),
            feedback: (0..8)
                .map(|i| {
                    Sample::new(
                        0.1 * f64::from(i),
                        json!({"remaining": 1.5 - 0.2 * f64::from(i)}),
                    )
                })
                .collect(),
        }
    }

    fn ros(fake: FakeGraph) -> (Ros, Arc<FakeGraph>) {
        let fake = Arc::new(fake.with_graph(graph()));
        let g: Arc<dyn RosGraph> = fake.clone();
        (Ros::new(g), fake)
    }

    #[test]
    fn actions_are_listed_with_their_type_and_server() {
        let (r, _) = ros(FakeGraph::new());
        let out = run(&ActionList(r), json!({})).unwrap();
        assert_eq!(out["count"], 1);
        assert_eq!(out["actions"][0]["action"], "/turtle1/rotate_absolute");
        assert_eq!(out["actions"][0]["type"], "turtlesim/action/RotateAbsolute");
        assert_eq!(out["actions"][0]["servers"], json!(["/turtlesim"]));
        assert_eq!(out["summary"], "1 action: /turtle1/rotate_absolute");
    }

    #[test]
    fn a_goal_reports_its_result_and_the_newest_feedback() {
        let fake = FakeGraph::new()
            .with_action("/turtle1/rotate_absolute", outcome(GoalStatus::Succeeded));
        let (r, fake) = ros(fake);
        let out = run(
            &ActionSendGoal(r),
            json!({"action": "turtle1/rotate_absolute", "goal": {"theta": 1.57}}),
        )
        .unwrap();
        assert_eq!(out["status"], "succeeded");
        assert_eq!(out["result"]["delta"], -1.5);
        assert_eq!(out["feedback_count"], 8);
        assert_eq!(out["feedback"].as_array().unwrap().len(), FEEDBACK_SHOWN);
        assert!(out["summary"].as_str().unwrap().contains("succeeded"));
        assert_eq!(
            fake.sent(),
            [Sent::Goal {
                action: "/turtle1/rotate_absolute".into(),
                type_name: "turtlesim/action/RotateAbsolute".into(),
                goal: json!({"theta": 1.57}),
            }]
        );
    }

    #[test]
    fn a_goal_still_running_says_how_to_cancel_it() {
        let fake =
            FakeGraph::new().with_action("/turtle1/rotate_absolute", outcome(GoalStatus::Running));
        let (r, _) = ros(fake);
        let out = run(
            &ActionSendGoal(r),
            json!({"action": "/turtle1/rotate_absolute", "goal": {"theta": 3.0}, "wait_s": 0.5}),
        )
        .unwrap();
        assert_eq!(out["status"], "running");
        let summary = out["summary"].as_str().unwrap();
        assert!(
            summary.contains("ros_action_cancel") && summary.contains("00112233"),
            "{summary}"
        );
    }

    #[test]
    fn unknown_actions_name_the_near_ones_and_cancel_passes_the_id() {
        let fake =
            FakeGraph::new().with_action("/turtle1/rotate_absolute", outcome(GoalStatus::Running));
        let (r, fake) = ros(fake);
        let err = run(
            &ActionSendGoal(Ros::new(r.graph.clone())),
            json!({"action": "/rotate_absolute", "goal": {}}),
        )
        .unwrap_err();
        assert!(
            err.to_string()
                .contains("did you mean /turtle1/rotate_absolute"),
            "{err}"
        );
        let out = run(
            &ActionCancel(r),
            json!({"action": "/turtle1/rotate_absolute", "goal_id": "abc"}),
        )
        .unwrap();
        assert_eq!(out["return_code"], "accepted");
        assert_eq!(
            fake.sent(),
            [Sent::Cancel {
                action: "/turtle1/rotate_absolute".into(),
                goal_id: Some("abc".into()),
            }]
        );
    }
}
