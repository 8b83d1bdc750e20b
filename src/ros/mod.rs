//! ROS access behind one trait, so tools are written once for ROS 2, ROS 1 and the
//! in-memory fake. Messages cross this boundary as JSON with their type name
//! (`geometry_msgs/msg/Twist`); encoding them is the implementation's job.
//!
//! Parameters are services (`rcl_interfaces`), so tools reach them through
//! `call_service`; logs are the `/rosout` topic. Actions have their own two calls
//! (`send_goal`, `cancel_goals`): a goal is followed through acceptance, feedback and
//! result, which no single service call or subscription covers.
//!
//! Layout:
//! - `graph`: the joined graph (nodes, topics, services, actions) and its cache
//! - `boundary`: the boundary every tool goes through: deny-list, e-stop, motion limits,
//!   mux, redaction, and the brake
//! - `ros2`: the ROS 2 implementation over ros2-client (RustDDS), localhost-only by default
//! - `ros1`: the ROS 1 implementation (XML-RPC and TCPROS), loopback unless told otherwise
//! - `sim`: the built-in turtlesim-compatible robot
//! - `msg`: interface definitions (.msg/.srv/.action), the shipped bundle, lookup
//! - `cdr`: CDR <-> JSON driven by those definitions
//! - `fake`: an in-memory graph that records what was sent (tests)
//! - `switch`: a graph whose target is replaced under the tools (a fresh robot per case)
//! - `typedesc`: types learnt from a peer, verified by their hash

pub mod boundary;
pub mod cdr;
pub mod fake;
pub mod graph;
pub mod msg;
pub mod ros1;
pub mod ros2;
pub mod sim;
pub mod switch;
pub mod typedesc;

use std::future::Future;
use std::pin::Pin;
use std::time::Duration;

use serde_json::Value;

pub use graph::Graph;
pub use msg::Interfaces;

pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RosError {
    #[error("no service {0}; list services to see what exists")]
    NoService(String),
    #[error("service {service} did not answer within {timeout:?}")]
    Timeout { service: String, timeout: Duration },
    #[error("cannot encode the message as {type_name}: {reason}")]
    Encode { type_name: String, reason: String },
    #[error("cannot decode a {type_name} message: {reason}")]
    Decode { type_name: String, reason: String },
    #[error("no topic {0}; list topics to see what exists")]
    NoTopic(String),
    #[error("no subscriber matched {topic} within {timeout:?}; is the node running?")]
    NoSubscriber { topic: String, timeout: Duration },
    #[error("no action server for {0} answered; list actions to see what exists")]
    NoAction(String),
    #[error("{0}: invalid ROS name")]
    BadName(String),
    /// A name the operator's deny-list covers: the name itself is not repeated.
    #[error("that name is off limits (the operator's deny-list); do not try it or anything like it again")]
    OffLimits,
    #[error("the e-stop is engaged ({0}): motion is refused until the operator resets it")]
    Stopped(String),
    #[error("refused by the motion limits: {0}")]
    Limit(String),
    #[error("{0}")]
    Other(String),
}

/// One received message; `t` is seconds since the subscription started.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Sample {
    pub t: f64,
    pub message: Value,
    /// Published before the subscription started: a latched topic's history, delivered
    /// at once on joining (a rate counts only what was published while it listened).
    #[serde(skip)]
    pub history: bool,
}

impl Sample {
    /// A message published while the subscription listened.
    pub fn new(t: f64, message: Value) -> Sample {
        Sample {
            t,
            message,
            history: false,
        }
    }
}

/// How a goal ended, or that it had not yet when the wait was over.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum GoalStatus {
    Rejected,
    Running,
    Succeeded,
    Canceled,
    Aborted,
}

/// What became of one goal.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GoalOutcome {
    /// The goal's UUID as 32 hex digits (what `cancel_goals` takes).
    pub goal_id: String,
    pub status: GoalStatus,
    /// The action's result message, once it ended.
    pub result: Option<Value>,
    /// Feedback messages received, oldest first (`t`: seconds since the goal was sent).
    pub feedback: Vec<Sample>,
}

/// The server's answer to a cancel request.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CancelOutcome {
    /// `accepted`, `rejected`, `unknown_goal` or `goal_terminated` (action_msgs/CancelGoal).
    pub return_code: String,
    /// The goals now canceling (32 hex digits each).
    pub canceling: Vec<String>,
}

/// The graph as discovered so far when `graph` answers without waiting (the sim's and
/// the DDS graph's do), else `None`: for what is built inside a model's turn, which never
/// waits on the robot.
pub fn graph_now(graph: &dyn RosGraph) -> Option<Graph> {
    let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
    match graph.graph().as_mut().poll(&mut cx) {
        std::task::Poll::Ready(Ok(g)) => Some(g),
        _ => None,
    }
}

