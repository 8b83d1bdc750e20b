//! The persistent prompt cache with the real models: a process that starts from a kept
//! prefix generates exactly what one that evaluated it generates, and an entry that is
//! corrupted, truncated or made under other settings is only a miss.

use std::path::Path;
use std::sync::Arc;

use ferrosa::backend::prompt_cache::DEFAULT_MAX_BYTES;
use ferrosa::backend::PromptCache;
use ferrosa::backend::{Backend, BackendKind};
use ferrosa::decode::Session;
use ferrosa::tool::{Confirm, ToolCall};
use ferrosa::ui::agent::{build_with, Robot};

use crate::util::{agent_args, greedy_after, load, model_path};

/// A stable prefix of some 800 tokens (the text five times over), then a request: the
/// cache keeps the whole prefix (a batch of 512 and a part of one).
const SYSTEM: &str = "You are the on-board assistant of a small inspection robot in a warehouse. You are brief and exact. Use a tool to get facts; never invent them. The robot has a camera, a thermometer and a gas sensor; it drives on four wheels at up to 1 m/s and its battery lasts six hours. Report temperatures in degrees Celsius and distances in meters. Never drive into shelves, people or other robots. The operator may ask for readings, for the robot's health or for motion; answer in one sentence with the values the tools return.";

/// The prompt's tokens (`model`'s template) and where its stable prefix ends.
fn prompt(model: &dyn Backend, request: &str) -> (Vec<u32>, usize) {
    use ferrosa::chat::{ChatMessage, Role};
    use ferrosa::decode::request::render_prompt_split;
    let messages = [
        ChatMessage::new(Role::System, SYSTEM.repeat(5)),
        ChatMessage::new(Role::User, request),
    ];
    let envelope = ferrosa::decode::Envelope::Smollm2;
    render_prompt_split(model, &messages, envelope).unwrap()
}

/// Greedy tokens after `request`'s prompt, through `session` (and its prompt cache).
fn greedy(model: &mut dyn Backend, session: &mut Session, request: &str) -> Vec<u32> {
    let (ids, stable) = prompt(model, request);
    assert!(
        stable > 512,
        "a stable prefix of a whole batch: {stable} tokens"
    );
    session.set_stable(&ids[..stable]);
    greedy_after(model, session, &ids, 24)
}

fn cache(dir: &Path, name: &str, model: &dyn Backend) -> Arc<PromptCache> {
    let sha = ferrosa::models::checksum::sha256_remembered(&model_path(name)).unwrap();
    Arc::new(PromptCache::open(dir, &sha, model, DEFAULT_MAX_BYTES).unwrap())
}

/// Every entry file in `dir`.
fn entries(dir: &Path) -> Vec<std::path::PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "kv"))
        .collect()
}

/// What is done to an entry file's bytes.
type Damage = dyn Fn(&mut Vec<u8>);

/// Per model: evaluated from nothing, stored, restored in a fresh load; then damaged
/// entries (a flipped byte, a cut file) and another context size, each a miss that
/// generates the same.
fn same_from_disk(name: &str) {
    let dir = tempfile::tempdir().unwrap();
    let request = "What is the temperature in aisle 4?";
    let fresh = || load(name, BackendKind::Llama, 2048);

    let mut m = fresh();
    let stable = prompt(m.as_ref(), request).1;
    let reference = greedy(m.as_mut(), &mut Session::new(), request);

    let mut m = fresh();
    let c = cache(dir.path(), name, m.as_ref());
    let stored = greedy(m.as_mut(), &mut Session::with_cache(c.clone()), request);
    c.flush();
    assert_eq!(c.counts().0, 0, "{name}: nothing to restore the first time");
    assert_eq!(c.counts().1, stable, "{name}: the stable prefix is stored");
    assert_eq!(stored, reference, "{name}: storing changes nothing");
    drop(c);

    let mut m = fresh();
    let c = cache(dir.path(), name, m.as_ref());
    let restored = greedy(m.as_mut(), &mut Session::with_cache(c.clone()), request);
    assert_eq!(c.counts().0, stable, "{name}: a fresh load restores it");
    assert_eq!(
        restored, reference,
        "{name}: generated from the restored prefix as from the evaluated one"
    );
    drop(c);

    let damages: [(&str, &Damage); 2] = [
        ("a flipped byte", &|b| {
            let at = b.len() / 2;
            b[at] ^= 0x40;
        }),
        ("a cut file", &|b| b.truncate(b.len() * 2 / 3)),
    ];
    for (what, damage) in damages {
        for path in entries(dir.path()) {
            let mut bytes = std::fs::read(&path).unwrap();
            damage(&mut bytes);
            std::fs::write(&path, bytes).unwrap();
        }
        let mut m = fresh();
        let c = cache(dir.path(), name, m.as_ref());
        let again = greedy(m.as_mut(), &mut Session::with_cache(c.clone()), request);
        c.flush();
        assert_eq!(c.counts().0, 0, "{name}, {what}: a miss");
        assert_eq!(again, reference, "{name}, {what}: the same answer");
        assert_eq!(
            entries(dir.path()).len(),
            1,
            "{name}, {what}: the damaged entry replaced by a good one"
        );
    }

    // Another context size is another key: the entry is not even listed.
    let mut m = load(name, BackendKind::Llama, 1024);
    let c = cache(dir.path(), name, m.as_ref());
    assert!(c.entries().is_empty(), "{name}: another key sees no entry");
    let other = greedy(m.as_mut(), &mut Session::with_cache(c.clone()), request);
    assert_eq!(c.counts().0, 0);
    assert!(!other.is_empty());
}

#[test]
#[ignore = "needs the model weights: cargo test --release -- --include-ignored"]
fn a_fresh_load_from_the_cache_generates_as_evaluating_would() {
    same_from_disk("smollm2-135m");
    same_from_disk("gemma3-270m");
}

struct Yes;
impl Confirm for Yes {
    fn confirm(&self, _: &ToolCall) -> bool {
        true
    }
}

#[test]
#[ignore = "needs the model weights: cargo test --release -- --include-ignored"]
fn the_agent_starting_from_the_cache_runs_as_from_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let mut args = agent_args(Robot::None, true);
    args.model.prompt_cache = false;
    let run = |with_cache: bool| {
        let estop = ferrosa::estop::EStop::new();
        let mut agent = build_with(&args, Arc::new(Yes), None, estop).unwrap();
        let c = cache(dir.path(), "smollm2-135m", agent.backend());
        if with_cache {
            agent = agent.with_prompt_cache(c.clone());
        }
        let r = agent
            .ask("convert 3 meters to feet", &mut |_| {})
            .expect("the agent runs");
        c.flush();
        let calls: Vec<String> = r
            .steps
            .iter()
            .map(|s| format!("{} {}", s.name, s.arguments))
            .collect();
        eprintln!("cache {with_cache}: {calls:?} → {}", r.answer);
        (calls, r.answer, c.counts())
    };
    let (calls, answer, _) = run(false);
    assert!(answer.contains("9.84"), "{answer}");
    let (calls_1, answer_1, (restored, stored)) = run(true);
    assert_eq!(restored, 0);
    assert!(stored > 64, "the first step's prefix is kept");
    let (calls_2, answer_2, (restored, _)) = run(true);
    assert!(restored > 64, "a new agent starts from it");
    assert_eq!((&calls_1, &answer_1), (&calls, &answer));
    assert_eq!((&calls_2, &answer_2), (&calls, &answer));
}
