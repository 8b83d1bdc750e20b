//! What a request means to the robot's tools, read with the sentence encoder (`embed`):
//! each tool's similarity to a request is the mean of the two best cosines between the
//! request and the tool's examples (those it ships with, those a declared tool file
//! gives, those the robot prompt file adds under `[examples]`), its description counted
//! among them when it has fewer than two. The two best, not the best: one example that
//! happens to share a request's words does not decide alone. Descriptions only fill in:
//! written to say what a tool returns, they share a request's form more than its intent
//! ("List the parameters of a ROS node." is nearer "list all the ROS nodes" than any way an
//! operator asks for the parameters). No
//! word list: a request in other words or another of the encoder's languages finds the
//! tool its examples describe. `select` turns the similarities into the scores that
//! decide which tools are offered and the prior of the first step's tool choice.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex};

use crate::embed::{cosine, Encoder};
use crate::tool::ToolSpec;

/// The sentences' vectors kept (the tools' sentences: a few hundred); past this the
/// cache starts again, so a stream of distinct declared tools cannot grow it without end.
const MAX_CACHED: usize = 8192;

pub struct Meaning {
    encoder: Arc<Encoder>,
    /// Examples the robot prompt file adds, by tool name.
    extra: BTreeMap<String, Vec<String>>,
    cache: Mutex<HashMap<String, Arc<Vec<f32>>>>,
}

impl Meaning {
    pub fn new(encoder: Arc<Encoder>, extra: BTreeMap<String, Vec<String>>) -> Meaning {
        Meaning {
            encoder,
            extra,
            cache: Mutex::new(HashMap::new()),
        }
    }

    fn vector(&self, text: &str) -> Arc<Vec<f32>> {
        let mut cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(v) = cache.get(text) {
            return v.clone();
        }
        if cache.len() >= MAX_CACHED {
            cache.clear();
        }
        let v = Arc::new(self.encoder.encode(text));
        cache.insert(text.to_string(), v.clone());
        v
    }

    /// A tool's sentences: its examples and the prompt file's, and its description when
    /// those are fewer than two.
    fn sentences<'a>(&'a self, spec: &'a ToolSpec) -> Vec<&'a str> {
        let mut out: Vec<&str> = spec
            .examples
            .iter()
            .chain(self.extra.get(&spec.name).into_iter().flatten())
            .map(String::as_str)
            .filter(|s| !s.trim().is_empty())
            .collect();
        if out.len() < 2 && !spec.description.trim().is_empty() {
            out.push(&spec.description);
        }
        out
    }

    /// Encode every tool's sentences now (the first request need not).
    pub fn prepare(&self, specs: &[ToolSpec]) {
        for spec in specs {
            for s in self.sentences(spec) {
                self.vector(s);
            }
        }
    }

    /// Each tool's similarity to `query`: the mean of its two best cosines with its
    /// sentences (-1 to 1; the one when it has one, 0 when none), raised by
    /// `NAME_GAIN` times how much nearer the request is to the robot's nearest name of
    /// a kind the tool takes than to that kind's names on average (`names`: (kind,
    /// name) pairs; a name read as its words, so `/gripper/close` is "gripper close",
    /// which "cierra la pinza" is near).
    pub fn similarities(
        &self,
        query: &str,
        specs: &[ToolSpec],
        names: &[(String, String)],
    ) -> Vec<f64> {
        // Kept like the tools' sentences: each step of a run asks again.
        let q = self.vector(query);
        let mut by_kind: HashMap<&str, Vec<f64>> = HashMap::new();
        for (kind, name) in names {
            let c = f64::from(cosine(&q, &self.vector(&words_of_name(name))));
            by_kind.entry(kind.as_str()).or_default().push(c);
        }
        // How far the nearest name of a kind stands out from the kind's names on
        // average: a word every name of the robot has ("arm" on an arm) raises them
        // all and points at none.
        let nearest: HashMap<&str, f64> = by_kind
            .into_iter()
            .filter(|(_, c)| c.len() > 1)
            .map(|(kind, c)| {
                let max = c.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let mean = c.iter().sum::<f64>() / c.len() as f64;
                (kind, max - mean)
            })
            .collect();
        specs
            .iter()
            .map(|spec| {
                let named = super::select::name_kinds(spec)
                    .filter_map(|k| nearest.get(k).copied())
                    .fold(0.0, f64::max);
                let mut c: Vec<f64> = self
                    .sentences(spec)
                    .into_iter()
                    .map(|s| f64::from(cosine(&q, &self.vector(s))))
                    .collect();
                c.sort_by(|a, b| b.total_cmp(a));
                let best = &c[..c.len().min(2)];
                let own = if best.is_empty() {
                    0.0
                } else {
                    best.iter().sum::<f64>() / best.len() as f64
                };
                own + NAME_GAIN * named
            })
            .collect()
    }
}

/// How much the robot's names weigh beside a tool's own sentences (chosen on the tune
/// halves of both robots' suites, by the encoder's choice alone: 0.3 was best on both,
/// 0.5 lost a turtle case, the nearest name's plain similarity lost arm listings).
const NAME_GAIN: f64 = 0.3;

/// A ROS name as the encoder reads it: its words (`lexicon::name_words`) apart
/// (`sensor_msgs/msg/JointState`: "sensor msgs msg Joint State").
fn words_of_name(name: &str) -> String {
    crate::lexicon::name_words(name).join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_name_reads_as_its_words() {
        assert_eq!(words_of_name("/gripper/close"), "gripper close");
        assert_eq!(words_of_name("/arm/named_pose_cmd"), "arm named pose cmd");
        assert_eq!(
            words_of_name("sensor_msgs/msg/JointState"),
            "sensor msgs msg Joint State"
        );
    }
}
