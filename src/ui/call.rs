//! `ferrosa call NAME 'JSON'`: one tool call through exactly the agent's policy path
//! (the fence, the e-stop, read-only, limits, confirmation, the ROS boundary, the time
//! limit, redaction), without a model. It prints `{"name", "arguments", "decision",
//! "output"}` as JSON. Without a terminal and without `--yes`, an actuating call is
//! refused as unconfirmed. Operators script with it; the tests drive the policy with it.

use std::io::IsTerminal;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use super::agent::{robot_tools, AgentArgs};
use super::term::{parse_call, report_call, Input, TerminalConfirm};
use crate::estop::EStop;
use crate::tool::exec::Executor;
use crate::tool::policy::NoOperator;
use crate::tool::Confirm;

/// `ferrosa call` (see the module header).
pub fn run(args: &AgentArgs, name: &str, arguments: &str) -> anyhow::Result<()> {
    let call = parse_call(&format!("{name} {arguments}"))?;
    let estop = EStop::new();
    let cancel = Arc::new(AtomicBool::new(false));
    let confirm: Arc<dyn Confirm> = if std::io::stdin().is_terminal() {
        Arc::new(TerminalConfirm {
            input: Input::start(estop.clone(), cancel.clone()),
        })
    } else {
        Arc::new(NoOperator)
    };
    let (_robot, registry, policy) = robot_tools(args, confirm, estop)?;
    if registry.get(&call.name).is_none() {
        let names: Vec<String> = registry.specs().into_iter().map(|s| s.name).collect();
        anyhow::bail!(
            "no tool named {}; the tools are: {} (with --robot sim or ros2, the ROS tools too)",
            call.name,
            names.join(", ")
        );
    }
    let exec = Executor::new(registry, policy.clone())?;
    let mut shown = call.clone();
    policy.redact(&mut shown.arguments);
    let o = exec.call(&call, &cancel);
    println!(
        "{}",
        serde_json::to_string_pretty(&report_call(&shown, &o))?
    );
    let acted = exec
        .registry()
        .get(&call.name)
        .is_some_and(|t| t.effect() == crate::tool::Effect::Actuates);
    if acted && o.ok {
        // What was just sent to a reliable subscriber that matched this process late is
        // sent again only when it asks, and only while the process is here.
        std::thread::sleep(LINGER);
    }
    Ok(())
}

/// How long a call that acted keeps the process (and its ROS participant) alive after.
const LINGER: std::time::Duration = std::time::Duration::from_millis(300);
