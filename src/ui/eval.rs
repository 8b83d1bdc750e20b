//! `ferrosa eval bfcl PATH...`: run BFCL files through the model; `ferrosa eval ros
//! SUITE`: run agent episodes against a fresh built-in sim per case, or against a robot
//! already on the graph (`--robot ros2|ros1`), joined once and never reset between
//! cases. Both print a markdown summary (decoding modes side by side with `--decoding
//! both`) and write every case as JSONL so failures can be read.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::Context;

use super::agent::Robot;
use crate::agent::Event;
use crate::decode::envelope::Envelope;
use crate::decode::{Decoding, Grammars, Session};
use crate::eval::{self, bfcl, CaseResult};
use crate::reading::language::Language;
use crate::ros::switch::SwitchGraph;
use crate::ros::RosGraph;
use crate::tool::{Confirm, Decision, ToolCall};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DecodingChoice {
    Constrained,
    Free,
    Both,
}

pub struct BfclArgs {
    pub model: super::ModelArgs,
    pub paths: Vec<PathBuf>,
    pub decoding: DecodingChoice,
    /// Questions (cases) passed over first, e.g. to tune on ones a report does not use.
    pub skip: usize,
    pub limit: Option<usize>,
    pub out: PathBuf,
    pub envelope: Option<Envelope>,
    pub rules: eval::TurnRules,
}

impl DecodingChoice {
    fn modes(self) -> &'static [Decoding] {
        match self {
            DecodingChoice::Constrained => &[Decoding::Constrained],
            DecodingChoice::Free => &[Decoding::Free],
            DecodingChoice::Both => &[Decoding::Constrained, Decoding::Free],
        }
    }
}

/// The per-case JSONL file in `out`.
fn case_file(out: &Path, name: &str) -> anyhow::Result<(PathBuf, std::fs::File)> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let path = out.join(name);
    let file =
        std::fs::File::create(&path).with_context(|| format!("cannot write {}", path.display()))?;
    Ok((path, file))
}

pub fn bfcl(args: &BfclArgs) -> anyhow::Result<()> {
    let mut cases = Vec::new();
    for p in &args.paths {
        cases.extend(bfcl::load(p, args.skip, args.limit)?);
    }
    let (resolved, _, mut model) = args.model.load()?;
    let mut remote = args.model.connect(&resolved, model.as_ref())?;
    let envelope = args
        .envelope
        .unwrap_or_else(|| Envelope::for_family(resolved.family().unwrap_or("chatml")));
    let grammars = Grammars::new(model.vocab(), model.tokenizer())?;
    let modes = args.decoding.modes();
    let (jsonl, mut file) = case_file(&args.out, "bfcl_cases.jsonl")?;
    let mut results: Vec<CaseResult> = Vec::new();
    let mut session = Session::new();
    let total = cases.len() * modes.len();
    for &mode in modes {
        for case in &cases {
            let r = eval::run_case(
                model.as_mut(),
                &mut session,
                &grammars,
                remote.as_mut(),
                envelope,
                mode,
                args.rules,
                case,
            )?;
            writeln!(file, "{}", serde_json::to_string(&r)?)?;
            results.push(r);
            eprint!("\r{} / {total}", results.len());
        }
    }
    eprintln!();
    let summaries = eval::summarize(&results);
    let rules = args.rules;
    let mut setting = if rules.force_call {
        "call forced".to_string()
    } else {
        format!("answer mode {:?}", rules.answer_mode)
    };
    if rules.relevance_gate {
        setting.push_str(" | relevance gate");
    }
    if rules.copy_bias > 0.0 {
        setting.push_str(&format!(" | copy bias {}", rules.copy_bias));
    }
    if rules.ground {
        setting.push_str(" | optional values grounded");
    }
    let engine = crate::remote::Remote::describe_engine(remote.as_ref(), model.as_ref());
    println!(
        "model {} | {engine} | envelope {envelope:?} | {setting} | {} cases per mode\n",
        resolved.path.display(),
        cases.len()
    );
    print!("{}", eval::markdown(&summaries));
    std::fs::write(
        args.out.join("bfcl_summary.json"),
        serde_json::to_string_pretty(&summaries)?,
    )?;
    eprintln!("per-case results: {}", jsonl.display());
    Ok(())
}

