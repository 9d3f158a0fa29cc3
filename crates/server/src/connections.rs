//! The HTTP/WebSocket accept loop: a connection cap for the server and per client address,
//! a deadline on a connection's opening bytes and a timer-driven header-read timeout
//! (hyper's is off without a timer, which `axum::serve` does not give it, and its protocol
//! detection has none at all), HTTP/2 keep-alive pings, the client's address for the handlers
//! ([`Peer`]), and a graceful shutdown that lets every open connection finish.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::extract::ConnectInfo;
use axum::serve::Listener;
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto::Builder;
use hyper_util::server::graceful::GracefulShutdown;
use tokio::net::{TcpListener, TcpStream};

use super::audit::Peer;
use super::metrics::Metrics;

/// Limits of the accept loop (from [`super::config::LimitsConfig`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ConnectionLimits {
    /// Most open connections of the listener.
    pub max_connections: usize,
    /// Most open connections from one client IP address.
    pub max_per_address: usize,
    /// Longest a client may take to send a request's headers (also the wait for the next
    /// request on an idle keep-alive connection).
    pub header_read_timeout: Duration,
}

/// Open connections, in all and per client address; a [`ConnectionPermit`] holds one place.
#[derive(Debug)]
pub(crate) struct ConnectionLimiter {
    limits: ConnectionLimits,
    open: Mutex<(usize, HashMap<IpAddr, usize>)>,
}

/// One admitted connection's place; released when dropped.
#[derive(Debug)]
pub(crate) struct ConnectionPermit {
    limiter: Arc<ConnectionLimiter>,
    ip: IpAddr,
}

/// Why a connection was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Refusal {
    /// The listener holds `max_connections`.
    ServerFull,
    /// The address holds `max_per_address`.
    AddressFull,
}

impl Refusal {
    /// The metrics label (`server`, `address`).
    pub(crate) fn label(self) -> &'static str {
        match self {
            Refusal::ServerFull => "server",
            Refusal::AddressFull => "address",
        }
    }
}

impl ConnectionLimiter {
    /// A limiter with `limits` and nothing open.
    pub(crate) fn new(limits: ConnectionLimits) -> Arc<Self> {
        Arc::new(Self {
            limits,
            open: Mutex::new((0, HashMap::new())),
        })
    }

    /// A place for a connection from `ip`, or why not.
    pub(crate) fn admit(self: &Arc<Self>, ip: IpAddr) -> Result<ConnectionPermit, Refusal> {
        let mut g = self.open.lock().unwrap_or_else(|p| p.into_inner());
        if g.0 >= self.limits.max_connections {
            return Err(Refusal::ServerFull);
        }
        let n = g.1.entry(ip).or_insert(0);
        if *n >= self.limits.max_per_address {
            return Err(Refusal::AddressFull);
        }
        *n += 1;
        g.0 += 1;
        Ok(ConnectionPermit {
            limiter: self.clone(),
            ip,
        })
    }

    /// Open connections (in all, from `ip`); the unit tests' view of the counts.
    #[cfg(test)]
    pub(crate) fn open(&self, ip: IpAddr) -> (usize, usize) {
        let g = self.open.lock().unwrap_or_else(|p| p.into_inner());
        (g.0, g.1.get(&ip).copied().unwrap_or(0))
    }
}

impl Drop for ConnectionPermit {
    fn drop(&mut self) {
        let mut g = self.limiter.open.lock().unwrap_or_else(|p| p.into_inner());
        g.0 = g.0.saturating_sub(1);
        if let Some(n) = g.1.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                g.1.remove(&self.ip);
            }
        }
    }
}

/// Interval of the HTTP/2 pings on every HTTP/2 connection (gRPC included), and how long an
/// unanswered one waits before the connection is closed.
pub(crate) const HTTP2_KEEPALIVE: Duration = Duration::from_secs(20);

/// Most concurrent HTTP/2 streams (gRPC calls) on one connection.
pub(crate) const MAX_STREAMS_PER_CONNECTION: u32 = 64;

/// Bytes a client must send before hyper's own timers take over: the length of the HTTP/2
/// preface, which hyper's protocol detection waits for without any timeout.
const OPENING_BYTES: usize = 24;

/// A connection that must send its first [`OPENING_BYTES`] within a deadline: hyper's
/// HTTP/1-or-2 detection reads them with no timer, so a client that connects and says
/// nothing (or a few bytes) would hold the connection forever. Past them, hyper's
/// header-read timeout and HTTP/2 keep-alive apply.
struct OpeningDeadline<T> {
    inner: T,
    read: usize,
    deadline: std::pin::Pin<Box<tokio::time::Sleep>>,
}

impl<T> OpeningDeadline<T> {
    fn new(inner: T, within: Duration) -> Self {
        Self {
            inner,
            read: 0,
            deadline: Box::pin(tokio::time::sleep(within)),
        }
    }
}

