//! What an operator's request says, read without a model: which acts it asks for (move,
//! turn, reset, …), which it forbids ("don't move"), and which it only asks about ("is
//! it moving?"), in English, Spanish, French, German, Italian and Portuguese.
//!
//! A request is cut into clauses (at punctuation and at "but", "then", "and" and their
//! translations). A clause that holds a negation ("don't", "no", "ne … pas", "nicht",
//! "never", …) forbids every act it names; a clause that opens with a question word
//! ("how", "is", "dónde", "wo", …) asks about them; any other clause asks for them.
//! "Can you …" and "please …" are requests, not questions.
//!
//! Words are compared folded (lowercase, no accents) and by prefix, so "muévete",
//! "muevas" and "mueve" all meet "muev". The lexicon is of acts a robot performs, not of
//! any one request's wording.

use crate::lexicon::folded_words;

/// Something a request may ask the robot to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Act {
    Move,
    Turn,
    Teleport,
    Pen,
    Reset,
    Spawn,
    Kill,
    Clear,
    Set,
    Publish,
    Call,
    Goal,
    Cancel,
    Stop,
    Fence,
}

/// Folded word prefixes that name each act. A prefix of three letters or fewer matches
/// only a whole word.
const ACTS: &[(Act, &[&str])] = &[
    (
        Act::Move,
        &[
            "move", "drive", "go", "forward", "backward", "advance", "proceed", "travel", "vel",
            "velocity", "muev", "mover", "avanz", "adelant", "retroced", "conduc", "anda",
            "camina", "bouge", "boug", "deplac", "avance", "recul", "conduis", "roule", "beweg",
            "fahr", "vorwart", "ruckwart", "geh", "muov", "avanti", "guida", "sposta", "mova",
            "movi", "anda", "desloc",
        ],
    ),
    (
        Act::Turn,
        &[
            "turn", "rotat", "spin", "face", "pivot", "gira", "girar", "gire", "giro", "vuelta",
            "rota", "tourn", "pivote", "dreh", "wend", "ruot", "volta",
        ],
    ),
    (
        Act::Teleport,
        &[
            "teleport",
            "teletransport",
            "place",
            "jump",
            "coloca",
            "platzier",
            "posiziona",
            "posicion",
        ],
    ),
    (
        Act::Pen,
        &[
            "pen", "draw", "colou", "color", "lapiz", "dibuj", "stylo", "dessin", "couleur",
            "stift", "zeichne", "farbe", "penna", "disegn", "colore", "caneta", "desenh",
        ],
    ),
    (
        Act::Reset,
        &[
            "reset",
            "restart",
            "reinici",
            "restablec",
            "reinitialis",
            "zurucksetz",
            "neustart",
            "ripristin",
            "redefin",
        ],
    ),
    (
        Act::Spawn,
        &[
            "spawn", "create", "crea", "agrega", "anade", "ajoute", "erzeug", "aggiung", "cria",
            "adicion",
        ],
    ),
    (
        Act::Kill,
        &[
            "kill", "remove", "delete", "destroy", "elimin", "borra", "mata", "supprim", "tue",
            "losch", "entfern", "cancell", "uccid", "remov",
        ],
    ),
    (
        Act::Clear,
        &[
            "clear", "erase", "limpia", "borrar", "efface", "nettoie", "pulisci", "limpa", "apaga",
        ],
    ),
    (
        Act::Set,
        &[
            "set", "change", "configur", "adjust", "increase", "decrease", "raise", "lower",
            "cambia", "establec", "ajusta", "pon", "modific", "regle", "chang", "setze", "ander",
            "stell", "imposta", "altera", "defin", "aument", "diminu", "baja", "sube",
        ],
    ),
    (
        Act::Publish,
        &[
            "publish",
            "send",
            "publica",
            "envia",
            "publie",
            "envoie",
            "sende",
            "veroffentlich",
            "pubblica",
            "invia",
        ],
    ),
    (
        Act::Call,
        &[
            "call", "trigger", "run", "invoke", "execut", "llama", "ejecut", "appel", "lance",
            "ruf", "aufruf", "fuhr", "chiama", "esegu", "chama",
        ],
    ),
    (
        Act::Goal,
        &[
            "goal",
            "action",
            "objetivo",
            "meta",
            "objectif",
            "ziel",
            "obiettivo",
        ],
    ),
    (
        Act::Cancel,
        &["cancel", "abort", "anula", "annul", "abbrech", "annulla"],
    ),
    (
        Act::Stop,
        &[
            "stop",
            "halt",
            "freeze",
            "brake",
            "emergency",
            "estop",
            "e-stop",
            "detente",
            "deten",
            "alto",
            "arret",
            "arrete",
            "stopp",
            "anhalt",
            "ferma",
            "fermati",
        ],
    ),
    (
        Act::Fence,
        &["avoid", "evita", "evite", "meide", "vermeid", "evitare"],
    ),
];

