//! Units of measure: the table (`data/units.toml`: each unit's kind, its offset and
//! factor to its kind's base, its symbols and its names in six languages), conversion
//! between units of one kind, and reading units out of text: the amounts a request
//! writes ("50 cm", "10km/h", "drei Grad") and the unit a tool's argument declares in
//! its description or name ("Meters to drive", "Speed in m/s", `theta_deg`).
//!
//! `calc_convert` converts with it; `reading::bound` holds a conversion's units and an
//! argument's amount to what the request writes.

use serde::Deserialize;

use crate::lexicon::{fold, is_number, number_word};

/// A unit (`data/units.toml`): its kind, its offset and factor to the kind's base unit
/// (base = (value + offset) * factor), and its spellings.
#[derive(Debug, Deserialize)]
pub(crate) struct Unit {
    /// Written the same in every language; the first as the prompt shows it.
    pub symbols: Vec<String>,
    pub kind: String,
    #[serde(default)]
    offset: f64,
    factor: f64,
    /// Its names that are also everyday words ("second", "nœud"): the unit only right
    /// after a number.
    #[serde(default)]
    everyday: Vec<String>,
    /// The unit's names in each language (`en`, `es`, ...).
    #[serde(flatten)]
    names: std::collections::BTreeMap<String, Vec<String>>,
}

impl Unit {
    pub fn spellings(&self) -> impl Iterator<Item = &str> {
        self.symbols
            .iter()
            .chain(self.names.values().flatten())
            .map(String::as_str)
    }

    /// Whether a value of this unit keeps its meaning with its sign turned (a length,
    /// an angle; not a temperature on a scale with an offset).
    pub fn signed(&self) -> bool {
        self.offset == 0.0
    }
}

#[derive(Deserialize)]
struct Units {
    unit: Vec<Unit>,
}

/// The units of `data/units.toml`, parsed once (a test parses it, so a bad edit fails
/// there first).
pub(crate) fn table() -> &'static [Unit] {
    static TABLE: std::sync::OnceLock<Vec<Unit>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let units: Units = toml::from_str(include_str!("../data/units.toml"))
            .unwrap_or_else(|e| panic!("data/units.toml: {e}"));
        units.unit
    })
}

/// Whether `u` is one of a unit's spellings, folded and without surrounding space.
fn spelled(u: &Unit, written: &str) -> bool {
    let written = fold(written.trim());
    u.spellings().any(|s| fold(s) == written)
}

/// The unit `written` spells, if any.
pub(crate) fn unit(written: &str) -> Option<&'static Unit> {
    table().iter().find(|u| spelled(u, written))
}

/// The kinds of quantity, in the table's order.
pub(crate) fn kinds() -> Vec<&'static str> {
    let mut kinds: Vec<&str> = Vec::new();
    for u in table() {
        if !kinds.contains(&u.kind.as_str()) {
            kinds.push(&u.kind);
        }
    }
    kinds
}

/// Every spelling of a unit of `kind`, each once, as the data writes it.
pub(crate) fn spellings(kind: &str) -> Vec<&'static str> {
    let mut out: Vec<&str> = Vec::new();
    for s in table()
        .iter()
        .filter(|u| u.kind == kind)
        .flat_map(Unit::spellings)
    {
        if !out.iter().any(|o| fold(o) == fold(s)) {
            out.push(s);
        }
    }
    out
}

/// `value` in `a` written in `b`; `None` unless they are of one kind.
pub(crate) fn between(value: f64, a: &Unit, b: &Unit) -> Option<f64> {
    (a.kind == b.kind).then(|| (value + a.offset) * a.factor / b.factor - b.offset)
}

/// Most words a unit's name is written in ("kilómetros por hora", "chilometri all'ora").
const UNIT_WORDS: usize = 4;

/// A unit a text writes: at which token, in how many, and the spelling it matched.
pub(crate) struct WrittenUnit {
    pub at: usize,
    pub len: usize,
    pub spelling: String,
}

/// The units of `spellings` that `tokens` write, in order, the longest name at each
/// place ("grad celsius" before "grad").
pub(crate) fn units_written(tokens: &[String], spellings: &[String]) -> Vec<WrittenUnit> {
    let spelt: Vec<(Vec<String>, &String)> =
        spellings.iter().map(|s| (unit_tokens(s), s)).collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < tokens.len() {
        let found = (1..=UNIT_WORDS.min(tokens.len() - i))
            .rev()
            .find_map(|len| {
                let here = &tokens[i..i + len];
                spelt
                    .iter()
                    .find(|(t, _)| t.as_slice() == here)
                    .map(|(_, s)| (len, (*s).clone()))
            });
        match found {
            Some((len, spelling)) => {
                out.push(WrittenUnit {
                    at: i,
                    len,
                    spelling,
                });
                i += len;
            }
            None => i += 1,
        }
    }
    out
}

