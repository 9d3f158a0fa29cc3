//! livereg-server: the registration server (`livereg serve`): HTTP + WebSocket (axum), gRPC
//! (tonic) and OpenIGTLink front ends over one set of sessions, for AR displays streaming point
//! clouds.
//!
//! What it offers:
//! - [`start`]: checks a [`ServerConfig`], binds the listeners and returns a [`RunningServer`]
//!   (its addresses, a [`ShutdownHandle`], its metrics);
//! - [`config`]: the configuration from file, environment and flags ([`ServerConfig`], its
//!   limits, tokens and TLS files);
//! - [`codec`]: the frames clients send (JSON, the compact binary encoding) and the JSON result
//!   ([`codec::ResultMessage`]); [`result_codec`]: the compact binary result encoding of
//!   WebSocket streams;
//! - [`http::ROUTES`]: the HTTP API's routes; [`SESSION_HEADER`]: the header naming a session;
//!   [`proto`]: the gRPC messages, server and client;
//! - [`openigtlink`]: the OpenIGTLink protocol codec, which the OpenIGTLink listener speaks;
//! - [`tls`]: the handshake limits of the TLS listeners;
//! - [`ApiError`]: the API's one error type, with its JSON shape [`ErrorBody`].
//!
//! The rest is the server's own: bearer tokens checked in constant time, sizes and rates, the
//! session registry (ownership, random ids), scenes uploaded with their files, per-session
//! registration on the blocking pool with a newest-wins mailbox, the operations and shared
//! state, the HTTP, WebSocket, gRPC and OpenIGTLink front ends, the Prometheus metrics and the
//! HTTP API's OpenAPI document.
//!
//! The server stands on the scene layer (`livereg-scene`: scenes, result records,
//! recordings), the registration sessions (`livereg-registration`) and the mesh reader
//! (`livereg-fem`, to check uploaded meshes before building anything); nothing below it
//! imports it.
//!
//! # Starting a server
//!
//! ```no_run
//! # async fn run() -> Result<(), Box<dyn std::error::Error>> {
//! use livereg_server::ServerConfig;
//!
//! let config = ServerConfig::default();
//! let server = livereg_server::start(config).await?;
//! println!("HTTP and WebSocket on {}", server.http_addr);
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]
// The public API is what the crate root and its public modules offer: an item is `pub` only
// when a user of the crate can reach it, and every type a public item shows can be named.
#![warn(unnameable_types, unreachable_pub)]

// The layers below: their modules keep the paths the server's code names them by.
#[cfg(test)]
use livereg_fem::random;
use livereg_fem::{geometry, mesh};
use livereg_registration::session;
use livereg_scene::{evaluation, recording, scene, simulation};

pub(crate) mod audit;
pub(crate) mod auth;
pub mod codec;
pub mod config;
pub(crate) mod connections;
pub(crate) mod error;
pub(crate) mod grpc;
pub mod http;
pub(crate) mod igtl;
pub(crate) mod limits;
pub(crate) mod memory_budget;
pub(crate) mod metrics;
pub(crate) mod openapi;
pub mod openigtlink;
pub(crate) mod registry;
pub mod result_codec;
pub(crate) mod service;
pub(crate) mod slots;
pub(crate) mod stream_frames;
pub mod tls;
pub(crate) mod upload;
pub(crate) mod worker;
pub(crate) mod ws;

/// Generated gRPC messages, server and client of `proto/livereg/v1/registration.proto`.
#[allow(missing_docs, clippy::all, clippy::pedantic, rustdoc::all)]
pub mod proto {
    tonic::include_proto!("livereg.v1");
}

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::watch;
use tokio::task::JoinHandle;

pub use config::ServerConfig;
pub use error::{ApiError, ErrorBody, ErrorDetail};
pub use registry::SESSION_HEADER;
use service::AppState;

/// Triggers a graceful shutdown: new work is refused (503 / `UNAVAILABLE`), frames in flight
/// finish and are delivered, streams close (WebSocket code 1001), then the servers stop.
#[derive(Debug, Clone)]
pub struct ShutdownHandle {
    tx: Arc<watch::Sender<bool>>,
    state: Arc<AppState>,
}

