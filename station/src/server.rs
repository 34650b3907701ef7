//! The HTTP side: the embedded page, the WebSocket that streams the rigs' frames, and the JSON
//! API (rigs, statistics, control, recordings). Routes are exact: anything else is a 404, and no
//! route reads a file but the recordings a rig's directory lists.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::extract::{DefaultBodyLimit, Path, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures_util::{SinkExt, StreamExt};
use hydrometra_ipc::control::{self, command, ControlResponse};
use serde::Deserialize;
use serde_json::json;
use tokio::sync::oneshot;

use crate::auth::Token;
use crate::hub::{Hub, Rig};
use crate::recordings::{self, DebriefCache, RecordingsError};

/// Largest message a browser may send (its hello and acknowledgements are far smaller).
pub const MAX_CLIENT_MESSAGE: usize = 1024;
/// Largest request body (control requests).
pub const MAX_BODY: usize = 4096;
/// A browser must say hello within this time.
pub const HELLO_TIMEOUT: Duration = Duration::from_secs(5);
/// A browser that takes one frame slower than this is disconnected.
pub const SEND_TIMEOUT: Duration = Duration::from_secs(10);

/// WebSocket close codes the station uses (RFC 6455).
pub mod close_code {
    /// The browser sent a message kind the station does not take (binary).
    pub const UNSUPPORTED: u16 = 1003;
    /// The message is not valid JSON of a known type.
    pub const INVALID: u16 = 1007;
    /// Missing or wrong token, or no hello in time.
    pub const POLICY: u16 = 1008;
    /// The message is larger than [`super::MAX_CLIENT_MESSAGE`].
    pub const TOO_BIG: u16 = 1009;
}

/// Sends a control request to a rig; the receiver gets the response or why there is none.
pub type ControlRoute =
    Arc<dyn Fn(u32, String) -> oneshot::Receiver<Result<ControlResponse, String>> + Send + Sync>;

/// Where a rig's recordings are.
#[derive(Clone)]
pub enum RecordingsDir {
    /// This directory.
    Fixed(std::path::PathBuf),
    /// The directory of the daemon's open or last recording (asked over control).
    FromDaemon,
}

/// What the station can do with a rig besides showing it.
#[derive(Clone, Default)]
pub struct Backend {
    /// Control requests, if allowed.
    pub control: Option<ControlRoute>,
    /// Recordings, if on this machine.
    pub recordings: Option<RecordingsDir>,
}

/// The server's shared state.
pub struct AppState {
    /// Rigs and browsers.
    pub hub: Arc<Hub>,
    /// The access token.
    pub token: Token,
    /// Whether data may be viewed without the token (the listener is on loopback).
    pub view_open: bool,
    backends: Mutex<HashMap<u16, Backend>>,
    debriefs: DebriefCache,
}

impl AppState {
    /// State over `hub`.
    pub fn new(hub: Arc<Hub>, token: Token, view_open: bool) -> Arc<Self> {
        Arc::new(Self {
            hub,
            token,
            view_open,
            backends: Mutex::new(HashMap::new()),
            debriefs: DebriefCache::default(),
        })
    }

    /// Sets what the station can do with rig `index`.
    pub fn set_backend(&self, index: u16, backend: Backend) {
        self.backends
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(index, backend);
    }

    fn backend(&self, index: u16) -> Option<Backend> {
        self.backends
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .get(&index)
            .cloned()
    }

    fn bearer_ok(&self, headers: &HeaderMap) -> bool {
        headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .is_some_and(|t| self.token.matches(t.trim()))
    }

    fn may_view(&self, headers: &HeaderMap) -> bool {
        self.view_open || self.bearer_ok(headers)
    }
}

const INDEX_HTML: &str = include_str!("assets/index.html");
const STATION_JS: &str = include_str!("assets/station.js");
const VIEWS_JS: &str = include_str!("assets/views.js");
const STATION_CSS: &str = include_str!("assets/station.css");