/// Stop words too ambiguous to count anywhere but at a clause's start ("para" is also
/// "for", "halt" a German filler, "pare" Portuguese for "stop" and Spanish for "seem").
const STOP_AT_START: &[&str] = &[
    "para", "parar", "pare", "halte", "wait", "espera", "attends", "warte", "aspetta",
];

/// Words that make a clause a negation.
const NEGATIONS: &[&str] = &[
    // "t" is what is left of "n't" ("can't", "shouldn't", "won't") once split at the
    // apostrophe.
    "not", "don", "dont", "t", "never", "no", "without", "neither", "nor", "nothing", "nunca",
    "jamas", "sin", "ni", "tampoco", "ne", "pas", "jamais", "sans", "aucun", "nicht", "kein",
    "keine", "keinen", "nie", "niemals", "ohne", "non", "mai", "senza", "niente", "nao", "nem",
    "sem",
];

/// Words that open a question about the world (not a request).
const QUESTION_WORDS: &[&str] = &[
    "how", "what", "where", "which", "who", "when", "why", "is", "are", "was", "were", "does",
    "do", "did", "has", "have", "que", "como", "donde", "cuando", "cuanto", "cuanta", "cual",
    "quien", "esta", "es", "quel", "quelle", "ou", "combien", "quand", "pourquoi", "est", "wie",
    "was", "wo", "welche", "welcher", "wann", "warum", "ist", "sind", "cosa", "dove", "quanto",
    "quale", "chi", "perche", "onde", "quando", "qual", "porque",
];

/// Words that cut a request into clauses.
const CONJUNCTIONS: &[&str] = &[
    "but", "then", "and", "or", "pero", "luego", "despues", "y", "o", "mais", "puis", "et", "ou",
    "aber", "dann", "und", "oder", "ma", "poi", "e", "mas", "depois",
];

/// Conjunctions that join alternatives.
const DISJUNCTIONS: &[&str] = &[
    "or", "nor", "o", "ni", "ou", "oder", "weder", "noch", "oppure",
];

/// Words that turn a sentence around ("don't move, just turn"): a clause they open does
/// not take the negation or the question of the clause before it.
const CONTRASTS: &[&str] = &[
    "but",
    "then",
    "just",
    "only",
    "instead",
    "pero",
    "luego",
    "despues",
    "solo",
    "mais",
    "puis",
    "seulement",
    "plutot",
    "aber",
    "dann",
    "nur",
    "sondern",
    "stattdessen",
    "ma",
    "poi",
    "invece",
    "mas",
    "depois",
    "apenas",
    "sino",
];

/// Verbs that ask to be told, not to act ("explain how to move it").
const TELL: &[&str] = &[
    "explain",
    "tell",
    "describe",
    "show",
    "teach",
    "explica",
    "dime",
    "describe",
    "explique",
    "dis",
    "decris",
    "erklare",
    "erklaer",
    "sag",
    "beschreibe",
    "spiega",
    "dimmi",
    "descrivi",
    "diga",
    "descreva",
];

/// How a clause treats an act.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mood {
    /// Asks for it.
    Asked,
    /// Forbids it.
    Forbidden,
    /// Asks about it.
    Questioned,
}

/// One clause of a request.
#[derive(Debug, Clone, PartialEq)]
pub struct Clause {
    /// Its folded words.
    pub words: Vec<String>,
    pub acts: Vec<Act>,
    pub mood: Mood,
}

/// Whether `word` (folded) names `prefix`: by prefix, or whole for short prefixes.
pub fn word_matches(word: &str, prefix: &str) -> bool {
    if prefix.len() <= 3 {
        word == prefix
    } else {
        word.starts_with(prefix)
    }
}

/// The acts `words` (folded) name.
pub fn acts_of(words: &[String]) -> Vec<Act> {
    let mut acts: Vec<Act> = ACTS
        .iter()
        .filter(|(_, prefixes)| {
            words
                .iter()
                .any(|w| prefixes.iter().any(|p| word_matches(w, p)))
        })
        .map(|(a, _)| *a)
        .collect();
    if words
        .first()
        .is_some_and(|w| STOP_AT_START.contains(&w.as_str()))
    {
        acts.push(Act::Stop);
    }
    acts.sort();
    acts.dedup();
    acts
}