impl<T: tokio::io::AsyncRead + Unpin> tokio::io::AsyncRead for OpeningDeadline<T> {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        use std::task::Poll;
        let before = buf.filled().len();
        let this = &mut *self;
        match std::pin::Pin::new(&mut this.inner).poll_read(cx, buf) {
            Poll::Ready(r) => {
                this.read += buf.filled().len() - before;
                Poll::Ready(r)
            }
            Poll::Pending => {
                if this.read < OPENING_BYTES
                    && std::future::Future::poll(this.deadline.as_mut(), cx).is_ready()
                {
                    return Poll::Ready(Err(std::io::Error::new(
                        std::io::ErrorKind::TimedOut,
                        "the client sent no request in time",
                    )));
                }
                Poll::Pending
            }
        }
    }
}

impl<T: tokio::io::AsyncWrite + Unpin> tokio::io::AsyncWrite for OpeningDeadline<T> {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}

/// A TCP listener whose accepted sockets have `TCP_NODELAY` set: results are small writes
/// that must leave at once, not wait for the client's delayed ACK (Nagle's algorithm).
#[derive(Debug)]
pub(crate) struct NoDelayListener(TcpListener);

impl NoDelayListener {
    /// Wraps a bound listener.
    pub(crate) fn new(listener: TcpListener) -> Self {
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

/// Serves `app` on `listener` until `shutdown`, then waits for the open connections to
/// finish (their requests complete, WebSockets close on their own shutdown signal).
pub(crate) async fn serve<L>(
    mut listener: L,
    app: axum::Router,
    limits: ConnectionLimits,
    metrics: Arc<Metrics>,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) where
    L: Listener<Addr = SocketAddr>,
    L::Io: Unpin,
{
    let limiter = ConnectionLimiter::new(limits);
    let graceful = GracefulShutdown::new();
    let mut builder = Builder::new(TokioExecutor::new());
    builder
        .http1()
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout)
        .keep_alive(true);
    builder
        .http2()
        .timer(TokioTimer::new())
        .keep_alive_interval(Some(HTTP2_KEEPALIVE))
        .keep_alive_timeout(HTTP2_KEEPALIVE)
        .max_concurrent_streams(MAX_STREAMS_PER_CONNECTION)
        // CONNECT protocol: WebSockets over HTTP/2.
        .enable_connect_protocol();
    let builder = Arc::new(builder);
    tokio::pin!(shutdown);
    loop {
        let (io, addr) = tokio::select! {
            c = listener.accept() => c,
            _ = &mut shutdown => break,
        };
        let permit = match limiter.admit(addr.ip()) {
            Ok(p) => p,
            Err(why) => {
                metrics.inc("livereg_connections_refused_total", why.label(), 1);
                tracing::debug!(peer = %addr, reason = why.label(), "connection refused: too many open");
                drop(io);
                continue;
            }
        };
        let app = app.clone();
        let service =
            hyper::service::service_fn(move |req: hyper::Request<hyper::body::Incoming>| {
                let mut req = req.map(axum::body::Body::new);
                req.extensions_mut().insert(ConnectInfo(Peer(Some(addr))));
                tower::ServiceExt::oneshot(app.clone(), req)
            });
        let io = OpeningDeadline::new(io, limits.header_read_timeout);
        let conn = builder
            .serve_connection_with_upgrades(TokioIo::new(io), service)
            .into_owned();
        let conn = graceful.watch(conn);
        tokio::spawn(async move {
            let _permit = permit;
            if let Err(e) = conn.await {
                tracing::debug!(peer = %addr, "connection ended: {e}");
            }
        });
    }
    drop(listener);
    graceful.shutdown().await;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn places_are_counted_per_server_and_per_address_and_given_back() {
        let l = ConnectionLimiter::new(ConnectionLimits {
            max_connections: 3,
            max_per_address: 2,
            header_read_timeout: Duration::from_secs(1),
        });
        let a: IpAddr = "10.0.0.1".parse().unwrap();
        let b: IpAddr = "10.0.0.2".parse().unwrap();
        let a1 = l.admit(a).unwrap();
        let a2 = l.admit(a).unwrap();
        assert_eq!(l.admit(a).unwrap_err(), Refusal::AddressFull);
        let b1 = l.admit(b).unwrap();
        assert_eq!(l.admit(b).unwrap_err(), Refusal::ServerFull);
        assert_eq!(l.open(a), (3, 2));
        drop(a1);
        assert_eq!(l.open(a), (2, 1));
        let a3 = l.admit(a).unwrap();
        drop((a2, a3, b1));
        assert_eq!(l.open(a), (0, 0));
        assert_eq!(l.open(b), (0, 0));
    }
}
