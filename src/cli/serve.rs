//! `livereg serve [--config FILE]`: the registration server (see docs/server.md). Settings come
//! from the configuration file, then `LIVEREG_*` environment variables, then these flags.

use std::net::SocketAddr;
use std::path::PathBuf;

use crate::server::config::{ServerConfig, TlsConfig};

/// Flags of `serve` (each overrides the file and the environment).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ServeArgs {
    /// Configuration file (TOML; keys in docs/server.md).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// HTTP + WebSocket address, e.g. 0.0.0.0:8080.
    #[arg(long)]
    pub bind: Option<SocketAddr>,
    /// gRPC address, or `off`.
    #[arg(long)]
    pub grpc_bind: Option<String>,
    /// OpenIGTLink address (e.g. 127.0.0.1:18944), or `off` (the default).
    #[arg(long)]
    pub igtl_bind: Option<String>,
    /// The scene OpenIGTLink sessions are built from.
    #[arg(long)]
    pub igtl_scene: Option<PathBuf>,
    /// File of bearer tokens (`name:token` per line). Tokens are not taken as flags, since
    /// command lines are visible to other users of the machine.
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// Development only: accept requests without a token. Refused unless every bind address
    /// is loopback.
    #[arg(long)]
    pub insecure_loopback_dev: bool,
    /// Where uploaded scenes are kept while their session lives.
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Frames registered at the same time (default: the number of cores).
    #[arg(long)]
    pub worker_threads: Option<usize>,
    /// Threads handling the network (default 2).
    #[arg(long)]
    pub io_threads: Option<usize>,
    /// Log format: text or json.
    #[arg(long)]
    pub log_format: Option<String>,
    /// TLS certificate chain (PEM, leaf first): HTTP, WebSocket and gRPC then speak TLS only.
    #[arg(long, requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// TLS private key (PEM).
    #[arg(long, requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
}

/// The configuration from file, environment and flags.
pub fn config_from(args: &ServeArgs) -> Result<ServerConfig, String> {
    let mut c = match &args.config {
        Some(p) => ServerConfig::from_file(p)?,
        None => ServerConfig::default(),
    };
    c.apply_env(|k| std::env::var(k).ok())?;
    if let Some(b) = args.bind {
        c.bind = b;
    }
    if let Some(g) = &args.grpc_bind {
        c.grpc_bind = if g.eq_ignore_ascii_case("off") {
            None
        } else {
            Some(
                g.parse()
                    .map_err(|e| format!("--grpc-bind {g:?}: {e} (an address or `off`)"))?,
            )
        };
    }
    if let Some(g) = &args.igtl_bind {
        c.igtl_bind = if g.eq_ignore_ascii_case("off") {
            None
        } else {
            Some(
                g.parse()
                    .map_err(|e| format!("--igtl-bind {g:?}: {e} (an address or `off`)"))?,
            )
        };
    }
    if let Some(s) = &args.igtl_scene {
        c.igtl_scene = Some(s.clone());
    }
    if let Some(f) = &args.token_file {
        c.token_file = Some(f.clone());
    }
    if args.insecure_loopback_dev {
        c.insecure_loopback_dev = true;
    }
    if let Some(d) = &args.data_dir {
        c.data_dir = d.clone();
    }
    if let Some(n) = args.worker_threads {
        c.worker_threads = n;
    }
    if let Some(n) = args.io_threads {
        c.io_threads = n;
    }
    if let Some(f) = &args.log_format {
        c.log_format = f.clone();
    }
    if let (Some(cert), Some(key)) = (&args.tls_cert, &args.tls_key) {
        c.tls = Some(TlsConfig {
            cert: cert.clone(),
            key: key.clone(),
        });
    }
    c.validate()?;
    Ok(c)
}

fn init_logs(c: &ServerConfig) {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_new(&c.log_filter).unwrap_or_else(|_| EnvFilter::new("info"));
    let b = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let _ = if c.log_format == "json" {
        b.json().try_init()
    } else {
        b.try_init()
    };
}

/// Runs the server until SIGINT or SIGTERM, then shuts down gracefully.
pub fn run(args: &ServeArgs) -> Result<(), String> {
    let config = config_from(args)?;
    init_logs(&config);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(config.io_threads)
        .thread_name("livereg-io")
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the async runtime: {e}"))?;
    rt.block_on(async move {
        let server = crate::server::start(config).await?;
        let handle = server.shutdown_handle();
        tokio::spawn(async move {
            wait_for_signal().await;
            tracing::info!("signal received");
            handle.trigger();
        });
        server.run_until_stopped().await
    })
}

async fn wait_for_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}
