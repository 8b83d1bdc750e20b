//! Words and numbers, read one way everywhere: the copy bias, call verification,
//! grounding, declared defaults, tool retrieval and the actuation gate all split text and
//! read numbers through this module.
//!
//! - Words are runs of letters and digits (any script), compared lowercased and, where a
//!   caller asks, with Latin diacritics folded (`fold`: "Batería" and "bateria" meet).
//! - Numbers are read as a reader would: digit groups as one number ("$400,000" is
//!   400000, but "5,10" is two numbers), decimals, exponents ("1e-9"), a sign, and small
//!   numbers written as words in English, Spanish, French, German, Italian and Portuguese
//!   ("three", "tres", "drei").
//!
//! The byte-level predicates (`word_start`, `word_end`, `number_end`) serve code that
//! walks text a byte at a time (the copy bias over a vocabulary); the rest works on `str`.

/// Lowercased runs of letters and digits.
pub fn words(text: &str) -> Vec<String> {
    text.split(|c: char| !c.is_alphanumeric())
        .filter(|w| !w.is_empty())
        .map(str::to_lowercase)
        .collect()
}

/// The words of a ROS name or type, as written: runs of letters and digits, camel case
/// split ("sensor_msgs/msg/BatteryState" → sensor, msgs, msg, Battery, State).
pub(crate) fn name_words(name: &str) -> Vec<String> {
    let mut words = Vec::new();
    let mut cur = String::new();
    let mut prev_lower = false;
    for c in name.chars() {
        if !c.is_alphanumeric() {
            words.push(std::mem::take(&mut cur));
            prev_lower = false;
            continue;
        }
        if c.is_uppercase() && prev_lower {
            words.push(std::mem::take(&mut cur));
        }
        prev_lower = c.is_lowercase() || c.is_ascii_digit();
        cur.push(c);
    }
    words.push(cur);
    words.retain(|w| !w.is_empty());
    words
}

/// `text` lowercased with the diacritics of Latin letters removed, so the same word
/// written with or without accents compares equal ("Posición" → "posicion").
pub fn fold(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars().flat_map(char::to_lowercase) {
        match c {
            'à' | 'á' | 'â' | 'ã' | 'ä' | 'å' => out.push('a'),
            'ç' => out.push('c'),
            'è' | 'é' | 'ê' | 'ë' => out.push('e'),
            'ì' | 'í' | 'î' | 'ï' => out.push('i'),
            'ñ' => out.push('n'),
            'ò' | 'ó' | 'ô' | 'õ' | 'ö' => out.push('o'),
            'ù' | 'ú' | 'û' | 'ü' => out.push('u'),
            'ý' | 'ÿ' => out.push('y'),
            'ß' => out.push_str("ss"),
            'œ' => out.push_str("oe"),
            'æ' => out.push_str("ae"),
            _ => out.push(c),
        }
    }
    out
}

/// Folded words (`fold`, then `words`).
pub(crate) fn folded_words(text: &str) -> Vec<String> {
    words(&fold(text))
}

