//! Motion limits: how fast a robot may be told to move, and how far a motion service
//! may take it, out of the box and per robot (the policy file's `[motion]` table).
//!
//! They are enforced at the ROS boundary (`ros::boundary`) on the message as it will be
//! encoded (every field filled in, any spelling of the type resolved), so no tool, no
//! argument name and no type spelling gets around them:
//!
//! - every message carrying a `geometry_msgs/Twist` (`Twist`, `TwistStamped`, and any
//!   type nesting one): the norm of `linear` at most `linear_max` m/s, of `angular` at
//!   most `angular_max` rad/s; a velocity type ferrosa ships (`VELOCITY_TYPES`) must
//!   hold its Twist where its shipped definition puts it, under the shipped field
//!   names, or it is refused: a peer's definition with renamed fields cannot carry a
//!   speed past the limits;
//! - `turtlesim/srv/TeleportRelative`: `linear` at most `teleport_max` m, `angular` at
//!   most π; `TeleportAbsolute`: finite coordinates inside `workspace` when one is set;
//! - `nav2_msgs/action/NavigateToPose` goals: the goal position inside `workspace` when
//!   one is set;
//! - parameters set through `rcl_interfaces/srv/SetParameters` whose names match a rule's
//!   pattern: numeric values within its bounds;
//! - everywhere: no NaN, no infinity.
//!
//! A value over its limit is clamped (scaled down to the limit) or the message refused,
//! as `on_exceed` says; either way the boundary reports what it did.
//! Depends on nothing else in the crate.

use serde::Deserialize;
use serde_json::Value;

/// The velocity types ferrosa ships, and where each holds its Twist by its shipped
/// definition (field names; `*` for every element of an array).
pub(crate) const VELOCITY_TYPES: [(&str, &[&str]); 7] = [
    ("geometry_msgs/msg/Twist", &[]),
    ("geometry_msgs/msg/TwistStamped", &["twist"]),
    ("geometry_msgs/msg/TwistWithCovariance", &["twist"]),
    (
        "geometry_msgs/msg/TwistWithCovarianceStamped",
        &["twist", "twist"],
    ),
    ("geometry_msgs/msg/VelocityStamped", &["velocity"]),
    ("nav_msgs/msg/Odometry", &["twist", "twist"]),
    ("sensor_msgs/msg/MultiDOFJointState", &["twist", "*"]),
];

/// What to do with a value over its limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum OnExceed {
    /// Scale it down to the limit, and say so.
    #[default]
    Clamp,
    /// Refuse the message.
    Block,
}

/// A bound on parameters of some nodes.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamLimit {
    /// Regex on parameter names (e.g. "max_vel").
    pub name: String,
    #[serde(default)]
    pub min: Option<f64>,
    #[serde(default)]
    pub max: Option<f64>,
}

/// The `[motion]` table (see the module header). Every field has a default.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Motion {
    pub linear_max: f64,
    pub angular_max: f64,
    pub teleport_max: f64,
    /// `[x_min, y_min, x_max, y_max]` for absolute teleports.
    pub workspace: Option<[f64; 4]>,
    pub on_exceed: OnExceed,
    #[serde(rename = "param")]
    pub params: Vec<ParamLimit>,
    /// Velocity topics the robot listens to, braked by the e-stop even before the agent
    /// commanded them (besides every topic it did command).
    pub velocity_topics: Vec<String>,
    /// The operator's velocity topic → the agent's lower-priority input to the mux
    /// (twist_mux semantics: while the operator's input is active, the agent's is
    /// dropped). The agent's motion sent to the operator's topic goes to its own.
    pub mux: std::collections::BTreeMap<String, String>,
    /// Where the mux says which input is active (std_msgs/String).
    pub mux_status: Option<String>,
}

impl Default for Motion {
    fn default() -> Motion {
        Motion {
            linear_max: 1.0,
            angular_max: 1.5,
            teleport_max: 2.0,
            workspace: None,
            on_exceed: OnExceed::Clamp,
            params: Vec::new(),
            velocity_topics: Vec::new(),
            mux: Default::default(),
            mux_status: None,
        }
    }
}

