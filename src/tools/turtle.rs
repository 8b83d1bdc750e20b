//! The sim turtle's own tools, written with the public `Tool` API over a `RosGraph`:
//! the worked example of robot-specific tools for integrators (see prompts/turtlesim.toml
//! for its prompt). Motion tools wait for the move to finish and return the new pose.

use std::sync::Arc;
use std::time::Duration;

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use crate::ros::RosGraph;
use crate::tool::{Effect, Package, Tool, ToolContext, ToolError};
use crate::tools::ros::failed;

/// The turtle tools for `turtle` (e.g. "turtle1").
pub fn package(graph: Arc<dyn RosGraph>, turtle: &str) -> Package {
    let t = || Turtle {
        graph: graph.clone(),
        name: turtle.trim_matches('/').to_string(),
    };
    Package::new("turtle")
        .with(Move(t()))
        .with(Rotate(t()))
        .with(Pose(t()))
        .with(Teleport(t()))
        .with(Pen(t(), Default::default()))
        .with(Reset(t()))
}

#[derive(Clone)]
pub struct Turtle {
    graph: Arc<dyn RosGraph>,
    name: String,
}

/// How often a motion command is repeated while the turtle moves (turtlesim drops a
/// command after one second; a stop must not wait that long to be noticed).
const TICK: Duration = Duration::from_millis(100);
/// How often a motion says how far it has got.
const REPORT_EVERY: Duration = Duration::from_millis(500);
/// Default speeds: well inside the default motion limits.
const SPEED: f64 = 0.5;
const TURN_RATE: f64 = 1.0;

/// How a motion went.
struct Drive {
    /// Seconds the command was held at the speed actually sent.
    seconds: f64,
    /// The speed actually sent (after the ROS boundary's limits).
    speed: f64,
    /// What the boundary said, if anything (a clamp, the mux).
    note: Option<String>,
    /// The operator's input took over the mux (the motion ended early).
    overridden: bool,
}

impl Drive {
    /// `out` with what the limits changed and whether the operator took over.
    fn report(self, mut out: Value) -> Value {
        if let Some(n) = self.note {
            out["limited"] = json!(n);
        }
        if self.overridden {
            out["overridden"] =
                json!("the operator's input took over the mux: the motion ended early");
        }
        out
    }
}

impl Turtle {
    async fn pose(&self) -> Result<Value, ToolError> {
        let topic = format!("/{}/pose", self.name);
        let samples = self
            .graph
            .subscribe(
                &topic,
                Some("turtlesim/msg/Pose"),
                1,
                Duration::from_secs(3),
            )
            .await
            .map_err(failed)?;
        let p = samples
            .into_iter()
            .next()
            .ok_or_else(|| ToolError::Failed(format!("no pose on {topic}; is the sim running?")))?
            .message;
        let round = |v: &Value| (v.as_f64().unwrap_or(0.0) * 1000.0).round() / 1000.0;
        Ok(json!({"x": round(&p["x"]), "y": round(&p["y"]),
                  "theta_deg": (p["theta"].as_f64().unwrap_or(0.0).to_degrees() * 10.0).round() / 10.0}))
    }

    /// Command `linear` m/s and `angular` rad/s until `amount` (metres or radians, by
    /// the speed actually sent) is covered, repeating the command every tick, then
    /// command zero; how much is covered so far goes to `cx`'s progress as `say` words
    /// it. Stops early when the operator's input takes over the mux.
    async fn drive(
        &self,
        linear: f64,
        angular: f64,
        amount: f64,
        cx: &ToolContext,
        say: impl Fn(f64) -> String,
    ) -> Result<Drive, ToolError> {
        let topic = format!("/{}/cmd_vel", self.name);
        let twist = |l: f64, a: f64| json!({"linear": {"x": l}, "angular": {"z": a}});
        let start = std::time::Instant::now();
        let mut sent = self
            .graph
            .publish(&topic, "geometry_msgs/msg/Twist", twist(linear, angular))
            .await
            .map_err(failed)?;
        // The speed that went out (the boundary may have clamped it) sets the duration.
        let speed = match &sent.sent {
            Some(m) if linear != 0.0 => m["linear"]["x"].as_f64().unwrap_or(linear),
            Some(m) => m["angular"]["z"].as_f64().unwrap_or(angular),
            None if linear != 0.0 => linear,
            None => angular,
        };
        let (l, a) = match &sent.sent {
            Some(m) => (
                m["linear"]["x"].as_f64().unwrap_or(0.0),
                m["angular"]["z"].as_f64().unwrap_or(0.0),
            ),
            None => (linear, angular),
        };
        let seconds = if speed.abs() > 1e-9 {
            (amount / speed).abs()
        } else {
            0.0
        };
        let mut note = sent.note.clone();
        let mut overridden = sent.overridden_by.is_some();
        let mut reported = start;
        while !overridden && start.elapsed().as_secs_f64() + TICK.as_secs_f64() < seconds {
            tokio::time::sleep(TICK).await;
            if reported.elapsed() >= REPORT_EVERY {
                reported = std::time::Instant::now();
                cx.progress
                    .report(say((start.elapsed().as_secs_f64() * speed).abs()));
            }
            sent = self
                .graph
                .publish(&topic, "geometry_msgs/msg/Twist", twist(l, a))
                .await
                .map_err(failed)?;
            if sent.note.is_some() {
                note = sent.note.clone();
            }
            overridden = sent.overridden_by.is_some();
        }
        let left = seconds - start.elapsed().as_secs_f64();
        if left > 0.0 && !overridden {
            tokio::time::sleep(Duration::from_secs_f64(left)).await;
        }
        self.graph
            .publish(&topic, "geometry_msgs/msg/Twist", twist(0.0, 0.0))
            .await
            .map_err(failed)?;
        Ok(Drive {
            seconds: start.elapsed().as_secs_f64().min(seconds),
            speed,
            note,
            overridden,
        })
    }

