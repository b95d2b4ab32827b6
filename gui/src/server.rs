//! The HTTP side (axum): the embedded page, the live stream (`/ws`) and the order endpoints
//! (`/api/*`). Every request under `/api` and the stream check the access token when one is
//! set; every order is checked ([`crate::orders`]) before it reaches the orders thread.

use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use axum::Router;
use axum::body::Bytes;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{RawQuery, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use futures_util::{SinkExt as _, StreamExt as _};
use serde_json::{Value, json};

use crate::hub::Hub;
use crate::orders::{self, Invalid};
use crate::send::{ModuleCommand, Outgoing, Senders};

/// A client that has not taken a frame for this long is dropped (it never blocks anyone
/// meanwhile: only its own task waits).
pub const SEND_TIMEOUT: Duration = Duration::from_secs(5);

/// How long an order waits for the Interface's answer before `202 Accepted`.
pub const ANSWER_WAIT: Duration = Duration::from_secs(2);

const INDEX_HTML: &str = include_str!("../assets/index.html");
const APP_JS: &str = include_str!("../assets/app.js");
const STYLE_CSS: &str = include_str!("../assets/style.css");

/// The server's shared state.
pub struct App {
    /// The live frames.
    pub hub: Arc<Hub>,
    /// The sending threads.
    pub senders: Senders,
    /// The access token, when one is required.
    pub token: Option<String>,
    /// The system's prefix (shown on the page).
    pub prefix: String,
    seq: AtomicU32,
}

impl App {
    /// The shared state; order numbers start at `seq0`.
    pub fn new(
        hub: Arc<Hub>,
        senders: Senders,
        token: Option<String>,
        prefix: String,
        seq0: u32,
    ) -> App {
        App {
            hub,
            senders,
            token,
            prefix,
            seq: AtomicU32::new(seq0),
        }
    }

    #[allow(clippy::result_large_err)]
    fn auth(&self, headers: &HeaderMap, query: Option<&str>) -> Result<(), Response> {
        let Some(expected) = &self.token else {
            return Ok(());
        };
        let from_header = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(str::trim);
        let from_query = query.and_then(|q| {
            q.split('&')
                .find_map(|kv| kv.strip_prefix("token="))
                .map(str::trim)
        });
        match from_header.or(from_query) {
            None => Err(error(
                StatusCode::UNAUTHORIZED,
                "this operator page needs the access token printed by hng at start: open the address it printed (…/?token=…) or send `Authorization: Bearer TOKEN`",
            )),
            Some(t) if constant_time_eq(t.as_bytes(), expected.as_bytes()) => Ok(()),
            Some(_) => Err(error(
                StatusCode::FORBIDDEN,
                "wrong access token: use the one hng printed at start",
            )),
        }
    }
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

fn error(status: StatusCode, msg: &str) -> Response {
    (status, axum::Json(json!({ "error": msg }))).into_response()
}

fn invalid(e: &Invalid) -> Response {
    error(
        StatusCode::from_u16(e.status()).unwrap_or(StatusCode::BAD_REQUEST),
        &e.to_string(),
    )
}

fn asset(body: &'static str, mime: &'static str) -> Response {
    let mut r = body.into_response();
    r.headers_mut()
        .insert(header::CONTENT_TYPE, HeaderValue::from_static(mime));
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}

/// The routes.
pub fn router(app: Arc<App>) -> Router {
    Router::new()
        .route(
            "/",
            get(|| async { asset(INDEX_HTML, "text/html; charset=utf-8") }),
        )
        .route(
            "/app.js",
            get(|| async { asset(APP_JS, "text/javascript; charset=utf-8") }),
        )
        .route(
            "/style.css",
            get(|| async { asset(STYLE_CSS, "text/css; charset=utf-8") }),
        )
        .route("/favicon.ico", get(|| async { StatusCode::NO_CONTENT }))
        .route("/ws", get(ws))
        .route("/api/info", get(info))
        .route("/api/order", post(order))
        .route("/api/teleop", post(teleop))
        .route("/api/designate", post(designate))
        .route("/api/module", post(module))
        .with_state(app)
}

async fn info(State(app): State<Arc<App>>, headers: HeaderMap, q: RawQuery) -> Response {
    if let Err(r) = app.auth(&headers, q.0.as_deref()) {
        return r;
    }
    axum::Json(json!({ "prefix": app.prefix, "stream": app.hub.stats() })).into_response()
}

/// Every request that gives an order: the token checked, then the body parsed and checked
/// by `parse` ([`crate::orders`]); a refusal is the response to send, and nothing is
/// published for it.
#[allow(clippy::result_large_err)]
fn checked<T>(
    app: &App,
    headers: &HeaderMap,
    q: &RawQuery,
    body: &[u8],
    parse: impl FnOnce(&[u8]) -> Result<T, Invalid>,
) -> Result<T, Response> {
    app.auth(headers, q.0.as_deref())?;
    parse(body).map_err(|e| invalid(&e))
}

/// Hands a checked order to the orders thread, which publishes it at once.
#[allow(clippy::result_large_err)]
fn publish(app: &App, out: Outgoing) -> Result<(), Response> {
    app.senders.out.send(out).map_err(|_| stopping())
}

fn stopping() -> Response {
    error(
        StatusCode::SERVICE_UNAVAILABLE,
        "the operator station is stopping",
    )
}

async fn order(
    State(app): State<Arc<App>>,
    headers: HeaderMap,
    q: RawQuery,
    body: Bytes,
) -> Response {
    let o = match checked(&app, &headers, &q, &body, |b| {
        orders::order(b, app.seq.fetch_add(1, Ordering::Relaxed))
    }) {
        Ok(o) => o,
        Err(r) => return r,
    };
    let seq = o.seq;
    let mut answers = app.hub.answers();
    answers.mark_unchanged();
    if let Err(r) = publish(&app, Outgoing::Order(Box::new(o))) {
        return r;
    }
    let wait = async {
        loop {
            if answers.changed().await.is_err() {
                return None;
            }
            if let Some((s, v)) = answers.borrow_and_update().clone()
                && s == seq
            {
                return Some(v);
            }
        }
    };
    match tokio::time::timeout(ANSWER_WAIT, wait).await {
        Ok(Some(v)) => axum::Json(json!({ "seq": seq, "answer": v })).into_response(),
        _ => (
            StatusCode::ACCEPTED,
            axum::Json(json!({
                "seq": seq,
                "answer": Value::Null,
                "note": format!("sent on the order channel; no answer from the Interface within {} s", ANSWER_WAIT.as_secs()),
            })),
        )
            .into_response(),
    }
}

// The refusal is the response itself (an axum `Response`, large by nature).
#[allow(clippy::result_large_err)]
async fn teleop(
    State(app): State<Arc<App>>,
    headers: HeaderMap,
    q: RawQuery,
    body: Bytes,
) -> Response {
    match checked(&app, &headers, &q, &body, orders::teleop)
        .and_then(|t| publish(&app, Outgoing::Teleop(t)))
    {
        Ok(()) => axum::Json(json!({ "sent": true })).into_response(),
        Err(r) => r,
    }
}

// The refusal is the response itself (an axum `Response`, large by nature).
#[allow(clippy::result_large_err)]
async fn designate(
    State(app): State<Arc<App>>,
    headers: HeaderMap,
    q: RawQuery,
    body: Bytes,
) -> Response {
    match checked(&app, &headers, &q, &body, orders::designation)
        .and_then(|d| publish(&app, Outgoing::Designate(d)).map(|()| d.beacon_id))
    {
        Ok(id) => axum::Json(json!({ "sent": true, "beacon_id": id })).into_response(),
        Err(r) => r,
    }
}

async fn module(
    State(app): State<Arc<App>>,
    headers: HeaderMap,
    q: RawQuery,
    body: Bytes,
) -> Response {
    let (req, signal) = match checked(&app, &headers, &q, &body, orders::module_command) {
        Ok(r) => r,
        Err(r) => return r,
    };
    let (reply, answer) = tokio::sync::oneshot::channel();
    let cmd = ModuleCommand {
        op: req.op,
        module: req.module,
        signal,
        reply,
    };
    if app.senders.control.send(cmd).is_err() {
        return stopping();
    }
    match tokio::time::timeout(Duration::from_secs(10), answer).await {
        Ok(Ok(Ok(done))) => axum::Json(json!({ "done": done })).into_response(),
        Ok(Ok(Err(why))) => error(StatusCode::CONFLICT, &why),
        _ => error(StatusCode::GATEWAY_TIMEOUT, "no answer from the supervisor"),
    }
}

async fn ws(
    State(app): State<Arc<App>>,
    headers: HeaderMap,
    q: RawQuery,
    upgrade: WebSocketUpgrade,
) -> Response {
    if let Err(r) = app.auth(&headers, q.0.as_deref()) {
        return r;
    }
    upgrade.on_upgrade(move |socket| client(socket, app))
}

/// One page: the latest frames on every tick, teleop messages in.
async fn client(socket: WebSocket, app: Arc<App>) {
    let hub = Arc::clone(&app.hub);
    hub.client_joined();
    let (mut tx, mut rx) = socket.split();
    let mut tick = hub.subscribe();
    let mut seen = hub.fresh();
    let hello = json!({ "t": "hello", "v": { "prefix": app.prefix } }).to_string();
    let mut alive = tx.send(Message::Text(hello.into())).await.is_ok();
    while alive {
        tokio::select! {
            changed = tick.changed() => {
                if changed.is_err() {
                    break;
                }
                let (frames, _) = hub.newer(&mut seen);
                for f in frames {
                    // Encoded once for all clients: the message shares the frame's bytes.
                    match tokio::time::timeout(SEND_TIMEOUT, tx.send(f.payload.message())).await {
                        Ok(Ok(())) => hub.sent(&f),
                        Ok(Err(_)) => { alive = false; break; }
                        Err(_) => {
                            tracing::warn!("operator page: a client took no frame for {SEND_TIMEOUT:?}: dropped");
                            hub.client_dropped();
                            alive = false;
                            break;
                        }
                    }
                }
            }
            msg = rx.next() => {
                match msg {
                    Some(Ok(Message::Text(t))) => {
                        if let Some(reply) = on_message(&app, t.as_bytes()) {
                            let m = json!({ "t": "error", "v": reply }).to_string();
                            alive = tx.send(Message::Text(m.into())).await.is_ok();
                        }
                    }
                    Some(Ok(Message::Close(_))) | None | Some(Err(_)) => alive = false,
                    Some(Ok(_)) => {}
                }
            }
        }
    }
    hub.client_left();
}

/// A message from the page on the stream: `{"teleop": {"linear_x": .., "angular_z": ..}}`
/// (the deadman's stream of commands). Returns an error text for the page, if any.
fn on_message(app: &App, text: &[u8]) -> Option<String> {
    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct In {
        teleop: orders::TeleopReq,
    }
    match serde_json::from_slice::<In>(text)
        .map_err(|e| Invalid::Malformed(format!("stream message: {e}")))
        .and_then(|m| orders::teleop_checked(m.teleop))
    {
        Ok(t) => {
            let _ = app.senders.out.send(Outgoing::Teleop(t));
            None
        }
        Err(e) => Some(e.to_string()),
    }
}
