//! An in-memory `RosGraph`: a fixed graph, messages per topic, services and actions
//! answered from tables; records every publish, service call, goal and cancel, so tool
//! tests run without DDS.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::time::Duration;

use serde_json::Value;

use super::{BoxFuture, CancelOutcome, GoalOutcome, Graph, Interfaces, RosError, RosGraph, Sample};

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
    Goal {
        action: String,
        type_name: String,
        goal: Value,
    },
    Cancel {
        action: String,
        goal_id: Option<String>,
    },
}

#[derive(Default)]
pub struct FakeGraph {
    sent: Mutex<Vec<Sent>>,
    services: BTreeMap<String, Value>,
    actions: BTreeMap<String, GoalOutcome>,
    topics: BTreeMap<String, Vec<Value>>,
    /// How many of a topic's first messages a new subscription receives as history
    /// (a latched topic's), all at once.
    history: BTreeMap<String, usize>,
    graph: Graph,
    interfaces: Interfaces,
    watchers: Mutex<Vec<(String, tokio::sync::mpsc::UnboundedSender<Value>)>>,
    /// How long a `publish` is held up before it goes out (`publish_now` never is).
    publish_delay: Duration,
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

    /// An action that answers every goal with `outcome` (and cancels whatever it is asked).
    pub fn with_action(mut self, name: &str, outcome: GoalOutcome) -> FakeGraph {
        self.actions.insert(name.to_string(), outcome);
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

    /// The first `n` of `topic`'s messages come as a latched topic's history: all at
    /// once, on joining, before the rest.
    #[cfg(test)]
    pub(crate) fn with_history(mut self, topic: &str, n: usize) -> FakeGraph {
        self.history.insert(topic.to_string(), n);
        self
    }

    /// Hold every `publish` up for `delay` before it goes out, as a busy node or a
    /// wait for a subscriber does; `publish_now` (the brake's) goes out at once.
    #[cfg(test)]
    pub(crate) fn with_publish_delay(mut self, delay: Duration) -> FakeGraph {
        self.publish_delay = delay;
        self
    }

    fn record_publish(&self, topic: &str, type_name: &str, message: Value) -> super::Delivery {
        self.sent
            .lock()
            .expect("fake graph lock")
            .push(Sent::Publish {
                topic: topic.to_string(),
                type_name: type_name.to_string(),
                message,
            });
        super::Delivery::to(topic)
    }

    /// Deliver `message` on `topic` to everyone watching it.
    pub fn inject(&self, topic: &str, message: Value) {
        for (t, tx) in self.watchers.lock().expect("fake graph lock").iter() {
            if t == topic {
                let _ = tx.send(message.clone());
            }
        }
    }

    /// Whether someone watches `topic` (a watcher started on its own thread may not yet).
    pub fn watched(&self, topic: &str) -> bool {
        let watchers = self.watchers.lock().expect("fake graph lock");
        watchers.iter().any(|(t, _)| t == topic)
    }

    pub fn sent(&self) -> Vec<Sent> {
        self.sent.lock().expect("fake graph lock").clone()
    }
}

impl RosGraph for FakeGraph {
    fn graph(&self) -> BoxFuture<'_, Result<Graph, RosError>> {
        Box::pin(async move { Ok(self.graph.clone()) })
    }

    fn watch<'a>(
        &'a self,
        topic: &'a str,
        _type_name: &'a str,
    ) -> BoxFuture<'a, Result<super::Watch, RosError>> {
        Box::pin(async move {
            let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
            self.watchers
                .lock()
                .expect("fake graph lock")
                .push((topic.to_string(), tx));
            Ok(rx)
        })
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
            // The history at once, then the rest spread evenly over the window, as a
            // steady publisher would.
            let history = self.history.get(topic).copied().unwrap_or(0);
            let step = window.as_secs_f64() / messages.len().max(1) as f64;
            Ok(messages
                .iter()
                .take(max)
                .enumerate()
                .map(|(i, m)| Sample {
                    history: i < history,
                    ..Sample::new(step * i.saturating_sub(history) as f64, m.clone())
                })
                .collect())
        })
    }

    fn publish<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<super::Delivery, RosError>> {
        Box::pin(async move {
            if !self.publish_delay.is_zero() {
                tokio::time::sleep(self.publish_delay).await;
            }
            Ok(self.record_publish(topic, type_name, message))
        })
    }

    fn publish_now<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<super::Delivery, RosError>> {
        Box::pin(async move { Ok(self.record_publish(topic, type_name, message)) })
    }

    fn call_service<'a>(
        &'a self,
        service: &'a str,
        type_name: &'a str,
        request: Value,
        _timeout: Duration,
    ) -> BoxFuture<'a, Result<super::Reply, RosError>> {
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
            Ok(response.into())
        })
    }

    fn send_goal<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal: Value,
        _wait: Duration,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>> {
        Box::pin(async move {
            let outcome = self
                .actions
                .get(action)
                .cloned()
                .ok_or_else(|| RosError::NoAction(action.to_string()))?;
            self.sent.lock().expect("fake graph lock").push(Sent::Goal {
                action: action.to_string(),
                type_name: type_name.to_string(),
                goal,
            });
            Ok(outcome)
        })
    }

    fn cancel_goals<'a>(
        &'a self,
        action: &'a str,
        _type_name: &'a str,
        goal_id: Option<&'a str>,
        _timeout: Duration,
    ) -> BoxFuture<'a, Result<CancelOutcome, RosError>> {
        Box::pin(async move {
            let outcome = self
                .actions
                .get(action)
                .ok_or_else(|| RosError::NoAction(action.to_string()))?;
            self.sent
                .lock()
                .expect("fake graph lock")
                .push(Sent::Cancel {
                    action: action.to_string(),
                    goal_id: goal_id.map(str::to_string),
                });
            Ok(CancelOutcome {
                return_code: "accepted".into(),
                canceling: vec![goal_id.unwrap_or(&outcome.goal_id).to_string()],
            })
        })
    }
}
