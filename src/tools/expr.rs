//! A small arithmetic expression evaluator: numbers, + - * / % ^, parentheses, unary
//! minus, constants (pi, e) and functions (sqrt, abs, sin, cos, tan, asin, acos, atan,
//! atan2, exp, ln, log10, deg, rad, min, max, round, floor, ceil). Angles are radians.
//!
//! The expression comes from whoever calls `calc_eval` (a model, `ferrosa call`, an MCP
//! client): its length and its nesting are bounded before anything recurses, so no
//! expression can overflow the stack of the thread that evaluates it (issue 41). A run
//! of signs (`--1`) is read in a loop, not by recursion.

/// Longest expression read, in characters (a model writes a few dozen).
pub(crate) const MAX_LEN: usize = 4096;
/// Deepest nesting of parentheses, function calls and powers evaluated.
pub const MAX_DEPTH: usize = 64;

/// Why an expression has no value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExprError {
    #[error("the expression is too long ({len} characters; at most {MAX_LEN}): split it into smaller ones")]
    TooLong { len: usize },
    #[error("the expression nests parentheses, calls or powers more than {MAX_DEPTH} deep: write it flatter")]
    TooDeep,
    #[error("{0}")]
    Invalid(String),
}

impl From<String> for ExprError {
    fn from(why: String) -> ExprError {
        ExprError::Invalid(why)
    }
}

impl From<&str> for ExprError {
    fn from(why: &str) -> ExprError {
        ExprError::Invalid(why.to_string())
    }
}

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Num(f64),
    Ident(String),
    Op(char),
    LParen,
    RParen,
    Comma,
}

fn lex(s: &str) -> Result<Vec<Tok>, String> {
    let mut out = Vec::new();
    let b: Vec<char> = s.chars().collect();
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        if c.is_whitespace() {
            i += 1;
        } else if c.is_ascii_digit() || c == '.' {
            let start = i;
            while i < b.len() && (b[i].is_ascii_digit() || b[i] == '.') {
                i += 1;
            }
            if i < b.len()
                && (b[i] == 'e' || b[i] == 'E')
                && i + 1 < b.len()
                && (b[i + 1].is_ascii_digit() || b[i + 1] == '-' || b[i + 1] == '+')
            {
                i += 2;
                while i < b.len() && b[i].is_ascii_digit() {
                    i += 1;
                }
            }
            let t: String = b[start..i].iter().collect();
            out.push(Tok::Num(t.parse().map_err(|_| format!("bad number {t}"))?));
        } else if c.is_alphabetic() || c == '_' {
            let start = i;
            while i < b.len() && (b[i].is_alphanumeric() || b[i] == '_') {
                i += 1;
            }
            out.push(Tok::Ident(
                b[start..i].iter().collect::<String>().to_lowercase(),
            ));
        } else {
            out.push(match c {
                '(' => Tok::LParen,
                ')' => Tok::RParen,
                ',' => Tok::Comma,
                '+' | '-' | '*' | '/' | '%' | '^' => Tok::Op(c),
                '×' => Tok::Op('*'),
                '÷' => Tok::Op('/'),
                _ => return Err(format!("unexpected character {c:?}")),
            });
            i += 1;
        }
    }
    Ok(out)
}

struct Parser {
    toks: Vec<Tok>,
    pos: usize,
    /// Parentheses, calls and powers open where the parser stands.
    depth: usize,
}

