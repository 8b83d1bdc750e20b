//! `ferrosa mcp`: the robot's tools for any Model Context Protocol client (a desktop
//! assistant, an IDE, another agent), over stdio or, with `--http ADDR`, streamable HTTP
//! on loopback. No model runs here: the client's model chooses the calls.
//!
//! Who may call: over stdio, the process that started this one (the operator's client).
//! Over HTTP, only a client holding the server's secret (`ui::secret`: drawn at start or
//! taken from `FERROSA_MCP_TOKEN`, kept in a file only the user can read), sent as
//! `Authorization: Bearer`; any other local process is refused before the protocol
//! starts, as is any request that names a browser origin or a host that is not
//! loopback (DNS rebinding). So an elicitation's answer, the operator's approval, comes
//! from the operator's own client on either transport.
//!
//! Every call goes through exactly the agent's path (`tool::exec`): the deny-list and the
//! fence, read-only, the limits, the e-stop (`robot_stop` is one of the tools), the time
//! limit and redaction. An actuating call needs the operator's approval: with `--yes` it
//! has it; otherwise the client is asked for it with MCP elicitation, and a client that
//! cannot elicit, or an operator who declines, leaves the call refused as unconfirmed.
//! An approval is for that one call, with those arguments.
//!
//! Tools are listed with their JSON schemas and `readOnlyHint` (observing tools) or
//! `destructiveHint` (actuating ones; the stop is neither); with `--read-only` the tools
//! that only act are not listed, as a read-only agent is not offered them. A result is
//! the call's report (`{"name",
//! "arguments", "decision", "output", "ok", "ms"}`) as text and as structured content,
//! flagged as an error when the call did not run or failed.
//!
//! The handshake versions are offered (2025-03-26 to 2025-11-25): their clients take
//! the server's elicitation requests.

use std::borrow::Cow;
use std::net::SocketAddr;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::Context;
use rmcp::model::{
    CallToolRequestParams, CallToolResponse, CallToolResult, ContentBlock, Implementation,
    InitializeResult, ListToolsResult, PaginatedRequestParams, ProtocolVersion, ServerCapabilities,
    Tool, ToolAnnotations,
};
use rmcp::service::RequestContext;
use rmcp::{ErrorData, RoleServer, ServerHandler, ServiceExt};
use serde_json::Value;

use super::agent::{robot_tools, AgentArgs};
use super::secret::{bearer, Secret};
use super::term::report_call;
use crate::estop::EStop;
use crate::tool::exec::Executor;
use crate::tool::{Confirm, Effect, ToolCall};

/// The environment variable that sets the HTTP server's secret (else one is drawn).
pub(crate) const TOKEN_ENV: &str = "FERROSA_MCP_TOKEN";

/// How long the operator has to answer an approval request.
const APPROVAL_WAIT: Duration = Duration::from_secs(120);

/// The protocol versions served: those whose clients take elicitation requests.
const VERSIONS: &[ProtocolVersion] = &[
    ProtocolVersion::V_2025_11_25,
    ProtocolVersion::V_2025_06_18,
    ProtocolVersion::V_2025_03_26,
];

#[derive(Debug, Clone)]
pub struct McpArgs {
    pub agent: AgentArgs,
    /// Serve streamable HTTP on this loopback address instead of stdio.
    pub http: Option<SocketAddr>,
}

/// Approvals the operator gave through the client, one per call, taken by the policy
/// when it asks about that call.
#[derive(Default)]
struct Approvals(Mutex<Vec<ToolCall>>);

impl Approvals {
    fn give(&self, call: ToolCall) {
        self.0.lock().expect("approvals lock").push(call);
    }

    /// Take back an approval the call did not use (the deny-list refused it first).
    fn withdraw(&self, call: &ToolCall) {
        let mut given = self.0.lock().expect("approvals lock");
        if let Some(i) = given.iter().position(|c| c == call) {
            given.remove(i);
        }
    }
}

impl Confirm for Approvals {
    fn confirm(&self, call: &ToolCall) -> bool {
        let mut given = self.0.lock().expect("approvals lock");
        match given.iter().position(|c| c == call) {
            Some(i) => {
                given.remove(i);
                true
            }
            None => false,
        }
    }
}

/// The operator's answer about one actuating call, asked through the client.
#[derive(Debug, serde::Deserialize, schemars::JsonSchema)]
struct Approval {
    /// Run this call on the robot?
    approve: bool,
}

rmcp::elicit_safe!(Approval);

/// The MCP server: the tools behind the agent's policy path.
#[derive(Clone)]
struct RobotServer {
    exec: Arc<Executor>,
    approvals: Arc<Approvals>,
    cancel: Arc<AtomicBool>,
}

