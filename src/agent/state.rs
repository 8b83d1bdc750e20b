//! The agent's state between requests: the model and its KV-cache session, the tools
//! and the policy, the robot prompt, the conversation, the trace; and what a run asks
//! of it (the context of a step, the strategies of a turn, running calls).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use serde_json::json;

use super::answer::{answer_spec, ANSWER_TOOL};
use super::config::{AgentConfig, AnswerMode, Pick};
use super::guard::Asked;
use super::history::History;
use super::outcome::AgentError;
use super::trace::Trace;
use crate::backend::Backend;
use crate::chat::{ChatMessage, Role};
use crate::decode::envelope::{Envelope, ToolChoice};
use crate::decode::request::{render_prompt, render_prompt_split, with_tools, TurnRequest};
use crate::decode::{DecodeError, Decoding, Grammars, Session};
use crate::reading::intent;
use crate::reading::select;
use crate::strategy::choice::{Calibrated, Weighed};
use crate::strategy::copy::{defaults, CopyBias, CopyIndex, Scoped};
use crate::strategy::repeats::LoopGuard;
use crate::strategy::Pipeline;
use crate::tool::exec::Executor;
use crate::tool::{Effect, Policy, Registry, ToolSpec};

/// The agent: a model, tools under a policy, a robot prompt, and the conversation so
/// far. `ask` runs one request (see `run`).
pub struct Agent {
    pub(super) backend: Box<dyn Backend>,
    /// What the actuation guard knows of the tools (`guard::Asked`).
    pub(super) asked: Asked,
    pub(super) grammars: Grammars,
    /// Runs calls through the policy (and holds the registry and the policy).
    pub(super) exec: Executor,
    pub(super) system: String,
    pub config: AgentConfig,
    pub(super) session: Session,
    pub(super) history: History,
    pub(super) trace: Option<Trace>,
    pub(super) cancel: Arc<AtomicBool>,
    /// The names the robot holds now, by the argument that takes them (`with_names`).
    pub(super) names: Option<NameSource>,
    /// Tool choice by meaning (`with_meaning`); by words without it.
    pub(super) meaning: Option<Arc<crate::reading::meaning::Meaning>>,
    /// The server that writes the turns, when the model runs there (`backend` is then
    /// its vocabulary only).
    pub(super) remote: Option<crate::remote::Remote>,
    /// Told of every finished run (`with_journal`).
    pub(super) journal: Option<Journal>,
}

/// What is told of each finished run: the request and what came of it (its answer is
/// redacted by the fence; its calls' arguments are as the model wrote them).
pub type Journal = Box<dyn FnMut(&str, &super::RunResult) + Send>;

/// The names a robot holds, each with the argument key that takes it (`"topic"`,
/// `"/turtle1/pose"`), read when a turn's copy bias is built.
pub type NameSource = Arc<dyn Fn() -> Vec<(String, String)> + Send + Sync>;

/// Tokens `text` takes in a prompt (a guess from its length if it cannot be tokenized).
fn token_count(backend: &dyn Backend, text: &str) -> usize {
    backend
        .tokenize(text, true)
        .map_or(text.len() / 3, |t| t.len())
}

impl Agent {
    pub fn new(
        backend: Box<dyn Backend>,
        registry: Registry,
        policy: Arc<Policy>,
        system: String,
        config: AgentConfig,
    ) -> Result<Agent, AgentError> {
        let grammars = Grammars::new(backend.vocab(), backend.tokenizer())
            .map_err(|e| AgentError::Decode(e.into()))?;
        let registry = policy.offered(registry);
        // Tools whose every call changes the robot (no `observes` rule may cover one),
        // and the words of all the others, for telling which actuation a request asks for.
        let actuators: BTreeSet<String> = registry
            .tools()
            .filter(|t| t.effect() == Effect::Actuates && !policy.may_observe(&t.spec().name))
            .map(|t| t.spec().name.clone())
            .collect();
        let observing = intent::vocabulary(
            registry
                .tools()
                .filter(|t| !actuators.contains(&t.spec().name))
                .map(|t| t.spec()),
        );
        let effects: BTreeMap<String, Effect> = registry
            .tools()
            .map(|t| (t.spec().name.clone(), t.effect()))
            .collect();
        let records: BTreeSet<String> = registry
            .tools()
            .filter(|t| t.spec().records)
            .map(|t| t.spec().name.clone())
            .collect();
        Ok(Agent {
            asked: Asked {
                policy: policy.clone(),
                effects,
                records,
                actuators,
                observing,
                known: BTreeMap::new(),
            },
            backend,
            grammars,
            exec: Executor::new(registry, policy)
                .map_err(|e| AgentError::Runtime(e.to_string()))?,
            system,
            config,
            session: Session::new(),
            history: History::default(),
            trace: None,
            cancel: Arc::new(AtomicBool::new(false)),
            names: None,
            meaning: None,
            remote: None,
            journal: None,
        })
    }

