//! The agent loop end to end with the scripted backend over the synthetic vocabulary:
//! real template, grammar, fast-forward and agent loop; the model's replies come from a
//! script. No weights needed.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use ferrosa::agent::{Agent, AgentConfig, Event, Finish, ANSWER_TOOL};
use ferrosa::decode::envelope::Envelope;
use ferrosa::tool::policy::{NoOperator, PolicyFile};
use ferrosa::tool::{
    Confirm, Decision, Effect, Package, Policy, Registry, Tool, ToolCall, ToolContext, ToolError,
};
use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use crate::support::scripted::Scripted;

fn call(name: &str, args: Value) -> String {
    calls(&[(name, args)])
}

/// Calls written as the SmolLM2 envelope writes them.
fn calls(list: &[(&str, Value)]) -> String {
    let items: Vec<ToolCall> = list
        .iter()
        .map(|(n, a)| ToolCall {
            name: n.to_string(),
            arguments: a.clone(),
        })
        .collect();
    Envelope::Smollm2.render_calls(&items)
}

fn answer(text: &str) -> String {
    call(ANSWER_TOOL, json!({"text": text}))
}

fn agent(script: &[String], packages: Vec<Package>, policy: Policy, context: usize) -> Agent {
    let replies: Vec<&str> = script.iter().map(String::as_str).collect();
    agent_on(
        Scripted::synthetic(&replies).with_context(context),
        packages,
        policy,
    )
}

fn agent_on(backend: Scripted, packages: Vec<Package>, policy: Policy) -> Agent {
    let mut registry = Registry::new();
    for p in ferrosa::tools::standard().into_iter().chain(packages) {
        registry.add(p);
    }
    let mut config = AgentConfig::for_family("smollm2");
    config.max_steps = 6;
    // The synthetic vocabulary spends about four tokens where SmolLM2's spends one: room
    // for every tool (the selection test narrows its own).
    config.tool_budget_tokens = 20_000;
    // The scripted replies are the model's choices; a weighed or calibrated choice
    // would read the synthetic logits as preferences and choose again.
    config.pick = ferrosa::agent::config::Pick::Likeliest;
    Agent::new(
        Box::new(backend),
        registry,
        Arc::new(policy),
        "You are a test robot.".into(),
        config,
    )
    .unwrap()
}

fn ask(a: &mut Agent, q: &str) -> (ferrosa::agent::RunResult, Vec<Event>) {
    let mut events = Vec::new();
    let r = a.ask(q, &mut |e| events.push(e.clone())).unwrap();
    (r, events)
}

#[test]
fn multi_step_run_observes_and_answers() {
    let script = [
        call("calc_eval", json!({"expression": "3 + 5 + 10"})),
        call("calc_stats", json!({"values": [3, 5, 10], "stat": "mean"})),
    ];
    let mut a = agent(&script, vec![], Policy::default(), 8192);
    let (r, events) = ask(&mut a, "sum and mean of 3, 5, 10");
    assert_eq!(r.finish, Finish::Answer);
    // Once the result is in and only the answer may follow, the answer is the result,
    // with no model turn (the script has none left to give).
    assert!(r.answer.contains("6.0"), "{}", r.answer);
    assert_eq!(r.steps.len(), 2);
    assert_eq!(r.steps[0].output["result"], json!(18.0));
    assert_eq!(r.steps[1].output["result"], json!(6.0));
    assert!(events
        .iter()
        .any(|e| matches!(e, Event::ToolResult { name, ok: true, .. } if name == "calc_stats")));
    // Later steps reuse the cached prefix: only the scratchpad is evaluated again.
    assert!(
        r.timings.reused_tokens[1] > r.timings.prompt_tokens[0],
        "{:?}",
        r.timings
    );
}

