//! What every ROS tool shares: the graph handle, failures as the model reads them ("no
//! topic /x; did you mean /y?"), listing filters and summaries, and name spelling.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use regex::Regex;
use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use crate::ros::{Graph, RosError, RosGraph};
use crate::tool::ToolError;

#[derive(Clone)]
pub(crate) struct Ros {
    pub(super) graph: Arc<dyn RosGraph>,
    /// The nodes' parameter names, shared by the parameter tools.
    pub(super) params: Arc<super::param_names::ParamNames>,
}

/// A ROS failure as the model reads it (also used by the turtle tools).
pub(crate) fn failed(e: RosError) -> ToolError {
    ToolError::Failed(e.to_string())
}

impl Ros {
    pub(super) fn new(graph: Arc<dyn RosGraph>) -> Ros {
        Ros {
            graph,
            params: Arc::default(),
        }
    }

    pub(super) async fn snapshot(&self) -> Result<Graph, ToolError> {
        self.graph.graph().await.map_err(failed)
    }

    /// For a tool that only reads: `topic` as asked when it exists, else the one topic
    /// its words name best (`resolve_loose`), with a note saying so; else a "no topic"
    /// error with near names.
    pub(super) async fn read_topic(&self, topic: &str) -> Result<Resolved, ToolError> {
        let g = self.snapshot().await?;
        if let Some(ty) = g.topic_type(topic) {
            return Ok(Resolved {
                topic: topic.to_string(),
                type_name: ty,
                note: None,
            });
        }
        let topics = g.topics();
        let Some(found) = resolve_loose(topic, &topics) else {
            return Err(no_topic(topic, &g));
        };
        let type_name = g.topic_type(&found).ok_or_else(|| no_topic(topic, &g))?;
        Ok(Resolved {
            note: Some(resolved_note(topic, &found, &type_name, "read")),
            topic: found,
            type_name,
        })
    }
}

/// A topic a reading tool resolved from what the model wrote.
pub(super) struct Resolved {
    pub topic: String,
    pub type_name: String,
    /// Set when the topic is not the one asked for, but the nearest match.
    pub note: Option<String>,
}

/// What a result says when its tool `did` (read, described) `found` for the `asked`
/// topic the graph lacks; a result carries it as `resolved`.
pub(super) fn resolved_note(asked: &str, found: &str, type_name: &str, did: &str) -> String {
    format!("no topic {asked}; {did} {found} ({type_name}), the topic whose name and type match it best")
}

/// `out` with the note of a resolved topic, when there is one.
pub(super) fn with_resolved(mut out: Value, note: Option<String>) -> Value {
    if let Some(n) = note {
        out["resolved"] = json!(n);
    }
    out
}

/// The words of a ROS name or type, lowercase (`lexicon::name_words`: camel case split,
/// "BatteryState" → "battery", "state"); words under three characters dropped.
fn name_words(name: &str) -> Vec<String> {
    crate::lexicon::name_words(name)
        .into_iter()
        .map(|w| w.to_lowercase())
        .filter(|w| w.chars().count() >= 3)
        .collect()
}

/// The one topic whose name and type share the most words with `wanted`, a word of its
/// name counting twice one of its type only ("battery" →
/// `/battery_state`, "Battery_Level" → the topic of type `BatteryState`, "pose" →
/// `/turtle1/pose`), a word matching when one is a prefix of the other ("diag" and
/// "diagnostics"); `None` when no topic shares a word or two share the most.
pub(super) fn resolve_loose(
    wanted: &str,
    topics: &BTreeMap<String, BTreeSet<String>>,
) -> Option<String> {
    let asked = name_words(wanted);
    if asked.is_empty() {
        return None;
    }
    let mut scored: Vec<(usize, &String)> = topics
        .iter()
        .map(|(name, types)| {
            let in_name = name_words(name);
            // The package ("sensor_msgs") says little; the type's own name says what
            // the topic carries.
            let in_type: Vec<String> = types
                .iter()
                .flat_map(|t| name_words(t.rsplit('/').next().unwrap_or(t)))
                .collect();
            let meets = |words: &[String], a: &str| {
                words
                    .iter()
                    .any(|w| w.starts_with(a) || a.starts_with(w.as_str()))
            };
            // A word the name has counts twice one only the type has.
            let hits: usize = asked
                .iter()
                .map(|a| match (meets(&in_name, a), meets(&in_type, a)) {
                    (true, _) => 2,
                    (false, true) => 1,
                    _ => 0,
                })
                .sum();
            (hits, name)
        })
        .filter(|(hits, _)| *hits > 0)
        .collect();
    scored.sort_by_key(|b| std::cmp::Reverse(b.0));
    match scored.as_slice() {
        [(best, name), rest @ ..] if rest.first().is_none_or(|(next, _)| next < best) => {
            Some((*name).clone())
        }
        _ => None,
    }
}