impl Parser {
    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.pos)
    }
    fn next(&mut self) -> Option<Tok> {
        let t = self.toks.get(self.pos).cloned();
        self.pos += 1;
        t
    }
    /// One level deeper, for `f`, refused past `MAX_DEPTH`.
    fn nested(
        &mut self,
        f: impl FnOnce(&mut Parser) -> Result<f64, ExprError>,
    ) -> Result<f64, ExprError> {
        if self.depth >= MAX_DEPTH {
            return Err(ExprError::TooDeep);
        }
        self.depth += 1;
        let v = f(self);
        self.depth -= 1;
        v
    }
    fn expr(&mut self) -> Result<f64, ExprError> {
        let mut v = self.term()?;
        while let Some(Tok::Op(op @ ('+' | '-'))) = self.peek().cloned() {
            self.pos += 1;
            let r = self.term()?;
            v = if op == '+' { v + r } else { v - r };
        }
        Ok(v)
    }
    fn term(&mut self) -> Result<f64, ExprError> {
        let mut v = self.unary()?;
        while let Some(Tok::Op(op @ ('*' | '/' | '%'))) = self.peek().cloned() {
            self.pos += 1;
            let r = self.unary()?;
            v = match op {
                '*' => v * r,
                '/' if r == 0.0 => return Err("division by zero".into()),
                '/' => v / r,
                _ => v % r,
            };
        }
        Ok(v)
    }
    /// Signs, then a power: `-2^2` is -(2^2). A run of signs is counted, not recursed.
    fn unary(&mut self) -> Result<f64, ExprError> {
        let mut negative = false;
        while let Some(Tok::Op(op @ ('-' | '+'))) = self.peek() {
            negative ^= *op == '-';
            self.pos += 1;
        }
        let v = self.power()?;
        Ok(if negative { -v } else { v })
    }
    fn power(&mut self) -> Result<f64, ExprError> {
        let base = self.atom()?;
        if let Some(Tok::Op('^')) = self.peek() {
            self.pos += 1;
            let exp = self.nested(Parser::unary)?;
            return Ok(base.powf(exp));
        }
        Ok(base)
    }
    fn atom(&mut self) -> Result<f64, ExprError> {
        match self.next() {
            Some(Tok::Num(n)) => Ok(n),
            Some(Tok::LParen) => {
                let v = self.nested(Parser::expr)?;
                match self.next() {
                    Some(Tok::RParen) => Ok(v),
                    _ => Err("missing )".into()),
                }
            }
            Some(Tok::Ident(name)) => {
                if let Some(Tok::LParen) = self.peek() {
                    self.pos += 1;
                    let mut args = Vec::new();
                    if self.peek() != Some(&Tok::RParen) {
                        loop {
                            args.push(self.nested(Parser::expr)?);
                            match self.next() {
                                Some(Tok::Comma) => continue,
                                Some(Tok::RParen) => break,
                                _ => {
                                    return Err(
                                        format!("missing ) after arguments of {name}").into()
                                    )
                                }
                            }
                        }
                    } else {
                        self.pos += 1;
                    }
                    Ok(call(&name, &args)?)
                } else {
                    match name.as_str() {
                        "pi" => Ok(std::f64::consts::PI),
                        "e" => Ok(std::f64::consts::E),
                        "tau" => Ok(std::f64::consts::TAU),
                        _ => Err(format!("unknown name {name}").into()),
                    }
                }
            }
            Some(t) => Err(format!("unexpected {t:?}").into()),
            None => Err("expression ends too early".into()),
        }
    }
}

fn call(name: &str, a: &[f64]) -> Result<f64, String> {
    let one = |f: fn(f64) -> f64| -> Result<f64, String> {
        match a {
            [x] => Ok(f(*x)),
            _ => Err(format!("{name} takes one argument")),
        }
    };
    match name {
        "sqrt" => one(f64::sqrt),
        "abs" => one(f64::abs),
        "sin" => one(f64::sin),
        "cos" => one(f64::cos),
        "tan" => one(f64::tan),
        "asin" => one(f64::asin),
        "acos" => one(f64::acos),
        "atan" => one(f64::atan),
        "exp" => one(f64::exp),
        "ln" => one(f64::ln),
        "log10" | "log" => one(f64::log10),
        "deg" | "degrees" => one(f64::to_degrees),
        "rad" | "radians" => one(f64::to_radians),
        "round" => one(f64::round),
        "floor" => one(f64::floor),
        "ceil" => one(f64::ceil),
        "atan2" => match a {
            [y, x] => Ok(y.atan2(*x)),
            _ => Err("atan2 takes two arguments (y, x)".into()),
        },
        "min" if !a.is_empty() => Ok(a.iter().copied().fold(f64::INFINITY, f64::min)),
        "max" if !a.is_empty() => Ok(a.iter().copied().fold(f64::NEG_INFINITY, f64::max)),
        _ => Err(format!("unknown function {name}")),
    }
}

