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
//! - holds node parameters to the fence by their full names (`/turtlesim/background_r`,
//!   `fence::parameter_name`), whoever calls a node's `rcl_interfaces` parameter
//!   services (the parameter tools, `ros_service_call`, a declared tool): a get, set,
//!   description or type query naming a denied one is refused, a listing leaves denied
//!   ones out, and a `ParameterEvent` read from a topic loses them;
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
use crate::fence::{canonical, visible, Fence};
use crate::limits::{Motion, Verdict};

/// Services that only read state, allowed while the e-stop is engaged.
const READ_ONLY_SERVICES: &[&str] = &[
    "rcl_interfaces/srv/GetParameters",
    "rcl_interfaces/srv/ListParameters",
    "rcl_interfaces/srv/DescribeParameters",
    "rcl_interfaces/srv/GetParameterTypes",
    "type_description_interfaces/srv/GetTypeDescription",
];

/// A node's parameter services (`rcl_interfaces`): the name each is served under, its
/// type, and where its request names parameters.
const PARAMETER_SERVICES: &[(&str, &str, NamedBy)] = &[
    (
        "list_parameters",
        "rcl_interfaces/srv/ListParameters",
        NamedBy::Prefixes,
    ),
    (
        "get_parameters",
        "rcl_interfaces/srv/GetParameters",
        NamedBy::Names,
    ),
    (
        "set_parameters",
        "rcl_interfaces/srv/SetParameters",
        NamedBy::Parameters,
    ),
    (
        "set_parameters_atomically",
        "rcl_interfaces/srv/SetParametersAtomically",
        NamedBy::Parameters,
    ),
    (
        "describe_parameters",
        "rcl_interfaces/srv/DescribeParameters",
        NamedBy::Names,
    ),
    (
        "get_parameter_types",
        "rcl_interfaces/srv/GetParameterTypes",
        NamedBy::Names,
    ),
];

/// Whether a service of type `ty` is one every ROS 2 node serves of itself, for its
/// parameters (`rcl_interfaces`) or its types' descriptions: the node's machinery,
/// not something the robot does. The parameter tools are their way in, so a tool
/// choice and a generic service call's grammar leave them out unless the operator
/// writes one (on the arm, a change of the gripper's setting was sent as a hand-built
/// `set_parameters_atomically` request, and a drive the arm cannot make as a
/// `get_parameters` call).
pub fn node_machinery(ty: &str) -> bool {
    let ty = normalize_type(ty);
    PARAMETER_SERVICES.iter().any(|(_, t, _)| *t == ty) || READ_ONLY_SERVICES.contains(&ty.as_str())
}

/// The field of `rcl_interfaces/msg/ParameterValue` each `ParameterType` from 1
/// (`PARAMETER_BOOL`) to 9 (`PARAMETER_STRING_ARRAY`) sets.
const PARAMETER_FIELDS: [&str; 9] = [
    "bool_value",
    "integer_value",
    "double_value",
    "string_value",
    "byte_array_value",
    "bool_array_value",
    "integer_array_value",
    "double_array_value",
    "string_array_value",
];

/// Where a parameter service's request names parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
enum NamedBy {
    /// `prefixes: string[]` (a listing; its answer is filtered too).
    Prefixes,
    /// `names: string[]`.
    Names,
    /// `parameters: Parameter[]`, each with a `name`.
    Parameters,
}

/// A call of one of a node's parameter services.
struct ParameterCall {
    node: String,
    names: NamedBy,
}

impl ParameterCall {
    /// The parameter call `service` of type `ty` (normalised) is, if it is one: known by
    /// its type, wherever it is served. A service named as a parameter service but
    /// called with another type is refused: its request would be read by other fields.
    fn of(service: &str, ty: &str) -> Result<Option<ParameterCall>, RosError> {
        let (node, which) = service.rsplit_once('/').unwrap_or(("", service));
        if let Some((_, _, names)) = PARAMETER_SERVICES.iter().find(|(_, t, _)| *t == ty) {
            return Ok(Some(ParameterCall {
                node: node.to_string(),
                names: *names,
            }));
        }
        match PARAMETER_SERVICES.iter().find(|(w, _, _)| *w == which) {
            Some((_, expected, _)) => Err(RosError::Other(format!(
                "{service} serves a node's parameters: call it as {expected}"
            ))),
            None => Ok(None),
        }
    }

