//! ROS 2 actions for `Ros2Graph`: one `ActionClient` of type-erased payloads per action,
//! a goal followed through acceptance, feedback and result, cancels by goal id or all;
//! plus the QoS both sides use (the sim's action servers take theirs from here).
//!
//! Payload offsets: the goal follows a 16-byte goal id in `SendGoal_Request`, feedback a
//! goal id in `FeedbackMessage`, and the result a one-byte status in `GetResult_Response`,
//! so they are encoded and decoded at those origins.

use std::sync::Arc;
use std::time::{Duration, Instant};

use futures::StreamExt;
use ros2_client::action::{
    ActionClientQosPolicies, ActionServerQosPolicies, GoalId, GoalStatusEnum,
};
use ros2_client::action_msgs::CancelGoalResponseEnum;
use ros2_client::builtin_interfaces::Time;
use ros2_client::qos::Durability as QDurability;
use ros2_client::{ActionTypeName, ServiceMapping};
use serde_json::{json, Value};

use super::dds::{
    reliable_qos, ros_name, service_ready, split_type, EndpointCache, Raw, MATCH_SETTLE,
};
use crate::ros::cdr;
use crate::ros::msg::normalize_type;
use crate::ros::msg::Interfaces;
use crate::ros::{CancelOutcome, GoalOutcome, GoalStatus, RosError, Sample};

/// Feedback messages kept per goal (the newest).
const FEEDBACK_KEPT: usize = 50;

pub(crate) type RawActionClient = ros2_client::action::ActionClient<Raw, Raw, Raw>;

/// Services reliable and volatile; feedback keeps 10; status is transient-local with
/// depth 1 (a late client still sees the goals' states), as rclcpp's defaults.
pub(crate) fn client_qos() -> ActionClientQosPolicies {
    let service = reliable_qos(QDurability::Volatile, 10);
    ActionClientQosPolicies {
        goal_service: service.clone(),
        result_service: service.clone(),
        cancel_service: service.clone(),
        feedback_subscription: service,
        status_subscription: reliable_qos(QDurability::TransientLocal, 1),
    }
}

pub(crate) fn server_qos() -> ActionServerQosPolicies {
    let c = client_qos();
    ActionServerQosPolicies {
        goal_service: c.goal_service,
        result_service: c.result_service,
        cancel_service: c.cancel_service,
        feedback_publisher: c.feedback_subscription,
        status_publisher: c.status_subscription,
    }
}

/// `pkg/action/Name` (any spelling) as (`pkg/action/Name`, its `ActionTypeName`).
fn action_type(type_name: &str) -> Result<(String, ActionTypeName), RosError> {
    let ty = normalize_type(type_name);
    let (pkg, kind, short) = split_type(&ty)?;
    if kind != "action" {
        return Err(RosError::Other(format!(
            "{type_name} is not an action type (pkg/action/Name)"
        )));
    }
    Ok((ty, ActionTypeName::new(&pkg, &short)))
}

/// A goal id as 32 lowercase hex digits.
pub(crate) fn goal_hex(id: &GoalId) -> String {
    format!("{id:?}")
}

/// 32 hex digits (dashes allowed) back to a goal id.
fn parse_goal_id(text: &str) -> Result<GoalId, RosError> {
    let hex: String = text.chars().filter(|c| *c != '-').collect();
    let bad = || RosError::Other(format!("goal id {text:?} is not 32 hex digits"));
    if hex.len() != 32 || !hex.is_ascii() {
        return Err(bad());
    }
    let bytes = (0..16)
        .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).map_err(|_| bad()))
        .collect::<Result<Vec<u8>, RosError>>()?;
    // GoalId keeps its bytes private; it deserializes from them.
    serde_json::from_value(json!({ "uuid": bytes })).map_err(|_| bad())
}