/// What the limits did to a message.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// Within every limit.
    Within,
    /// Scaled down; the message to send instead, and what was changed.
    Clamped(Value, String),
    /// Refused, and why.
    Refused(String),
}

impl Motion {
    /// Check `message` of type `type_name` (`pkg/msg/Name` or `pkg/srv/Name_Request`)
    /// against the limits. `message` is the full message as it will be encoded.
    pub fn check(&self, type_name: &str, message: &Value) -> Verdict {
        if let Some(path) = non_finite(message, String::new()) {
            return Verdict::Refused(format!("{path} is not a finite number"));
        }
        if let Some((_, path)) = VELOCITY_TYPES.iter().find(|(t, _)| *t == type_name) {
            if !twist_at(message, path) {
                return Verdict::Refused(format!(
                    "this {type_name} does not hold its Twist as ferrosa's definition does (at /{}, `linear` and `angular`); a velocity type is read by its shipped definition only",
                    path.join("/")
                ));
            }
        }
        let mut out = message.clone();
        let mut changes = Vec::new();
        let r = match type_name {
            "turtlesim/srv/TeleportRelative_Request" => {
                self.teleport_relative(&mut out, &mut changes)
            }
            "turtlesim/srv/TeleportAbsolute_Request" => self.teleport_absolute(&out),
            "nav2_msgs/action/NavigateToPose_Goal" => {
                self.teleport_absolute(&out["pose"]["pose"]["position"])
            }
            "rcl_interfaces/srv/SetParameters_Request"
            | "rcl_interfaces/srv/SetParametersAtomically_Request" => {
                self.parameters(&mut out, &mut changes)
            }
            _ => self.twists(&mut out, &mut changes),
        };
        if let Err(why) = r {
            return Verdict::Refused(why);
        }
        if changes.is_empty() {
            Verdict::Within
        } else {
            Verdict::Clamped(out, changes.join("; "))
        }
    }

    /// Bound `v` (at `what`) to `max` in norm, per `on_exceed`.
    fn bound(
        &self,
        what: &str,
        v: &mut [f64],
        max: f64,
        changes: &mut Vec<String>,
    ) -> Result<(), String> {
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm <= max + 1e-9 {
            return Ok(());
        }
        match self.on_exceed {
            OnExceed::Block => Err(format!("{what} {norm:.3} exceeds the limit {max}")),
            OnExceed::Clamp => {
                let k = max / norm;
                v.iter_mut().for_each(|x| *x *= k);
                changes.push(format!("{what} clamped from {norm:.3} to {max}"));
                Ok(())
            }
        }
    }

    /// Every Twist inside the message (a `linear` and an `angular` vector side by side),
    /// in arrays and sequences too.
    fn twists(&self, v: &mut Value, changes: &mut Vec<String>) -> Result<(), String> {
        let map = match v {
            Value::Object(map) => map,
            Value::Array(items) => {
                for x in items {
                    self.twists(x, changes)?;
                }
                return Ok(());
            }
            _ => return Ok(()),
        };
        if is_vector(map.get("linear")) && is_vector(map.get("angular")) {
            for (key, max) in [("linear", self.linear_max), ("angular", self.angular_max)] {
                let mut xyz = vector(&map[key]);
                self.bound(&format!("{key} speed"), &mut xyz, max, changes)?;
                set_vector(map.get_mut(key).expect("checked above"), xyz);
            }
        }
        for x in map.values_mut() {
            self.twists(x, changes)?;
        }
        Ok(())
    }

    fn teleport_relative(&self, v: &mut Value, changes: &mut Vec<String>) -> Result<(), String> {
        let mut d = [v["linear"].as_f64().unwrap_or(0.0)];
        self.bound("teleport distance", &mut d, self.teleport_max, changes)?;
        v["linear"] = d[0].into();
        let mut a = [v["angular"].as_f64().unwrap_or(0.0)];
        self.bound("teleport turn", &mut a, std::f64::consts::PI, changes)?;
        v["angular"] = a[0].into();
        Ok(())
    }