    pub fn with_trace(mut self, trace: Trace) -> Agent {
        self.trace = Some(trace);
        self
    }

    pub fn trace_path(&self) -> Option<&std::path::Path> {
        self.trace.as_ref().map(|t| t.path())
    }

    /// Let argument values lean towards the names `names` returns, each for the
    /// parameters of its key (with the copy bias on): a topic argument towards the
    /// robot's topics, a node argument towards its nodes.
    pub fn with_names(mut self, names: NameSource) -> Agent {
        self.names = Some(names);
        self
    }

    /// Keep the prompts' stable prefixes in `cache`, and start from them (a cold start
    /// evaluates only what no earlier process did).
    pub fn with_prompt_cache(mut self, cache: Arc<crate::backend::PromptCache>) -> Agent {
        self.session = Session::with_cache(cache);
        self
    }

    /// Have `remote`'s server write every turn (the agent loaded only the model's
    /// vocabulary). Where the model runs is said in each trace's header.
    pub(crate) fn with_remote(mut self, remote: crate::remote::Remote) -> Agent {
        self.remote = Some(remote);
        self
    }

    /// The remote engine, if the model runs on a server.
    pub fn remote(&self) -> Option<&crate::remote::Remote> {
        self.remote.as_ref()
    }

    /// Where the model runs, for traces and reports: the server and its grammar form,
    /// or the local runtime.
    pub fn engine(&self) -> String {
        crate::remote::Remote::describe_engine(self.remote.as_ref(), self.backend.as_ref())
    }

    /// Use `cancel` as the run's cancel flag (one the front end also sets).
    pub(crate) fn with_cancel(mut self, cancel: Arc<AtomicBool>) -> Agent {
        self.cancel = cancel;
        self
    }

    /// The e-stop the policy and the ROS boundary share.
    pub fn estop(&self) -> Arc<crate::estop::EStop> {
        self.exec.policy().estop().clone()
    }

    /// The names off limits.
    pub fn fence(&self) -> &Arc<crate::fence::Fence> {
        self.exec.policy().fence()
    }

    /// One call straight through the policy (the operator's own, e.g. the REPL's
    /// `/call`): no model, no guards, exactly the checks and the running the agent's
    /// calls get.
    pub fn call(&self, call: &crate::tool::ToolCall) -> crate::tool::exec::Outcome {
        self.exec.call(call, &self.cancel)
    }

    /// Set this flag (e.g. from a Ctrl-C handler) to end the current run cleanly.
    pub fn cancel_flag(&self) -> Arc<AtomicBool> {
        self.cancel.clone()
    }

    pub fn registry(&self) -> &Registry {
        self.exec.registry()
    }

    /// Exchanges the agent remembers (what the next prompt may include).
    pub fn history_len(&self) -> usize {
        self.history.len()
    }

    pub fn backend(&self) -> &dyn Backend {
        self.backend.as_ref()
    }

    /// Forget the conversation (the KV cache keeps the system prompt).
    pub fn clear(&mut self) {
        self.history.clear();
    }

    /// Tell `journal` of every finished run (the memory file's run log), in place of
    /// the one before.
    pub(crate) fn set_journal(&mut self, journal: Journal) {
        self.journal = Some(journal);
    }

