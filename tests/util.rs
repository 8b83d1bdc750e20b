//! Shared test helpers: where the real weights are, and loading them.

use std::path::PathBuf;

use ferrosa::backend::{self, Backend, BackendKind, LoadOptions};

pub fn models_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models")
}

pub fn model_path(name: &str) -> PathBuf {
    let resolved = ferrosa::models::resolve(Some(name), &models_dir()).unwrap_or_else(|e| {
        panic!(
            "{e}\n(the tests need real weights: run `cargo run --release -- models fetch --all`)"
        )
    });
    resolved.path
}

pub fn load(name: &str, kind: BackendKind, max_context: usize) -> Box<dyn Backend> {
    let path = model_path(name);
    let mut opts = LoadOptions::new(path);
    opts.max_context = max_context;
    opts.family = ferrosa::models::Catalog::load(&models_dir())
        .ok()
        .and_then(|c| c.get(name).map(|e| e.family.clone()));
    backend::load(kind, &opts).unwrap_or_else(|e| panic!("loading {name} with {kind:?}: {e}"))
}

/// Greedy continuation of `prompt` (tokenized with special tokens), `n` tokens.
pub fn greedy(model: &mut dyn Backend, prompt: &str, n: usize) -> Vec<u32> {
    use ferrosa::decode::{generate, Sampler, SamplerConfig, Session};
    let mut ids: Vec<u32> = model.vocab().bos().into_iter().collect();
    ids.extend(model.tokenize(prompt, true).unwrap());
    let mut sampler = Sampler::new(SamplerConfig::default(), model.vocab().len());
    let mut out = Vec::new();
    generate(
        model,
        &mut Session::new(),
        &ids,
        n,
        &mut sampler,
        None,
        |t| {
            out.push(t);
            std::ops::ControlFlow::Continue(())
        },
    )
    .unwrap();
    out
}