/// `text` folded and cut into the tokens units are read from: words, numbers, and
/// symbols with a slash or a degree sign ("km/h", "°c"); a number written against its
/// unit is two ("10km" → 10, km).
pub(crate) fn unit_tokens(text: &str) -> Vec<String> {
    let kept = |c: char| c.is_alphanumeric() || matches!(c, '/' | '°' | '.' | ',' | '-');
    let mut out = Vec::new();
    for raw in fold(text).split(|c: char| !kept(c)) {
        let t = raw
            .trim_end_matches(['.', ',', '-', '/'])
            .trim_start_matches(['.', ',', '/']);
        let t = match t.strip_prefix('-') {
            Some(rest) if !rest.starts_with(|c: char| c.is_ascii_digit()) => rest,
            _ => t,
        };
        let numeric = |c: char| c.is_ascii_digit() || matches!(c, '.' | ',' | '-');
        match t.find(|c: char| !numeric(c)) {
            Some(cut) if cut > 0 && t[..cut].contains(|c: char| c.is_ascii_digit()) => {
                out.push(t[..cut].to_string());
                out.push(t[cut..].to_string());
            }
            _ if !t.is_empty() => out.push(t.to_string()),
            _ => {}
        }
    }
    out
}

/// Every spelling of every unit, each once.
fn every_spelling() -> &'static [String] {
    static ALL: std::sync::OnceLock<Vec<String>> = std::sync::OnceLock::new();
    ALL.get_or_init(|| {
        let mut out: Vec<String> = Vec::new();
        for s in table().iter().flat_map(Unit::spellings) {
            let s = fold(s);
            if !out.contains(&s) {
                out.push(s);
            }
        }
        out
    })
}

/// Whether `w` is written right after a number: digits, or a number word before a
/// unit's name ("two meters"; "one in" is no inch).
fn after_number(tokens: &[String], w: &WrittenUnit) -> bool {
    let Some(before) = w.at.checked_sub(1).map(|i| &tokens[i]) else {
        return false;
    };
    let digits = before.contains(|c: char| c.is_ascii_digit());
    let symbol = !w.spelling.contains(' ')
        && w.spelling.chars().all(char::is_alphabetic)
        && unit(&w.spelling).is_some_and(|u| u.symbols.iter().any(|s| fold(s) == w.spelling));
    is_number(before) && (digits || !symbol)
}

/// An amount a text writes: a number and the unit right after it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Amount {
    pub value: f64,
    pub unit: &'static Unit,
}

/// The value of a number token as `unit_tokens` cuts it: digits with a decimal point
/// or comma ("1,5"), or a number word ("drei").
fn number_value(token: &str) -> Option<f64> {
    token
        .replace(',', ".")
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .or_else(|| number_word(token))
}

/// The amounts `text` writes, in order: each number with a unit written right after it
/// ("move 50 cm", "10km/h", "zwei Meter"). A number with no unit after it is none.
pub(crate) fn amounts(text: &str) -> Vec<Amount> {
    let tokens = unit_tokens(text);
    units_written(&tokens, every_spelling())
        .into_iter()
        .filter_map(|w| {
            let unit = unit(&w.spelling)?;
            Some(Amount {
                value: value_before(&tokens, &w, unit)?,
                unit,
            })
        })
        .collect()
}

/// The value written right before `w`, a spelling of `unit`: a number, or before an
/// angle's unit a multiple of π, as angles in radians are said ("pi radians", "2 pi
/// rad", "pi/2 rad").
fn value_before(tokens: &[String], w: &WrittenUnit, unit: &Unit) -> Option<f64> {
    let at = w.at.checked_sub(1)?;
    if unit.kind == "angle" {
        if let Some(pi) = pi_multiple(&tokens[..at], &tokens[at]) {
            return Some(pi);
        }
    }
    after_number(tokens, w)
        .then(|| number_value(&tokens[at]))
        .flatten()
}

/// `token` as a multiple of π: "pi" or "π", divided ("pi/2") or times the number
/// before it ("2 pi"); `before` is what precedes it.
fn pi_multiple(before: &[String], token: &str) -> Option<f64> {
    let rest = token
        .strip_prefix("pi")
        .or_else(|| token.strip_prefix('π'))?;
    let divisor = match rest.strip_prefix('/') {
        Some(d) => d
            .parse::<f64>()
            .ok()
            .filter(|d| d.is_finite() && *d != 0.0)?,
        None if rest.is_empty() => 1.0,
        None => return None,
    };
    let times = before.last().and_then(|t| number_value(t)).unwrap_or(1.0);
    Some(times * std::f64::consts::PI / divisor)
}

/// The symbol `spelling`'s unit is shown by (its first: "deg" for "degrés"), or
/// `spelling` itself when it spells no unit.
pub(crate) fn symbol(spelling: &str) -> String {
    unit(spelling).map_or_else(|| spelling.to_string(), |u| u.symbols[0].clone())
}