/// The router.
pub fn router(state: Arc<AppState>) -> Router {
    Router::new()
        .route(
            "/",
            get(|| async { asset("text/html; charset=utf-8", INDEX_HTML) }),
        )
        .route(
            "/station.js",
            get(|| async { asset("text/javascript; charset=utf-8", STATION_JS) }),
        )
        .route(
            "/views.js",
            get(|| async { asset("text/javascript; charset=utf-8", VIEWS_JS) }),
        )
        .route(
            "/station.css",
            get(|| async { asset("text/css; charset=utf-8", STATION_CSS) }),
        )
        .route(
            "/layout.json",
            get(|| async { Json(crate::layout::layout()) }),
        )
        .route("/ws", get(ws_upgrade))
        .route("/api/rigs", get(rigs))
        .route("/api/stats", get(stats))
        .route("/api/stats/reset", post(stats_reset))
        .route("/api/rigs/{rig}/control", post(control_request))
        .route("/api/rigs/{rig}/recordings", get(recordings_list))
        .route(
            "/api/rigs/{rig}/recordings/{name}/debrief",
            get(recording_debrief),
        )
        .fallback(|| async { error(StatusCode::NOT_FOUND, "no such page") })
        .layer(DefaultBodyLimit::max(MAX_BODY))
        .layer(axum::middleware::map_response(security_headers))
        .with_state(state)
}

async fn security_headers(mut r: Response) -> Response {
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(
            "default-src 'self'; connect-src 'self'; img-src 'self' data:; \
             frame-ancestors 'none'; base-uri 'none'; form-action 'none'",
        ),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}

fn asset(content_type: &'static str, body: &'static str) -> Response {
    ([(header::CONTENT_TYPE, content_type)], body).into_response()
}

fn error(code: StatusCode, message: impl Into<String>) -> Response {
    (code, Json(json!({ "error": message.into() }))).into_response()
}

fn unauthorized() -> Response {
    let mut r = error(
        StatusCode::UNAUTHORIZED,
        "missing or wrong token (header `Authorization: Bearer <token>`)",
    );
    r.headers_mut()
        .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
    r
}

async fn rigs(State(st): State<Arc<AppState>>, headers: HeaderMap) -> Response {
    if !st.may_view(&headers) {
        return unauthorized();
    }
    let rigs: Vec<_> = st.hub.rigs().iter().map(|r| rig_json(r)).collect();
    Json(json!({ "rigs": rigs })).into_response()
}

fn rig_json(r: &Rig) -> serde_json::Value {
    let latest = r.latest();
    json!({
        "info": r.info,
        "counters": r.counters,
        "latest": latest.map(|s| json!({
            "sequence": s.sequence,
            "run_id": s.run_id,
            "procedure_id": s.procedure_id.to_string(),
            "cavity_pressure_pa": s.cavity_pressure_pa,
            "deficit_m3": s.deficit_m3,
            "deadline_misses": s.deadline_misses,
            "latency_p99_s": s.latency_p99_s,
        })),
    })
}

async fn stats(State(st): State<Arc<AppState>>, headers: HeaderMap) -> Response {
    if !st.may_view(&headers) {
        return unauthorized();
    }
    let (p50, p99, max, count) = st.hub.latency();
    let rigs: Vec<_> = st.hub.rigs().iter().map(|r| rig_json(r)).collect();
    Json(json!({
        "station": st.hub.counters,
        "page_latency": { "p50_s": p50, "p99_s": p99, "max_s": max, "count": count },
        "cpu_s": crate::cpu::process_cpu_s(),
        "rigs": rigs,
    }))
    .into_response()
}

async fn stats_reset(State(st): State<Arc<AppState>>, headers: HeaderMap) -> Response {
    if !st.bearer_ok(&headers) {
        return unauthorized();
    }
    st.hub.reset_latency();
    Json(json!({ "reset": true })).into_response()
}

