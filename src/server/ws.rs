//! `GET /v1/sessions/{id}/stream`: a WebSocket per session. The client sends frames (JSON text
//! messages, or binary messages in the encoding of [`super::codec`]); the server pushes
//! `{"type": "result", ...}` as frames finish (newest wins; `skipped` counts the frames of this
//! stream dropped since the previous result) and `{"type": "error", "seq": n, "error": {code,
//! message}}` for a frame it refuses — the stream goes on. On shutdown the server stops reading,
//! finishes the frame in flight, sends its result and closes with code 1001. A message over
//! `limits.max_body_bytes` closes the stream with code 1009 (message too big).
//!
//! Results are JSON text messages by default; `?results=binary` on the URL asks for them as
//! binary messages in the encoding of [`super::result_codec`] (errors stay JSON text).

use std::sync::atomic::{AtomicU16, AtomicU64, Ordering};
use std::sync::Arc;
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
use super::codec::{decode_binary_frame, decode_json_frame, ResultMessage};
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

/// Close code of a stream the client or the server ended normally (RFC 6455 §7.4.1).
const CLOSE_NORMAL: u16 = 1000;
/// Close code when the server shuts down ("going away").
const CLOSE_GOING_AWAY: u16 = 1001;
/// Close code for a message larger than `limits.max_body_bytes` ("message too big").
const CLOSE_TOO_BIG: u16 = 1009;

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
    let close_code = Arc::new(AtomicU16::new(CLOSE_NORMAL));
    let cc = close_code.clone();
    let limit = state.config.limits.max_body_bytes;
    let writer = tokio::spawn(async move {
        while let Some(ev) = rx.recv().await {
            if sink.send(encode(&ev, scale, format)).await.is_err() {
                return;
            }
        }
        let code = cc.load(Ordering::Relaxed);
        let reason = match code {
            CLOSE_GOING_AWAY => "server shutting down".to_string(),
            CLOSE_TOO_BIG => format!("message larger than the limit of {limit} bytes"),
            _ => String::new(),
        };
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
    loop {
        let msg = tokio::select! {
            m = incoming.next() => m,
            _ = shutdown.wait_for(|s| *s) => {
                close_code.store(CLOSE_GOING_AWAY, Ordering::Relaxed);
                break;
            }
        };
        let received = Instant::now();
        let decoded = match msg {
            None | Some(Ok(Message::Close(_))) => break,
            Some(Err(e)) => {
                if is_too_big(&e) {
                    close_code.store(CLOSE_TOO_BIG, Ordering::Relaxed);
                    state.reject(
                        &handle,
                        &ApiError::too_large("payload_too_large", e.to_string()),
                    );
                    tracing::info!(session = %handle.id, error = %e, "stream closed: message too big");
                }
                break;
            }
            Some(Ok(Message::Ping(_) | Message::Pong(_))) => continue,
            Some(Ok(Message::Text(t))) => decode_json_frame(t.as_bytes()),
            Some(Ok(Message::Binary(b))) => {
                decode_binary_frame(&b, state.config.limits.max_frame_points)
            }
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
        let refused = match decoded {
            Err(e) => {
                state.reject(&handle, &e);
                Err((0, e))
            }
            Ok(f) => match state.admit(&handle, &f) {
                Ok(()) => Ok(f),
                Err(e) => Err((f.seq, e)),
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
            close_code.load(Ordering::Relaxed)
        ),
    );
}