#[test]
fn a_request_of_several_parts_is_worked_one_part_at_a_time() {
    let script = [
        call("calc_eval", json!({"expression": "3 + 5"})),
        call("calc_stats", json!({"values": [3, 5, 10], "stat": "mean"})),
    ];
    let replies: Vec<&str> = script.iter().map(String::as_str).collect();
    let prompts = Arc::new(Mutex::new(Vec::new()));
    let backend = Scripted::synthetic(&replies).with_probe(prompts.clone());
    let mut a = agent_on(backend, vec![], Policy::default());
    let (r, _) = ask(&mut a, "add 3 and 5, then tell me the mean of 3, 5 and 10");
    assert!(r.answer.contains("6.0"), "{}", r.answer);
    assert_eq!(r.steps.len(), 2);
    let prompts = prompts.lock().unwrap();
    let text = |i: usize| a.backend().vocab().decode_lossy(&prompts[i]);
    // The first turn shows the first part alone; the next shows the second part as the
    // operator's next turn, after the first part's result.
    let (first, second) = (text(0), text(1));
    assert!(first.contains("add 3 and 5"), "{first}");
    assert!(!first.contains("the mean of"), "{first}");
    let result = second
        .find("\"result\"")
        .expect("the first result is shown");
    let part = second
        .find("tell me the mean of 3, 5 and 10")
        .expect("the second part");
    assert!(part > result, "{second}");
}

#[test]
fn a_part_the_model_answers_without_a_call_is_kept_and_the_next_part_worked() {
    let script = [
        answer("Hello!"),
        call("calc_eval", json!({"expression": "2 + 2"})),
    ];
    let mut a = agent(&script, vec![], Policy::default(), 8192);
    let (r, _) = ask(&mut a, "hello there, what is 2 + 2?");
    assert_eq!(r.finish, Finish::Answer);
    assert_eq!(r.steps.len(), 1);
    // The first part's answer, then the second's: its result.
    assert!(r.answer.starts_with("Hello! "), "{}", r.answer);
    assert!(r.answer.contains("2 + 2 = 4"), "{}", r.answer);
}

/// Two tools that each wait until both have started: run one after the other, the first
/// would wait in vain and time out.
struct Rendezvous {
    name: &'static str,
    started: Arc<AtomicUsize>,
}

#[derive(Deserialize, JsonSchema)]
struct NoArgs {}

struct RendezvousA(Rendezvous);
struct RendezvousB(Rendezvous);

async fn meet(r: &Rendezvous) -> Result<Value, ToolError> {
    r.started.fetch_add(1, Ordering::SeqCst);
    for _ in 0..200 {
        if r.started.load(Ordering::SeqCst) >= 2 {
            return Ok(json!({"tool": r.name, "saw_both_started": true}));
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    Err(ToolError::Failed(format!(
        "{} never saw the other call start",
        r.name
    )))
}

impl Tool for RendezvousA {
    type Args = NoArgs;
    const NAME: &'static str = "meet_a";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Test tool A.".into()
    }
    async fn call(&self, _: NoArgs, _: &ToolContext) -> Result<Value, ToolError> {
        meet(&self.0).await
    }
}

impl Tool for RendezvousB {
    type Args = NoArgs;
    const NAME: &'static str = "meet_b";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Test tool B.".into()
    }
    async fn call(&self, _: NoArgs, _: &ToolContext) -> Result<Value, ToolError> {
        meet(&self.0).await
    }
}

#[test]
fn parallel_calls_run_concurrently_and_return_in_call_order() {
    let started = Arc::new(AtomicUsize::new(0));
    let pkg = Package::new("test")
        .with(RendezvousA(Rendezvous {
            name: "a",
            started: started.clone(),
        }))
        .with(RendezvousB(Rendezvous {
            name: "b",
            started: started.clone(),
        }));
    let script = [
        calls(&[("meet_b", json!({})), ("meet_a", json!({}))]),
        answer("Both met."),
    ];
    let mut a = agent(&script, vec![pkg], Policy::default(), 8192);
    let (r, _) = ask(&mut a, "meet");
    assert_eq!(r.steps.len(), 2);
    assert_eq!(r.steps[0].name, "meet_b", "results come back in call order");
    assert_eq!(r.steps[1].name, "meet_a");
    for s in &r.steps {
        assert!(s.ok, "{}: {}", s.name, s.output);
        assert_eq!(s.output["saw_both_started"], json!(true));
    }
}

