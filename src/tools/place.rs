//! Named places: `place_list`, `place_go`, `place_remember` and `place_forget`.
//!
//! A robot's places come from its robot file (`[[places]]`: name, frame, x, y, yaw,
//! aliases, description) and from its memory (`store`: places taught at run time with
//! `place_remember`, from the pose the robot reports). A place is found by its name or
//! an alias, compared without case or accents, also inside longer words ("the loading
//! area" finds "loading area"); a name that finds none is an error listing the known
//! ones, never a guess.
//!
//! Going to a place sends a `nav2_msgs/action/NavigateToPose` goal to the action the
//! robot serves (Nav2's `/navigate_to_pose` first; the built-in sim serves one too) and
//! follows it within the call's time limit: its feedback (distance remaining), and its
//! end. It goes through the guarded graph like every actuating call, so the workspace
//! bounds refuse a place outside them and the e-stop cancels the goal.

use std::sync::Arc;
use std::time::Duration;

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use crate::lexicon::folded_words;
use crate::ros::{GoalStatus, RosGraph};
use crate::store::{same_name, Place, Store};
use crate::tool::{Effect, Package, Progress, Tool, ToolContext, ToolError};
use crate::tools::ros::{failed, send_goal_reporting};
use crate::tools::system::NoArgs;

/// The action type a robot navigates with.
pub(crate) const NAVIGATE_TYPE: &str = "nav2_msgs/action/NavigateToPose";
/// Where Nav2 serves it.
const NAVIGATE_ACTION: &str = "/navigate_to_pose";
/// Message types a pose is read from, with where each holds its pose (a
/// `geometry_msgs/Pose` or, for turtlesim, x / y / theta at the top).
const POSE_TYPES: [(&str, &[&str]); 4] = [
    (
        "geometry_msgs/msg/PoseWithCovarianceStamped",
        &["pose", "pose"],
    ),
    ("geometry_msgs/msg/PoseStamped", &["pose"]),
    ("nav_msgs/msg/Odometry", &["pose", "pose"]),
    ("turtlesim/msg/Pose", &[]),
];
/// How long a pose is waited for.
const POSE_WAIT: Duration = Duration::from_secs(3);

/// Where the robot's places come from and how it is driven to them.
#[derive(Clone)]
pub(crate) struct Places {
    graph: Arc<dyn RosGraph>,
    /// The robot file's places.
    fixed: Arc<Vec<Place>>,
    /// The robot's memory, when it has one; `Err` says why it has none.
    store: Result<Arc<Store>, String>,
    /// The topic the robot's pose is read from (else found by type on the graph).
    pose_topic: Option<String>,
    /// The frame of a pose whose message has none (turtlesim's).
    frame: String,
}

/// Where a place is kept.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Kept {
    RobotFile,
    Memory,
}

impl Kept {
    fn label(self) -> &'static str {
        match self {
            Kept::RobotFile => "robot file",
            Kept::Memory => "memory",
        }
    }
}

/// The place tools. `fixed`: the robot file's places; `store`: its memory (or why there
/// is none); `pose_topic`: where its pose is read (found by type when `None`).
pub fn package(
    graph: Arc<dyn RosGraph>,
    fixed: Vec<Place>,
    store: Result<Arc<Store>, String>,
    pose_topic: Option<String>,
) -> Package {
    let p = Places {
        graph,
        fixed: Arc::new(fixed),
        store,
        pose_topic,
        frame: "map".to_string(),
    };
    Package::new("place")
        .with(PlaceList(p.clone()))
        .with(PlaceGo(p.clone()))
        .with(PlaceRemember(p.clone()))
        .with(PlaceForget(p))
}

/// A heading in degrees, one decimal.
fn degrees(rad: f64) -> f64 {
    (rad.to_degrees() * 10.0).round() / 10.0
}

fn round2(v: f64) -> f64 {
    (v * 100.0).round() / 100.0
}

fn round3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

fn shown(p: &Place, kept: Kept) -> Value {
    let mut v = json!({"name": p.name, "x": round3(p.x), "y": round3(p.y),
                       "yaw_deg": degrees(p.yaw), "frame": p.frame, "kept_in": kept.label()});
    if !p.aliases.is_empty() {
        v["aliases"] = json!(p.aliases);
    }
    if !p.description.is_empty() {
        v["description"] = json!(p.description);
    }
    v
}

