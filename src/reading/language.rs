//! The language an answer is written in: the one the operator set (`--lang`), else the
//! request's own, read from its words.
//!
//! A request is read for the six languages `concepts` reads. The evidence is each
//! language's closed-class words (articles, prepositions, pronouns, question words and
//! the commonest verb forms: the words every sentence of a language is made of, not the
//! words of any request) and the letters only some languages write ("ñ", "ß", "ã"). A
//! word several languages share counts for each of them in part ("la" is Spanish,
//! French and Italian). ROS names (`/turtle1/pose`, `background_r`) and numbers are no
//! evidence. A request with no evidence, or evidence split evenly, is English.
//!
//! The language decides three things: the note that asks the model to answer in it,
//! whether the model's answer is in it (`Language::differs`: an answer plainly in
//! another language is replaced by the result, as an answer that states none of the
//! result's facts is), and the words the agent writes itself around a result
//! (`Phrase`).

use crate::lexicon::fold;

/// A language the agent answers in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Language {
    #[default]
    English,
    Spanish,
    French,
    German,
    Italian,
    Portuguese,
}

/// Every language, in the order of `NAMES` and `WORDS`.
pub(crate) const ALL: [Language; 6] = [
    Language::English,
    Language::Spanish,
    Language::French,
    Language::German,
    Language::Italian,
    Language::Portuguese,
];

/// Each language's ISO 639-1 code, name in English (as the model is told it), own name
/// folded, and code in the trigram detector.
const NAMES: [(&str, &str, &str, whatlang::Lang); 6] = [
    ("en", "English", "english", whatlang::Lang::Eng),
    ("es", "Spanish", "espanol", whatlang::Lang::Spa),
    ("fr", "French", "francais", whatlang::Lang::Fra),
    ("de", "German", "deutsch", whatlang::Lang::Deu),
    ("it", "Italian", "italiano", whatlang::Lang::Ita),
    ("pt", "Portuguese", "portugues", whatlang::Lang::Por),
];

/// Closed-class words of each language, folded (lowercase, no accents).
const WORDS: [&[&str]; 6] = [
    // English
    &[
        "the", "a", "an", "is", "are", "was", "what", "which", "who", "where", "how", "of", "to",
        "in", "on", "and", "me", "my", "it", "its", "does", "do", "can", "you", "please", "from",
        "with", "for", "this", "that", "there", "many", "much", "tell", "show", "give", "now",
        "your", "has", "have", "at", "by", "then", "all", "any", "some", "i", "be",
    ],
    // Spanish
    &[
        "el",
        "la",
        "los",
        "las",
        "un",
        "una",
        "unos",
        "de",
        "del",
        "que",
        "donde",
        "esta",
        "estan",
        "cual",
        "cuales",
        "como",
        "cuantos",
        "cuantas",
        "es",
        "son",
        "por",
        "para",
        "con",
        "en",
        "y",
        "mi",
        "me",
        "hacia",
        "a",
        "muestra",
        "muestrame",
        "dime",
        "dame",
        "hay",
        "ahora",
        "tu",
        "su",
        "al",
        "lo",
        "se",
    ],
    // French
    &[
        "le",
        "la",
        "les",
        "un",
        "une",
        "des",
        "du",
        "de",
        "quels",
        "quelles",
        "quel",
        "quelle",
        "ou",
        "est",
        "sont",
        "et",
        "pour",
        "avec",
        "dans",
        "sur",
        "moi",
        "montre",
        "montrez",
        "donne",
        "donnez",
        "combien",
        "qui",
        "que",
        "au",
        "aux",
        "il",
        "y",
        "a",
        "ce",
        "cette",
        "maintenant",
        "votre",
        "ton",
        "ta",
        "tes",
        "vos",
        "se",
        "en",
    ],
    // German
    &[
        "der", "die", "das", "den", "dem", "des", "ein", "eine", "einen", "einem", "und", "ist",
        "sind", "wie", "wo", "was", "welche", "welcher", "welches", "wer", "zeige", "zeig", "mir",
        "bitte", "nach", "mit", "auf", "fur", "von", "zu", "im", "jetzt", "gib", "sag", "wieviele",
        "viele", "es", "um", "dich", "dir", "ich", "kannst", "kann", "bist", "hast", "nicht",
        "auch", "noch", "alles", "mein", "dein",
    ],
    // Italian
    &[
        "il", "lo", "la", "i", "gli", "le", "un", "una", "di", "del", "della", "dei", "delle",
        "che", "dove", "qual", "quale", "quali", "e", "sono", "per", "con", "mostra", "mostrami",
        "dimmi", "dammi", "quanti", "quante", "come", "ora", "adesso", "al", "alla", "nel", "su",
        "chi", "si", "a",
    ],
    // Portuguese
    &[
        "o", "a", "os", "as", "um", "uma", "de", "do", "da", "dos", "das", "que", "onde", "qual",
        "quais", "esta", "e", "sao", "para", "com", "mostre", "mostra", "me", "diga", "quantos",
        "quantas", "como", "agora", "no", "na", "em", "ao", "se", "voce",
    ],
];

