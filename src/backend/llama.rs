//! The llama.cpp runtime through `llama-cpp-2`: mmap load, batched prompt evaluation,
//! last-position logits, and a KV cache trimmed to a kept prefix so a later turn only
//! evaluates its new tokens.
//!
//! Tokenization is llama.cpp's own; the vocabulary table is read back from it so the
//! rest of ferrosa (detokenization, grammars) sees exactly what llama.cpp samples.

use std::mem::ManuallyDrop;
use std::num::NonZeroU32;
use std::sync::{Arc, OnceLock};

use llama_cpp_2::context::params::LlamaContextParams;
use llama_cpp_2::context::session::LlamaStateSeqFlags;
use llama_cpp_2::context::LlamaContext;
use llama_cpp_2::llama_backend::LlamaBackend;
use llama_cpp_2::llama_batch::LlamaBatch;
use llama_cpp_2::model::params::LlamaModelParams;
use llama_cpp_2::model::LlamaLoraAdapter;
use llama_cpp_2::model::LlamaModel;
use llama_cpp_2::token::LlamaToken;
use llama_cpp_2::token_type::LlamaTokenAttr;

use super::vocab::{TokenKind, Vocab};
use super::{Backend, BackendError, ChatTemplate, Gguf, LoadOptions, TokenId, Tokenize};

const NAME: &str = "llama.cpp";
/// Most branches one batch evaluates side by side (`Backend::branches`).
const BRANCHES: usize = 15;
/// Tokens llama.cpp evaluates per graph. Its compute buffer grows with this times the
/// context (the attention scores of every query against every cached key), and what a
/// deep prompt touches of it stays resident: 110 MiB at 512 and a 4,096-token context,
/// 28 MiB at 128 (the agent's 8,192: 144 and 36 MiB for the scores alone). A request's
/// own tokens (tens) fit in one graph either way; a long prompt is split, which costs
/// it speed (llama-bench here, noisy: pp2048 162–179 tok/s at 128 against 168–198 at
/// 512; pp4096 138 against 172).
pub const UBATCH: usize = 128;

fn eval(e: impl std::fmt::Display) -> BackendError {
    BackendError::Eval {
        backend: NAME,
        reason: e.to_string(),
    }
}

/// llama.cpp's global state may be initialised once per process.
fn runtime() -> Result<&'static LlamaBackend, BackendError> {
    static RUNTIME: OnceLock<Result<LlamaBackend, String>> = OnceLock::new();
    RUNTIME
        .get_or_init(|| {
            // llama.cpp prints to stderr by default; route it through tracing, where the
            // default filter keeps only warnings.
            llama_cpp_2::send_logs_to_tracing(llama_cpp_2::LogOptions::default());
            LlamaBackend::init().map_err(|e| e.to_string())
        })
        .as_ref()
        .map_err(|e| BackendError::Load {
            backend: NAME,
            path: Default::default(),
            reason: e.clone(),
        })
}

pub(crate) struct LlamaCpp {
    // Field order is drop order: the context borrows the model, so it goes first.
    ctx: ManuallyDrop<LlamaContext<'static>>,
    /// Shared with tokenizers handed out by `tokenizer()`; the context borrows it through
    /// a `'static` reference that is valid because this Arc is dropped after the context.
    model: Arc<LlamaModel>,
    batch: LlamaBatch<'static>,
    /// A batch whose tokens may each be in the main sequence and every branch
    /// (`Backend::branches`).
    branch_batch: LlamaBatch<'static>,
    /// Most branches one batch holds (sequences besides the main one).
    max_branches: usize,
    n_batch: usize,
    n_ctx: usize,
    threads: usize,
    /// Tokens in the KV cache.
    n_past: usize,
    logits: Vec<f32>,
    vocab: Vocab,
    template: ChatTemplate,
    /// The tool chooser's adapter (`LoadOptions::adapter`), owned by the model and
    /// switched on only while `chooser_branches` evaluates.
    adapter: Option<LlamaLoraAdapter>,
}

impl Drop for LlamaCpp {
    fn drop(&mut self) {
        // SAFETY: the context is dropped before this value's Arc of the model it borrows
        // (fields drop after `drop` returns), and it is not used again.
        unsafe { ManuallyDrop::drop(&mut self.ctx) };
    }
}