#[test]
fn a_tool_error_is_an_observation_the_model_recovers_from() {
    let script = [
        call("calc_eval", json!({"expression": "2 +"})),
        call("calc_eval", json!({"expression": "2 + 2"})),
    ];
    let mut a = agent(&script, vec![], Policy::default(), 8192);
    // Not said as arithmetic ("2 plus 2"), which would hold the expression to `2 + 2`
    // (`reading::arithmetic`) and leave the scripted model no error to make.
    let (r, _) = ask(&mut a, "2 and 2, added?");
    assert!(!r.steps[0].ok);
    assert!(r.steps[0].output["error"]
        .as_str()
        .unwrap()
        .contains("invalid arguments"));
    assert!(r.steps[1].ok);
    assert!(r.answer.contains("2 + 2 = 4"), "{}", r.answer);
}

struct Sleepy;

#[derive(Deserialize, JsonSchema)]
struct SleepArgs {
    seconds: f64,
}

impl Tool for Sleepy {
    type Args = SleepArgs;
    const NAME: &'static str = "slow_sensor";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "Takes a while.".into()
    }
    async fn call(&self, a: SleepArgs, _: &ToolContext) -> Result<Value, ToolError> {
        tokio::time::sleep(Duration::from_secs_f64(a.seconds)).await;
        Ok(json!({"done": true}))
    }
}

#[test]
fn a_timeout_is_an_observation_not_a_hang() {
    let file = PolicyFile {
        timeout_s: Some(0.2),
        ..Default::default()
    };
    let policy = Policy::from_file(file, Arc::new(NoOperator)).unwrap();
    let script = [
        call("slow_sensor", json!({"seconds": 30})),
        answer("The sensor did not answer."),
    ];
    let mut a = agent(&script, vec![Package::new("t").with(Sleepy)], policy, 8192);
    let started = std::time::Instant::now();
    // The request gives the number the tool takes (a tool that takes numbers only the
    // operator gives is not offered before one is said).
    let (r, _) = ask(&mut a, "read the slow sensor, waiting up to 30 seconds");
    assert!(
        started.elapsed() < Duration::from_secs(20),
        "the timeout did not cut the call"
    );
    assert!(!r.steps[0].ok);
    assert!(r.steps[0].output["error"]
        .as_str()
        .unwrap()
        .contains("timed out"));
    assert_eq!(r.finish, Finish::Answer);
}

#[test]
fn the_step_limit_ends_the_run_with_what_is_known() {
    let script: Vec<String> = (0..10)
        .map(|i| call("calc_eval", json!({"expression": format!("{i} + 1")})))
        .collect();
    let mut a = agent(&script, vec![], Policy::default(), 8192);
    a.config.max_steps = 3;
    // Four parts, a call each (a part whose call succeeded is answered next, not
    // called again), and three steps.
    let (r, _) = ask(
        &mut a,
        "Add 0 and 1. Add 1 and 1. Add 2 and 1. Add 3 and 1.",
    );
    assert_eq!(r.finish, Finish::MaxSteps);
    assert_eq!(r.steps.len(), 3);
    assert!(r.answer.contains("3 steps"), "{}", r.answer);
    // The last result in one line (its summary), not the JSON the model read.
    let last = r.answer.split("Last result:").nth(1).unwrap_or_default();
    assert!(
        last.contains('3') && !last.contains('{') && !last.contains('"'),
        "{}",
        r.answer
    );
}