/// Number words and their values. Small numbers only: larger ones are written in digits
/// in every language an operator uses here, and the fractions said of an amount ("half
/// a meter"). Words that are also common English words ("due", "null", "sept") are left
/// out: they would make numbers of text that names none.
const NUMBER_WORDS: &[(&str, f64)] = &[
    // English
    ("zero", 0.0),
    ("one", 1.0),
    ("two", 2.0),
    ("three", 3.0),
    ("four", 4.0),
    ("five", 5.0),
    ("six", 6.0),
    ("seven", 7.0),
    ("eight", 8.0),
    ("nine", 9.0),
    ("ten", 10.0),
    ("eleven", 11.0),
    ("twelve", 12.0),
    ("thirteen", 13.0),
    ("fourteen", 14.0),
    ("fifteen", 15.0),
    ("sixteen", 16.0),
    ("seventeen", 17.0),
    ("eighteen", 18.0),
    ("nineteen", 19.0),
    ("twenty", 20.0),
    ("thirty", 30.0),
    ("forty", 40.0),
    ("fifty", 50.0),
    ("sixty", 60.0),
    ("seventy", 70.0),
    ("eighty", 80.0),
    ("ninety", 90.0),
    ("dozen", 12.0),
    ("twice", 2.0),
    ("half", 0.5),
    ("quarter", 0.25),
    ("hundred", 100.0),
    ("thousand", 1000.0),
    // Spanish and Portuguese (folded)
    ("cero", 0.0),
    ("uno", 1.0),
    ("una", 1.0),
    ("uma", 1.0),
    ("dos", 2.0),
    ("dois", 2.0),
    ("duas", 2.0),
    ("tres", 3.0),
    ("cuatro", 4.0),
    ("quatro", 4.0),
    ("cinco", 5.0),
    ("seis", 6.0),
    ("siete", 7.0),
    ("sete", 7.0),
    ("ocho", 8.0),
    ("oito", 8.0),
    ("nueve", 9.0),
    ("diez", 10.0),
    ("dez", 10.0),
    ("veinte", 20.0),
    ("vinte", 20.0),
    ("treinta", 30.0),
    ("noventa", 90.0),
    ("cien", 100.0),
    ("ciento", 100.0),
    ("cem", 100.0),
    ("medio", 0.5),
    ("meio", 0.5),
    // French
    ("un", 1.0),
    ("une", 1.0),
    ("deux", 2.0),
    ("trois", 3.0),
    ("quatre", 4.0),
    ("cinq", 5.0),
    ("huit", 8.0),
    ("neuf", 9.0),
    ("dix", 10.0),
    ("vingt", 20.0),
    ("trente", 30.0),
    ("demi", 0.5),
    // German
    ("eins", 1.0),
    ("ein", 1.0),
    ("eine", 1.0),
    ("einen", 1.0),
    ("zwei", 2.0),
    ("drei", 3.0),
    ("vier", 4.0),
    ("funf", 5.0),
    ("sechs", 6.0),
    ("sieben", 7.0),
    ("acht", 8.0),
    ("neun", 9.0),
    ("zehn", 10.0),
    ("zwanzig", 20.0),
    ("zweimal", 2.0),
    ("dreissig", 30.0),
    ("neunzig", 90.0),
    ("hundert", 100.0),
    ("halb", 0.5),
    ("halbe", 0.5),
    ("halben", 0.5),
    ("viertel", 0.25),
    // Italian
    ("uno", 1.0),
    ("quattro", 4.0),
    ("sette", 7.0),
    ("dieci", 10.0),
    ("venti", 20.0),
    ("novanta", 90.0),
    ("cento", 100.0),
    ("mezzo", 0.5),
];

/// The value of a number written as a word ("three hours", "drei Meter"); `w` is one
/// word, compared folded.
pub(crate) fn number_word(w: &str) -> Option<f64> {
    let w = fold(w);
    NUMBER_WORDS.iter().find(|(x, _)| *x == w).map(|&(_, v)| v)
}

/// Whether one word is a number: digits (a decimal point or comma, a sign) or a number
/// word ("3", "1,5", "-40", "drei").
pub(crate) fn is_number(w: &str) -> bool {
    w.replace(',', ".").parse::<f64>().is_ok() || number_word(w).is_some()
}