    fn teleport_absolute(&self, v: &Value) -> Result<(), String> {
        let (x, y) = (
            v["x"].as_f64().unwrap_or(0.0),
            v["y"].as_f64().unwrap_or(0.0),
        );
        match self.workspace {
            Some([x0, y0, x1, y1]) if x < x0 || x > x1 || y < y0 || y > y1 => Err(format!(
                "({x}, {y}) is outside the workspace [{x0}, {x1}] x [{y0}, {y1}]"
            )),
            _ => Ok(()),
        }
    }

    fn parameters(&self, v: &mut Value, changes: &mut Vec<String>) -> Result<(), String> {
        let Some(params) = v["parameters"].as_array_mut() else {
            return Ok(());
        };
        for p in params {
            let name = p["name"].as_str().unwrap_or_default().to_string();
            for rule in &self.params {
                let Ok(re) = regex::Regex::new(&rule.name) else {
                    continue;
                };
                if !re.is_match(&name) {
                    continue;
                }
                let (lo, hi) = (
                    rule.min.unwrap_or(f64::NEG_INFINITY),
                    rule.max.unwrap_or(f64::INFINITY),
                );
                for field in [
                    "integer_value",
                    "double_value",
                    "integer_array_value",
                    "double_array_value",
                ] {
                    let slot = &mut p["value"][field];
                    let values: Vec<&mut Value> = match slot {
                        Value::Array(items) => items.iter_mut().collect(),
                        Value::Number(_) => vec![slot],
                        _ => continue,
                    };
                    for v in values {
                        let Some(x) = v.as_f64() else { continue };
                        if (lo..=hi).contains(&x) {
                            continue;
                        }
                        if self.on_exceed == OnExceed::Block {
                            return Err(format!("parameter {name} = {x} is outside [{lo}, {hi}]"));
                        }
                        let c = x.clamp(lo, hi);
                        *v = if field.starts_with("integer") {
                            (c.round() as i64).into()
                        } else {
                            c.into()
                        };
                        changes.push(format!("parameter {name} clamped from {x} to {c}"));
                    }
                }
            }
        }
        Ok(())
    }

    /// Check every pattern compiles (at start, so a bad policy file says so at once).
    pub(crate) fn validate(&self) -> Result<(), String> {
        for p in &self.params {
            regex::Regex::new(&p.name).map_err(|e| format!("motion.param {:?}: {e}", p.name))?;
        }
        if self.linear_max < 0.0 || self.angular_max < 0.0 || self.teleport_max < 0.0 {
            return Err("motion limits must not be negative".into());
        }
        Ok(())
    }
}

/// Whether `message` (as encoded) holds a Twist anywhere: a velocity command.
pub(crate) fn carries_twist(message: &Value) -> bool {
    match message {
        Value::Object(map) => {
            (is_vector(map.get("linear")) && is_vector(map.get("angular")))
                || map.values().any(carries_twist)
        }
        Value::Array(items) => items.iter().any(carries_twist),
        _ => false,
    }
}

/// `message` with every Twist in it (arrays included) at zero: what the brake sends
/// on a topic after the last command that went out on it.
pub(crate) fn zeroed(message: &Value) -> Value {
    let mut out = message.clone();
    zero_twists(&mut out);
    out
}

fn zero_twists(v: &mut Value) {
    match v {
        Value::Object(map) => {
            if is_vector(map.get("linear")) && is_vector(map.get("angular")) {
                for key in ["linear", "angular"] {
                    set_vector(map.get_mut(key).expect("checked above"), [0.0; 3]);
                }
            }
            map.values_mut().for_each(zero_twists);
        }
        Value::Array(items) => items.iter_mut().for_each(zero_twists),
        _ => {}
    }
}

