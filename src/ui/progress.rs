//! What the operator's terminal shows of a run: one live line (a spinner, what the agent
//! is doing now and for how long: thinking, a call running, the answer being written)
//! redrawn in place, each call left behind as one line once it returns
//! (`→ ros_topic_echo /turtle1/pose · 0.4 s`), then the answer. `--verbose` shows
//! what the model writes as it writes it, each call's arguments as JSON and what it
//! returned. Off a terminal nothing is redrawn: the finished lines alone.
//!
//! The live line belongs to the process (there is one terminal): anything else that
//! writes to it first takes the line down with `hold` (a confirmation question does).

use std::collections::HashMap;
use std::io::{IsTerminal, Write};
use std::sync::{Mutex, Once};
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::agent::event::Event;
use crate::agent::ANSWER_TOOL;
use crate::tool::Decision;

/// Text from the model or a robot, safe to print (the terminal's `term::clean`, read
/// here from the fence itself: the terminal's confirmation takes this line down).
fn clean(text: &str) -> String {
    crate::fence::visible(text).into_owned()
}

/// Characters of the live line at most (it must fit one row to be redrawn in place).
const WIDTH: usize = 78;
const FRAMES: [char; 10] = ['⠋', '⠙', '⠹', '⠸', '⠼', '⠴', '⠦', '⠧', '⠇', '⠏'];
const TICK: Duration = Duration::from_millis(100);

struct Live {
    /// What is going on and since when; `None`: nothing shown.
    what: Option<(String, Instant)>,
    /// Whether the line is on the screen now.
    drawn: bool,
    frame: usize,
}

static LIVE: Mutex<Live> = Mutex::new(Live {
    what: None,
    drawn: false,
    frame: 0,
});
static TICKER: Once = Once::new();

fn live() -> std::sync::MutexGuard<'static, Live> {
    LIVE.lock().unwrap_or_else(|p| p.into_inner())
}

fn redraw(l: &mut Live) {
    let Some((what, since)) = &l.what else {
        return;
    };
    let secs = since.elapsed().as_secs_f64();
    let text: String = format!("{} {what} · {secs:.1} s", FRAMES[l.frame % FRAMES.len()]);
    let text = fit(&text, WIDTH);
    let mut err = std::io::stderr();
    let _ = write!(err, "\r\x1b[K{text}");
    let _ = err.flush();
    l.drawn = true;
    l.frame += 1;
}

fn erase(l: &mut Live) {
    if l.drawn {
        let mut err = std::io::stderr();
        let _ = write!(err, "\r\x1b[K");
        let _ = err.flush();
        l.drawn = false;
    }
}

/// Show `what` on the live line from now (on a terminal only), until `hold`.
pub(crate) fn begin(what: String) {
    if !std::io::stderr().is_terminal() {
        return;
    }
    TICKER.call_once(|| {
        std::thread::Builder::new()
            .name("progress".into())
            .spawn(|| loop {
                std::thread::sleep(TICK);
                let mut l = live();
                redraw(&mut l);
            })
            .map(drop)
            .unwrap_or(());
    });
    let mut l = live();
    l.what = Some((what, Instant::now()));
    redraw(&mut l);
}

/// Take the live line down (so something else can be written) and say how long what it
/// showed went on.
pub fn hold() -> Option<Duration> {
    let mut l = live();
    erase(&mut l);
    l.what.take().map(|(_, since)| since.elapsed())
}

/// `text` on one line, cut to `width` characters.
fn fit(text: &str, width: usize) -> String {
    let text = text.replace(['\n', '\r', '\t'], " ");
    let n = text.chars().count();
    if n <= width {
        return text;
    }
    let head: String = text.chars().take(width - 1).collect();
    format!("{head}…")
}

/// The last `width` characters of `text` on one line, led by `…` when cut (an answer
/// being written grows at its end).
fn tail(text: &str, width: usize) -> String {
    let text = text.replace(['\n', '\r', '\t'], " ");
    let n = text.chars().count();
    if n <= width {
        return text;
    }
    let rest: String = text.chars().skip(n - width + 1).collect();
    format!("…{rest}")
}

