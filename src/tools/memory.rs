//! The robot's memory as the model reaches it: `memory_note` keeps a fact the operator
//! states, `memory_recall` finds facts, taught places and past requests about a subject
//! (or the latest requests). Both read and write `store` only; neither moves the robot.
//!
//! What is kept has passed the policy like every call's arguments: a fact that names a
//! name off limits is refused before it reaches here, and what recall returns is
//! redacted by the executor like every result.

use std::sync::Arc;

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use crate::lexicon::folded_words;
use crate::store::{Run, Store};
use crate::tool::{Effect, Package, Tool, ToolContext, ToolError};

/// How a recall shows in the run log's calls.
const NAME_OF_RECALL: &str = "memory_recall(";
/// How a note shows in the run log's calls.
const NAME_OF_NOTE: &str = "memory_note(";
/// How many past requests recall shows.
const RECENT: usize = 8;
/// Words shorter than this do not pick what is recalled ("is", "the", "an").
const MIN_WORD: usize = 4;

/// The memory tools over `store`.
pub fn package(store: Arc<Store>) -> Package {
    Package::new("memory")
        .with(MemoryNote(store.clone()))
        .with(MemoryRecall(store))
}

/// A memory file error as a tool reports it (the place tools' too).
pub(crate) fn failed(e: crate::store::StoreError) -> ToolError {
    ToolError::Failed(e.to_string())
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct NoteArgs {
    /// The fact, in the operator's words ("the charger sits in aisle 3").
    pub fact: String,
}

pub(crate) struct MemoryNote(Arc<Store>);

impl Tool for MemoryNote {
    type Args = NoteArgs;
    const NAME: &'static str = "memory_note";
    const EFFECT: Effect = Effect::Observes;
    const RECORDS: bool = true;
    fn description(&self) -> String {
        "Keep a fact the operator states, across restarts, for memory_recall. Moves nothing.".into()
    }
    /// The fact as the grammar takes it: words the request ends with (`reading::bound`'s
    /// quote), not whatever the model makes of them. The prompt shows `NoteArgs`.
    fn live_parameters(&self) -> Option<Value> {
        let mut schema = crate::tool::schema::schema_for::<NoteArgs>();
        schema["properties"]["fact"][crate::tool::schema::QUOTE] = json!(true);
        Some(schema)
    }
    async fn call(&self, a: NoteArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let fact = a.fact.trim();
        if folded_words(fact).is_empty() {
            return Err(ToolError::InvalidArguments(
                "a fact needs words, e.g. \"the charger is in aisle 3\"".into(),
            ));
        }
        let id = self.0.add_fact(fact).map_err(failed)?;
        Ok(json!({"summary": format!("noted: {fact}"), "id": id, "fact": fact}))
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct RecallArgs {
    /// The subject, in the operator's words ("charger"); left out: the latest.
    #[serde(default)]
    pub about: Option<String>,
}

pub(crate) struct MemoryRecall(Arc<Store>);

/// The words of `text` that pick what is recalled.
fn subject_words(text: &str) -> Vec<String> {
    folded_words(text)
        .into_iter()
        .filter(|w| w.chars().count() >= MIN_WORD)
        .collect()
}

/// How much of `words` `text` mentions (as a word, or a word's start: "charger" finds
/// "chargers"): the letters of the words it holds. A longer word says more of a subject
/// than a short one ("charger" over "where").
fn mentions(text: &str, words: &[String]) -> usize {
    let said = folded_words(text);
    words
        .iter()
        .filter(|w| said.iter().any(|s| s.starts_with(w.as_str())))
        .map(|w| w.chars().count())
        .sum()
}

fn shown_run(r: &Run) -> Value {
    json!({"at": r.at, "request": r.request, "answer": r.answer, "calls": r.calls})
}

/// "at 08:12, asked 'go to the dock': arrived" (the time of day of an ISO stamp).
fn said_run(r: &Run) -> String {
    let time = r.at.get(11..16).unwrap_or(&r.at);
    let answer: String = r.answer.chars().take(100).collect();
    format!(
        "{} {time}: \"{}\" → {answer}",
        r.at.get(..10).unwrap_or(""),
        r.request
    )
}

/// What recall found: facts, places and logged requests.
type Recalled = (Vec<crate::store::Fact>, Vec<crate::store::Place>, Vec<Run>);

impl MemoryRecall {
    /// The latest requests, recalls left out: asking what was done is not something done.
    fn latest(&self) -> Result<Vec<Run>, ToolError> {
        let mut runs = self.0.runs(RECENT).map_err(failed)?;
        runs.retain(|r| !r.calls.contains(NAME_OF_RECALL));
        Ok(runs)
    }

    /// Of `facts`, `places` and the logged requests, those that mention `words` most
    /// (`mentions`): the others are beside the subject. Recalls are left out, and so are
    /// notes (a fact noted is shown as the fact).
    fn mentioning(
        &self,
        words: &[String],
        facts: Vec<crate::store::Fact>,
        places: Vec<crate::store::Place>,
    ) -> Result<Recalled, ToolError> {
        let mut runs: Vec<Run> = Vec::new();
        for w in words {
            for r in self.0.runs_about(w, RECENT).map_err(failed)? {
                if !runs.iter().any(|x| x.id == r.id) {
                    runs.push(r);
                }
            }
        }
        runs.retain(|r| !r.calls.contains(NAME_OF_RECALL) && !r.calls.contains(NAME_OF_NOTE));
        runs.sort_by_key(|r| r.id);
        let fact_score = |f: &crate::store::Fact| mentions(&f.text, words);
        let place_score = |p: &crate::store::Place| {
            std::iter::once(&p.name)
                .chain(&p.aliases)
                .map(|n| mentions(n, words))
                .max()
                .unwrap_or(0)
        };
        let run_score = |r: &Run| mentions(&format!("{} {}", r.request, r.answer), words);
        let best = facts
            .iter()
            .map(fact_score)
            .chain(places.iter().map(place_score))
            .chain(runs.iter().map(run_score))
            .max()
            .unwrap_or(0)
            .max(1);
        let facts = facts
            .into_iter()
            .filter(|f| fact_score(f) >= best)
            .collect();
        let places = places
            .into_iter()
            .filter(|p| place_score(p) >= best)
            .collect();
        runs.retain(|r| run_score(r) >= best);
        let keep = runs.len().saturating_sub(RECENT);
        runs.drain(..keep);
        Ok((facts, places, runs))
    }
}

impl Tool for MemoryRecall {
    type Args = RecallArgs;
    const NAME: &'static str = "memory_recall";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Recall facts the operator stated, taught places and past requests with their outcomes and dates, about a subject or the latest.".into()
    }
    async fn call(&self, a: RecallArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let about = a.about.unwrap_or_default();
        let words = subject_words(&about);
        let facts = self.0.facts().map_err(failed)?;
        let places = self.0.places().map_err(failed)?;
        let (facts, places, mut runs) = if words.is_empty() {
            (facts, Vec::new(), self.latest()?)
        } else {
            self.mentioning(&words, facts, places)?
        };
        let mut said = Vec::new();
        if !facts.is_empty() {
            let each: Vec<&str> = facts.iter().map(|f| f.text.as_str()).collect();
            said.push(format!("told: {}", each.join("; ")));
        }
        for p in &places {
            said.push(format!(
                "place {} at ({:.2}, {:.2}) in {}",
                p.name, p.x, p.y, p.frame
            ));
        }
        if !runs.is_empty() {
            let each: Vec<String> = runs.iter().map(said_run).collect();
            said.push(format!("asked before: {}", each.join("; ")));
        }
        // A subject nothing mentions ("earlier today" names a time, not a subject): the
        // latest requests, after saying so.
        if said.is_empty() && !words.is_empty() {
            runs = self.latest()?;
            let each: Vec<String> = runs.iter().map(said_run).collect();
            said.push(format!("nothing remembered about {}", about.trim()));
            if !each.is_empty() {
                said.push(format!("latest requests: {}", each.join("; ")));
            }
        }
        let summary = if said.is_empty() {
            "nothing is remembered yet".to_string()
        } else {
            said.join(". ")
        };
        Ok(json!({
            "summary": summary,
            "facts": facts,
            "places": places,
            "requests": runs.iter().map(shown_run).collect::<Vec<_>>(),
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::NewRun;

    fn recall(store: &Arc<Store>, about: Option<&str>) -> Value {
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let cx = ToolContext::new(std::time::Duration::from_secs(1));
        rt.block_on(MemoryRecall(store.clone()).call(
            RecallArgs {
                about: about.map(str::to_string),
            },
            &cx,
        ))
        .unwrap()
    }

    #[test]
    fn facts_and_requests_are_recalled_by_subject_or_latest() {
        let dir = tempfile::tempdir().unwrap();
        let store = Arc::new(Store::open(&dir.path().join("m.sqlite"), "sim").unwrap());
        store.add_fact("The chargers are in aisle 3").unwrap();
        store.add_fact("the forklift is blue").unwrap();
        store
            .log_run(&NewRun {
                session: "s",
                request: "drive to the charger",
                calls: "place_go",
                answer: "arrived at the charger",
                finish: "answer",
            })
            .unwrap();
        store
            .log_run(&NewRun {
                session: "s",
                request: "where are you?",
                answer: "at (1, 2)",
                ..Default::default()
            })
            .unwrap();
        // The subject's longest word picks: a past question that shares only "where"
        // is beside it.
        let v = recall(&store, Some("where is the charger?"));
        assert_eq!(v["facts"].as_array().unwrap().len(), 1, "{v}");
        assert_eq!(v["requests"].as_array().unwrap().len(), 1, "{v}");
        assert!(v["summary"].as_str().unwrap().contains("aisle 3"), "{v}");
        // No subject: every fact and the latest requests.
        let v = recall(&store, None);
        assert_eq!(v["facts"].as_array().unwrap().len(), 2, "{v}");
        // A subject nothing mentions says so, and gives the latest requests.
        let v = recall(&store, Some("the kitchen"));
        let said = v["summary"].as_str().unwrap();
        assert!(
            said.starts_with("nothing remembered about the kitchen. latest requests: "),
            "{v}"
        );
        assert!(said.contains("drive to the charger"), "{v}");
    }
}