/// A directory of its own for a run's memory file, removed when the run ends.
struct FreshMemory(PathBuf);

impl FreshMemory {
    fn new() -> anyhow::Result<FreshMemory> {
        // A name of its own per run: the memory a process opened is kept open by path.
        static RUNS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let run = RUNS.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let dir =
            std::env::temp_dir().join(format!("ferrosa-eval-memory-{}-{run}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        Ok(FreshMemory(dir))
    }
}

impl Drop for FreshMemory {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub struct RosArgs {
    pub agent: super::agent::AgentArgs,
    pub suite: PathBuf,
    pub decoding: DecodingChoice,
    /// Questions (cases) passed over first, e.g. to tune on ones a report does not use.
    pub skip: usize,
    pub limit: Option<usize>,
    pub out: PathBuf,
    /// Measure tool retrieval only (`retrieval`).
    pub retrieval: bool,
}

/// Approves actuating calls when the current case says the operator would.
struct CaseOperator(Arc<AtomicBool>);

impl Confirm for CaseOperator {
    fn confirm(&self, _: &ToolCall) -> bool {
        self.0.load(Ordering::SeqCst)
    }
}

/// How the cases meet the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fixture {
    /// The built-in sim (over ROS 2, or served on ROS 1): a new one per case.
    FreshSim,
    /// A robot already on the graph (`--robot ros2|ros1`): joined once, never reset; it
    /// keeps the state each case leaves it in.
    Shared,
}

impl Fixture {
    fn of(robot: Robot) -> anyhow::Result<Fixture> {
        Ok(match robot {
            Robot::Sim | Robot::SimRos1 => Fixture::FreshSim,
            Robot::Ros2 | Robot::Ros1 => Fixture::Shared,
            Robot::None => anyhow::bail!(
                "the ROS suite needs a robot: --robot sim or sim-ros1 (a fresh built-in sim per case), or --robot ros2 or ros1 (the robot already on the graph, kept between cases)"
            ),
        })
    }

    /// The report header's robot part.
    fn describe(self, robot: Robot) -> String {
        let name = format!("{robot:?}").to_lowercase();
        match self {
            Fixture::FreshSim => format!("robot {name} (a fresh one per case)"),
            Fixture::Shared => format!(
                "robot {name} (the one on the graph, not reset: it keeps its state between cases)"
            ),
        }
    }
}

/// Before a case on a shared robot: an e-stop engaged since the last case was pressed
/// on the robot's side, and only its operator releases it. `skip` resumes at this case.
fn refuse_outside_estop(
    estop: &crate::estop::EStop,
    case: &eval::ros::RosCase,
    skip: usize,
) -> anyhow::Result<()> {
    match estop.engaged_by() {
        Some(e) => anyhow::bail!(
            "the e-stop was engaged by {} before case {}: the suite stops here; release it on the robot's side and go on with --skip {skip}",
            e.source,
            case.id
        ),
        None => Ok(()),
    }
}

/// After a case: an e-stop the case latched (the agent's `robot_stop`, a request to
/// stop) is released before the next one, as an operator would; one a ROS node pressed
/// on a shared robot is not (the suite stops; `skip` resumes at this case, run again).
/// Returns whether the case latched it.
fn release_case_estop(
    estop: &crate::estop::EStop,
    fixture: Fixture,
    case: &eval::ros::RosCase,
    skip: usize,
) -> anyhow::Result<bool> {
    let Some(engaged) = estop.engaged_by() else {
        return Ok(false);
    };
    if fixture == Fixture::Shared && engaged.source == super::robot::estop_topic_source() {
        anyhow::bail!(
            "the e-stop was engaged by {} during case {}: the suite stops here; release it on the robot's side and go on with --skip {skip}",
            engaged.source,
            case.id
        );
    }
    estop.reset();
    Ok(true)
}

/// The nodes of a shared robot, as first seen: a case after which one has left the graph
/// (a driver the case's call crashed, say) stops the suite, for every later case would
/// measure a robot that is no longer there.
#[derive(Default)]
struct Present(Option<std::collections::BTreeSet<String>>);

impl Present {
    /// After a case: the nodes the graph now shows (`None` when it cannot say at once).
    fn check(
        &mut self,
        nodes: Option<Vec<String>>,
        case: &eval::ros::RosCase,
        skip: usize,
    ) -> anyhow::Result<()> {
        let Some(nodes) = nodes else { return Ok(()) };
        let now = visible_nodes(nodes);
        let Some(first) = &self.0 else {
            self.0 = Some(now);
            return Ok(());
        };
        let gone: Vec<&str> = first.difference(&now).map(String::as_str).collect();
        if !gone.is_empty() {
            anyhow::bail!(
                "{} left the graph during or before case {} (its result is kept): the suite stops here, for the cases after it would measure a robot that is not there; start it again and go on with --skip {skip}",
                gone.join(", "),
                case.id
            );
        }
        Ok(())
    }
}

/// The visible nodes the graph shows now (`None` when it cannot say at once).
fn nodes_now(graph: &dyn RosGraph) -> Option<std::collections::BTreeSet<String>> {
    crate::ros::graph_now(graph).map(|g| visible_nodes(g.nodes))
}

/// The nodes of `nodes` that are not hidden (a last segment that opens with `_`, as a
/// command-line tool's passing node does).
fn visible_nodes(nodes: Vec<String>) -> std::collections::BTreeSet<String> {
    nodes
        .into_iter()
        .filter(|n| !n.rsplit('/').next().unwrap_or(n).starts_with('_'))
        .collect()
}

pub fn ros(args: &RosArgs) -> anyhow::Result<()> {
    use super::agent::{build_with, connect};
    let cases = eval::ros::load(&args.suite, args.skip, args.limit)?;
    let approve = Arc::new(AtomicBool::new(false));
    let operator: Arc<dyn Confirm> = Arc::new(CaseOperator(approve.clone()));
    let robot = args.agent.robot;
    let fixture = Fixture::of(robot)?;
    // A shared robot is joined as `ask` joins it (and the discovery reported).
    let mut link = connect(robot, fixture == Fixture::Shared)?;
    let first: Arc<dyn RosGraph> = link
        .graph
        .clone()
        .context("no ROS graph joined for the robot")?;
    let switch = Arc::new(SwitchGraph::new(first));
    // A run starts from an empty memory of its own, never the operator's: what one run
    // taught is not the next run's, and nothing of the suite is kept.
    let fresh = FreshMemory::new()?;
    let mut base = args.agent.clone();
    base.memory
        .get_or_insert_with(|| fresh.0.join(crate::store::FILE));
    // The robot just started serves the first case; on the sim every later case gets a
    // new one.
    if args.retrieval {
        let agent = build_with(&base, operator, Some(switch), crate::estop::EStop::new())?;
        return retrieval(&agent, &cases);
    }
    let mut used = false;
    let (jsonl, mut file) = case_file(&args.out, "ros_cases.jsonl")?;
    let mut results: Vec<CaseResult> = Vec::new();
    let mut run = SuiteRun {
        model: String::new(),
        fixture: fixture.describe(robot),
        answered_in: [0; 3],
        latched: Vec::new(),
    };
    let total = cases.len() * args.decoding.modes().len();
    let shared = link.graph.clone().filter(|_| fixture == Fixture::Shared);
    let mut present = Present(shared.as_deref().and_then(nodes_now));
    for &mode in args.decoding.modes() {
        let mut agent_args = base.clone();
        agent_args.decoding = mode;
        let mut agent = build_with(
            &agent_args,
            operator.clone(),
            Some(switch.clone()),
            crate::estop::EStop::new(),
        )?;
        // As `ask` does: what a shared robot's graph asks of other nodes by itself stays
        // outside the fence.
        if let Some(g) = link.graph.as_ref().filter(|_| fixture == Fixture::Shared) {
            g.set_fence(agent.fence().clone());
        }
        run.model = format!(
            "{} ({})",
            args.agent.model.model.as_deref().unwrap_or("default"),
            agent.backend().name()
        );
        for (i, case) in cases.iter().enumerate() {
            match fixture {
                Fixture::FreshSim => {
                    if used {
                        link = fresh_sim(robot, link, &switch)?;
                    }
                    // A fresh robot starts released.
                    agent.estop().reset();
                }
                Fixture::Shared => refuse_outside_estop(&agent.estop(), case, args.skip + i)?,
            }
            used = true;
            agent.clear();
            approve.store(case.confirm, Ordering::SeqCst);
            let (r, calls, invalid) = ask_case(&mut agent, case)?;
            // The operator releases an e-stop the case engaged before the next one.
            if release_case_estop(&agent.estop(), fixture, case, args.skip + i)? {
                eprintln!(
                    "\ncase {}: the e-stop it engaged is released for the next case",
                    case.id
                );
                run.latched.push(case.id.clone());
            }
            if let Some(i) = answered_in_index(&case.query, &r.answer) {
                run.answered_in[i] += 1;
            }
            let result = case_result(case, mode, &r, calls, invalid);
            writeln!(file, "{}", serde_json::to_string(&result)?)?;
            results.push(result);
            // The case's result is kept; then a robot that lost a node stops the run.
            if let Some(g) = shared.as_deref() {
                present.check(nodes_now(g).map(Vec::from_iter), case, args.skip + i + 1)?;
            }
            let passed = results.iter().filter(|r| r.pass).count();
            eprint!("\r{} / {total} ({passed} passed)", results.len());
        }
    }
    drop(link);
    eprintln!();
    report(args, &cases, &results, &run)?;
    eprintln!("per-case results: {}", jsonl.display());
    Ok(())
}

/// One case asked of the agent (as cleared, with the case's answer to confirmation set):
/// the run, the calls it made, and how many calls were not valid.
fn ask_case(
    agent: &mut crate::agent::Agent,
    case: &eval::ros::RosCase,
) -> anyhow::Result<(crate::agent::RunResult, Vec<ToolCall>, usize)> {
    let (mut calls, mut invalid) = (Vec::new(), 0usize);
    let r = agent.ask(&case.query, &mut |e| match e {
        Event::ToolCall {
            name,
            arguments,
            decision,
            ..
        } => {
            if matches!(decision, Decision::Refused(w) if w.starts_with("invalid arguments")) {
                invalid += 1;
            }
            calls.push(ToolCall {
                name: name.clone(),
                arguments: arguments.clone(),
            });
        }
        Event::Error { message } if message.contains("did not parse") => invalid += 1,
        _ => {}
    })?;
    Ok((r, calls, invalid))
}

/// For a request not in English, whether its answer is in its language (0), in another
/// (1), or data alone (2).
fn answered_in_index(query: &str, answer: &str) -> Option<usize> {
    match Language::of(query) {
        Some(l) if l != Language::English => Some(match Language::of(answer) {
            Some(a) if a == l => 0,
            _ if l.differs(answer) => 1,
            _ => 2,
        }),
        _ => None,
    }
}

/// A case's line of the per-case results.
fn case_result(
    case: &eval::ros::RosCase,
    mode: Decoding,
    r: &crate::agent::RunResult,
    calls: Vec<ToolCall>,
    invalid: usize,
) -> CaseResult {
    let tokens = r.timings.generated_tokens;
    let verdict = eval::ros::check(case, &calls, &r.answer);
    let model_s = r.timings.model_ms / 1e3;
    CaseResult {
        id: case.id.clone(),
        category: case.category(),
        decoding: format!("{mode:?}").to_lowercase(),
        pass: verdict.passed(),
        reason: match verdict {
            eval::score::Verdict::Fail(why) => Some(why),
            eval::score::Verdict::Pass => None,
        },
        attempted_call: !calls.is_empty() || invalid > 0,
        valid_call: invalid == 0 && !calls.is_empty(),
        calls,
        text: r.answer.clone(),
        ms: r.timings.total_ms,
        generated_tokens: tokens,
        tok_per_s: if model_s > 0.0 {
            tokens as f64 / model_s
        } else {
            0.0
        },
    }
}

/// A new sim robot and a new participant to see it, in place of the old pair.
fn fresh_sim(
    robot: Robot,
    mut link: super::robot::RobotLink,
    switch: &SwitchGraph,
) -> anyhow::Result<super::robot::RobotLink> {
    if robot == Robot::SimRos1 {
        // On ROS 1 the new robot takes the old one's node name: the old one leaves the
        // master first.
        drop(std::mem::replace(
            &mut link,
            super::robot::RobotLink::none(),
        ));
    }
    let fresh = super::agent::connect(robot, false)?;
    switch.replace(fresh.graph.clone().context("the sim has no graph")?);
    drop(link);
    Ok(fresh)
}

/// What a suite run saw besides its cases' results.
struct SuiteRun {
    model: String,
    fixture: String,
    /// Answers to requests not in English: in their language, in another one, or data
    /// alone (names and numbers, words no language shows).
    answered_in: [usize; 3],
    /// The cases that latched the e-stop (released before the next case).
    latched: Vec<String>,
}

/// The suite's summary: per category and decoding mode, per half, overall; the
/// languages of the answers; the e-stops cases latched.
fn report(
    args: &RosArgs,
    cases: &[eval::ros::RosCase],
    results: &[CaseResult],
    run: &SuiteRun,
) -> anyhow::Result<()> {
    let summaries = eval::summarize(results);
    std::fs::write(
        args.out.join("ros_summary.json"),
        serde_json::to_string_pretty(&summaries)?,
    )?;
    let copy = match args.agent.copy_bias {
        b if b > 0.0 => format!(" | copy bias {b}"),
        _ => String::new(),
    };
    let pick = format!("{:?}", args.agent.pick).to_lowercase();
    let pick = format!("{pick}, adapter {}", args.agent.model.adapter);
    println!(
        "model {} | suite {}{copy} | tool pick {pick} | {} | {} cases per mode\n",
        run.model,
        args.suite.display(),
        run.fixture,
        cases.len()
    );
    let overall = eval::summarize_overall(results);
    // Each half on its own (see `eval::ros::halves`): tune on one, report the other.
    let halves = eval::ros::halves(cases);
    let mut by_half = Vec::new();
    for (half, label) in [
        (eval::ros::Half::Tune, "tune half"),
        (eval::ros::Half::Report, "report half"),
    ] {
        let ids: std::collections::HashSet<&str> = cases
            .iter()
            .zip(&halves)
            .filter(|(_, h)| **h == half)
            .map(|(c, _)| c.id.as_str())
            .collect();
        let part: Vec<CaseResult> = results
            .iter()
            .filter(|r| ids.contains(r.id.as_str()))
            .cloned()
            .collect();
        for mut s in eval::summarize_overall(&part) {
            s.category = label.into();
            by_half.push(s);
        }
    }
    print!(
        "{}",
        eval::markdown(&[summaries, by_half, overall].concat())
    );
    let [own, other, data] = run.answered_in;
    if own + other + data > 0 {
        println!(
            "\nanswers to the {} requests not in English: {own} in their language, {other} in another, {data} data alone (names and numbers; the agent's lead word)",
            own + other + data
        );
    }
    if !run.latched.is_empty() {
        println!(
            "\ne-stop: engaged by {} case(s) ({}), released before the next case",
            run.latched.len(),
            run.latched.join(", ")
        );
    }
    Ok(())
}

/// The share of cases whose expected tools (every `expect_calls` name, one of
/// `expect_any`) are all offered, per category and per half, with the misses.
fn retrieval(agent: &crate::agent::Agent, cases: &[eval::ros::RosCase]) -> anyhow::Result<()> {
    use std::collections::BTreeMap;
    let halves = eval::ros::halves(cases);
    let mut by: BTreeMap<String, (usize, usize)> = BTreeMap::new();
    let (mut tune, mut report) = ((0, 0), (0, 0));
    let mut sizes = Vec::new();
    let mut first = 0usize;
    for (case, half) in cases.iter().zip(halves) {
        let offered: Vec<String> = agent
            .offered_tools(&case.query)
            .into_iter()
            .map(|s| s.name)
            .collect();
        sizes.push(offered.len());
        if let Some(want) = case.expect_calls.first().or(case.expect_any.first()) {
            if offered.first() == Some(&want.name) {
                first += 1;
            }
        }
        let has = |n: &String| offered.contains(n);
        let hit = case.expect_calls.iter().all(|c| has(&c.name))
            && (case.expect_any.is_empty() || case.expect_any.iter().any(|c| has(&c.name)));
        if !hit {
            let want: Vec<&str> = case
                .expect_calls
                .iter()
                .chain(&case.expect_any)
                .map(|c| c.name.as_str())
                .collect();
            println!(
                "miss {}: {:?} wants {want:?}, offered {offered:?}",
                case.id, case.query
            );
        }
        for counts in [
            by.entry(case.category()).or_default(),
            match half {
                eval::ros::Half::Tune => &mut tune,
                eval::ros::Half::Report => &mut report,
            },
        ] {
            counts.0 += usize::from(hit);
            counts.1 += 1;
        }
    }
    let pct = |(h, n): (usize, usize)| 100.0 * h as f64 / n.max(1) as f64;
    let all = (tune.0 + report.0, tune.1 + report.1);
    println!(
        "\nretrieval: {:.1}% ({}/{}) | tune half {:.1}% | report half {:.1}% | first call's tool ranked first: {first} | tools offered per case: {:.1} of {}",
        pct(all),
        all.0,
        all.1,
        pct(tune),
        pct(report),
        sizes.iter().sum::<usize>() as f64 / sizes.len().max(1) as f64,
        agent.registry().len() + 1
    );
    for (cat, c) in by {
        println!("  {cat:<12} {:5.1}% ({}/{})", pct(c), c.0, c.1);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn case(id: &str) -> eval::ros::RosCase {
        serde_json::from_value(serde_json::json!({"id": id, "query": "q"})).unwrap()
    }

    #[test]
    fn a_node_that_leaves_a_shared_robot_stops_the_suite() {
        let nodes = |n: &[&str]| Some(n.iter().map(|s| s.to_string()).collect::<Vec<_>>());
        let mut present = Present::default();
        present
            .check(nodes(&["/arm", "/grip", "/_cli_1"]), &case("a-01"), 0)
            .unwrap();
        // Unknown for now, or a node more: the run goes on.
        present.check(None, &case("a-02"), 1).unwrap();
        present
            .check(nodes(&["/grip", "/arm", "/cam"]), &case("a-03"), 2)
            .unwrap();
        let err = present
            .check(nodes(&["/arm"]), &case("a-04"), 3)
            .unwrap_err();
        let err = err.to_string();
        assert!(err.starts_with("/grip left the graph"), "{err}");
        assert!(
            err.contains("case a-04") && err.contains("--skip 3"),
            "{err}"
        );
    }

    #[test]
    fn a_case_releases_its_own_estop_but_never_one_pressed_on_a_shared_robot() {
        let estop = crate::estop::EStop::new();
        let c = case("stop-01");
        assert!(!release_case_estop(&estop, Fixture::Shared, &c, 1).unwrap());
        // The agent's stop, or the request's: released for the next case.
        estop.trigger("the agent (robot_stop)");
        assert!(release_case_estop(&estop, Fixture::Shared, &c, 1).unwrap());
        assert!(!estop.is_engaged());
        refuse_outside_estop(&estop, &c, 1).unwrap();
        // A node on the robot's e-stop topic: the suite stops, the e-stop stays.
        estop.trigger(&crate::ui::robot::estop_topic_source());
        let err = release_case_estop(&estop, Fixture::Shared, &c, 3).unwrap_err();
        assert!(err.to_string().contains("--skip 3"), "{err}");
        assert!(estop.is_engaged());
        let err = refuse_outside_estop(&estop, &case("listing-02"), 3).unwrap_err();
        assert!(err.to_string().contains("before case listing-02"), "{err}");
        // On the sim, a fresh robot per case: whoever pressed it, it is released.
        assert!(release_case_estop(&estop, Fixture::FreshSim, &c, 3).unwrap());
        assert!(!estop.is_engaged());
    }

    #[test]
    fn only_a_robot_decides_how_cases_meet_it() {
        assert_eq!(Fixture::of(Robot::Sim).unwrap(), Fixture::FreshSim);
        assert_eq!(Fixture::of(Robot::SimRos1).unwrap(), Fixture::FreshSim);
        assert_eq!(Fixture::of(Robot::Ros2).unwrap(), Fixture::Shared);
        assert_eq!(Fixture::of(Robot::Ros1).unwrap(), Fixture::Shared);
        assert!(Fixture::of(Robot::None).is_err());
        assert!(Fixture::Shared
            .describe(Robot::Ros1)
            .contains("robot ros1 (the one on the graph, not reset"));
    }
}