#[test]
fn a_repeated_call_leads_to_the_answer_instead_of_a_loop() {
    // A failing call made again as it was (after a success, the grammar offers the
    // part's tool no more: `Run::settled`).
    let script = [
        call("calc_eval", json!({"expression": "6 *"})),
        call("calc_eval", json!({"expression": "6 *"})),
        answer("I could not work it out."),
    ];
    let mut a = agent(&script, vec![], Policy::default(), 8192);
    // Not said as arithmetic ("6 times 7": see above).
    let (r, _) = ask(&mut a, "6 and 7, multiplied");
    assert_eq!(r.steps.len(), 1, "the repeat was not run again");
    // Only the answer is left: it is what went wrong, without a model turn.
    assert!(
        r.answer.contains("expression ends too early"),
        "{}",
        r.answer
    );
}

#[test]
fn history_is_trimmed_oldest_first_to_fit_the_context() {
    let dir = tempfile::tempdir().unwrap();
    // Thirty different words (a word said over and over is a loop the answer cuts).
    let long: String = (0..30).map(|k| format!("w{k} ")).collect();
    let mut script = Vec::new();
    for i in 0..8 {
        script.push(answer(&format!("Answer {i}: {}", long.trim())));
    }
    // 5200 tokens (about 1300 of SmolLM2's): the system prompt and tools take most of
    // it, so old pairs must go.
    let mut a = agent(&script, vec![], Policy::default(), 5200)
        .with_trace(ferrosa::agent::trace::Trace::create(dir.path()).unwrap());
    for i in 0..8 {
        let (r, _) = ask(&mut a, &format!("question {i}"));
        assert_eq!(r.finish, Finish::Answer, "{}", r.answer);
        assert!(r.timings.prompt_tokens[0] < 5200);
    }
    let trace = std::fs::read_to_string(a.trace_path().unwrap()).unwrap();
    assert!(trace.contains("history_trimmed"), "no trimming recorded");
    assert!(trace.contains("\"kind\":\"query\""));
}

#[test]
fn a_long_chat_keeps_a_bounded_history_trimmed_in_chunks() {
    let turns = 60;
    let script: Vec<String> = (0..turns)
        .map(|i| answer(&format!("Answer {i}: the turtle is at the centre.")))
        .collect();
    let mut a = agent(&script, vec![], Policy::default(), 8192);
    a.config.history_tokens = 800;
    let mut prompts = Vec::new();
    for i in 0..turns {
        let (r, _) = ask(&mut a, &format!("question {i}"));
        assert_eq!(r.finish, Finish::Answer, "{}", r.answer);
        prompts.push(r.timings.prompt_tokens[0]);
    }
    // However long the chat, the history stays within its budget …
    assert!(a.history_len() < 15, "{} exchanges kept", a.history_len());
    let first = prompts[0];
    assert!(
        prompts.iter().all(|&p| p <= first + 800 + 200),
        "{prompts:?}"
    );
    // … and is cut in chunks (the prompt shrinks now and then, not every turn), so most
    // turns extend the cached prefix instead of evaluating the history again.
    let shrinks = prompts.windows(2).filter(|w| w[1] < w[0]).count();
    assert!(
        (2..turns / 3).contains(&shrinks),
        "{shrinks} shrinks: {prompts:?}"
    );
}

/// Stand-ins with the ROS tools' argument shapes, to show the deny-list holds on every
/// kind of call; `runs` counts calls that actually executed.
#[derive(Clone)]
struct Named {
    name: &'static str,
    effect: Effect,
    runs: Arc<AtomicUsize>,
}

#[derive(Deserialize, JsonSchema)]
struct NameArgs {
    name: String,
    value: Option<f64>,
}

macro_rules! named_tool {
    ($ty:ident, $tool:literal, $effect:expr) => {
        struct $ty(Named);
        impl Tool for $ty {
            type Args = NameArgs;
            const NAME: &'static str = $tool;
            const EFFECT: Effect = $effect;
            fn description(&self) -> String {
                format!("{} on a ROS name.", $tool)
            }
            async fn call(&self, a: NameArgs, _: &ToolContext) -> Result<Value, ToolError> {
                self.0.runs.fetch_add(1, Ordering::SeqCst);
                let _ = (self.0.name, self.0.effect);
                Ok(json!({"name": a.name, "value": a.value}))
            }
        }
    };
}