/// Whether `needle`'s words appear in `hay`'s, in order and side by side.
fn contains_words(hay: &[String], needle: &[String]) -> bool {
    !needle.is_empty() && hay.windows(needle.len()).any(|w| w == needle)
}

impl Places {
    /// Every place: the robot file's, then memory's (a memory place never shadows one of
    /// the robot file: `place_remember` refuses those names).
    fn all(&self) -> Result<Vec<(Place, Kept)>, ToolError> {
        let mut out: Vec<(Place, Kept)> = self
            .fixed
            .iter()
            .cloned()
            .map(|p| (p, Kept::RobotFile))
            .collect();
        if let Ok(store) = &self.store {
            let taught = store.places().map_err(crate::tools::memory::failed)?;
            out.extend(taught.into_iter().map(|p| (p, Kept::Memory)));
        }
        Ok(out)
    }

    /// The place `query` names: by whole name or alias first, then the name or alias
    /// sharing the most words with it, the one inside the other.
    fn find(&self, query: &str) -> Result<(Place, Kept), ToolError> {
        let all = self.all()?;
        let words = folded_words(query);
        let names = |p: &Place| -> Vec<Vec<String>> {
            std::iter::once(&p.name)
                .chain(&p.aliases)
                .map(|n| folded_words(n))
                .collect()
        };
        if let Some(hit) = all.iter().find(|(p, _)| names(p).contains(&words)) {
            return Ok(hit.clone());
        }
        let best = all
            .iter()
            .filter_map(|(p, k)| {
                // The words shared: a name said inside more words ("the loading area"),
                // or the request's words inside a longer name ("garden" for "the garden").
                let len = names(p)
                    .iter()
                    .filter(|n| contains_words(&words, n) || contains_words(n, &words))
                    .map(|n| n.len().min(words.len()))
                    .max()?;
                Some((len, p, k))
            })
            .max_by_key(|(len, _, _)| *len);
        if let Some((_, p, k)) = best {
            return Ok((p.clone(), *k));
        }
        Err(ToolError::Failed(if all.is_empty() {
            format!(
                "no place called \"{query}\": this robot knows no places yet; teach one with place_remember, or give the robot file [[places]]"
            )
        } else {
            let known: Vec<&str> = all.iter().map(|(p, _)| p.name.as_str()).collect();
            format!(
                "no place called \"{query}\"; the known places are {} (place_list gives where each is)",
                known.join(", ")
            )
        }))
    }

    /// Arguments of one required property `key` that takes a place: one of the names and
    /// aliases of the places `kept` accepts, or any other string (`reading::bound` reads
    /// this form as names to hold the value to). `None` when there are no such places,
    /// unless `new` (a name not yet given is what the property is for).
    fn named(&self, key: &str, kept: impl Fn(Kept) -> bool, new: bool) -> Option<Value> {
        let mut names: Vec<String> = self
            .all()
            .ok()?
            .into_iter()
            .filter(|(_, k)| kept(*k))
            .flat_map(|(p, _)| std::iter::once(p.name).chain(p.aliases))
            .collect();
        names.sort_unstable();
        names.dedup();
        if names.is_empty() && !new {
            return None;
        }
        Some(json!({
            "type": "object",
            "properties": {key: {"anyOf": [{"enum": names}, {"type": "string"}]}},
            "required": [key],
            "additionalProperties": false,
        }))
    }

    fn store(&self) -> Result<&Arc<Store>, ToolError> {
        self.store.as_ref().map_err(|why| {
            ToolError::Failed(format!("this robot has no memory to keep places in: {why}"))
        })
    }