impl ShutdownHandle {
    /// Starts the shutdown (idempotent).
    pub fn trigger(&self) {
        self.state.start_draining();
        self.tx.send_replace(true);
    }
}

/// A started server: its bound addresses and how to stop it.
#[derive(Debug)]
pub struct RunningServer {
    /// Where HTTP and WebSocket listen.
    pub http_addr: SocketAddr,
    /// Where gRPC listens (`None` when off).
    pub grpc_addr: Option<SocketAddr>,
    /// Where OpenIGTLink listens (`None` when off).
    pub igtl_addr: Option<SocketAddr>,
    handle: ShutdownHandle,
    state: Arc<AppState>,
    tasks: Vec<JoinHandle<Result<(), String>>>,
}

impl RunningServer {
    /// A handle that triggers the shutdown (e.g. from a signal handler).
    pub fn shutdown_handle(&self) -> ShutdownHandle {
        self.handle.clone()
    }

    /// The text exposition of the server's metrics: what `GET /metrics` serves, without the
    /// registration slots' and draining gauges it adds. For tests and tools.
    pub fn metrics_text(&self) -> String {
        self.state.metrics.render()
    }

    /// The value of the metrics counter `family` with label value `label` (0 when never
    /// incremented), for tests and tools.
    pub fn counter(&self, family: &'static str, label: &str) -> u64 {
        self.state.metrics.counter(family, label)
    }

    /// Waits until a shutdown is triggered, then drains: closes every session, lets the frames
    /// in flight finish and every session worker end, those of sessions closed earlier
    /// included, so their recordings are finished (all within `shutdown_grace_s`), and stops
    /// the servers.
    pub async fn run_until_stopped(self) -> Result<(), String> {
        let mut rx = self.handle.tx.subscribe();
        let _ = rx.wait_for(|s| *s).await;
        let state = self.state.clone();
        let grace = Duration::from_secs(state.config.shutdown_grace_s);
        tracing::info!("shutting down: finishing frames in flight");
        let sessions = state.registry.drain();
        for h in &sessions {
            state.retire(h, "shutdown");
        }
        let drain = async {
            for h in &sessions {
                h.wait_ended().await;
            }
            state.streams_closed().await;
            state.workers_ended().await;
        };
        if tokio::time::timeout(grace, drain).await.is_err() {
            tracing::warn!("shutdown grace of {grace:?} exceeded; stopping anyway");
        }
        let mut result = Ok(());
        for t in self.tasks {
            match tokio::time::timeout(grace, t).await {
                Ok(Ok(Ok(()))) => {}
                Ok(Ok(Err(e))) => result = Err(e),
                Ok(Err(e)) => result = Err(format!("server task: {e}")),
                Err(_) => tracing::warn!("a server did not stop within the grace period"),
            }
        }
        tracing::info!("stopped");
        result
    }

    /// Triggers the shutdown and waits for it to finish.
    pub async fn shutdown(self) -> Result<(), String> {
        self.handle.trigger();
        self.run_until_stopped().await
    }
}