    async fn call(
        &self,
        service: &str,
        ty: &str,
        request: Value,
        cx: &ToolContext,
    ) -> Result<crate::ros::Reply, ToolError> {
        self.graph
            .call_service(service, ty, request, cx.timeout)
            .await
            .map_err(failed)
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct MoveArgs {
    /// Meters to drive, -5 to 5 (negative drives backward).
    #[schemars(range(min = -5.0, max = 5.0))]
    pub distance: f64,
    /// Speed in m/s, 0.05 to 1 (default 0.5); the robot's motion limits may lower it.
    #[serde(default)]
    #[schemars(range(min = 0.05, max = 1.0))]
    pub speed: Option<f64>,
}

pub struct Move(Turtle);

impl Tool for Move {
    type Args = MoveArgs;
    const NAME: &'static str = "turtle_move";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Drive the turtle straight forward (or backward) a distance in meters; returns the new pose. Moves the robot.".into()
    }
    async fn call(&self, a: MoveArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let d = a.distance.clamp(-5.0, 5.0);
        let speed = a.speed.unwrap_or(SPEED).clamp(0.05, 1.0).copysign(d);
        let say = |m: f64| format!("{m:.1} of {:.1} m driven", d.abs());
        let drive = self.0.drive(speed, 0.0, d, cx, say).await?;
        let moved = (drive.seconds * drive.speed * 1000.0).round() / 1000.0;
        let out = json!({"requested_m": d, "moved_m": moved, "speed_m_s": drive.speed.abs(),
                             "pose": self.0.pose().await?});
        Ok(drive.report(out))
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct RotateArgs {
    /// Degrees to turn, -180 to 180 (positive is counter-clockwise, to the left).
    #[schemars(range(min = -180.0, max = 180.0))]
    pub degrees: f64,
}

pub(crate) struct Rotate(Turtle);

impl Tool for Rotate {
    type Args = RotateArgs;
    const NAME: &'static str = "turtle_rotate";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Turn the turtle in place by an angle in degrees (positive turns left); returns the new pose. Moves the robot.".into()
    }
    async fn call(&self, a: RotateArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let deg = a.degrees.clamp(-180.0, 180.0);
        let rate = TURN_RATE.copysign(deg);
        let say = |r: f64| format!("{:.0} of {:.0}° turned", r.to_degrees(), deg.abs());
        let drive = self.0.drive(0.0, rate, deg.to_radians(), cx, say).await?;
        let turned = (drive.seconds * drive.speed).to_degrees();
        let out = json!({"requested_deg": deg, "turned_deg": (turned * 10.0).round() / 10.0,
                             "pose": self.0.pose().await?});
        Ok(drive.report(out))
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct NoArgs {}

pub struct Pose(Turtle);

impl Tool for Pose {
    type Args = NoArgs;
    const NAME: &'static str = "turtle_pose";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Where the turtle is: x and y in meters and heading in degrees.".into()
    }
    async fn call(&self, _: NoArgs, _: &ToolContext) -> Result<Value, ToolError> {
        self.0.pose().await
    }
}

#[derive(Deserialize, JsonSchema)]
pub struct TeleportArgs {
    /// x in meters, 0 to 11.
    #[schemars(range(min = 0.0, max = 11.0))]
    pub x: f64,
    /// y in meters, 0 to 11.
    #[schemars(range(min = 0.0, max = 11.0))]
    pub y: f64,
    /// Heading in degrees (default 0, facing +x).
    #[serde(default)]
    #[schemars(range(min = -180.0, max = 180.0))]
    pub theta_deg: Option<f64>,
}

pub struct Teleport(Turtle);

impl Tool for Teleport {
    type Args = TeleportArgs;
    const NAME: &'static str = "turtle_teleport";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Put the turtle at a position (x, y in meters) instantly. Moves the robot.".into()
    }
    async fn call(&self, a: TeleportArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let service = format!("/{}/teleport_absolute", self.0.name);
        let theta = a.theta_deg.unwrap_or(0.0).to_radians();
        self.0
            .call(
                &service,
                "turtlesim/srv/TeleportAbsolute",
                json!({"x": a.x, "y": a.y, "theta": theta}),
                cx,
            )
            .await?;
        tokio::time::sleep(Duration::from_millis(100)).await;
        Ok(json!({"teleported": true, "pose": self.0.pose().await?}))
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct PenArgs {
    /// Pen colour, red 0-255.
    #[serde(default)]
    #[schemars(range(min = 0, max = 255))]
    pub r: Option<u8>,
    /// Green 0-255.
    #[serde(default)]
    #[schemars(range(min = 0, max = 255))]
    pub g: Option<u8>,
    /// Blue 0-255.
    #[serde(default)]
    #[schemars(range(min = 0, max = 255))]
    pub b: Option<u8>,
    /// Line width 1-10.
    #[serde(default)]
    #[schemars(range(min = 1, max = 10))]
    pub width: Option<u8>,
    /// up: lifted, draws nothing; down: draws.
    #[serde(default)]
    pub pen: Option<PenPosition>,
}

#[derive(Deserialize, JsonSchema, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub(crate) enum PenPosition {
    Up,
    Down,
}

/// The pen as last set: turtlesim's set_pen takes every field at once, so what a call
/// leaves out keeps its value (turtlesim starts with 179, 184, 255, width 3, down).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct PenState {
    r: u8,
    g: u8,
    b: u8,
    width: u8,
    off: bool,
}

impl Default for PenState {
    fn default() -> Self {
        PenState {
            r: 179,
            g: 184,
            b: 255,
            width: 3,
            off: false,
        }
    }
}

impl PenState {
    fn with(self, a: &PenArgs) -> PenState {
        PenState {
            r: a.r.unwrap_or(self.r),
            g: a.g.unwrap_or(self.g),
            b: a.b.unwrap_or(self.b),
            width: a.width.unwrap_or(self.width),
            off: a.pen.map_or(self.off, |p| p == PenPosition::Up),
        }
    }
}

pub(crate) struct Pen(Turtle, std::sync::Mutex<PenState>);

impl Tool for Pen {
    type Args = PenArgs;
    const NAME: &'static str = "turtle_pen";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Set the turtle's pen: colour (r, g, b), width, or lift it (pen up) or put it down. Fields left out keep their value.".into()
    }
    async fn call(&self, a: PenArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        let last = *self.1.lock().unwrap_or_else(|e| e.into_inner());
        let pen = last.with(&a);
        let req =
            json!({"r": pen.r, "g": pen.g, "b": pen.b, "width": pen.width, "off": pen.off as u8});
        self.0
            .call(
                &format!("/{}/set_pen", self.0.name),
                "turtlesim/srv/SetPen",
                req.clone(),
                cx,
            )
            .await?;
        *self.1.lock().unwrap_or_else(|e| e.into_inner()) = pen;
        Ok(json!({"pen": req}))
    }
}

pub(crate) struct Reset(Turtle);

impl Tool for Reset {
    type Args = NoArgs;
    const NAME: &'static str = "turtle_reset";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Reset the sim: remove other turtles and put the turtle back at the center. Moves the robot.".into()
    }
    async fn call(&self, _: NoArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        self.0
            .call("/reset", "std_srvs/srv/Empty", json!({}), cx)
            .await?;
        tokio::time::sleep(Duration::from_millis(100)).await;
        Ok(json!({"reset": true, "pose": self.0.pose().await?}))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pen_call_keeps_what_it_leaves_out() {
        let args = |v: Value| serde_json::from_value::<PenArgs>(v).unwrap();
        let red = PenState::default().with(&args(json!({"r": 255, "g": 0, "b": 0})));
        assert_eq!(
            (red.r, red.g, red.b, red.width, red.off),
            (255, 0, 0, 3, false)
        );
        let up = red.with(&args(json!({"pen": "up"})));
        assert_eq!(up, PenState { off: true, ..red });
        assert_eq!(up.with(&args(json!({"pen": "down"}))), red);
    }
}