/// Arguments as one branch per name in `entries` (name → types), its `body` typed by
/// that name's type (`cdr::schema` of the type plus `suffix`, e.g. `_Request`), and one
/// branch for a name the robot lacks, as `Args` declares it (`open`): what a call tool
/// gives as its `Tool::live_parameters`. `None` when no name has a known type.
pub(super) fn typed_by_name(
    ros: &Ros,
    entries: BTreeMap<String, BTreeSet<String>>,
    (name_key, body_key, suffix): (&str, &str, &str),
    body_required: bool,
    open: Value,
) -> Option<Value> {
    let required = if body_required {
        json!([name_key, body_key])
    } else {
        json!([name_key])
    };
    let mut branches: Vec<Value> = entries
        .into_iter()
        .filter_map(|(name, types)| {
            let ty = crate::ros::msg::normalize_type(types.iter().next()?);
            if ty.is_empty() {
                return None;
            }
            // A type whose definition is not known yet (ROS 1 learns one from the peers
            // when it is used): the name is still the robot's, the body any object.
            let body = crate::ros::cdr::schema(ros.graph.interfaces(), &format!("{ty}{suffix}"))
                .unwrap_or_else(|_| json!({"type": "object", "additionalProperties": true}));
            Some(json!({
                "type": "object",
                "properties": {name_key: {"type": "string", "const": name}, body_key: body},
                "required": required,
                "additionalProperties": false,
            }))
        })
        .collect();
    if branches.is_empty() {
        return None;
    }
    branches.push(open);
    Some(json!({ "anyOf": branches }))
}

/// "no topic /x; did you mean /y?" or, with nothing near, which tool lists them.
pub(super) fn not_found<'a>(
    kind: &str,
    wanted: &str,
    names: impl Iterator<Item = &'a String>,
    list_tool: &str,
) -> ToolError {
    let near = suggest(wanted, names);
    ToolError::Failed(if near.is_empty() {
        format!("no {kind} {wanted}; call {list_tool} to see the {kind}s")
    } else {
        format!("no {kind} {wanted}; did you mean {}?", near.join(" or "))
    })
}

pub(super) fn require_node(g: &Graph, node: &str) -> Result<(), ToolError> {
    if g.nodes.iter().any(|n| n == node) {
        Ok(())
    } else {
        Err(ToolError::Failed(format!(
            "no node {node}; running nodes: {}",
            g.nodes.join(", ")
        )))
    }
}

/// `{name, type}` items of a name → types map, keyed by their name for filtering.
pub(super) fn typed(item: &str, map: BTreeMap<String, BTreeSet<String>>) -> Vec<(String, Value)> {
    map.into_iter()
        .map(|(name, types)| {
            let ty = types.into_iter().collect::<Vec<_>>().join(", ");
            (name.clone(), json!({item: name, "type": ty}))
        })
        .collect()
}

/// `pattern` and `namespace` of a listing, compiled.
pub(super) struct Filter {
    pattern: Option<Regex>,
    namespace: Option<String>,
    echo: Value,
}

impl Filter {
    pub(super) fn new(
        pattern: Option<String>,
        namespace: Option<String>,
    ) -> Result<Filter, ToolError> {
        let re = match pattern.as_deref().filter(|p| !p.is_empty()) {
            Some(p) => Some(
                Regex::new(p)
                    .map_err(|e| ToolError::InvalidArguments(format!("pattern {p:?}: {e}")))?,
            ),
            None => None,
        };
        let namespace = namespace.filter(|n| !n.is_empty() && n != "/").map(|n| {
            if n.starts_with('/') {
                n
            } else {
                format!("/{n}")
            }
        });
        Ok(Filter {
            echo: json!({"pattern": pattern, "namespace": namespace}),
            pattern: re,
            namespace,
        })
    }