fn goal_status(s: GoalStatusEnum) -> GoalStatus {
    match s {
        GoalStatusEnum::Succeeded => GoalStatus::Succeeded,
        GoalStatusEnum::Canceled => GoalStatus::Canceled,
        GoalStatusEnum::Aborted => GoalStatus::Aborted,
        GoalStatusEnum::Unknown
        | GoalStatusEnum::Accepted
        | GoalStatusEnum::Executing
        | GoalStatusEnum::Canceling => GoalStatus::Running,
    }
}

/// How long a goal's acceptance may take, however long the goal is followed.
const GOAL_ANSWER_WAIT: Duration = Duration::from_secs(10);

/// The action clients of a graph's node, made on first use and kept.
#[derive(Default)]
pub(super) struct Actions {
    clients: EndpointCache<RawActionClient>,
}

type NodeLock = tokio::sync::Mutex<ros2_client::Node>;

impl Actions {
    async fn client(
        &self,
        node: &NodeLock,
        action: &str,
        ty: &str,
        kind: &ActionTypeName,
        timeout: Duration,
    ) -> Result<Arc<RawActionClient>, RosError> {
        let (client, made) = self
            .clients
            .get_or_make(node, action, ty, |node| {
                node.create_action_client::<Raw, Raw, Raw>(
                    ServiceMapping::Enhanced,
                    &ros_name(action)?,
                    kind,
                    client_qos(),
                )
                .map_err(|e| RosError::Other(format!("action client {action}: {e:?}")))
            })
            .await?;
        // Both services the goal needs: a result request sent before the server's reader
        // matches is lost, and the goal then looks as if it never ends.
        let start = Instant::now();
        if !service_ready(node, client.goal_client(), timeout).await
            || !service_ready(
                node,
                client.result_client(),
                timeout.saturating_sub(start.elapsed()),
            )
            .await
        {
            return Err(RosError::NoAction(action.to_string()));
        }
        if made {
            // We see the server's readers; they may not see our writers yet (a goal sent
            // then went unanswered for the whole wait).
            tokio::time::sleep(MATCH_SETTLE).await;
        }
        Ok(client)
    }

    pub(super) async fn send_goal(
        &self,
        node: &NodeLock,
        interfaces: &Interfaces,
        (action, type_name): (&str, &str),
        goal: Value,
        wait: Duration,
        sink: Option<crate::ros::FeedbackSink>,
    ) -> Result<GoalOutcome, RosError> {
        let start = Instant::now();
        let (ty, kind) = action_type(type_name)?;
        let goal_ty = format!("{ty}_Goal");
        let bytes = cdr::encode(interfaces, &goal_ty, &goal, 16).map_err(|e| RosError::Encode {
            type_name: goal_ty.clone(),
            reason: e.to_string(),
        })?;
        // Finding the server may take part of the wait, but never all of it.
        let find = wait.max(Duration::from_secs(3));
        let client = self.client(node, action, &ty, &kind, find).await?;
        let left = |floor: u64| {
            wait.saturating_sub(start.elapsed())
                .max(Duration::from_millis(floor))
        };
        // The server answers a goal at once, accepted or not: a long wait is for the
        // goal to end, never for that answer.
        let answer = left(2000).min(GOAL_ANSWER_WAIT);
        let sent = tokio::time::timeout(answer, client.async_send_goal(Raw(bytes))).await;
        let (goal_id, response) = match sent {
            Ok(Ok(r)) => r,
            Ok(Err(e)) => return Err(RosError::Other(format!("send goal to {action}: {e:?}"))),
            Err(_) => {
                return Err(RosError::Timeout {
                    service: format!("{action}/_action/send_goal"),
                    timeout: answer,
                })
            }
        };
        let mut outcome = GoalOutcome {
            goal_id: goal_hex(&goal_id),
            status: GoalStatus::Rejected,
            result: None,
            feedback: Vec::new(),
        };
        if !response.accepted {
            return Ok(outcome);
        }
        outcome.status = GoalStatus::Running;
        let feedback_ty = format!("{ty}_Feedback");
        let result_ty = format!("{ty}_Result");
        let mut feedback = std::pin::pin!(client.feedback_stream(goal_id));
        let result = client.async_request_result(goal_id);
        let mut result = std::pin::pin!(tokio::time::timeout(left(100), result));
        loop {
            tokio::select! {
                r = &mut result => {
                    match r {
                        Ok(Ok((status, raw))) => {
                            outcome.status = goal_status(status);
                            outcome.result = Some(
                                cdr::decode(interfaces, &result_ty, &raw.0, 1).map_err(
                                    |e| RosError::Decode { type_name: result_ty.clone(), reason: e.to_string() },
                                )?,
                            );
                        }
                        Ok(Err(e)) => {
                            return Err(RosError::Other(format!("result of {action}: {e:?}")))
                        }
                        // Still going when the wait is over: the goal runs on.
                        Err(_) => {}
                    }
                    break;
                }
                Some(Ok(raw)) = feedback.next() => {
                    if let Ok(message) = cdr::decode(interfaces, &feedback_ty, &raw.0, 16) {
                        if let Some(sink) = &sink {
                            // A watcher gone is no failure of the goal.
                            let _ = sink.send(message.clone());
                        }
                        if outcome.feedback.len() == FEEDBACK_KEPT {
                            outcome.feedback.remove(0);
                        }
                        outcome.feedback.push(Sample::new(start.elapsed().as_secs_f64(), message));
                    }
                }
            }
        }
        Ok(outcome)
    }