pub trait RosGraph: Send + Sync {
    /// The graph as discovered so far.
    fn graph(&self) -> BoxFuture<'_, Result<Graph, RosError>>;
    /// The interface definitions this graph encodes with.
    fn interfaces(&self) -> &Interfaces;
    /// Subscribe to `topic` (type from the graph when `None`), with the QoS its
    /// publishers offer, and collect up to `max` messages within `window`.
    fn subscribe<'a>(
        &'a self,
        topic: &'a str,
        type_name: Option<&'a str>,
        max: usize,
        window: Duration,
    ) -> BoxFuture<'a, Result<Vec<Sample>, RosError>>;
    /// Publish one message on `topic`.
    fn publish<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<Delivery, RosError>>;
    /// Call `service` and return its response.
    fn call_service<'a>(
        &'a self,
        service: &'a str,
        type_name: &'a str,
        request: Value,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<Reply, RosError>>;
    /// Send `goal` to `action` (type `pkg/action/Name`) and follow it for up to `wait`:
    /// its feedback, and its result if it ends in time (else it is `Running` and goes on).
    fn send_goal<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal: Value,
        wait: Duration,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>>;
    /// `send_goal`, with each feedback message also sent to `feedback` as it comes (a
    /// long goal's progress, for the operator). A graph that cannot stream feedback
    /// sends none and still returns it in the outcome.
    fn send_goal_watched<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal: Value,
        wait: Duration,
        feedback: FeedbackSink,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>> {
        drop(feedback);
        self.send_goal(action, type_name, goal, wait)
    }
    /// Cancel one goal of `action` (by its id) or, with `None`, every goal it has.
    fn cancel_goals<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal_id: Option<&'a str>,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<CancelOutcome, RosError>>;
    /// Every message on `topic` (of `type_name`) from now on, as it arrives, until the
    /// receiver is dropped.
    fn watch<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<Watch, RosError>>;
    /// Get ready to publish on `topic` without publishing (the publisher exists and is
    /// being discovered), so a later `publish_now` goes out at once.
    fn advertise<'a>(
        &'a self,
        _topic: &'a str,
        _type_name: &'a str,
    ) -> BoxFuture<'a, Result<(), RosError>> {
        Box::pin(async { Ok(()) })
    }
    /// Publish at once, without waiting for a subscriber to match: the brake cannot wait
    /// for discovery.
    fn publish_now<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<Delivery, RosError>> {
        self.publish(topic, type_name, message)
    }
    /// Make `type_name`, used on `topic`, known to `interfaces()` where the graph learns
    /// types from its peers when they are used (ROS 1: from a publisher's or a
    /// subscriber's connection header); the default knows every type it can encode.
    fn learn_type<'a>(
        &'a self,
        _topic: &'a str,
        _type_name: &'a str,
    ) -> BoxFuture<'a, Result<(), RosError>> {
        Box::pin(async { Ok(()) })
    }
    /// The fence applied to what this graph asks of other nodes by itself (type
    /// descriptions, service probes); tools' requests meet it at `ros::boundary`.
    fn set_fence(&self, _fence: std::sync::Arc<crate::fence::Fence>) {}
}

/// What went out when a message was published: where, and what the boundary changed.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Delivery {
    /// The topic it went out on (the agent's input to a mux, when the operator's velocity
    /// topic was asked for).
    pub topic: String,
    /// The message as sent, when the limits changed it.
    pub sent: Option<Value>,
    /// What the limits changed, if anything.
    pub note: Option<String>,
    /// The name of a higher-priority input the mux says is active (the operator's
    /// teleop): this message is dropped until it ends.
    pub overridden_by: Option<String>,
}

impl Delivery {
    pub fn to(topic: &str) -> Delivery {
        Delivery {
            topic: topic.to_string(),
            ..Delivery::default()
        }
    }
}

/// A service's response, and what the boundary changed in the request, if anything.
#[derive(Debug, Clone, PartialEq)]
pub struct Reply {
    pub response: Value,
    pub note: Option<String>,
}

impl From<Value> for Reply {
    fn from(response: Value) -> Reply {
        Reply {
            response,
            note: None,
        }
    }
}

/// Messages of a watched topic, as they arrive.
pub(crate) type Watch = tokio::sync::mpsc::UnboundedReceiver<Value>;

/// Where a goal's feedback messages go as they come (`send_goal_watched`), decoded.
pub(crate) type FeedbackSink = tokio::sync::mpsc::UnboundedSender<Value>;
