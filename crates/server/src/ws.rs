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
use std::time::{Duration, Instant};

use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, RawQuery, State};
use axum::response::{IntoResponse, Response};
use axum::Extension;
use futures_util::stream::{SplitSink, SplitStream};
use futures_util::{SinkExt, StreamExt};
use serde::Serialize;
use tokio::sync::mpsc;

use super::audit::Peer;
use super::auth::Owner;
use super::codec::{peek_binary_seq, ResultMessage};
use super::config::LimitsConfig;
use super::error::{ApiError, ErrorBody};
use super::result_codec::{encode_binary_result, ResultFormat};
use super::service::AppState;
use super::stream_frames::{admit_frame, next_message, submit_frame, Next, OpenStream};
use super::worker::{SessionHandle, StreamEvent, StreamSink};

/// A server → client message.
#[derive(Debug, Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub(crate) enum ServerMessage<'a> {
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
pub(crate) async fn stream(
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

/// One WebSocket stream of `handle`'s frames: the writer sends results (and pings) while
/// the reader takes frames in, until the client closes, the session goes away, the stream
/// stays idle or the server shuts down.
async fn run(
    socket: WebSocket,
    state: Arc<AppState>,
    owner: Owner,
    peer: Peer,
    handle: Arc<SessionHandle>,
    format: ResultFormat,
) {
    let stream = OpenStream::new(&state, peer, owner.name());
    let (sink, incoming) = socket.split();
    let (tx, rx) = mpsc::channel::<StreamEvent>(STREAM_BUFFER);
    let results = StreamSink {
        tx,
        skipped: Arc::new(AtomicU64::new(0)),
    };
    // Set once, by the reader, when it is the server that ends the stream.
    let close_why = Arc::new(OnceLock::<CloseWhy>::new());
    let writer = tokio::spawn(write_results(
        sink,
        rx,
        close_why.clone(),
        handle.info.length_scale,
        format,
        state.config.limits.clone(),
    ));
    stream.audit_open(Some(&handle.id), "websocket");
    read_frames(incoming, &state, &owner, &handle, &results, &close_why).await;
    // Frames in flight still hold senders: the writer ends after their results.
    drop(results);
    let _ = writer.await;
    let (code, _) = close_why
        .get()
        .copied()
        .unwrap_or_default()
        .frame(&state.config.limits);
    stream.close(Some(&handle.id), &format!("websocket, close code {code}"));
}

/// The stream's writer: each result or error as it comes (encoded in `format`, lengths in
/// scene units of `length_scale`), a ping every third of the idle timeout (a live client's
/// pongs keep the stream open, and NAT tables warm, while it sends no frame), and once every
/// sender is gone the close frame `close_why` names.
async fn write_results(
    mut sink: SplitSink<WebSocket, Message>,
    mut rx: mpsc::Receiver<StreamEvent>,
    close_why: Arc<OnceLock<CloseWhy>>,
    length_scale: f64,
    format: ResultFormat,
    limits: LimitsConfig,
) {
    let idle = Duration::from_secs_f64(limits.stream_idle_timeout_s);
    let mut ping = tokio::time::interval_at(tokio::time::Instant::now() + idle / 3, idle / 3);
    loop {
        let out = tokio::select! {
            ev = rx.recv() => match ev {
                Some(ev) => encode(&ev, length_scale, format),
                None => break,
            },
            _ = ping.tick() => Message::Ping(axum::body::Bytes::new()),
        };
        if sink.send(out).await.is_err() {
            return;
        }
    }
    let (code, reason) = close_why.get().copied().unwrap_or_default().frame(&limits);
    let _ = sink
        .send(Message::Close(Some(CloseFrame {
            code,
            reason: reason.into(),
        })))
        .await;
}

/// The stream's reader: each frame message through the shared admission
/// ([`admit_frame`]: the rate first, then the decode, off the network threads when large,
/// then the frame's content) to the session, a refusal answered on the stream. Returns when
/// the client closes, the session is gone, or `close_why` is set (the server ends it).
async fn read_frames(
    mut incoming: SplitStream<WebSocket>,
    state: &Arc<AppState>,
    owner: &Owner,
    handle: &Arc<SessionHandle>,
    results: &StreamSink,
    close_why: &OnceLock<CloseWhy>,
) {
    let mut shutdown = state.shutdown.clone();
    let idle = Duration::from_secs_f64(state.config.limits.stream_idle_timeout_s);
    loop {
        let msg = match next_message(incoming.next(), &mut shutdown, idle).await {
            Next::Message(m) => m,
            Next::ShuttingDown => {
                let _ = close_why.set(CloseWhy::ShuttingDown);
                break;
            }
            Next::Idle => {
                let _ = close_why.set(CloseWhy::Idle);
                break;
            }
        };
        let received = Instant::now();
        let (bytes, binary) = match msg {
            None | Some(Ok(Message::Close(_))) => break,
            Some(Err(e)) => {
                if is_too_big(&e) {
                    let _ = close_why.set(CloseWhy::TooBig);
                    state.reject(
                        handle,
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
        if state.registry.get(owner, &handle.id).is_err() {
            let _ = results
                .tx
                .send(StreamEvent::Error {
                    seq: 0,
                    error: state.count(ApiError::unknown_session(&handle.id)),
                })
                .await;
            break;
        }
        let seq = if binary { peek_binary_seq(&bytes) } else { 0 };
        match admit_frame(state, handle, seq, state.decode(handle, bytes, binary)).await {
            Ok(frame) => submit_frame(state, handle, frame, received, results),
            Err((seq, e)) => {
                let ev = StreamEvent::Error {
                    seq,
                    error: state.count(e),
                };
                if results.tx.send(ev).await.is_err() {
                    break;
                }
            }
        }
    }
}