    /// Continue a conversation: `exchanges` (request, answer), oldest first, are the
    /// history the next request reads, as if asked in this process.
    pub fn resume<'a>(&mut self, exchanges: impl IntoIterator<Item = (&'a str, &'a str)>) {
        self.history.clear();
        for (q, a) in exchanges {
            self.history.push(q, a);
        }
    }

    fn tokens(&self, text: &str) -> usize {
        token_count(self.backend.as_ref(), text)
    }

    /// The tools retrieval reads: every tool a request could be offered (the answer too,
    /// when answering is a tool).
    fn retrievable(&self) -> Vec<ToolSpec> {
        let mut specs = self.exec.registry().specs();
        if self.config.answer_mode == AnswerMode::Tool {
            specs.push(answer_spec());
        }
        specs
    }

    /// The robot's names now (`with_names`), fenced ones left out; none without a robot.
    /// One graph snapshot: a turn reads it once and hands it on.
    pub(super) fn robot_names(&self) -> Vec<(String, String)> {
        self.names.as_ref().map(|n| n()).unwrap_or_default()
    }

    /// The tools a prompt lists when its request is offered `offered`: every tool, in
    /// the registry's order, when their specs fit `config.listing_budget_tokens` (the
    /// prompt before the request is then the same for every request); else `offered`.
    pub(super) fn listed(&self, offered: &[ToolSpec]) -> Vec<ToolSpec> {
        let all = self.retrievable();
        let budget = self.config.listing_budget_tokens;
        if budget == 0 || all.len() <= offered.len() {
            return offered.to_vec();
        }
        let cost: usize = all
            .iter()
            .map(|s| self.tokens(&Envelope::describe_tool(s)))
            .sum();
        tracing::debug!(target: "ferrosa::select", cost, budget, tools = all.len(), "listing every tool");
        if cost <= budget {
            all
        } else {
            offered.to_vec()
        }
    }

    /// Whether every request's prompt lists every tool (`listed`): then the prompt
    /// before a request is the same for all of them, and warming it once serves all.
    pub fn lists_every_tool(&self) -> bool {
        !self.listed(&[]).is_empty()
    }

    /// `names` with the robot's parameters (`select::PARAMETER`, each by its own name)
    /// as a tool that takes a node's parameter can be given them now (its live schema's
    /// names, `Tool::live_parameters`), for tool choice: "which stored positions does
    /// it know?" is near `stored_positions`, which a parameter tool reads. Those every node
    /// declares of itself (`meant::every_node_parameter`) point at nothing. Not for the
    /// grammar, which reads each tool's own live names (`bound`).
    /// `specs`: the tools as retrieval reads them, the parameter tool among them.
    fn with_parameters(
        &self,
        specs: &[ToolSpec],
        names: &[(String, String)],
    ) -> Vec<(String, String)> {
        let mut out = names.to_vec();
        if names.is_empty() {
            return out;
        }
        let registry = self.exec.registry();
        let live = specs
            .iter()
            .filter(|s| select::name_kinds(s).any(|k| k == select::PARAMETER))
            .find_map(|s| registry.get(&s.name)?.live_spec());
        let Some(live) = live else {
            return out;
        };
        let mut found = Vec::new();
        crate::reading::bound::suggested_names(&live.parameters, &mut found);
        let params: BTreeSet<String> = found
            .into_iter()
            .filter(|(key, name)| {
                key == "name" && !crate::reading::meant::every_node_parameter(name)
            })
            .map(|(_, name)| name)
            .collect();
        out.extend(
            params
                .into_iter()
                .map(|n| (select::PARAMETER.to_string(), n)),
        );
        out
    }

    /// Which tools to offer for `query`, by the token cost of their specs.
    pub fn offered_tools(&self, query: &str) -> Vec<ToolSpec> {
        let specs = self.retrievable();
        let names = self.with_parameters(&specs, &self.robot_names());
        let sims = self.similarities(query, &specs, &names);
        // A tool asked to convert an amount the request gives is offered whatever its
        // words' score (`converts`): an Italian "how many kilometers are 10 miles" met
        // the statistics and the rates before it.
        let candidates: Vec<&str> = specs.iter().map(|s| s.name.as_str()).collect();
        let mut always = self.config.always_on.clone();
        for (name, converts) in candidates.iter().zip(self.converts(query, &candidates)) {
            if converts && !always.iter().any(|a| a == name) {
                always.push(name.to_string());
            }
        }
        let chosen = select::select(
            query,
            &specs,
            &names,
            sims.as_deref(),
            &always,
            self.config.tool_budget_tokens,
            |s| self.tokens(&Envelope::describe_tool(s)),
        );
        chosen.into_iter().map(|i| specs[i].clone()).collect()
    }

    /// Each candidate's prior for the weighed tool choice (`select::prior`), in order,
    /// with the robot's `names` as the turn read them.
    pub(super) fn prior(
        &self,
        part: &str,
        candidates: &[&str],
        names: &[(String, String)],
    ) -> Vec<f64> {
        let specs = self.retrievable();
        let names = &self.with_parameters(&specs, names);
        let sims = self.similarities(part, &specs, names);
        let mut prior = select::prior(
            part,
            &specs,
            names,
            sims.as_deref(),
            candidates,
            ANSWER_TOOL,
        );
        // An amount to convert is for the tool that converts it, on the first step and
        // after its call alike (`Run::settled` reads the same prior): a conversion asked
        // in Portuguese was followed by arithmetic over its result.
        let converts = self.converts(part, candidates);
        select::hold_to(
            &mut prior,
            candidates,
            &converts,
            ANSWER_TOOL,
            select::CONVERTS_ASKED_SHARE,
        );
        // Arithmetic asked ("6 mal 9", "2^10") is for the tool that evaluates an
        // expression, as strongly, and that tool is the best: statistics over numbers
        // of the model's own had answered it, and the evaluator's words meet few.
        let evaluates: Vec<bool> = if crate::reading::arithmetic::asked(part) {
            let registry = self.exec.registry();
            candidates
                .iter()
                .map(|c| registry.get(c).is_some_and(|t| t.spec().computes))
                .collect()
        } else {
            vec![false; candidates.len()]
        };
        select::hold_to(
            &mut prior,
            candidates,
            &evaluates,
            ANSWER_TOOL,
            select::CONVERTS_ASKED_SHARE,
        );
        for (p, _) in prior.iter_mut().zip(&evaluates).filter(|(_, e)| **e) {
            *p = p.max(0.0);
        }
        let (acting, takers) = self.acts_on_amounts(part, candidates);
        // An act that takes the amounts: the converter is cut as a conversion cuts others.
        select::hold_to(
            &mut prior,
            candidates,
            &acting,
            ANSWER_TOOL,
            select::CONVERTS_ASKED_SHARE,
        );
        select::hold_to(
            &mut prior,
            candidates,
            &takers,
            ANSWER_TOOL,
            select::TAKES_AMOUNT_SHARE,
        );
        prior
    }

    /// What the amounts `part` writes say of the candidates, when it asks to convert
    /// none and a candidate that converts no units takes one in its argument's own unit
    /// (`amount::takes`); all false otherwise. First, per candidate, whether it converts
    /// no units, when the part also asks for an act: "drive 2 feet at 1.8 km/h" is a
    /// drive whose amounts the grammar converts (`reading::amount`), and the converter
    /// its unit words point at had been called after the drive, its result answered.
    /// Second, whether it takes one: "reverse 20 inches" is for a tool that takes a
    /// length, and had echoed a topic 20 times.
    fn acts_on_amounts(&self, part: &str, candidates: &[&str]) -> (Vec<bool>, Vec<bool>) {
        use crate::reading::concepts::{asked_acts, clauses};
        let none = || (vec![false; candidates.len()], vec![false; candidates.len()]);
        let amounts = crate::units::amounts(part);
        if amounts.is_empty() {
            return none();
        }
        let registry = self.exec.registry();
        let specs: Vec<Option<ToolSpec>> = candidates
            .iter()
            .map(|c| {
                registry
                    .get(c)
                    .map(|t| t.live_spec().unwrap_or_else(|| t.spec().clone()))
            })
            .collect();
        let asks_conversion = specs
            .iter()
            .flatten()
            .any(|s| crate::reading::bound::asks_a_conversion(&s.parameters, part));
        let read: Vec<(bool, bool)> = specs
            .iter()
            .map(|s| {
                s.as_ref().map_or((false, false), |s| {
                    let converts = crate::reading::bound::converts_units(&s.parameters);
                    let takes = !converts && crate::reading::amount::takes(&s.parameters, &amounts);
                    (converts, takes)
                })
            })
            .collect();
        if asks_conversion || !read.iter().any(|&(_, takes)| takes) {
            return none();
        }
        let acts = !asked_acts(&clauses(part)).is_empty();
        let acting = read
            .iter()
            .map(|&(converts, _)| acts && !converts)
            .collect();
        let takers = read.iter().map(|&(_, takes)| takes).collect();
        (acting, takers)
    }

    /// Per candidate, whether `part` asks it to convert an amount it gives between two
    /// of its units (`bound::asks_a_conversion`, on the tool's live schema). None does
    /// when the part gives no number, or asks for an act ("move forward 50 centimeters,
    /// not meters").
    fn converts(&self, part: &str, candidates: &[&str]) -> Vec<bool> {
        use crate::reading::concepts::{asked_acts, clauses};
        if crate::lexicon::numbers(part).is_empty() || !asked_acts(&clauses(part)).is_empty() {
            return vec![false; candidates.len()];
        }
        let registry = self.exec.registry();
        candidates
            .iter()
            .map(|c| {
                registry
                    .get(c)
                    .and_then(|t| t.live_spec())
                    .is_some_and(|s| crate::reading::bound::asks_a_conversion(&s.parameters, part))
            })
            .collect()
    }

    /// Each of `specs`' similarity to `text` by meaning, with the sentence encoder
    /// (`with_meaning`); None without it.
    fn similarities(
        &self,
        text: &str,
        specs: &[ToolSpec],
        names: &[(String, String)],
    ) -> Option<Vec<f64>> {
        self.meaning
            .as_ref()
            .map(|m| m.similarities(text, specs, names))
    }

    /// Read requests by meaning (`meaning`): tool choice compares each with the tools'
    /// descriptions and examples instead of their words. The tools' sentences are
    /// encoded now.
    pub(crate) fn with_meaning(mut self, meaning: Arc<crate::reading::meaning::Meaning>) -> Agent {
        meaning.prepare(&self.retrievable());
        self.meaning = Some(meaning);
        self
    }

    /// The prompt cache the agent keeps its stable prefixes in, if any.
    pub fn prompt_cache(&self) -> Option<&Arc<crate::backend::PromptCache>> {
        self.session.cache()
    }

    /// Make the prompt cache hold the stable prefix of `query`'s first step (the system
    /// prompt and the tools `query` is offered), evaluating it if no entry holds it:
    /// what `ferrosa models warm` does ahead of the first request. Returns how many
    /// tokens the cache holds of it (whole batches), or None without a prompt cache.
    pub fn warm(&mut self, query: &str) -> Result<Option<usize>, AgentError> {
        if self.session.cache().is_none() {
            return Ok(None);
        }
        let listed = self.listed(&self.offered_tools(query));
        let messages = [
            ChatMessage::new(Role::System, self.system.clone()),
            ChatMessage::new(Role::User, query),
        ];
        let req = self.request(&messages, &listed, None);
        let (tokens, stable) =
            render_prompt_split(self.backend.as_ref(), &with_tools(&req), req.envelope)
                .map_err(AgentError::Decode)?;
        self.session.set_stable(&tokens[..stable]);
        let (_, held) = self
            .session
            .prepare(self.backend.as_mut(), &tokens)
            .map_err(|e| AgentError::Decode(e.into()))?;
        Ok(Some(held))
    }

    /// Prompt tokens of the first step of `query` with these tools and no history.
    pub fn prompt_tokens_with(&self, query: &str, specs: &[ToolSpec]) -> usize {
        let messages = [
            ChatMessage::new(Role::System, self.system.clone()),
            ChatMessage::new(Role::User, query),
        ];
        let req = self.request(&messages, specs, None);
        render_prompt(
            self.backend.as_ref(),
            &with_tools(&req),
            self.config.envelope,
        )
        .map_or(0, |t| t.len())
    }

    pub(super) fn choice(&self) -> ToolChoice {
        match self.config.answer_mode {
            AnswerMode::Tool => ToolChoice::Required,
            AnswerMode::Prose => ToolChoice::Auto,
            AnswerMode::Decline => ToolChoice::Decline,
        }
    }

    pub(super) fn request<'a>(
        &self,
        messages: &'a [ChatMessage],
        specs: &'a [ToolSpec],
        allowed: Option<&'a [ToolSpec]>,
    ) -> TurnRequest<'a> {
        TurnRequest {
            messages,
            specs,
            allowed,
            envelope: self.config.envelope,
            choice: self.choice(),
            parallel: true,
            decoding: self.config.decoding,
            max_tokens: self.config.max_turn_tokens,
        }
    }

    /// The strategies of a step's turn: the tool choice `config.pick` names (on the
    /// first step of a request or of a part, `pick`: the part's text, the tools the
    /// step may call and which of them take a name the part writes
    /// (`select::takes_written`); after a result the question is whether to answer, which neither
    /// a content-free request nor the retrieval says anything about) and the copy bias
    /// (with its array guard), each when on. `names`: the robot's names as the turn read
    /// them.
    pub(super) fn pipeline(
        &self,
        sources: &[&str],
        pick: Option<(&str, &[&str], &[bool])>,
        names: &[(String, String)],
    ) -> Pipeline {
        let mut p = Pipeline::new();
        let constrained = self.config.decoding == Decoding::Constrained;
        match pick.filter(|_| constrained) {
            Some(_) if self.config.pick == Pick::Calibrated => {
                p = p.with(Calibrated { lists: false });
            }
            Some((part, candidates, takes)) if self.config.pick == Pick::Weighed => {
                let mut prior = self.prior(part, candidates, names);
                select::hold_to(
                    &mut prior,
                    candidates,
                    takes,
                    ANSWER_TOOL,
                    select::DROPS_WRITTEN_SHARE,
                );
                p = p.with(Weighed {
                    prior,
                    weight: select::PRIOR_WEIGHT,
                });
            }
            _ => {}
        }
        if self.config.copy_bias > 0.0 && constrained {
            let vocab = self.backend.vocab();
            let offered = self.exec.registry().specs();
            let mut scoped = defaults(&offered);
            let written: Vec<String> = sources
                .iter()
                .flat_map(|s| crate::reading::bound::written_names(s))
                .collect();
            let pointed = crate::reading::bound::pointed(names, sources, &written);
            scoped.extend(graph_names(&offered, &pointed));
            let index = CopyIndex::new(
                vocab,
                sources,
                &scoped,
                self.config.copy_bias,
                Some(ANSWER_TOOL),
            );
            p = p.with(CopyBias::new(index)).with(LoopGuard::new(vocab));
        }
        p
    }

    /// The messages of a step: the system prompt, the history that fits, the query and
    /// this run's scratchpad.
    pub(super) fn context(
        &mut self,
        query: &str,
        scratch: &[ChatMessage],
        offered: &[ToolSpec],
    ) -> Result<Vec<ChatMessage>, DecodeError> {
        let mut base = vec![ChatMessage::new(Role::System, self.system.clone())];
        base.push(ChatMessage::new(Role::User, query));
        base.extend(scratch.iter().cloned());
        let fixed = {
            let req = self.request(&base, offered, None);
            render_prompt(
                self.backend.as_ref(),
                &with_tools(&req),
                self.config.envelope,
            )?
            .len()
        };
        let room = self
            .backend
            .context_len()
            .saturating_sub(fixed + self.config.reserve_tokens)
            .min(self.config.history_tokens);
        let backend = self.backend.as_ref();
        let dropped = self.history.trim(room, |s| token_count(backend, s));
        if dropped > 0 {
            if let Some(t) = &mut self.trace {
                t.record(
                    "history_trimmed",
                    json!({"dropped_exchanges": dropped, "room_tokens": room}),
                );
            }
        }
        let mut messages = vec![base[0].clone()];
        messages.extend(self.history.messages());
        messages.extend(base[1..].iter().cloned());
        Ok(messages)
    }
}

/// One source per name and per offered parameter of the name's key: each name is a
/// candidate for the arguments of its kind only, and those arguments lean towards the
/// robot's names alone (a request's "background_r" is no node name). A name the robot
/// does not have can still be written: the bias is a nudge.
fn graph_names(offered: &[ToolSpec], names: &[(String, String)]) -> Vec<Scoped> {
    let mut out = Vec::new();
    for spec in offered {
        let Some(props) = spec.parameters["properties"].as_object() else {
            continue;
        };
        for (key, value) in names {
            if props.get(key).is_some_and(|p| p["type"] == "string") {
                out.push(Scoped {
                    tool: spec.name.clone(),
                    key: key.clone(),
                    text: value.clone(),
                    literal: false,
                    exclusive: true,
                });
            }
        }
    }
    out
}
