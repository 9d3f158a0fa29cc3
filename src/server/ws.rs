//! `GET /v1/sessions/{id}/stream`: a WebSocket per session. The client sends frames (JSON text
//! messages, or binary messages in the encoding of [`super::codec`]); the server pushes
//! `{"type": "result", ...}` as frames finish (newest wins; `skipped` counts the frames of this
//! stream dropped since the previous result) and `{"type": "error", "seq": n, "error": {code,
//! message}}` for a frame it refuses — the stream goes on. On shutdown the server stops reading,
//! finishes the frame in flight, sends its result and closes with code 1001. A message over
//! `limits.max_body_bytes` closes the stream with code 1009 (message too big). The server pings
//! every third of `limits.stream_idle_timeout_s`, and a stream that receives nothing (no
//! frame, no pong) for that long closes with 1000, reason "idle: …".
//!
//! Results are JSON text messages by default; `?results=binary` on the URL asks for them as
//! binary messages in the encoding of [`super::result_codec`] (errors stay JSON text).

use std::sync::atomic::AtomicU64;
use std::sync::Arc;
use std::sync::OnceLock;
use std::time::Instant;

use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, RawQuery, State};
use axum::response::{IntoResponse, Response};
use axum::Extension;
use futures_util::{SinkExt, StreamExt};
use serde::Serialize;
use tokio::sync::mpsc;

use super::audit::{self, Action, Peer};
use super::auth::Owner;
use super::codec::{peek_binary_seq, ResultMessage};
use super::error::{ApiError, ErrorBody};
use super::result_codec::{encode_binary_result, ResultFormat};
use super::service::AppState;
use super::worker::{Job, Reply, SessionHandle, StreamEvent, StreamSink};

/// A server → client message.
#[derive(Debug, Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum ServerMessage<'a> {
    /// A frame's result.
    Result(&'a ResultMessage),
    /// A refused frame (or a stream-level problem).
    Error {
        /// The frame concerned (0 when unknown).
        seq: u64,
        /// The error, in the shape of every HTTP error.
        #[serde(flatten)]
        body: ErrorBody,
    },
}

/// Why the server ends a stream, and the close frame it sends (RFC 6455 §7.4.1 codes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
enum CloseWhy {
    /// The client closed, or its session went away: 1000.
    #[default]
    Normal,
    /// The server shuts down: 1001 ("going away").
    ShuttingDown,
    /// A message over `limits.max_body_bytes`: 1009 ("message too big").
    TooBig,
    /// Nothing received (no frame, no pong) for `limits.stream_idle_timeout_s`: 1000 with
    /// the reason "idle".
    Idle,
}

impl CloseWhy {
    /// The close code and reason; `limits` gives the numbers the reasons quote.
    fn frame(self, limits: &super::config::LimitsConfig) -> (u16, String) {
        match self {
            CloseWhy::Normal => (1000, String::new()),
            CloseWhy::ShuttingDown => (1001, "server shutting down".into()),
            CloseWhy::TooBig => (
                1009,
                format!(
                    "message larger than the limit of {} bytes",
                    limits.max_body_bytes
                ),
            ),
            CloseWhy::Idle => (
                1000,
                format!(
                    "idle: nothing received for {} s",
                    limits.stream_idle_timeout_s
                ),
            ),
        }
    }
}

/// Whether a read error is a message or frame over the size limit (tungstenite's capacity
/// error, which axum passes on only as text: "Space limit exceeded: Message too long …").
fn is_too_big(e: &axum::Error) -> bool {
    let text = e.to_string();
    text.contains("Space limit exceeded") || text.contains("too long")
}

/// Results waiting to be written per stream (beyond this a client that does not read loses
/// results, counted as skipped).
const STREAM_BUFFER: usize = 8;

/// Upgrades to a WebSocket for the session `id` of the caller (404 before the upgrade when
/// it is not theirs).
pub async fn stream(
    State(state): State<Arc<AppState>>,
    Extension(owner): Extension<Owner>,
    Extension(peer): Extension<Peer>,
    Path(id): Path<String>,
    RawQuery(query): RawQuery,
    ws: Result<WebSocketUpgrade, axum::extract::ws::rejection::WebSocketUpgradeRejection>,
) -> Response {
    let handle = match state.session(&owner, &id) {
        Ok(h) => h,
        Err(e) => return state.count(e).into_response(),
    };
    if state.is_draining() {
        return state.count(ApiError::shutting_down()).into_response();
    }
    let format = match ResultFormat::from_query(query.as_deref()) {
        Ok(f) => f,
        Err(e) => return state.count(e).into_response(),
    };
    let ws = match ws {
        Ok(ws) => ws,
        Err(e) => {
            return state
                .count(ApiError::new(
                    axum::http::StatusCode::UPGRADE_REQUIRED,
                    "websocket_required",
                    format!("this endpoint is a WebSocket: {e}"),
                ))
                .into_response()
        }
    };
    let limit = state.config.limits.max_body_bytes;
    ws.max_message_size(limit)
        .max_frame_size(limit)
        .on_upgrade(move |socket| run(socket, state, owner, peer, handle, format))
}

fn error_text(e: impl std::fmt::Display) -> String {
    let body = ApiError::internal(format!("cannot encode: {e}")).body();
    serde_json::to_string(&ServerMessage::Error { seq: 0, body }).unwrap_or_else(|_| {
        r#"{"type":"error","seq":0,"error":{"code":"internal","message":"cannot encode"}}"#.into()
    })
}

