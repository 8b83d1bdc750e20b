//! No request of the project's suites and request lists stands in the product (issue
//! 42): each word a suite request brings into `src/` fixes that request and teaches the
//! product nothing. Owns the reading of every request list and the scan of `src/`,
//! `web/`, `prompts/` and `data/` for them; not what the product does with words.
//!
//! The requests: every `query` of every `.jsonl` file under `tests/eval/` (found there,
//! so a suite added later is read too), every line of every `.txt` file under
//! `tests/eval/` and `tests/data/` (`spoken.txt`, `operator_requests.txt`; `#` lines are
//! comments), and the request lists of `benches/*.rs` (a `const`, `static` or `let`
//! bound to sentences). A file under `tests/eval/` of another kind fails the test until
//! it is taught here.
//!
//! A request and the scanned text are compared normalised: lowercase, `’` as `'`,
//! whitespace collapsed, comment markers (`//!`, `///`, `//`, `#`, `*`) and a string's
//! line-continuation `\` dropped at each line's ends, `\n`/`\t`/`\"` escapes as the
//! characters they stand for, and the request's closing `?.!` (and opening `¿¡`)
//! stripped. A hit is the request anywhere in that text between non-alphanumeric
//! characters: inside a longer literal or comment, or over a wrapped comment's lines.
//!
//! Exempt: a request of fewer than three words made only of letters (no digit, no ROS
//! name): "stop!", "battery?", "fermati subito!", "good morning!". Such a request is a
//! bare concept word or a greeting that a stop table or the lexicon must be able to hold
//! to work at all; a sentence of three words or more, or one that carries a name or a
//! number ("echo /turtle/pose"), is specific to the suite and is never exempt.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use syn::visit::Visit;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn relative(path: &Path) -> String {
    path.strip_prefix(root())
        .unwrap_or(path)
        .display()
        .to_string()
}

/// A request as compared: lowercase, one space between words, no closing `?.!`.
fn normalise_request(text: &str) -> String {
    let flat = text.to_lowercase().replace('\u{2019}', "'");
    let words: Vec<&str> = flat.split_whitespace().collect();
    words
        .join(" ")
        .trim_start_matches(['¿', '¡', ' '])
        .trim_end_matches(['?', '.', '!', ' '])
        .to_string()
}

/// Fewer than three words, letters only: a concept word or a greeting (module header).
fn exempt(normalised: &str) -> bool {
    normalised.split_whitespace().count() < 3
        && normalised
            .chars()
            .all(|c| c.is_alphabetic() || matches!(c, ' ' | '\'' | '-' | ','))
}

/// The scanned text normalised (module header), with the line each byte came from.
fn prose(text: &str) -> (String, Vec<usize>) {
    let (mut out, mut lines) = (String::new(), Vec::new());
    for (i, line) in text.lines().enumerate() {
        let mut l = line.trim();
        for marker in ["//!", "///", "//", "#", "*"] {
            if let Some(rest) = l.strip_prefix(marker) {
                l = rest.trim_start();
                break;
            }
        }
        let l = l.strip_suffix('\\').unwrap_or(l);
        let l = l
            .replace("\\n", " ")
            .replace("\\t", " ")
            .replace("\\\"", "\"")
            .replace('\u{2019}', "'")
            .to_lowercase();
        for c in l.chars().chain([' ']) {
            let c = if c.is_whitespace() { ' ' } else { c };
            if c == ' ' && (out.is_empty() || out.ends_with(' ')) {
                continue;
            }
            out.push(c);
            lines.extend(std::iter::repeat_n(i + 1, c.len_utf8()));
        }
    }
    (out, lines)
}

/// The lines of `text` where `request` (normalised) stands between non-alphanumerics.
fn lines_with(text: &str, lines: &[usize], request: &str) -> Vec<usize> {
    let mut found = Vec::new();
    for (at, _) in text.match_indices(request) {
        let before = text[..at].chars().next_back();
        let after = text[at + request.len()..].chars().next();
        if !before.is_some_and(char::is_alphanumeric) && !after.is_some_and(char::is_alphanumeric) {
            found.push(lines[at]);
        }
    }
    found
}

fn files_under(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<PathBuf> = entries.filter_map(|e| e.ok()).map(|e| e.path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            files_under(&p, out);
        } else {
            out.push(p);
        }
    }
}

/// The sentences a bench file lists: a `const`, `static` or `let` bound to a string
/// array whose every element has a space, or a `&str` constant that has one (chart
/// labels and other strings passed inline are not requests).
#[derive(Default)]
struct BenchRequests(Vec<String>);

impl BenchRequests {
    fn take(&mut self, expr: &syn::Expr) {
        let sentence = |e: &syn::Expr| match e {
            syn::Expr::Lit(syn::ExprLit {
                lit: syn::Lit::Str(s),
                ..
            }) if s.value().trim().contains(' ') => Some(s.value()),
            _ => None,
        };
        match expr {
            syn::Expr::Reference(r) => self.take(&r.expr),
            syn::Expr::Array(a) => {
                let all: Vec<String> = a.elems.iter().filter_map(sentence).collect();
                if !all.is_empty() && all.len() == a.elems.len() {
                    self.0.extend(all);
                }
            }
            e => self.0.extend(sentence(e)),
        }
    }
}

impl<'a> Visit<'a> for BenchRequests {
    fn visit_item_const(&mut self, c: &'a syn::ItemConst) {
        self.take(&c.expr);
        syn::visit::visit_item_const(self, c);
    }

