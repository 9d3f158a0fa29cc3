//! The plain-TCP listener of the HTTP/WebSocket server, and the client address each accepted
//! connection carries into the handlers ([`Peer`], for audit events).

use std::net::SocketAddr;

use axum::extract::connect_info::Connected;
use axum::serve::{IncomingStream, Listener};
use tokio::net::{TcpListener, TcpStream};

use super::audit::Peer;
use super::tls::TlsListener;

/// A TCP listener whose accepted sockets have `TCP_NODELAY` set: results are small writes
/// that must leave at once, not wait for the client's delayed ACK (Nagle's algorithm).
#[derive(Debug)]
pub struct NoDelayListener(TcpListener);

impl NoDelayListener {
    /// Wraps a bound listener.
    pub fn new(listener: TcpListener) -> Self {
        Self(listener)
    }
}

impl Listener for NoDelayListener {
    type Io = TcpStream;
    type Addr = SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        // axum's own accept loop for TCP (it waits out transient errors such as EMFILE).
        let (tcp, addr) = Listener::accept(&mut self.0).await;
        let _ = tcp.set_nodelay(true);
        (tcp, addr)
    }

    fn local_addr(&self) -> std::io::Result<Self::Addr> {
        self.0.local_addr()
    }
}

impl Connected<IncomingStream<'_, NoDelayListener>> for Peer {
    fn connect_info(stream: IncomingStream<'_, NoDelayListener>) -> Self {
        Peer(Some(*stream.remote_addr()))
    }
}

impl Connected<IncomingStream<'_, TlsListener>> for Peer {
    fn connect_info(stream: IncomingStream<'_, TlsListener>) -> Self {
        Peer(Some(*stream.remote_addr()))
    }
}
