//! The library's structure, read from its source with a Rust parser.
//!
//! - Dependency arrows: every path a file names (`use` trees, types, calls, macros'
//!   paths), resolved through module declarations and re-exports to the file that defines
//!   the item. Fails on a cycle between files and on an arrow the layering does not allow
//!   (see `src/lib.rs`). `#[cfg(test)]` code is left out: tests may reach anywhere.
//! - Size: no function over 100 lines in `src/`, test code left out.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use syn::visit::Visit;

/// Which top-level modules each may use (besides itself).
const ALLOWED: &[(&str, &[&str])] = &[
    ("chat", &[]),
    ("lexicon", &[]),
    ("stop_intent", &["lexicon"]),
    ("json", &["lexicon"]),
    ("units", &["lexicon"]),
    ("estop", &[]),
    ("fence", &[]),
    ("limits", &[]),
    ("clock", &[]),
    ("dirs", &[]),
    ("store", &["clock", "dirs", "lexicon"]),
    ("metrics", &[]),
    ("speech", &["dirs"]),
    ("backend", &["chat", "clock", "metrics"]),
    ("models", &["backend", "metrics", "dirs"]),
    ("embed", &["models"]),
    ("tool", &["chat", "lexicon", "estop", "fence", "limits"]),
    (
        "reading",
        &["tool", "lexicon", "units", "stop_intent", "embed"],
    ),
    ("decode", &["backend", "tool", "chat", "lexicon", "json"]),
    ("remote", &["decode", "backend", "tool", "chat", "json"]),
    (
        "strategy",
        &["decode", "backend", "tool", "chat", "lexicon", "json"],
    ),
    (
        "turn",
        &[
            "strategy", "remote", "decode", "backend", "tool", "chat", "json",
        ],
    ),
    ("ros", &["lexicon", "clock", "estop", "fence", "limits"]),
    (
        "tools",
        &[
            "tool", "ros", "lexicon", "units", "clock", "chat", "estop", "fence", "limits", "store",
        ],
    ),
    (
        "agent",
        &[
            "reading",
            "turn",
            "decode",
            "strategy",
            "backend",
            "tool",
            "chat",
            "lexicon",
            "units",
            "clock",
            "estop",
            "fence",
            "remote",
            "stop_intent",
            "embed",
            "store",
        ],
    ),
    (
        "eval",
        &[
            "agent", "reading", "turn", "strategy", "decode", "backend", "tool", "tools", "ros",
            "chat", "lexicon", "models", "metrics", "clock", "json", "estop", "fence", "limits",
            "remote", "speech",
        ],
    ),
    (
        "ui",
        &[
            "agent",
            "reading",
            "turn",
            "embed",
            "strategy",
            "decode",
            "backend",
            "tool",
            "tools",
            "ros",
            "chat",
            "lexicon",
            "models",
            "metrics",
            "clock",
            "eval",
            "json",
            "estop",
            "fence",
            "limits",
            "dirs",
            "remote",
            "speech",
            "stop_intent",
            "store",
        ],
    ),
];

/// One source file as a module: its path in the crate, what it defines, what it imports.
#[derive(Default)]
struct Module {
    file: PathBuf,
    /// Child modules declared here (`mod x;` or inline), by name → module path.
    children: BTreeMap<String, Vec<String>>,
    /// Items defined here.
    items: BTreeSet<String>,
    /// `use` bindings: name → absolute path (segments after `crate`).
    uses: BTreeMap<String, Vec<String>>,
    /// Glob imports (`use x::*`), as absolute module paths.
    globs: Vec<Vec<String>>,
    /// Every path this file names, as written, made absolute where it starts with
    /// `crate`, `self`, `super` or a `use` binding.
    refs: Vec<Vec<String>>,
}

fn is_test(attrs: &[syn::Attribute]) -> bool {
    attrs.iter().any(|a| {
        a.path().is_ident("cfg")
            && a.parse_args::<syn::Meta>()
                .is_ok_and(|m| m.path().is_ident("test"))
    })
}

