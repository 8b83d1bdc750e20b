//! The operator's terminal: text from the model or a robot is cleaned before it is
//! printed (no escape sequences, no control characters, no bidirectional overrides that
//! would make an answer read otherwise than it is), and confirmations are asked on it.
//!
//! Input comes from one reader thread (`Input`), so the operator can type `/stop` while
//! a run (or a confirmation question) is in progress: `/stop` engages the e-stop the
//! moment it is read, every other line waits for whoever asks. Tool calls the operator types
//! (`/call`, `ferrosa call`) are parsed and reported here.

use std::io::{BufRead, Write};
use std::sync::mpsc::{Receiver, Sender};
use std::sync::{Arc, Mutex};

use anyhow::Context;
use serde_json::{json, Value};

use crate::estop::EStop;
use crate::tool::exec::Outcome;
use crate::tool::{Confirm, ToolCall};

/// `text` safe to print: escape sequences and control characters (but newlines and
/// tabs) removed, bidirectional overrides and every other format character (Unicode
/// category Cf: zero-width, joiners, BOM, soft hyphen) dropped. It is the fence's
/// `visible`, the form names were judged in, so a name the fence redacted cannot be
/// put back together here by removing what split it.
pub fn clean(text: &str) -> String {
    crate::fence::visible(text).into_owned()
}

/// Lines the operator types, read by one thread (see the module header).
pub struct Input {
    lines: Mutex<Receiver<String>>,
}

impl Input {
    /// Start reading standard input. `/stop` (and `/estop`), and any line that is not a
    /// command and asks to stop in words (`reading::concepts::operator_stops`: "stop", "hold on",
    /// "¡para!"), trigger `estop` at once
    /// and set `cancel`, whatever is running or waiting for an answer; every line (those
    /// too) is also passed on.
    pub fn start(estop: Arc<EStop>, cancel: Arc<std::sync::atomic::AtomicBool>) -> Arc<Input> {
        let (tx, rx): (Sender<String>, Receiver<String>) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("stdin".into())
            .spawn(move || {
                let stdin = std::io::stdin();
                for line in stdin.lock().lines() {
                    let Ok(line) = line else { break };
                    // A command (`/call NAME {json}`, `/reset`) is not read as words: its
                    // JSON may hold any ("wait_s").
                    let command = line.trim_start().starts_with('/');
                    let said = !command && crate::reading::concepts::operator_stops(&line);
                    if said || matches!(line.trim(), "/stop" | "/estop") {
                        let source = match said {
                            true => "the operator (typed a stop)",
                            false => "the operator (/stop)",
                        };
                        estop.trigger(source);
                        cancel.store(true, std::sync::atomic::Ordering::SeqCst);
                    }
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            })
            .expect("spawning the input thread");
        Arc::new(Input {
            lines: Mutex::new(rx),
        })
    }

    /// The next line; `None` at the end of input.
    pub(crate) fn next_line(&self) -> Option<String> {
        self.lines.lock().expect("input lock").recv().ok()
    }
}

/// Resolves at Ctrl-C, or at the TERM a service manager sends (what ends a server).
pub(crate) async fn interrupted() {
    use tokio::signal::unix::{signal, SignalKind};
    match signal(SignalKind::terminate()) {
        Ok(mut term) => {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = term.recv() => {}
            }
        }
        Err(_) => {
            let _ = tokio::signal::ctrl_c().await;
        }
    }
}

/// Asks on the terminal: "allow turtle_move {...}? [y/N]", the answer read from `Input`.
pub(crate) struct TerminalConfirm {
    pub input: Arc<Input>,
}

impl Confirm for TerminalConfirm {
    fn confirm(&self, call: &ToolCall) -> bool {
        let _ = super::progress::hold();
        eprint!(
            "\nallow {} {}? [y/N] ",
            clean(&call.name),
            clean(&serde_json::to_string(&call.arguments).unwrap_or_default())
        );
        let _ = std::io::stderr().flush();
        self.input
            .next_line()
            .is_some_and(|l| matches!(l.trim(), "y" | "Y" | "yes"))
    }
}

/// A call written as `NAME {json}` (the arguments may be left out for `{}`).
pub fn parse_call(text: &str) -> anyhow::Result<ToolCall> {
    let text = text.trim();
    let (name, args) = text.split_once(char::is_whitespace).unwrap_or((text, "{}"));
    let arguments: Value = serde_json::from_str(args.trim()).with_context(|| {
        format!("the arguments of {name} are not JSON: write them as an object, e.g. '{{\"distance\": 1.0}}'")
    })?;
    if !arguments.is_object() {
        anyhow::bail!(
            "the arguments of {name} must be a JSON object, e.g. '{{\"distance\": 1.0}}'"
        );
    }
    Ok(ToolCall {
        name: name.to_string(),
        arguments,
    })
}

/// What `ferrosa call` prints for a call.
pub(crate) fn report_call(call: &ToolCall, o: &Outcome) -> Value {
    let decision = serde_json::to_value(&o.decision).unwrap_or_default();
    json!({"name": call.name, "arguments": call.arguments, "decision": decision,
           "output": o.output, "ok": o.ok, "ms": o.ms})
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escape_sequences_controls_and_bidi_are_removed() {
        assert_eq!(clean("ok\u{1b}[2J\u{1b}[31mred\u{1b}[0m"), "okred");
        assert_eq!(clean("a\u{1b}]0;title\u{7}b"), "ab");
        assert_eq!(clean("safe\u{202e}txt.exe\u{0}\r\n"), "safetxt.exe\n");
        assert_eq!(clean("Größe 3 m"), "Größe 3 m");
        assert_eq!(clean("a\u{1b}]8;;x\u{1b}\\b"), "ab");
    }

    /// Issue 41: a denied name split by a format character is redacted whole, and what
    /// cleaning prints is what the fence judged.
    #[test]
    fn a_split_name_is_redacted_before_it_is_cleaned() {
        let fence = crate::fence::Fence::new(&["^/turtle1".to_string()]).unwrap();
        for split in [
            "/turtle\u{200B}1/cmd_vel",
            "/turtle\u{AD}1/cmd_vel",
            "/turtle\u{2060}1/cmd_vel",
            "/turtle\u{E0020}1/cmd_vel",
        ] {
            let shown = clean(&fence.redact(&format!("no topic {split}; try again")));
            assert_eq!(shown, "no topic [off limits]; try again", "{split:?}");
        }
    }
}