/// Every number `text` spells, in order: digits (with a sign, digit groups, decimals
/// and exponents; a negative number also counts as its magnitude, since "-3" is often
/// said of a 3) and number words.
pub fn numbers(text: &str) -> Vec<f64> {
    let plain = without_digit_grouping(text.as_bytes());
    let bytes = plain.as_slice();
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let starts = bytes[i].is_ascii_digit()
            && (i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'.'));
        if !starts {
            i += 1;
            continue;
        }
        let mut digits = String::new();
        let mut j = i;
        while j < bytes.len() {
            let b = bytes[j];
            let next_digit = bytes.get(j + 1).is_some_and(u8::is_ascii_digit);
            if b.is_ascii_digit() {
                digits.push(b as char);
            } else if b == b'.' && next_digit && !digits.contains(['.', 'e']) {
                digits.push('.');
            } else if matches!(b, b'e' | b'E') && !digits.contains('e') && exponent_at(bytes, j) {
                digits.push('e');
                if let Some(&sign @ (b'-' | b'+')) = bytes.get(j + 1) {
                    digits.push(sign as char);
                    j += 1;
                }
            } else {
                break;
            }
            j += 1;
        }
        if let Ok(n) = digits.parse::<f64>() {
            if i > 0 && bytes[i - 1] == b'-' {
                out.push(-n);
            }
            out.push(n);
        }
        i = j.max(i + 1);
    }
    out.extend(words(text).iter().filter_map(|w| number_word(w)));
    out
}

/// The numbers `text` writes in digits, each once and in order, a sign with it: a list
/// as written ("0, -1.2, 1.5"). Unlike `numbers`, number words are left out ("the six
/// joints to 0, 1, 2" lists three numbers, not four) and a negative number does not
/// count as its magnitude too.
pub(crate) fn digit_list(text: &str) -> Vec<f64> {
    text.split_whitespace()
        .map(|w| w.trim_matches(|c: char| matches!(c, ',' | ';' | ':' | '(' | ')' | '[' | ']')))
        .filter(|w| w.chars().any(|c| c.is_ascii_digit()))
        .filter_map(|w| w.parse::<f64>().ok())
        .filter(|v| v.is_finite())
        .collect()
}

/// An exponent starts at `j` (`e`, an optional sign, then a digit).
fn exponent_at(bytes: &[u8], j: usize) -> bool {
    let sign = matches!(bytes.get(j + 1), Some(b'-' | b'+'));
    bytes
        .get(j + 1 + usize::from(sign))
        .is_some_and(u8::is_ascii_digit)
}

/// Two numbers are the same value (relative tolerance for floats written differently).
pub(crate) fn same_number(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0)
}

fn alnum(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b >= 0x80
}

/// A copied value may start at `p`: the start of a word (or of a number after `$`), or
/// of a path or negative number (`/turtle1/pose`, `-7`) after a space or an opening.
pub(crate) fn word_start(text: &[u8], p: usize) -> bool {
    let Some(&b) = text.get(p) else {
        return false;
    };
    let before = p.checked_sub(1).map(|i| text[i]);
    if alnum(b) {
        // A number's decimals ("5" of "0.5") are not a number of their own.
        let decimals = b.is_ascii_digit()
            && before == Some(b'.')
            && p.checked_sub(2).is_some_and(|i| text[i].is_ascii_digit());
        return before.is_none_or(|c| !alnum(c)) && !decimals;
    }
    matches!(b, b'/' | b'~' | b'-')
        && before.is_none_or(|c| c.is_ascii_whitespace() || b"\"'([{,:=".contains(&c))
}

/// A byte a JSON number may hold.
pub(crate) fn number_byte(b: u8) -> bool {
    b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E')
}

/// A copied string may end at `p`.
pub(crate) fn word_end(text: &[u8], p: usize) -> bool {
    p > 0 && (p == text.len() || !alnum(text[p]))
}

/// A copied number may end at `p`: no digit follows, nor a decimal point and a digit, nor
/// an exponent ("1e-9"), nor a digit group ("5,10" ends after the 5; "400,000" does not).
pub(crate) fn number_end(text: &[u8], p: usize) -> bool {
    let digit_at = |i: usize| text.get(i).is_some_and(u8::is_ascii_digit);
    match text.get(p) {
        None => true,
        Some(b) if b.is_ascii_digit() => false,
        Some(b'.') => !digit_at(p + 1),
        Some(b'e' | b'E') if p > 0 && text[p - 1].is_ascii_digit() => !exponent_at(text, p),
        Some(b',') => !digit_group_at(text, p),
        Some(_) => true,
    }
}

