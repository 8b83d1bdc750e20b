//! Arithmetic said in words: "12 times 7", "3 plus 4 mal 2", read as the expression a
//! computing tool takes ("12 * 7"). Asked "what is 17 times 23?", a small model wrote
//! the expression "17" and stopped: the operator's word is no symbol it copies. `bound`
//! holds a computing tool's expression to the one the request says, so the call
//! computes what was asked.
//!
//! The operator words are data (`[operator."*"]` and its kin in
//! `data/words/<lang>.toml`, read by `concepts`); `×`, `÷`, `x` between two numbers and
//! the symbols themselves are read in every language. A request must say at least one
//! operator in words: one written all in symbols is the model's to copy as it is.

use super::concepts::operators;

/// One piece of a request, as read for arithmetic.
#[derive(Debug, Clone, PartialEq)]
enum Piece {
    /// A number as it is written, its decimal comma a point.
    Number(String),
    /// An operator symbol (`+ - * / ^`).
    Symbol(char),
    /// A folded word.
    Word(String),
}

/// The expression `request` says with at least one operator in words ("12 times 7" is
/// `12 * 7`), when it says exactly one; `None` otherwise.
/// Written all in symbols with parentheses ("(3+5)*2"), it is that text as written: a
/// small model had stopped at the parenthesis.
pub(crate) fn said(request: &str) -> Option<String> {
    // Parentheses group what `runs` reads flat: "(3 plus 5) times 2" is no `3 + 5 * 2`.
    if request.contains(['(', ')']) {
        return written(request);
    }
    match &runs(request)[..] {
        [run] if run.in_words => Some(run.expression.clone()),
        _ => None,
    }
}

/// The one stretch of `request` written in digits, operators and parentheses alone
/// that groups with parentheses (balanced) and joins numbers with `+`, `*`, `^`, `×` or
/// `÷`, with `×` and `÷` as the evaluator writes them.
fn written(request: &str) -> Option<String> {
    let arithmetic = |c: char| c.is_ascii_digit() || " .+-*/^()×÷".contains(c);
    let mut found = Vec::new();
    let mut rest = request;
    while let Some(start) = rest.find(|c: char| c.is_ascii_digit() || c == '(') {
        let tail = &rest[start..];
        let len = tail.find(|c: char| !arithmetic(c)).unwrap_or(tail.len());
        let span = tail[..len].trim_end_matches(|c: char| !c.is_ascii_digit() && c != ')');
        found.push(span.to_string());
        rest = &tail[len.max(1)..];
    }
    let balanced = |s: &str| {
        let mut depth = 0i32;
        s.chars().all(|c| {
            depth += match c {
                '(' => 1,
                ')' => -1,
                _ => 0,
            };
            depth >= 0
        }) && depth == 0
    };
    let grouped: Vec<String> = found
        .into_iter()
        .filter(|s| s.contains('(') && s.contains(['+', '*', '^', '×', '÷']) && balanced(s))
        .collect();
    match &grouped[..] {
        [one] => Some(one.trim().replace('×', "*").replace('÷', "/")),
        _ => None,
    }
}

/// Whether `request` asks for arithmetic: numbers joined by an operator said in words,
/// or by one no range, date or name writes (`*`, `^`, `×`, `÷`; not `-` or `/`, as in
/// "3-5 m" or "/turtle1").
pub(crate) fn asked(request: &str) -> bool {
    runs(request).iter().any(|r| r.in_words || r.plain)
}

/// Numbers joined by operators, as a request writes them.
struct Run {
    expression: String,
    /// An operator in it is said in words.
    in_words: bool,
    /// An operator in it is one only arithmetic writes.
    plain: bool,
}

/// Every run of numbers joined by operators in `request`, in order.
fn runs(request: &str) -> Vec<Run> {
    let pieces = pieces(request);
    let mut found = Vec::new();
    let mut i = 0;
    while i < pieces.len() {
        match run(&pieces, i) {
            Some((end, r)) => {
                found.push(r);
                i = end;
            }
            None => i += 1,
        }
    }
    found
}

/// The run that starts at `at`, if one does (a number, then at least one operator and
/// number), and where it ends.
fn run(pieces: &[Piece], at: usize) -> Option<(usize, Run)> {
    let Piece::Number(first) = &pieces[at] else {
        return None;
    };
    let mut r = Run {
        expression: first.clone(),
        in_words: false,
        plain: false,
    };
    let mut i = at + 1;
    while let Some((symbol, len, words)) = operator(&pieces[i.min(pieces.len())..]) {
        let Some(Piece::Number(n)) = pieces.get(i + len) else {
            break;
        };
        r.expression.push_str(&format!(" {symbol} {n}"));
        r.in_words |= words;
        r.plain |= !words && matches!(symbol, '*' | '^');
        i += len + 1;
    }
    (i > at + 1).then_some((i, r))
}