/// Evaluate `s`.
pub fn eval(s: &str) -> Result<f64, ExprError> {
    let len = s.chars().count();
    if len > MAX_LEN {
        return Err(ExprError::TooLong { len });
    }
    let toks = lex(s)?;
    if toks.is_empty() {
        return Err("empty expression".into());
    }
    let mut p = Parser {
        toks,
        pos: 0,
        depth: 0,
    };
    let v = p.expr()?;
    if p.pos < p.toks.len() {
        return Err(format!("unexpected {:?}", p.toks[p.pos]).into());
    }
    if !v.is_finite() {
        return Err("the result is not a finite number".into());
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::{eval, MAX_DEPTH, MAX_LEN};

    #[test]
    fn precedence_functions_and_errors() {
        assert_eq!(eval("2 + 3 * 4").unwrap(), 14.0);
        assert_eq!(eval("(2 + 3) * 4").unwrap(), 20.0);
        assert_eq!(eval("2^10").unwrap(), 1024.0);
        assert_eq!(eval("-2^2").unwrap(), -4.0);
        assert_eq!(eval("2^-1").unwrap(), 0.5);
        assert_eq!(eval("100 / 8 % 5").unwrap(), 2.5);
        assert!((eval("sin(pi/2)").unwrap() - 1.0).abs() < 1e-12);
        assert!((eval("deg(atan2(1, 1))").unwrap() - 45.0).abs() < 1e-9);
        assert_eq!(eval("max(3, 9, 4)").unwrap(), 9.0);
        assert_eq!(eval("1.5e3").unwrap(), 1500.0);
        assert!(eval("1/0").unwrap_err().to_string().contains("zero"));
        assert!(eval("2 +").is_err());
        assert!(eval("foo(1)")
            .unwrap_err()
            .to_string()
            .contains("unknown function"));
    }

    #[test]
    fn signs_repeat_and_nesting_is_bounded() {
        assert_eq!(eval("--1").unwrap(), 1.0);
        assert_eq!(eval("- + -2").unwrap(), 2.0);
        assert_eq!(eval("2^-2^2").unwrap(), 2f64.powf(-4.0));
        assert_eq!(eval("-(-(3))").unwrap(), 3.0);
        let deep = |n: usize| format!("{}1{}", "(".repeat(n), ")".repeat(n));
        assert_eq!(eval(&deep(MAX_DEPTH)).unwrap(), 1.0);
        assert_eq!(eval(&deep(MAX_DEPTH + 1)), Err(super::ExprError::TooDeep));
        assert_eq!(
            eval(&format!(
                "{}4{}",
                "sqrt(".repeat(MAX_DEPTH + 1),
                ")".repeat(MAX_DEPTH + 1)
            )),
            Err(super::ExprError::TooDeep)
        );
        assert_eq!(
            eval(&format!("{}2", "2^".repeat(MAX_DEPTH + 1))),
            Err(super::ExprError::TooDeep)
        );
        assert_eq!(
            eval(&"-".repeat(MAX_LEN - 1)),
            Err("expression ends too early".into())
        );
        let long = format!("{}1", "-".repeat(MAX_LEN));
        assert_eq!(
            eval(&long),
            Err(super::ExprError::TooLong { len: MAX_LEN + 1 })
        );
    }
}
