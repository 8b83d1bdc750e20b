//! The sim's `/navigate_to_pose` action (`nav2_msgs/action/NavigateToPose`), so a
//! place can be reached on the built-in robot as on a Nav2 robot: the goal is a pose in
//! the `map` frame (the arena's coordinates); turtle1 turns toward it, drives there at
//! a bounded speed, then turns to the goal's heading. Feedback at about 10 Hz carries
//! the current pose, the time so far, the distance remaining and an estimate of the
//! time left. A goal outside the arena, or not finite, is rejected; one in another
//! frame is aborted with Nav2's TF error. A new goal aborts the one running (as
//! bt_navigator preempts), a cancel ends it where it is, and like every motion of the
//! agent it drives through the agent's mux input, so the operator's teleop takes over.

use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use ros2_client::action::{AsyncActionServer, ExecutingGoalHandle, GoalEndStatus, GoalId};
use ros2_client::log::LogLevel;
use ros2_client::{ActionTypeName, Message, Node, ServiceMapping};
use serde::{Deserialize, Serialize};
use tokio::task::JoinHandle;

use super::world::{normalize_angle, Command, Navigation, Shared, Target, AGENT, ARENA, STEP};
use crate::ros::ros2::{action_server_qos, ros_name};
use crate::ros::RosError;

