//! What the robot keeps across sessions, on the robot only: one SQLite file in the data
//! directory (`memory.sqlite`), opened at start. It holds the places taught at run time
//! (a robot file's own places stay in that file), facts the operator states, and a log
//! of past requests, their calls and answers.
//!
//! The file is the operator's: a file that is not a database, is another program's
//! database, is from a newer ferrosa, or is locked by another process is a clear error
//! that names it, and it is never rewritten or removed here. Every write is one
//! transaction. Text stored here has passed the fence's redaction where it came from a
//! tool (the caller's duty: the store keeps what it is given).
//!
//! Depends on `clock` and `dirs`.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Duration;

use rusqlite::{params, Connection, OpenFlags};
use serde::{Deserialize, Serialize};

/// The file's name in the data directory.
pub const FILE: &str = "memory.sqlite";
/// The schema this build writes (SQLite's `user_version`). 2: runs carry their
/// session and how they ended.
const SCHEMA: i64 = 2;
/// How long a write waits for another process holding the file.
const BUSY_WAIT: Duration = Duration::from_secs(2);
/// Longest text kept in one field; longer is cut (a log, not an archive).
const MAX_TEXT: usize = 4000;

const TABLES: &str = "
CREATE TABLE IF NOT EXISTS places (
    robot TEXT NOT NULL,
    name TEXT NOT NULL,
    frame TEXT NOT NULL,
    x REAL NOT NULL,
    y REAL NOT NULL,
    yaw REAL NOT NULL,
    aliases TEXT NOT NULL DEFAULT '[]',
    description TEXT NOT NULL DEFAULT '',
    created TEXT NOT NULL,
    PRIMARY KEY (robot, name)
);
CREATE TABLE IF NOT EXISTS facts (
    id INTEGER PRIMARY KEY,
    robot TEXT NOT NULL,
    text TEXT NOT NULL,
    created TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY,
    robot TEXT NOT NULL,
    at TEXT NOT NULL,
    request TEXT NOT NULL,
    calls TEXT NOT NULL,
    answer TEXT NOT NULL,
    session TEXT NOT NULL DEFAULT '',
    finish TEXT NOT NULL DEFAULT 'answer'
);
";
/// From schema 1 (runs without their session).
const FROM_1: &str = "
ALTER TABLE runs ADD COLUMN session TEXT NOT NULL DEFAULT '';
ALTER TABLE runs ADD COLUMN finish TEXT NOT NULL DEFAULT 'answer';
";

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("the memory file {0} is not a database ferrosa can read; it is kept as it is: move it aside to start a new memory, or point XDG_DATA_HOME elsewhere")]
    NotADatabase(PathBuf),
    #[error("the memory file {path} was written by a newer ferrosa (schema {found}, this build reads {SCHEMA}); it is kept as it is: run that ferrosa, or move the file aside")]
    Newer { path: PathBuf, found: i64 },
    #[error("{0} is a database of something else, not a ferrosa memory file; it is kept as it is: give --memory another file")]
    Foreign(PathBuf),
    #[error("the memory file {0} is locked by another process; close the other ferrosa using it, or wait and try again")]
    Locked(PathBuf),
    #[error("the memory file {path}: {message}")]
    Other { path: PathBuf, message: String },
}

/// A named pose: where the robot can be sent by name.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Place {
    pub name: String,
    /// The frame of `x`, `y`, `yaw` (Nav2's global frame, `map`, unless said).
    #[serde(default = "map_frame")]
    pub frame: String,
    pub x: f64,
    pub y: f64,
    /// Heading to end at, radians, counter-clockwise from the frame's x axis.
    #[serde(default)]
    pub yaw: f64,
    /// Other names operators use for it, in any language ("dock", "Ladestation").
    #[serde(default)]
    pub aliases: Vec<String>,
    #[serde(default)]
    pub description: String,
}

fn map_frame() -> String {
    "map".to_string()
}

/// A fact the operator stated, as stored.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Fact {
    pub id: i64,
    pub text: String,
    pub created: String,
}

/// One past request, as logged.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Run {
    pub id: i64,
    pub at: String,
    pub request: String,
    /// The calls made, as `name(arguments)` lines.
    pub calls: String,
    pub answer: String,
    /// The conversation it was part of (`chat --resume` continues the last one).
    pub session: String,
    /// How it ended: `answer`, `cancelled`, `max_steps`.
    pub finish: String,
}

/// A run to log: what was asked, the calls made, what came of it.
#[derive(Debug, Clone, Default)]
pub(crate) struct NewRun<'a> {
    pub session: &'a str,
    pub request: &'a str,
    pub calls: &'a str,
    pub answer: &'a str,
    pub finish: &'a str,
}

