//! `ferrosa memory list|export|forget`: what the robot keeps across sessions (the memory
//! file, `store`), shown to the operator, written out whole, or deleted. Each robot's
//! memory is kept apart under its key (`sim`, `ros2`, `ros2/arm`: the robot kind and its
//! robot file's name), and every command takes `--of KEY` to work on one.

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde_json::{json, Value};

use super::term::clean;
use crate::store::Store;

/// Which memory, and whose.
pub struct Which {
    /// The memory file; `None`: `memory.sqlite` in the data directory.
    pub file: Option<PathBuf>,
    /// One robot's key; `None`: every robot the file keeps anything for.
    pub of: Option<String>,
}

/// What `forget` deletes.
pub enum Forget {
    /// A place taught at run time, by name.
    Place(String),
    /// A fact, by the id `list` shows.
    Fact(i64),
    /// The request log.
    Runs,
    /// Everything.
    All,
}

fn path(which: &Which) -> anyhow::Result<PathBuf> {
    which.file.clone().or_else(crate::store::default_path).context(
        "this machine has no data directory (set HOME or XDG_DATA_HOME), and no --memory FILE was given",
    )
}

/// The stores of the robots `which` names (every robot in the file without `--of`).
fn stores(which: &Which) -> anyhow::Result<(PathBuf, Vec<Store>)> {
    let path = path(which)?;
    if !path.exists() {
        return Ok((path, Vec::new()));
    }
    let keys = match &which.of {
        Some(k) => vec![k.clone()],
        None => Store::open(&path, "")?.robots()?,
    };
    let stores = keys
        .iter()
        .map(|k| Store::open(&path, k))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((path, stores))
}

fn nothing(path: &Path, which: &Which) {
    match &which.of {
        Some(k) => eprintln!("{}: nothing is kept for {}", path.display(), clean(k)),
        None => eprintln!("{}: nothing is kept", path.display()),
    }
}

/// `ferrosa memory list`: each robot's places, facts and latest requests.
pub fn list(which: &Which, runs: usize) -> anyhow::Result<()> {
    let (path, stores) = stores(which)?;
    if stores.is_empty() {
        nothing(&path, which);
        return Ok(());
    }
    println!("{}", path.display());
    for s in &stores {
        println!("\n[{}]", clean(s.robot()));
        let places = s.places()?;
        println!("places taught ({}):", places.len());
        for p in &places {
            println!(
                "  {:<20} x {:.2}  y {:.2}  yaw {:.1}°  {}",
                clean(&p.name),
                p.x,
                p.y,
                p.yaw.to_degrees(),
                clean(&p.frame)
            );
        }
        let facts = s.facts()?;
        println!("facts ({}):", facts.len());
        for f in &facts {
            println!(
                "  #{:<4} {}  {}",
                f.id,
                short_time(&f.created),
                clean(&f.text)
            );
        }
        let log = s.runs(runs)?;
        println!("latest requests ({}):", log.len());
        for r in &log {
            println!(
                "  {}  {} → {}",
                short_time(&r.at),
                clean(&r.request),
                clean(&first_line(&r.answer, 100))
            );
        }
    }
    Ok(())
}

/// `ferrosa memory export`: everything, as JSON, to `out` or standard output.
pub fn export(which: &Which, out: Option<&Path>) -> anyhow::Result<()> {
    let (path, stores) = stores(which)?;
    let mut robots = serde_json::Map::new();
    for s in &stores {
        robots.insert(
            s.robot().to_string(),
            json!({"places": s.places()?, "facts": s.facts()?, "requests": s.runs(usize::MAX >> 1)?}),
        );
    }
    let doc: Value = json!({"file": path.display().to_string(), "robots": robots});
    let text = serde_json::to_string_pretty(&doc)? + "\n";
    match out {
        Some(o) => {
            std::fs::write(o, text).with_context(|| format!("cannot write {}", o.display()))?;
            eprintln!("wrote {} robots' memory to {}", stores.len(), o.display());
        }
        None => print!("{text}"),
    }
    Ok(())
}

/// `ferrosa memory forget`: delete what `what` names, for the robots `which` names.
pub fn forget(which: &Which, what: &Forget) -> anyhow::Result<()> {
    let (path, stores) = stores(which)?;
    if stores.is_empty() && matches!(what, Forget::Runs | Forget::All) {
        nothing(&path, which);
        return Ok(());
    }
    let mut gone = 0usize;
    for s in &stores {
        let robot = clean(s.robot());
        match what {
            Forget::Place(name) => {
                if s.forget_place(name)? {
                    println!("[{robot}] forgot the place {}", clean(name));
                    gone += 1;
                }
            }
            Forget::Fact(id) => {
                if s.forget_fact(*id)? {
                    println!("[{robot}] forgot fact #{id}");
                    gone += 1;
                }
            }
            Forget::Runs => {
                let n = s.forget_runs()?;
                println!("[{robot}] forgot {n} logged requests");
                gone += n;
            }
            Forget::All => {
                s.forget_all()?;
                println!("[{robot}] forgot everything");
                gone += 1;
            }
        }
    }
    match what {
        Forget::Place(name) if gone == 0 => anyhow::bail!(
            "no taught place is called {}: `ferrosa memory list` shows them (a robot file's places are changed in that file)",
            clean(name)
        ),
        Forget::Fact(id) if gone == 0 => {
            anyhow::bail!("no fact #{id}: `ferrosa memory list` shows their numbers")
        }
        _ => Ok(()),
    }
}

/// "2026-11-28 08:12" of an ISO time.
pub(super) fn short_time(iso: &str) -> String {
    iso.get(..16).unwrap_or(iso).replace('T', " ")
}

fn first_line(text: &str, max: usize) -> String {
    let line = text.lines().next().unwrap_or("");
    match line.char_indices().nth(max) {
        Some((at, _)) => format!("{}…", &line[..at]),
        None => line.to_string(),
    }
}