/// A control request from the page.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ControlBody {
    /// A command name of docs/ipc.md (`new_procedure`, `load_scene`, `record_start`, ...).
    command: String,
    /// Its argument (the scene of `load_scene`).
    #[serde(default)]
    argument: String,
}

/// The command code of a docs/ipc.md command name.
fn command_code(name: &str) -> Option<u32> {
    (1..=16).find(|c| command::name(*c) == name && name != "unknown")
}

async fn ask(route: &ControlRoute, code: u32, argument: String) -> Result<ControlResponse, String> {
    let rx = route(code, argument);
    // The daemon answers within 5 s; a little more for the hop.
    match tokio::time::timeout(control::RESPONSE_TIMEOUT + Duration::from_secs(1), rx).await {
        Ok(Ok(answer)) => answer,
        Ok(Err(_)) => Err("the control route stopped".into()),
        Err(_) => Err("no response in time".into()),
    }
}

async fn control_request(
    State(st): State<Arc<AppState>>,
    Path(rig): Path<u16>,
    headers: HeaderMap,
    body: Bytes,
) -> Response {
    if !st.bearer_ok(&headers) {
        return unauthorized();
    }
    let req: ControlBody = match serde_json::from_slice(&body) {
        Ok(r) => r,
        Err(e) => {
            return error(
                StatusCode::BAD_REQUEST,
                format!(
                    "control request: {e} (expected {{\"command\": NAME, \"argument\": TEXT}})"
                ),
            )
        }
    };
    let Some(code) = command_code(&req.command) else {
        return error(
            StatusCode::BAD_REQUEST,
            format!("unknown command {:?}", req.command),
        );
    };
    let Some(backend) = st.backend(rig) else {
        return error(StatusCode::NOT_FOUND, format!("no rig {rig}"));
    };
    let Some(route) = backend.control else {
        return error(
            StatusCode::FORBIDDEN,
            format!("rig {rig} does not take control requests from this station"),
        );
    };
    tracing::info!(
        rig,
        command = req.command,
        argument = req.argument,
        "control request"
    );
    match ask(&route, code, req.argument).await {
        Ok(r) => Json(json!({
            "command": command::name(r.command),
            "result": control::result::name(r.result),
            "result_code": r.result,
            "message": r.message(),
            "procedure_id": r.procedure_id.to_string(),
            "recording": r.recording == 1,
            "recording_path": r.recording_path(),
            "recorded_messages": r.recorded_messages,
            "recordings_finished": r.recordings_finished,
        }))
        .into_response(),
        Err(e) => error(StatusCode::SERVICE_UNAVAILABLE, e),
    }
}

/// The rig's recordings directory, or the response to send instead.
async fn recordings_dir(
    st: &AppState,
    rig: u16,
    headers: &HeaderMap,
) -> Result<std::path::PathBuf, Response> {
    if !st.may_view(headers) {
        return Err(unauthorized());
    }
    let backend = st
        .backend(rig)
        .ok_or_else(|| error(StatusCode::NOT_FOUND, format!("no rig {rig}")))?;
    match backend.recordings {
        Some(RecordingsDir::Fixed(dir)) => Ok(dir),
        Some(RecordingsDir::FromDaemon) => {
            let route = backend.control.ok_or_else(|| {
                error(
                    StatusCode::NOT_FOUND,
                    "no control route to ask for recordings",
                )
            })?;
            let r = ask(&route, command::RECORD_STATUS, String::new())
                .await
                .map_err(|e| error(StatusCode::SERVICE_UNAVAILABLE, e))?;
            let path = r.recording_path();
            std::path::Path::new(&path)
                .parent()
                .filter(|_| !path.is_empty())
                .map(|p| p.to_path_buf())
                .ok_or_else(|| {
                    error(
                        StatusCode::NOT_FOUND,
                        format!("the daemon names no recording ({})", r.message()),
                    )
                })
        }
        None => Err(error(
            StatusCode::NOT_FOUND,
            format!("the recordings of rig {rig} are not on this machine"),
        )),
    }
}