impl RobotServer {
    fn tools(&self) -> Vec<Tool> {
        self.exec
            .registry()
            .tools()
            .map(|t| {
                let spec = t.spec();
                let schema = spec.parameters.as_object().cloned().unwrap_or_default();
                Tool::new(
                    spec.name.clone(),
                    spec.description.clone(),
                    Arc::new(schema),
                )
                .with_annotations(
                    ToolAnnotations::new()
                        .read_only(t.effect() == Effect::Observes)
                        .destructive(t.effect() == Effect::Actuates),
                )
            })
            .collect()
    }

    /// Ask the operator through the client about an actuating `call`; their yes is
    /// kept for the policy. Why it was not approved, otherwise.
    async fn ask_operator(
        &self,
        call: &ToolCall,
        cx: &RequestContext<RoleServer>,
    ) -> Result<(), String> {
        let elicits = cx
            .peer
            .peer_info()
            .is_some_and(|i| i.capabilities.elicitation.is_some());
        if !elicits {
            return Err("this client cannot ask the operator (no MCP elicitation): approve actuating calls by starting `ferrosa mcp --yes`, or use a client that supports elicitation".into());
        }
        let mut shown = call.clone();
        self.exec.policy().redact(&mut shown.arguments);
        let message = format!(
            "The robot is asked to run {} with {}. Approve it?",
            shown.name, shown.arguments
        );
        match cx
            .peer
            .elicit_with_timeout::<Approval>(message, Some(APPROVAL_WAIT))
            .await
        {
            Ok(Some(Approval { approve: true })) => {
                self.approvals.give(call.clone());
                Ok(())
            }
            Ok(_) => Err("the operator did not approve it".into()),
            Err(e) => Err(format!("the operator's approval was not had: {e}")),
        }
    }

    async fn call(
        &self,
        request: CallToolRequestParams,
        cx: RequestContext<RoleServer>,
    ) -> Result<CallToolResult, ErrorData> {
        let call = ToolCall {
            name: request.name.to_string(),
            arguments: Value::Object(request.arguments.unwrap_or_default()),
        };
        let Some(tool) = self.exec.registry().get(&call.name) else {
            return Err(ErrorData::invalid_params(
                format!("no tool named {}; tools/list lists them", call.name),
                None,
            ));
        };
        let policy = self.exec.policy().clone();
        let mut unapproved = None;
        if policy.actuates(tool.effect(), &call) && !policy.auto_approve {
            unapproved = self.ask_operator(&call, &cx).await.err();
        }
        let (exec, cancel, run) = (self.exec.clone(), self.cancel.clone(), call.clone());
        let outcome = tokio::task::spawn_blocking(move || exec.call(&run, &cancel))
            .await
            .map_err(|e| {
                ErrorData::internal_error(format!("the call did not finish: {e}"), None)
            })?;
        self.approvals.withdraw(&call);
        let mut shown = call;
        policy.redact(&mut shown.arguments);
        let mut report = report_call(&shown, &outcome);
        if let (Some(why), false) = (unapproved, outcome.ok) {
            report["approval"] = Value::String(why);
        }
        let text = ContentBlock::text(report.to_string());
        let mut result = if outcome.ok {
            CallToolResult::success(vec![text])
        } else {
            CallToolResult::error(vec![text])
        };
        result.structured_content = Some(report);
        Ok(result)
    }
}

impl ServerHandler for RobotServer {
    fn get_info(&self) -> InitializeResult {
        InitializeResult::new(ServerCapabilities::builder().enable_tools().build())
            .with_protocol_version(ProtocolVersion::V_2025_11_25)
            .with_server_info(Implementation::new("ferrosa", env!("CARGO_PKG_VERSION")))
            .with_instructions(
                "The tools of one robot, under its operator's policy. Calls that move the robot need the operator's approval, asked through elicitation; robot_stop stops it at once.",
            )
    }

    fn supported_protocol_versions(&self) -> Cow<'static, [ProtocolVersion]> {
        Cow::Borrowed(VERSIONS)
    }

    async fn list_tools(
        &self,
        _request: Option<PaginatedRequestParams>,
        _cx: RequestContext<RoleServer>,
    ) -> Result<ListToolsResult, ErrorData> {
        Ok(ListToolsResult::with_all_items(self.tools()))
    }

    async fn call_tool(
        &self,
        request: CallToolRequestParams,
        cx: RequestContext<RoleServer>,
    ) -> Result<CallToolResponse, ErrorData> {
        self.call(request, cx).await.map(Into::into)
    }
}

