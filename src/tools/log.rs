//! `log_read`: the last lines of a log file, only inside the configured log directories
//! (paths that resolve outside them, through `..` or links, are refused).

use std::path::{Path, PathBuf};

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use crate::tool::{Effect, Tool, ToolContext, ToolError};

/// Lines returned at most, whatever is asked.
const LINE_CAP: usize = 200;
/// Bytes read from the end of a file at most: a log of gigabytes is not read whole (the
/// lines asked for are near its end).
const TAIL_BYTES: u64 = 1 << 20;

/// The last `TAIL_BYTES` of the file at `path`, from the first whole line in them.
fn tail(path: &Path) -> std::io::Result<String> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(path)?;
    let len = f.metadata()?.len();
    let start = len.saturating_sub(TAIL_BYTES);
    f.seek(SeekFrom::Start(start))?;
    let mut bytes = Vec::with_capacity((len - start) as usize);
    f.take(TAIL_BYTES).read_to_end(&mut bytes)?;
    let text = String::from_utf8_lossy(&bytes).into_owned();
    Ok(match (start, text.find('\n')) {
        (0, _) | (_, None) => text,
        (_, Some(nl)) => text[nl + 1..].to_string(),
    })
}

pub(crate) struct LogRead {
    dirs: Vec<PathBuf>,
}

impl LogRead {
    pub fn new(dirs: Vec<PathBuf>) -> LogRead {
        LogRead { dirs }
    }

    fn resolve(&self, file: &str) -> Result<PathBuf, ToolError> {
        for dir in &self.dirs {
            let Ok(root) = dir.canonicalize() else {
                continue;
            };
            let candidate = if Path::new(file).is_absolute() {
                PathBuf::from(file)
            } else {
                root.join(file)
            };
            if let Ok(real) = candidate.canonicalize() {
                if real.starts_with(&root) && real.is_file() {
                    return Ok(real);
                }
                if !real.starts_with(&root) && Path::new(file).is_absolute() {
                    continue;
                }
                if !real.starts_with(&root) {
                    return Err(ToolError::Refused(format!(
                        "{file} is outside the log directories; list files with a plain name"
                    )));
                }
            }
        }
        let names: Vec<String> = self
            .dirs
            .iter()
            .filter_map(|d| std::fs::read_dir(d).ok())
            .flat_map(|rd| rd.flatten())
            .filter(|e| e.path().is_file())
            .filter_map(|e| e.file_name().to_str().map(str::to_string))
            .take(20)
            .collect();
        Err(ToolError::Failed(format!(
            "no log file {file} in the log directories; available: {}",
            if names.is_empty() {
                "none".to_string()
            } else {
                names.join(", ")
            }
        )))
    }
}

#[derive(Deserialize, JsonSchema, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
#[serde(rename_all = "lowercase")]
pub enum Level {
    Debug,
    Info,
    Warn,
    Error,
}

fn level_of(line: &str) -> Option<Level> {
    let up = line.to_ascii_uppercase();
    if up.contains("ERROR") || up.contains("FATAL") {
        Some(Level::Error)
    } else if up.contains("WARN") {
        Some(Level::Warn)
    } else if up.contains("INFO") {
        Some(Level::Info)
    } else if up.contains("DEBUG") {
        Some(Level::Debug)
    } else {
        None
    }
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct LogArgs {
    /// Log file name, e.g. "robot.log".
    pub file: String,
    /// How many of the last matching lines, 1 to 200.
    #[schemars(range(min = 1, max = 200))]
    pub lines: Option<u32>,
    /// Only lines at or above this level.
    pub level: Option<Level>,
}

impl Tool for LogRead {
    type Args = LogArgs;
    const NAME: &'static str = "log_read";
    const EFFECT: Effect = Effect::Observes;

    fn description(&self) -> String {
        "Read the last lines (1-200, default 50) of a log file in the robot's log directory, optionally only at or above a level (debug, info, warn, error).".into()
    }

    async fn call(&self, a: LogArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let path = self.resolve(&a.file)?;
        let text =
            tail(&path).map_err(|e| ToolError::Failed(format!("cannot read {}: {e}", a.file)))?;
        let want = (a.lines.unwrap_or(50) as usize).clamp(1, LINE_CAP);
        let matching: Vec<&str> = text
            .lines()
            .filter(|l| match a.level {
                Some(min) => level_of(l).is_some_and(|lv| lv >= min),
                None => true,
            })
            .collect();
        let start = matching.len().saturating_sub(want);
        Ok(json!({
            "file": a.file,
            "lines": &matching[start..],
            "count": matching.len() - start,
            "matching_lines": matching.len(),
            "total_lines": text.lines().count(),
            "filters": {"level": a.level.map(|l| match l {
                Level::Debug => "debug", Level::Info => "info", Level::Warn => "warn", Level::Error => "error",
            }), "last": want},
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn run(t: &LogRead, args: Value) -> Result<Value, ToolError> {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let a: LogArgs = serde_json::from_value(args).unwrap();
        rt.block_on(t.call(a, &ToolContext::new(Duration::from_secs(1))))
    }

    #[test]
    fn reads_filters_and_refuses_escapes() {
        let dir = tempfile::tempdir().unwrap();
        let logs = dir.path().join("logs");
        std::fs::create_dir(&logs).unwrap();
        std::fs::write(
            logs.join("robot.log"),
            "INFO start\nWARN low battery\nERROR motor stalled\nINFO ok\n",
        )
        .unwrap();
        std::fs::write(dir.path().join("secret.txt"), "key").unwrap();
        let t = LogRead::new(vec![logs.clone()]);
        let out = run(&t, json!({"file": "robot.log", "level": "warn"})).unwrap();
        assert_eq!(
            out["lines"],
            json!(["WARN low battery", "ERROR motor stalled"])
        );
        let out = run(&t, json!({"file": "robot.log", "lines": 1})).unwrap();
        assert_eq!(out["lines"], json!(["INFO ok"]));
        let err = run(&t, json!({"file": "../secret.txt"})).unwrap_err();
        assert!(matches!(err, ToolError::Refused(_)), "{err}");
        let abs = dir.path().join("secret.txt");
        let err = run(&t, json!({"file": abs.to_str().unwrap()})).unwrap_err();
        assert!(err.to_string().contains("robot.log"), "{err}");
    }
}