fn recordings_error(e: RecordingsError) -> Response {
    let code = match e {
        RecordingsError::NotFound(_) => StatusCode::NOT_FOUND,
        RecordingsError::Io(_) => StatusCode::SERVICE_UNAVAILABLE,
        RecordingsError::Debrief { .. } => StatusCode::UNPROCESSABLE_ENTITY,
    };
    error(code, e.to_string())
}

async fn recordings_list(
    State(st): State<Arc<AppState>>,
    Path(rig): Path<u16>,
    headers: HeaderMap,
) -> Response {
    let dir = match recordings_dir(&st, rig, &headers).await {
        Ok(d) => d,
        Err(r) => return r,
    };
    match tokio::task::spawn_blocking(move || recordings::list(&dir)).await {
        Ok(Ok(list)) => Json(json!({ "recordings": list })).into_response(),
        Ok(Err(e)) => recordings_error(e),
        Err(e) => error(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()),
    }
}

async fn recording_debrief(
    State(st): State<Arc<AppState>>,
    Path((rig, name)): Path<(u16, String)>,
    headers: HeaderMap,
) -> Response {
    if !recordings::valid_name(&name) {
        return error(StatusCode::NOT_FOUND, "no such recording");
    }
    let dir = match recordings_dir(&st, rig, &headers).await {
        Ok(d) => d,
        Err(r) => return r,
    };
    let st2 = st.clone();
    match tokio::task::spawn_blocking(move || st2.debriefs.get(&dir, &name)).await {
        Ok(Ok(d)) => Json(&*d).into_response(),
        Ok(Err(e)) => recordings_error(e),
        Err(e) => error(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()),
    }
}

/// Whether a WebSocket's `Origin` (if any) is this server (`Host`): another site's page must not
/// read the rigs through the instructor's browser.
fn same_origin(headers: &HeaderMap) -> bool {
    let Some(origin) = headers.get(header::ORIGIN).and_then(|v| v.to_str().ok()) else {
        return true; // not a browser
    };
    let host = headers
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let origin_host = origin
        .strip_prefix("http://")
        .or_else(|| origin.strip_prefix("https://"))
        .unwrap_or("");
    !host.is_empty() && origin_host == host
}

async fn ws_upgrade(
    State(st): State<Arc<AppState>>,
    headers: HeaderMap,
    ws: WebSocketUpgrade,
) -> Response {
    if !same_origin(&headers) {
        return error(StatusCode::FORBIDDEN, "WebSocket from another origin");
    }
    // Beyond this tungstenite refuses a message outright; up to it the station answers with an
    // error and a close frame.
    ws.max_message_size(64 * 1024)
        .max_frame_size(64 * 1024)
        .on_upgrade(move |socket| browser(socket, st))
}

/// A message from the page.
#[derive(Debug, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum ClientMessage {
    /// First message: the token (needed off loopback, and for the page to offer control).
    Hello {
        #[serde(default)]
        token: Option<String>,
    },
    /// The page shows a status frame whose header had this `origin_ns` (decimal).
    Ack { rig: u16, origin_ns: String },
}

/// Why a browser's connection is closed.
struct Refusal {
    code: u16,
    message: String,
}

fn refuse(code: u16, message: impl Into<String>) -> Refusal {
    Refusal {
        code,
        message: message.into(),
    }
}

/// Parses a browser's message; `Ok(None)` for control frames (ping, pong) and a close.
fn parse(msg: Message) -> Result<Option<ClientMessage>, Refusal> {
    match msg {
        Message::Text(t) => {
            if t.len() > MAX_CLIENT_MESSAGE {
                return Err(refuse(
                    close_code::TOO_BIG,
                    format!("message of {} bytes; at most {MAX_CLIENT_MESSAGE}", t.len()),
                ));
            }
            serde_json::from_str(t.as_str())
                .map(Some)
                .map_err(|e| refuse(close_code::INVALID, format!("malformed message: {e}")))
        }
        Message::Binary(b) => Err(refuse(
            close_code::UNSUPPORTED,
            format!(
                "binary message of {} bytes: the station takes JSON text only",
                b.len()
            ),
        )),
        Message::Ping(_) | Message::Pong(_) | Message::Close(_) => Ok(None),
    }
}