/// llama.cpp's tokenizer, usable from any thread while the backend decodes: tokenizing
/// reads only the immutable vocabulary.
struct LlamaTokenizer(Arc<LlamaModel>);

impl Tokenize for LlamaTokenizer {
    fn tokenize(&self, text: &str, special: bool) -> Vec<TokenId> {
        self.0
            .vocab()
            .tokenize(text.as_bytes(), false, special)
            .into_iter()
            .map(|t| t.0 as TokenId)
            .collect()
    }
}

impl LlamaCpp {
    /// Before `more` new tokens (`tokens`) are evaluated after the first `keep` cached
    /// ones: refuse what does not fit the context or the vocabulary, and drop the cache
    /// past `keep`. Returns `keep` as the cache can hold it.
    fn make_room<'t>(
        &mut self,
        keep: usize,
        more: usize,
        tokens: impl Iterator<Item = &'t TokenId>,
    ) -> Result<usize, BackendError> {
        let (held, limit, n_vocab) = (self.n_past, self.n_ctx, self.vocab.len());
        let keep = super::admit(keep, held, more, tokens, limit, n_vocab)?;
        if keep < self.n_past {
            self.ctx
                .kv_cache_seq_rm(0, Some(keep as u32), None)
                .map_err(eval)?;
        }
        self.n_past = keep;
        Ok(keep)
    }

    /// Evaluate `lead` and `group` (at most `max_branches` branches) in one batch as a
    /// tree after the main sequence's first `keep` cells: `lead` goes into the main
    /// sequence and every branch's, branch `b` is sequence `b + 1` after it, and a token
    /// the branches share with their leading tokens is evaluated once, in each of their
    /// sequences. Returns the logits after `lead`'s last token, if it has one. The caller
    /// removes the branches' sequences after.
    fn branch_group(
        &mut self,
        keep: usize,
        lead: &[TokenId],
        group: &[&[TokenId]],
        each: &mut dyn FnMut(usize, usize, &[f32]),
    ) -> Result<Option<Vec<f32>>, BackendError> {
        // The tree: each distinct leading part of a branch, with the sequences sharing
        // it, parents before children; and for each branch, its tokens' nodes.
        let mut nodes: Vec<(&[TokenId], Vec<i32>)> = Vec::new();
        let mut path: Vec<Vec<usize>> = Vec::with_capacity(group.len());
        for (b, tokens) in group.iter().enumerate() {
            let mut at = Vec::with_capacity(tokens.len());
            for j in 0..tokens.len() {
                let part = &tokens[..=j];
                let n = match nodes.iter().position(|(k, _)| *k == part) {
                    Some(n) => n,
                    None => {
                        nodes.push((part, Vec::new()));
                        nodes.len() - 1
                    }
                };
                nodes[n].1.push(b as i32 + 1);
                at.push(n);
            }
            path.push(at);
        }
        debug_assert!(
            lead.len() + nodes.len() <= self.n_batch,
            "a group fits a batch"
        );
        if lead.is_empty() && nodes.is_empty() {
            return Ok(None);
        }
        for seq in 1..=group.len() as i32 {
            self.ctx
                .kv_cache_seq_cp(0, seq, None, Some(keep as u32))
                .map_err(eval)?;
        }
        self.branch_batch.clear();
        // llama-cpp-2 does not check a token's sequence count against the batch's
        // (`branch_batch` has room for the main sequence and `max_branches`).
        if group.len() > self.max_branches {
            return Err(eval("more branches than a batch holds"));
        }
        let every: Vec<i32> = (0..=group.len() as i32).collect();
        for (i, &t) in lead.iter().enumerate() {
            let pos = (keep + i) as i32;
            let last = i + 1 == lead.len();
            self.branch_batch
                .add(LlamaToken(t as i32), pos, &every, last)
                .map_err(eval)?;
        }
        let start = keep + lead.len();
        for (part, seqs) in &nodes {
            let (&t, pos) = (
                part.last().expect("a node has a token"),
                start + part.len() - 1,
            );
            self.branch_batch
                .add(LlamaToken(t as i32), pos as i32, seqs, true)
                .map_err(eval)?;
        }
        if let Err(e) = self.ctx.decode(&mut self.branch_batch) {
            // The main sequence may hold part of `lead`: drop it so `n_past` stays true.
            if !lead.is_empty() {
                let _ = self.ctx.kv_cache_seq_rm(0, Some(keep as u32), None);
            }
            return Err(eval(e));
        }
        self.n_past = start;
        let n_vocab = self.vocab.len();
        let root = (!lead.is_empty())
            .then(|| self.ctx.get_logits_ith(lead.len() as i32 - 1)[..n_vocab].to_vec());
        let first = lead.len();
        for (b, at) in path.iter().enumerate() {
            for (j, &n) in at.iter().enumerate() {
                each(
                    b,
                    j,
                    &self.ctx.get_logits_ith((first + n) as i32)[..n_vocab],
                );
            }
        }
        Ok(root)
    }

    pub fn load(gguf: &Gguf, opts: &LoadOptions) -> Result<LlamaCpp, BackendError> {
        let rt = runtime()?;
        let fail = |reason: String| BackendError::Load {
            backend: NAME,
            path: opts.path.clone(),
            reason,
        };
        let template = ChatTemplate::for_model(gguf, opts.family.as_deref())?;
        let params = LlamaModelParams::default().with_use_mmap(true);
        let mut model = LlamaModel::load_from_file(rt, &opts.path, &params).map_err(|e| {
            fail(format!(
                "{e} (architecture '{}'; is it supported by this llama.cpp?)",
                gguf.architecture().unwrap_or("unknown")
            ))
        })?;
        // The model owns the adapter once loaded (llama.cpp frees it with the model).
        let adapter = match &opts.adapter {
            Some(path) => Some(model.lora_adapter_init(path).map_err(|e| {
                fail(format!(
                    "the adapter {} does not load over this model: {e} (it was trained for another model, or the file is damaged; run without it with --adapter none)",
                    path.display()
                ))
            })?),
            None => None,
        };
        let model = Arc::new(model);
        // SAFETY: the Arc's allocation does not move and outlives the context: `LlamaCpp`
        // holds a clone and drops the context first (see Drop).
        let model_ref: &'static LlamaModel = unsafe { &*Arc::as_ptr(&model) };

        let train_ctx = model_ref.n_ctx_train() as usize;
        let n_ctx = opts.max_context.min(train_ctx.max(1)).max(16);
        let n_batch = opts.batch.clamp(1, n_ctx);
        let threads = opts.threads.max(1) as i32;
        // llama.cpp keeps no more sequences than a batch has outputs.
        let branches = BRANCHES.min(n_batch - 1);
        let cparams = LlamaContextParams::default()
            .with_n_ctx(NonZeroU32::new(n_ctx as u32))
            .with_n_batch(n_batch as u32)
            .with_n_ubatch(n_batch.min(UBATCH) as u32)
            .with_n_threads(threads)
            .with_n_threads_batch(threads)
            // Sliding-window layers (Gemma 3) keep every position so a kept prefix can be
            // extended after its tail is dropped; a window-sized cache would have evicted it.
            .with_swa_full(true)
            // Flash attention off: on CPU its one-token step grows with the depth about
            // three times as fast (SmolLM2 at 1,800 cached tokens: 40 ms a token with it,
            // 13 ms without), for 10% faster prompts. The agent's turns are mostly
            // one-token steps deep in a long prompt.
            .with_flash_attention_policy(0)
            // Branches (`Backend::branches`) are sequences beside the main one, sharing
            // its cells: one cache of n_ctx cells for all of them.
            .with_n_seq_max(1 + branches as u32)
            .with_kv_unified(true);
        let ctx = model_ref
            .new_context(rt, cparams)
            .map_err(|e| fail(format!("cannot create a context of {n_ctx} tokens: {e}")))?;
        let vocab = read_vocab(model_ref);
        Ok(LlamaCpp {
            ctx: ManuallyDrop::new(ctx),
            model,
            batch: LlamaBatch::new(n_batch, 1),
            // A token shared by every branch is in the main sequence and all of theirs.
            branch_batch: LlamaBatch::new(n_batch, branches as i32 + 1),
            max_branches: branches,
            n_batch,
            n_ctx,
            threads: threads as usize,
            n_past: 0,
            logits: vec![0.0; vocab.len()],
            vocab,
            template,
            adapter,
        })
    }

    /// `branch_group` over `branches` in groups that each fit a batch, `lead` riding in
    /// the first; each group's sequences are removed after it. Returns the logits after
    /// `lead`, if it has tokens.
    fn grouped(
        &mut self,
        keep: usize,
        lead: &[TokenId],
        branches: &[&[TokenId]],
        each: &mut dyn FnMut(usize, usize, &[f32]),
    ) -> Result<Option<Vec<f32>>, BackendError> {
        let (mut keep, mut lead, mut root) = (keep, lead, None);
        let mut start = 0;
        while start < branches.len() {
            let mut end = start;
            let mut len = lead.len();
            while end < branches.len()
                && end - start < self.max_branches
                && (end == start || len + branches[end].len() <= self.n_batch)
            {
                len += branches[end].len();
                end += 1;
            }
            let group = &branches[start..end];
            let result = self.branch_group(keep, lead, group, &mut |b, j, l| each(start + b, j, l));
            for s in 1..=group.len() {
                let _ = self.ctx.kv_cache_seq_rm(s as i32, None, None);
            }
            if let Some(r) = result? {
                root = Some(r);
            }
            (keep, lead) = (keep + lead.len(), &[]);
            start = end;
        }
        Ok(root)
    }
}

