//! The station's HTTP and WebSocket side in-process, without a daemon: unknown paths and path
//! traversal get a 404, control needs the token, viewing needs it off loopback, malformed or
//! oversized messages get an error and the connection closed, and a stalled browser neither
//! blocks the sources nor delays another browser.

use std::io::{Read, Write};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use bytes::Bytes;
use futures_util::{SinkExt, StreamExt};
use hydrometra_ipc::control::{command, result, ControlResponse};
use hydrometra_station::auth;
use hydrometra_station::frame::kind;
use hydrometra_station::hub::{Hub, Rig};
use hydrometra_station::server::{self, close_code, AppState, Backend};
use serde_json::{json, Value};
use tokio_tungstenite::tungstenite::Message;

const TOKEN: &str = "test-token-0123456789";

struct Station {
    addr: SocketAddr,
    hub: Arc<Hub>,
    rig: Arc<Rig>,
    runtime: tokio::runtime::Runtime,
}

/// A station with one rig whose control route answers `ok` with procedure id 42.
fn station(view_open: bool) -> Station {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let hub = Hub::new(60.0);
    let rig = hub.add_rig("rig-a".into(), "test".into(), true, false);
    let token = auth::configured(Some(TOKEN), None, None).unwrap().unwrap();
    let state = AppState::new(hub.clone(), token, view_open);
    state.set_backend(
        rig.info.index,
        Backend {
            control: Some(Arc::new(|code, _argument| {
                let (tx, rx) = tokio::sync::oneshot::channel();
                let mut r = ControlResponse::new(code, result::OK, "done");
                r.procedure_id = 42;
                let _ = tx.send(Ok(r));
                rx
            })),
            recordings: None,
        },
    );
    let listener = runtime
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .unwrap();
    let addr = listener.local_addr().unwrap();
    runtime.spawn(async move { axum::serve(listener, server::router(state)).await });
    Station {
        addr,
        hub,
        rig,
        runtime,
    }
}

/// One raw HTTP/1.1 request (the request line as given, no normalisation); status and body.
fn http(addr: SocketAddr, request_line: &str, headers: &str, body: &str) -> (u16, String) {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "{request_line} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n{headers}\
         Content-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).unwrap();
    let code = out
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let body = out
        .split_once("\r\n\r\n")
        .map_or("", |(_, b)| b)
        .to_string();
    (code, body)
}

#[test]
fn unknown_paths_and_traversal_attempts_get_404_and_never_a_file() {
    let st = station(true);
    for path in [
        "/nope",
        "/index.html",
        "/../../../../etc/passwd",
        "/station.js/../../../../etc/passwd",
        "/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
        "/..%2f..%2f..%2fetc%2fpasswd",
        "/api/rigs/0/recordings/..%2F..%2F..%2Fetc%2Fpasswd/debrief",
        "/api/rigs/0/recordings/....//....//etc/passwd/debrief",
        "/api/nothing",
        "//etc/passwd",
    ] {
        let (code, body) = http(st.addr, &format!("GET {path}"), "", "");
        assert_eq!(code, 404, "{path}: {body}");
        assert!(!body.contains("root:"), "{path} leaked a file: {body}");
    }
    // The page's own assets are there.
    for path in [
        "/",
        "/station.js",
        "/views.js",
        "/station.css",
        "/layout.json",
    ] {
        let (code, _) = http(st.addr, &format!("GET {path}"), "", "");
        assert_eq!(code, 200, "{path}");
    }
}