/// The comma at `p` separates digit groups: a digit before it and exactly three after.
fn digit_group_at(text: &[u8], p: usize) -> bool {
    text[p] == b','
        && p > 0
        && text[p - 1].is_ascii_digit()
        && text
            .get(p + 1..p + 4)
            .is_some_and(|g| g.iter().all(u8::is_ascii_digit))
        && !text.get(p + 4).is_some_and(u8::is_ascii_digit)
}

/// `text` with the thousands separators of its numbers removed: a comma between a digit
/// and exactly three digits ("1,250,000" → "1250000"; "5,10" stays a list).
pub(crate) fn without_digit_grouping(text: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(text.len());
    for (i, &b) in text.iter().enumerate() {
        if !digit_group_at(text, i) {
            out.push(b);
        }
    }
    out
}

/// `text` with the numbers it spells as words written in digits ("initial velocity is
/// zero" → "initial velocity is 0").
pub(crate) fn number_words_as_digits(text: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(text.len());
    let mut i = 0;
    while i < text.len() {
        let end = i + text[i..]
            .iter()
            .position(|b| !b.is_ascii_alphabetic())
            .unwrap_or(text.len() - i);
        if end == i {
            out.push(text[i]);
            i += 1;
            continue;
        }
        let word = String::from_utf8_lossy(&text[i..end]);
        let alone = (i == 0 || !alnum(text[i - 1])) && !text.get(end).is_some_and(|&b| alnum(b));
        match number_word(&word).filter(|_| alone) {
            Some(n) => out.extend_from_slice(format!("{n}").as_bytes()),
            None => out.extend_from_slice(&text[i..end]),
        }
        i = end;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_as_a_reader_reads_them() {
        let n = numbers("Tax on $30.45; $1,250,000 in Portland; -3 and 5m; 10,11; 2e-9 C.");
        for want in [30.45, 1_250_000.0, -3.0, 3.0, 5.0, 10.0, 11.0, 2e-9] {
            assert!(n.iter().any(|&x| same_number(x, want)), "{want} in {n:?}");
        }
        for absent in [1250.0, 1011.0, 2.0, 30.0] {
            assert!(!n.iter().any(|&x| same_number(x, absent)), "{absent}");
        }
        assert_eq!(numbers("three hours, drei Meter, tres metros"), [3.0; 3]);
        assert_eq!(numbers("half a lap, einen halben Meter"), [0.5, 1.0, 0.5]);
    }

    #[test]
    fn folding_meets_accented_and_plain_words() {
        assert_eq!(fold("Posición BATERÍA Straße"), "posicion bateria strasse");
        assert_eq!(folded_words("¿Dónde está?"), ["donde", "esta"]);
    }

    #[test]
    fn number_words_are_also_digits() {
        assert_eq!(
            number_words_as_digits(b"Three hours, velocity zero; someone, 2twelve"),
            b"3 hours, velocity 0; someone, 2twelve"
        );
    }

    #[test]
    fn digit_groups_and_word_edges() {
        assert_eq!(
            without_digit_grouping(b"$1,250,000 and 3,4"),
            b"$1250000 and 3,4"
        );
        assert!(word_start(b"$400", 1) && !word_start(b"ab", 1));
        assert!(word_start(b"echo /turtle1/pose", 5) && !word_start(b"echo /turtle1/pose", 13));
        assert!(word_start(b"b = -7", 4) && !word_start(b"3-7", 1));
        assert!(
            !word_start(b"go 0.5 m", 5) && word_start(b"go 0.5 m", 3) && word_start(b"end. 5", 5)
        );
        assert!(word_end(b"New York, NY", 8) && !word_end(b"New York", 5));
        assert!(!number_end(b"400,000", 3) && number_end(b"5, 10", 1) && number_end(b"5.", 1));
        assert!(number_end(b"5,10 and 15", 1) && number_end(b"1,5 and 10", 1));
        assert!(!number_end(b"2.5", 1) && !number_end(b"1,250,000", 1));
        assert!(!number_end(b"1e-9 C", 1) && !number_end(b"2E5", 1) && number_end(b"2 eggs", 1));
    }
}