/// A call as one short line: its name and its arguments' values (`ros_topic_echo
/// /turtle1/pose`, `turtle_move distance=1 speed=0.5`).
pub(crate) fn call_line(name: &str, arguments: &Value) -> String {
    let mut line = clean(name);
    if let Some(args) = arguments.as_object() {
        let one = args.len() == 1;
        for (k, v) in args {
            let value = match v {
                Value::String(s) => clean(s),
                other => clean(&other.to_string()),
            };
            if one {
                line.push_str(&format!(" {value}"));
            } else {
                line.push_str(&format!(" {}={value}", clean(k)));
            }
        }
    }
    fit(&line, WIDTH - 16)
}

fn took(d: Option<Duration>, ms: f64) -> String {
    let secs = d.map_or(ms / 1e3, |d| d.as_secs_f64());
    if secs < 0.1 {
        format!("{:.0} ms", secs * 1e3)
    } else {
        format!("{secs:.1} s")
    }
}

/// One run as the terminal shows it (see the module header).
pub struct View {
    verbose: bool,
    /// What the model wrote this step, to find the answer in as it is written.
    raw: String,
    /// The calls running: their line and the policy's decision, by step and index.
    calls: HashMap<(usize, usize), (String, Decision)>,
}

impl View {
    pub fn new(verbose: bool) -> View {
        View {
            verbose,
            raw: String::new(),
            calls: HashMap::new(),
        }
    }

    pub fn event(&mut self, e: &Event) {
        if self.verbose {
            return verbose(e);
        }
        let mut out = std::io::stderr();
        match e {
            Event::Step { .. } => {
                self.raw.clear();
                begin("thinking".into());
            }
            Event::Token { text } => {
                self.raw.push_str(text);
                if let Some(answer) = answer_so_far(&self.raw) {
                    begin_or_update(format!("✎ {}", tail(&clean(&answer), WIDTH - 16)));
                }
            }
            Event::ToolCall {
                step,
                index,
                name,
                arguments,
                decision,
            } if name != ANSWER_TOOL => {
                let _ = hold();
                let line = call_line(name, arguments);
                if !matches!(decision, Decision::Refused(_)) {
                    begin(format!("→ {line}"));
                }
                self.calls.insert((*step, *index), (line, decision.clone()));
            }
            Event::ToolProgress {
                step, index, text, ..
            } => {
                if let Some((line, _)) = self.calls.get(&(*step, *index)) {
                    begin_or_update(format!("→ {line}: {}", clean(text)));
                }
            }
            Event::ToolResult {
                step,
                index,
                name,
                output,
                ok,
                ms,
            } => {
                let d = hold();
                let (line, decision) = self
                    .calls
                    .remove(&(*step, *index))
                    .unwrap_or_else(|| (clean(name), Decision::Allowed));
                let _ = match decision {
                    Decision::Refused(why) => writeln!(out, "✗ {line}: refused: {}", clean(&why)),
                    Decision::Clamped(what) if *ok => writeln!(
                        out,
                        "→ {line} · {} (held to the limits: {})",
                        took(d, *ms),
                        clean(&what)
                    ),
                    _ if *ok => writeln!(out, "→ {line} · {}", took(d, *ms)),
                    _ => {
                        let why = output["error"]
                            .as_str()
                            .map_or_else(|| output.to_string(), str::to_string);
                        writeln!(
                            out,
                            "✗ {line} · {}: {}",
                            took(d, *ms),
                            fit(&clean(&why), 120)
                        )
                    }
                };
                begin("thinking".into());
            }
            Event::Answer { .. } => {
                let _ = hold();
            }
            Event::Error { message } => {
                let _ = hold();
                let _ = writeln!(out, "! {}", clean(message));
            }
            _ => {}
        }
    }
}

/// Show `what` on the live line, keeping the time of what is shown already.
fn begin_or_update(what: String) {
    {
        let mut l = live();
        if let Some((shown, _)) = &mut l.what {
            *shown = what;
            redraw(&mut l);
            return;
        }
    }
    begin(what);
}

