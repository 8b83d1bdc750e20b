//! The console's robot view: the robot's planar pose read from a topic (the sim's
//! `/turtle1/pose`, or a topic the operator names), whatever common message carries it:
//! turtlesim's Pose and Pose2D (`x`, `y`, `theta`), and every message with a
//! `position` and an `orientation` quaternion at some depth (PoseStamped, Odometry,
//! PoseWithCovarianceStamped).

use std::sync::Arc;
use std::time::{Duration, Instant};

use serde_json::Value;

use super::hub::{Hub, Pose};
use crate::ros::RosGraph;

/// Poses sent to the clients at most this often (the sim publishes at 60 Hz).
const EVERY: Duration = Duration::from_millis(50);

/// Where the view reads the pose: the topic, its type once the graph knows it, and the
/// area to draw (`None`: fitted to the trail).
#[derive(Debug, Clone, serde::Serialize)]
pub struct View {
    pub topic: String,
    pub bounds: Option<[f64; 4]>,
}

/// The pose a message carries, if it carries one.
pub fn pose_of(msg: &Value) -> Option<Pose> {
    let num = |v: &Value, k: &str| v.get(k).and_then(Value::as_f64);
    if let (Some(x), Some(y), Some(theta)) = (num(msg, "x"), num(msg, "y"), num(msg, "theta")) {
        return Some(Pose { x, y, theta });
    }
    if let (Some(p), Some(q)) = (msg.get("position"), msg.get("orientation")) {
        let (x, y) = (num(p, "x")?, num(p, "y")?);
        let (qx, qy, qz, qw) = (num(q, "x")?, num(q, "y")?, num(q, "z")?, num(q, "w")?);
        let theta = (2.0 * (qw * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz));
        return Some(Pose { x, y, theta });
    }
    // One level down, in the order the common messages nest it.
    ["pose", "transform"]
        .iter()
        .filter_map(|k| msg.get(*k))
        .find_map(pose_of)
}

/// Follow `view.topic` on `graph` and give the hub each pose (at most every `EVERY`),
/// until the graph ends the subscription. The type is the one the graph shows for the
/// topic (waited for up to 20 s).
pub async fn follow(graph: Arc<dyn RosGraph>, hub: Arc<Hub>, view: View) {
    let Some(type_name) = topic_type(graph.as_ref(), &view.topic).await else {
        tracing::warn!(topic = %view.topic, "robot view: no publisher of this topic within 20 s; the view stays empty");
        return;
    };
    let mut rx = match graph.watch(&view.topic, &type_name).await {
        Ok(rx) => rx,
        Err(e) => {
            tracing::warn!(topic = %view.topic, "robot view: cannot subscribe: {e}");
            return;
        }
    };
    let mut last = Instant::now() - EVERY;
    let mut warned = false;
    while let Some(msg) = rx.recv().await {
        match pose_of(&msg) {
            Some(p) if last.elapsed() >= EVERY => {
                last = Instant::now();
                hub.pose(p);
            }
            Some(_) => {}
            None if !warned => {
                warned = true;
                tracing::warn!(topic = %view.topic, %type_name, "robot view: this message carries no pose the view reads (x/y/theta, or position and orientation)");
            }
            None => {}
        }
    }
}

/// The type the graph shows for `topic`, once it shows one.
async fn topic_type(graph: &dyn RosGraph, topic: &str) -> Option<String> {
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(20) {
        if let Ok(g) = graph.graph().await {
            if let Some(t) = g.topics().get(topic).and_then(|ts| ts.iter().next()) {
                return Some(t.clone());
            }
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn reads_the_common_pose_messages() {
        let turtle = json!({"x": 5.5, "y": 4.0, "theta": 1.0, "linear_velocity": 0.0});
        assert_eq!(
            pose_of(&turtle),
            Some(Pose {
                x: 5.5,
                y: 4.0,
                theta: 1.0
            })
        );
        // A quarter turn about z: yaw π/2.
        let (s, c) = (
            std::f64::consts::FRAC_PI_4.sin(),
            std::f64::consts::FRAC_PI_4.cos(),
        );
        let pose = json!({"position": {"x": 1.0, "y": -2.0, "z": 0.3},
                          "orientation": {"x": 0.0, "y": 0.0, "z": s, "w": c}});
        let stamped = json!({"header": {}, "pose": pose});
        let odom = json!({"header": {}, "child_frame_id": "base", "pose": {"pose": pose, "covariance": []},
                          "twist": {}});
        for m in [&stamped, &odom] {
            let p = pose_of(m).unwrap();
            assert_eq!((p.x, p.y), (1.0, -2.0));
            assert!(
                (p.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-9,
                "{p:?}"
            );
        }
        assert_eq!(pose_of(&json!({"data": 1.0})), None);
        assert_eq!(pose_of(&json!({"position": {"x": 1.0, "y": 2.0}})), None);
    }
}