    /// The topic the pose is read from and its type: the configured one, else the first
    /// topic of a pose type, in `POSE_TYPES` order.
    async fn pose_source(&self) -> Result<(String, String), ToolError> {
        let g = self.graph.graph().await.map_err(failed)?;
        let topics = g.topics();
        if let Some(t) = &self.pose_topic {
            let ty = topics
                .get(t)
                .and_then(|types| types.iter().next())
                .map(|ty| crate::ros::msg::normalize_type(ty))
                .ok_or_else(|| {
                    ToolError::Failed(format!("no pose on {t}: nothing publishes it"))
                })?;
            return Ok((t.clone(), ty));
        }
        for (want, _) in POSE_TYPES {
            let found = topics.iter().find(|(_, types)| {
                types
                    .iter()
                    .any(|ty| crate::ros::msg::normalize_type(ty) == want)
            });
            if let Some((topic, _)) = found {
                return Ok((topic.clone(), want.to_string()));
            }
        }
        Err(ToolError::Failed(
            "no topic carries the robot's pose (PoseWithCovarianceStamped, PoseStamped, Odometry or turtlesim Pose); set pose_topic in the robot file".into(),
        ))
    }

    /// Where the robot is now: frame, x, y, yaw.
    async fn here(&self) -> Result<(String, f64, f64, f64), ToolError> {
        let (topic, ty) = self.pose_source().await?;
        let samples = self
            .graph
            .subscribe(&topic, Some(&ty), 1, POSE_WAIT)
            .await
            .map_err(failed)?;
        let m = samples
            .into_iter()
            .next()
            .ok_or_else(|| {
                ToolError::Failed(format!(
                    "no pose came on {topic} within {} s",
                    POSE_WAIT.as_secs()
                ))
            })?
            .message;
        pose_of(&m, &ty, &self.frame)
            .ok_or_else(|| ToolError::Failed(format!("the message on {topic} holds no pose")))
    }
}

/// Where a NavigateToPose feedback says the robot is (its `current_pose`).
fn feedback_pose(feedback: &Value, frame: &str) -> Option<(String, f64, f64, f64)> {
    pose_of(
        &feedback["current_pose"],
        "geometry_msgs/msg/PoseStamped",
        frame,
    )
}

/// Frame, x, y and yaw from a message of `ty` (one of `POSE_TYPES`); `frame` when the
/// message names none.
fn pose_of(m: &Value, ty: &str, frame: &str) -> Option<(String, f64, f64, f64)> {
    let path = POSE_TYPES.iter().find(|(t, _)| *t == ty)?.1;
    let f = |v: &Value| v.as_f64();
    if path.is_empty() {
        return Some((frame.to_string(), f(&m["x"])?, f(&m["y"])?, f(&m["theta"])?));
    }
    let pose = path.iter().fold(m, |v, k| &v[*k]);
    let q = &pose["orientation"];
    let (qx, qy, qz, qw) = (f(&q["x"])?, f(&q["y"])?, f(&q["z"])?, f(&q["w"])?);
    let yaw = (2.0 * (qw * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz));
    let named = m["header"]["frame_id"].as_str().unwrap_or_default();
    let frame = if named.is_empty() { frame } else { named };
    Some((
        frame.trim_start_matches('/').to_string(),
        f(&pose["position"]["x"])?,
        f(&pose["position"]["y"])?,
        yaw,
    ))
}

pub(crate) struct PlaceList(Places);