named_tool!(Echo, "ros_topic_echo", Effect::Observes);
named_tool!(Info, "ros_topic_info", Effect::Observes);
named_tool!(Publish, "ros_topic_publish", Effect::Actuates);
named_tool!(CallSrv, "ros_service_call", Effect::Actuates);
named_tool!(ParamGet, "ros_param_get", Effect::Observes);
named_tool!(ParamSet, "ros_param_set", Effect::Actuates);

struct ListTopics;

impl Tool for ListTopics {
    type Args = NoArgs;
    const NAME: &'static str = "ros_topic_list";
    const EFFECT: Effect = Effect::Observes;
    fn description(&self) -> String {
        "List topics.".into()
    }
    async fn call(&self, _: NoArgs, _: &ToolContext) -> Result<Value, ToolError> {
        Ok(
            json!({"topics": [{"name": "/turtle1/pose"}, {"name": "/secret/keys"}], "names": ["/turtle1/pose", "/secret/keys"]}),
        )
    }
}

fn ros_like(runs: &Arc<AtomicUsize>) -> Package {
    let n = |name| Named {
        name,
        effect: Effect::Observes,
        runs: runs.clone(),
    };
    Package::new("ros")
        .with(Echo(n("echo")))
        .with(Info(n("info")))
        .with(Publish(n("publish")))
        .with(CallSrv(n("call")))
        .with(ParamGet(n("get")))
        .with(ParamSet(n("set")))
        .with(ListTopics)
}

#[test]
fn actuation_runs_only_when_the_request_points_at_it() {
    let runs = Arc::new(AtomicUsize::new(0));
    let approve_all = || {
        let file = PolicyFile {
            auto_approve: true,
            ..Default::default()
        };
        Policy::from_file(file, Arc::new(NoOperator)).unwrap()
    };
    let publish = call(
        "ros_topic_publish",
        json!({"name": "/turtle1/cmd_vel", "value": 1.0}),
    );
    // A request that asks for nothing the call targets (a question would not even offer
    // the publish): the model publishes anyway; even with everything approved, it is
    // refused before it runs, and the model is told why.
    let script = [publish.clone(), answer("The turtle is at the centre.")];
    let mut a = agent(&script, vec![ros_like(&runs)], approve_all(), 8192);
    let (r, _) = ask(&mut a, "check on the turtle for me");
    assert_eq!(runs.load(Ordering::SeqCst), 0, "an unasked publish ran");
    assert!(
        matches!(&r.steps[0].decision, Decision::Refused(why) if why.contains("did not ask")),
        "{:?}",
        r.steps[0].decision
    );
    // Asked for by the tool's own word, or by the target the call names: it runs.
    for query in ["publish 1.0 on /turtle1/cmd_vel", "send 1.0 to cmd_vel"] {
        let script = [publish.clone(), answer("Done.")];
        let mut a = agent(&script, vec![ros_like(&runs)], approve_all(), 8192);
        let before = runs.load(Ordering::SeqCst);
        let (r, _) = ask(&mut a, query);
        assert_eq!(
            runs.load(Ordering::SeqCst),
            before + 1,
            "{query}: {:?}",
            r.steps
        );
    }
}

