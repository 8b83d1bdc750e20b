//! Session traces: one JSONL file per session under the trace directory, a line per
//! event with a timestamp, so a run can be read back (query, prompt sizes, every call
//! with its arguments, decision, result and timings).

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use serde_json::json;

use super::event::Event;

pub struct Trace {
    path: PathBuf,
    out: BufWriter<File>,
}

impl Trace {
    /// Open a new trace file `session-<unix ms>-<pid>.jsonl` in `dir`.
    pub fn create(dir: &Path) -> std::io::Result<Trace> {
        std::fs::create_dir_all(dir)?;
        let ms = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_millis());
        let path = dir.join(format!("session-{ms}-{}.jsonl", std::process::id()));
        let out = BufWriter::new(OpenOptions::new().create(true).append(true).open(&path)?);
        Ok(Trace { path, out })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Append a record: `kind` plus fields.
    pub fn record(&mut self, kind: &str, fields: serde_json::Value) {
        let t = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        let mut line = json!({"t": t, "kind": kind});
        if let (Some(l), serde_json::Value::Object(f)) = (line.as_object_mut(), fields) {
            l.extend(f);
        }
        // A trace that cannot be written must not stop the robot; the error is logged.
        if let Err(e) = writeln!(self.out, "{line}").and_then(|_| self.out.flush()) {
            tracing::warn!(path = %self.path.display(), error = %e, "trace write failed");
        }
    }

    pub fn event(&mut self, e: &Event) {
        // Tokens are in the answer and the calls, progress in the result; a line for
        // each would bury them.
        if matches!(e, Event::Token { .. } | Event::ToolProgress { .. }) {
            return;
        }
        let v = serde_json::to_value(e).unwrap_or_default();
        self.record("event", v);
    }
}