    /// The parameter names the request (as encoded) gives.
    fn requested<'a>(&self, request: &'a Value) -> Vec<&'a str> {
        let strings = |v: &'a Value| v.as_array().into_iter().flatten().filter_map(Value::as_str);
        match self.names {
            NamedBy::Prefixes => strings(&request["prefixes"]).collect(),
            NamedBy::Names => strings(&request["names"]).collect(),
            NamedBy::Parameters => request["parameters"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(|p| p["name"].as_str())
                .collect(),
        }
    }

    /// Refuse a parameter value a node would take for another, or throw on: its `type`
    /// must be one of `rcl_interfaces`' `ParameterType` constants that set a value (1 to
    /// 9; 0, not set, would remove the parameter), and the request as written must give
    /// the field of that type (`{type: 3, integer_value: 5}` would set 0.0). A node's
    /// parameter service turns the type into its own enum, and rclpy's and rclcpp's both
    /// throw on an unknown one, inside the service's callback, which takes the node
    /// down. `request`: as the caller wrote it, before the encoder fills every field.
    fn check_types(&self, request: &Value) -> Result<(), RosError> {
        if self.names != NamedBy::Parameters {
            return Ok(());
        }
        let parameters = request["parameters"].as_array().into_iter().flatten();
        for p in parameters {
            let name = p["name"].as_str().unwrap_or("?");
            let ty = &p["value"]["type"];
            let field = ty
                .as_u64()
                .and_then(|t| PARAMETER_FIELDS.get(usize::try_from(t).ok()?.checked_sub(1)?));
            let Some(field) = field else {
                return Err(RosError::Other(format!(
                    "parameter {name}: value type {ty} is not a ParameterType that sets a value \
                     (1 bool, 2 integer, 3 double, 4 string, 5 to 9 arrays); set a parameter \
                     with ros_param_set, which takes the value itself"
                )));
            };
            if p["value"].get(*field).is_none() {
                return Err(RosError::Other(format!(
                    "parameter {name}: value type {ty} is given no {field}; set a parameter \
                     with ros_param_set, which takes the value itself"
                )));
            }
        }
        Ok(())
    }

    /// Leave the denied parameters out of a listing's answer.
    fn filter(&self, fence: &Fence, response: &mut Value) {
        if self.names != NamedBy::Prefixes {
            return;
        }
        for key in ["names", "prefixes"] {
            if let Some(items) = response
                .pointer_mut(&format!("/result/{key}"))
                .and_then(Value::as_array_mut)
            {
                items.retain(|n| {
                    n.as_str()
                        .is_some_and(|n| !fence.denies_parameter(&self.node, n))
                });
            }
        }
    }
}

/// Leave the denied parameters out of a `rcl_interfaces/msg/ParameterEvent` (any message
/// with a `node` and lists of parameters), so echoing `/parameter_events` shows none.
fn hide_parameters(fence: &Fence, message: &mut Value) {
    let Some(node) = message["node"].as_str().map(str::to_string) else {
        return;
    };
    for key in ["new_parameters", "changed_parameters", "deleted_parameters"] {
        if let Some(items) = message.get_mut(key).and_then(Value::as_array_mut) {
            items.retain(|p| {
                p["name"]
                    .as_str()
                    .is_none_or(|n| !fence.denies_parameter(&node, n))
            });
        }
    }
}

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
pub(crate) struct Guarded {
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
        // Judged before it is checked as a name, so a refusal never repeats it.
        if self.fence.denies(raw) {
            return Err(RosError::OffLimits);
        }
        let name =
            canonical(raw).map_err(|_| RosError::BadName(visible(raw).trim().to_string()))?;
        if self.fence.denies(&name) {
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
        let parameters = ParameterCall::of(&service, &ty)?;
        if let Some(p) = &parameters {
            p.check_types(&request)?;
        }
        self.inner.learn_type(&service, &ty).await?;
        let (request, note) = self.limited(&format!("{ty}_Request"), &request)?;
        // Parameters are judged by their full names in the request as it will be sent.
        if let Some(p) = &parameters {
            let names = p.requested(&request);
            if names
                .iter()
                .any(|n| self.fence.denies_parameter(&p.node, n))
            {
                return Err(RosError::OffLimits);
            }
        }
        let mut reply = self
            .inner
            .call_service(&service, &ty, request, timeout)
            .await?;
        if let Some(p) = &parameters {
            p.filter(&self.fence, &mut reply.response);
        }
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
        feedback: Option<super::FeedbackSink>,
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
        let outcome = match feedback {
            Some(f) => {
                self.inner
                    .send_goal_watched(&action, &ty, goal, wait, f)
                    .await
            }
            None => self.inner.send_goal(&action, &ty, goal, wait).await,
        };
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
                hide_parameters(&self.fence, &mut s.message);
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
        Box::pin(self.do_send_goal(action, type_name, goal, wait, None))
    }