    /// `{count, <key>: the items whose names the filters keep, filters}`; when they keep
    /// nothing but there is something, the unfiltered listing too, so a wrong filter is
    /// seen as one.
    pub(super) fn listing(&self, key: &str, items: Vec<(String, Value)>) -> Value {
        let (kept_names, kept): (Vec<&str>, Vec<&Value>) = items
            .iter()
            .filter(|(n, _)| self.keeps(n))
            .map(|(n, v)| (n.as_str(), v))
            .unzip();
        // The robot's own names first: every ROS 2 node's parameter and type
        // description services (and the logging and parameter-event topics) say
        // nothing of this robot, and would otherwise fill the names shown.
        let shown = own_first(kept.iter().copied().zip(kept_names.iter().copied()));
        let mut out = json!({"summary": summary(key, &shown), "count": kept.len(), key: kept, "filters": self.echo});
        let filtered = self.pattern.is_some() || self.namespace.is_some();
        if kept.is_empty() && !items.is_empty() && filtered {
            let (all_names, all): (Vec<&str>, Vec<&Value>) =
                items.iter().map(|(n, v)| (n.as_str(), v)).unzip();
            out["summary"] = json!(format!(
                "No {key} matched the filters; without them, {}",
                summary(key, &all_names)
            ));
            out[format!("all_{key}")] = json!(all);
            out["all_count"] = json!(all.len());
        }
        out
    }

    fn keeps(&self, name: &str) -> bool {
        let ns_ok = self.namespace.as_deref().is_none_or(|ns| {
            name == ns || name.starts_with(&format!("{}/", ns.trim_end_matches('/')))
        });
        ns_ok && self.pattern.as_ref().is_none_or(|re| re.is_match(name))
    }
}

/// The names of listed items (item, name), the robot's own first and the client
/// library's (`infrastructure`) after them, each group in the order given.
pub(super) fn own_first<'a>(items: impl Iterator<Item = (&'a Value, &'a str)>) -> Vec<&'a str> {
    let mut named: Vec<(bool, &str)> = items.map(|(v, n)| (infrastructure(v), n)).collect();
    named.sort_by_key(|(infra, _)| *infra);
    named.into_iter().map(|(_, n)| n).collect()
}

/// Whether a listed item is the ROS 2 client library's own, on every node whatever the
/// robot: its type is of `rcl_interfaces` (parameters, `/rosout`, `/parameter_events`)
/// or `type_description_interfaces`.
fn infrastructure(item: &Value) -> bool {
    // `typed` joins a name's types with ", ".
    item["type"].as_str().is_some_and(|types| {
        types.split(", ").all(|t| {
            t.starts_with("rcl_interfaces/") || t.starts_with("type_description_interfaces/")
        })
    })
}

/// "2 nodes: /a, /b" (at most 12 names, then "and N more"), the sentence a small model
/// copies into its answer instead of counting a JSON array itself.
pub(super) fn summary(key: &str, names: &[&str]) -> String {
    const SHOWN: usize = 12;
    let noun = if names.len() == 1 {
        key.trim_end_matches('s')
    } else {
        key
    };
    if names.is_empty() {
        return format!("0 {key}");
    }
    let mut text = format!(
        "{} {noun}: {}",
        names.len(),
        names[..names.len().min(SHOWN)].join(", ")
    );
    if names.len() > SHOWN {
        text.push_str(&format!(" and {} more", names.len() - SHOWN));
    }
    text
}

/// `name` made absolute, as shown (`fence::visible`: a zero-width or other hidden
/// character a name was written with is no part of it, here as at the fence).
pub(super) fn absolute(name: &str) -> String {
    let shown = crate::fence::visible(name);
    let name = shown.trim();
    if name.starts_with('/') {
        name.to_string()
    } else {
        format!("/{name}")
    }
}

