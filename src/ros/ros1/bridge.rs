//! A node of another graph served on ROS 1 under its own name, as ros1_bridge serves one:
//! what it publishes is published, what it subscribes to is subscribed to and passed on,
//! its services are served and passed on, its parameters set on the parameter server,
//! its log lines published on `/rosout`. `--robot sim-ros1` serves the built-in sim
//! (ROS 2, in this process) this way, so ROS 1 tools, and the agent over ROS 1, have it
//! to act on. Endpoints the node gains later (a spawned turtle's) are served as they
//! appear; ROS 2's parameter, type-description and action plumbing is not.

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Duration;

use serde_json::{json, Map, Value};

use super::master::Master;
use super::node::{Handler, Node};
use super::Ros1Options;
use crate::ros::graph::Graph;
use crate::ros::{RosError, RosGraph};

/// ROS 1's log message, which the bundle (ROS 2's `rosgraph_msgs`) lacks.
const LOG: &str = "byte DEBUG=1\nbyte INFO=2\nbyte WARN=4\nbyte ERROR=8\nbyte FATAL=16\n\
Header header\nbyte level\nstring name\nstring msg\nstring file\nstring function\nuint32 line\nstring[] topics\n";

/// How long a passed-on service call may take.
const CALL_LIMIT: Duration = Duration::from_secs(5);

/// A served node; dropping it unregisters it and deletes its parameters.
pub struct Bridge {
    node: Arc<Node>,
    rt: tokio::runtime::Handle,
    /// The refresh and every message-passing task: each holds the source graph and
    /// the node, so all end with the bridge.
    tasks: Tasks,
}

type Tasks = Arc<std::sync::Mutex<Vec<tokio::task::JoinHandle<()>>>>;

impl Drop for Bridge {
    fn drop(&mut self) {
        for t in self.tasks.lock().expect("bridge tasks").drain(..) {
            t.abort();
        }
        let node = self.node.clone();
        let done = self.rt.spawn(async move {
            tokio::time::timeout(Duration::from_secs(2), node.shutdown()).await
        });
        let _ = futures::executor::block_on(done);
    }
}

/// ROS 2's time (`sec`, `nanosec`) as ROS 1's (`secs`, `nsecs`), everywhere in `v`, and
/// back with `to_ros1` false.
fn times(v: Value, to_ros1: bool) -> Value {
    let (from, to) = if to_ros1 {
        (["sec", "nanosec"], ["secs", "nsecs"])
    } else {
        (["secs", "nsecs"], ["sec", "nanosec"])
    };
    match v {
        Value::Object(m) => {
            let is_time = m.len() == 2 && from.iter().all(|k| m.contains_key(*k));
            Value::Object(
                m.into_iter()
                    .map(|(k, v)| {
                        let k = match from.iter().position(|f| *f == k) {
                            Some(i) if is_time => to[i].to_string(),
                            _ => k,
                        };
                        (k, times(v, to_ros1))
                    })
                    .collect::<Map<String, Value>>(),
            )
        }
        Value::Array(a) => Value::Array(a.into_iter().map(|v| times(v, to_ros1)).collect()),
        other => other,
    }
}

/// A ROS 2 log line (`rcl_interfaces/msg/Log`) as ROS 1's, from node `name`.
fn log_as_ros1(v: &Value, name: &str) -> Value {
    let level = match v["level"].as_u64().unwrap_or(0) {
        0..=10 => 1,
        11..=20 => 2,
        21..=30 => 4,
        31..=40 => 8,
        _ => 16,
    };
    json!({
        "header": {"stamp": times(v["stamp"].clone(), true)},
        "level": level, "name": name, "msg": v["msg"], "file": v["file"],
        "function": v["function"], "line": v["line"],
    })
}

/// ROS 2 plumbing a ROS 1 node has no counterpart for.
fn plumbing(name: &str) -> bool {
    const SUFFIXES: [&str; 7] = [
        "/describe_parameters",
        "/get_parameter_types",
        "/get_parameters",
        "/list_parameters",
        "/set_parameters",
        "/set_parameters_atomically",
        "/get_type_description",
    ];
    name.contains("/_action/")
        || name == "/parameter_events"
        || SUFFIXES.iter().any(|s| name.ends_with(s))
}

