//! The ROS tools, `ros_<noun>_<verb>`, over any `RosGraph` (ROS 2, the sim, the fake).
//! Each returns structured JSON with counts and the filters applied, so a small model
//! reads answers instead of counting; listings take a `pattern` (regex) and a
//! `namespace`. String arguments pass the policy's deny-list before a call runs, and
//! listings are redacted after, like every tool.
//!
//! Layout:
//! - `base`: the graph handle, failures as the model reads them, filters, summaries
//! - `graph`: nodes, topics and services listed and described
//! - `topic`: echo, rate, publish
//! - `service`: service calls
//! - `param`: parameters (through the node's `rcl_interfaces` services)
//! - `iface`: interface definitions and `/rosout` logs
//! - `action`: actions (list, send a goal, cancel)
//! - `status`: the robot's health (battery, diagnostics, nodes) in one call

mod action;
mod base;
mod graph;
mod iface;
mod param;
mod param_names;
mod service;
mod status;
mod topic;

use std::sync::Arc;

pub(crate) use action::send_goal_reporting;
pub(crate) use base::failed;
use base::Ros;

use crate::ros::RosGraph;
use crate::tool::Package;

/// Every ROS tool over `graph`.
pub fn package(graph: Arc<dyn RosGraph>) -> Package {
    let ros = Ros::new(graph.clone());
    ros.params.prefetch(graph);
    let g = || ros.clone();
    Package::new("ros")
        .with(graph::NodeList(g()))
        .with(graph::NodeInfo(g()))
        .with(graph::TopicList(g()))
        .with(graph::TopicInfo(g()))
        .with(topic::TopicEcho(g()))
        .with(topic::TopicHz(g()))
        .with(topic::TopicPublish(g()))
        .with(graph::ServiceList(g()))
        .with(graph::ServiceInfo(g()))
        .with(service::ServiceCall(g()))
        .with(param::ParamList(g()))
        .with(param::ParamGet(g()))
        .with(param::ParamSet(g()))
        .with(iface::InterfaceShow(g()))
        .with(iface::LogRead(g()))
        .with(action::ActionList(g()))
        .with(action::ActionSendGoal(g()))
        .with(action::ActionCancel(g()))
        .with(status::RobotStatus(g()))
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use serde_json::{json, Value};

    use super::graph::{NodeInfo, NodeList, ServiceList, TopicList};
    use super::iface::InterfaceShow;
    use super::service::ServiceCall;
    use super::topic::{TopicEcho, TopicHz, TopicPublish};
    use super::*;
    use crate::ros::fake::{FakeGraph, Sent};
    use crate::ros::graph::testing::{ep, gid};
    use crate::ros::graph::{DdsEndpoint, GraphCache, NodeEntities};
    use crate::tool::{Tool, ToolContext, ToolError};

    /// `/turtlesim` as the only node, with these endpoints (each one's gid its number).
    fn turtlesim(endpoints: &[DdsEndpoint]) -> crate::ros::Graph {
        let mut cache = GraphCache::default();
        let (writers, readers): (Vec<_>, Vec<_>) = endpoints.iter().partition(|e| e.writer);
        cache.update_participant(
            gid(99),
            vec![NodeEntities {
                name: "turtlesim".into(),
                namespace: "/".into(),
                readers: readers.iter().map(|e| e.gid).collect(),
                writers: writers.iter().map(|e| e.gid).collect(),
            }],
        );
        cache.join(endpoints)
    }

    fn fake() -> Arc<FakeGraph> {
        let graph = turtlesim(&[
            ep(
                1,
                false,
                "rt/turtle1/cmd_vel",
                "geometry_msgs::msg::dds_::Twist_",
            ),
            ep(2, true, "rt/turtle1/pose", "turtlesim::msg::dds_::Pose_"),
            ep(
                3,
                false,
                "rq/turtle1/teleport_absoluteRequest",
                "turtlesim::srv::dds_::TeleportAbsolute_Request_",
            ),
        ]);
        Arc::new(
            FakeGraph::new()
                .with_graph(graph)
                .with_messages(
                    "/turtle1/pose",
                    vec![json!({"x": 1.0}), json!({"x": 2.0}), json!({"x": 3.0})],
                )
                .with_service("/turtle1/teleport_absolute", json!({})),
        )
    }

    /// `/turtlesim` serving one service (`rq/...Request` DDS name and type), alone
    /// (also the action tests').
    pub(super) fn serving(dds_request: &str, dds_type: &str) -> crate::ros::Graph {
        turtlesim(&[ep(1, false, dds_request, dds_type)])
    }

    /// Run a tool on a current-thread runtime with a 5 s limit (also the action tests').
    pub(super) fn run<T: Tool>(t: &T, args: Value) -> Result<Value, ToolError> {
        let args: T::Args = serde_json::from_value(args).unwrap();
        let cx = ToolContext::new(Duration::from_secs(5));
        tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap()
            .block_on(t.call(args, &cx))
    }

    #[test]
    fn listings_count_and_filter() {
        let ros = Ros::new(fake());
        let out = run(&NodeList(ros.clone()), json!({})).unwrap();
        assert_eq!(out["count"], 1);
        assert_eq!(out["nodes"][0], "/turtlesim");
        let out = run(&TopicList(ros.clone()), json!({"pattern": "pose"})).unwrap();
        assert_eq!(out["count"], 1);
        assert_eq!(out["topics"][0]["type"], "turtlesim/msg/Pose");
        assert_eq!(out["filters"]["pattern"], "pose");
        let out = run(&TopicList(ros.clone()), json!({"namespace": "turtle1"})).unwrap();
        assert_eq!(out["count"], 2);
        let out = run(&TopicList(ros.clone()), json!({"namespace": "/turtle"})).unwrap();
        assert_eq!(out["count"], 0, "a namespace is a whole path segment");
        assert_eq!(
            out["all_count"], 2,
            "an empty filtered listing shows the unfiltered one"
        );
        assert!(run(&TopicList(ros.clone()), json!({"pattern": "("})).is_err());
        let out = run(&ServiceList(ros.clone()), json!({})).unwrap();
        assert_eq!(out["services"][0]["type"], "turtlesim/srv/TeleportAbsolute");
        let info = run(&NodeInfo(ros.clone()), json!({"node": "turtlesim"})).unwrap();
        assert_eq!(
            info["counts"],
            json!({"publishers": 1, "subscribers": 1, "services": 1, "clients": 0})
        );
        assert_eq!(
            info["summary"],
            "node /turtlesim publishes 1 topic: /turtle1/pose; subscribes to 1 topic: \
             /turtle1/cmd_vel; serves 1 service: /turtle1/teleport_absolute"
        );
    }

    #[test]
    fn a_rate_leaves_out_a_latched_topics_history() {
        let log = |i: u32| json!({"msg": format!("line {i}")});
        let latched = |messages: u32, history: usize| {
            let graph = turtlesim(&[ep(4, true, "rt/rosout", "rcl_interfaces::msg::dds_::Log_")]);
            Ros::new(Arc::new(
                FakeGraph::new()
                    .with_graph(graph)
                    .with_messages("/rosout", (0..messages).map(log).collect())
                    .with_history("/rosout", history),
            ))
        };
        let ros = latched(6, 4);
        // Six messages over 3 s, four of them history: two live ones 0.5 s apart.
        let hz = run(&TopicHz(ros), json!({"topic": "/rosout", "window_s": 3.0})).unwrap();
        assert_eq!(hz["messages"], 2, "{hz}");
        assert_eq!(hz["rate_hz"], 2.0, "{hz}");
        // All history: no rate, and a note that says what to do.
        let hz = run(&TopicHz(latched(3, 3)), json!({"topic": "/rosout"})).unwrap();
        assert_eq!(hz["rate_hz"], 0.0, "{hz}");
        assert!(hz["note"].as_str().unwrap().contains("window_s"), "{hz}");
    }

    #[test]
    fn echo_hz_and_unknown_topics() {
        let ros = Ros::new(fake());
        let out = run(
            &TopicEcho(ros.clone()),
            json!({"topic": "/turtle1/pose", "count": 2}),
        )
        .unwrap();
        assert_eq!(out["count"], 2);
        assert_eq!(out["messages"][1]["x"], 2.0);
        let hz = run(
            &TopicHz(ros.clone()),
            json!({"topic": "/turtle1/pose", "window_s": 3.0}),
        )
        .unwrap();
        assert_eq!(hz["rate_hz"], 1.0);
        assert!(hz.get("note").is_none(), "{hz}");
        // A loose name reads the one topic it names, and says so.
        let near = run(&TopicEcho(ros.clone()), json!({"topic": "/turtle1/pos"})).unwrap();
        assert_eq!(near["topic"], "/turtle1/pose");
        assert!(
            near["resolved"]
                .as_str()
                .unwrap()
                .contains("no topic /turtle1/pos"),
            "{near}"
        );
        let err = run(&TopicEcho(ros.clone()), json!({"topic": "/xyz"})).unwrap_err();
        assert!(err.to_string().starts_with("no topic /xyz"), "{err}");
    }

    #[test]
    fn publish_and_call_take_types_from_the_graph() {
        let graph = fake();
        let ros = Ros::new(graph.clone());
        run(
            &TopicPublish(ros.clone()),
            json!({"topic": "/turtle1/cmd_vel", "message": {"linear": {"x": 1.0}}}),
        )
        .unwrap();
        let out = run(
            &ServiceCall(ros.clone()),
            json!({"service": "turtle1/teleport_absolute", "request": {"x": 1.0}}),
        )
        .unwrap();
        assert_eq!(out["type"], "turtlesim/srv/TeleportAbsolute");
        assert_eq!(
            graph.sent(),
            [
                Sent::Publish {
                    topic: "/turtle1/cmd_vel".into(),
                    type_name: "geometry_msgs/msg/Twist".into(),
                    message: json!({"linear": {"x": 1.0}})
                },
                Sent::Call {
                    service: "/turtle1/teleport_absolute".into(),
                    type_name: "turtlesim/srv/TeleportAbsolute".into(),
                    request: json!({"x": 1.0})
                },
            ]
        );
        let err = run(&ServiceCall(ros), json!({"service": "/teleport"})).unwrap_err();
        assert!(
            err.to_string()
                .contains("did you mean /turtle1/teleport_absolute"),
            "{err}"
        );
    }

    #[test]
    fn interface_show_gives_definition_and_example() {
        let ros = Ros::new(fake());
        let out = run(&InterfaceShow(ros), json!({"type": "turtlesim/srv/Spawn"})).unwrap();
        assert!(out["definition"].as_str().unwrap().contains("string name"));
        assert_eq!(out["example"]["request"]["name"], "");
        // The summary says the fields, by part; constants are not fields.
        let summary = out["summary"].as_str().unwrap();
        assert!(
            summary.starts_with("turtlesim/srv/Spawn: request: x (float32), y (float32)")
                && summary.ends_with("; response: name (string)"),
            "{summary}"
        );
        let out = run(
            &InterfaceShow(Ros::new(fake())),
            json!({"type": "diagnostic_msgs/msg/DiagnosticStatus"}),
        )
        .unwrap();
        let summary = out["summary"].as_str().unwrap();
        assert!(
            summary.contains("level (byte), name (string)") && !summary.contains("OK"),
            "{summary}"
        );
    }

    #[test]
    fn a_service_call_is_not_offered_a_nodes_own_parameter_services() {
        let graph = turtlesim(&[
            ep(
                1,
                false,
                "rq/turtle1/teleport_absoluteRequest",
                "turtlesim::srv::dds_::TeleportAbsolute_Request_",
            ),
            ep(
                2,
                false,
                "rq/turtlesim/set_parameters_atomicallyRequest",
                "rcl_interfaces::srv::dds_::SetParametersAtomically_Request_",
            ),
            ep(
                3,
                false,
                "rq/turtlesim/get_type_descriptionRequest",
                "type_description_interfaces::srv::dds_::GetTypeDescription_Request_",
            ),
        ]);
        let ros = Ros::new(Arc::new(FakeGraph::new().with_graph(graph)));
        let live = ServiceCall(ros).live_parameters().unwrap();
        let named: Vec<&str> = live["anyOf"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(|b| b["properties"]["service"]["const"].as_str())
            .collect();
        assert_eq!(named, ["/turtle1/teleport_absolute"]);
    }

    #[test]
    fn calls_take_arguments_typed_by_the_names_the_robot_holds() {
        let ros = Ros::new(fake());
        let live = ServiceCall(ros.clone()).live_parameters().unwrap();
        let branches = live["anyOf"].as_array().unwrap();
        // One branch per service of a known type, then one for a service it lacks.
        assert_eq!(branches.len(), 2);
        let teleport = &branches[0];
        assert_eq!(
            teleport["properties"]["service"]["const"],
            "/turtle1/teleport_absolute"
        );
        let request = &teleport["properties"]["request"];
        assert_eq!(request["properties"]["theta"]["type"], "number");
        assert_eq!(request["additionalProperties"], false);
        assert_eq!(teleport["required"], json!(["service"]));
        assert!(branches[1]["properties"]["service"].get("const").is_none());

        let live = TopicPublish(ros.clone()).live_parameters().unwrap();
        let branches = live["anyOf"].as_array().unwrap();
        // Only a topic some node listens to is typed (`/turtle1/pose` is only
        // published), then the open branch.
        assert_eq!(branches.len(), 2, "{live}");
        // Reading offers the topics some node publishes, or any other.
        for reading in [
            TopicEcho(ros.clone()).live_parameters().unwrap(),
            TopicHz(ros.clone()).live_parameters().unwrap(),
        ] {
            let topic = &reading["properties"]["topic"]["anyOf"];
            assert_eq!(topic[0]["enum"], json!(["/turtle1/pose"]), "{reading}");
            assert_eq!(topic[1], json!({"type": "string"}));
            assert_eq!(reading["required"], json!(["topic"]));
            assert_eq!(reading["additionalProperties"], json!(false));
        }
        let twist = branches
            .iter()
            .find(|b| b["properties"]["topic"]["const"] == "/turtle1/cmd_vel")
            .unwrap();
        let linear = &twist["properties"]["message"]["properties"]["linear"];
        assert_eq!(linear["properties"]["x"]["type"], "number");
        assert_eq!(twist["required"], json!(["topic", "message"]));
        // A topic the robot lacks needs its type.
        let open = branches.last().unwrap();
        assert_eq!(
            open["required"],
            json!(["topic", "message", "message_type"])
        );
        // Every branch is a value the declared arguments take.
        let declared = crate::tool::registry::erase(TopicPublish(Ros::new(fake())));
        let call = json!({"topic": "/turtle1/cmd_vel", "message": {"linear": {"x": 0.5}}});
        assert!(declared.spec().validate(&call).is_ok());
        assert!(jsonschema::validator_for(&live).unwrap().is_valid(&call));
        let forged = json!({"topic": "/turtle1/cmd_vel", "message": {"type": "object"}});
        assert!(!jsonschema::validator_for(&live).unwrap().is_valid(&forged));
    }

    #[test]
    fn a_goal_is_typed_by_the_action_the_robot_serves() {
        let graph = serving(
            "rq/turtle1/rotate_absolute/_action/send_goalRequest",
            "turtlesim::action::dds_::RotateAbsolute_SendGoal_Request_",
        );
        let ros = Ros::new(Arc::new(FakeGraph::new().with_graph(graph)));
        let live = action::ActionSendGoal(ros).live_parameters().unwrap();
        let branches = live["anyOf"].as_array().unwrap();
        assert_eq!(branches.len(), 2);
        let rotate = &branches[0]["properties"];
        assert_eq!(rotate["action"]["const"], "/turtle1/rotate_absolute");
        assert_eq!(rotate["goal"]["properties"]["theta"]["type"], "number");
        let typed = jsonschema::validator_for(&branches[0]).unwrap();
        let call = json!({"action": "/turtle1/rotate_absolute", "goal": {"theta": 1.57}});
        assert!(typed.is_valid(&call));
        let forged = json!({"action": "/turtle1/rotate_absolute", "goal": {"type": "object"}});
        assert!(!typed.is_valid(&forged));
        // An action the robot lacks stays open to a name the operator wrote.
        let valid = jsonschema::validator_for(&live).unwrap();
        assert!(valid.is_valid(&json!({"action": "/dock", "goal": {}})));
    }

    #[test]
    fn parameter_names_are_the_ones_each_node_lists() {
        let graph = serving(
            "rq/turtlesim/list_parametersRequest",
            "rcl_interfaces::srv::dds_::ListParameters_Request_",
        );
        let listing =
            json!({"result": {"names": ["background_b", "background_r"], "prefixes": []}});
        let fake = Arc::new(
            FakeGraph::new()
                .with_graph(graph)
                .with_service("/turtlesim/list_parameters", listing),
        );
        let ros = Ros::new(fake.clone());
        let live = param::ParamGet(ros.clone()).live_parameters().unwrap();
        let branches = live["anyOf"].as_array().unwrap();
        assert_eq!(branches.len(), 2);
        let turtlesim = &branches[0]["properties"];
        assert_eq!(turtlesim["node"]["const"], "/turtlesim");
        assert_eq!(
            turtlesim["name"]["anyOf"][0]["enum"],
            json!(["background_b", "background_r"])
        );
        // Listed once, then known: the next turn asks the robot nothing.
        let asked = fake.sent().len();
        param::ParamSet(ros).live_parameters().unwrap();
        assert_eq!(fake.sent().len(), asked);
        // Any name stays valid, for the tool to report one the node lacks.
        let valid = jsonschema::validator_for(&live).unwrap();
        assert!(valid.is_valid(&json!({"node": "/turtlesim", "name": "max_speed"})));
    }
}