/// Absolute segments of `path` written in module `at` (`None` when it is not a crate
/// path: std, an external crate, a local name). `children` are `at`'s child modules,
/// which a path may start with.
fn absolute(
    at: &[String],
    path: &[String],
    uses: &BTreeMap<String, Vec<String>>,
    children: &BTreeMap<String, Vec<String>>,
) -> Option<Vec<String>> {
    let first = path.first()?;
    if let Some(child) = children.get(first) {
        let mut out = child.clone();
        out.extend(path[1..].iter().cloned());
        return Some(out);
    }
    let mut out: Vec<String> = match first.as_str() {
        "crate" => Vec::new(),
        "self" => at.to_vec(),
        "super" => {
            let mut m = at.to_vec();
            let mut rest = path;
            while rest.first().is_some_and(|s| s == "super") {
                m.pop()?;
                rest = &rest[1..];
            }
            m.extend(rest.iter().cloned());
            return Some(m);
        }
        name => {
            let mut target = uses.get(name)?.clone();
            target.extend(path[1..].iter().cloned());
            return Some(target);
        }
    };
    out.extend(path[1..].iter().cloned());
    Some(out)
}

fn segments(p: &syn::Path) -> Vec<String> {
    p.segments.iter().map(|s| s.ident.to_string()).collect()
}

/// Flatten a use tree into (binding name, path) pairs; globs get the name "*".
fn use_tree(prefix: &mut Vec<String>, tree: &syn::UseTree, out: &mut Vec<(String, Vec<String>)>) {
    match tree {
        syn::UseTree::Path(p) => {
            prefix.push(p.ident.to_string());
            use_tree(prefix, &p.tree, out);
            prefix.pop();
        }
        syn::UseTree::Name(n) => {
            let name = n.ident.to_string();
            let mut path = prefix.clone();
            if name != "self" {
                path.push(name.clone());
            }
            let bound = if name == "self" {
                prefix.last().cloned().unwrap_or_default()
            } else {
                name
            };
            out.push((bound, path));
        }
        syn::UseTree::Rename(r) => {
            let mut path = prefix.clone();
            path.push(r.ident.to_string());
            out.push((r.rename.to_string(), path));
        }
        syn::UseTree::Glob(_) => out.push(("*".into(), prefix.clone())),
        syn::UseTree::Group(g) => g.items.iter().for_each(|t| use_tree(prefix, t, out)),
    }
}

/// Every path named in non-test code.
struct Paths(Vec<Vec<String>>);

impl<'a> Visit<'a> for Paths {
    fn visit_path(&mut self, p: &'a syn::Path) {
        self.0.push(segments(p));
        syn::visit::visit_path(self, p);
    }
    fn visit_item_mod(&mut self, m: &'a syn::ItemMod) {
        if !is_test(&m.attrs) {
            syn::visit::visit_item_mod(self, m);
        }
    }
    fn visit_item_fn(&mut self, f: &'a syn::ItemFn) {
        if !is_test(&f.attrs) {
            syn::visit::visit_item_fn(self, f);
        }
    }
    fn visit_macro(&mut self, m: &'a syn::Macro) {
        // Paths inside macro bodies (`json!`, `format!`) are not parsed; those of the
        // macro itself are.
        self.visit_path(&m.path);
    }
}