impl Tool for PlaceList {
    type Args = NoArgs;
    const NAME: &'static str = "place_list";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "List the named places the robot can go to (from its robot file and those it was taught), with their coordinates.".into()
    }
    async fn call(&self, _: NoArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let all = self.0.all()?;
        let places: Vec<Value> = all.iter().map(|(p, k)| shown(p, *k)).collect();
        let each: Vec<String> = all
            .iter()
            .map(|(p, _)| format!("{} ({}, {})", p.name, round2(p.x), round2(p.y)))
            .collect();
        let summary = match each.len() {
            0 => "no places are known yet".to_string(),
            1 => format!("1 place: {}", each[0]),
            n => format!("{n} places: {}", each.join(", ")),
        };
        Ok(json!({"summary": summary, "count": places.len(), "places": places}))
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct GoArgs {
    /// The place's name or one of its aliases, as the operator said it.
    pub place: String,
    /// Places to go to after it, in order.
    #[serde(default)]
    pub then: Vec<String>,
    /// Return to where the robot started, last.
    #[serde(default)]
    pub back: bool,
}

/// Most places one call goes to (a route), the return to the start included.
const MAX_LEGS: usize = 8;
/// How long a drive may take unless the policy file sets a time limit.
const ROUTE_TIME: Duration = Duration::from_secs(300);

pub(crate) struct PlaceGo(Places);

impl Tool for PlaceGo {
    type Args = GoArgs;
    const NAME: &'static str = "place_go";
    const EFFECT: Effect = Effect::Actuates;
    const SEQUENCE: &'static [&'static str] = &["place", "then"];
    fn description(&self) -> String {
        "Drive the robot to a named place, or through several in order, with its navigation (Nav2's navigate_to_pose); returns where it arrived or stopped. Moves the robot.".into()
    }
    /// The known places' names and aliases for `place`, or any other name (which the
    /// call reports missing, with the known ones), and known ones for `then`.
    fn live_parameters(&self) -> Option<Value> {
        let mut schema = self.0.named("place", |_| true, false)?;
        // The places after the first are only known ones: a small model fills a list
        // it may write freely with words of its own ("to_land", "then").
        let known = schema["properties"]["place"]["anyOf"][0].clone();
        schema["properties"]["then"] =
            json!({"type": "array", "items": known, "maxItems": MAX_LEGS - 2});
        schema["properties"]["back"] = json!({"type": "boolean"});
        Some(schema)
    }
    /// A route of several places takes minutes (a real robot drives about 0.5 m/s);
    /// the e-stop and the operator's cancel still end it at once.
    fn time_limit(&self) -> Option<Duration> {
        Some(ROUTE_TIME)
    }
    async fn call(&self, a: GoArgs, cx: &ToolContext) -> Result<Value, ToolError> {
        // Every place is found before the robot moves: a route with a name the robot
        // lacks is refused whole.
        let mut legs = vec![self.0.find(&a.place)?.0];
        for name in &a.then {
            legs.push(self.0.find(name)?.0);
        }
        // A place again right after itself is no leg ("dock, then dock"): a small model
        // repeats the place it was given to fill the list.
        legs.dedup_by(|b, a| a.name == b.name);
        if a.back {
            let (frame, x, y, yaw) = self.0.here().await?;
            legs.push(Place {
                name: "the start".into(),
                frame,
                x,
                y,
                yaw,
                aliases: Vec::new(),
                description: String::new(),
            });
        }
        if legs.len() > MAX_LEGS {
            return Err(ToolError::InvalidArguments(format!(
                "a route goes to at most {MAX_LEGS} places; split it"
            )));
        }
        let action = self.0.navigate_action().await?;
        // Leave a second of the call's time limit for the answer to come back.
        let deadline =
            std::time::Instant::now() + cx.timeout.saturating_sub(Duration::from_secs(1));
        if legs.len() == 1 {
            return self
                .0
                .drive(&legs[0], &action, deadline, &cx.progress, "")
                .await;
        }
        route(&self.0, &legs, &action, deadline, &cx.progress).await
    }
}

/// Drive `legs` in order, each after the one before arrived; stop at the first that
/// does not (the e-stop, a cancel, a refusal, the time limit) and say where.
async fn route(
    places: &Places,
    legs: &[Place],
    action: &str,
    deadline: std::time::Instant,
    progress: &Progress,
) -> Result<Value, ToolError> {
    let n = legs.len();
    let mut done: Vec<Value> = Vec::new();
    for (i, leg) in legs.iter().enumerate() {
        let lead = format!("leg {} of {n}, ", i + 1);
        let out = match places.drive(leg, action, deadline, progress, &lead).await {
            Ok(out) => out,
            // A leg refused after others were driven (the e-stop engaged between them)
            // ends the route; what was reached is still reported.
            Err(e) if !done.is_empty() => {
                json!({"summary": e.to_string(), "place": leg.name, "status": "refused"})
            }
            Err(e) => return Err(e),
        };
        let arrived = out["status"] == json!(GoalStatus::Succeeded);
        done.push(out);
        if !arrived {
            break;
        }
    }
    let reached: Vec<&str> = done
        .iter()
        .filter(|o| o["status"] == json!(GoalStatus::Succeeded))
        .filter_map(|o| o["place"].as_str())
        .collect();
    let last = done.last().cloned().unwrap_or_default();
    let pose = last["last_pose"].clone();
    let at = match (pose["x"].as_f64(), pose["y"].as_f64()) {
        (Some(x), Some(y)) => format!(", at ({}, {})", round2(x), round2(y)),
        _ => String::new(),
    };
    let summary = if reached.len() == n {
        format!("route done, {n} of {n}: {}{at}", reached.join(", "))
    } else {
        let stopped = last["summary"].as_str().unwrap_or("");
        let before = if reached.is_empty() {
            "nothing reached before".to_string()
        } else {
            format!("reached {}", reached.join(", "))
        };
        format!(
            "route stopped on leg {} of {n}: {stopped}; {before}; the rest was not driven",
            done.len()
        )
    };
    Ok(json!({
        "summary": summary,
        "reached": reached.len(),
        "of": n,
        "legs": done,
        "last_pose": pose,
    }))
}