/// Names close to `wanted`, for "no such X" answers.
pub(super) fn suggest<'a>(wanted: &str, names: impl Iterator<Item = &'a String>) -> Vec<String> {
    let tail = wanted.rsplit('/').next().unwrap_or(wanted).to_lowercase();
    names
        .filter(|n| {
            let n = n.to_lowercase();
            !tail.is_empty()
                && (n.contains(&tail) || tail.contains(n.rsplit('/').next().unwrap_or("")))
        })
        .take(5)
        .cloned()
        .collect()
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct ListArgs {
    /// Only names matching this regular expression; leave out to list all.
    #[serde(default)]
    pub pattern: Option<String>,
    /// Only names under this namespace; leave out to list all.
    #[serde(default)]
    #[schemars(regex(pattern = r"^/[A-Za-z0-9_/]*$"))]
    pub namespace: Option<String>,
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct NodeArgs {
    /// Node name, e.g. "/turtlesim".
    pub node: String,
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct TopicArgs {
    /// Topic name, e.g. "/turtle1/pose".
    pub topic: String,
}

pub(super) fn no_topic(topic: &str, g: &Graph) -> ToolError {
    not_found("topic", topic, g.topics().keys(), "ros_topic_list")
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct ServiceArgs {
    /// Service name, e.g. "/spawn".
    pub service: String,
}

pub(super) fn service_type(g: &Graph, service: &str) -> Result<String, ToolError> {
    let services = g.services();
    match services.get(service).and_then(|t| t.iter().next()) {
        Some(t) => Ok(t.clone()),
        None => Err(not_found(
            "service",
            service,
            services.keys(),
            "ros_service_list",
        )),
    }
}

/// A tool's output, with what the ROS boundary's limits changed in the request (a
/// clamped speed) when they changed something: the model and the trace both see it.
pub(crate) fn with_note(mut out: Value, note: Option<String>) -> Value {
    if let Some(n) = note {
        out["limited"] = json!(n);
    }
    out
}

/// What the mux did with a publish: the agent's input it went to, and whether the
/// operator's own input holds the mux (the message is dropped meanwhile).
pub(crate) fn with_mux(mut out: Value, asked: &str, d: &crate::ros::Delivery) -> Value {
    if d.topic != asked {
        out["mux"] = json!(format!(
            "sent on {}, the agent's input; the operator's own input on {asked} takes priority",
            d.topic
        ));
    }
    if let Some(who) = &d.overridden_by {
        out["overridden_by"] = json!(format!(
            "the operator's input ({who}) holds the mux: this motion is dropped until it ends"
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_listing_names_the_robots_own_services_before_every_nodes_parameter_services() {
        let items = typed(
            "service",
            graph(&[
                (
                    "/arm/describe_parameters",
                    "rcl_interfaces/srv/DescribeParameters",
                ),
                ("/arm/get_parameters", "rcl_interfaces/srv/GetParameters"),
                (
                    "/arm/get_type_description",
                    "type_description_interfaces/srv/GetTypeDescription",
                ),
                ("/arm/list_parameters", "rcl_interfaces/srv/ListParameters"),
                ("/zz/open", "std_srvs/srv/Trigger"),
            ]),
        );
        let f = Filter::new(None, None).unwrap();
        let out = f.listing("services", items);
        let summary = out["summary"].as_str().unwrap();
        assert!(
            summary.starts_with("5 services: /zz/open, /arm/"),
            "{summary}"
        );
        // The listing itself keeps its order.
        assert_eq!(out["services"][0]["service"], "/arm/describe_parameters");
    }

    fn graph(items: &[(&str, &str)]) -> BTreeMap<String, BTreeSet<String>> {
        items
            .iter()
            .map(|(n, t)| (n.to_string(), BTreeSet::from([t.to_string()])))
            .collect()
    }

    #[test]
    fn a_loose_name_resolves_to_the_one_topic_its_words_name() {
        let g = graph(&[
            ("/battery_state", "sensor_msgs/msg/BatteryState"),
            ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"),
            ("/turtle1/pose", "turtlesim/msg/Pose"),
            ("/turtle1/cmd_vel", "geometry_msgs/msg/Twist"),
            ("/turtle1/cmd_vel_agent", "geometry_msgs/msg/Twist"),
            ("/power", "sensor_msgs/msg/BatteryState"),
        ]);
        let r = |w: &str| resolve_loose(w, &g);
        assert_eq!(r("/Battery_Level").as_deref(), Some("/battery_state"));
        assert_eq!(r("/diag").as_deref(), Some("/diagnostics"));
        assert_eq!(r("pose").as_deref(), Some("/turtle1/pose"));
        assert_eq!(r("/turtle/pose").as_deref(), Some("/turtle1/pose"));
        // Two topics equally near, or none: no guess.
        assert_eq!(r("/cmd_vel"), None);
        assert_eq!(r("/temperature"), None);
        assert_eq!(r("/"), None);
    }

    #[test]
    fn words_split_at_punctuation_and_camel_case() {
        assert_eq!(name_words("BatteryState"), ["battery", "state"]);
        assert_eq!(name_words("/turtle1/cmd_vel"), ["turtle1", "cmd", "vel"]);
        assert_eq!(name_words("Battery_Level"), ["battery", "level"]);
    }
}