#[test]
fn control_needs_the_token_and_answers_with_the_daemons_response() {
    let st = station(true);
    let body = r#"{"command":"new_procedure"}"#;
    let path = "POST /api/rigs/0/control";
    let ct = "Content-Type: application/json\r\n";
    assert_eq!(http(st.addr, path, ct, body).0, 401);
    let wrong = format!("{ct}Authorization: Bearer wrong-token-0123456789\r\n");
    assert_eq!(http(st.addr, path, &wrong, body).0, 401);
    let right = format!("{ct}Authorization: Bearer {TOKEN}\r\n");
    let (code, answer) = http(st.addr, path, &right, body);
    assert_eq!(code, 200, "{answer}");
    let v: Value = serde_json::from_str(&answer).unwrap();
    assert_eq!(v["result"], "ok");
    assert_eq!(v["command"], command::name(command::NEW_PROCEDURE));
    assert_eq!(v["procedure_id"], "42");
    // Malformed requests: named, not executed.
    for bad in [
        "not json",
        r#"{"command":"reboot"}"#,
        r#"{"command":"new_procedure","x":1}"#,
    ] {
        let (code, answer) = http(st.addr, path, &right, bad);
        assert_eq!(code, 400, "{bad}: {answer}");
    }
    let (code, _) = http(st.addr, "POST /api/rigs/7/control", &right, body);
    assert_eq!(code, 404);
    // Larger than the body limit.
    let big = format!(
        r#"{{"command":"load_scene","argument":"{}"}}"#,
        "x".repeat(10_000)
    );
    assert_eq!(http(st.addr, path, &right, &big).0, 413);
}