fn text(value: serde_json::Value) -> Message {
    Message::Text(value.to_string().into())
}

fn hello_json(st: &AppState, control: bool) -> serde_json::Value {
    let rigs: Vec<_> = st.hub.rigs().iter().map(|r| r.info.clone()).collect();
    json!({
        "type": "hello",
        "version": crate::frame::VERSION,
        "station": concat!("hydrometra-station ", env!("CARGO_PKG_VERSION")),
        "control": control,
        "rigs": rigs,
    })
}

/// One browser's connection.
async fn browser(socket: WebSocket, st: Arc<AppState>) {
    let (mut tx, mut rx) = socket.split();
    let result = serve_browser(&mut tx, &mut rx, &st).await;
    if let Err(r) = result {
        st.hub
            .counters
            .client_errors
            .fetch_add(1, Ordering::Relaxed);
        tracing::info!(code = r.code, "browser refused: {}", r.message);
        let _ = tx
            .send(text(json!({ "type": "error", "message": r.message })))
            .await;
        let _ = tx
            .send(Message::Close(Some(CloseFrame {
                code: r.code,
                reason: r.message.chars().take(100).collect::<String>().into(),
            })))
            .await;
    }
    let _ = tx.close().await;
}

type Tx = futures_util::stream::SplitSink<WebSocket, Message>;
type Rx = futures_util::stream::SplitStream<WebSocket>;

async fn send(tx: &mut Tx, st: &AppState, msg: Message) -> Result<(), Refusal> {
    match tokio::time::timeout(SEND_TIMEOUT, tx.send(msg)).await {
        Ok(Ok(())) => {
            st.hub.counters.frames_sent.fetch_add(1, Ordering::Relaxed);
            Ok(())
        }
        Ok(Err(e)) => Err(refuse(1001, format!("send failed: {e}"))),
        Err(_) => {
            st.hub
                .counters
                .browsers_dropped_slow
                .fetch_add(1, Ordering::Relaxed);
            Err(refuse(1008, "the browser took no data for 10 s"))
        }
    }
}

async fn serve_browser(tx: &mut Tx, rx: &mut Rx, st: &Arc<AppState>) -> Result<(), Refusal> {
    // The hello, with the token where needed.
    let first = match tokio::time::timeout(HELLO_TIMEOUT, rx.next()).await {
        Ok(Some(Ok(m))) => parse(m)?,
        Ok(Some(Err(e))) => return Err(refuse(close_code::TOO_BIG, format!("{e}"))),
        Ok(None) => return Ok(()),
        Err(_) => return Err(refuse(close_code::POLICY, "no hello within 5 s")),
    };
    let token_ok = match first {
        Some(ClientMessage::Hello { token }) => token.is_some_and(|t| st.token.matches(&t)),
        _ => {
            return Err(refuse(
                close_code::POLICY,
                "the first message must be {\"type\": \"hello\"}",
            ))
        }
    };
    if !(token_ok || st.view_open) {
        return Err(refuse(close_code::POLICY, "missing or wrong token"));
    }
    let _guard = st.hub.browser();
    let mut changed = st.hub.subscribe();
    let mut seen: HashMap<u16, [u64; 5]> = HashMap::new();
    let mut rigs_told = 0usize;
    send(tx, st, text(hello_json(st, token_ok))).await?;
    loop {
        let rigs = st.hub.rigs();
        if rigs.len() != rigs_told {
            if rigs_told > 0 {
                let mut h = hello_json(st, token_ok);
                h["type"] = json!("rigs");
                send(tx, st, text(h)).await?;
            }
            for r in &rigs[rigs_told..] {
                send(tx, st, Message::Binary(r.history_frame())).await?;
            }
            rigs_told = rigs.len();
        }
        for r in &rigs {
            let seen = seen.entry(r.info.index).or_default();
            let (frames, superseded) = r.newer(seen);
            st.hub
                .counters
                .frames_superseded
                .fetch_add(superseded, Ordering::Relaxed);
            for f in frames {
                send(tx, st, Message::Binary(f)).await?;
            }
        }
        tokio::select! {
            m = rx.next() => match m {
                None | Some(Ok(Message::Close(_))) => return Ok(()),
                Some(Err(e)) => return Err(refuse(close_code::TOO_BIG, format!("{e}"))),
                Some(Ok(m)) => match parse(m)? {
                    Some(ClientMessage::Ack { rig, origin_ns }) => {
                        let origin: u64 = origin_ns.parse().map_err(|_| {
                            refuse(close_code::INVALID, "ack: origin_ns is not a decimal integer")
                        })?;
                        if origin > 0 {
                            let latency = hydrometra_drivers::transport::monotonic_ns().saturating_sub(origin);
                            tracing::trace!(rig, latency_ns = latency, "page shows a status");
                            st.hub.record_latency(latency);
                        }
                    }
                    Some(ClientMessage::Hello { .. }) => {
                        return Err(refuse(close_code::INVALID, "hello sent twice"));
                    }
                    None => {}
                },
            },
            r = changed.changed() => if r.is_err() { return Ok(()) },
        }
    }
}

