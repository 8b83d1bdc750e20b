//! Which tools a request is offered when their specs together exceed the prompt budget
//! (the sim has 33; ROSA's turtle demo 75). Retrieval, read without a model and in the
//! languages an operator uses:
//!
//! - each tool is a document: the words of its name (weighing three times), of its
//!   description and of its parameters; a tool that acts on a ROS thing by name
//!   (`topic`, `service`, `node`, `action`, `type` arguments) also holds the words of the
//!   robot's names of that kind (weighing twice): "clear it all" meets the service
//!   `/clear`, "the color sensor" the topic `/turtle1/color_sensor`; a name the request
//!   writes whole ("/turtle1/pose") weighs more than a tool's own name;
//! - a request word meets a document word when they are the same word folded, one is a
//!   prefix of the other (four letters at least) or they share five first letters, when
//!   both name the same act (`concepts`: "mueve" and `turtle_move`), or when both are
//!   words of one concept of the robot's domain below ("nodos" and "node", "batería" and
//!   "battery", "dónde" and "where");
//! - a word counts by how few tools it meets (BM25's inverse document frequency), so
//!   words every description has ("the", "of", "de") count for nearly nothing. There is
//!   no stop-word list and no stemming: nothing here is English-only. Words that ask to
//!   be told ("show", "dime": `concepts::tells`) frame the request and are not read;
//!   a tool may be named after one (`ros_interface_show`).
//!
//! The best scoring tools are offered, best first, within the budget and down to a
//! share of the best score; the always-on ones (the answer, the stop) last. Cheap and deterministic; the trace records what was
//! offered, and `ferrosa eval ros --retrieval` measures it.

use crate::lexicon::folded_words;
use crate::tool::ToolSpec;

use super::concepts::{acts_of, word_matches, Act};
use crate::tool::STOP_TOOL;

/// Concepts of the robot's domain: the words (folded prefixes, whole words when three
/// letters or fewer) that say each, in English, Spanish, French, German, Italian and
/// Portuguese. The English words are those the tools' descriptions use.
const CONCEPTS: &[&[&str]] = &[
    &["node", "nodo", "noeud", "knoten", "nodi"],
    &[
        "topic", "topico", "tema", "sujet", "thema", "themen", "argoment",
    ],
    &["servic", "servizi", "servico", "dienst"],
    &["param", "parametr"],
    &["action", "accion", "azion", "acao", "acoes", "aktion"],
    &["messag", "mensaj", "mensag", "nachricht"],
    &[
        "field",
        "campo",
        "campi",
        "champ",
        "feld",
        "definit",
        "definic",
        "definiz",
        "structur",
        "estructur",
        "struktur",
    ],
    &[
        "batter", "bateri", "akku", "charge", "charging", "carga", "caric",
    ],
    &[
        "pose",
        "where",
        "donde",
        "ou",
        "wo",
        "dove",
        "onde",
        "position",
        "posicion",
        "posizion",
        "posica",
        "location",
        "ubicacion",
        "standort",
        "localiz",
    ],
    &["rate", "often", "hz", "frequen", "frecuen", "haufig"],
    &["log", "logs", "registr", "journal", "protokoll", "rosout"],
    &[
        "error",
        "erreur",
        "fehler",
        "errore",
        "erro",
        "health",
        "salud",
        "sante",
        "zustand",
        "gesundheit",
        "salute",
        "saude",
        "status",
        "estado",
        "etat",
        "stato",
        "diagnos",
        "warning",
        "advertenc",
        "avertiss",
        "warnung",
        "avvis",
        "aviso",
    ],
    &[
        "time", "hora", "tiempo", "heure", "zeit", "uhr", "ora", "tempo", "date", "fecha", "datum",
    ],
    &["color", "colour", "couleur", "farbe", "colore", "cor"],
    &[
        "speed",
        "velocidad",
        "vitesse",
        "geschwindigkeit",
        "velocita",
        "velocidade",
    ],
    &[
        "arithmet", "times", "plus", "minus", "divid", "multipl", "calcul", "comput", "evaluat",
        "rechne", "berechn", "suma", "somm",
    ],
    &[
        "mean",
        "average",
        "media",
        "promedio",
        "moyenne",
        "mittel",
        "durchschnitt",
        "median",
        "statist",
        "estadist",
    ],
    &["conver", "umrechn", "umwand"],
    &["distan", "abstand", "entfernung"],
    &["list", "lista", "liste", "elenc", "auflist", "enumer"],
    &[
        "running",
        "ejecut",
        "laufend",
        "marcha",
        "funcion",
        "fonctionn",
        "esecuz",
        "execut",
        "rodando",
    ],
    &["turtle", "tortug", "tortue", "schildkrot", "tartarug"],
    &["wait", "espera", "attend", "warte", "aspett", "aguard"],
    &[
        "read", "show", "echo", "lee", "leer", "lire", "lies", "leggi", "ler", "muestra", "montre",
        "zeig", "mostra", "display",
    ],
];

/// What a folded word stands for beyond itself: its acts and its concepts.
struct Word {
    text: String,
    acts: Vec<Act>,
    concepts: Vec<usize>,
    /// The English words of ROS names it says (`concepts::says_in_names`).
    english: Vec<&'static str>,
}

impl Word {
    fn new(text: String) -> Word {
        let acts = acts_of(std::slice::from_ref(&text));
        // The concepts whose entry for the word is the longest: "times" is arithmetic
        // ("times"), not time ("time").
        let matched: Vec<(usize, usize)> = CONCEPTS
            .iter()
            .enumerate()
            .filter_map(|(i, words)| {
                let len = words
                    .iter()
                    .filter(|p| word_matches(&text, p))
                    .map(|p| p.len())
                    .max()?;
                Some((i, len))
            })
            .collect();
        let longest = matched.iter().map(|(_, l)| *l).max().unwrap_or(0);
        let concepts = matched
            .into_iter()
            .filter(|(_, l)| *l == longest)
            .map(|(i, _)| i)
            .collect();
        Word {
            english: super::concepts::says_in_names(&text),
            text,
            acts,
            concepts,
        }
    }