    pub(super) async fn cancel_goals(
        &self,
        node: &NodeLock,
        action: &str,
        type_name: &str,
        goal_id: Option<&str>,
        timeout: Duration,
    ) -> Result<CancelOutcome, RosError> {
        let start = Instant::now();
        let (ty, kind) = action_type(type_name)?;
        let id = goal_id.map(parse_goal_id).transpose()?;
        let client = self.client(node, action, &ty, &kind, timeout).await?;
        let left = timeout.saturating_sub(start.elapsed());
        if !service_ready(node, client.cancel_client(), left).await {
            return Err(RosError::NoAction(action.to_string()));
        }
        let left = timeout
            .saturating_sub(start.elapsed())
            .max(Duration::from_millis(100));
        let call = client.async_cancel_goal(id.unwrap_or(GoalId::ZERO), Time::ZERO);
        let response = match tokio::time::timeout(left, call).await {
            Ok(Ok(r)) => r,
            Ok(Err(e)) => return Err(RosError::Other(format!("cancel on {action}: {e:?}"))),
            Err(_) => {
                return Err(RosError::Timeout {
                    service: format!("{action}/_action/cancel_goal"),
                    timeout,
                })
            }
        };
        let return_code = match response.return_code {
            CancelGoalResponseEnum::None => "accepted",
            CancelGoalResponseEnum::Rejected => "rejected",
            CancelGoalResponseEnum::UnknownGoal => "unknown_goal",
            CancelGoalResponseEnum::GoalTerminated => "goal_terminated",
        };
        Ok(CancelOutcome {
            return_code: return_code.to_string(),
            canceling: response
                .goals_canceling
                .iter()
                .map(|g| goal_hex(&g.goal_id))
                .collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn goal_ids_round_trip_through_hex() {
        let id = GoalId::new_random();
        let hex = goal_hex(&id);
        assert_eq!(hex.len(), 32);
        assert_eq!(parse_goal_id(&hex).unwrap(), id);
        let dashed = format!("{}-{}", &hex[..8], &hex[8..]);
        assert_eq!(parse_goal_id(&dashed).unwrap(), id);
        assert!(parse_goal_id("abc").is_err());
        assert!(parse_goal_id(&"zz".repeat(16)).is_err());
    }

    #[test]
    fn only_action_types_are_actions() {
        assert!(action_type("turtlesim/action/RotateAbsolute").is_ok());
        assert!(action_type("turtlesim/srv/Spawn").is_err());
    }
}