/// `ferrosa mcp` (see the module header).
pub fn run(args: &McpArgs) -> anyhow::Result<()> {
    if let Some(addr) = args.http {
        anyhow::ensure!(
            addr.ip().is_loopback(),
            "--http {addr}: ferrosa mcp serves loopback only (127.0.0.1 or [::1]); to reach it from another machine, put an authenticating proxy in front of it"
        );
    }
    let approvals = Arc::new(Approvals::default());
    let (robot, registry, policy) = robot_tools(&args.agent, approvals.clone(), EStop::new())?;
    // Read-only lists what a read-only agent is offered: no tool that only acts.
    let registry = policy.offered(registry);
    let server = RobotServer {
        exec: Arc::new(Executor::new(registry, policy)?),
        approvals,
        cancel: Arc::new(AtomicBool::new(false)),
    };
    // The executor owns a runtime: its last handle must go outside this one.
    let keep = server.exec.clone();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let served = rt.block_on(async move {
        match args.http {
            None => {
                let running = server
                    .serve(rmcp::transport::io::stdio())
                    .await
                    .context("starting the MCP server on stdio")?;
                running.waiting().await?;
                Ok(())
            }
            // Ctrl-C or TERM end it with the secret's file removed (dropped here).
            Some(addr) => tokio::select! {
                served = serve_http(server, addr) => served,
                _ = super::term::interrupted() => Ok(()),
            },
        }
    });
    rt.shutdown_timeout(Duration::from_secs(2));
    drop(keep);
    drop(robot);
    served
}

/// Streamable HTTP on `addr` (loopback), until the process ends; every request
/// authenticated first (see the module header).
async fn serve_http(server: RobotServer, addr: SocketAddr) -> anyhow::Result<()> {
    use rmcp::transport::streamable_http_server::session::local::LocalSessionManager;
    use rmcp::transport::streamable_http_server::{
        StreamableHttpServerConfig, StreamableHttpService,
    };
    let service = StreamableHttpService::new(
        move || Ok(server.clone()),
        Arc::new(LocalSessionManager::default()),
        // Loopback hosts only (the default), and no browser origin at all.
        StreamableHttpServerConfig::default().enforce_origin_validation(),
    );
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("binding {addr}"))?;
    let local = listener.local_addr()?;
    let secret = Arc::new(Secret::create(TOKEN_ENV, &format!("mcp-{}", local.port()))?);
    eprintln!(
        "ferrosa mcp: streamable HTTP on http://{local}/mcp (clients send Authorization: Bearer TOKEN; {})",
        secret.where_kept()
    );
    loop {
        let (stream, _) = listener.accept().await?;
        let (service, secret) = (service.clone(), secret.clone());
        let svc = hyper::service::service_fn(move |req: hyper::Request<hyper::body::Incoming>| {
            let (service, secret) = (service.clone(), secret.clone());
            async move {
                if let Some(refused) = refuse(&req, &secret) {
                    return Ok::<_, std::convert::Infallible>(refused);
                }
                Ok(service.handle(req).await)
            }
        });
        tokio::spawn(async move {
            let io = hyper_util::rt::TokioIo::new(stream);
            if let Err(e) = hyper::server::conn::http1::Builder::new()
                .serve_connection(io, svc)
                .await
            {
                tracing::debug!("MCP connection: {e}");
            }
        });
    }
}

type Body = http_body_util::combinators::BoxBody<bytes::Bytes, std::convert::Infallible>;

/// The answer to a request that does not hold the secret or names a browser origin;
/// `None` for one that may go on to the protocol.
fn refuse<B>(req: &hyper::Request<B>, secret: &Secret) -> Option<hyper::Response<Body>> {
    use http_body_util::BodyExt;
    use hyper::StatusCode;
    let (status, message) = if req.headers().contains_key(hyper::header::ORIGIN) {
        (
            StatusCode::FORBIDDEN,
            "ferrosa mcp takes no requests from web pages (the request names an Origin)",
        )
    } else if !bearer(req.headers()).is_some_and(|t| secret.matches(t)) {
        (
            StatusCode::UNAUTHORIZED,
            "ferrosa mcp needs its secret: send Authorization: Bearer TOKEN (the token is in the file `ferrosa mcp` printed at start, or set it with FERROSA_MCP_TOKEN)",
        )
    } else {
        return None;
    };
    let body = serde_json::json!({"error": message}).to_string();
    let mut resp = hyper::Response::new(
        http_body_util::Full::new(bytes::Bytes::from(body))
            .map_err(|never| match never {})
            .boxed(),
    );
    *resp.status_mut() = status;
    resp.headers_mut().insert(
        hyper::header::CONTENT_TYPE,
        hyper::header::HeaderValue::from_static("application/json"),
    );
    if status == StatusCode::UNAUTHORIZED {
        resp.headers_mut().insert(
            hyper::header::WWW_AUTHENTICATE,
            hyper::header::HeaderValue::from_static("Bearer"),
        );
    }
    Some(resp)
}