    /// Whether two words say the same (see the module header). Two words the lexicon
    /// gives different concepts do not meet by their letters ("times" and "time").
    fn meets(&self, other: &Word) -> bool {
        let (a, b) = (self.text.as_str(), other.text.as_str());
        let (short, long) = if a.len() <= b.len() { (a, b) } else { (b, a) };
        let shared = self.concepts.iter().any(|c| other.concepts.contains(c));
        let apart = !shared && !self.concepts.is_empty() && !other.concepts.is_empty();
        a == b
            || (!apart && short.len() >= 4 && long.starts_with(short))
            || (!apart && a.bytes().zip(b.bytes()).take_while(|(x, y)| x == y).count() >= 5)
            || self.acts.iter().any(|x| other.acts.contains(x))
            || shared
            || self.english.contains(&b)
            || other.english.contains(&a)
            || self.english.iter().any(|e| other.english.contains(e))
    }
}

fn words_of(text: &str) -> Vec<Word> {
    // `folded_words` already splits names at `_`, `/` and `.`.
    let mut w = folded_words(text);
    w.sort();
    w.dedup();
    w.into_iter().map(Word::new).collect()
}

/// A tool as retrieval reads it, with the weight of each field.
struct Document {
    fields: [(f64, Vec<Word>); 4],
}

/// Weight of the words of a robot's name the request writes whole ("/turtle1/pose"):
/// above a tool's own name, so "show two messages of /turtle1/pose" is for a tool that
/// takes a topic, not `turtle_pose`.
const WRITTEN_NAME: f64 = 4.0;

/// Arguments that name a ROS thing of the robot's graph (the kinds of `names`).
pub(crate) const NAME_KINDS: &[&str] = &["node", "topic", "service", "action", "type"];

/// The kind of the robot's names that are its nodes' parameters. A parameter is
/// addressed by its node and its name, so a tool takes one when it takes both as
/// strings (the parameter tools, and a declared tool addressed the same way).
pub(crate) const PARAMETER: &str = "parameter";

/// The kinds of the robot's names `spec` takes (its string arguments of those names,
/// and `PARAMETER` for a node and a name).
pub(crate) fn name_kinds(spec: &ToolSpec) -> impl Iterator<Item = &'static str> + '_ {
    let props = spec.parameters["properties"].as_object();
    let string =
        move |k: &str| props.is_some_and(|p| p.get(k).is_some_and(|v| v["type"] == "string"));
    NAME_KINDS
        .iter()
        .copied()
        .filter(move |k| string(k))
        .chain((string("node") && string("name")).then_some(PARAMETER))
}

impl Document {
    /// `spelled`: the robot's parameters the request says in words (`spelled_parameters`).
    fn new(
        spec: &ToolSpec,
        names: &[(String, String)],
        written: &[String],
        spelled: &[&str],
    ) -> Document {
        let props = spec.parameters["properties"].as_object();
        let mut text = spec.description.clone();
        for (key, p) in props.into_iter().flatten() {
            text.push(' ');
            text.push_str(key);
            if let Some(d) = p["description"].as_str() {
                text.push(' ');
                text.push_str(d);
            }
        }
        // Parameters are read by meaning only: as words, a setting's ("grip_force")
        // met a question about the state ("how hard does the gripper squeeze now?")
        // that no topic's name says in its words.
        // Said whole in words, though ("how many named poses" for `named_poses`), a
        // setting is as written.
        let kinds: Vec<&str> = name_kinds(spec).filter(|k| *k != PARAMETER).collect();
        let (mut whole, graph): (Vec<&str>, Vec<&str>) = names
            .iter()
            .filter(|(kind, _)| kinds.contains(&kind.as_str()))
            .map(|(_, name)| name.as_str())
            .partition(|name| written.iter().any(|w| bare(w) == bare(name)));
        if name_kinds(spec).any(|k| k == PARAMETER) {
            whole.extend(spelled);
        }
        Document {
            fields: [
                (3.0, words_of(&spec.name)),
                (1.0, words_of(&text)),
                (2.0, words_of(&graph.join(" "))),
                (WRITTEN_NAME, words_of(&whole.join(" "))),
            ],
        }
    }

    /// The weight of the best field `w` meets (0 when none).
    fn meets(&self, w: &Word) -> f64 {
        self.fields
            .iter()
            .filter(|(_, words)| words.iter().any(|d| d.meets(w)))
            .map(|(weight, _)| *weight)
            .fold(0.0, f64::max)
    }
}

/// Each tool's score for `query`, by its words: over the request's words, the weight
/// of the field each meets times how rare the word is among the tools. `names` are the
/// robot's (kind, name) pairs.
fn lexical(query: &str, specs: &[ToolSpec], names: &[(String, String)]) -> Vec<f64> {
    let written = super::bound::written_names(query);
    let spelled = spelled_parameters(query, names);
    let docs: Vec<Document> = specs
        .iter()
        .map(|s| Document::new(s, names, &written, &spelled))
        .collect();
    // Words that ask to be told ("show", "describe") frame a request, and say nothing of
    // which tool: "show the services" met `ros_interface_show` by its name.
    let words = words_of(query)
        .into_iter()
        .filter(|w| !super::concepts::tells(&w.text));
    let n = docs.len() as f64;
    let mut out = vec![0.0; docs.len()];
    for w in words {
        let hits: Vec<f64> = docs.iter().map(|d| d.meets(&w)).collect();
        let df = hits.iter().filter(|h| **h > 0.0).count() as f64;
        if df == 0.0 {
            continue;
        }
        let idf = ((n - df + 0.5) / (df + 0.5) + 1.0).ln();
        for (o, h) in out.iter_mut().zip(hits) {
            *o += h * idf;
        }
    }
    out
}