/// Binds `addr`.
pub async fn bind(addr: SocketAddr) -> std::io::Result<tokio::net::TcpListener> {
    tokio::net::TcpListener::bind(addr).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_names_map_to_their_codes() {
        assert_eq!(command_code("new_procedure"), Some(command::NEW_PROCEDURE));
        assert_eq!(command_code("load_scene"), Some(command::LOAD_SCENE));
        assert_eq!(command_code("record_stop"), Some(command::RECORD_STOP));
        assert_eq!(command_code("unknown"), None);
        assert_eq!(command_code("reboot"), None);
    }

    #[test]
    fn client_messages_parse_strictly() {
        let ok = |s: &str| parse(Message::Text(s.to_string().into()));
        assert!(matches!(
            ok(r#"{"type":"ack","rig":1,"origin_ns":"12"}"#),
            Ok(Some(ClientMessage::Ack { rig: 1, .. }))
        ));
        assert!(matches!(
            ok(r#"{"type":"hello"}"#),
            Ok(Some(ClientMessage::Hello { token: None }))
        ));
        for bad in [
            "not json",
            r#"{"type":"shutdown"}"#,
            r#"{"type":"ack","rig":1}"#,
            r#"{"type":"hello","token":"x","extra":1}"#,
        ] {
            assert_eq!(
                ok(bad).err().map(|r| r.code),
                Some(close_code::INVALID),
                "{bad}"
            );
        }
        let big = format!(r#"{{"type":"hello","token":"{}"}}"#, "x".repeat(2000));
        assert_eq!(ok(&big).err().map(|r| r.code), Some(close_code::TOO_BIG));
        let bin = parse(Message::Binary(Bytes::from_static(b"\x00\x01")));
        assert_eq!(bin.err().map(|r| r.code), Some(close_code::UNSUPPORTED));
    }

    #[test]
    fn websocket_origin_must_be_this_host() {
        let h = |origin: Option<&str>, host: &str| {
            let mut m = HeaderMap::new();
            m.insert(header::HOST, HeaderValue::from_str(host).unwrap());
            if let Some(o) = origin {
                m.insert(header::ORIGIN, HeaderValue::from_str(o).unwrap());
            }
            same_origin(&m)
        };
        assert!(h(Some("http://127.0.0.1:8737"), "127.0.0.1:8737"));
        assert!(h(None, "127.0.0.1:8737"));
        assert!(!h(Some("http://evil.example"), "127.0.0.1:8737"));
        assert!(!h(Some("null"), "127.0.0.1:8737"));
    }
}