/// The action's name, as Nav2's bt_navigator serves it.
pub const ACTION: &str = "/navigate_to_pose";
/// The frame goals are given in: the arena's own coordinates.
pub const FRAME: &str = "map";
/// The turtle that navigates.
const ROBOT: &str = "turtle1";
/// Driving speed, m/s, and turning rate, rad/s: inside the default motion limits.
pub(crate) const SPEED: f64 = 0.5;
const TURN: f64 = 1.0;
/// Close enough: Nav2's default goal checker tolerances (0.25 m, 0.25 rad) made tighter,
/// as the sim has no noise.
const XY_TOLERANCE: f64 = 0.05;
const YAW_TOLERANCE: f64 = 0.05;
/// Heading error above which the turtle turns in place before it drives.
const AIM: f64 = 0.15;
/// Feedback every this many updates (about 10 Hz).
const FEEDBACK_EVERY: u32 = 6;
/// How long a finished goal waits for its client to ask for the result.
const RESULT_WAIT: Duration = Duration::from_secs(60);
/// Nav2's result codes (`NavigateToPose_Result`).
const TF_ERROR: u16 = 9002;

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
struct Stamp {
    sec: i32,
    nanosec: u32,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct Header {
    stamp: Stamp,
    frame_id: String,
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
struct Point {
    x: f64,
    y: f64,
    z: f64,
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
struct Quaternion {
    x: f64,
    y: f64,
    z: f64,
    w: f64,
}

#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
struct Pose {
    position: Point,
    orientation: Quaternion,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct PoseStamped {
    header: Header,
    pose: Pose,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Goal {
    pose: PoseStamped,
    behavior_tree: String,
}
impl Message for Goal {}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Outcome {
    error_code: u16,
    error_msg: String,
}
impl Message for Outcome {}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Feedback {
    current_pose: PoseStamped,
    navigation_time: Stamp,
    estimated_time_remaining: Stamp,
    number_of_recoveries: i16,
    distance_remaining: f32,
}
impl Message for Feedback {}

type Server = AsyncActionServer<Goal, Outcome, Feedback>;

/// What the navigator commands for one update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Steer {
    Drive { linear: f64, angular: f64 },
    Arrived,
}

/// The command that brings a turtle at (`x`, `y`, `theta`) to `target`: turn toward it,
/// drive with the heading corrected, then turn to the goal's heading.
pub(super) fn steer(x: f64, y: f64, theta: f64, target: &Target) -> Steer {
    let (dx, dy) = (target.x - x, target.y - y);
    let distance = dx.hypot(dy);
    if distance > XY_TOLERANCE {
        let error = normalize_angle(dy.atan2(dx) - theta);
        let angular = (2.0 * error).clamp(-TURN, TURN);
        let linear = if error.abs() > AIM {
            0.0
        } else {
            // Slow down over the last 20 cm so an update never overshoots.
            SPEED.min(distance * 2.5).max(0.05)
        };
        return Steer::Drive { linear, angular };
    }
    match target.yaw {
        Some(yaw) => {
            let error = normalize_angle(yaw - theta);
            if error.abs() <= YAW_TOLERANCE {
                Steer::Arrived
            } else {
                let rate = (2.0 * error.abs()).clamp(0.3, TURN);
                Steer::Drive {
                    linear: 0.0,
                    angular: rate.copysign(error),
                }
            }
        }
        None => Steer::Arrived,
    }
}

/// The heading of a quaternion about z; `None` for the zero quaternion (no orientation
/// given) or one that is not finite.
fn yaw_of(q: &Quaternion) -> Option<f64> {
    let norm = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
    if !norm.is_finite() || norm < 1e-9 {
        return None;
    }
    let (x, y, z, w) = (q.x / norm, q.y / norm, q.z / norm, q.w / norm);
    Some((2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z)))
}

/// Whether `goal` lies in the arena and is finite.
fn reachable(goal: &Goal) -> bool {
    let p = goal.pose.pose.position;
    p.x.is_finite()
        && p.y.is_finite()
        && (0.0..=ARENA).contains(&p.x)
        && (0.0..=ARENA).contains(&p.y)
}

fn stamp(d: Duration) -> Stamp {
    Stamp {
        sec: i32::try_from(d.as_secs()).unwrap_or(i32::MAX),
        nanosec: d.subsec_nanos(),
    }
}

fn pose_stamped(x: f64, y: f64, theta: f64) -> PoseStamped {
    let now = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default();
    PoseStamped {
        header: Header {
            stamp: stamp(now),
            frame_id: FRAME.to_string(),
        },
        pose: Pose {
            position: Point { x, y, z: 0.0 },
            orientation: Quaternion {
                x: 0.0,
                y: 0.0,
                z: (theta / 2.0).sin(),
                w: (theta / 2.0).cos(),
            },
        },
    }
}

/// Serve `/navigate_to_pose` for turtle1; the returned tasks take goals and cancels.
pub(super) fn serve(
    rt: &tokio::runtime::Handle,
    shared: &Arc<Shared>,
    node: &mut Node,
) -> Result<Vec<JoinHandle<()>>, RosError> {
    let server = node
        .create_action_server::<Goal, Outcome, Feedback>(
            ServiceMapping::Enhanced,
            &ros_name(ACTION)?,
            &ActionTypeName::new("nav2_msgs", "NavigateToPose"),
            action_server_qos(),
        )
        .map_err(|e| RosError::Other(format!("sim: {ACTION}: {e:?}")))?;
    let server = Arc::new(AsyncActionServer::new(server));
    let (s, srv) = (shared.clone(), server.clone());
    let rt2 = rt.clone();
    let goals = rt.spawn(async move {
        loop {
            let Ok(handle) = srv.receive_new_goal().await else {
                continue;
            };
            let Some(goal) = srv.get_new_goal(handle.clone()) else {
                continue;
            };
            if !reachable(&goal) {
                let p = goal.pose.pose.position;
                s.log(
                    LogLevel::Warn,
                    &format!("Goal ({}, {}) is outside the arena: rejected", p.x, p.y),
                );
                let _ = srv.reject_goal(handle).await;
                continue;
            }
            let Ok(accepted) = srv.accept_goal(handle).await else {
                continue;
            };
            let Ok(exec) = srv.start_executing_goal(accepted).await else {
                continue;
            };
            let frame = goal.pose.header.frame_id.trim_start_matches('/');
            if !frame.is_empty() && frame != FRAME {
                let msg = format!("no transform from {frame} to {FRAME}: give the goal in {FRAME}");
                s.log(LogLevel::Error, &msg);
                rt2.spawn(finish(
                    srv.clone(),
                    exec,
                    GoalEndStatus::Aborted,
                    TF_ERROR,
                    msg,
                ));
                continue;
            }
            let p = goal.pose.pose.position;
            let target = Target {
                x: p.x,
                y: p.y,
                yaw: yaw_of(&goal.pose.pose.orientation),
            };
            let preempted = {
                let mut world = s.world.lock().expect("world");
                // A navigation takes over from a rotation under way, as a new goal does.
                world.rotations.remove(ROBOT);
                let navigation = Navigation {
                    id: exec.goal_id(),
                    target,
                    cancel: false,
                };
                world
                    .navigations
                    .insert(ROBOT.to_string(), navigation)
                    .is_some()
            };
            if preempted {
                s.log(LogLevel::Info, "Navigation goal preempted by a new goal");
            }
            s.log(
                LogLevel::Info,
                &format!("Begin navigating to ({:.2}, {:.2})", target.x, target.y),
            );
            rt2.spawn(execute(s.clone(), srv.clone(), exec));
        }
    });
    let (s, srv) = (shared.clone(), server);
    let cancels = rt.spawn(async move {
        loop {
            let Ok(handle) = srv.receive_cancel_request().await else {
                continue;
            };
            let ids: Vec<GoalId> = handle.goals().collect();
            if let Some(n) = s.world.lock().expect("world").navigations.get_mut(ROBOT) {
                n.cancel |= ids.contains(&n.id);
            }
            let _ = srv
                .respond_to_cancel_requests(&handle, ids.into_iter())
                .await;
        }
    });
    Ok(vec![goals, cancels])
}

enum Next {
    Feedback(Box<Feedback>),
    Quiet,
    End(GoalEndStatus, String),
}

/// Drive turtle1 to the goal until it arrives, or the goal is canceled or replaced.
async fn execute(shared: Arc<Shared>, server: Arc<Server>, exec: ExecutingGoalHandle<Goal>) {
    let start = Instant::now();
    let mut tick = tokio::time::interval(STEP);
    let mut updates = 0u32;
    loop {
        tick.tick().await;
        updates += 1;
        let next = {
            let mut world = shared.world.lock().expect("world");
            let world = &mut *world;
            match (world.navigations.get(ROBOT), world.turtles.get_mut(ROBOT)) {
                (Some(n), Some(t)) if n.id == exec.goal_id() => {
                    let steer = steer(t.x, t.y, t.theta, &n.target);
                    let end = match (n.cancel, steer) {
                        (true, _) => Some((GoalEndStatus::Canceled, "canceled".to_string())),
                        (false, Steer::Arrived) => Some((GoalEndStatus::Succeeded, String::new())),
                        _ => None,
                    };
                    if let Some((status, msg)) = end {
                        world.navigations.remove(ROBOT);
                        t.inputs[AGENT] = None;
                        Next::End(status, msg)
                    } else {
                        let Steer::Drive { linear, angular } = steer else {
                            unreachable!("arrival ends the goal above")
                        };
                        t.inputs[AGENT] = Some(Command {
                            linear,
                            angular,
                            at: Instant::now(),
                        });
                        if updates % FEEDBACK_EVERY == 1 {
                            let distance = (n.target.x - t.x).hypot(n.target.y - t.y);
                            Next::Feedback(Box::new(Feedback {
                                current_pose: pose_stamped(t.x, t.y, t.theta),
                                navigation_time: stamp(start.elapsed()),
                                estimated_time_remaining: stamp(Duration::from_secs_f64(
                                    distance / SPEED,
                                )),
                                number_of_recoveries: 0,
                                distance_remaining: distance as f32,
                            }))
                        } else {
                            Next::Quiet
                        }
                    }
                }
                // Replaced by a newer goal, or the turtle is gone.
                _ => Next::End(GoalEndStatus::Aborted, "preempted".to_string()),
            }
        };
        match next {
            Next::Quiet => {}
            Next::Feedback(f) => {
                let _ = server.publish_feedback(exec.clone(), *f).await;
            }
            Next::End(status, msg) => {
                let how = match status {
                    GoalEndStatus::Succeeded => "succeeded",
                    GoalEndStatus::Canceled => "canceled",
                    _ => "aborted",
                };
                shared.log(LogLevel::Info, &format!("Navigation {how}"));
                let code = if status == GoalEndStatus::Aborted {
                    9000
                } else {
                    0
                };
                finish(server, exec, status, code, msg).await;
                return;
            }
        }
    }
}

async fn finish(
    server: Arc<Server>,
    exec: ExecutingGoalHandle<Goal>,
    status: GoalEndStatus,
    error_code: u16,
    error_msg: String,
) {
    let result = Outcome {
        error_code,
        error_msg,
    };
    let _ = tokio::time::timeout(
        RESULT_WAIT,
        server.send_result_response(exec, status, result),
    )
    .await;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::sim::world::Turtle;

    /// Run the navigator on a turtle with turtlesim's kinematics until it arrives.
    fn drive(mut t: Turtle, target: Target) -> (Turtle, f64) {
        let dt = STEP.as_secs_f64();
        let mut now = Instant::now();
        for i in 0..20_000 {
            match steer(t.x, t.y, t.theta, &target) {
                Steer::Arrived => return (t, i as f64 * dt),
                Steer::Drive { linear, angular } => {
                    t.inputs[AGENT] = Some(Command {
                        linear,
                        angular,
                        at: now,
                    });
                    now += STEP;
                    t.step(dt, now);
                    assert!(t.linear.abs() <= SPEED + 1e-9 && t.angular.abs() <= TURN + 1e-9);
                }
            }
        }
        panic!(
            "never arrived at {target:?}: at ({}, {}, {})",
            t.x, t.y, t.theta
        );
    }

    #[test]
    fn reaches_the_point_then_the_heading() {
        let target = Target {
            x: 2.0,
            y: 9.0,
            yaw: Some(-1.2),
        };
        let (t, seconds) = drive(Turtle::at(5.5, 5.5, 0.0), target);
        assert!((t.x - 2.0).hypot(t.y - 9.0) <= XY_TOLERANCE);
        assert!(normalize_angle(t.theta + 1.2).abs() <= YAW_TOLERANCE);
        // About 4.9 m at 0.5 m/s, plus the turns: bounded speed, no detour.
        assert!((9.0..20.0).contains(&seconds), "{seconds} s");
    }

    #[test]
    fn no_orientation_keeps_the_heading_it_arrives_with() {
        let target = Target {
            x: 6.5,
            y: 5.5,
            yaw: None,
        };
        let (t, _) = drive(Turtle::at(5.5, 5.5, 0.0), target);
        assert!((t.x - 6.5).abs() <= XY_TOLERANCE && t.theta.abs() < 0.2);
    }

    #[test]
    fn quaternions_read_as_headings() {
        let q = |theta: f64| Quaternion {
            x: 0.0,
            y: 0.0,
            z: (theta / 2.0).sin(),
            w: (theta / 2.0).cos(),
        };
        for theta in [0.0, 1.0, -2.5, 3.1] {
            assert!((yaw_of(&q(theta)).unwrap() - theta).abs() < 1e-9);
        }
        assert_eq!(yaw_of(&Quaternion::default()), None);
        let nan = Quaternion {
            w: f64::NAN,
            ..Quaternion::default()
        };
        assert_eq!(yaw_of(&nan), None);
    }

    #[test]
    fn goals_outside_the_arena_are_not_taken() {
        let goal = |x: f64, y: f64| Goal {
            pose: PoseStamped {
                pose: Pose {
                    position: Point { x, y, z: 0.0 },
                    ..Pose::default()
                },
                ..PoseStamped::default()
            },
            behavior_tree: String::new(),
        };
        assert!(reachable(&goal(1.0, 10.0)));
        assert!(!reachable(&goal(-0.5, 3.0)));
        assert!(!reachable(&goal(3.0, 12.0)));
        assert!(!reachable(&goal(f64::NAN, 3.0)));
    }
}
