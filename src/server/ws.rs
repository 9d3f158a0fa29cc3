//! `GET /v1/sessions/{id}/stream`: a WebSocket per session. The client sends frames (JSON text
//! messages, or binary messages in the encoding of [`super::codec`]); the server pushes
//! `{"type": "result", ...}` as frames finish (newest wins; `skipped` counts the frames of this
//! stream dropped since the previous result) and `{"type": "error", "seq": n, "error": {code,
//! message}}` for a frame it refuses — the stream goes on. On shutdown the server stops reading,
//! finishes the frame in flight, sends its result and closes with code 1001.
//!
//! Results are JSON text messages by default; `?results=binary` on the URL asks for them as
//! binary messages in the encoding of [`super::result_codec`] (errors stay JSON text).

use std::sync::atomic::AtomicU64;
use std::sync::Arc;
use std::time::Instant;

use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, RawQuery, State};
use axum::response::{IntoResponse, Response};
use axum::Extension;
use futures_util::{SinkExt, StreamExt};
use serde::Serialize;
use tokio::sync::mpsc;

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

/// Results waiting to be written per stream (beyond this a client that does not read loses
/// results, counted as skipped).
const STREAM_BUFFER: usize = 8;

/// Upgrades to a WebSocket for the session `id` of the caller (404 before the upgrade when
/// it is not theirs).
pub async fn stream(
    State(state): State<Arc<AppState>>,
    Extension(owner): Extension<Owner>,
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
        .on_upgrade(move |socket| run(socket, state, owner, handle, format))
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
    handle: Arc<SessionHandle>,
    format: ResultFormat,
) {
    let _guard = state.stream_guard();
    let (mut sink, mut incoming) = socket.split();
    let (tx, mut rx) = mpsc::channel::<StreamEvent>(STREAM_BUFFER);
    let skipped = Arc::new(AtomicU64::new(0));
    let scale = handle.info.length_scale;
    let mut shutdown = state.shutdown.clone();
    let going_away = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let ga = going_away.clone();
    let writer = tokio::spawn(async move {
        while let Some(ev) = rx.recv().await {
            if sink.send(encode(&ev, scale, format)).await.is_err() {
                return;
            }
        }
        let code = if ga.load(std::sync::atomic::Ordering::Relaxed) {
            1001
        } else {
            1000
        };
        let _ = sink
            .send(Message::Close(Some(CloseFrame {
                code,
                reason: if code == 1001 {
                    "server shutting down".into()
                } else {
                    "".into()
                },
            })))
            .await;
    });
    tracing::info!(session = %handle.id, owner = owner.name(), results = ?format, "stream opened");
    let id = handle.id.clone();
    loop {
        let msg = tokio::select! {
            m = incoming.next() => m,
            _ = shutdown.wait_for(|s| *s) => {
                going_away.store(true, std::sync::atomic::Ordering::Relaxed);
                break;
            }
        };
        let received = Instant::now();
        let decoded = match msg {
            None | Some(Err(_)) | Some(Ok(Message::Close(_))) => break,
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
    tracing::info!(session = %handle.id, owner = owner.name(), "stream closed");
}