impl Places {
    /// The navigation action this robot serves: Nav2's first, else the first of its type.
    async fn navigate_action(&self) -> Result<String, ToolError> {
        let g = self.graph.graph().await.map_err(failed)?;
        let served: Vec<String> = g
            .actions()
            .into_iter()
            .filter(|x| crate::ros::msg::normalize_type(&x.type_name) == NAVIGATE_TYPE)
            .map(|x| x.action)
            .collect();
        served
            .iter()
            .find(|x| *x == NAVIGATE_ACTION)
            .or(served.first())
            .cloned()
            .ok_or_else(|| {
                ToolError::Failed(format!(
                    "this robot serves no {NAVIGATE_TYPE} action (Nav2's navigate_to_pose), so it cannot drive to places; start its navigation first"
                ))
            })
    }

    /// Drive to `place` until it is reached or `deadline`: the leg's report (its summary,
    /// status, the distance left and the last pose). The distance left goes to
    /// `progress` as the navigation reports it, after `lead`.
    async fn drive(
        &self,
        place: &Place,
        action: &str,
        deadline: std::time::Instant,
        progress: &Progress,
        lead: &str,
    ) -> Result<Value, ToolError> {
        let goal = json!({
            "pose": {
                "header": {"frame_id": place.frame},
                "pose": {
                    "position": {"x": place.x, "y": place.y, "z": 0.0},
                    "orientation": {"x": 0.0, "y": 0.0,
                                    "z": (place.yaw / 2.0).sin(), "w": (place.yaw / 2.0).cos()},
                },
            },
            "behavior_tree": "",
        });
        let wait = deadline
            .saturating_duration_since(std::time::Instant::now())
            .max(Duration::from_millis(100));
        let name = &place.name;
        progress.report(format!("{lead}to {name}"));
        let say = |f: &Value| {
            let left = f["distance_remaining"].as_f64()?;
            let at = feedback_pose(f, &place.frame)
                .map(|(_, x, y, _)| format!(" (at {}, {})", round2(x), round2(y)))
                .unwrap_or_default();
            Some(json!(format!(
                "{lead}to {name}{at}: {:.1} m to go",
                left.max(0.0)
            )))
        };
        let outcome = send_goal_reporting(
            self.graph.as_ref(),
            (action, NAVIGATE_TYPE),
            goal,
            wait,
            progress,
            say,
        )
        .await
        .map_err(failed)?;
        let last = outcome.feedback.last().map(|s| {
            let m = &s.message;
            m.get("feedback").unwrap_or(m).clone()
        });
        let remaining = last
            .as_ref()
            .and_then(|f| f["distance_remaining"].as_f64())
            .map(round3);
        let at = last.as_ref().and_then(|f| feedback_pose(f, &place.frame));
        let summary = leg_summary(name, &outcome, at.as_ref(), remaining, wait);
        let mut out = json!({
            "summary": summary,
            "place": name,
            "target": {"x": round3(place.x), "y": round3(place.y), "yaw_deg": degrees(place.yaw), "frame": place.frame},
            "status": outcome.status,
            "action": action,
            "goal_id": outcome.goal_id,
        });
        if let Some(r) = remaining {
            out["distance_remaining_m"] = json!(r);
        }
        if let Some((frame, x, y, yaw)) = at {
            out["last_pose"] =
                json!({"x": round3(x), "y": round3(y), "yaw_deg": degrees(yaw), "frame": frame});
        }
        Ok(out)
    }
}