/// Read the module at `path` (file `file`) and its children, into `out`.
fn read(path: Vec<String>, file: &Path, out: &mut BTreeMap<Vec<String>, Module>) {
    let text = std::fs::read_to_string(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let ast = syn::parse_file(&text).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let dir = match file.file_name().and_then(|n| n.to_str()) {
        Some("lib.rs" | "mod.rs" | "main.rs") => file.parent().unwrap().to_path_buf(),
        _ => file.with_extension(""),
    };
    let mut m = Module {
        file: file.to_path_buf(),
        ..Module::default()
    };
    let mut bindings = Vec::new();
    for item in &ast.items {
        let (ident, attrs) = match item {
            syn::Item::Struct(i) => (Some(&i.ident), &i.attrs),
            syn::Item::Enum(i) => (Some(&i.ident), &i.attrs),
            syn::Item::Fn(i) => (Some(&i.sig.ident), &i.attrs),
            syn::Item::Trait(i) => (Some(&i.ident), &i.attrs),
            syn::Item::Type(i) => (Some(&i.ident), &i.attrs),
            syn::Item::Const(i) => (Some(&i.ident), &i.attrs),
            syn::Item::Static(i) => (Some(&i.ident), &i.attrs),
            syn::Item::Union(i) => (Some(&i.ident), &i.attrs),
            syn::Item::Macro(i) => (i.ident.as_ref(), &i.attrs),
            syn::Item::Mod(i) => {
                if is_test(&i.attrs) {
                    continue;
                }
                let name = i.ident.to_string();
                let mut child = path.clone();
                child.push(name.clone());
                m.children.insert(name.clone(), child.clone());
                if i.content.is_none() {
                    let f = dir.join(format!("{name}.rs"));
                    let f = if f.exists() {
                        f
                    } else {
                        dir.join(&name).join("mod.rs")
                    };
                    read(child, &f, out);
                }
                continue;
            }
            syn::Item::Use(u) => {
                if !is_test(&u.attrs) {
                    let mut found = Vec::new();
                    use_tree(&mut Vec::new(), &u.tree, &mut found);
                    let public = !matches!(u.vis, syn::Visibility::Inherited);
                    bindings.extend(found.into_iter().map(|(n, p)| (n, p, public)));
                }
                continue;
            }
            _ => continue,
        };
        if let Some(ident) = ident.filter(|_| !is_test(attrs)) {
            m.items.insert(ident.to_string());
        }
    }
    for (name, p, public) in &bindings {
        if let Some(abs) = absolute(&path, p, &BTreeMap::new(), &m.children) {
            if name == "*" {
                m.globs.push(abs.clone());
            } else {
                m.uses.insert(name.clone(), abs.clone());
            }
            // A re-export is not a use of the item by this file's own code.
            if !public {
                m.refs.push(abs);
            }
        }
    }
    let mut paths = Paths(Vec::new());
    paths.visit_file(&ast);
    for p in paths.0 {
        if let Some(abs) = absolute(&path, &p, &m.uses, &m.children) {
            m.refs.push(abs);
        }
    }
    out.insert(path, m);
}

/// The file that defines what `path` names, following modules and re-exports.
fn resolve(
    path: &[String],
    modules: &BTreeMap<Vec<String>, Module>,
    depth: usize,
) -> Option<PathBuf> {
    if depth > 16 {
        return None;
    }
    let mut at: Vec<String> = Vec::new();
    for (i, seg) in path.iter().enumerate() {
        let m = modules.get(&at)?;
        if let Some(child) = m.children.get(seg) {
            at = child.clone();
            continue;
        }
        if m.items.contains(seg) {
            return Some(m.file.clone());
        }
        if let Some(target) = m.uses.get(seg) {
            let mut t = target.clone();
            t.extend(path[i + 1..].iter().cloned());
            return resolve(&t, modules, depth + 1);
        }
        for g in &m.globs {
            let mut t = g.clone();
            t.extend(path[i..].iter().cloned());
            if let Some(f) = resolve(&t, modules, depth + 1) {
                return Some(f);
            }
        }
        return None;
    }
    // A path to a module itself names nothing in particular.
    None
}

/// The top-level module a library file belongs to (`src/agent/run.rs` → `agent`).
fn top(file: &Path, src: &Path) -> String {
    let rel = file.strip_prefix(src).unwrap();
    let first = rel
        .components()
        .next()
        .unwrap()
        .as_os_str()
        .to_string_lossy();
    first.trim_end_matches(".rs").to_string()
}

/// Files in a cycle (strongly connected components of more than one file).
fn cycles(edges: &BTreeMap<PathBuf, BTreeSet<PathBuf>>) -> Vec<Vec<PathBuf>> {
    // Tarjan's algorithm, iteratively small enough to write recursively here.
    struct T<'a> {
        edges: &'a BTreeMap<PathBuf, BTreeSet<PathBuf>>,
        index: BTreeMap<&'a PathBuf, usize>,
        low: BTreeMap<&'a PathBuf, usize>,
        stack: Vec<&'a PathBuf>,
        on: BTreeSet<&'a PathBuf>,
        next: usize,
        out: Vec<Vec<PathBuf>>,
    }
    impl<'a> T<'a> {
        fn visit(&mut self, v: &'a PathBuf) {
            self.index.insert(v, self.next);
            self.low.insert(v, self.next);
            self.next += 1;
            self.stack.push(v);
            self.on.insert(v);
            for w in self.edges.get(v).into_iter().flatten() {
                if !self.index.contains_key(w) {
                    self.visit(w);
                    let l = self.low[w].min(self.low[v]);
                    self.low.insert(v, l);
                } else if self.on.contains(w) {
                    let l = self.index[w].min(self.low[v]);
                    self.low.insert(v, l);
                }
            }
            if self.low[v] == self.index[v] {
                let mut scc = Vec::new();
                while let Some(w) = self.stack.pop() {
                    self.on.remove(w);
                    scc.push(w.clone());
                    if w == v {
                        break;
                    }
                }
                if scc.len() > 1 {
                    self.out.push(scc);
                }
            }
        }
    }
    let mut t = T {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in edges.keys() {
        if !t.index.contains_key(v) {
            t.visit(v);
        }
    }
    t.out
}

/// The file-to-file arrows of the library at `src`.
fn arrows(src: &Path) -> BTreeMap<PathBuf, BTreeSet<PathBuf>> {
    let mut modules = BTreeMap::new();
    read(Vec::new(), &src.join("lib.rs"), &mut modules);
    let mut edges: BTreeMap<PathBuf, BTreeSet<PathBuf>> = BTreeMap::new();
    for m in modules.values() {
        let to = edges.entry(m.file.clone()).or_default();
        for r in &m.refs {
            if let Some(f) = resolve(r, &modules, 0) {
                if f != m.file {
                    to.insert(f);
                }
            }
        }
    }
    edges
}

/// What is wrong with the arrows of the library at `src`: cycles, and arrows the
/// layering does not allow.
fn problems(src: &Path) -> Vec<String> {
    let edges = arrows(src);
    let rel = |f: &Path| f.strip_prefix(src).unwrap().display().to_string();
    let mut out: Vec<String> = cycles(&edges)
        .into_iter()
        .map(|c| {
            format!(
                "cycle: {}",
                c.iter().map(|f| rel(f)).collect::<Vec<_>>().join(" ↔ ")
            )
        })
        .collect();
    let allowed: BTreeMap<&str, &[&str]> = ALLOWED.iter().copied().collect();
    for (from, tos) in &edges {
        let a = top(from, src);
        for to in tos {
            let b = top(to, src);
            if a == b || a == "lib" {
                continue;
            }
            match allowed.get(a.as_str()) {
                Some(ok) if ok.contains(&b.as_str()) => {}
                Some(_) => out.push(format!(
                    "arrow against the layering: {} → {} ({a} may not use {b})",
                    rel(from),
                    rel(to)
                )),
                None => out.push(format!(
                    "{a} is not in the layering (tests/arrows.rs ALLOWED)"
                )),
            }
        }
    }
    out.sort();
    out.dedup();
    out
}

#[test]
fn no_cycles_and_every_arrow_points_the_intended_way() {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src");
    let problems = problems(&src);
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    // The reader sees the whole library: a resolver that found nothing would pass.
    let edges = arrows(&src);
    let agent_uses_decode = edges
        .iter()
        .any(|(f, tos)| top(f, &src) == "agent" && tos.iter().any(|t| top(t, &src) == "decode"));
    assert!(
        agent_uses_decode,
        "the resolver lost the agent → decode arrows"
    );
    assert!(edges.len() > 60, "only {} files read", edges.len());
}

#[test]
fn a_wrong_arrow_or_a_cycle_is_caught() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path();
    let write = |p: &str, t: &str| {
        let f = src.join(p);
        std::fs::create_dir_all(f.parent().unwrap()).unwrap();
        std::fs::write(f, t).unwrap();
    };
    write("lib.rs", "pub mod agent;\npub mod ros;\npub mod tool;\n");
    write(
        "agent/mod.rs",
        "mod run;\npub use run::Run;\npub struct Agent;\nfn go() -> run::Run { run::Run::new() }\n",
    );
    write(
        "agent/run.rs",
        "use crate::ros::Graph;\npub struct Run(Graph, super::Agent);\n",
    );
    write("ros.rs", "pub struct Graph;\n");
    write("tool/mod.rs", "pub mod a;\npub mod b;\n");
    write("tool/a.rs", "pub struct A(pub super::b::B);\n");
    write(
        "tool/b.rs",
        "pub struct B(pub Option<Box<crate::tool::a::A>>);\n",
    );
    let found = problems(src);
    assert!(
        found.iter().any(|p| p.contains("agent/run.rs → ros.rs")),
        "{found:?}"
    );
    assert!(
        found
            .iter()
            .any(|p| p.starts_with("cycle") && p.contains("tool/a.rs") && p.contains("tool/b.rs")),
        "{found:?}"
    );
    // A module and its child that use each other are a cycle too; a re-export is not.
    assert!(
        found.iter().any(|p| p.starts_with("cycle")
            && p.contains("agent/mod.rs")
            && p.contains("agent/run.rs")),
        "{found:?}"
    );
}

