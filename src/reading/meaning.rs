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
    /// Examples the robot prompt file gives for one of the robot's names (a key that
    /// starts with `/`: "/gripper/close" = ["grip the part"]), by the name without its
    /// leading slash.
    named: BTreeMap<String, Vec<String>>,
    /// The robot prompt file's prose, cut into clauses (`clauses`): what it says of each
    /// of the robot's names.
    about: Vec<String>,
    cache: Mutex<HashMap<String, Arc<Vec<f32>>>>,
}

impl Meaning {
    /// `extra`: the robot prompt file's examples, by tool name, or by one of the
    /// robot's names when the key starts with `/`. `about`: the robot prompt file's
    /// prose (its sections joined), which describes the robot's names ("/gripper/state
    /// gives its opening and grip force").
    pub fn new(
        encoder: Arc<Encoder>,
        extra: BTreeMap<String, Vec<String>>,
        about: &str,
    ) -> Meaning {
        let (named, extra): (BTreeMap<_, _>, BTreeMap<_, _>) =
            extra.into_iter().partition(|(k, _)| k.starts_with('/'));
        let named = named
            .into_iter()
            .map(|(k, v)| {
                let v = v.into_iter().filter(|e| !e.trim().is_empty()).collect();
                (k.trim_start_matches('/').to_string(), v)
            })
            .collect();
        Meaning {
            encoder,
            extra,
            named,
            about: clauses(about),
            cache: Mutex::new(HashMap::new()),
        }
    }

    /// The examples the robot prompt file gives for `name`.
    fn named_examples(&self, name: &str) -> &[String] {
        self.named
            .get(name.trim_start_matches('/'))
            .map_or(&[], Vec::as_slice)
    }

    /// The cosine of `q` with `name` read as its words, or with the nearest example the
    /// robot prompt file gives for it when that is nearer.
    fn name_cosine(&self, q: &[f32], name: &str) -> f64 {
        let own = f64::from(cosine(q, &self.vector(&words_of_name(name))));
        self.named_examples(name)
            .iter()
            .map(|s| f64::from(cosine(q, &self.vector(s))))
            .fold(own, f64::max)
    }

    /// How near `query` is to the robot's `name`: the best cosine of the request with the
    /// name read as its words, with the examples the robot prompt file gives for it,
    /// and with each clause of the robot prompt file that writes the name ("what the
    /// arm is doing on /arm/state"). `bound` breaks a tie of the names a request's
    /// words point at with it, and chooses among names they point at none of.
    pub(crate) fn name_similarity(&self, query: &str, name: &str) -> f64 {
        let q = self.vector(query);
        self.about
            .iter()
            .filter_map(|c| said_of(c, name))
            .map(|s| f64::from(cosine(&q, &self.vector(&s))))
            .fold(self.name_cosine(&q, name), f64::max)
    }

    /// The cosine between `query` and the nearest of `sentences` (-inf when none).
    pub fn nearest(&self, query: &str, sentences: &[String]) -> f64 {
        let q = self.vector(query);
        sentences
            .iter()
            .map(|s| f64::from(cosine(&q, &self.vector(s))))
            .fold(f64::NEG_INFINITY, f64::max)
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
        for s in self.named.values().flatten() {
            self.vector(s);
        }
    }

    /// Each tool's similarity to `query`: the mean of its two best cosines with its
    /// sentences (-1 to 1; the one when it has one, 0 when none), raised by
    /// `NAME_GAIN` times how much nearer the request is to the robot's nearest name of
    /// a kind the tool takes than to that kind's names on average (`names`: (kind,
    /// name) pairs; a name read as its words, so `/gripper/close` is "gripper close",
    /// which "cierra la pinza" is near, or as the robot file's examples for it).
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
            let c = self.name_cosine(&q, name);
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

/// `text` cut where a sentence or a clause ends (a `.`, `;` or `:` before a space): a
/// prompt file describes one name or a few in each.
fn clauses(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut start = 0;
    let chars: Vec<(usize, char)> = text.char_indices().collect();
    for (i, &(at, c)) in chars.iter().enumerate() {
        let next_space = chars.get(i + 1).is_none_or(|(_, n)| n.is_whitespace());
        if matches!(c, '.' | ';' | ':') && next_space {
            out.push(text[start..at].trim().to_string());
            start = at + c.len_utf8();
        }
    }
    out.push(text[start..].trim().to_string());
    out.retain(|c| !c.is_empty());
    out
}

/// What `clause` says of the ROS `name` it writes: the words between it and the name
/// written before it ("motor temperatures and currents on /diagnostics"), or when
/// those are fewer than two, the words after it up to the next name
/// ("/gripper/state gives its opening and grip force"). A clause often describes
/// several names in turn; each keeps its own words. `None` when the clause does not
/// write the name whole (only as the start of a longer one).
fn said_of(clause: &str, name: &str) -> Option<String> {
    let names = ros_names(clause);
    let i = names.iter().position(|(_, n)| *n == name)?;
    let start = names[i].0;
    let end = start + name.len();
    let prev_end = i
        .checked_sub(1)
        .map_or(0, |j| names[j].0 + names[j].1.len());
    let next_start = names.get(i + 1).map_or(clause.len(), |(at, _)| *at);
    let trim = |t: &str| {
        t.trim_matches(|c: char| c.is_whitespace() || matches!(c, ',' | ';' | '.' | ':'))
            .to_string()
    };
    let before = trim(&clause[prev_end..start]);
    Some(if before.split_whitespace().count() >= 2 {
        format!("{before} {name}")
    } else {
        format!("{name} {}", trim(&clause[end..next_start]))
    })
}

/// The ROS names `text` writes (words that start with `/`), with where each starts.
fn ros_names(text: &str) -> Vec<(usize, &str)> {
    let part = |c: char| c.is_alphanumeric() || c == '_' || c == '/';
    let mut out = Vec::new();
    let mut iter = text.char_indices().peekable();
    while let Some((at, c)) = iter.next() {
        let after_space = text[..at].chars().next_back().is_none_or(|b| !part(b));
        if c != '/' || !after_space {
            continue;
        }
        let mut end = at + 1;
        while let Some(&(j, d)) = iter.peek() {
            if !part(d) {
                break;
            }
            end = j + d.len_utf8();
            iter.next();
        }
        let word = text[at..end].trim_end_matches('/');
        if word.len() > 1 {
            out.push((at, word));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_prompt_file_is_read_as_clauses_that_name_things() {
        let about =
            clauses("Lights: /lamp/on turns them on; /lamp/level is 0.5 now. The dock is /dock.");
        assert_eq!(
            about,
            [
                "Lights",
                "/lamp/on turns them on",
                "/lamp/level is 0.5 now",
                "The dock is /dock"
            ]
        );
        // Each name keeps the words said of it.
        assert_eq!(
            said_of(&about[1], "/lamp/on").as_deref(),
            Some("/lamp/on turns them on")
        );
        assert_eq!(said_of(&about[1], "/lamp"), None);
        let shared = "the pose is on /arm/pose, what the arm does on /arm/state";
        assert_eq!(
            said_of(shared, "/arm/state").as_deref(),
            Some("what the arm does on /arm/state")
        );
        assert_eq!(
            said_of(shared, "/arm/pose").as_deref(),
            Some("the pose is on /arm/pose")
        );
    }

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