impl Bridge {
    /// Serve node `name` of `source` on the ROS 1 master `opts` names.
    pub fn start(
        source: Arc<dyn RosGraph>,
        name: &str,
        opts: &Ros1Options,
    ) -> Result<Bridge, RosError> {
        let rt = super::runtime();
        let master = Master {
            uri: opts.master_uri.clone(),
            caller_id: name.to_string(),
        };
        let (host, bind) = (opts.host.clone(), opts.bind.clone());
        let node = super::block(&rt, async move { Node::start(master, &host, &bind).await })?;
        for (ty, text) in [
            ("std_msgs/msg/Header", super::wire::HEADER),
            ("rosgraph_msgs/msg/Log", LOG),
        ] {
            node.wire
                .add(ty, text)
                .map_err(|e| RosError::Other(e.to_string()))?;
        }
        let (n, s, who) = (node.clone(), source.clone(), name.to_string());
        // The node's parameters and what it has now, before anyone is told it is ready.
        let tasks: Tasks = Arc::default();
        let t = tasks.clone();
        let done = super::block(&rt, async move {
            copy_parameters(&n, s.as_ref(), &who).await?;
            let mut done = BTreeSet::new();
            let g = s.graph().await?;
            serve_new(&n, &s, &who, &g, &mut done, &t).await;
            Ok(done)
        });
        let bridge = Bridge {
            node: node.clone(),
            rt: rt.clone(),
            tasks: tasks.clone(),
        };
        // On an error the bridge is dropped: what started ends, what registered leaves.
        let done = done?;
        let (n, s, who, t) = (node, source, name.to_string(), tasks.clone());
        let refresh = rt.spawn(async move {
            let mut done = done;
            loop {
                tokio::time::sleep(Duration::from_millis(500)).await;
                if let Ok(g) = s.graph().await {
                    serve_new(&n, &s, &who, &g, &mut done, &t).await;
                }
            }
        });
        tasks.lock().expect("bridge tasks").push(refresh);
        Ok(bridge)
    }
}

async fn copy_parameters(node: &Node, source: &dyn RosGraph, name: &str) -> Result<(), RosError> {
    let list = source
        .call_service(
            &format!("{name}/list_parameters"),
            "rcl_interfaces/srv/ListParameters",
            json!({"prefixes": [], "depth": 0}),
            CALL_LIMIT,
        )
        .await?;
    let names = list.response["result"]["names"].clone();
    let got = source
        .call_service(
            &format!("{name}/get_parameters"),
            "rcl_interfaces/srv/GetParameters",
            json!({ "names": names }),
            CALL_LIMIT,
        )
        .await?;
    let values = got.response["values"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    for (key, value) in names.as_array().into_iter().flatten().zip(values) {
        let (Some(key), Ok(v)) = (key.as_str(), super::master::xml_value(&value)) else {
            continue;
        };
        // ROS 2's own (`use_sim_time`) is not the robot's.
        if key != "use_sim_time" {
            node.set_param(&format!("{name}/{key}"), v).await?;
        }
    }
    Ok(())
}

/// Serve what `name` has in `g` and `done` does not hold yet.
async fn serve_new(
    node: &Arc<Node>,
    source: &Arc<dyn RosGraph>,
    name: &str,
    g: &Graph,
    done: &mut BTreeSet<String>,
    tasks: &Tasks,
) {
    let mine = |e: &Option<String>| e.as_deref() == Some(name);
    for e in g
        .publishers
        .iter()
        .filter(|e| mine(&e.node) && !plumbing(&e.topic))
    {
        if done.insert(format!("pub {}", e.topic)) {
            match publish_from(node, source, name, &e.topic, &e.type_name).await {
                Ok(t) => tasks.lock().expect("bridge tasks").push(t),
                Err(err) => tracing::warn!("bridge {}: {err}", e.topic),
            }
        }
    }
    for e in g
        .subscribers
        .iter()
        .filter(|e| mine(&e.node) && !plumbing(&e.topic))
    {
        if done.insert(format!("sub {}", e.topic)) {
            match subscribe_for(node, source, &e.topic, &e.type_name).await {
                Ok(t) => tasks.lock().expect("bridge tasks").push(t),
                Err(err) => tracing::warn!("bridge {}: {err}", e.topic),
            }
        }
    }
    for e in g
        .servers
        .iter()
        .filter(|e| mine(&e.node) && !plumbing(&e.service))
    {
        if done.insert(format!("srv {}", e.service)) {
            let (s, service, ty) = (source.clone(), e.service.clone(), e.type_name.clone());
            let handler: Handler = Arc::new(
                move |request: Value| -> crate::ros::BoxFuture<'static, Result<Value, String>> {
                    let (s, service, ty) = (s.clone(), service.clone(), ty.clone());
                    Box::pin(async move {
                        s.call_service(&service, &ty, times(request, false), CALL_LIMIT)
                            .await
                            .map(|r| times(r.response, true))
                            .map_err(|e| e.to_string())
                    })
                },
            );
            if let Err(err) = node.serve(&e.service, &e.type_name, handler).await {
                tracing::warn!("bridge {}: {err}", e.service);
            }
        }
    }
}

