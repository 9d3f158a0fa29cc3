//! The way every stream transport (WebSocket, gRPC, OpenIGTLink) takes frames into a session,
//! written once: the stream's guard and audit trail, the wait for the next message (or the
//! server's shutdown, or the idle timeout), the admission of a frame (the rate first, so a
//! flood costs a counter and not a decode; then the decode; then the frame's content) and its
//! submission to the session's worker, whose result goes back on the stream.
//!
//! Each transport keeps what is its own: how a message is read and decoded, how a refusal and
//! a result are written, how the stream closes.

use std::future::Future;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::watch;

use super::audit::{self, Action, Peer};
use super::codec::Incoming;
use super::error::ApiError;
use super::service::{AppState, StreamGuard};
use super::worker::{Job, Reply, SessionHandle, StreamSink};

/// What ended the wait for a stream's next message.
#[derive(Debug)]
pub(crate) enum Next<T> {
    /// The read finished with this.
    Message(T),
    /// The server is shutting down.
    ShuttingDown,
    /// Nothing arrived within the idle timeout.
    Idle,
}

/// Waits for `read`, the server's `shutdown` or `idle` to pass, whichever comes first.
pub(crate) async fn next_message<T>(
    read: impl Future<Output = T>,
    shutdown: &mut watch::Receiver<bool>,
    idle: Duration,
) -> Next<T> {
    tokio::select! {
        m = read => Next::Message(m),
        _ = shutdown.wait_for(|s| *s) => Next::ShuttingDown,
        _ = tokio::time::sleep(idle) => Next::Idle,
    }
}

/// A frame refused before registration: the sequence number to answer with (0 when the
/// frame's own is not known) and why.
pub(crate) type Refusal = (u64, ApiError);

/// Admits one frame of `handle`: [`AppState::admit_rate`] (refused with `seq_if_rate_refused`,
/// the sequence number the transport could read without decoding), then `decode` (refused
/// with 0; it counts its own failures), then [`AppState::admit_decoded`] (refused with the
/// frame's sequence number). `decode` runs only when the rate admits the frame.
pub(crate) async fn admit_frame(
    state: &AppState,
    handle: &SessionHandle,
    seq_if_rate_refused: u64,
    decode: impl Future<Output = Result<Incoming, ApiError>>,
) -> Result<Incoming, Refusal> {
    state
        .admit_rate(handle)
        .map_err(|e| (seq_if_rate_refused, e))?;
    let incoming = decode.await.map_err(|e| (0, e))?;
    state
        .admit_decoded(handle, &incoming)
        .map_err(|e| (incoming.seq, e))?;
    Ok(incoming)
}

/// Submits an admitted frame, received at `received`, to `handle`'s worker; its result (or
/// its skip, when a newer frame replaces it) goes to `sink`.
pub(crate) fn submit_frame(
    state: &AppState,
    handle: &SessionHandle,
    incoming: Incoming,
    received: Instant,
    sink: &StreamSink,
) {
    handle.submit(
        Job {
            incoming,
            received,
            reply: Reply::Stream(sink.clone()),
        },
        &state.metrics,
    );
}

/// An open stream: counted while it lives (shutdown waits for it) and audited as it opens
/// and closes, with its transport named in every audit line.
pub(crate) struct OpenStream {
    _guard: StreamGuard,
    peer: Peer,
    token: Arc<str>,
}

impl OpenStream {
    /// Counts the stream open; nothing is audited until [`OpenStream::audit_open`].
    pub(crate) fn new(state: &Arc<AppState>, peer: Peer, token: &str) -> Self {
        Self {
            _guard: state.stream_guard(),
            peer,
            token: Arc::from(token),
        }
    }

    /// Audits the stream (or one of its sessions) opening: `detail` names the transport.
    pub(crate) fn audit_open(&self, session: Option<&str>, detail: &str) {
        audit::event(
            Action::OpenStream,
            "ok",
            self.peer,
            Some(&self.token),
            session,
            detail,
        );
    }

    /// Audits the stream closing (`detail`: the transport and how it closed) and lets the
    /// shutdown stop waiting for it.
    pub(crate) fn close(self, session: Option<&str>, detail: &str) {
        audit::event(
            Action::CloseStream,
            "ok",
            self.peer,
            Some(&self.token),
            session,
            detail,
        );
    }
}
