//! The ROS boundary: the one choke point every tool reaches the robot through. A
//! `Guarded` graph wraps any `RosGraph` and, whatever tool calls it and however the name
//! was written or built:
//!
//! - resolves every name (topic, service, action, the `<node>/set_parameters` a
//!   parameter tool builds) to its canonical form and refuses it when the operator's
//!   deny-list covers it ("off limits", never quoting the pattern or the name);
//! - hides denied nodes, topics, services and actions from the graph, so listings,
//!   counts and "did you mean" suggestions never show them, and redacts denied names in
//!   every message, response, result and feedback that comes back;
//! - refuses every publish, goal and state-changing service call while the e-stop is
//!   engaged;
//! - encodes each outgoing message first (every field filled, the type's spelling
//!   resolved; a null or NaN is an error) and applies the motion limits to it as it will
//!   be sent, clamping or refusing (`limits`);
//! - sends the agent's motion to its lower-priority mux input when the operator's
//!   velocity topic was asked for, and says when the operator's input is active;
//! - refuses a message whose type is not the one the graph announces for its topic (the
//!   limits read fields by name: a Wrench has the bytes of a Twist) and any type that is
//!   not a message (`pkg/srv/X` would go out as `pkg/msg/X`);
//! - treats the names under a denied name as denied too (a denied node's own topics,
//!   services and parameters);
//! - remembers every velocity topic it sent motion on (with the last command) and every
//!   goal that may still run, so the e-stop's brake can zero the one (the last command
//!   with every Twist at zero: at once, again once every publish that passed the e-stop
//!   check before the trigger has gone out, and again after 100 and 300 ms, so a command
//!   already on its way cannot win however long it was held up) and cancel the other
//!   (`brake`).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;

use serde_json::Value;

use super::msg::normalize_type;
use super::{
    cdr, BoxFuture, CancelOutcome, Delivery, GoalOutcome, GoalStatus, Graph, Interfaces, Reply,
    RosError, RosGraph, Sample, Watch,
};
use crate::estop::EStop;
use crate::fence::{canonical, Fence};
use crate::limits::{Motion, Verdict};

/// Services that only read state, allowed while the e-stop is engaged.
const READ_ONLY_SERVICES: &[&str] = &[
    "rcl_interfaces/srv/GetParameters",
    "rcl_interfaces/srv/ListParameters",
    "rcl_interfaces/srv/DescribeParameters",
    "rcl_interfaces/srv/GetParameterTypes",
    "type_description_interfaces/srv/GetTypeDescription",
];

/// What the e-stop's brake needs: where motion went, and goals that may still run.
#[derive(Default)]
struct Sent {
    /// Velocity topic → its type and the last command sent on it.
    velocity: BTreeMap<String, (String, Option<Value>)>,
    /// (topic, type) pairs checked against the graph's announced types.
    typed: std::collections::BTreeSet<(String, String)>,
    /// Goals sent and not known to have ended.
    goals: Vec<Goal>,
    /// Numbers the goals, so a send that returns removes its own.
    next_goal: u64,
}

/// A goal this process sent. Its id is known only once the send returns (the wait for
/// the result included): until then the brake cancels every goal of its action, which
/// on an e-stop is the safe side.
struct Goal {
    key: u64,
    action: String,
    ty: String,
    id: Option<String>,
}

/// The guarded graph (see the module header).
pub struct Guarded {
    inner: Arc<dyn RosGraph>,
    fence: Arc<Fence>,
    estop: Arc<EStop>,
    motion: Motion,
    sent: Mutex<Sent>,
    /// What the mux last said was active.
    mux_active: Arc<Mutex<Option<String>>>,
    /// Held shared by a publish from its last e-stop check until its message is out;
    /// the brake takes it exclusively, so its zero goes out after any such message.
    in_flight: Arc<tokio::sync::RwLock<()>>,
    rt: tokio::runtime::Handle,
}

