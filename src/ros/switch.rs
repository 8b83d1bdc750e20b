//! A `RosGraph` whose target can be replaced while tools hold it: the evaluation gives
//! every case a fresh robot without rebuilding the agent (and losing its KV cache).

use std::sync::{Arc, RwLock};
use std::time::Duration;

use serde_json::Value;

use super::{BoxFuture, CancelOutcome, GoalOutcome, Graph, Interfaces, RosError, RosGraph, Sample};

pub(crate) struct SwitchGraph {
    current: RwLock<Arc<dyn RosGraph>>,
    interfaces: Interfaces,
}

impl SwitchGraph {
    pub fn new(graph: Arc<dyn RosGraph>) -> SwitchGraph {
        SwitchGraph {
            interfaces: graph.interfaces().clone(),
            current: RwLock::new(graph),
        }
    }

    /// Point every holder at `graph` from the next call on; returns the previous one.
    pub fn replace(&self, graph: Arc<dyn RosGraph>) -> Arc<dyn RosGraph> {
        std::mem::replace(&mut *self.current.write().expect("switch lock"), graph)
    }

    fn get(&self) -> Arc<dyn RosGraph> {
        self.current.read().expect("switch lock").clone()
    }
}

impl RosGraph for SwitchGraph {
    fn learn_type<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<(), RosError>> {
        let g = self.get();
        Box::pin(async move { g.learn_type(topic, type_name).await })
    }

    fn watch<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<super::Watch, RosError>> {
        let g = self.get();
        Box::pin(async move { g.watch(topic, type_name).await })
    }

    fn advertise<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<(), RosError>> {
        let g = self.get();
        Box::pin(async move { g.advertise(topic, type_name).await })
    }

    fn publish_now<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<super::Delivery, RosError>> {
        let g = self.get();
        Box::pin(async move { g.publish_now(topic, type_name, message).await })
    }

    fn graph(&self) -> BoxFuture<'_, Result<Graph, RosError>> {
        let g = self.get();
        Box::pin(async move { g.graph().await })
    }

    fn interfaces(&self) -> &Interfaces {
        &self.interfaces
    }

    fn subscribe<'a>(
        &'a self,
        topic: &'a str,
        type_name: Option<&'a str>,
        max: usize,
        window: Duration,
    ) -> BoxFuture<'a, Result<Vec<Sample>, RosError>> {
        let g = self.get();
        Box::pin(async move { g.subscribe(topic, type_name, max, window).await })
    }

    fn publish<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<super::Delivery, RosError>> {
        let g = self.get();
        Box::pin(async move { g.publish(topic, type_name, message).await })
    }

    fn call_service<'a>(
        &'a self,
        service: &'a str,
        type_name: &'a str,
        request: Value,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<super::Reply, RosError>> {
        let g = self.get();
        Box::pin(async move { g.call_service(service, type_name, request, timeout).await })
    }

    fn send_goal<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal: Value,
        wait: Duration,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>> {
        let g = self.get();
        Box::pin(async move { g.send_goal(action, type_name, goal, wait).await })
    }

    fn send_goal_watched<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal: Value,
        wait: Duration,
        feedback: super::FeedbackSink,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>> {
        let g = self.get();
        Box::pin(async move {
            g.send_goal_watched(action, type_name, goal, wait, feedback)
                .await
        })
    }

    fn cancel_goals<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal_id: Option<&'a str>,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<CancelOutcome, RosError>> {
        let g = self.get();
        Box::pin(async move { g.cancel_goals(action, type_name, goal_id, timeout).await })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::fake::FakeGraph;

    #[test]
    fn calls_go_to_the_graph_in_place_at_the_time() {
        let a = Arc::new(FakeGraph::new().with_service("/a", serde_json::json!({"from": "a"})));
        let b = Arc::new(FakeGraph::new().with_service("/a", serde_json::json!({"from": "b"})));
        let s = SwitchGraph::new(a.clone());
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let call = || {
            rt.block_on(s.call_service(
                "/a",
                "std_srvs/srv/Empty",
                Value::Null,
                Duration::from_secs(1),
            ))
        };
        assert_eq!(call().unwrap().response["from"], "a");
        s.replace(b.clone());
        assert_eq!(call().unwrap().response["from"], "b");
        assert_eq!((a.sent().len(), b.sent().len()), (1, 1));
    }
}