    fn send_goal_watched<'a>(
        &'a self,
        action: &'a str,
        type_name: &'a str,
        goal: Value,
        wait: Duration,
        feedback: super::FeedbackSink,
    ) -> BoxFuture<'a, Result<GoalOutcome, RosError>> {
        Box::pin(self.do_send_goal(action, type_name, goal, wait, Some(feedback)))
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
                    hide_parameters(&fence, &mut v);
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

    #[test]
    fn a_nodes_own_services_are_told_from_the_robots() {
        assert!(node_machinery("rcl_interfaces/srv/SetParametersAtomically"));
        assert!(node_machinery(
            "type_description_interfaces/srv/GetTypeDescription"
        ));
        assert!(!node_machinery("std_srvs/srv/Trigger"));
    }

    /// Issue 41: parameters are judged by their full names on every parameter service,
    /// whoever calls it, and listings and parameter events leave denied ones out.
    #[test]
    fn parameters_meet_the_fence_by_their_full_names() {
        let listing = json!({"result": {"names": ["background_b", "background_r", "background\u{200B}_r"],
                                        "prefixes": []}});
        let fake = Arc::new(
            FakeGraph::new()
                .with_service("/turtlesim/list_parameters", listing)
                .with_service("/turtlesim/get_parameters", json!({"values": [{"type": 2, "integer_value": 69}]}))
                .with_service("/turtlesim/set_parameters", json!({"results": [{"successful": true, "reason": ""}]}))
                .with_service("/turtlesim/describe_parameters", json!({"descriptors": []}))
                .with_messages(
                    "/parameter_events",
                    vec![json!({"node": "/turtlesim", "new_parameters": [],
                                "changed_parameters": [{"name": "background_r", "value": {"type": 2}},
                                                       {"name": "background_b", "value": {"type": 2}}],
                                "deleted_parameters": []})],
                ),
        );
        let fence = Fence::new(&["^/turtlesim/background_r$".to_string()]).unwrap();
        let guarded = Guarded::new(
            fake.clone(),
            Arc::new(fence),
            EStop::new(),
            Motion::default(),
        );
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap();
        let t = Duration::from_secs(1);
        let call = |service: &str, ty: &str, request: Value| {
            rt.block_on(guarded.call_service(service, ty, request, t))
        };
        let set = |name: &str| json!({"parameters": [{"name": name, "value": {"type": 2, "integer_value": 5}}]});
        for (service, ty, request) in [
            (
                "/turtlesim/get_parameters",
                "rcl_interfaces/srv/GetParameters",
                json!({"names": ["background_r"]}),
            ),
            (
                "/turtlesim/get_parameters",
                "rcl_interfaces/srv/GetParameters",
                json!({"names": ["background_b", "BACKGROUND_R"]}),
            ),
            (
                "/turtlesim/set_parameters",
                "rcl_interfaces/srv/SetParameters",
                set("background_r"),
            ),
            (
                "turtlesim/set_parameters",
                "rcl_interfaces::srv::dds_::SetParameters_",
                set("background\u{2060}_r"),
            ),
            (
                "/turtlesim/describe_parameters",
                "rcl_interfaces/srv/DescribeParameters",
                json!({"names": ["background_r"]}),
            ),
        ] {
            let r = call(service, ty, request.clone());
            assert!(
                matches!(r, Err(RosError::OffLimits)),
                "{service} {request}: {r:?}"
            );
        }
        // Called as another type, a parameter service is refused rather than misread.
        let r = call("/turtlesim/set_parameters", "std_srvs/srv/Empty", json!({}));
        assert!(matches!(r, Err(RosError::Other(_))), "{r:?}");
        assert!(fake.sent().is_empty(), "{:?}", fake.sent());

        let ok = call(
            "/turtlesim/set_parameters",
            "rcl_interfaces/srv/SetParameters",
            set("background_b"),
        );
        assert!(ok.is_ok(), "{ok:?}");
        // A value type outside ParameterType would throw inside the node's callback.
        let sent = fake.sent().len();
        for (ty, field) in [
            (json!(60), "integer_value"),
            (json!(-1), "integer_value"),
            (json!("double"), "double_value"),
            (Value::Null, "integer_value"),
            (json!(0), "integer_value"),
            (json!(3), "integer_value"),
        ] {
            let bad =
                json!({"parameters": [{"name": "background_b", "value": {"type": ty, field: 60}}]});
            let r = call(
                "/turtlesim/set_parameters",
                "rcl_interfaces/srv/SetParameters",
                bad,
            );
            let told = matches!(&r, Err(RosError::Other(e)) if e.contains("ros_param_set"));
            assert!(told, "{ty}: {r:?}");
        }
        assert_eq!(fake.sent().len(), sent, "{:?}", fake.sent());
        let listed = call(
            "/turtlesim/list_parameters",
            "rcl_interfaces/srv/ListParameters",
            json!({}),
        )
        .unwrap()
        .response;
        assert_eq!(listed["result"]["names"], json!(["background_b"]));

        let events = rt
            .block_on(guarded.subscribe("/parameter_events", None, 1, t))
            .unwrap();
        let changed = &events[0].message["changed_parameters"];
        assert_eq!(changed.as_array().map(Vec::len), Some(1), "{changed}");
        assert_eq!(changed[0]["name"], "background_b");
    }

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
