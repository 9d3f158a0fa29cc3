//! Audit events: one structured log line per authentication failure and per session
//! operation (create, close, reset, stream open and close, retirement), with the peer
//! address, the token's name (never the token), the session id, the action and its outcome.
//!
//! Events go through `tracing` with the target [`TARGET`], so that an operator can route them
//! apart (`log_filter = "info,livereg::audit=info"`); with `log_format = "json"` each is one
//! JSON object whose `fields` hold `audit`, `action`, `outcome`, `peer`, `token`, `session`
//! and `detail` (docs/server.md, "Audit events").

use std::net::SocketAddr;

/// The `tracing` target of every audit event.
pub(crate) const TARGET: &str = "livereg::audit";

/// The client's address of a request, as the transports know it (axum's connection info,
/// tonic's remote address); `None` where the transport does not say (in-process tests).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Peer(pub Option<SocketAddr>);

impl Peer {
    /// The address as text, `-` when unknown.
    pub(crate) fn shown(&self) -> String {
        self.0.map_or_else(|| "-".to_string(), |a| a.to_string())
    }
}

/// What was attempted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Action {
    /// A request's bearer token was checked (only failures are logged: successes are the
    /// operations that follow).
    Authenticate,
    /// `POST /v1/sessions`, gRPC `CreateSession`.
    CreateSession,
    /// `DELETE /v1/sessions/{id}`, gRPC `CloseSession`.
    CloseSession,
    /// `POST /v1/sessions/{id}/reset`.
    ResetSession,
    /// A WebSocket or gRPC stream opened on a session.
    OpenStream,
    /// A stream ended.
    CloseStream,
    /// The server retired a session (idle timeout, shutdown).
    RetireSession,
}

impl Action {
    /// The action's name in the log (`create_session`, …).
    pub(crate) fn name(self) -> &'static str {
        match self {
            Action::Authenticate => "authenticate",
            Action::CreateSession => "create_session",
            Action::CloseSession => "close_session",
            Action::ResetSession => "reset_session",
            Action::OpenStream => "open_stream",
            Action::CloseStream => "close_stream",
            Action::RetireSession => "retire_session",
        }
    }
}

/// One audit event: `outcome` is `ok` or the refusal's error code (`unauthorized`,
/// `invalid_scene`, …); `detail` says more for people (an error message, a close reason).
pub(crate) fn event(
    action: Action,
    outcome: &str,
    peer: Peer,
    token: Option<&str>,
    session: Option<&str>,
    detail: &str,
) {
    let peer = peer.shown();
    let token = token.unwrap_or("-");
    let session = session.unwrap_or("-");
    let action = action.name();
    if outcome == "ok" {
        tracing::info!(target: TARGET, audit = true, action, outcome, peer, token, session, detail, "audit");
    } else {
        tracing::warn!(target: TARGET, audit = true, action, outcome, peer, token, session, detail, "audit");
    }
}

/// The outcome field for a result: `ok`, or the error's code.
pub(crate) fn outcome<T>(r: &Result<T, super::error::ApiError>) -> &'static str {
    match r {
        Ok(_) => "ok",
        Err(e) => e.code,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peers_and_actions_have_stable_names() {
        assert_eq!(Peer(None).shown(), "-");
        let a: SocketAddr = "10.1.2.3:4567".parse().unwrap();
        assert_eq!(Peer(Some(a)).shown(), "10.1.2.3:4567");
        let names: Vec<&str> = [
            Action::Authenticate,
            Action::CreateSession,
            Action::CloseSession,
            Action::ResetSession,
            Action::OpenStream,
            Action::CloseStream,
            Action::RetireSession,
        ]
        .iter()
        .map(|a| a.name())
        .collect();
        let mut unique = names.clone();
        unique.dedup();
        assert_eq!(unique.len(), names.len());
        assert!(names
            .iter()
            .all(|n| n.chars().all(|c| c.is_ascii_lowercase() || c == '_')));
        let ok: Result<(), super::super::error::ApiError> = Ok(());
        assert_eq!(outcome(&ok), "ok");
        let e: Result<(), _> = Err(super::super::error::ApiError::unauthorized("x"));
        assert_eq!(outcome(&e), "unauthorized");
    }
}