/// Functions (free, in impls, in traits) longer than `max` lines in the files under `dir`
/// and its folders; test code (`#[cfg(test)]` modules, `#[test]` functions) left out.
fn long_functions(dir: &Path, max: usize) -> Vec<String> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let file = entry.unwrap().path();
        if file.is_dir() {
            out.extend(long_functions(&file, max));
        } else if file.extension().is_some_and(|e| e == "rs") {
            out.extend(long_in(
                &file,
                &std::fs::read_to_string(&file).unwrap(),
                max,
            ));
        }
    }
    out
}

/// As `long_functions`, in one file's text.
fn long_in(file: &Path, text: &str, max: usize) -> Vec<String> {
    struct Long<'a> {
        file: &'a Path,
        max: usize,
        out: Vec<String>,
    }
    impl Long<'_> {
        fn check(&mut self, name: &syn::Ident, span: proc_macro2::Span) {
            let lines = span.end().line + 1 - span.start().line;
            if lines > self.max {
                self.out
                    .push(format!("{}: {name} is {lines} lines", self.file.display()));
            }
        }
    }
    impl<'a> Visit<'a> for Long<'_> {
        fn visit_item_mod(&mut self, m: &'a syn::ItemMod) {
            if !is_test(&m.attrs) {
                syn::visit::visit_item_mod(self, m);
            }
        }
        fn visit_item_fn(&mut self, f: &'a syn::ItemFn) {
            use syn::spanned::Spanned;
            if f.attrs.iter().any(|a| a.path().is_ident("test")) || is_test(&f.attrs) {
                return;
            }
            self.check(&f.sig.ident, f.span());
            syn::visit::visit_item_fn(self, f);
        }
        fn visit_impl_item_fn(&mut self, f: &'a syn::ImplItemFn) {
            use syn::spanned::Spanned;
            self.check(&f.sig.ident, f.span());
            syn::visit::visit_impl_item_fn(self, f);
        }
        fn visit_trait_item_fn(&mut self, f: &'a syn::TraitItemFn) {
            use syn::spanned::Spanned;
            self.check(&f.sig.ident, f.span());
            syn::visit::visit_trait_item_fn(self, f);
        }
    }
    let mut v = Long {
        file,
        max,
        out: Vec::new(),
    };
    v.visit_file(&syn::parse_file(text).unwrap());
    v.out
}

#[test]
fn no_function_runs_long() {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src");
    let long = long_functions(&src, 100);
    assert!(long.is_empty(), "{}", long.join("\n"));
    // The check sees functions at all, in folders too, and not test code: the longest
    // in decode/ is well over 10 lines, and a test module's functions do not count.
    assert!(!long_functions(&src.join("decode"), 10).is_empty());
    let probe = "#[cfg(test)]\nmod tests {\n    fn t() {\n\n\n    }\n}\n\n#[test]\nfn u() {\n\n\n}\n\nfn f() {\n\n\n}\n";
    let found = long_in(Path::new("probe.rs"), probe, 3);
    assert_eq!(found, ["probe.rs: f is 4 lines"]);
}