/// Validates `config`, binds the HTTP (and gRPC) listeners and starts serving on the current
/// tokio runtime. Port 0 binds a free port; the bound addresses are returned.
pub async fn start(config: ServerConfig) -> Result<RunningServer, String> {
    config.validate()?;
    let tokens = config.all_tokens()?;
    let tls = config.tls.as_ref().map(tls::TlsFiles::load).transpose()?;
    create_data_dirs(&config)?;
    let (tx, rx) = watch::channel(false);
    let auth = auth::Authenticator::new(&tokens, config.insecure_loopback_dev);
    let state = Arc::new(AppState::new(config.clone(), auth, rx.clone()));
    let handle = ShutdownHandle {
        tx: Arc::new(tx),
        state: state.clone(),
    };
    let signal = |mut rx: watch::Receiver<bool>| async move {
        let _ = rx.wait_for(|s| *s).await;
    };
    let listener = tokio::net::TcpListener::bind(config.bind)
        .await
        .map_err(|e| format!("cannot listen on {} (bind): {e}", config.bind))?;
    let http_addr = listener
        .local_addr()
        .map_err(|e| format!("bound address: {e}"))?;
    let mut tasks = Vec::new();
    let grpc_service =
        proto::registration_server::RegistrationServer::new(grpc::GrpcService::new(state.clone()))
            .max_decoding_message_size(config.limits.max_body_bytes)
            .max_encoding_message_size(usize::MAX);
    let mut app = http::router(state.clone());
    let grpc_path = {
        use tonic::server::NamedService;
        format!(
            "/{}/{{*method}}",
            proto::registration_server::RegistrationServer::<grpc::GrpcService>::NAME
        )
    };
    let grpc_route = {
        use tower::ServiceExt;
        grpc_service.map_request(|r: axum::extract::Request| r.map(tonic::body::Body::new))
    };
    if config.grpc_bind.is_some() {
        // gRPC also on the HTTP port (HTTP/2, told apart by its path): one address per
        // backend, so that a proxy hashing sessions onto backends sends a session's HTTP,
        // WebSocket and gRPC requests to the same one (docs/server.md, "Scaling out").
        app = app.route_service(&grpc_path, grpc_route.clone());
    }
    let http_tls = tls.as_ref().map(|t| t.server_config.clone());
    let sig = signal(rx.clone());
    let conn_limits = connections::ConnectionLimits {
        max_connections: config.limits.max_connections,
        max_per_address: config.limits.max_connections_per_address,
        header_read_timeout: Duration::from_secs_f64(config.limits.header_read_timeout_s),
    };
    let m = state.metrics.clone();
    tasks.push(tokio::spawn(async move {
        serve_http(listener, app, http_tls, conn_limits, m, sig).await
    }));
    let mut grpc_addr = None;
    if let Some(addr) = config.grpc_bind {
        let l = tokio::net::TcpListener::bind(addr)
            .await
            .map_err(|e| format!("cannot listen on {addr} (grpc_bind): {e}"))?;
        grpc_addr = Some(l.local_addr().map_err(|e| format!("bound address: {e}"))?);
        // The dedicated gRPC port runs the same accept loop as the HTTP port (connection
        // caps, opening deadline, HTTP/2 keep-alive pings, TLS with ALPN h2), serving only
        // the gRPC service.
        let grpc_app = axum::Router::new().route_service(&grpc_path, grpc_route.clone());
        let sig = signal(rx.clone());
        let (m, grpc_tls) = (
            state.metrics.clone(),
            tls.as_ref().map(|t| t.server_config.clone()),
        );
        tasks.push(tokio::spawn(async move {
            serve_http(l, grpc_app, grpc_tls, conn_limits, m, sig).await
        }));
    }
    let igtl_addr = match config.igtl_bind {
        Some(addr) => {
            let (bound, task) =
                start_igtl(addr, &config, &state, tls.as_ref(), conn_limits, rx.clone()).await?;
            tasks.push(task);
            Some(bound)
        }
        None => None,
    };
    let policy = config.recordings_retention();
    if config.record && policy.is_active() {
        tokio::spawn(keep_recordings_within(
            state.clone(),
            config.recordings_path(),
            policy,
            rx.clone(),
        ));
    }
    let idle = config.limits.session_idle_timeout_s;
    if idle > 0 {
        tokio::spawn(retire_idle_sessions(state.clone(), idle, rx.clone()));
    }
    tracing::info!(%http_addr, grpc_addr = ?grpc_addr, igtl_addr = ?igtl_addr, tls = tls.is_some(), "listening");
    Ok(RunningServer {
        http_addr,
        grpc_addr,
        igtl_addr,
        handle,
        state,
        tasks,
    })
}

/// Creates the data directory's `sessions` folder and, when recording, the recordings
/// directory; an error names the key and the path.
fn create_data_dirs(config: &ServerConfig) -> Result<(), String> {
    std::fs::create_dir_all(config.data_dir.join("sessions"))
        .map_err(|e| format!("data_dir {}: cannot create: {e}", config.data_dir.display()))?;
    if config.record {
        let rec = config.recordings_path();
        std::fs::create_dir_all(&rec)
            .map_err(|e| format!("recordings_dir {}: cannot create: {e}", rec.display()))?;
    }
    Ok(())
}