fn read_vocab(model: &LlamaModel) -> Vocab {
    let v = model.vocab();
    let n = v.n_tokens().max(0) as usize;
    let mut pieces = Vec::with_capacity(n);
    let mut kinds = Vec::with_capacity(n);
    let mut eog = Vec::new();
    for i in 0..n {
        let t = LlamaToken(i as i32);
        pieces.push(v.token_to_piece(t, true, None));
        let attr = v.attr(t);
        kinds.push(if attr.contains(LlamaTokenAttr::Control) {
            TokenKind::Control
        } else if attr.contains(LlamaTokenAttr::UserDefined) {
            TokenKind::UserDefined
        } else if attr.contains(LlamaTokenAttr::Byte) {
            TokenKind::Byte
        } else if attr.contains(LlamaTokenAttr::Unused) {
            TokenKind::Unused
        } else if attr.contains(LlamaTokenAttr::Unknown) {
            TokenKind::Unknown
        } else {
            TokenKind::Normal
        });
        if v.is_eog(t) {
            eog.push(i as TokenId);
        }
    }
    let bos = v.bos();
    let bos = (bos.0 >= 0).then_some(bos.0 as TokenId);
    Vocab::new(pieces, kinds, eog, bos, v.should_add_bos())
}

impl Backend for LlamaCpp {
    fn name(&self) -> &'static str {
        NAME
    }

    fn vocab(&self) -> &Vocab {
        &self.vocab
    }

    fn chat_template(&self) -> &ChatTemplate {
        &self.template
    }

    fn context_len(&self) -> usize {
        self.n_ctx
    }

    fn tokenize(&self, text: &str, special: bool) -> Result<Vec<TokenId>, BackendError> {
        Ok(LlamaTokenizer(self.model.clone()).tokenize(text, special))
    }

    fn tokenizer(&self) -> Arc<dyn Tokenize> {
        Arc::new(LlamaTokenizer(self.model.clone()))
    }

    fn forward(&mut self, keep: usize, tokens: &[TokenId]) -> Result<&mut [f32], BackendError> {
        let _span = tracing::trace_span!("forward", n = tokens.len()).entered();
        super::forward_last(self, |b| &mut b.logits, keep, tokens)?;
        Ok(&mut self.logits)
    }

    fn forward_each(
        &mut self,
        keep: usize,
        tokens: &[TokenId],
        from: usize,
        each: &mut dyn FnMut(usize, &[f32]),
    ) -> Result<(), BackendError> {
        let _span = tracing::trace_span!("forward_each", n = tokens.len()).entered();
        if tokens.is_empty() {
            return Err(eval("nothing to evaluate: no tokens given"));
        }
        self.make_room(keep, tokens.len(), tokens.iter())?;
        let n_vocab = self.vocab.len();
        for (c, chunk) in tokens.chunks(self.n_batch).enumerate() {
            let offset = c * self.n_batch;
            self.batch.clear();
            let last = chunk.len() - 1;
            for (i, &t) in chunk.iter().enumerate() {
                let wanted = offset + i >= from || i == last;
                self.batch
                    .add(LlamaToken(t as i32), (self.n_past + i) as i32, &[0], wanted)
                    .map_err(eval)?;
            }
            if let Err(e) = self.ctx.decode(&mut self.batch) {
                // The cache may hold part of this chunk; drop it so `n_past` stays true.
                let _ = self.ctx.kv_cache_seq_rm(0, Some(self.n_past as u32), None);
                return Err(eval(e));
            }
            self.n_past += chunk.len();
            for i in (0..chunk.len()).filter(|i| offset + i >= from) {
                each(offset + i, &self.ctx.get_logits_ith(i as i32)[..n_vocab]);
            }
        }
        Ok(())
    }

    fn batch_len(&self) -> usize {
        self.n_batch
    }

    fn branches(
        &mut self,
        keep: usize,
        shared: &[TokenId],
        branches: &[&[TokenId]],
        each: &mut dyn FnMut(usize, usize, &[f32]),
    ) -> Result<Vec<f32>, BackendError> {
        let _span = tracing::trace_span!("branches", n = branches.len()).entered();
        if shared.is_empty() {
            return Err(eval("branches called with no shared tokens"));
        }
        let too_long = branches.iter().any(|b| b.len() > self.n_batch);
        if self.max_branches == 0 || branches.is_empty() || too_long {
            return super::branches_one_by_one(self, keep, shared, branches, each);
        }
        // `shared` rides in the first group's batch when it leaves room for any branch;
        // a longer one is a prompt of its own first.
        let longest = branches.iter().map(|b| b.len()).max().unwrap_or(0);
        let (mut root, mut lead, mut keep) = (None, shared, keep);
        if shared.len() + longest > self.n_batch {
            root = Some(self.forward(keep, shared)?.to_vec());
            (lead, keep) = (&[], keep + shared.len());
        }
        // Every cell at once, at most: shared tokens take one.
        let total = lead.len() + branches.iter().map(|b| b.len()).sum::<usize>();
        let tokens = lead.iter().chain(branches.iter().flat_map(|b| b.iter()));
        let keep = self.make_room(keep, total, tokens)?;
        if let Some(r) = self.grouped(keep, lead, branches, each)? {
            root = Some(r);
        }
        Ok(root.expect("the first group carries `shared`, or it was evaluated first"))
    }

    fn has_chooser(&self) -> bool {
        self.adapter.is_some()
    }

    fn chooser_branches(
        &mut self,
        keep: usize,
        branches: &[&[TokenId]],
        each: &mut dyn FnMut(usize, usize, &[f32]),
    ) -> Result<bool, BackendError> {
        let fits = branches
            .iter()
            .all(|b| !b.is_empty() && b.len() <= self.n_batch);
        // The branches' cells beside the main sequence's, in the one cache.
        let cells = self.n_past + branches.iter().map(|b| b.len()).sum::<usize>();
        if self.adapter.is_none()
            || self.max_branches == 0
            || !fits
            || keep >= self.n_past
            || cells > self.n_ctx
        {
            return Ok(false);
        }
        let _span = tracing::trace_span!("chooser", n = branches.len()).entered();
        let held = self.n_past;
        let adapter = self.adapter.as_mut().expect("checked above");
        self.ctx.lora_adapter_set(adapter, 1.0).map_err(|e| {
            eval(format!(
                "cannot switch the adapter on: {e} (run with --adapter none)"
            ))
        })?;
        let result = self.grouped(keep, &[], branches, each).map(|_| ());
        // Off again whatever happened: every other evaluation is the base model's. With
        // no lead, the main sequence was not written: it holds what it held.
        let adapter = self.adapter.as_mut().expect("checked above");
        let off = self.ctx.lora_adapter_remove(adapter);
        self.n_past = held;
        if let Err(e) = off {
            // An adapter that may still be on is never used again.
            self.adapter = None;
            return Err(eval(format!(
                "cannot switch the adapter off: {e}; the chooser reads without it from now on"
            )));
        }
        result?;
        Ok(true)
    }

    fn snapshot_key(&self) -> Option<String> {
        Some(format!(
            "{NAME} llama-cpp-2 {LLAMA_CPP_2} n_ctx {} n_batch {} threads {} kv f16 unified, flash attention off",
            self.n_ctx, self.n_batch, self.threads
        ))
    }

    fn snapshot(&self) -> Result<Vec<u8>, BackendError> {
        let flags = LlamaStateSeqFlags::empty();
        let size = self.ctx.state_seq_get_size_ext(0, flags);
        let mut out = vec![0u8; size];
        // SAFETY: `out` holds the size llama.cpp just reported for this sequence.
        let n = unsafe { self.ctx.state_seq_get_data_ext(out.as_mut_ptr(), 0, flags) };
        if n != size {
            return Err(eval(format!(
                "the cache's snapshot took {n} bytes, not {size}"
            )));
        }
        Ok(out)
    }

    fn restore(&mut self, snapshot: &[u8], tokens: usize) -> Result<(), BackendError> {
        if tokens == 0 || tokens > self.n_ctx {
            return Err(eval(format!("a snapshot of {tokens} tokens does not fit")));
        }
        let _ = self.ctx.kv_cache_seq_rm(0, None, None);
        self.n_past = 0;
        // SAFETY: llama.cpp reads at most `snapshot.len()` bytes and checks the layout
        // it reads (layers, cells, types) against this context, failing rather than
        // reading out of bounds. The caller hands over only bytes a `snapshot` of this
        // runtime produced under the same key (checked by hash before they come here).
        let ok = unsafe {
            self.ctx
                .state_seq_set_data_ext(snapshot, 0, LlamaStateSeqFlags::empty())
        };
        if !ok {
            let _ = self.ctx.kv_cache_seq_rm(0, None, None);
            return Err(eval("llama.cpp refused the snapshot"));
        }
        self.n_past = tokens;
        Ok(())
    }
}

