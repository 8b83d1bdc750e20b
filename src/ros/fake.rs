//! An in-memory `RosGraph`: a fixed graph, messages per topic, services answered from a
//! table; records every publish and service call, so tool tests run without DDS.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::time::Duration;

use serde_json::Value;

use super::{BoxFuture, Graph, Interfaces, RosError, RosGraph, Sample};

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
    topics: BTreeMap<String, Vec<Value>>,
    graph: Graph,
    interfaces: Interfaces,
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

    /// The graph `graph()` reports.
    pub fn with_graph(mut self, graph: Graph) -> FakeGraph {
        self.graph = graph;
        self
    }

    /// Messages a subscription to `topic` receives, in order.
    pub fn with_messages(mut self, topic: &str, messages: Vec<Value>) -> FakeGraph {
        self.topics.insert(topic.to_string(), messages);
        self
    }

    pub fn sent(&self) -> Vec<Sent> {
        self.sent.lock().expect("fake graph lock").clone()
    }
}

impl RosGraph for FakeGraph {
    fn graph(&self) -> BoxFuture<'_, Result<Graph, RosError>> {
        Box::pin(async move { Ok(self.graph.clone()) })
    }

    fn interfaces(&self) -> &Interfaces {
        &self.interfaces
    }

    fn subscribe<'a>(
        &'a self,
        topic: &'a str,
        _type_name: Option<&'a str>,
        max: usize,
        window: Duration,
    ) -> BoxFuture<'a, Result<Vec<Sample>, RosError>> {
        Box::pin(async move {
            let messages = self
                .topics
                .get(topic)
                .ok_or_else(|| RosError::NoTopic(topic.to_string()))?;
            // Spread the messages evenly over the window, as a steady publisher would.
            let step = window.as_secs_f64() / messages.len().max(1) as f64;
            Ok(messages
                .iter()
                .take(max)
                .enumerate()
                .map(|(i, m)| Sample {
                    t: step * i as f64,
                    message: m.clone(),
                })
                .collect())
        })
    }

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
