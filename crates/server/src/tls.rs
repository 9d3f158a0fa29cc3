//! Native TLS (rustls, ring provider) for both listeners (HTTP/WebSocket, and the dedicated
//! gRPC port, which runs the same accept loop).
//!
//! - The PEM certificate chain and private key named by [`TlsConfig`] are read, and checked
//!   to belong together, before anything is bound: every failure names the file and what is
//!   wrong with it.
//! - The listener is an [`axum::serve::Listener`]: a task accepts TCP connections and
//!   performs each handshake in a task of its own, with a time limit
//!   ([`HANDSHAKE_TIMEOUT`]) and caps on the handshakes pending ([`MAX_PENDING_HANDSHAKES`],
//!   [`MAX_PENDING_HANDSHAKES_PER_ADDRESS`]), so a client that connects and never speaks (or
//!   speaks plain HTTP) does not hold up anyone else's connection. Failed handshakes are
//!   logged at debug level and dropped.
//!
//! ALPN offers `http/1.1` first (WebSocket streams need the HTTP/1.1 upgrade; rustls picks by
//! the server's order), then `h2` for gRPC clients, which offer only h2.
//!
//! Public here are those limits; the listener itself is the server's own.

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, Semaphore};
use tokio_rustls::rustls;
use tokio_rustls::rustls::pki_types::pem::PemObject;
use tokio_rustls::rustls::pki_types::{CertificateDer, PrivateKeyDer};
use tokio_rustls::server::TlsStream;
use tokio_rustls::TlsAcceptor;

use super::config::TlsConfig;

/// A client gets this long to complete its TLS handshake.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// Handshakes in progress at once; further connections wait in the kernel's backlog.
pub const MAX_PENDING_HANDSHAKES: usize = 256;

/// Most TLS handshakes in progress from one client IP address: one address that opens
/// connections and never completes them holds at most this many of the
/// [`MAX_PENDING_HANDSHAKES`] places; its further connections are closed at once.
pub const MAX_PENDING_HANDSHAKES_PER_ADDRESS: usize = 8;

/// The certificate chain and key of [`TlsConfig`], read and checked.
#[derive(Debug, Clone)]
pub(crate) struct TlsFiles {
    /// The rustls configuration of the HTTP listener (ALPN `http/1.1`).
    pub server_config: Arc<rustls::ServerConfig>,
}

impl TlsFiles {
    /// Reads and checks `config`'s files: the certificate file must hold at least one PEM
    /// certificate, the key file one PEM private key (PKCS#8, PKCS#1 or SEC1), and the key
    /// must match the first (leaf) certificate.
    pub(crate) fn load(config: &TlsConfig) -> Result<Self, String> {
        let read = |what: &str, p: &Path| {
            std::fs::read(p).map_err(|e| format!("tls.{what} {}: cannot read: {e}", p.display()))
        };
        let cert_pem = read("cert", &config.cert)?;
        let key_pem = read("key", &config.key)?;
        let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_slice_iter(&cert_pem)
            .collect::<Result<_, _>>()
            .map_err(|e| {
                format!(
                    "tls.cert {}: not a PEM certificate chain: {e}",
                    config.cert.display()
                )
            })?;
        if certs.is_empty() {
            return Err(format!(
                "tls.cert {}: no PEM certificate (-----BEGIN CERTIFICATE-----) in the file",
                config.cert.display()
            ));
        }
        let key = PrivateKeyDer::from_pem_slice(&key_pem).map_err(|e| {
            format!(
                "tls.key {}: no PEM private key (PKCS#8, PKCS#1 or SEC1): {e}",
                config.key.display()
            )
        })?;
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let mut server_config = rustls::ServerConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()
            .map_err(|e| format!("TLS protocol versions: {e}"))?
            .with_no_client_auth()
            .with_single_cert(certs, key)
            .map_err(|e| {
                format!(
                    "tls.key {} does not fit tls.cert {}: {e}",
                    config.key.display(),
                    config.cert.display()
                )
            })?;
        // HTTP/1.1 first (WebSocket upgrades need it; rustls picks by the server's order),
        // then HTTP/2 for gRPC clients, which offer only h2, on the HTTP port.
        server_config.alpn_protocols = vec![b"http/1.1".to_vec(), b"h2".to_vec()];
        Ok(Self {
            server_config: Arc::new(server_config),
        })
    }
}

/// Handshakes in progress per client address.
type PendingPerAddress = Arc<std::sync::Mutex<std::collections::HashMap<std::net::IpAddr, usize>>>;

/// One handshake's place in [`PendingPerAddress`], given back when dropped.
struct PendingHandshake {
    per_address: PendingPerAddress,
    ip: std::net::IpAddr,
}

impl Drop for PendingHandshake {
    fn drop(&mut self) {
        let mut p = self.per_address.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = p.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                p.remove(&self.ip);
            }
        }
    }
}