impl Guarded {
    /// Guard `inner`. The e-stop's trigger brakes through this graph; the configured
    /// velocity topics are made ready so the brake reaches them at once.
    pub fn new(
        inner: Arc<dyn RosGraph>,
        fence: Arc<Fence>,
        estop: Arc<EStop>,
        motion: Motion,
    ) -> Arc<Guarded> {
        let rt = super::ros2::background();
        let g = Arc::new(Guarded {
            inner,
            fence,
            estop: estop.clone(),
            sent: Mutex::new(Sent::default()),
            mux_active: Arc::new(Mutex::new(None)),
            in_flight: Arc::new(tokio::sync::RwLock::new(())),
            rt,
            motion,
        });
        let weak: Weak<Guarded> = Arc::downgrade(&g);
        estop.on_trigger(move |_| {
            if let Some(g) = weak.upgrade() {
                g.brake();
            }
        });
        {
            let mut sent = g.sent.lock().expect("guard lock");
            for t in &g.motion.velocity_topics {
                let topic = g.motion.mux.get(t).cloned().unwrap_or_else(|| t.clone());
                sent.velocity
                    .insert(topic, ("geometry_msgs/msg/Twist".to_string(), None));
            }
        }
        g.prepare();
        g
    }

    /// Advertise the velocity topics the brake may need, and follow the mux's status.
    fn prepare(self: &Arc<Guarded>) {
        let topics: Vec<(String, String)> = self
            .sent
            .lock()
            .expect("guard lock")
            .velocity
            .iter()
            .map(|(t, (ty, _))| (t.clone(), ty.clone()))
            .collect();
        let me = self.clone();
        self.rt.spawn(async move {
            for (t, ty) in topics {
                if let Err(e) = me.inner.advertise(&t, &ty).await {
                    tracing::warn!(topic = %t, "cannot prepare the brake: {e}");
                }
            }
            let Some(status) = me.motion.mux_status.clone() else {
                return;
            };
            match me.inner.watch(&status, "std_msgs/msg/String").await {
                Ok(mut rx) => {
                    while let Some(v) = rx.recv().await {
                        *me.mux_active.lock().expect("guard lock") =
                            v["data"].as_str().map(str::to_string);
                    }
                }
                Err(e) => tracing::warn!(%status, "cannot follow the mux: {e}"),
            }
        });
    }