/// The operator `pieces` open with: its symbol, how many pieces it takes, and whether
/// it is said in words.
fn operator(pieces: &[Piece]) -> Option<(char, usize, bool)> {
    match pieces.first()? {
        Piece::Symbol(c) => Some((*c, 1, false)),
        Piece::Word(w) if w == "x" => Some(('*', 1, true)),
        Piece::Word(_) => operators()
            .iter()
            .filter(|(phrase, _)| {
                phrase.len() <= pieces.len()
                    && phrase
                        .iter()
                        .zip(pieces)
                        .all(|(p, piece)| matches!(piece, Piece::Word(w) if w == p))
            })
            .max_by_key(|(phrase, _)| phrase.len())
            .map(|(phrase, symbol)| (*symbol, phrase.len(), true)),
        Piece::Number(_) => None,
    }
}

/// `text` folded and cut into numbers, operator symbols and words, without its
/// parentheses. A `-` right before a digit, where no number ends, is the number's sign.
fn pieces(text: &str) -> Vec<Piece> {
    let folded = crate::lexicon::fold(text).replace(['(', ')'], " ");
    let mut out: Vec<Piece> = Vec::new();
    for raw in folded.split_whitespace() {
        let raw = raw.trim_matches(|c: char| {
            matches!(c, '?' | '!' | '.' | ',' | ';' | ':' | '¿' | '¡' | '"')
        });
        let chars: Vec<char> = raw.chars().collect();
        let mut i = 0;
        while i < chars.len() {
            let c = chars[i];
            let after_number = matches!(out.last(), Some(Piece::Number(_)));
            let signed =
                c == '-' && !after_number && chars.get(i + 1).is_some_and(char::is_ascii_digit);
            if c.is_ascii_digit() || signed {
                let start = i;
                i += 1;
                while i < chars.len()
                    && (chars[i].is_ascii_digit()
                        || (matches!(chars[i], '.' | ',')
                            && chars.get(i + 1).is_some_and(char::is_ascii_digit)))
                {
                    i += 1;
                }
                let n: String = chars[start..i].iter().collect();
                out.push(Piece::Number(n.replace(',', ".")));
            } else if let Some(symbol) = symbol(c) {
                out.push(Piece::Symbol(symbol));
                i += 1;
            } else {
                let start = i;
                while i < chars.len() && !chars[i].is_ascii_digit() && symbol(chars[i]).is_none() {
                    i += 1;
                }
                let word: String = chars[start..i].iter().collect();
                out.push(Piece::Word(word));
            }
        }
    }
    out
}

/// The operator a character writes, as the evaluator reads it.
fn symbol(c: char) -> Option<char> {
    match c {
        '+' | '-' | '*' | '/' | '^' => Some(c),
        '×' | '·' => Some('*'),
        '÷' => Some('/'),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn operators_said_in_words_are_read_as_symbols() {
        assert_eq!(said("how much is 31 times 4?").as_deref(), Some("31 * 4"));
        assert_eq!(said("rechne 9 mal 8 plus 1").as_deref(), Some("9 * 8 + 1"));
        assert_eq!(
            said("combien font 100 divisé par 8 ?").as_deref(),
            Some("100 / 8")
        );
        assert_eq!(said("quanto fa 2,5 per 4").as_deref(), Some("2.5 * 4"));
        assert_eq!(said("cuánto es 10 menos -3").as_deref(), Some("10 - -3"));
        assert_eq!(said("6 x 7").as_deref(), Some("6 * 7"));
    }

    #[test]
    fn nothing_is_read_without_an_operator_in_words_or_with_two_expressions() {
        // All symbols: the model copies them as they are; grouped, they are no run.
        assert_eq!(said("what is 3 + 5 * 2?"), None);
        assert_eq!(said("(3 plus 5) times 2"), None);
        // Grouped in symbols: as written.
        assert_eq!(said("and (2+4)×3?").as_deref(), Some("(2+4)*3"));
        assert_eq!(said("(2+4"), None);
        // Numbers that are no arithmetic.
        assert_eq!(said("teleport the turtle to x 2 y 3"), None);
        assert_eq!(said("riduci al 30 per cento"), None);
        assert_eq!(said("move 2 meters"), None);
        // Two things to compute: which one is the call's is the model's to say.
        assert_eq!(said("3 plus 4, and 5 times 6"), None);
    }

    #[test]
    fn arithmetic_is_asked_by_words_or_by_symbols_only_arithmetic_writes() {
        assert!(asked("what is (3 + 5) * 2?"));
        assert!(asked("2^10"));
        assert!(asked("was ist 7 durch 2"));
        assert!(!asked("drive 3-5 meters"));
        assert!(!asked("echo /turtle1/pose 3 times"));
        assert!(!asked("set the date to 12/05"));
    }
}