/// Publish on ROS 1 what the node publishes (its log as ROS 1's).
async fn publish_from(
    node: &Arc<Node>,
    source: &Arc<dyn RosGraph>,
    name: &str,
    topic: &str,
    ty: &str,
) -> Result<tokio::task::JoinHandle<()>, RosError> {
    let log = topic == "/rosout";
    let ros1_ty = if log { "rosgraph_msgs/msg/Log" } else { ty };
    let publication = node.publication(topic, ros1_ty).await?;
    let mut rx = source.watch(topic, ty).await?;
    let (node, name) = (node.clone(), name.to_string());
    Ok(tokio::spawn(async move {
        while let Some(v) = rx.recv().await {
            let v = if log {
                log_as_ros1(&v, &name)
            } else {
                times(v, true)
            };
            if let Err(e) = publication.send(&node.wire, &v).await {
                tracing::debug!("bridge: {e}");
            }
        }
    }))
}

/// Subscribe on ROS 1 to what the node subscribes to, and pass each message on.
async fn subscribe_for(
    node: &Arc<Node>,
    source: &Arc<dyn RosGraph>,
    topic: &str,
    ty: &str,
) -> Result<tokio::task::JoinHandle<()>, RosError> {
    node.ensure_definition(ty)?;
    source.advertise(topic, ty).await?;
    let mut listener = node.listen(topic, Some(ty)).await?;
    let (source, topic, ty) = (source.clone(), topic.to_string(), ty.to_string());
    Ok(tokio::spawn(async move {
        while let Some(v) = listener.rx.recv().await {
            if let Err(e) = source.publish_now(&topic, &ty, times(v, false)).await {
                tracing::debug!("bridge {topic}: {e}");
            }
        }
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_and_logs_read_as_ros1_and_back() {
        let ros2 =
            json!({"header": {"stamp": {"sec": 3, "nanosec": 4}, "frame_id": "base"}, "sec": 1});
        let ros1 = times(ros2.clone(), true);
        assert_eq!(ros1["header"]["stamp"], json!({"secs": 3, "nsecs": 4}));
        assert_eq!(ros1["sec"], 1);
        assert_eq!(times(ros1, false), ros2);
        let log = log_as_ros1(
            &json!({"stamp": {"sec": 1, "nanosec": 2}, "level": 30, "msg": "wall"}),
            "/turtlesim",
        );
        assert_eq!(log["level"], 4);
        assert_eq!(log["header"]["stamp"]["secs"], 1);
        assert!(plumbing("/turtlesim/get_parameters"));
        assert!(plumbing("/turtle1/rotate_absolute/_action/send_goal"));
        assert!(!plumbing("/turtle1/teleport_absolute"));
    }
}