    /// Zero every velocity topic motion went out on (and the configured ones) and cancel
    /// every goal still running. Returns at once; the work runs on the ROS runtime.
    pub fn brake(&self) {
        let (velocity, goals) = {
            let mut sent = self.sent.lock().expect("guard lock");
            (sent.velocity.clone(), std::mem::take(&mut sent.goals))
        };
        let inner = self.inner.clone();
        let ifaces = self.inner.interfaces().clone();
        for (topic, (ty, last)) in velocity {
            let inner = inner.clone();
            let zero = match &last {
                Some(m) => crate::limits::zeroed(m),
                None => cdr::template(&ifaces, &ty).unwrap_or(Value::Null),
            };
            let in_flight = self.in_flight.clone();
            self.rt.spawn(async move {
                let zero = |why: &'static str| {
                    let (inner, topic, ty, zero) = (&inner, &topic, &ty, zero.clone());
                    async move {
                        if let Err(e) = inner.publish_now(topic, ty, zero).await {
                            tracing::warn!(%topic, "brake ({why}): {e}");
                        }
                    }
                };
                zero("at once").await;
                // A publish that passed its check before the trigger may still be on its
                // way (held up on the node, or waiting for a subscriber): once it is out,
                // this zero follows it on the same writer. Later publishes are refused.
                drop(in_flight.write().await);
                zero("after the commands in flight").await;
                for wait in [100, 200] {
                    tokio::time::sleep(Duration::from_millis(wait)).await;
                    zero("again").await;
                }
            });
        }
        for g in goals {
            let inner = inner.clone();
            self.rt.spawn(async move {
                let r = inner
                    .cancel_goals(&g.action, &g.ty, g.id.as_deref(), Duration::from_secs(3))
                    .await;
                if let Err(e) = r {
                    let action = &g.action;
                    tracing::warn!(%action, id = ?g.id, "brake: cannot cancel: {e}");
                }
            });
        }
    }

    /// `raw` in canonical form, unless the fence covers it (or a name it lies under: a
    /// denied node's `/arm_driver/cmd`).
    fn name(&self, raw: &str) -> Result<String, RosError> {
        let name = canonical(raw).map_err(|_| RosError::BadName(raw.trim().to_string()))?;
        if self.fence.denies(raw) || self.fence.denies(&name) {
            return Err(RosError::OffLimits);
        }
        Ok(name)
    }

    /// Refuse `ty` on `topic` when it is not a message type, or when the graph announces
    /// the topic with other types. Checked once per (topic, type).
    async fn check_type(&self, topic: &str, ty: &str) -> Result<(), RosError> {
        if !ty.contains("/msg/") {
            return Err(RosError::Other(format!(
                "{ty} is not a message type: publish a pkg/msg/Name type"
            )));
        }
        let key = (topic.to_string(), ty.to_string());
        if self.sent.lock().expect("guard lock").typed.contains(&key) {
            return Ok(());
        }
        let g = self.inner.graph().await?;
        let announced: std::collections::BTreeSet<String> = g
            .publishers
            .iter()
            .chain(&g.subscribers)
            .filter(|e| e.topic == topic)
            .map(|e| normalize_type(&e.type_name))
            .collect();
        if !announced.is_empty() && !announced.contains(ty) {
            let list: Vec<&str> = announced.iter().map(String::as_str).collect();
            return Err(RosError::Other(format!(
                "{topic} carries {}, not {ty}: publish with that type",
                list.join(", ")
            )));
        }
        if !announced.is_empty() {
            self.sent.lock().expect("guard lock").typed.insert(key);
        }
        Ok(())
    }

    fn stopped(&self) -> Result<(), RosError> {
        match self.estop.engaged_by() {
            Some(e) => Err(RosError::Stopped(e.source)),
            None => Ok(()),
        }
    }

    /// `message` as it will be encoded, within the limits (clamped when allowed), and
    /// what the limits did to it.
    fn limited(&self, ty: &str, message: &Value) -> Result<(Value, Option<String>), RosError> {
        let ifaces = self.inner.interfaces();
        let bytes = cdr::encode(ifaces, ty, message, 0).map_err(|e| RosError::Encode {
            type_name: ty.to_string(),
            reason: e.to_string(),
        })?;
        let full = cdr::decode(ifaces, ty, &bytes, 0).map_err(|e| RosError::Encode {
            type_name: ty.to_string(),
            reason: e.to_string(),
        })?;
        match self.motion.check(ty, &full) {
            Verdict::Within => Ok((full, None)),
            Verdict::Clamped(out, why) => Ok((out, Some(why))),
            Verdict::Refused(why) => Err(RosError::Limit(why)),
        }
    }

    fn redact(&self, v: &mut Value) {
        self.fence.redact_json(v);
    }

    async fn do_publish(
        &self,
        topic: &str,
        type_name: &str,
        message: Value,
        now: bool,
    ) -> Result<Delivery, RosError> {
        let topic = self.name(topic)?;
        let ty = normalize_type(type_name);
        self.stopped()?;
        // The agent's motion goes to its own, lower-priority input of the mux.
        let out = self.motion.mux.get(&topic).unwrap_or(&topic).clone();
        if !now {
            // The limits read the message by its definition: one the graph learns from
            // its peers must be known first.
            self.inner.learn_type(&out, &ty).await?;
        }
        let (message, clamp) = self.limited(&ty, &message)?;
        self.check_type(&out, &ty).await?;
        let mut overridden_by = None;
        if crate::limits::carries_twist(&message) {
            self.sent
                .lock()
                .expect("guard lock")
                .velocity
                .insert(out.clone(), (ty.clone(), Some(message.clone())));
            let active = self.mux_active.lock().expect("guard lock").clone();
            overridden_by = active.filter(|a| !matches!(a.as_str(), "" | "none" | "agent"));
        }
        // Again, right before it goes: the checks above may have waited on the graph.
        // Until the message is out, the brake's ordered zero waits for it.
        let _in_flight = self.in_flight.read().await;
        self.stopped()?;
        let mut d = if now {
            self.inner.publish_now(&out, &ty, message.clone()).await?
        } else {
            self.inner.publish(&out, &ty, message.clone()).await?
        };
        d.topic = out;
        d.overridden_by = overridden_by;
        if clamp.is_some() {
            d.sent = Some(message);
            d.note = clamp;
        }
        Ok(d)
    }

    async fn do_call(
        &self,
        service: &str,
        type_name: &str,
        request: Value,
        timeout: Duration,
    ) -> Result<Reply, RosError> {
        let service = self.name(service)?;
        let ty = normalize_type(type_name);
        if !READ_ONLY_SERVICES.contains(&ty.as_str()) {
            self.stopped()?;
        }
        self.inner.learn_type(&service, &ty).await?;
        let (request, note) = self.limited(&format!("{ty}_Request"), &request)?;
        let mut reply = self
            .inner
            .call_service(&service, &ty, request, timeout)
            .await?;
        self.redact(&mut reply.response);
        reply.note = note.or(reply.note);
        Ok(reply)
    }

    async fn do_send_goal(
        &self,
        action: &str,
        type_name: &str,
        goal: Value,
        wait: Duration,
    ) -> Result<GoalOutcome, RosError> {
        let action = self.name(action)?;
        let ty = normalize_type(type_name);
        self.stopped()?;
        let (goal, _) = self.limited(&format!("{ty}_Goal"), &goal)?;
        let key = {
            let mut sent = self.sent.lock().expect("guard lock");
            sent.next_goal += 1;
            let key = sent.next_goal;
            sent.goals.push(Goal {
                key,
                action: action.clone(),
                ty: ty.clone(),
                id: None,
            });
            key
        };
        let outcome = self.inner.send_goal(&action, &ty, goal, wait).await;
        {
            let mut sent = self.sent.lock().expect("guard lock");
            let at = sent.goals.iter().position(|g| g.key == key);
            match (&outcome, at) {
                (Ok(o), Some(at)) if o.status == GoalStatus::Running => {
                    sent.goals[at].id = Some(o.goal_id.clone());
                }
                (Ok(_), Some(at)) => {
                    sent.goals.remove(at);
                }
                // An error may come after the server took the goal (a late acceptance, a
                // lost result): the record stays, and the brake cancels every goal of
                // the action.
                (Err(_), Some(_)) => {}
                // The brake took it meanwhile.
                (_, None) => {}
            }
        }
        let mut outcome = outcome?;
        if let Some(r) = outcome.result.as_mut() {
            self.redact(r);
        }
        for f in &mut outcome.feedback {
            self.redact(&mut f.message);
        }
        Ok(outcome)
    }

    /// The graph without what the fence covers.
    fn filtered(&self, mut g: Graph) -> Graph {
        let f = &self.fence;
        let node_ok = |n: &Option<String>| n.as_deref().is_none_or(|n| !f.denies(n));
        g.nodes.retain(|n| !f.denies(n));
        g.publishers
            .retain(|e| !f.denies(&e.topic) && node_ok(&e.node));
        g.subscribers
            .retain(|e| !f.denies(&e.topic) && node_ok(&e.node));
        g.servers
            .retain(|e| !f.denies(&e.service) && node_ok(&e.node));
        g.clients
            .retain(|e| !f.denies(&e.service) && node_ok(&e.node));
        g
    }
}