/// A TCP listener that yields TLS streams whose handshake completed (see the module docs).
/// Dropping it stops the accepting task.
#[derive(Debug)]
pub(crate) struct TlsListener {
    ready: mpsc::Receiver<(TlsStream<TcpStream>, SocketAddr)>,
    local: SocketAddr,
    accepting: tokio::task::JoinHandle<()>,
}

impl TlsListener {
    /// Serves TLS on `listener` with `config`; accepted sockets get `TCP_NODELAY` (results
    /// are small writes that must leave at once).
    pub(crate) fn new(
        listener: TcpListener,
        config: Arc<rustls::ServerConfig>,
    ) -> std::io::Result<Self> {
        let local = listener.local_addr()?;
        let acceptor = TlsAcceptor::from(config);
        let (tx, ready) = mpsc::channel(64);
        let permits = Arc::new(Semaphore::new(MAX_PENDING_HANDSHAKES));
        let per_address: PendingPerAddress = Arc::default();
        let accepting = tokio::spawn(async move {
            loop {
                let Ok(permit) = permits.clone().acquire_owned().await else {
                    return;
                };
                let (tcp, peer) = tokio::select! {
                    r = listener.accept() => match r {
                        Ok(c) => c,
                        Err(e) => {
                            // Out of descriptors and the like: wait, as axum's own loop does.
                            tracing::warn!("TLS listener: accept failed: {e}");
                            tokio::time::sleep(Duration::from_millis(100)).await;
                            continue;
                        }
                    },
                    _ = tx.closed() => return,
                };
                let ip = peer.ip();
                {
                    let mut p = per_address.lock().unwrap_or_else(|e| e.into_inner());
                    let n = p.entry(ip).or_insert(0);
                    if *n >= MAX_PENDING_HANDSHAKES_PER_ADDRESS {
                        tracing::debug!(%peer, "TLS handshake refused: too many pending from this address");
                        continue;
                    }
                    *n += 1;
                }
                let _ = tcp.set_nodelay(true);
                let (acceptor, tx) = (acceptor.clone(), tx.clone());
                let per_address = per_address.clone();
                tokio::spawn(async move {
                    let _permit = permit;
                    let _pending = PendingHandshake { per_address, ip };
                    match tokio::time::timeout(HANDSHAKE_TIMEOUT, acceptor.accept(tcp)).await {
                        Ok(Ok(tls)) => {
                            let _ = tx.send((tls, peer)).await;
                        }
                        Ok(Err(e)) => tracing::debug!(%peer, "TLS handshake failed: {e}"),
                        Err(_) => tracing::debug!(%peer, "TLS handshake timed out"),
                    }
                });
            }
        });
        Ok(Self {
            ready,
            local,
            accepting,
        })
    }
}

impl Drop for TlsListener {
    fn drop(&mut self) {
        self.accepting.abort();
    }
}

impl axum::serve::Listener for TlsListener {
    type Io = TlsStream<TcpStream>;
    type Addr = SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        match self.ready.recv().await {
            Some(c) => c,
            // The accepting task ended (it only does when this listener is dropped).
            None => std::future::pending().await,
        }
    }

    fn local_addr(&self) -> std::io::Result<Self::Addr> {
        Ok(self.local)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fixture(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../fixtures/tls")
            .join(name)
    }

    fn config(cert: &str, key: &str) -> TlsConfig {
        TlsConfig {
            cert: fixture(cert),
            key: fixture(key),
        }
    }

    #[test]
    fn the_fixture_pair_loads() {
        let files = TlsFiles::load(&config("server.pem", "server.key")).unwrap();
        assert_eq!(
            files.server_config.alpn_protocols,
            vec![b"http/1.1".to_vec(), b"h2".to_vec()]
        );
    }

    #[test]
    fn errors_name_the_file_and_the_fault() {
        let missing = TlsFiles::load(&config("absent.pem", "server.key")).unwrap_err();
        assert!(
            missing.contains("tls.cert") && missing.contains("absent.pem"),
            "{missing}"
        );
        // A key in the certificate's place and the other way round.
        let no_cert = TlsFiles::load(&config("server.key", "server.key")).unwrap_err();
        assert!(
            no_cert.contains("tls.cert") && no_cert.contains("no PEM certificate"),
            "{no_cert}"
        );
        let no_key = TlsFiles::load(&config("server.pem", "server.pem")).unwrap_err();
        assert!(
            no_key.contains("tls.key") && no_key.contains("private key"),
            "{no_key}"
        );
        // The CA's certificate with the server's key: a valid pair of files that do not fit.
        let mismatch = TlsFiles::load(&config("ca.pem", "server.key")).unwrap_err();
        assert!(mismatch.contains("does not fit"), "{mismatch}");
    }
}