#[test]
fn off_loopback_viewing_needs_the_token_too() {
    let st = station(false);
    assert_eq!(http(st.addr, "GET /api/rigs", "", "").0, 401);
    let auth = format!("Authorization: Bearer {TOKEN}\r\n");
    assert_eq!(http(st.addr, "GET /api/rigs", &auth, "").0, 200);
    st.runtime.block_on(async {
        let mut ws = connect(st.addr).await;
        ws.send(Message::Text(json!({"type": "hello"}).to_string().into()))
            .await
            .unwrap();
        assert_refused(&mut ws, close_code::POLICY).await;
        let mut ws = connect(st.addr).await;
        hello(&mut ws, Some(TOKEN)).await;
    });
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn connect(addr: SocketAddr) -> Ws {
    tokio_tungstenite::connect_async(format!("ws://{addr}/ws"))
        .await
        .unwrap()
        .0
}

/// Says hello and returns the station's hello.
async fn hello(ws: &mut Ws, token: Option<&str>) -> Value {
    ws.send(Message::Text(
        json!({"type": "hello", "token": token}).to_string().into(),
    ))
    .await
    .unwrap();
    loop {
        match next(ws).await {
            Some(Message::Text(t)) => return serde_json::from_str(t.as_str()).unwrap(),
            Some(Message::Binary(_)) => continue,
            other => panic!("expected the hello, got {other:?}"),
        }
    }
}

async fn next(ws: &mut Ws) -> Option<Message> {
    tokio::time::timeout(Duration::from_secs(10), ws.next())
        .await
        .expect("no message within 10 s")
        .map(|m| m.expect("websocket error"))
}

/// The station answers with an error message, then closes with `code`.
async fn assert_refused(ws: &mut Ws, code: u16) {
    let mut saw_error = false;
    loop {
        match tokio::time::timeout(Duration::from_secs(10), ws.next()).await {
            Ok(Some(Ok(Message::Text(t)))) => {
                let v: Value = serde_json::from_str(t.as_str()).unwrap();
                if v["type"] == "error" {
                    assert!(v["message"].as_str().is_some_and(|m| !m.is_empty()));
                    saw_error = true;
                }
            }
            Ok(Some(Ok(Message::Binary(_)))) => {}
            Ok(Some(Ok(Message::Close(frame)))) => {
                assert!(saw_error, "closed without an error message");
                let got = frame.map(|f| u16::from(f.code));
                assert_eq!(got, Some(code));
                return;
            }
            Ok(Some(Ok(_))) => {}
            Ok(Some(Err(e))) => panic!("websocket error instead of a close frame: {e}"),
            Ok(None) => panic!("connection ended without a close frame"),
            Err(_) => panic!("not closed within 10 s"),
        }
    }
}

#[test]
fn malformed_binary_or_oversized_messages_get_an_error_and_the_connection_closed() {
    let st = station(true);
    st.runtime.block_on(async {
        let cases: Vec<(Message, u16)> = vec![
            (Message::Text("not json".into()), close_code::INVALID),
            (
                Message::Text(r#"{"type":"reboot"}"#.into()),
                close_code::INVALID,
            ),
            (
                Message::Text(r#"{"type":"ack","rig":0,"origin_ns":"x"}"#.into()),
                close_code::INVALID,
            ),
            (
                Message::Binary(Bytes::from_static(&[1, 2, 3])),
                close_code::UNSUPPORTED,
            ),
            (Message::Text("x".repeat(4000).into()), close_code::TOO_BIG),
        ];
        for (msg, code) in cases {
            let mut ws = connect(st.addr).await;
            hello(&mut ws, None).await;
            ws.send(msg).await.unwrap();
            assert_refused(&mut ws, code).await;
        }
        // Far beyond what the WebSocket layer takes: the connection ends (close or reset).
        let mut ws = connect(st.addr).await;
        hello(&mut ws, None).await;
        let _ = ws.send(Message::Text("x".repeat(1 << 20).into())).await;
        let ended = loop {
            match tokio::time::timeout(Duration::from_secs(10), ws.next()).await {
                Ok(Some(Ok(Message::Close(_)))) | Ok(None) | Ok(Some(Err(_))) => break true,
                Ok(Some(Ok(_))) => continue,
                Err(_) => break false,
            }
        };
        assert!(ended, "a 1 MiB message did not end the connection");
        // A first message that is no hello.
        let mut ws = connect(st.addr).await;
        ws.send(Message::Text(
            r#"{"type":"ack","rig":0,"origin_ns":"1"}"#.into(),
        ))
        .await
        .unwrap();
        assert_refused(&mut ws, close_code::POLICY).await;
    });
    let refused = st
        .hub
        .counters
        .client_errors
        .load(std::sync::atomic::Ordering::Relaxed);
    assert!(refused >= 7, "{refused}");
}

#[test]
fn a_stalled_browser_never_blocks_the_source_nor_another_browser() {
    let st = station(true);
    let (mut stalled, mut live) = st.runtime.block_on(async {
        let mut a = connect(st.addr).await;
        hello(&mut a, None).await;
        let mut b = connect(st.addr).await;
        hello(&mut b, None).await;
        (a, b)
    });
    // 200 frames of 256 KiB: far more than the stalled browser's socket buffers hold.
    let started = Instant::now();
    for i in 0..200u32 {
        let mut f = vec![0u8; 256 * 1024];
        f[0] = kind::POSITIONS;
        f[4..8].copy_from_slice(&i.to_le_bytes());
        st.rig.put(kind::POSITIONS, Bytes::from(f));
    }
    let put_time = started.elapsed();
    // The source side never waited for a browser (generous bound on a shared machine).
    assert!(put_time < Duration::from_secs(5), "{put_time:?}");
    // The live browser gets the newest frame.
    st.runtime.block_on(async {
        loop {
            match next(&mut live).await {
                Some(Message::Binary(b)) if b[0] == kind::POSITIONS => {
                    if u32::from_le_bytes([b[4], b[5], b[6], b[7]]) == 199 {
                        break;
                    }
                }
                Some(_) => {}
                None => panic!("live browser disconnected"),
            }
        }
        // Only now does the stalled browser read: it skipped to the newest, too.
        let mut last = 0;
        while let Ok(Some(Ok(Message::Binary(b)))) =
            tokio::time::timeout(Duration::from_millis(500), stalled.next()).await
        {
            if b[0] == kind::POSITIONS {
                last = u32::from_le_bytes([b[4], b[5], b[6], b[7]]);
            }
        }
        assert_eq!(last, 199);
    });
    let superseded = st
        .hub
        .counters
        .frames_superseded
        .load(std::sync::atomic::Ordering::Relaxed);
    assert!(superseded > 0, "no frame was dropped for the slow browsers");
}