/// Whether two spellings are of one unit ("degree", "degrés" and "deg").
pub(crate) fn same_unit(a: &str, b: &str) -> bool {
    unit(a)
        .zip(unit(b))
        .is_some_and(|(a, b)| std::ptr::eq(a, b))
}

/// Whether `spelling` is a unit's that reads as the unit wherever it is written
/// (`unmistakable`).
pub(crate) fn unmistakable_spelling(spelling: &str) -> bool {
    unit(spelling).is_some_and(|u| unmistakable(u, &fold(spelling)))
}

/// Whether `folded`, a spelling of `u`, reads as the unit wherever it is written: a
/// name that is no everyday word, or a symbol with more than letters ("m/s", "°c").
/// Symbols of letters alone ("in", "s") and everyday words ("second") are the unit only
/// right after a number.
fn unmistakable(u: &Unit, folded: &str) -> bool {
    let symbol = u.symbols.iter().any(|s| fold(s) == folded);
    let named = u.names.values().flatten().any(|n| fold(n) == folded);
    let everyday = u.everyday.iter().any(|n| fold(n) == folded);
    if named {
        !everyday
    } else {
        symbol && !folded.chars().all(char::is_alphabetic)
    }
}

/// The unit an argument is in, as its tool declares it: the first unit its
/// `description` names ("Meters to drive", "Speed in m/s", "0 to 90 deg"), else the
/// last word of its `name` when that is a unit (`theta_deg`, `timeout_s`). In a
/// description a symbol of letters alone or an everyday word counts only right after a
/// number: the "in" of "x in meters" is a word, not inches, and "the second joint"
/// names no time.
pub(crate) fn declared(description: &str, name: &str) -> Option<&'static Unit> {
    let tokens = unit_tokens(description);
    let found = units_written(&tokens, every_spelling())
        .into_iter()
        .find_map(|w| {
            let u = unit(&w.spelling)?;
            (after_number(&tokens, &w) || unmistakable(u, &w.spelling)).then_some(u)
        });
    if found.is_some() {
        return found;
    }
    let words = crate::lexicon::name_words(name);
    let [_, .., last] = words.as_slice() else {
        return None;
    };
    let last = fold(last);
    unit(&last).filter(|u| !u.everyday.iter().any(|e| fold(e) == last))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn symbol(u: Option<&Unit>) -> Option<&str> {
        u.map(|u| u.symbols[0].as_str())
    }

    #[test]
    fn amounts_are_a_number_and_the_unit_after_it() {
        let read = |t: &str| -> Vec<(f64, String)> {
            amounts(t)
                .into_iter()
                .map(|a| (a.value, a.unit.symbols[0].clone()))
                .collect()
        };
        assert_eq!(
            read("roll 30cm, then spin by 2,5 radianes"),
            [(30.0, "cm".into()), (2.5, "rad".into())]
        );
        assert_eq!(read("fahr zwei Meter"), [(2.0, "m".into())]);
        assert_eq!(read("a 12 km/h"), [(12.0, "km/h".into())]);
        assert!(read("take 3 of them in a minute").is_empty());
        assert!(read("set it to 4").is_empty());
        assert!(read("put one in the tray").is_empty());
    }

    #[test]
    fn an_angle_is_read_as_a_multiple_of_pi() {
        let read = |t: &str| -> Vec<f64> { amounts(t).into_iter().map(|a| a.value).collect() };
        let pi = std::f64::consts::PI;
        assert_eq!(read("spin round by pi rad"), [pi]);
        assert_eq!(read("gira de 2 π radianes"), [2.0 * pi]);
        assert_eq!(read("tilt pi/4 radians, then 3 cm"), [pi / 4.0, 3.0]);
        assert!(read("a raspberry pi meter").is_empty());
        assert!(read("pi/0 rad").is_empty());
    }

    #[test]
    fn an_argument_declares_its_unit_in_its_description_or_its_name() {
        assert_eq!(symbol(declared("Metres to roll, -3 to 3.", "d")), Some("m"));
        assert_eq!(symbol(declared("Top speed in km/h.", "v")), Some("km/h"));
        assert_eq!(
            symbol(declared("x in feet, from the dock.", "x")),
            Some("ft")
        );
        assert_eq!(symbol(declared("Bend, 0 to 90 deg.", "bend")), Some("deg"));
        assert_eq!(symbol(declared("", "pan_rad")), Some("rad"));
        assert_eq!(symbol(declared("How long, in s", "wait")), None);
        assert_eq!(symbol(declared("How long to wait.", "hold_s")), Some("s"));
        assert_eq!(symbol(declared("Which one, in order.", "index")), None);
        assert_eq!(symbol(declared("", "m")), None);
        assert_eq!(symbol(declared("", "range_min")), None);
        assert_eq!(symbol(declared("Angle of the second joint.", "a")), None);
        assert_eq!(symbol(declared("Identifiant du nœud.", "id")), None);
        assert_eq!(symbol(declared("Pausa, in secondi.", "pausa")), Some("s"));
    }
}
