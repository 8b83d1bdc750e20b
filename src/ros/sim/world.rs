//! The sim's state: its turtles (turtlesim's kinematics in turtlesim's arena), the goals
//! they turn toward, the battery, and what every part of the sim shares.

use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use ros2_client::action::GoalId;
use ros2_client::builtin_interfaces::Time;
use ros2_client::log::LogLevel;
use ros2_client::rosout::RosoutRaw;
use ros2_client::{Node, NodeLoggingHandle};
use serde_json::{json, Value};
use tokio::task::JoinHandle;

use crate::ros::Interfaces;

/// The arena's side, in metres (turtlesim's 500 px at 45 px/m).
pub const ARENA: f64 = 11.088889;
/// Where turtles start and reset to.
pub const CENTER: f64 = 5.544445;
pub(super) const STEP: Duration = Duration::from_millis(16);
pub(super) const COMMAND_HOLD: Duration = Duration::from_secs(1);
/// How long after start-up (or a spawn) a turtle's topics begin to publish.
pub(super) const PUBLISH_AFTER: Duration = Duration::from_secs(2);

/// The inputs of a turtle's velocity mux, highest priority first (twist_mux semantics:
/// the highest-priority input that commanded within `COMMAND_HOLD` drives the turtle).
pub(super) const INPUTS: [(&str, &str); 2] = [("cmd_vel", "teleop"), ("cmd_vel_agent", "agent")];
/// The agent's input, in `INPUTS`.
pub(super) const AGENT: usize = 1;

/// One velocity command on one mux input.
#[derive(Debug, Clone, Copy)]
pub(super) struct Command {
    pub(super) linear: f64,
    pub(super) angular: f64,
    pub(super) at: Instant,
}

#[derive(Debug, Clone)]
pub(super) struct Turtle {
    pub(super) x: f64,
    pub(super) y: f64,
    pub(super) theta: f64,
    pub(super) linear: f64,
    pub(super) angular: f64,
    /// The last command on each mux input (`INPUTS`).
    pub(super) inputs: [Option<Command>; 2],
    pub(super) pen_on: bool,
}

impl Turtle {
    pub(super) fn at(x: f64, y: f64, theta: f64) -> Turtle {
        Turtle {
            x,
            y,
            theta,
            linear: 0.0,
            angular: 0.0,
            inputs: [None; 2],
            pen_on: true,
        }
    }

    /// One turtlesim update: turn, then move, then stay inside the arena.
    /// Returns true when the turtle hit the wall.
    pub(super) fn step(&mut self, dt: f64, now: Instant) -> bool {
        match self.active(now) {
            Some(i) => {
                let c = self.inputs[i].expect("an active input has a command");
                (self.linear, self.angular) = (c.linear, c.angular);
            }
            None => (self.linear, self.angular) = (0.0, 0.0),
        }
        self.theta = normalize_angle(self.theta + self.angular * dt);
        self.x += self.theta.cos() * self.linear * dt;
        self.y += self.theta.sin() * self.linear * dt;
        let hit = self.x < 0.0 || self.x > ARENA || self.y < 0.0 || self.y > ARENA;
        self.x = self.x.clamp(0.0, ARENA);
        self.y = self.y.clamp(0.0, ARENA);
        hit
    }

    /// The mux input driving the turtle now, if any.
    pub(super) fn active(&self, now: Instant) -> Option<usize> {
        self.inputs
            .iter()
            .position(|c| c.is_some_and(|c| now.duration_since(c.at) <= COMMAND_HOLD))
    }

    pub(super) fn pose(&self) -> Value {
        json!({"x": self.x, "y": self.y, "theta": self.theta,
               "linear_velocity": self.linear, "angular_velocity": self.angular})
    }
}

pub(super) fn normalize_angle(a: f64) -> f64 {
    let mut a = a % (2.0 * PI);
    if a > PI {
        a -= 2.0 * PI;
    } else if a < -PI {
        a += 2.0 * PI;
    }
    a
}

pub(super) struct World {
    pub(super) turtles: BTreeMap<String, Turtle>,
    /// The `rotate_absolute` goal each turtle is turning toward.
    pub(super) rotations: BTreeMap<String, Rotation>,
    /// The `navigate_to_pose` goal each turtle is driving to.
    pub(super) navigations: BTreeMap<String, Navigation>,
    pub(super) battery: f64,
    pub(super) tasks: BTreeMap<String, Vec<JoinHandle<()>>>,
}

pub(super) struct Shared {
    pub(super) world: Mutex<World>,
    pub(super) interfaces: Interfaces,
    pub(super) log: NodeLoggingHandle,
    pub(super) node: tokio::sync::Mutex<Node>,
    pub(super) background: Mutex<[i64; 3]>,
}

impl Shared {
    pub(super) fn log(&self, level: LogLevel, msg: &str) {
        self.log.rosout_raw(
            Time::now(),
            level,
            "turtlesim",
            msg,
            file!(),
            "sim",
            line!(),
        );
    }
}

/// The goal a turtle is turning toward.
#[derive(Debug, Clone)]
pub(super) struct Rotation {
    pub id: GoalId,
    pub target: f64,
    pub start: f64,
    pub cancel: bool,
}

/// Where a navigation goal ends: a point in the arena, and the heading to end at (none
/// when the goal's orientation is no rotation at all, all zeros).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Target {
    pub x: f64,
    pub y: f64,
    pub yaw: Option<f64>,
}

/// The goal turtle1 is navigating to.
#[derive(Debug, Clone)]
pub(super) struct Navigation {
    pub id: GoalId,
    pub target: Target,
    pub cancel: bool,
}
