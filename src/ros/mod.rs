//! ROS access behind one trait, so tools are written once for ROS 2, ROS 1 and the
//! in-memory fake. Messages cross this boundary as JSON with their type name
//! (`geometry_msgs/msg/Twist`); encoding them is the implementation's job.
//!
//! This holds what tools need so far (publish, call a service); the graph queries, echo,
//! parameters and the ROS 2 implementation join with the ROS tools.
//!
//! Layout:
//! - `msg`: interface definitions (.msg/.srv/.action), the shipped bundle, lookup
//! - `cdr`: CDR <-> JSON driven by those definitions
//! - `fake`: an in-memory graph that records what was sent (tests)

pub mod cdr;
pub mod fake;
pub mod msg;

use std::future::Future;
use std::pin::Pin;
use std::time::Duration;

use serde_json::Value;

pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RosError {
    #[error("no service {0}; list services to see what exists")]
    NoService(String),
    #[error("service {service} did not answer within {timeout:?}")]
    Timeout { service: String, timeout: Duration },
    #[error("cannot encode the message as {type_name}: {reason}")]
    Encode { type_name: String, reason: String },
    #[error("{0}")]
    Other(String),
}

pub trait RosGraph: Send + Sync {
    /// Publish one message on `topic`.
    fn publish<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<(), RosError>>;
    /// Call `service` and return its response.
    fn call_service<'a>(
        &'a self,
        service: &'a str,
        type_name: &'a str,
        request: Value,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<Value, RosError>>;
}