fn encode(ev: &StreamEvent, length_scale: f64, format: ResultFormat) -> Message {
    let text = match ev {
        StreamEvent::Result(c) => {
            let msg = ResultMessage::new(
                c.seq,
                c.skipped,
                c.server_ms,
                c.queue_ms,
                &c.result,
                length_scale,
            );
            if format == ResultFormat::Binary {
                return match encode_binary_result(&msg) {
                    Ok(b) => Message::Binary(b.into()),
                    Err(e) => Message::Text(error_text(e).into()),
                };
            }
            serde_json::to_string(&ServerMessage::Result(&msg))
        }
        StreamEvent::Error { seq, error } => serde_json::to_string(&ServerMessage::Error {
            seq: *seq,
            body: error.body(),
        }),
    };
    Message::Text(text.unwrap_or_else(error_text).into())
}

async fn run(
    socket: WebSocket,
    state: Arc<AppState>,
    owner: Owner,
    peer: Peer,
    handle: Arc<SessionHandle>,
    format: ResultFormat,
) {
    let _guard = state.stream_guard();
    let (mut sink, mut incoming) = socket.split();
    let (tx, mut rx) = mpsc::channel::<StreamEvent>(STREAM_BUFFER);
    let skipped = Arc::new(AtomicU64::new(0));
    let scale = handle.info.length_scale;
    let mut shutdown = state.shutdown.clone();
    // Set once, by the reader, when it is the server that ends the stream.
    let close_why = Arc::new(OnceLock::<CloseWhy>::new());
    let cw = close_why.clone();
    let limits = state.config.limits.clone();
    let idle = std::time::Duration::from_secs_f64(limits.stream_idle_timeout_s);
    let writer = tokio::spawn(async move {
        // Pings every third of the idle timeout: a live client's pongs keep the stream open
        // (and NAT tables warm) while it sends no frame.
        let mut ping = tokio::time::interval_at(tokio::time::Instant::now() + idle / 3, idle / 3);
        loop {
            let out = tokio::select! {
                ev = rx.recv() => match ev {
                    Some(ev) => encode(&ev, scale, format),
                    None => break,
                },
                _ = ping.tick() => Message::Ping(axum::body::Bytes::new()),
            };
            if sink.send(out).await.is_err() {
                return;
            }
        }
        let (code, reason) = cw.get().copied().unwrap_or_default().frame(&limits);
        let _ = sink
            .send(Message::Close(Some(CloseFrame {
                code,
                reason: reason.into(),
            })))
            .await;
    });
    audit::event(
        Action::OpenStream,
        "ok",
        peer,
        Some(owner.name()),
        Some(&handle.id),
        "websocket",
    );
    let id = handle.id.clone();
    let mut last_seen = Instant::now();
    loop {
        let msg = tokio::select! {
            m = incoming.next() => m,
            _ = shutdown.wait_for(|s| *s) => {
                let _ = close_why.set(CloseWhy::ShuttingDown);
                break;
            }
            _ = tokio::time::sleep_until((last_seen + idle).into()) => {
                let _ = close_why.set(CloseWhy::Idle);
                break;
            }
        };
        let received = Instant::now();
        last_seen = received;
        let decoded = match msg {
            None | Some(Ok(Message::Close(_))) => break,
            Some(Err(e)) => {
                if is_too_big(&e) {
                    let _ = close_why.set(CloseWhy::TooBig);
                    state.reject(
                        &handle,
                        &ApiError::too_large("payload_too_large", e.to_string()),
                    );
                    tracing::info!(session = %handle.id, error = %e, "stream closed: message too big");
                }
                break;
            }
            Some(Ok(Message::Ping(_) | Message::Pong(_))) => continue,
            Some(Ok(Message::Text(t))) => (axum::body::Bytes::from(t), false),
            Some(Ok(Message::Binary(b))) => (b, true),
        };
        if state.registry.get(&owner, &id).is_err() {
            let _ = tx
                .send(StreamEvent::Error {
                    seq: 0,
                    error: state.count(ApiError::unknown_session(&id)),
                })
                .await;
            break;
        }
        // The rate first (a flood costs a counter, not a decode), then the decode (large
        // frames off the network threads), then the frame's content.
        let (bytes, binary) = decoded;
        let refused = match state.admit_rate(&handle) {
            Err(e) => Err((if binary { peek_binary_seq(&bytes) } else { 0 }, e)),
            Ok(()) => match state.decode(&handle, bytes, binary).await {
                Err(e) => Err((0, e)),
                Ok(f) => match state.admit_decoded(&handle, &f) {
                    Ok(()) => Ok(f),
                    Err(e) => Err((f.seq, e)),
                },
            },
        };
        let incoming_frame = match refused {
            Ok(f) => f,
            Err((seq, e)) => {
                let ev = StreamEvent::Error {
                    seq,
                    error: state.count(e),
                };
                if tx.send(ev).await.is_err() {
                    break;
                }
                continue;
            }
        };
        handle.submit(
            Job {
                incoming: incoming_frame,
                received,
                reply: Reply::Stream(StreamSink {
                    tx: tx.clone(),
                    skipped: skipped.clone(),
                }),
            },
            &state.metrics,
        );
    }
    // Frames in flight still hold senders: the writer ends after their results.
    drop(tx);
    let _ = writer.await;
    audit::event(
        Action::CloseStream,
        "ok",
        peer,
        Some(owner.name()),
        Some(&handle.id),
        &format!(
            "websocket, close code {}",
            close_why
                .get()
                .copied()
                .unwrap_or_default()
                .frame(&state.config.limits)
                .0
        ),
    );
}