/// A leg's outcome in one line: where it arrived, how far short it stopped, or why the
/// navigation gave up.
fn leg_summary(
    name: &str,
    outcome: &crate::ros::GoalOutcome,
    at: Option<&(String, f64, f64, f64)>,
    remaining: Option<f64>,
    wait: Duration,
) -> String {
    match outcome.status {
        GoalStatus::Succeeded => match at {
            Some(&(_, x, y, _)) => format!("arrived at {name}, ({}, {})", round2(x), round2(y)),
            None => format!("arrived at {name}"),
        },
        GoalStatus::Running => format!(
            "still driving to {name} after {:.0} s{}; it goes on (robot_stop stops it)",
            wait.as_secs_f64(),
            remaining
                .map(|r| format!(", {r} m to go"))
                .unwrap_or_default()
        ),
        GoalStatus::Canceled => format!(
            "the drive to {name} was canceled{}{}",
            at.map(|&(_, x, y, _)| format!(" at ({}, {})", round2(x), round2(y)))
                .unwrap_or_default(),
            remaining
                .map(|r| format!(", {r} m short of it"))
                .unwrap_or_default()
        ),
        GoalStatus::Rejected => format!("the navigation refused to drive to {name}"),
        GoalStatus::Aborted => {
            let why = outcome
                .result
                .as_ref()
                .and_then(|r| r["error_msg"].as_str())
                .filter(|m| !m.is_empty())
                .map(|m| format!(": {m}"))
                .unwrap_or_default();
            format!("the navigation gave up on {name}{why}")
        }
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct RememberArgs {
    /// The new place's name, as the operator said it.
    pub name: String,
}

pub(crate) struct PlaceRemember(Places);

impl Tool for PlaceRemember {
    type Args = RememberArgs;
    const NAME: &'static str = "place_remember";
    const EFFECT: Effect = Effect::Observes;
    const RECORDS: bool = true;
    fn description(&self) -> String {
        "Remember where the robot is now as a named place, kept across restarts, so it can be sent back there by name.".into()
    }
    /// The taught places' names (to move one) or a new name: `reading::bound` holds a new
    /// one to the words the operator said.
    fn live_parameters(&self) -> Option<Value> {
        self.0.named("name", |k| k == Kept::Memory, true)
    }
    async fn call(&self, a: RememberArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let name = a.name.trim();
        if folded_words(name).is_empty() {
            return Err(ToolError::InvalidArguments(
                "a place needs a name with letters or digits, e.g. \"loading bay\"".into(),
            ));
        }
        if let Some(p) = self.0.fixed.iter().find(|p| {
            std::iter::once(&p.name)
                .chain(&p.aliases)
                .any(|n| same_name(n, name))
        }) {
            return Err(ToolError::Failed(format!(
                "\"{name}\" is the robot file's place {}; choose another name, or change the robot file",
                p.name
            )));
        }
        let store = self.0.store()?;
        let (frame, x, y, yaw) = self.0.here().await?;
        let place = Place {
            name: name.to_string(),
            frame,
            x,
            y,
            yaw,
            aliases: Vec::new(),
            description: String::new(),
        };
        let replaced = store
            .put_place(&place)
            .map_err(crate::tools::memory::failed)?;
        let mut out = shown(&place, Kept::Memory);
        out["summary"] = json!(if replaced {
            format!("{name} moved to where the robot is now")
        } else {
            format!("remembered {name} where the robot is now")
        });
        Ok(out)
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct ForgetArgs {
    /// The taught place to forget, e.g. "loading bay".
    pub name: String,
}

pub(crate) struct PlaceForget(Places);

impl Tool for PlaceForget {
    type Args = ForgetArgs;
    const NAME: &'static str = "place_forget";
    const EFFECT: Effect = Effect::Actuates;
    fn description(&self) -> String {
        "Forget a place the robot was taught (a robot file's places stay). Deletes it from memory."
            .into()
    }
    /// The places' names, or any other name (which the call reports missing; a robot
    /// file's place it refuses, saying why).
    fn live_parameters(&self) -> Option<Value> {
        self.0.named("name", |_| true, false)
    }
    async fn call(&self, a: ForgetArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let (place, kept) = self.0.find(&a.name)?;
        if kept == Kept::RobotFile {
            return Err(ToolError::Failed(format!(
                "{} is a place of the robot file, not of memory: change the robot file to remove it",
                place.name
            )));
        }
        let store = self.0.store()?;
        store
            .forget_place(&place.name)
            .map_err(crate::tools::memory::failed)?;
        Ok(json!({"summary": format!("forgot {}", place.name), "forgotten": place.name}))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::fake::FakeGraph;

    fn places(store: Option<Arc<Store>>) -> Places {
        Places {
            graph: Arc::new(FakeGraph::new()),
            fixed: Arc::new(vec![
                Place {
                    name: "dock".into(),
                    frame: "map".into(),
                    x: 1.0,
                    y: 1.0,
                    yaw: 0.0,
                    aliases: vec!["charging station".into(), "Ladestation".into()],
                    description: String::new(),
                },
                Place {
                    name: "loading area".into(),
                    frame: "map".into(),
                    x: 9.0,
                    y: 2.0,
                    yaw: 1.57,
                    aliases: vec![],
                    description: String::new(),
                },
            ]),
            store: store.ok_or_else(|| "no data directory".to_string()),
            pose_topic: None,
            frame: "map".into(),
        }
    }

    #[test]
    fn places_are_found_by_name_alias_and_inside_longer_words() {
        let p = places(None);
        assert_eq!(p.find("Dock").unwrap().0.name, "dock");
        assert_eq!(p.find("ladestation").unwrap().0.name, "dock");
        assert_eq!(p.find("the Loading Area").unwrap().0.name, "loading area");
        assert_eq!(p.find("la charging station").unwrap().0.name, "dock");
        assert_eq!(p.find("loading").unwrap().0.name, "loading area");
        let e = p.find("kitchen").unwrap_err().to_string();
        assert!(e.contains("dock, loading area"), "{e}");
    }

    #[test]
    fn taught_places_join_the_robot_files() {
        let dir = tempfile::tempdir().unwrap();
        let store = Arc::new(Store::open(&dir.path().join("m.sqlite"), "sim").unwrap());
        store
            .put_place(&Place {
                name: "Werkbank".into(),
                frame: "map".into(),
                x: 4.0,
                y: 4.0,
                yaw: 0.0,
                aliases: vec![],
                description: String::new(),
            })
            .unwrap();
        let p = places(Some(store));
        assert_eq!(p.find("die werkbank").unwrap().1, Kept::Memory);
        assert_eq!(p.all().unwrap().len(), 3);
    }

    #[test]
    fn poses_are_read_from_each_pose_type() {
        let q = json!({"x": 0.0, "y": 0.0, "z": (0.5f64).sin(), "w": (0.5f64).cos()});
        let stamped = json!({"header": {"frame_id": "map"}, "pose": {"position": {"x": 1.0, "y": 2.0, "z": 0.0}, "orientation": q}});
        let (f, x, y, yaw) = pose_of(&stamped, "geometry_msgs/msg/PoseStamped", "x").unwrap();
        assert_eq!((f.as_str(), x, y), ("map", 1.0, 2.0));
        assert!((yaw - 1.0).abs() < 1e-9);
        let odom = json!({"header": {"frame_id": "/odom"}, "pose": {"pose": stamped["pose"], "covariance": []}});
        assert_eq!(
            pose_of(&odom, "nav_msgs/msg/Odometry", "map").unwrap().0,
            "odom"
        );
        let turtle = json!({"x": 5.0, "y": 6.0, "theta": -1.0});
        assert_eq!(
            pose_of(&turtle, "turtlesim/msg/Pose", "map").unwrap(),
            ("map".to_string(), 5.0, 6.0, -1.0)
        );
        assert_eq!(pose_of(&json!({}), "turtlesim/msg/Pose", "map"), None);
    }
}