/// The robot's parameters (`PARAMETER` in `names`) of two words or more that `query`
/// says side by side in its words, each word whole or with an ending ("the named poses"
/// for `named_poses`, "max joint velocity" for `max_joint_velocity`). A setting of one
/// word is any word of a sentence, and one half said is not the setting.
fn spelled_parameters<'a>(query: &str, names: &'a [(String, String)]) -> Vec<&'a str> {
    let said = folded_words(query);
    let meets = |name_word: &String, w: &String| {
        w == name_word || (name_word.len() >= 4 && w.starts_with(name_word.as_str()))
    };
    names
        .iter()
        .filter(|(kind, _)| kind == PARAMETER)
        .map(|(_, name)| name.as_str())
        .filter(|name| {
            let own = folded_words(name);
            own.len() >= 2
                && said
                    .windows(own.len())
                    .any(|w| w.iter().zip(&own).all(|(s, o)| meets(o, s)))
        })
        .collect()
}

/// How much a similarity gap weighs: a tool whose similarity is `TEMPERATURE` below the
/// best one scores 1/e of it.
const TEMPERATURE: f64 = 0.1;

/// Each tool's score for `query` (`names`: the robot's (kind, name) pairs). With `sims`
/// (each tool's similarity to the request by meaning, the robot's names included,
/// `meaning`), the share exp((s - best) / TEMPERATURE); without, by the words the
/// request and the tool share (`lexical`).
pub fn scores(
    query: &str,
    specs: &[ToolSpec],
    names: &[(String, String)],
    sims: Option<&[f64]>,
) -> Vec<f64> {
    let Some(sims) = sims.filter(|s| s.len() == specs.len()) else {
        return lexical(query, specs, names);
    };
    let best = sims.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    sims.iter()
        .map(|r| ((r - best) / TEMPERATURE).exp())
        .collect()
}

/// Each tool's score for weighing the model's choice (`prior`), from its scores by meaning
/// (`scores`): with similarities, the mean of
/// its share by meaning and its share of the best score by words. The two err apart:
/// the encoder takes "ângulo" for a unit conversion, the words miss "pinza"; on the tune
/// halves of both robots' suites the mean chose better than either (README,
/// Understanding requests). Which tools are offered stays by meaning alone (`select`):
/// fewer tools, a shorter prompt.
fn blend(
    by_meaning: Vec<f64>,
    query: &str,
    specs: &[ToolSpec],
    names: &[(String, String)],
    sims: Option<&[f64]>,
) -> Vec<f64> {
    if sims.is_none_or(|s| s.len() != specs.len()) {
        return by_meaning;
    }
    let words = share_of_best(&lexical(query, specs, names));
    if words.iter().all(|w| *w <= 0.0) {
        return by_meaning;
    }
    by_meaning
        .iter()
        .zip(&words)
        .map(|(m, w)| (m + w) / 2.0)
        .collect()
}

/// A tool scoring under this share of the best one is not offered: a small model
/// chooses better among fewer. On the ROS suite, 0.3 keeps every expected tool (in both
/// halves) with 9.8 tools offered per request instead of 12.1; 0.4 loses two.
const RELATIVE_FLOOR: f64 = 0.3;

/// The same floor for scores by meaning: a tool more than 0.2 below the best one's
/// similarity (two `TEMPERATURE`s) is not offered.
const MEANING_FLOOR: f64 = 0.135;

/// By meaning, the share of the best score by words at which a tool is offered
/// whatever its meaning: the words point at it as strongly as at the best.
const WORDS_BAR: f64 = 0.8;

/// Each score as a share of the best one (all 0 when none is above 0).
fn share_of_best(scores: &[f64]) -> Vec<f64> {
    let top = scores.iter().copied().fold(0.0, f64::max);
    if top <= 0.0 {
        return vec![0.0; scores.len()];
    }
    scores.iter().map(|s| s / top).collect()
}

/// Indices of the tools to offer: the best scoring within `budget` tokens as measured
/// by `cost`, best first, then the always-on ones. When everything fits, all tools in
/// registry order.
pub fn select(
    query: &str,
    specs: &[ToolSpec],
    names: &[(String, String)],
    sims: Option<&[f64]>,
    always_on: &[String],
    budget: usize,
    cost: impl Fn(&ToolSpec) -> usize,
) -> Vec<usize> {
    let sims = sims.filter(|s| s.len() == specs.len());
    let costs: Vec<usize> = specs.iter().map(&cost).collect();
    if costs.iter().sum::<usize>() <= budget {
        return (0..specs.len()).collect();
    }
    let always: Vec<usize> = (0..specs.len())
        .filter(|&i| always_on.contains(&specs[i].name))
        .collect();
    let mut used: usize = always.iter().map(|&i| costs[i]).sum();
    let by_meaning = scores(query, specs, names, sims);
    // By meaning, a tool the words point at strongly is offered too, ranked by both
    // ("dock the robot": the encoder puts `base_dock`'s examples far, the word
    // "dock" in its name does not).
    let (ranking, words) = match sims {
        Some(_) => (
            blend(by_meaning.clone(), query, specs, names, sims),
            share_of_best(&lexical(query, specs, names)),
        ),
        None => (by_meaning.clone(), vec![0.0; specs.len()]),
    };
    let mut ranked: Vec<(f64, usize)> = ranking
        .iter()
        .enumerate()
        .filter(|(i, sc)| !always.contains(i) && **sc > 0.0)
        .map(|(i, sc)| (*sc, i))
        .collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    if tracing::enabled!(target: "ferrosa::select", tracing::Level::DEBUG) {
        // Each tool's score, and its similarity by meaning when read.
        let named: Vec<(&str, f64, Option<f64>)> = ranked
            .iter()
            .map(|(sc, i)| (specs[*i].name.as_str(), *sc, sims.map(|s| s[*i])))
            .collect();
        tracing::debug!(target: "ferrosa::select", ranked = ?named, "retrieval");
    }
    match sims {
        Some(_) => {
            let top = by_meaning.iter().copied().fold(0.0, f64::max);
            ranked.retain(|(_, i)| by_meaning[*i] >= MEANING_FLOOR * top || words[*i] >= WORDS_BAR);
        }
        None => {
            let top = ranked.first().map_or(0.0, |r| r.0);
            ranked.retain(|r| r.0 >= RELATIVE_FLOOR * top);
        }
    }
    let mut chosen: Vec<usize> = Vec::new();
    for (_, i) in ranked {
        if used + costs[i] <= budget {
            chosen.push(i);
            used += costs[i];
        }
    }
    // Best first: a small model leans toward the first tool it is shown.
    chosen.extend(always);
    chosen
}