/// Letters only some of the languages write, with the languages that write them.
const LETTERS: &[(char, &[Language])] = &[
    ('ñ', &[Language::Spanish]),
    ('¿', &[Language::Spanish]),
    ('¡', &[Language::Spanish]),
    ('ß', &[Language::German]),
    ('ä', &[Language::German]),
    ('ö', &[Language::German]),
    ('ü', &[Language::German]),
    ('ã', &[Language::Portuguese]),
    ('õ', &[Language::Portuguese]),
    ('ç', &[Language::French, Language::Portuguese]),
    ('è', &[Language::French, Language::Italian]),
    ('ê', &[Language::French, Language::Portuguese]),
    (
        'à',
        &[Language::French, Language::Italian, Language::Portuguese],
    ),
    ('ù', &[Language::French, Language::Italian]),
    ('ò', &[Language::Italian]),
    ('ì', &[Language::Italian]),
];

impl Language {
    /// ISO 639-1 code.
    pub fn code(self) -> &'static str {
        NAMES[self as usize].0
    }

    /// The language's name in English, as the model is told it.
    pub fn name(self) -> &'static str {
        NAMES[self as usize].1
    }

    /// A language by its code or its name, in English or in itself ("es", "Spanish",
    /// "español").
    pub fn parse(text: &str) -> Result<Language, String> {
        let t = fold(text.trim());
        let found = ALL.into_iter().find(|l| {
            let (code, name, own, _) = NAMES[*l as usize];
            t == code || t == name.to_lowercase() || t == own
        });
        found.ok_or_else(|| {
            let codes: Vec<&str> = ALL.iter().map(|l| l.code()).collect();
            format!(
                "unknown language {text:?}: use auto or one of {}",
                codes.join(", ")
            )
        })
    }

    /// The language `text` is written in, when it shows one more than any other. When
    /// several show the most ("pivote doucement la tortue de trente degrés": "la" and
    /// "de" are French and Spanish), the text's letter trigrams choose among them
    /// (`whatlang`, kept to the tied languages: on a short request its own guess across
    /// all languages is often wrong).
    pub fn of(text: &str) -> Option<Language> {
        let prose = prose(text);
        chosen(&evidence(&prose), &prose)
    }

    /// The language a request's answer is written in: `set`, else the request's own,
    /// else English.
    pub(crate) fn for_request(set: Option<Language>, request: &str) -> Language {
        set.or_else(|| Language::of(request)).unwrap_or_default()
    }

    /// Whether `text` is plainly in another language than this one: it shows another
    /// language clearly (`of`) and this one in at most half as much.
    pub fn differs(self, text: &str) -> bool {
        let prose = prose(text);
        let scores = evidence(&prose);
        let mine = scores[self as usize];
        match chosen(&scores, &prose) {
            Some(other) if other != self => mine * 2.0 <= scores[other as usize],
            _ => false,
        }
    }

    /// The note that asks the model to answer in this language: none for English, the
    /// language of the prompt.
    pub fn note(self) -> Option<String> {
        (self != Language::English).then(|| format!("(Answer in {}.)", self.name()))
    }

    /// A result's `summary` given as the answer: led by "Result" in this language, so
    /// the operator reads a sentence in their own; in English, the summary alone (as it
    /// is written).
    pub(crate) fn lead(self, summary: &str) -> String {
        match self {
            Language::English => summary.to_string(),
            _ => format!("{}: {summary}", self.say(Phrase::Result)),
        }
    }

    /// What the agent writes itself, in this language.
    pub fn say(self, phrase: Phrase) -> String {
        use Language::*;
        match phrase {
            Phrase::Result => match self {
                English => "Result",
                Spanish => "Resultado",
                French => "Résultat",
                German => "Ergebnis",
                Italian => "Risultato",
                Portuguese => "Resultado",
            }
            .to_string(),
            Phrase::LastResult => match self {
                English => "Last result",
                Spanish => "Último resultado",
                French => "Dernier résultat",
                German => "Letztes Ergebnis",
                Italian => "Ultimo risultato",
                Portuguese => "Último resultado",
            }
            .to_string(),
            Phrase::NothingYet => match self {
                English => "No tool returned anything yet.",
                Spanish => "Ninguna herramienta ha devuelto nada todavía.",
                French => "Aucun outil n'a encore rien renvoyé.",
                German => "Noch kein Werkzeug hat etwas zurückgegeben.",
                Italian => "Nessuno strumento ha ancora restituito nulla.",
                Portuguese => "Nenhuma ferramenta devolveu nada ainda.",
            }
            .to_string(),
            Phrase::Cancelled => match self {
                English => "Cancelled.",
                Spanish => "Cancelado.",
                French => "Annulé.",
                German => "Abgebrochen.",
                Italian => "Annullato.",
                Portuguese => "Cancelado.",
            }
            .to_string(),
            Phrase::EStopped => match self {
                English => "The e-stop was engaged: the robot stopped, and motion stays refused until the operator resets it.",
                Spanish => "Se activó la parada de emergencia: el robot se detuvo y el movimiento queda rechazado hasta que el operador la restablezca.",
                French => "L'arrêt d'urgence a été enclenché : le robot s'est arrêté, et tout mouvement reste refusé jusqu'à ce que l'opérateur le réarme.",
                German => "Der Not-Halt wurde ausgelöst: Der Roboter hat angehalten, und Bewegung bleibt verweigert, bis der Bediener ihn zurücksetzt.",
                Italian => "È stato attivato l'arresto di emergenza: il robot si è fermato e il movimento resta rifiutato finché l'operatore non lo ripristina.",
                Portuguese => "A parada de emergência foi acionada: o robô parou, e o movimento continua recusado até o operador a rearmar.",
            }
            .to_string(),
            Phrase::StoppedAfter(1) => match self {
                English => "I stopped after one step without a final answer.",
                Spanish => "Me detuve tras un paso sin una respuesta final.",
                French => "Je me suis arrêté après une étape sans réponse finale.",
                German => "Ich habe nach einem Schritt ohne endgültige Antwort aufgehört.",
                Italian => "Mi sono fermato dopo un passo senza una risposta finale.",
                Portuguese => "Parei após um passo sem uma resposta final.",
            }
            .to_string(),
            Phrase::StoppedAfter(n) => match self {
                English => format!("I stopped after {n} steps without a final answer."),
                Spanish => format!("Me detuve tras {n} pasos sin una respuesta final."),
                French => format!("Je me suis arrêté après {n} étapes sans réponse finale."),
                German => format!("Ich habe nach {n} Schritten ohne endgültige Antwort aufgehört."),
                Italian => format!("Mi sono fermato dopo {n} passi senza una risposta finale."),
                Portuguese => format!("Parei após {n} passos sem uma resposta final."),
            },
        }
    }
}