/// The answer's text so far in what the model has written this step: the `text` of an
/// answer call being written, or prose that is not a call. `None` while a call to
/// another tool is written.
fn answer_so_far(raw: &str) -> Option<String> {
    let trimmed = raw.trim_start();
    if trimmed.is_empty() {
        return None;
    }
    if !trimmed.starts_with(['<', '[', '{']) {
        return Some(trimmed.to_string());
    }
    let at = raw.find(&format!("\"name\": \"{ANSWER_TOOL}\""))?;
    let rest = &raw[at..];
    let open = rest.find("\"text\":")?;
    let rest = rest[open + 7..].trim_start().strip_prefix('"')?;
    Some(partial_string(rest))
}

/// A JSON string's content up to its closing quote or the end of what is written.
fn partial_string(s: &str) -> String {
    let mut out = String::new();
    let mut chars = s.chars();
    while let Some(c) = chars.next() {
        match c {
            '"' => break,
            '\\' => match chars.next() {
                Some('n') => out.push('\n'),
                Some('t') => out.push('\t'),
                Some('u') => {
                    let hex: String = chars.by_ref().take(4).collect();
                    match u32::from_str_radix(&hex, 16).ok().and_then(char::from_u32) {
                        Some(c) => out.push(c),
                        None => break,
                    }
                }
                Some(c) => out.push(c),
                None => break,
            },
            c => out.push(c),
        }
    }
    out
}

/// `--verbose`: the model's text as it comes, each call with its arguments and decision,
/// each result (cut at 300 characters).
fn verbose(e: &Event) {
    let mut err = std::io::stderr();
    match e {
        Event::Token { text } => {
            let _ = write!(err, "{}", clean(text));
            let _ = err.flush();
        }
        Event::ToolCall {
            name,
            arguments,
            decision,
            ..
        } => {
            let d = serde_json::to_value(decision).unwrap_or_default();
            let _ = writeln!(
                err,
                "\n→ {} {} [{}]",
                clean(name),
                clean(&arguments.to_string()),
                clean(d["decision"].as_str().unwrap_or_default())
            );
        }
        Event::ToolResult {
            name,
            output,
            ms,
            ok,
            ..
        } => {
            let text = clean(&output.to_string());
            let short: String = text.chars().take(300).collect();
            let mark = if *ok { "←" } else { "✗" };
            let _ = writeln!(err, "{mark} {} ({ms:.0} ms): {short}", clean(name));
        }
        Event::ToolProgress { name, text, .. } => {
            let _ = writeln!(err, "… {}: {}", clean(name), clean(text));
        }
        Event::Error { message } => {
            let _ = writeln!(err, "\n! {}", clean(message));
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn the_answer_is_read_from_an_answer_call_as_it_is_written() {
        let raw = "<tool_call>[\n{\"name\": \"reply\", \"arguments\": {\"text\": \"Ten top";
        assert_eq!(answer_so_far(raw).as_deref(), Some("Ten top"));
        let raw = "<tool_call>[\n{\"name\": \"reply\", \"arguments\": {\"text\": \"a \\\"b\\\" \\u00e9\"}}";
        assert_eq!(answer_so_far(raw).as_deref(), Some("a \"b\" é"));
        assert_eq!(
            answer_so_far("<tool_call>[\n{\"name\": \"ros_topic_list\""),
            None
        );
        assert_eq!(answer_so_far("Hello there").as_deref(), Some("Hello there"));
    }

    #[test]
    fn a_call_is_one_short_line_of_its_values() {
        assert_eq!(
            call_line("ros_topic_echo", &json!({"topic": "/turtle1/pose"})),
            "ros_topic_echo /turtle1/pose"
        );
        assert_eq!(
            call_line("turtle_move", &json!({"distance": 1.0, "speed": 0.5})),
            "turtle_move distance=1.0 speed=0.5"
        );
        assert_eq!(call_line("ros_node_list", &json!({})), "ros_node_list");
        let long = call_line("x", &json!({"text": "a".repeat(200)}));
        assert_eq!(long.chars().count(), WIDTH - 16);
        assert!(long.ends_with('…'));
        // Nothing the model wrote reaches the terminal as an escape sequence.
        assert_eq!(call_line("x", &json!({"t": "\u{1b}[2J"})), "x ");
        assert_eq!(tail("abcdef", 4), "…def");
        assert_eq!(tail("ab\ncd", 8), "ab cd");
    }
}