/// Starts the OpenIGTLink listener on `addr` with the scenes `config` names (TLS with the
/// HTTP certificate, without ALPN: OpenIGTLink over a TLS tunnel names none): its bound
/// address and its task.
async fn start_igtl(
    addr: SocketAddr,
    config: &ServerConfig,
    state: &Arc<AppState>,
    tls: Option<&tls::TlsFiles>,
    conn_limits: connections::ConnectionLimits,
    shutdown: watch::Receiver<bool>,
) -> Result<(SocketAddr, JoinHandle<Result<(), String>>), String> {
    let scenes = igtl::IgtlScenes::load(
        config.igtl_scene.as_deref(),
        &config.igtl_device_scenes,
        config.igtl_coordinates,
    )?;
    let l = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|e| format!("cannot listen on {addr} (igtl_bind): {e}"))?;
    let bound = l.local_addr().map_err(|e| format!("bound address: {e}"))?;
    let acceptor = tls.map(|t| {
        let mut c = (*t.server_config).clone();
        c.alpn_protocols.clear();
        tokio_rustls::TlsAcceptor::from(Arc::new(c))
    });
    let st = state.clone();
    let task = tokio::spawn(async move {
        igtl::serve(l, st, Arc::new(scenes), acceptor, conn_limits, shutdown).await
    });
    Ok((bound, task))
}

/// Retires the sessions idle for `idle` seconds, checking every `idle` seconds (1–30 s),
/// until shutdown.
async fn retire_idle_sessions(
    state: Arc<AppState>,
    idle: u64,
    mut shutdown: watch::Receiver<bool>,
) {
    let mut tick = tokio::time::interval(Duration::from_secs(idle.clamp(1, 30)));
    loop {
        tokio::select! {
            _ = tick.tick() => {
                for h in state.registry.take_idle(idle as f64) {
                    state.retire(&h, "idle");
                }
            }
            _ = shutdown.wait_for(|s| *s) => break,
        }
    }
}

/// How often the recordings directory is checked against its retention policy.
const RETENTION_PERIOD: Duration = Duration::from_secs(60);

/// Applies the recordings' retention `policy` to `dir` now and every [`RETENTION_PERIOD`]
/// until shutdown, sparing the recordings of open sessions; each removal is logged and
/// counted (`livereg_recordings_removed_total{reason=age|size}`).
async fn keep_recordings_within(
    state: Arc<service::AppState>,
    dir: std::path::PathBuf,
    policy: crate::recording::retention::RetentionPolicy,
    mut shutdown: watch::Receiver<bool>,
) {
    use crate::recording::retention::enforce;
    let mut tick = tokio::time::interval(RETENTION_PERIOD);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = shutdown.wait_for(|s| *s) => return,
        }
        let in_use = state.registry.recording_paths();
        let d = dir.clone();
        let report = tokio::task::spawn_blocking(move || {
            enforce(&d, &policy, &in_use, std::time::SystemTime::now())
        })
        .await;
        match report {
            Ok(Ok(r)) => {
                for (path, bytes, why) in &r.removed {
                    let reason = why.label();
                    state
                        .metrics
                        .inc("livereg_recordings_removed_total", reason, 1);
                    tracing::info!(file = %path.display(), bytes, reason, "recording removed by the retention policy");
                }
                for (path, e) in &r.errors {
                    tracing::warn!(file = %path.display(), error = %e, "retention could not remove a recording");
                }
            }
            Ok(Err(e)) => {
                tracing::warn!(dir = %dir.display(), error = %e, "retention could not read the recordings directory")
            }
            Err(e) => tracing::warn!(error = %e, "retention task failed"),
        }
    }
}

/// Serves `app` on `listener`, through TLS when `tls` is given, until `signal`, with the
/// connection limits of `limits` ([`connections::serve`]).
async fn serve_http(
    listener: tokio::net::TcpListener,
    app: axum::Router,
    tls: Option<Arc<tokio_rustls::rustls::ServerConfig>>,
    limits: connections::ConnectionLimits,
    metrics: Arc<metrics::Metrics>,
    signal: impl std::future::Future<Output = ()> + Send + 'static,
) -> Result<(), String> {
    match tls {
        Some(config) => {
            let listener = tls::TlsListener::new(listener, config)
                .map_err(|e| format!("HTTP server (TLS): {e}"))?;
            connections::serve(listener, app, limits, metrics, signal).await;
        }
        None => {
            let listener = connections::NoDelayListener::new(listener);
            connections::serve(listener, app, limits, metrics, signal).await;
        }
    }
    Ok(())
}