/// How much a tool's retrieval share weighs against the model's log-probability of its
/// name, when the first step of a request picks its tool (`config::Pick::Weighed`).
pub(crate) const PRIOR_WEIGHT: f64 = 8.0;

/// The share of the best tool's score the answer (`fallback`) is held at: the model
/// answers without a tool when it likes that better than a tool scoring this share
/// or less.
const FALLBACK_SHARE: f64 = 0.3;

/// The share a tool's prior is cut to when the request writes a name of the robot's
/// whole ("background_r", "/turtle1/pose") that another candidate takes as an argument
/// now and this one cannot: the tool would drop what the operator named.
pub(crate) const DROPS_WRITTEN_SHARE: f64 = 0.5;

/// The robot's names a tool takes now and does not declare: the string values
/// (`enum`, `const`) of its live schema (`Tool::live_parameters`: the topics, nodes,
/// parameters it can be given) that its declared one lacks.
fn live_values(live: &ToolSpec, declared: Option<&ToolSpec>) -> Vec<String> {
    fn walk(v: &serde_json::Value, out: &mut Vec<String>) {
        match v {
            serde_json::Value::Object(map) => {
                for (k, x) in map {
                    match (k.as_str(), x) {
                        ("enum", serde_json::Value::Array(items)) => {
                            out.extend(items.iter().filter_map(|i| i.as_str()).map(str::to_string))
                        }
                        ("const", serde_json::Value::String(c)) => out.push(c.clone()),
                        _ => walk(x, out),
                    }
                }
            }
            serde_json::Value::Array(items) => items.iter().for_each(|i| walk(i, out)),
            _ => {}
        }
    }
    let mut values = Vec::new();
    walk(&live.parameters, &mut values);
    let mut fixed = Vec::new();
    if let Some(d) = declared {
        walk(&d.parameters, &mut fixed);
    }
    values.retain(|v| !fixed.contains(v));
    values
}

/// Per tool of `live` (the candidates as the robot can take them now; `declared`, the
/// tools as declared), whether it takes a name `part` writes whole in the shape of a ROS
/// name (`bound::written_names`) among its live values. A request that names a
/// parameter or a topic asks for a tool that can be given it.
pub(crate) fn takes_written(part: &str, live: &[ToolSpec], declared: &[ToolSpec]) -> Vec<bool> {
    let written = written_bare(part);
    live.iter()
        .map(|spec| {
            !written.is_empty()
                && live_values(spec, declared.iter().find(|d| d.name == spec.name))
                    .iter()
                    .any(|v| written.iter().any(|w| w == bare(v)))
        })
        .collect()
}

/// The names `text` writes whole (`bound::written_names`), without a leading `/`.
fn written_bare(text: &str) -> Vec<String> {
    super::bound::written_names(text)
        .iter()
        .map(|w| bare(w).to_string())
        .collect()
}

/// A ROS name without its leading `/`: "/clear" and "clear" are the same name written.
fn bare(name: &str) -> &str {
    name.trim_start_matches('/')
}

/// The share a tool's prior is cut to when the request asks to convert an amount
/// between two units (`bound::asks_a_conversion`: the one after a number, another of
/// its kind apart) and another candidate converts them: a Spanish "how many kilometers
/// are 3 miles" went to statistics over the 3, which the model liked by far. Strong, as
/// such a request is seldom anything else; not the floor, so a model sure of another
/// tool still writes it.
pub(crate) const CONVERTS_ASKED_SHARE: f64 = 0.05;

/// The share a tool's prior is cut to when the request writes an amount in a unit
/// (`units::amounts`), asks to convert none, and another candidate takes it in an
/// argument's own unit (`amount::takes`): "reverse 20 inches" is for a tool that takes
/// a length. Milder than a conversion asked: a tool that takes a message of numbers
/// with no unit declared (a topic's publish) may be the one meant.
pub(crate) const TAKES_AMOUNT_SHARE: f64 = 0.3;

/// Cut to `share` the priors of the candidates `holds` leaves out when it keeps any
/// (in the candidates' order: those that take a name the request writes,
/// `DROPS_WRITTEN_SHARE`; that convert an amount it asks to convert,
/// `CONVERTS_ASKED_SHARE`; that take its amounts, `TAKES_AMOUNT_SHARE`); the answer and
/// the stop tool keep theirs.
pub(crate) fn hold_to(
    prior: &mut [f64],
    candidates: &[&str],
    holds: &[bool],
    fallback: &str,
    share: f64,
) {
    if holds.len() != prior.len() || !holds.iter().any(|t| *t) {
        return;
    }
    for ((p, name), held) in prior.iter_mut().zip(candidates).zip(holds) {
        if !held && *name != fallback && *name != STOP_TOOL {
            *p += share.ln();
        }
    }
}

/// The share a tool's score is cut to when the request asks about several of the
/// robot's names of a kind ("which topics carry turtle data?",
/// `concepts::kinds_in_plural`), writes none of that kind, and the tool takes exactly one
/// (a required argument of that kind): it would answer about one topic where the
/// operator asked about the topics. A tool that takes a node, or none, is not cut.
/// When the request writes no name at all and a tool lists that kind in full
/// (`ToolSpec::lists`), every other tool is cut so too and the listing is raised to the
/// best score: "show all the topics of the robot" asks for the topics, not for the
/// robot's status, which a small model liked for the word "robot".
const ONE_OF_MANY_SHARE: f64 = 0.5;