/// Whether `v` holds a Twist (`linear` and `angular` vectors) at `path`.
fn twist_at(v: &Value, path: &[&str]) -> bool {
    match path.split_first() {
        None => v
            .as_object()
            .is_some_and(|m| is_vector(m.get("linear")) && is_vector(m.get("angular"))),
        Some((&"*", rest)) => v
            .as_array()
            .is_some_and(|items| items.iter().all(|x| twist_at(x, rest))),
        Some((key, rest)) => v.get(*key).is_some_and(|x| twist_at(x, rest)),
    }
}

fn is_vector(v: Option<&Value>) -> bool {
    v.and_then(Value::as_object).is_some_and(|m| {
        ["x", "y", "z"]
            .iter()
            .all(|k| m.get(*k).is_some_and(Value::is_number))
    })
}

fn vector(v: &Value) -> [f64; 3] {
    ["x", "y", "z"].map(|k| v[k].as_f64().unwrap_or(0.0))
}

fn set_vector(v: &mut Value, xyz: [f64; 3]) {
    for (k, x) in ["x", "y", "z"].iter().zip(xyz) {
        v[*k] = x.into();
    }
}

/// The path of the first number that is not finite (or a null where a message holds
/// numbers), if any. Encoded messages hold no nulls.
fn non_finite(v: &Value, path: String) -> Option<String> {
    match v {
        Value::Number(n) if !n.as_f64().is_some_and(f64::is_finite) => Some(path),
        Value::Null => Some(path),
        Value::Array(a) => a
            .iter()
            .enumerate()
            .find_map(|(i, x)| non_finite(x, format!("{path}/{i}"))),
        Value::Object(m) => m
            .iter()
            .find_map(|(k, x)| non_finite(x, format!("{path}/{k}"))),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn twist(lx: f64, ly: f64, az: f64) -> Value {
        json!({"linear": {"x": lx, "y": ly, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": az}})
    }

    #[test]
    fn twists_in_arrays_are_bounded_and_zeroed() {
        let m = Motion::default();
        let msg = json!({"twist": [twist(0.5, 0.0, 0.0), twist(50.0, 0.0, 30.0)]});
        let Verdict::Clamped(out, _) = m.check("pkg/msg/Many", &msg) else {
            panic!("a Twist in an array went unchecked");
        };
        assert_eq!(out["twist"][1]["linear"]["x"], 1.0);
        assert_eq!(out["twist"][1]["angular"]["z"], 1.5);
        let zero = zeroed(&msg);
        assert_eq!(zero["twist"][1], twist(0.0, 0.0, 0.0));
        assert_eq!(zero["twist"].as_array().unwrap().len(), 2);
    }

    #[test]
    fn parameter_limits_hold_for_atomic_sets_and_arrays() {
        let m = Motion {
            params: vec![ParamLimit {
                name: "max_vel".into(),
                min: None,
                max: Some(1.0),
            }],
            on_exceed: OnExceed::Block,
            ..Motion::default()
        };
        for (ty, value) in [
            (
                "rcl_interfaces/srv/SetParametersAtomically_Request",
                json!({"type": 3, "double_value": 9.0}),
            ),
            (
                "rcl_interfaces/srv/SetParameters_Request",
                json!({"type": 8, "double_array_value": [0.5, 9.0]}),
            ),
        ] {
            let req = json!({"parameters": [{"name": "max_vel_x", "value": value}]});
            assert!(
                matches!(m.check(ty, &req), Verdict::Refused(_)),
                "{ty} {req}"
            );
        }
    }

    #[test]
    fn every_twist_is_bounded_whatever_carries_it() {
        let m = Motion::default();
        assert_eq!(
            m.check("geometry_msgs/msg/Twist", &twist(0.5, 0.0, 1.0)),
            Verdict::Within
        );
        let Verdict::Clamped(out, why) = m.check("geometry_msgs/msg/Twist", &twist(3.0, 4.0, 0.0))
        else {
            panic!()
        };
        assert!(
            (out["linear"]["x"].as_f64().unwrap() - 0.6).abs() < 1e-9,
            "{out}"
        );
        assert!(
            why.contains("linear speed clamped from 5.000 to 1"),
            "{why}"
        );
        // Inside a stamped twist, and angular too.
        let stamped = json!({"header": {"frame_id": "base"}, "twist": twist(0.0, 0.0, -9.0)});
        let Verdict::Clamped(out, _) = m.check("geometry_msgs/msg/TwistStamped", &stamped) else {
            panic!()
        };
        assert_eq!(out["twist"]["angular"]["z"], json!(-1.5));
        let block = Motion {
            on_exceed: OnExceed::Block,
            ..Motion::default()
        };
        assert!(matches!(
            block.check("x/msg/Y", &stamped),
            Verdict::Refused(_)
        ));
    }

    #[test]
    fn a_shipped_velocity_type_is_read_by_its_shipped_field_names_only() {
        let m = Motion::default();
        // A Twist as a peer might redefine it (`lin`, `ang`): the same bytes, 5 m/s.
        let renamed =
            json!({"lin": {"x": 5.0, "y": 0.0, "z": 0.0}, "ang": {"x": 0.0, "y": 0.0, "z": 0.0}});
        for ty in ["geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"] {
            assert!(
                matches!(m.check(ty, &renamed), Verdict::Refused(w) if w.contains("shipped")),
                "{ty}"
            );
        }
        let stamped =
            json!({"header": {}, "twist": {"twist": twist(5.0, 0.0, 0.0), "covariance": []}});
        assert!(matches!(
            m.check("geometry_msgs/msg/TwistWithCovarianceStamped", &stamped),
            Verdict::Clamped(..)
        ));
        let joints = json!({"twist": [twist(0.1, 0.0, 0.0), renamed]});
        assert!(matches!(
            m.check("sensor_msgs/msg/MultiDOFJointState", &joints),
            Verdict::Refused(_)
        ));
        // A type ferrosa does not ship is bounded wherever a Twist shows in it.
        assert_eq!(m.check("field_msgs/msg/Fast", &renamed), Verdict::Within);
    }

    #[test]
    fn nulls_and_services_that_move() {
        let m = Motion {
            workspace: Some([0.0, 0.0, 11.0, 11.0]),
            params: vec![ParamLimit {
                name: "^max_speed$".into(),
                min: Some(0.0),
                max: Some(1.0),
            }],
            ..Motion::default()
        };
        let null = json!({"linear": {"x": null, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}});
        assert!(
            matches!(m.check("geometry_msgs/msg/Twist", &null), Verdict::Refused(w) if w.contains("/linear/x"))
        );
        let Verdict::Clamped(out, _) = m.check(
            "turtlesim/srv/TeleportRelative_Request",
            &json!({"linear": 9.0, "angular": 0.1}),
        ) else {
            panic!()
        };
        assert_eq!(out["linear"], json!(2.0));
        assert!(matches!(
            m.check(
                "turtlesim/srv/TeleportAbsolute_Request",
                &json!({"x": 40.0, "y": 1.0, "theta": 0.0})
            ),
            Verdict::Refused(_)
        ));
        let set = json!({"parameters": [{"name": "max_speed", "value": {"type": 3, "double_value": 7.5}}]});
        let Verdict::Clamped(out, _) = m.check("rcl_interfaces/srv/SetParameters_Request", &set)
        else {
            panic!()
        };
        assert_eq!(out["parameters"][0]["value"]["double_value"], json!(1.0));
        let nav = |x: f64| json!({"pose": {"header": {"frame_id": "map"}, "pose": {"position": {"x": x, "y": 2.0, "z": 0.0}}}, "behavior_tree": ""});
        let ty = "nav2_msgs/action/NavigateToPose_Goal";
        assert_eq!(m.check(ty, &nav(3.0)), Verdict::Within);
        assert!(matches!(m.check(ty, &nav(12.5)), Verdict::Refused(w) if w.contains("workspace")));
    }
}