    fn visit_item_static(&mut self, s: &'a syn::ItemStatic) {
        self.take(&s.expr);
        syn::visit::visit_item_static(self, s);
    }

    fn visit_local(&mut self, l: &'a syn::Local) {
        if let Some(init) = &l.init {
            if matches!(&*init.expr, syn::Expr::Array(_) | syn::Expr::Reference(_)) {
                self.take(&init.expr);
            }
        }
        syn::visit::visit_local(self, l);
    }
}

/// Every request the project lists, with the file that lists it (first one wins);
/// `Err` names a file under `tests/eval/` this test cannot read.
fn requests() -> Result<BTreeMap<String, (String, String)>, String> {
    let mut out: BTreeMap<String, (String, String)> = BTreeMap::new();
    let mut add = |text: &str, from: &Path| {
        out.entry(normalise_request(text))
            .or_insert_with(|| (text.to_string(), relative(from)));
    };
    let lines_of = |p: &Path| -> Result<String, String> {
        std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", relative(p)))
    };
    let mut eval = Vec::new();
    files_under(&root().join("tests/eval"), &mut eval);
    for p in &eval {
        match p.extension().and_then(|e| e.to_str()) {
            Some("jsonl") => {
                for (i, line) in lines_of(p)?.lines().enumerate() {
                    if line.trim().is_empty() {
                        continue;
                    }
                    let v: serde_json::Value = serde_json::from_str(line)
                        .map_err(|e| format!("{}:{}: {e}", relative(p), i + 1))?;
                    let q = v["query"].as_str().ok_or_else(|| {
                        format!("{}:{}: a case without a `query` string", relative(p), i + 1)
                    })?;
                    add(q, p);
                }
            }
            Some("txt") => {}
            Some("md") => continue,
            _ => {
                return Err(format!(
                    "{}: not a request list this test reads (.jsonl cases with `query`, .txt one request a line): teach tests/suite_leak.rs to read it",
                    relative(p)
                ))
            }
        }
    }
    let mut data = Vec::new();
    files_under(&root().join("tests/data"), &mut data);
    for p in eval.iter().chain(&data) {
        if p.extension().is_some_and(|e| e == "txt") {
            for line in lines_of(p)?.lines() {
                let line = line.trim();
                if !line.is_empty() && !line.starts_with('#') {
                    add(line, p);
                }
            }
        }
    }
    let mut benches = Vec::new();
    files_under(&root().join("benches"), &mut benches);
    for p in benches
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e == "rs"))
    {
        let file = syn::parse_file(&lines_of(p)?).map_err(|e| format!("{}: {e}", relative(p)))?;
        let mut found = BenchRequests::default();
        found.visit_file(&file);
        for q in found.0 {
            add(&q, p);
        }
    }
    Ok(out)
}

#[test]
fn no_suite_request_stands_in_the_product() {
    let requests = requests().unwrap_or_else(|e| panic!("{e}"));
    let (checked, exempted): (Vec<_>, Vec<_>) =
        requests.iter().partition(|(norm, _)| !exempt(norm));
    assert!(
        checked.len() >= 100,
        "only {} requests read: the suites moved?",
        checked.len()
    );
    let mut scanned = Vec::new();
    for dir in ["src", "web", "prompts", "data"] {
        files_under(&root().join(dir), &mut scanned);
    }
    let mut hits: Vec<(String, usize, String)> = Vec::new();
    for p in &scanned {
        // Images and other bytes hold no sentence.
        let Ok(text) = std::fs::read_to_string(p) else {
            continue;
        };
        let (flat, lines) = prose(&text);
        for (norm, (request, from)) in &checked {
            for line in lines_with(&flat, &lines, norm) {
                hits.push((relative(p), line, format!("{request:?} (from {from})")));
            }
        }
    }
    let mut per_list: BTreeMap<&str, usize> = BTreeMap::new();
    for (_, (_, from)) in &checked {
        *per_list.entry(from.as_str()).or_default() += 1;
    }
    eprintln!(
        "{} requests checked ({per_list:?}) against {} files; exempt (fewer than three words, letters only): {:?}",
        checked.len(),
        scanned.len(),
        exempted.iter().map(|(_, (r, _))| r).collect::<Vec<_>>()
    );
    hits.sort();
    let listed: Vec<String> = hits
        .iter()
        .map(|(file, line, what)| format!("{file}:{line}: {what}"))
        .collect();
    assert!(
        hits.is_empty(),
        "{} suite requests stand in the product; write the product's own sentences instead:\n{}",
        hits.len(),
        listed.join("\n")
    );
}

/// The scan itself: a request found whatever its case and closing mark, inside a longer
/// literal, and over a doc comment's wrapped lines (on the line it starts); not inside
/// a longer word; a short request of plain words exempt, one with a name not.
#[test]
fn the_scan_finds_a_request_however_it_is_written() {
    let request = normalise_request("  Where IS the   robot? ");
    assert_eq!(request, "where is the robot");
    let source = "fn f() {}\n/// Asked \"where is the\n/// Robot!\" it reads the pose.\nlet s = \"ok\\nwhere is the robot now\";\nlet t = \"somewhere is the robots\";\n";
    let (flat, lines) = prose(source);
    assert_eq!(lines_with(&flat, &lines, &request), [2, 4]);
    assert!(exempt(&normalise_request("Fermati subito!")));
    assert!(exempt(&normalise_request("battery?")));
    assert!(!exempt(&normalise_request("echo /turtle/pose")));
    assert!(!exempt(&normalise_request("list the nodes")));
}