/// The clauses of `request`. Within one sentence a negation or a question carries on
/// into the clauses that follow ("don't move or turn", "is it moving or turning?",
/// "do not move, rotate or teleport it") unless one opens with a contrast ("but",
/// "just", "instead"): read this way a mistake blocks a motion, never allows one.
pub fn clauses(request: &str) -> Vec<Clause> {
    let mut out = Vec::new();
    for sentence in request.split_inclusive(['.', ';', '!', '?', '\n']) {
        let question_mark = sentence.trim_end().ends_with('?');
        let mut carried: Option<Mood> = None;
        // Clauses joined by "or": a negation anywhere among them governs them all
        // ("bewege oder drehe sie nicht").
        let mut alternatives = out.len();
        for part in sentence.split([',', ':']) {
            let mut current: Vec<String> = Vec::new();
            let mut contrast = false;
            for w in folded_words(part) {
                if CONJUNCTIONS.contains(&w.as_str()) {
                    carried = push_clause(
                        &mut out,
                        std::mem::take(&mut current),
                        question_mark,
                        carried,
                        contrast,
                    );
                    forbid_alternatives(&mut out, alternatives);
                    if !DISJUNCTIONS.contains(&w.as_str()) {
                        alternatives = out.len();
                    }
                    contrast = CONTRASTS.contains(&w.as_str());
                } else {
                    if current.is_empty() && CONTRASTS.contains(&w.as_str()) {
                        contrast = true;
                    }
                    current.push(w);
                }
            }
            carried = push_clause(&mut out, current, question_mark, carried, contrast);
            forbid_alternatives(&mut out, alternatives);
        }
    }
    out
}

/// When the newest clause forbids, so do the alternatives before it (from `from` on).
fn forbid_alternatives(out: &mut [Clause], from: usize) {
    if out.last().is_some_and(|c| c.mood == Mood::Forbidden) {
        for c in out.iter_mut().skip(from) {
            if c.mood == Mood::Asked {
                c.mood = Mood::Forbidden;
            }
        }
    }
}

/// Add the clause of `words`; the mood the next clause of the sentence may take on.
fn push_clause(
    out: &mut Vec<Clause>,
    words: Vec<String>,
    question_mark: bool,
    carried: Option<Mood>,
    contrast: bool,
) -> Option<Mood> {
    if words.is_empty() {
        return carried;
    }
    let acts = acts_of(&words);
    let negated = words.iter().any(|w| NEGATIONS.contains(&w.as_str()));
    // A question word before the first act ("how do I move", "explain how to move").
    let first_act = words
        .iter()
        .position(|w| !acts_of(std::slice::from_ref(w)).is_empty())
        .unwrap_or(words.len());
    let asks_about = words[..first_act]
        .iter()
        .any(|w| QUESTION_WORDS.contains(&w.as_str()) || TELL.contains(&w.as_str()))
        && !words
            .first()
            .is_some_and(|w| STOP_AT_START.contains(&w.as_str()));
    let inherited = carried.filter(|_| !contrast);
    let mood = if negated || inherited == Some(Mood::Forbidden) {
        Mood::Forbidden
    } else if asks_about
        || inherited == Some(Mood::Questioned)
        || (question_mark && acts.is_empty())
    {
        Mood::Questioned
    } else {
        Mood::Asked
    };
    // "Avoid moving": avoiding is an act of its own (fencing a name off); what it is
    // said of is forbidden.
    if acts.contains(&Act::Fence) && acts.len() > 1 && mood == Mood::Asked {
        let others: Vec<Act> = acts.iter().copied().filter(|a| *a != Act::Fence).collect();
        out.push(Clause {
            words: words.clone(),
            acts: others,
            mood: Mood::Forbidden,
        });
        out.push(Clause {
            words,
            acts: vec![Act::Fence],
            mood: Mood::Asked,
        });
        return Some(Mood::Forbidden);
    }
    out.push(Clause { words, acts, mood });
    (mood != Mood::Asked).then_some(mood)
}

/// How a folded word joins what follows to what came before: `Some(true)` when it
/// only chains ("and", "then", "puis"), `Some(false)` when it joins alternatives or
/// turns the sentence around ("or", "but"), `None` when it is no conjunction.
pub fn chains(word: &str) -> Option<bool> {
    CONJUNCTIONS.contains(&word).then(|| {
        !DISJUNCTIONS.contains(&word) && (!CONTRASTS.contains(&word) || SEQUENCERS.contains(&word))
    })
}