impl RosGraph for Guarded {
    fn graph(&self) -> BoxFuture<'_, Result<Graph, RosError>> {
        Box::pin(async move { Ok(self.filtered(self.inner.graph().await?)) })
    }

    fn interfaces(&self) -> &Interfaces {
        self.inner.interfaces()
    }

    fn subscribe<'a>(
        &'a self,
        topic: &'a str,
        type_name: Option<&'a str>,
        max: usize,
        window: Duration,
    ) -> BoxFuture<'a, Result<Vec<Sample>, RosError>> {
        Box::pin(async move {
            let topic = self.name(topic)?;
            let mut samples = self.inner.subscribe(&topic, type_name, max, window).await?;
            for s in &mut samples {
                self.redact(&mut s.message);
            }
            Ok(samples)
        })
    }

    fn publish<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<Delivery, RosError>> {
        Box::pin(self.do_publish(topic, type_name, message, false))
    }

    fn publish_now<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
        message: Value,
    ) -> BoxFuture<'a, Result<Delivery, RosError>> {
        Box::pin(self.do_publish(topic, type_name, message, true))
    }

    fn call_service<'a>(
        &'a self,
        service: &'a str,
        type_name: &'a str,
        request: Value,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<Reply, RosError>> {
        Box::pin(self.do_call(service, type_name, request, timeout))
    }

    fn send_goal<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal: Value,
        wait: Duration,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>> {
        Box::pin(self.do_send_goal(action, type_name, goal, wait))
    }

    fn cancel_goals<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal_id: Option<&'a str>,
        timeout: Duration,
    ) -> BoxFuture<'a, Result<CancelOutcome, RosError>> {
        // Stopping is always allowed, e-stop or not.
        Box::pin(async move {
            let action = self.name(action)?;
            self.inner
                .cancel_goals(&action, type_name, goal_id, timeout)
                .await
        })
    }

    fn watch<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<Watch, RosError>> {
        Box::pin(async move {
            let topic = self.name(topic)?;
            let mut raw = self.inner.watch(&topic, type_name).await?;
            let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
            let fence = self.fence.clone();
            self.rt.spawn(async move {
                while let Some(mut v) = raw.recv().await {
                    fence.redact_json(&mut v);
                    if tx.send(v).is_err() {
                        return;
                    }
                }
            });
            Ok(rx)
        })
    }

    fn advertise<'a>(
        &'a self,
        topic: &'a str,
        type_name: &'a str,
    ) -> BoxFuture<'a, Result<(), RosError>> {
        Box::pin(async move {
            let topic = self.name(topic)?;
            self.inner.advertise(&topic, type_name).await
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::fake::{FakeGraph, Sent as Published};
    use serde_json::json;

    /// A command that passed the e-stop check before the trigger but went out long after
    /// (a busy node, a wait for a subscriber) must not be the last word: the brake's zero
    /// follows it, whatever the delay.
    #[test]
    fn the_brake_follows_a_command_held_up_in_flight() {
        let fake = Arc::new(FakeGraph::new().with_publish_delay(Duration::from_millis(600)));
        let estop = EStop::new();
        let guarded = Guarded::new(
            fake.clone(),
            Arc::new(Fence::default()),
            estop.clone(),
            Motion::default(),
        );
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap();
        rt.block_on(async {
            let drive = {
                let g = guarded.clone();
                tokio::spawn(async move {
                    let twist = json!({"linear": {"x": 0.5}, "angular": {"z": 0.0}});
                    g.publish("/turtle1/cmd_vel", "geometry_msgs/msg/Twist", twist)
                        .await
                })
            };
            tokio::time::sleep(Duration::from_millis(100)).await;
            estop.trigger("test");
            drive
                .await
                .unwrap()
                .expect("the command passed its check before the trigger");
            // The brake's repeats end 300 ms after the trigger; wait past them.
            tokio::time::sleep(Duration::from_millis(900)).await;
        });
        let on_topic: Vec<Value> = fake
            .sent()
            .into_iter()
            .filter_map(|s| match s {
                Published::Publish { topic, message, .. } if topic == "/turtle1/cmd_vel" => {
                    Some(message)
                }
                _ => None,
            })
            .collect();
        let moving = |m: &Value| m["linear"]["x"].as_f64() != Some(0.0);
        let command = on_topic
            .iter()
            .position(moving)
            .expect("the command went out");
        assert!(
            on_topic[command + 1..].iter().any(|m| !moving(m)),
            "no zero after the held-up command: {on_topic:?}"
        );
        assert!(!moving(on_topic.last().unwrap()), "{on_topic:?}");
        // And once engaged, a new command is refused before it is held up.
        let again = rt.block_on(guarded.publish(
            "/turtle1/cmd_vel",
            "geometry_msgs/msg/Twist",
            json!({"linear": {"x": 0.5}}),
        ));
        assert!(matches!(again, Err(RosError::Stopped(_))), "{again:?}");
    }
}