/// Words the agent writes itself around what tools returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phrase {
    /// Leads a result's summary given as the answer in place of the model's.
    Result,
    /// Leads the last result of a run that ended without an answer.
    LastResult,
    /// A run ended before any tool returned.
    NothingYet,
    /// The operator cancelled the run.
    Cancelled,
    /// The run reached its step limit.
    StoppedAfter(usize),
    /// The e-stop was pressed while the run went on.
    EStopped,
}

/// The language `scores` (the evidence of the words `prose`) show more than any other;
/// a tie is settled by letter trigrams (see `Language::of`).
fn chosen(scores: &[f64; 6], prose: &[&str]) -> Option<Language> {
    let top = scores.iter().copied().fold(0.0, f64::max);
    if top <= 0.0 {
        return None;
    }
    let tied: Vec<Language> = ALL
        .into_iter()
        .filter(|l| scores[*l as usize] == top)
        .collect();
    if let [only] = tied[..] {
        return Some(only);
    }
    let allow = tied.iter().map(|l| NAMES[*l as usize].3).collect();
    let guess = whatlang::Detector::with_allowlist(allow).detect_lang(&prose.join(" "))?;
    tied.into_iter().find(|l| NAMES[*l as usize].3 == guess)
}

/// Each language's evidence in `prose` (the words `prose` keeps), in the order of `ALL`.
fn evidence(prose: &[&str]) -> [f64; 6] {
    let mut scores = [0.0; 6];
    for c in prose
        .iter()
        .flat_map(|t| t.chars())
        .flat_map(char::to_lowercase)
    {
        if let Some((_, langs)) = LETTERS.iter().find(|(l, _)| *l == c) {
            for l in *langs {
                scores[*l as usize] += 1.0 / langs.len() as f64;
            }
        }
    }
    for word in crate::lexicon::folded_words(&prose.join(" ")) {
        let langs: Vec<usize> = (0..ALL.len())
            .filter(|&i| WORDS[i].contains(&word.as_str()))
            .collect();
        for &i in &langs {
            scores[i] += 1.0 / langs.len() as f64;
        }
    }
    scores
}