/// Contrasts that only order what is asked ("then", "luego", "dann").
const SEQUENCERS: &[&str] = &["then", "luego", "despues", "puis", "dann", "poi", "depois"];

/// Whether a folded word can open a request of its own: it asks ("what", "wo"), asks to
/// be told ("tell", "dime") or names an act ("move", "gira").
pub fn opens_request(word: &str) -> bool {
    QUESTION_WORDS.contains(&word)
        || TELL.contains(&word)
        || !acts_of(std::slice::from_ref(&word.to_string())).is_empty()
}

/// Acts the request asks for (in some clause, and forbidden in none).
pub fn asked_acts(clauses: &[Clause]) -> Vec<Act> {
    let mut acts: Vec<Act> = clauses
        .iter()
        .filter(|c| c.mood == Mood::Asked)
        .flat_map(|c| c.acts.iter().copied())
        .filter(|a| {
            !clauses
                .iter()
                .any(|c| c.mood == Mood::Forbidden && c.acts.contains(a))
        })
        .collect();
    acts.sort();
    acts.dedup();
    acts
}

/// Whether the request, read on its own, asks the robot to stop.
pub fn asks_to_stop(request: &str) -> bool {
    asked_acts(&clauses(request)).contains(&Act::Stop)
}

/// Whether the operator's `request` asks the robot to stop: a stop phrase
/// (`stop_intent`, the words operators use) or a clause that asks for the stop act
/// (`asks_to_stop`). What every channel checks before anything else, the agent's run
/// included.
pub fn operator_stops(request: &str) -> bool {
    crate::stop_intent::asks_to_stop(request) || asks_to_stop(request)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn asked(q: &str) -> Vec<Act> {
        asked_acts(&clauses(q))
    }

    #[test]
    fn requests_negations_and_questions() {
        assert_eq!(asked("move the turtle forward 2 meters"), [Act::Move]);
        assert!(asked("don't move the turtle").is_empty());
        assert!(asked("do not move the turtle").is_empty());
        assert!(asked("how much battery is left?").is_empty());
        assert!(asked("is the turtle moving?").is_empty());
        assert_eq!(asked("can you move the turtle?"), [Act::Move]);
        assert_eq!(asked("move forward but don't turn"), [Act::Move]);
        assert_eq!(asked("stop the turtle now"), [Act::Stop]);
        assert!(asks_to_stop("STOP!") && asks_to_stop("halt") && !asks_to_stop("don't stop"));
        assert!(!asks_to_stop("why did it stop?"));
    }

    #[test]
    fn negations_and_questions_reach_every_act_they_govern() {
        for q in [
            "don't move or turn the turtle",
            "do not move, rotate or teleport it",
            "it shouldn't move",
            "you can't turn it",
            "is it moving or turning?",
            "explain how to move the turtle",
            "tell me how to turn it",
            "avoid moving the turtle",
            "bewege oder drehe die Schildkröte nicht",
        ] {
            let acts = asked(q);
            assert!(
                !acts.contains(&Act::Move) && !acts.contains(&Act::Turn),
                "{q}: {acts:?}"
            );
        }
        assert_eq!(asked("don't move, just turn left"), [Act::Turn]);
        assert_eq!(asked("don't turn but move forward 1 m"), [Act::Move]);
        assert_eq!(
            asked("move forward, then turn left"),
            [Act::Move, Act::Turn]
        );
        assert_eq!(
            asked("Bewege die Schildkröte 1 Meter vorwärts"),
            [Act::Move]
        );
    }

    #[test]
    fn other_languages() {
        assert_eq!(
            asked("Bewege die Schildkröte 1 Meter vorwärts"),
            [Act::Move]
        );
        assert!(asked("Bewege die Schildkröte nicht").is_empty());
        assert_eq!(
            asked("mueve la tortuga 1 metro hacia adelante"),
            [Act::Move]
        );
        assert!(asked("no muevas la tortuga").is_empty());
        assert_eq!(asked("fais tourner la tortue de 90 degrés"), [Act::Turn]);
        assert!(asked("ne bouge pas la tortue").is_empty());
        assert_eq!(asked("gira la tartaruga di 90 gradi"), [Act::Turn]);
        assert!(
            asks_to_stop("para la tortuga") && asks_to_stop("arrête") && asks_to_stop("Stopp!")
        );
        assert!(!asks_to_stop("avanza 2 metros para probar"));
        assert!(asked("¿dónde está la tortuga?").is_empty());
    }
}