#[test]
fn deny_listed_names_are_refused_on_every_kind_of_call_and_hidden_from_listings() {
    let runs = Arc::new(AtomicUsize::new(0));
    let file = PolicyFile {
        deny: vec!["^/secret".into()],
        auto_approve: true,
        ..Default::default()
    };
    let policy = Policy::from_file(file, Arc::new(NoOperator)).unwrap();
    // The acts in the first turn: once an act is refused, no other act is offered in
    // the run's part (`NoSubstitute`), so later turns only read.
    let tools = [
        "ros_topic_publish",
        "ros_service_call",
        "ros_param_set",
        "ros_topic_echo",
        "ros_topic_info",
        "ros_param_get",
    ];
    let list: Vec<(&str, Value)> = tools
        .iter()
        .map(|t| (*t, json!({"name": "/secret/keys"})))
        .collect();
    // At most four calls per turn: the six go in two turns.
    let script = [
        calls(&list[..4]),
        calls(&list[4..]),
        call("ros_topic_list", json!({})),
        answer("Denied."),
    ];
    let mut a = agent(&script, vec![ros_like(&runs)], policy, 8192);
    let (r, events) = ask(&mut a, "read or set /secret/keys every way you can");
    assert_eq!(runs.load(Ordering::SeqCst), 0, "a denied call ran");
    for s in &r.steps[..6] {
        assert!(
            matches!(&s.decision, Decision::Refused(why) if why.contains("off limits")),
            "{}: {:?}",
            s.name,
            s.decision
        );
        assert!(!s.ok);
    }
    let listing = &r.steps[6].output;
    assert_eq!(listing["topics"], json!([{"name": "/turtle1/pose"}]));
    assert_eq!(listing["names"], json!(["/turtle1/pose"]));
    assert_eq!(listing["hidden_by_policy"], json!(2));
    let refused = events
        .iter()
        .filter(|e| {
            matches!(
                e,
                Event::ToolCall {
                    decision: Decision::Refused(_),
                    ..
                }
            )
        })
        .count();
    assert_eq!(refused, 6);
    // The model may add a pattern; it cannot take the operator's away.
    let p = Policy::from_file(
        PolicyFile {
            deny: vec!["^/secret".into()],
            ..Default::default()
        },
        Arc::new(NoOperator),
    )
    .unwrap();
    p.add_model_pattern("^/camera").unwrap();
    assert!(p.denied("/camera/raw") && p.denied("/secret/x"));
}

struct Recorder {
    answer: bool,
    asked: Mutex<Vec<String>>,
}

impl Confirm for Recorder {
    fn confirm(&self, call: &ToolCall) -> bool {
        self.asked.lock().unwrap().push(call.name.clone());
        self.answer
    }
}

#[test]
fn actuating_calls_need_confirmation() {
    for approve in [false, true] {
        let runs = Arc::new(AtomicUsize::new(0));
        let rec = Arc::new(Recorder {
            answer: approve,
            asked: Mutex::new(Vec::new()),
        });
        let policy = Policy::from_file(PolicyFile::default(), rec.clone()).unwrap();
        let script = [
            calls(&[
                ("ros_param_get", json!({"name": "/turtlesim/background_r"})),
                (
                    "ros_param_set",
                    json!({"name": "/turtlesim/background_r", "value": 255}),
                ),
            ]),
            answer("Done."),
        ];
        let mut a = agent(&script, vec![ros_like(&runs)], policy, 8192);
        let (r, _) = ask(&mut a, "set background_r to 255");
        assert_eq!(
            *rec.asked.lock().unwrap(),
            vec!["ros_param_set".to_string()],
            "only the actuating call is asked about"
        );
        assert_eq!(r.steps[0].decision, Decision::Allowed);
        if approve {
            assert_eq!(r.steps[1].decision, Decision::Confirmed);
            assert_eq!(runs.load(Ordering::SeqCst), 2);
        } else {
            assert!(
                matches!(&r.steps[1].decision, Decision::Refused(w) if w.contains("did not approve"))
            );
            assert_eq!(
                runs.load(Ordering::SeqCst),
                1,
                "the refused call must not run"
            );
        }
    }
}