/// Cut (`ONE_OF_MANY_SHARE`) the scores (in `specs`' order) of the tools that take one
/// name of a kind `query` asks about in the plural without writing one of it, and point
/// at the tool that lists that kind (see `ONE_OF_MANY_SHARE`). A name written whole that
/// the robot lacks may be of any kind, so it keeps every tool.
fn cut_one_of_many(
    query: &str,
    specs: &[ToolSpec],
    names: &[(String, String)],
    scored: &mut [f64],
) {
    let plural = super::concepts::kinds_in_plural(&folded_words(query));
    if plural.is_empty() {
        return;
    }
    let written = written_bare(query);
    let writes = |kind: &str| {
        written.iter().any(|w| {
            let kinds: Vec<&str> = names
                .iter()
                .filter(|(_, n)| bare(n) == *w)
                .map(|(k, _)| k.as_str())
                .collect();
            kinds.is_empty() || kinds.contains(&kind)
        })
    };
    let lists = |spec: &ToolSpec| spec.lists.as_deref().is_some_and(|k| plural.contains(&k));
    let listing = written.is_empty() && specs.iter().any(lists);
    let best = scored.iter().copied().fold(0.0, f64::max);
    for (spec, score) in specs.iter().zip(scored.iter_mut()) {
        let required = crate::tool::schema::required(&spec.parameters);
        let one_of_many = name_kinds(spec)
            .any(|k| plural.contains(&k) && required.iter().any(|r| r == k) && !writes(k));
        if listing && lists(spec) {
            *score = best;
        } else if one_of_many || listing {
            *score *= ONE_OF_MANY_SHARE;
        }
    }
}

/// Raise to the best score (in `specs`' order) the tools that take a node's parameter
/// when `query` says one of the robot's settings whole in words (`spelled_parameters`)
/// and writes no name: "how many named poses can it reach?" asks for `named_poses`,
/// though its meaning is nearer a topic with "pose" in its name. A tool whose own name
/// names an act the request does not ask for (`ros_param_set` for a question) is left
/// as it is.
fn raise_spelled_setting(
    query: &str,
    specs: &[ToolSpec],
    names: &[(String, String)],
    scored: &mut [f64],
) {
    if !written_bare(query).is_empty() || spelled_parameters(query, names).is_empty() {
        return;
    }
    let asked = super::concepts::asked_acts(&super::concepts::clauses(query));
    let best = scored.iter().copied().fold(0.0, f64::max);
    for (spec, score) in specs.iter().zip(scored.iter_mut()) {
        let acts = acts_of(&super::intent::name_words(&spec.name));
        if name_kinds(spec).any(|k| k == PARAMETER) && acts.iter().all(|a| asked.contains(a)) {
            *score = best;
        }
    }
}

/// Which candidates (by their priors) the request points at more than at every tool
/// whose call already answered it (`done`, their priors): what may follow a result
/// (`Run::settled`).
pub fn beyond(candidates: &[f64], done: &[f64]) -> Vec<bool> {
    let bar = done.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    candidates
        .iter()
        .map(|p| *p > bar + FOLLOW_MARGIN)
        .collect()
}

/// How much more (in log share) the request must point at a tool than at those that
/// answered it for the tool to follow: a near tie is no second request ("what is the
/// background_r parameter?": the parameter's value, not the node's parameter list
/// after it).
const FOLLOW_MARGIN: f64 = 0.2;

/// The least share a tool is held at (a tool the request does not meet at all).
const PRIOR_FLOOR: f64 = 1e-3;

/// Which of a part's results an answer is held to, given each one's tool's prior (in
/// the order they ran): the latest of those whose tool the request meets best. A part
/// is one request (`plan` cuts "move, then tell me where it is" in two), so a result
/// the request asked for is not replaced by one the model went on to fetch ("how charged
/// is the battery?": the status, not the pose read after it; "which type does /spawn
/// have?": the service's info, not the list of services after it).
pub(crate) fn grounding(priors: &[f64]) -> Option<usize> {
    let best = priors.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    priors.iter().rposition(|p| *p >= best - 1e-9)
}