/// The words of `text` that say something of its language: not ROS names or field
/// paths (`pose.y`), and not a single letter before a number, which labels a value
/// ("y 5.5" is a coordinate, not Spanish "and").
fn prose(text: &str) -> Vec<&str> {
    let tokens: Vec<&str> = text.split_whitespace().collect();
    let number = |t: &str| {
        t.trim_matches(|c: char| !c.is_ascii_digit() && c != '.' && c != '-')
            .parse::<f64>()
            .is_ok()
    };
    tokens
        .iter()
        .enumerate()
        .filter(|(i, t)| {
            let label = t.chars().filter(|c| c.is_alphabetic()).count() == 1
                && tokens.get(i + 1).is_some_and(|n| number(n));
            !t.contains(['/', '_']) && !dotted(t) && !label
        })
        .map(|(_, t)| *t)
        .collect()
}

/// Whether `token` is a dotted path (`pose.y`, `entries.0.msg`): a dot with a letter or
/// digit on each side.
fn dotted(token: &str) -> bool {
    let c: Vec<char> = token.chars().collect();
    c.windows(3).any(|w| {
        w[1] == '.'
            && w[0].is_alphanumeric()
            && w[2].is_alphanumeric()
            && !(w[0].is_ascii_digit() && w[2].is_ascii_digit())
    })
}

#[cfg(test)]
mod tests {
    use super::Language::*;
    use super::*;

    #[test]
    fn requests_are_read_in_their_language() {
        let cases = [
            ("show me the running ROS nodes", Some(English)),
            ("which node sends /turtle1/pose?", Some(English)),
            ("muestra los nodos de ROS activos", Some(Spanish)),
            ("¿dónde se encuentra la tortuga ahora?", Some(Spanish)),
            ("quels topics sont publiés ?", Some(French)),
            ("pivote doucement la tortue de trente degrés", Some(French)),
            ("Welche ROS-Knoten laufen gerade?", Some(German)),
            ("Fahre die Schildkröte zwei Meter nach vorne", Some(German)),
            // "du" is French alone: German's own words say it.
            ("was kannst du für mich tun?", Some(German)),
            ("position du robot ?", Some(French)),
            ("qual è lo stato della batteria?", Some(Italian)),
            ("mostre os tópicos do robô", Some(Portuguese)),
            // "a" is a preposition of four of them, an article of English.
            ("sigue a la izquierda 20 metros", Some(Spanish)),
            ("va a destra per 3 metri", Some(Italian)),
            // Names and numbers alone say nothing.
            ("/turtle1/pose 2.0", None),
            ("battery?", None),
        ];
        for (text, want) in cases {
            assert_eq!(Language::of(text), want, "{text}");
        }
        assert_eq!(Language::for_request(None, "battery?"), English);
        assert_eq!(
            Language::for_request(Some(German), "list the nodes"),
            German
        );
    }

    #[test]
    fn an_answer_in_another_language_differs() {
        assert!(Spanish.differs("The turtle is at x 5.5 and y 5.5."));
        assert!(!Spanish.differs("La tortuga está en x 5.5 y y 5.5."));
        // Data alone is in every language.
        assert!(!Spanish.differs("x 5.544, y 5.544, theta_deg 0.0"));
        assert!(!Spanish.differs("1 node: /turtlesim"));
        // A coordinate's label is no word of any language.
        assert_eq!(Language::of("x 5.544, y 5.544, theta_deg 0.0"), None);
        assert_eq!(Language::of("pose.x: 6.52, pose.y: 5.544"), None);
        assert_eq!(
            Language::of("gira 90 grados y avanza 1 metro"),
            Some(Spanish)
        );
        assert!(!English.differs("1 node: /turtlesim"));
        assert!(English.differs("Hay un nodo: /turtlesim, y está activo."));
    }

    #[test]
    fn languages_parse_by_code_or_name() {
        assert_eq!(Language::parse("es"), Ok(Spanish));
        assert_eq!(Language::parse("Español"), Ok(Spanish));
        assert_eq!(Language::parse("german"), Ok(German));
        let e = Language::parse("klingon").unwrap_err();
        assert!(e.contains("auto") && e.contains("pt"), "{e}");
        assert_eq!(Spanish.note().as_deref(), Some("(Answer in Spanish.)"));
        assert_eq!(English.note(), None);
    }
}