#[test]
fn limits_refuse_before_anything_is_sent_and_read_only_removes_actuators() {
    let runs = Arc::new(AtomicUsize::new(0));
    let file: PolicyFile = toml::from_str(
        r#"
auto_approve = true
[[limit]]
tool = "^ros_param_set$"
paths = ["/value"]
max = 1.0
"#,
    )
    .unwrap();
    let policy = Policy::from_file(file, Arc::new(NoOperator)).unwrap();
    let script = [
        call("ros_param_set", json!({"name": "/speed", "value": 3.5})),
        answer("Refused."),
    ];
    let mut a = agent(&script, vec![ros_like(&runs)], policy, 8192);
    let (r, _) = ask(&mut a, "set speed to 3.5");
    assert!(
        matches!(&r.steps[0].decision, Decision::Refused(w) if w.contains("above the limit 1")),
        "{:?}",
        r.steps[0].decision
    );
    assert_eq!(runs.load(Ordering::SeqCst), 0);

    let ro = PolicyFile {
        read_only: true,
        ..Default::default()
    };
    let a = agent(
        &[],
        vec![ros_like(&runs)],
        Policy::from_file(ro, Arc::new(NoOperator)).unwrap(),
        8192,
    );
    let names: Vec<String> = a
        .registry()
        .tools()
        .map(|t| t.spec().name.clone())
        .collect();
    assert!(names.contains(&"ros_param_get".to_string()));
    assert!(!names
        .iter()
        .any(|n| n == "ros_param_set" || n == "ros_topic_publish" || n == "ros_service_call"));
}

#[test]
fn observes_rules_let_read_only_agents_make_query_calls_only() {
    let runs = Arc::new(AtomicUsize::new(0));
    let file: PolicyFile = toml::from_str(
        r#"
read_only = true
[[observes]]
tool = "^ros_service_call$"
argument = "name"
pattern = "/robot/get_.*"
"#,
    )
    .unwrap();
    // No operator and no auto-approval: only calls that observe can run.
    let policy = Policy::from_file(file, Arc::new(NoOperator)).unwrap();
    let script = [
        call("ros_service_call", json!({"name": "/robot/get_state"})),
        call("ros_service_call", json!({"name": "/robot/reset"})),
        answer("Done."),
    ];
    let mut a = agent(&script, vec![ros_like(&runs)], policy, 8192);
    let names: Vec<String> = a
        .registry()
        .tools()
        .map(|t| t.spec().name.clone())
        .collect();
    assert!(names.contains(&"ros_service_call".to_string()), "{names:?}");
    assert!(!names.contains(&"ros_param_set".to_string()), "{names:?}");
    let (r, _) = ask(&mut a, "what state is the robot in, then reset it");
    assert_eq!(r.steps[0].decision, Decision::Allowed, "{:?}", r.steps);
    assert!(
        matches!(&r.steps[1].decision, Decision::Refused(w) if w.contains("read-only")),
        "{:?}",
        r.steps[1].decision
    );
    assert_eq!(runs.load(Ordering::SeqCst), 1);
}

/// A tool known only by its spec (for selection tests): calling it is an error.
struct SpecOnly(ferrosa::tool::ToolSpec);

impl ferrosa::tool::DynTool for SpecOnly {
    fn spec(&self) -> &ferrosa::tool::ToolSpec {
        &self.0
    }
    fn effect(&self) -> Effect {
        Effect::Observes
    }
    fn call<'a>(
        &'a self,
        _: Value,
        _: &'a ToolContext,
    ) -> ferrosa::tool::registry::BoxFuture<'a, Result<Value, ToolError>> {
        Box::pin(async { Err(ToolError::Failed("not implemented in this test".into())) })
    }
}

#[test]
fn many_tools_are_narrowed_to_the_relevant_ones() {
    let specs = ferrosa::tool::specs_from_json(include_str!("data/robot_tools.json")).unwrap();
    let mut pkg = Package::new("robot");
    for s in specs {
        pkg = pkg.with_dyn(Arc::new(SpecOnly(s)));
    }
    let mut a = agent(&[], vec![pkg], Policy::default(), 8192);
    a.config.tool_budget_tokens = 6000;
    let all: Vec<_> = a.registry().specs();
    for (query, must) in [
        ("what is the mean of 3, 5 and 10?", "calc_stats"),
        ("list the ROS topics", "ros_topic_list"),
        ("move the turtle forward 2 meters", "turtle_move"),
    ] {
        let offered = a.offered_tools(query);
        let names: Vec<&str> = offered.iter().map(|s| s.name.as_str()).collect();
        assert!(names.contains(&must), "{query}: {names:?}");
        assert!(names.contains(&ANSWER_TOOL), "the answer tool is always on");
        assert!(offered.len() < all.len());
        let full = a.prompt_tokens_with(query, &all);
        let narrowed = a.prompt_tokens_with(query, &offered);
        eprintln!(
            "{query:?}: {} of {} tools offered; prompt {narrowed} tokens vs {full} with all tools",
            offered.len(),
            all.len()
        );
        assert!(narrowed < full);
    }
}