/// The memory file, open. Scoped to one robot: a data directory shared by the sim and
/// a real robot keeps each one's places and facts apart.
pub struct Store {
    conn: Mutex<Connection>,
    path: PathBuf,
    robot: String,
}

impl std::fmt::Debug for Store {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Store")
            .field("path", &self.path)
            .field("robot", &self.robot)
            .finish()
    }
}

/// The memory file's path in this machine's data directory.
pub(crate) fn default_path() -> Option<PathBuf> {
    crate::dirs::data_dir().map(|d| d.join(FILE))
}

fn now() -> String {
    crate::clock::Utc::now().iso()
}

fn cut(text: &str) -> String {
    match text.char_indices().nth(MAX_TEXT) {
        Some((at, _)) => format!("{}…", &text[..at]),
        None => text.to_string(),
    }
}

/// Whether `a` and `b` name the same place: letters compared without case or accents.
pub(crate) fn same_name(a: &str, b: &str) -> bool {
    crate::lexicon::folded_words(a) == crate::lexicon::folded_words(b)
}

impl Store {
    /// Open (or create) the memory file at `path` for `robot`.
    pub fn open(path: &Path, robot: &str) -> Result<Store, StoreError> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| StoreError::Other {
                path: path.to_path_buf(),
                message: format!("cannot create its directory: {e}"),
            })?;
        }
        let flags = OpenFlags::SQLITE_OPEN_READ_WRITE
            | OpenFlags::SQLITE_OPEN_CREATE
            | OpenFlags::SQLITE_OPEN_NO_MUTEX;
        let conn = Connection::open_with_flags(path, flags).map_err(|e| classify(path, &e))?;
        conn.busy_timeout(BUSY_WAIT)
            .map_err(|e| classify(path, &e))?;
        let found: i64 = conn
            .query_row("PRAGMA user_version", [], |r| r.get(0))
            .map_err(|e| classify(path, &e))?;
        if found > SCHEMA {
            return Err(StoreError::Newer {
                path: path.to_path_buf(),
                found,
            });
        }
        // A database of something else (`--memory` pointed at it) is not written into.
        let foreign: i64 = conn
            .query_row(
                "SELECT count(*) FROM sqlite_master WHERE type = 'table'
                   AND name NOT IN ('places', 'facts', 'runs') AND name NOT LIKE 'sqlite_%'",
                [],
                |r| r.get(0),
            )
            .map_err(|e| classify(path, &e))?;
        if foreign > 0 {
            return Err(StoreError::Foreign(path.to_path_buf()));
        }
        let upgrade = if found == 1 { FROM_1 } else { "" };
        conn.execute_batch(&format!(
            "BEGIN; {upgrade} {TABLES} PRAGMA user_version = {SCHEMA}; COMMIT;"
        ))
        .map_err(|e| classify(path, &e))?;
        Ok(Store {
            conn: Mutex::new(conn),
            path: path.to_path_buf(),
            robot: robot.to_string(),
        })
    }

    fn err(&self, e: rusqlite::Error) -> StoreError {
        classify(&self.path, &e)
    }

    fn conn(&self) -> std::sync::MutexGuard<'_, Connection> {
        // A panic while holding it leaves SQLite's own state consistent (every write is
        // one statement or one transaction): the connection is still usable.
        self.conn.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The places taught to this robot, by name.
    pub fn places(&self) -> Result<Vec<Place>, StoreError> {
        let conn = self.conn();
        let mut stmt = conn
            .prepare(
                "SELECT name, frame, x, y, yaw, aliases, description FROM places
                 WHERE robot = ?1 ORDER BY name",
            )
            .map_err(|e| self.err(e))?;
        let rows = stmt
            .query_map(params![self.robot], |r| {
                let aliases: String = r.get(5)?;
                Ok(Place {
                    name: r.get(0)?,
                    frame: r.get(1)?,
                    x: r.get(2)?,
                    y: r.get(3)?,
                    yaw: r.get(4)?,
                    aliases: serde_json::from_str(&aliases).unwrap_or_default(),
                    description: r.get(6)?,
                })
            })
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<_, _>>().map_err(|e| self.err(e))
    }

    /// Keep `place` (replacing a taught place of the same name). Whether one was replaced.
    pub(crate) fn put_place(&self, place: &Place) -> Result<bool, StoreError> {
        let mut conn = self.conn();
        let tx = conn.transaction().map_err(|e| self.err(e))?;
        let gone = delete_place(&tx, &self.robot, &place.name).map_err(|e| self.err(e))?;
        tx.execute(
            "INSERT INTO places (robot, name, frame, x, y, yaw, aliases, description, created)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
            params![
                self.robot,
                cut(place.name.trim()),
                cut(&place.frame),
                place.x,
                place.y,
                place.yaw,
                serde_json::to_string(&place.aliases).unwrap_or_else(|_| "[]".into()),
                cut(&place.description),
                now(),
            ],
        )
        .map_err(|e| self.err(e))?;
        tx.commit().map_err(|e| self.err(e))?;
        Ok(gone > 0)
    }

    /// Forget the taught place called `name` (any case or accents). Whether there was one.
    pub(crate) fn forget_place(&self, name: &str) -> Result<bool, StoreError> {
        let mut conn = self.conn();
        let tx = conn.transaction().map_err(|e| self.err(e))?;
        let gone = delete_place(&tx, &self.robot, name).map_err(|e| self.err(e))?;
        tx.commit().map_err(|e| self.err(e))?;
        Ok(gone > 0)
    }

    /// Keep a fact the operator stated; its id.
    pub(crate) fn add_fact(&self, text: &str) -> Result<i64, StoreError> {
        let conn = self.conn();
        conn.execute(
            "INSERT INTO facts (robot, text, created) VALUES (?1, ?2, ?3)",
            params![self.robot, cut(text.trim()), now()],
        )
        .map_err(|e| self.err(e))?;
        Ok(conn.last_insert_rowid())
    }

    /// The facts kept for this robot, oldest first.
    pub fn facts(&self) -> Result<Vec<Fact>, StoreError> {
        let conn = self.conn();
        let mut stmt = conn
            .prepare("SELECT id, text, created FROM facts WHERE robot = ?1 ORDER BY id")
            .map_err(|e| self.err(e))?;
        let rows = stmt
            .query_map(params![self.robot], |r| {
                Ok(Fact {
                    id: r.get(0)?,
                    text: r.get(1)?,
                    created: r.get(2)?,
                })
            })
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<_, _>>().map_err(|e| self.err(e))
    }

    /// Forget one fact by id. Whether there was one.
    pub(crate) fn forget_fact(&self, id: i64) -> Result<bool, StoreError> {
        let conn = self.conn();
        let n = conn
            .execute(
                "DELETE FROM facts WHERE robot = ?1 AND id = ?2",
                params![self.robot, id],
            )
            .map_err(|e| self.err(e))?;
        Ok(n > 0)
    }

    /// Log one finished request.
    pub(crate) fn log_run(&self, run: &NewRun) -> Result<(), StoreError> {
        self.conn()
            .execute(
                "INSERT INTO runs (robot, at, request, calls, answer, session, finish)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
                params![
                    self.robot,
                    now(),
                    cut(run.request),
                    cut(run.calls),
                    cut(run.answer),
                    run.session,
                    run.finish
                ],
            )
            .map_err(|e| self.err(e))?;
        Ok(())
    }

    /// The newest `limit` runs, oldest first.
    pub fn runs(&self, limit: usize) -> Result<Vec<Run>, StoreError> {
        self.query_runs(
            "SELECT * FROM runs WHERE robot = ?1 ORDER BY id DESC LIMIT ?2",
            params![self.robot, limit as i64],
        )
    }

    /// The runs of the newest session (up to `limit`, its last ones), oldest first; empty
    /// when nothing is logged.
    pub(crate) fn last_session(&self, limit: usize) -> Result<Vec<Run>, StoreError> {
        self.query_runs(
            "SELECT * FROM runs WHERE robot = ?1 AND session =
               (SELECT session FROM runs WHERE robot = ?1 ORDER BY id DESC LIMIT 1)
             ORDER BY id DESC LIMIT ?2",
            params![self.robot, limit as i64],
        )
    }

    /// Runs whose request or answer holds `needle` (any case), the newest `limit`,
    /// oldest first.
    pub(crate) fn runs_about(&self, needle: &str, limit: usize) -> Result<Vec<Run>, StoreError> {
        self.query_runs(
            "SELECT * FROM runs WHERE robot = ?1
               AND (instr(lower(request), lower(?3)) > 0 OR instr(lower(answer), lower(?3)) > 0)
             ORDER BY id DESC LIMIT ?2",
            params![self.robot, limit as i64, needle],
        )
    }

    /// `newest` selects rows of `runs`, newest first; they come back oldest first.
    fn query_runs(
        &self,
        newest: &str,
        params: impl rusqlite::Params,
    ) -> Result<Vec<Run>, StoreError> {
        let conn = self.conn();
        let mut stmt = conn
            .prepare(&format!(
                "SELECT id, at, request, calls, answer, session, finish FROM ({newest}) ORDER BY id"
            ))
            .map_err(|e| self.err(e))?;
        let rows = stmt
            .query_map(params, |r| {
                Ok(Run {
                    id: r.get(0)?,
                    at: r.get(1)?,
                    request: r.get(2)?,
                    calls: r.get(3)?,
                    answer: r.get(4)?,
                    session: r.get(5)?,
                    finish: r.get(6)?,
                })
            })
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<_, _>>().map_err(|e| self.err(e))
    }

    /// Forget the run log (places and facts stay). How many runs went.
    pub(crate) fn forget_runs(&self) -> Result<usize, StoreError> {
        self.conn()
            .execute("DELETE FROM runs WHERE robot = ?1", params![self.robot])
            .map_err(|e| self.err(e))
    }

    /// The robots this file keeps anything for.
    pub fn robots(&self) -> Result<Vec<String>, StoreError> {
        let conn = self.conn();
        let mut stmt = conn
            .prepare(
                "SELECT robot FROM places UNION SELECT robot FROM facts
                 UNION SELECT robot FROM runs ORDER BY robot",
            )
            .map_err(|e| self.err(e))?;
        let rows = stmt
            .query_map([], |r| r.get::<_, String>(0))
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<_, _>>().map_err(|e| self.err(e))
    }

    /// The robot this store is scoped to.
    pub fn robot(&self) -> &str {
        &self.robot
    }

    /// Delete everything kept for this robot (places, facts, runs).
    pub(crate) fn forget_all(&self) -> Result<(), StoreError> {
        let mut conn = self.conn();
        let tx = conn.transaction().map_err(|e| self.err(e))?;
        for table in ["places", "facts", "runs"] {
            tx.execute(
                &format!("DELETE FROM {table} WHERE robot = ?1"),
                params![self.robot],
            )
            .map_err(|e| self.err(e))?;
        }
        tx.commit().map_err(|e| self.err(e))
    }
}