/// The llama-cpp-2 version this binary links (a snapshot's layout is llama.cpp's).
const LLAMA_CPP_2: &str = "0.1.160";

/// A model's vocabulary and chat template without its weights (llama.cpp's vocab-only
/// load: the tensors are not read): what the remote engine renders and tokenizes prompts
/// with while a server runs the model. It cannot evaluate anything.
pub(crate) struct LlamaVocab {
    model: Arc<LlamaModel>,
    vocab: Vocab,
    template: ChatTemplate,
    n_ctx: usize,
}

impl LlamaVocab {
    pub fn load(gguf: &Gguf, opts: &LoadOptions) -> Result<LlamaVocab, BackendError> {
        let rt = runtime()?;
        let template = ChatTemplate::for_model(gguf, opts.family.as_deref())?;
        let params = LlamaModelParams::default().with_vocab_only(true);
        let model = LlamaModel::load_from_file(rt, &opts.path, &params).map_err(|e| {
            BackendError::Load {
                backend: NAME,
                path: opts.path.clone(),
                reason: format!("cannot read its vocabulary: {e}"),
            }
        })?;
        let vocab = read_vocab(&model);
        Ok(LlamaVocab {
            model: Arc::new(model),
            vocab,
            template,
            n_ctx: opts.max_context.max(16),
        })
    }
}

impl Backend for LlamaVocab {
    fn name(&self) -> &'static str {
        "llama.cpp (vocabulary only)"
    }

    fn vocab(&self) -> &Vocab {
        &self.vocab
    }

    fn chat_template(&self) -> &ChatTemplate {
        &self.template
    }

    fn context_len(&self) -> usize {
        self.n_ctx
    }

    fn tokenize(&self, text: &str, special: bool) -> Result<Vec<TokenId>, BackendError> {
        Ok(LlamaTokenizer(self.model.clone()).tokenize(text, special))
    }

    fn tokenizer(&self) -> Arc<dyn Tokenize> {
        Arc::new(LlamaTokenizer(self.model.clone()))
    }

    fn forward(&mut self, _keep: usize, _tokens: &[TokenId]) -> Result<&mut [f32], BackendError> {
        Err(BackendError::Eval {
            backend: self.name(),
            reason:
                "only this model's vocabulary is loaded here: a server runs it (--engine openai)"
                    .into(),
        })
    }
}