#[test]
fn every_request_reads_one_listing_of_the_tools_so_the_prompt_before_it_stays_cached() {
    let script = [
        answer("one"),
        answer("two"),
        answer("three"),
        answer("four"),
    ];
    let runs = Arc::new(AtomicUsize::new(0));
    let mut a = agent(&script, vec![ros_like(&runs)], Policy::default(), 1 << 16);
    // Few tools offered per request; all of them listed.
    a.config.tool_budget_tokens = 3000;
    a.config.listing_budget_tokens = 1 << 20;
    let all = a.registry().specs();
    let before_request = a.prompt_tokens_with("", &all);
    let (first, _) = ask(&mut a, "what is the mean of 3, 5 and 10?");
    a.clear();
    let (second, _) = ask(&mut a, "list the ROS topics");
    assert_ne!(first.tools_offered, second.tools_offered);
    assert!(second.tools_offered.len() < all.len());
    // The second request evaluates its own words only: everything up to them (the
    // system prompt and the listing of every tool) comes from the cache.
    let reused = second.timings.reused_tokens[0];
    assert!(
        reused + 8 >= before_request,
        "{reused} tokens reused of the {before_request} before the request"
    );
    // Listing what each request is offered instead, the listing itself is evaluated
    // again whenever the offer changes.
    a.config.listing_budget_tokens = 0;
    a.clear();
    let (_, _) = ask(&mut a, "what is the mean of 3, 5 and 10?");
    a.clear();
    let (narrow, _) = ask(&mut a, "list the ROS topics");
    assert!(
        narrow.timings.reused_tokens[0] + 8 < before_request / 2,
        "{:?}",
        narrow.timings
    );
}

#[test]
fn a_declarative_tool_acts_through_the_ros_graph_after_confirmation() {
    let graph = Arc::new(ferrosa::ros::fake::FakeGraph::new());
    let pkg = ferrosa::tools::declared::parse(
        r#"
[[tool]]
name = "eels_raise_head"
description = "Raise the head by angle degrees (0-45). Moves the robot."
effect = "actuates"
parameters = { type = "object", properties = { angle = { type = "number", minimum = 0, maximum = 45 } }, required = ["angle"] }
[tool.publish]
topic = "/eels/head/cmd"
type = "std_msgs/msg/Float64"
message = { data = "{{angle}}" }
"#,
        "test",
        graph.clone(),
        &Default::default(),
    )
    .unwrap();
    let rec = Arc::new(Recorder {
        answer: true,
        asked: Mutex::new(Vec::new()),
    });
    let policy = Policy::from_file(PolicyFile::default(), rec.clone()).unwrap();
    let script = [
        call("eels_raise_head", json!({"angle": 20})),
        answer("Head raised by 20 degrees."),
    ];
    let mut a = agent(&script, vec![pkg], policy, 8192);
    let (r, _) = ask(&mut a, "raise the head 20 degrees");
    assert_eq!(r.steps[0].decision, Decision::Confirmed);
    assert_eq!(
        *rec.asked.lock().unwrap(),
        vec!["eels_raise_head".to_string()]
    );
    assert_eq!(
        graph.sent(),
        vec![ferrosa::ros::fake::Sent::Publish {
            topic: "/eels/head/cmd".into(),
            type_name: "std_msgs/msg/Float64".into(),
            message: json!({"data": 20}),
        }]
    );
}
