//! The sim's `<turtle>/rotate_absolute` action (turtlesim/action/RotateAbsolute), as
//! turtlesim runs it: each update the turtle turns at 1 rad/s toward the goal's heading
//! and reports the angle remaining; within 0.02 rad it stops and succeeds with the angle
//! turned (start minus end, as turtlesim reports it). A new goal aborts the one running;
//! a cancel ends it where it is.

use std::sync::Arc;
use std::time::{Duration, Instant};

use ros2_client::action::{AsyncActionServer, ExecutingGoalHandle, GoalEndStatus, GoalId};
use ros2_client::log::LogLevel;
use ros2_client::{ActionTypeName, Message, Node, ServiceMapping};
use serde::{Deserialize, Serialize};
use tokio::task::JoinHandle;

use super::world::{normalize_angle, Command, Rotation, Shared, AGENT, STEP};
use crate::ros::ros2::{action_server_qos, ros_name};
use crate::ros::RosError;

/// Close enough to the goal heading (turtlesim's tolerance), in radians.
const TOLERANCE: f64 = 0.02;
/// How long a finished goal waits for its client to ask for the result.
const RESULT_WAIT: Duration = Duration::from_secs(60);

// Copy, so ros2-client's goal handles (Copy only when the goal is) can be reused.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
struct Goal {
    theta: f32,
}
impl Message for Goal {}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Outcome {
    delta: f32,
}
impl Message for Outcome {}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Feedback {
    remaining: f32,
}
impl Message for Feedback {}

type Server = AsyncActionServer<Goal, Outcome, Feedback>;

/// Serve `/<turtle>/rotate_absolute`; the returned tasks take goals and cancels.
pub(super) fn serve(
    rt: &tokio::runtime::Handle,
    shared: &Arc<Shared>,
    node: &mut Node,
    turtle: &str,
) -> Result<Vec<JoinHandle<()>>, RosError> {
    let name = format!("/{turtle}/rotate_absolute");
    let server = node
        .create_action_server::<Goal, Outcome, Feedback>(
            ServiceMapping::Enhanced,
            &ros_name(&name)?,
            &ActionTypeName::new("turtlesim", "RotateAbsolute"),
            action_server_qos(),
        )
        .map_err(|e| RosError::Other(format!("sim: {name}: {e:?}")))?;
    let server = Arc::new(AsyncActionServer::new(server));
    let (s, srv, who) = (shared.clone(), server.clone(), turtle.to_string());
    let rt2 = rt.clone();
    let goals = rt.spawn(async move {
        loop {
            let Ok(handle) = srv.receive_new_goal().await else {
                continue;
            };
            let Some(goal) = srv.get_new_goal(handle) else {
                continue;
            };
            let Ok(accepted) = srv.accept_goal(handle).await else {
                continue;
            };
            let Ok(exec) = srv.start_executing_goal(accepted).await else {
                continue;
            };
            let preempted = {
                let mut world = s.world.lock().expect("world");
                let Some(t) = world.turtles.get(&who) else {
                    break;
                };
                let rotation = Rotation {
                    id: exec.goal_id(),
                    target: f64::from(goal.theta),
                    start: t.theta,
                    cancel: false,
                };
                // A rotation takes over from a navigation under way.
                world.navigations.remove(&who);
                world.rotations.insert(who.clone(), rotation).is_some()
            };
            if preempted {
                s.log(
                    LogLevel::Warn,
                    "Rotation goal received before a previous goal finished. Aborting previous goal",
                );
            }
            rt2.spawn(execute(s.clone(), srv.clone(), who.clone(), exec));
        }
    });
    let (s, srv, who) = (shared.clone(), server, turtle.to_string());
    let cancels = rt.spawn(async move {
        loop {
            let Ok(handle) = srv.receive_cancel_request().await else {
                continue;
            };
            let ids: Vec<GoalId> = handle.goals().collect();
            if let Some(r) = s.world.lock().expect("world").rotations.get_mut(&who) {
                r.cancel |= ids.contains(&r.id);
            }
            let _ = srv
                .respond_to_cancel_requests(&handle, ids.into_iter())
                .await;
        }
    });
    Ok(vec![goals, cancels])
}

enum Next {
    Feedback(f64),
    End(GoalEndStatus, f64),
}

/// Turn the turtle toward the goal until it is reached, canceled or replaced.
async fn execute(
    shared: Arc<Shared>,
    server: Arc<Server>,
    who: String,
    exec: ExecutingGoalHandle<Goal>,
) {
    let mut tick = tokio::time::interval(STEP);
    loop {
        tick.tick().await;
        let next = {
            let mut world = shared.world.lock().expect("world");
            let world = &mut *world;
            match (world.rotations.get(&who), world.turtles.get_mut(&who)) {
                (Some(r), Some(t)) if r.id == exec.goal_id() => {
                    let remaining = normalize_angle(r.target - t.theta);
                    let turned = normalize_angle(r.start - t.theta);
                    let end = if r.cancel {
                        Some(GoalEndStatus::Canceled)
                    } else if remaining.abs() < TOLERANCE {
                        Some(GoalEndStatus::Succeeded)
                    } else {
                        None
                    };
                    match end {
                        Some(status) => {
                            world.rotations.remove(&who);
                            t.inputs[AGENT] = None;
                            Next::End(status, turned)
                        }
                        None => {
                            // The action drives through the agent's input: the operator's
                            // teleop takes over from it as from any agent command.
                            t.inputs[AGENT] = Some(Command {
                                linear: 0.0,
                                angular: if remaining < 0.0 { -1.0 } else { 1.0 },
                                at: Instant::now(),
                            });
                            Next::Feedback(remaining)
                        }
                    }
                }
                // Replaced by a newer goal, or the turtle was killed.
                _ => Next::End(GoalEndStatus::Aborted, 0.0),
            }
        };
        match next {
            Next::Feedback(remaining) => {
                let feedback = Feedback {
                    remaining: remaining as f32,
                };
                let _ = server.publish_feedback(exec, feedback).await;
            }
            Next::End(status, delta) => {
                let how = match status {
                    GoalEndStatus::Succeeded => "completed",
                    GoalEndStatus::Canceled => "canceled",
                    _ => "aborted",
                };
                shared.log(LogLevel::Info, &format!("Rotation goal {how}"));
                let result = Outcome {
                    delta: delta as f32,
                };
                let _ = tokio::time::timeout(
                    RESULT_WAIT,
                    server.send_result_response(exec, status, result),
                )
                .await;
                return;
            }
        }
    }
}