/// Delete the place `name` (folded comparison) of `robot`; how many rows went.
fn delete_place(conn: &Connection, robot: &str, name: &str) -> rusqlite::Result<usize> {
    let names: Vec<String> = {
        let mut stmt = conn.prepare("SELECT name FROM places WHERE robot = ?1")?;
        let rows = stmt.query_map(params![robot], |r| r.get::<_, String>(0))?;
        rows.collect::<Result<_, _>>()?
    };
    let mut gone = 0;
    for n in names.iter().filter(|n| same_name(n, name)) {
        gone += conn.execute(
            "DELETE FROM places WHERE robot = ?1 AND name = ?2",
            params![robot, n],
        )?;
    }
    Ok(gone)
}

fn classify(path: &Path, e: &rusqlite::Error) -> StoreError {
    use rusqlite::ErrorCode;
    let path = path.to_path_buf();
    match e.sqlite_error_code() {
        Some(ErrorCode::NotADatabase) | Some(ErrorCode::DatabaseCorrupt) => {
            StoreError::NotADatabase(path)
        }
        Some(ErrorCode::DatabaseBusy) | Some(ErrorCode::DatabaseLocked) => StoreError::Locked(path),
        _ => StoreError::Other {
            path,
            message: e.to_string(),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn place(name: &str, x: f64) -> Place {
        Place {
            name: name.into(),
            frame: "map".into(),
            x,
            y: 2.0,
            yaw: 0.5,
            aliases: vec!["Ladestation".into()],
            description: "where it charges".into(),
        }
    }

    #[test]
    fn places_outlive_the_process_and_stay_with_their_robot() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub").join(FILE);
        {
            let s = Store::open(&path, "sim").unwrap();
            assert!(!s.put_place(&place("Charger", 1.0)).unwrap());
            // Same name, other case: replaced, not doubled.
            assert!(s.put_place(&place("charger", 3.0)).unwrap());
            s.add_fact("the charger is in aisle 3").unwrap();
            s.log_run(&NewRun {
                session: "a",
                request: "go to the charger",
                calls: "place_go({\"place\":\"charger\"})",
                answer: "arrived",
                finish: "answer",
            })
            .unwrap();
        }
        let s = Store::open(&path, "sim").unwrap();
        let places = s.places().unwrap();
        assert_eq!(places, vec![place("charger", 3.0)]);
        assert_eq!(s.facts().unwrap()[0].text, "the charger is in aisle 3");
        assert_eq!(s.runs(10).unwrap()[0].answer, "arrived");
        let other = Store::open(&path, "arm").unwrap();
        assert!(other.places().unwrap().is_empty());
        assert!(s.forget_place("CHARGER").unwrap());
        assert!(!s.forget_place("charger").unwrap());
        s.forget_all().unwrap();
        assert!(s.facts().unwrap().is_empty() && s.runs(10).unwrap().is_empty());
    }

    #[test]
    fn a_file_that_is_not_memory_is_named_and_kept() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(FILE);
        let junk = b"this is not a database, it is someone's notes\n".repeat(200);
        std::fs::write(&path, &junk).unwrap();
        let e = Store::open(&path, "sim").unwrap_err();
        assert!(matches!(e, StoreError::NotADatabase(_)), "{e}");
        assert!(e.to_string().contains("move it aside"));
        assert_eq!(std::fs::read(&path).unwrap(), junk);
    }

    #[test]
    fn another_programs_database_is_not_written_into() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("inventory.db");
        Connection::open(&path)
            .unwrap()
            .execute_batch("CREATE TABLE parts (id INTEGER, name TEXT);")
            .unwrap();
        let before = std::fs::read(&path).unwrap();
        let e = Store::open(&path, "sim").unwrap_err();
        assert!(matches!(e, StoreError::Foreign(_)), "{e}");
        assert_eq!(std::fs::read(&path).unwrap(), before);
    }

    #[test]
    fn a_newer_schema_is_not_written_over() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(FILE);
        Connection::open(&path)
            .unwrap()
            .execute_batch("PRAGMA user_version = 99;")
            .unwrap();
        let e = Store::open(&path, "sim").unwrap_err();
        assert!(matches!(e, StoreError::Newer { found: 99, .. }), "{e}");
    }

    #[test]
    fn a_locked_file_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(FILE);
        let s = Store::open(&path, "sim").unwrap();
        let holder = Connection::open(&path).unwrap();
        holder.execute_batch("BEGIN EXCLUSIVE;").unwrap();
        let e = s.add_fact("x").unwrap_err();
        assert!(matches!(e, StoreError::Locked(_)), "{e}");
        holder.execute_batch("COMMIT;").unwrap();
        s.add_fact("x").unwrap();
    }

    #[test]
    fn the_last_session_and_runs_about_a_word_are_found() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(&dir.path().join(FILE), "sim").unwrap();
        assert!(s.last_session(10).unwrap().is_empty());
        let log = |session, request, answer| {
            s.log_run(&NewRun {
                session,
                request,
                answer,
                calls: "",
                finish: "answer",
            })
            .unwrap()
        };
        log("one", "go to the Dock", "arrived at the dock");
        log("two", "list the topics", "3 topics");
        log("two", "where are you", "at x 1, y 2");
        let last = s.last_session(10).unwrap();
        assert_eq!(
            last.iter().map(|r| r.request.as_str()).collect::<Vec<_>>(),
            ["list the topics", "where are you"]
        );
        assert_eq!(s.last_session(1).unwrap()[0].request, "where are you");
        assert_eq!(s.runs_about("DOCK", 10).unwrap().len(), 1);
        assert!(s.runs_about("kitchen", 10).unwrap().is_empty());
        assert_eq!(s.robots().unwrap(), ["sim"]);
        assert_eq!(s.forget_runs().unwrap(), 3);
    }

    #[test]
    fn a_schema_1_file_is_upgraded_and_keeps_its_runs() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(FILE);
        Connection::open(&path)
            .unwrap()
            .execute_batch(
                "CREATE TABLE runs (id INTEGER PRIMARY KEY, robot TEXT NOT NULL, at TEXT NOT NULL,
                   request TEXT NOT NULL, calls TEXT NOT NULL, answer TEXT NOT NULL);
                 INSERT INTO runs (robot, at, request, calls, answer)
                   VALUES ('sim', 'then', 'hello', '', 'hi');
                 PRAGMA user_version = 1;",
            )
            .unwrap();
        let s = Store::open(&path, "sim").unwrap();
        let runs = s.runs(5).unwrap();
        assert_eq!(
            (runs[0].request.as_str(), runs[0].finish.as_str()),
            ("hello", "answer")
        );
    }

    #[test]
    fn long_text_is_cut() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(&dir.path().join(FILE), "sim").unwrap();
        s.add_fact(&"é".repeat(MAX_TEXT + 10)).unwrap();
        assert_eq!(s.facts().unwrap()[0].text.chars().count(), MAX_TEXT + 1);
    }
}
