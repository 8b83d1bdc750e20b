//! An in-memory `RosGraph`: records every publish and service call, and answers services
//! from a table, so tool tests run without DDS.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::time::Duration;

use serde_json::Value;

use super::{BoxFuture, RosError, RosGraph};

/// One thing sent to the fake graph.
#[derive(Debug, Clone, PartialEq)]
pub enum Sent {
    Publish {
        topic: String,
        type_name: String,
        message: Value,
    },
    Call {
        service: String,
        type_name: String,
        request: Value,
    },
}

#[derive(Default)]
pub struct FakeGraph {
    sent: Mutex<Vec<Sent>>,
    services: BTreeMap<String, Value>,
}

impl FakeGraph {
    pub fn new() -> FakeGraph {
        FakeGraph::default()
    }

    /// A service that answers every request with `response`.
    pub fn with_service(mut self, name: &str, response: Value) -> FakeGraph {
        self.services.insert(name.to_string(), response);
        self
    }

    pub fn sent(&self) -> Vec<Sent> {
        self.sent.lock().expect("fake graph lock").clone()
    }
}

impl RosGraph for FakeGraph {
    fn publish<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<(), RosError>> {
        Box::pin(async move {
            self.sent
                .lock()
                .expect("fake graph lock")
                .push(Sent::Publish {
                    topic: topic.to_string(),
                    type_name: type_name.to_string(),
                    message,
                });
            Ok(())
        })
    }

    fn call_service<'a>(
        &'a self,
        service: &'a str,
        type_name: &'a str,
        request: Value,
        _timeout: Duration,
    ) -> BoxFuture<'a, Result<Value, RosError>> {
        Box::pin(async move {
            let response = self
                .services
                .get(service)
                .cloned()
                .ok_or_else(|| RosError::NoService(service.to_string()))?;
            self.sent.lock().expect("fake graph lock").push(Sent::Call {
                service: service.to_string(),
                type_name: type_name.to_string(),
                request,
            });
            Ok(response)
        })
    }
}