/// Per candidate name, its prior for the weighed tool choice: the log of its retrieval
/// score's share of the best score among `specs` (all the tools the request could be
/// offered, so the words' weights are those `select` uses). The answer, `fallback`,
/// is held at `FALLBACK_SHARE` (by meaning, at least there); when the request meets no tool at all, every tool is
/// at the floor and the answer at 0.
pub fn prior(
    query: &str,
    specs: &[ToolSpec],
    names: &[(String, String)],
    sims: Option<&[f64]>,
    candidates: &[&str],
    fallback: &str,
) -> Vec<f64> {
    let by_meaning = scores(query, specs, names, sims);
    let mut scored = blend(by_meaning.clone(), query, specs, names, sims);
    cut_one_of_many(query, specs, names, &mut scored);
    raise_spelled_setting(query, specs, names, &mut scored);
    let at = |name: &str| specs.iter().position(|s| s.name == name);
    if tracing::enabled!(target: "ferrosa::select", tracing::Level::DEBUG) {
        let each: Vec<(&str, Option<f64>, Option<f64>)> = candidates
            .iter()
            .map(|&c| {
                (
                    c,
                    at(c).map(|i| scored[i]),
                    at(c).and_then(|i| sims.map(|s| s[i])),
                )
            })
            .collect();
        tracing::debug!(target: "ferrosa::select", ?each, "prior: score, similarity");
    }
    let score_of = |name: &str| at(name).map_or(0.0, |i| scored[i]);
    let meaning_of = |name: &str| at(name).map_or(0.0, |i| by_meaning[i]);
    // A tool that computes from numbers and is held back until one is said or returned
    // (`ToolSpec::waits_for_numbers`) sets no bar: the request that meets it best
    // ("the elbow's angle in degrees") needs its number read first.
    let top = specs
        .iter()
        .zip(&scored)
        .filter(|(s, _)| s.name != fallback && s.name != STOP_TOOL)
        .filter(|(s, _)| !s.waits_for_numbers() || candidates.contains(&s.name.as_str()))
        .map(|(_, sc)| *sc)
        .fold(0.0, f64::max);
    candidates
        .iter()
        .map(|&c| match (c == fallback, top > 0.0) {
            // The stop is taken without the model when the operator's words ask for it
            // (`stop_intent`); the model's own choice of it gets no push from how much
            // a request looks like "halt the robot" ("dock the robot" does).
            (false, true) if c == STOP_TOOL => FALLBACK_SHARE.ln(),
            (false, false) if c == STOP_TOOL => PRIOR_FLOOR.ln(),
            // By meaning, the answer has examples of its own (small talk): it is held at
            // its share when that is above the floor. Its share by meaning alone: it has
            // no words of its own for a request's to meet, so blended (the mean with
            // words) it stayed below any tool one word of the request met, however far
            // that tool's meaning: thanks and farewells went to an echo.
            (true, true) if sims.is_some() => (meaning_of(c) / top).max(FALLBACK_SHARE).ln(),
            (true, true) => FALLBACK_SHARE.ln(),
            (true, false) => 0.0,
            (false, true) => (score_of(c) / top).max(PRIOR_FLOOR).ln(),
            (false, false) => PRIOR_FLOOR.ln(),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn spec(name: &str, desc: &str, props: serde_json::Value) -> ToolSpec {
        ToolSpec::new(name, desc, json!({"type": "object", "properties": props})).unwrap()
    }

    fn specs() -> Vec<ToolSpec> {
        let target = |k: &str| json!({ k: {"type": "string"} });
        vec![
            spec("ros_topic_list", "List topics with their types.", json!({})),
            spec("ros_node_list", "List the running nodes.", json!({})),
            spec("calc_stats", "Mean, median of numbers.", json!({})),
            spec("calc_eval", "Evaluate arithmetic.", json!({})),
            spec("system_time", "The current time.", json!({})),
            spec("turtle_move", "Drive the turtle forward.", json!({})),
            spec("turtle_pose", "Where the turtle is.", json!({})),
            spec("ros_service_call", "Call a service.", target("service")),
            spec("reply", "Give the final answer.", json!({})),
        ]
    }

    fn pick(q: &str) -> Vec<String> {
        let names = [("service".to_string(), "/clear".to_string())];
        let s = specs();
        select(q, &s, &names, None, &["reply".into()], 20, |_| 10)
            .into_iter()
            .map(|i| s[i].name.clone())
            .collect()
    }

    #[test]
    fn a_kind_asked_about_in_the_plural_is_not_for_a_tool_that_takes_one() {
        let one = |name: &str, kind: &str| {
            ToolSpec::new(
                name,
                "Read the laser data.",
                json!({"type": "object", "properties": {kind: {"type": "string"}}, "required": [kind]}),
            )
            .unwrap()
        };
        let s = vec![
            spec("ros_topic_list", "List the laser topics.", json!({})),
            one("ros_topic_echo", "topic"),
            one("ros_node_info", "node"),
        ];
        let names = [
            ("topic".to_string(), "/laser/scan".to_string()),
            ("node".to_string(), "/laser_driver".to_string()),
        ];
        let cands = ["ros_topic_list", "ros_topic_echo", "ros_node_info"];
        // Each tool's prior against the listing's.
        let of = |q: &str| {
            let p = prior(q, &s, &names, None, &cands, "reply");
            [p[1] - p[0], p[2] - p[0]]
        };
        // Singular, the echo leads the listing; in the plural, the echo that takes one
        // topic is cut, the node's info (one node) is not.
        let single = of("read the laser topic");
        let plural = of("read the laser topics");
        assert!(plural[0] < single[0] - 0.5, "{single:?} {plural:?}");
        assert!(
            (plural[1] - single[1]).abs() < 1e-9,
            "{single:?} {plural:?}"
        );
        // A topic written whole is the one asked about: nothing is cut.
        let written = of("read the laser topics /laser/scan");
        assert!(written[0] > plural[0] + 0.5, "{written:?} {plural:?}");
        // Spanish says it too.
        assert!(of("lee los topicos del laser")[0] < of("lee el topico del laser")[0] - 0.5);
    }

    #[test]
    fn after_a_result_only_a_better_match_may_follow() {
        let s = specs();
        let names: [(String, String); 0] = [];
        let q = "which topics are there? list them";
        let cands = ["ros_topic_list", "ros_node_list", "turtle_pose"];
        let priors = prior(q, &s, &names, None, &cands, "reply");
        // The best match answered: nothing follows but the answer.
        assert_eq!(beyond(&priors, &priors[..1]), [false, false, false]);
        // One it does not meet answered: those it meets more may follow.
        assert_eq!(beyond(&priors, &priors[2..]), [true, true, false]);
        assert_eq!(beyond(&priors, &priors[1..2]), [true, false, false]);
    }

    #[test]
    fn a_node_and_a_name_take_a_parameter_and_parameters_are_not_read_as_words() {
        let string = json!({"type": "string"});
        let param = spec(
            "param_read",
            "Read a setting.",
            json!({"node": string, "name": string}),
        );
        let place = spec("place_go", "Drive to a place.", json!({"name": string}));
        assert_eq!(name_kinds(&param).collect::<Vec<_>>(), ["node", PARAMETER]);
        assert!(name_kinds(&place).next().is_none());
        // A parameter's words ("grip", "force") do not meet a question about the
        // state that does not say the setting whole: by words, the request meets
        // neither tool.
        let names = vec![(PARAMETER.to_string(), "grip_force".to_string())];
        let scores = lexical(
            "how hard does it grip, with what force",
            &[param, place],
            &names,
        );
        assert_eq!(scores, [0.0, 0.0]);
    }

    #[test]
    fn a_name_written_whole_points_at_the_tools_that_take_it() {
        let s = vec![
            spec("turtle_pose", "Where the turtle is.", json!({})),
            spec(
                "ros_topic_hz",
                "How often a topic is published.",
                json!({"topic": {"type": "string"}}),
            ),
        ];
        let names = [("topic".to_string(), "/turtle1/pose".to_string())];
        let sc = scores("at what rate does /turtle1/pose come in?", &s, &names, None);
        assert!(sc[1] > sc[0], "{sc:?}");
        // Its words alone still point at the tool named for them.
        let sc = scores("tell me the turtle pose", &s, &names, None);
        assert!(sc[0] > sc[1], "{sc:?}");
    }

    #[test]
    fn picks_relevant_tools_within_budget_in_any_language() {
        assert_eq!(pick("which topics exist?"), ["ros_topic_list", "reply"]);
        assert_eq!(pick("what is the mean of 3 and 5"), ["calc_stats", "reply"]);
        assert_eq!(pick("what is 9 times 6?")[0], "calc_eval");
        assert_eq!(pick("mueve la tortuga 1 metro")[0], "turtle_move");
        assert_eq!(pick("dime dónde está ahora la tortuga")[0], "turtle_pose");
        assert_eq!(pick("Zeige die laufenden Knoten")[0], "ros_node_list");
        // The robot's names: the service /clear is what "clear" asks for.
        assert_eq!(pick("please clear all of it")[0], "ros_service_call");
        assert_eq!(pick("hello"), ["reply"]);
        // Everything fits: everything is offered.
        assert_eq!(
            select("hi", &specs(), &[], None, &[], 1000, |_| 10).len(),
            9
        );
    }

    #[test]
    fn the_prior_is_each_tools_share_of_the_best_and_the_answer_a_fixed_one() {
        let s = specs();
        let p = prior(
            "which topics exist?",
            &s,
            &[],
            None,
            &["ros_node_list", "ros_topic_list", "reply"],
            "reply",
        );
        assert_eq!(p[1], 0.0, "{p:?}");
        assert!(p[0] < FALLBACK_SHARE.ln(), "{p:?}");
        assert_eq!(p[2], FALLBACK_SHARE.ln());
        // A request no tool meets: the answer is all the prior allows.
        let p = prior("hello", &s, &[], None, &["ros_node_list", "reply"], "reply");
        assert_eq!(p, [PRIOR_FLOOR.ln(), 0.0]);
    }

    #[test]
    fn a_setting_said_whole_in_words_is_as_written() {
        let names: Vec<(String, String)> = ["stored_positions", "gain_p", "speed"]
            .iter()
            .map(|n| (PARAMETER.to_string(), n.to_string()))
            .collect();
        assert_eq!(
            spelled_parameters("Which stored positions do you know?", &names),
            ["stored_positions"]
        );
        // Half a setting, or a setting of one word, is any word of a sentence.
        assert!(spelled_parameters("what is the gain now, and the speed?", &names).is_empty());
        let getter = spec(
            "ros_param_get",
            "Read a node's setting.",
            json!({"node": {"type": "string"}, "name": {"type": "string"}}),
        );
        let echo = spec(
            "ros_topic_echo",
            "Read the latest messages of a topic.",
            json!({"topic": {"type": "string"}}),
        );
        let mut names = names;
        names.push(("topic".into(), "/arm/positions".into()));
        let setter = spec(
            "ros_param_set",
            "Change a node's setting.",
            json!({"node": {"type": "string"}, "name": {"type": "string"}}),
        );
        let specs = [getter, echo, setter];
        let q = "how many stored positions are there";
        let s = lexical(q, &specs, &names);
        assert!(s[0] > s[1], "{s:?}");
        // Said whole, the setting raises the tool that reads it to the best, not the
        // one that changes it, which the question does not ask for.
        let mut scored = vec![0.2, 1.0, 0.1];
        raise_spelled_setting(q, &specs, &names, &mut scored);
        assert_eq!(scored, [1.0, 1.0, 0.1]);
        let mut scored = vec![0.2, 1.0, 0.1];
        raise_spelled_setting(
            "read the stored positions on /arm/positions",
            &specs,
            &names,
            &mut scored,
        );
        assert_eq!(scored, [0.2, 1.0, 0.1]);
    }

    #[test]
    fn a_kind_asked_of_in_the_plural_points_at_its_listing() {
        let mut listing = spec(
            "ros_service_list",
            "Every service the robot offers.",
            json!({}),
        );
        listing.lists = Some("service".into());
        let s = vec![
            listing,
            spec(
                "robot_health",
                "The robot's health and its nodes.",
                json!({}),
            ),
            spec("reply", "Give the final answer.", json!({})),
        ];
        let cands = ["ros_service_list", "robot_health", "reply"];
        // The encoder and the words lean to the health report ("robot").
        let sims = [0.40, 0.55, 0.1];
        let p = prior(
            "which services does the robot have?",
            &s,
            &[],
            Some(&sims),
            &cands,
            "reply",
        );
        assert_eq!(p[0], 0.0, "{p:?}");
        assert!(p[1] <= ONE_OF_MANY_SHARE.ln(), "{p:?}");
        // A name written: the plural may be about it, nothing is pointed at.
        let p = prior(
            "which services does /gripper_driver have?",
            &s,
            &[],
            Some(&sims),
            &cands,
            "reply",
        );
        assert!(p[1] > ONE_OF_MANY_SHARE.ln(), "{p:?}");
    }

    #[test]
    fn a_tool_waiting_for_a_number_sets_no_bar_for_the_step_that_reads_one() {
        let mut convert = spec(
            "unit_convert",
            "Convert a value in degrees or radians.",
            json!({"value": {"type": "number"}}),
        );
        convert.parameters["required"] = json!(["value"]);
        assert!(convert.waits_for_numbers());
        let s = vec![
            convert,
            spec("joint_read", "Read the joint angles.", json!({})),
            spec("reply", "Give the final answer.", json!({})),
        ];
        let sims = [0.9, 0.4, 0.1];
        let request = "how far is the knee bent, in degrees?";
        let p = prior(
            request,
            &s,
            &[],
            Some(&sims),
            &["joint_read", "reply"],
            "reply",
        );
        assert_eq!(p[0], 0.0, "{p:?}");
        // Offered, it is the bar again.
        let cands = ["unit_convert", "joint_read", "reply"];
        let p = prior(request, &s, &[], Some(&sims), &cands, "reply");
        assert!(p[1] < 0.0 && p[0] == 0.0, "{p:?}");
    }

    #[test]
    fn by_meaning_the_prior_is_weighed_with_the_words() {
        let s = specs();
        let cands = ["ros_topic_list", "ros_node_list", "calc_eval"];
        // The encoder leans a little to the node list; the words say topics.
        let mut sims = vec![0.2; s.len()];
        sims[0] = 0.50;
        sims[1] = 0.52;
        let p = prior("which topics exist?", &s, &[], Some(&sims), &cands, "reply");
        assert!(p[0] > p[1], "{p:?}");
        // Offered: the tools near by meaning, ranked by both; not the rest.
        let offered = select("which topics exist?", &s, &[], Some(&sims), &[], 20, |_| 10);
        assert_eq!(offered, [0, 1]);
        // A tool far by meaning that the words point at as strongly as at the best is
        // offered too.
        let mut far = sims.clone();
        far[5] = -0.5;
        let offered = select("move the turtle", &s, &[], Some(&far), &[], 40, |_| 10);
        assert!(offered.contains(&5), "{offered:?}");
        // Words that meet no tool leave the meaning as it is.
        let p = prior("xyzzy", &s, &[], Some(&sims), &cands, "reply");
        assert!(p[1] > p[0] && p[0] > p[2], "{p:?}");
    }

    #[test]
    fn words_every_tool_has_count_for_little() {
        let s = specs();
        let sc = scores("the turtle", &s, &[], None);
        let turtle = scores("turtle", &s, &[], None);
        let top = turtle.iter().copied().fold(0.0, f64::max);
        for (a, b) in sc.iter().zip(&turtle) {
            assert!((a - b).abs() < 0.2 * top, "{sc:?} {turtle:?}");
        }
    }

    #[test]
    fn an_answer_is_held_to_the_latest_result_the_request_asked_for() {
        // The status (share 1), then the pose the request never named (the floor).
        assert_eq!(grounding(&[0.0, 1e-3f64.ln()]), Some(0));
        // The service's info (share 1), then the list of services (0.56).
        assert_eq!(grounding(&[0.0, 0.56f64.ln()]), Some(0));
        assert_eq!(grounding(&[0.4f64.ln(), 0.0, 0.1f64.ln()]), Some(1));
        // The same tool twice (a read, then a read after a wait): the later one.
        assert_eq!(grounding(&[0.0, 0.5f64.ln(), 0.0]), Some(2));
        assert_eq!(grounding(&[]), None);
    }

    #[test]
    fn an_amount_to_convert_holds_the_pick_to_the_converter_but_not_the_answer() {
        let names = ["stats", "convert", "robot_stop", "reply"];
        let mut prior = vec![0.0, -0.5, -1.0, -1.2];
        hold_to(
            &mut prior,
            &names,
            &[false, true, false, false],
            "reply",
            CONVERTS_ASKED_SHARE,
        );
        assert!(prior[1] > prior[0] + 2.0, "{prior:?}");
        assert_eq!(&prior[1..], [-0.5, -1.0, -1.2]);
        // Nothing converts: nothing is cut.
        let mut same = vec![0.0, -0.5, -1.0, -1.2];
        hold_to(
            &mut same,
            &names,
            &[false; 4],
            "reply",
            CONVERTS_ASKED_SHARE,
        );
        assert_eq!(same, [0.0, -0.5, -1.0, -1.2]);
    }

    #[test]
    fn a_written_name_holds_the_pick_to_the_tools_that_take_it() {
        let declared = vec![
            spec(
                "ros_param_list",
                "List a node's parameters.",
                json!({"node": {"type": "string"}}),
            ),
            spec(
                "ros_param_get",
                "Read one parameter.",
                json!({"node": {"type": "string"}, "name": {"type": "string"}}),
            ),
            spec("reply", "Give the final answer.", json!({})),
        ];
        // As the robot takes them now: the node's parameters are known.
        let mut live = declared.clone();
        live[1].parameters = json!({"type": "object", "properties": {
            "node": {"type": "string", "const": "/arm_controller"},
            "name": {"anyOf": [{"type": "string", "enum": ["max_speed", "payload_kg"]}, {"type": "string"}]}
        }});
        let takes = takes_written("how large is payload_kg on the arm?", &live, &declared);
        assert_eq!(takes, [false, true, false]);
        let names = ["ros_param_list", "ros_param_get", "reply"];
        let mut prior = vec![0.0, -0.1, -1.2];
        hold_to(&mut prior, &names, &takes, "reply", DROPS_WRITTEN_SHARE);
        assert!(prior[1] > prior[0], "{prior:?}");
        // The answer keeps its share; so does every tool when no name is written, or
        // when the written one is no value the robot has.
        assert_eq!(prior[2], -1.2);
        assert_eq!(
            takes_written("how large is the payload?", &live, &declared),
            [false; 3]
        );
        assert_eq!(
            takes_written("read payload_lbs", &live, &declared),
            [false; 3]
        );
        // A value the tool declares (not one of the robot's names) does not count.
        let fixed = vec![spec(
            "ros_log_read",
            "Logs.",
            json!({"level": {"type": "string", "enum": ["info_level"]}}),
        )];
        assert_eq!(
            takes_written("show info_level logs", &fixed, &fixed),
            [false]
        );
    }
}
