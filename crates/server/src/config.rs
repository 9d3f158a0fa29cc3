//! Server configuration: a TOML file, then `LIVEREG_*` environment variables, then command-line
//! flags, each overriding the one before (see docs/server.md for every key).

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// A bearer token and the name it is known by (logs, metrics; never the token itself).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TokenEntry {
    /// Name of the client (an operating room, a display), shown in logs.
    pub name: String,
    /// The secret (at least 16 characters).
    pub token: String,
}

/// TLS certificate chain and private key (PEM files): with them both the HTTP/WebSocket and
/// the gRPC listener speak TLS only (see [`super::tls`] and docs/server.md).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TlsConfig {
    /// PEM certificate chain.
    pub cert: PathBuf,
    /// PEM private key.
    pub key: PathBuf,
}

/// Limits enforced on every request.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LimitsConfig {
    /// Largest request body (HTTP body, WebSocket message, gRPC message), bytes.
    pub max_body_bytes: usize,
    /// Most points in one frame (larger frames are refused with 413; the session thins frames
    /// above its own `max_cloud_points` on its own).
    pub max_frame_points: usize,
    /// Most triangles of any mesh of a scene (surface or structure).
    pub max_mesh_triangles: usize,
    /// Most grid cells a scene may ask for (bounding box volume / cell_size³).
    pub max_grid_cells: usize,
    /// Most octree levels (`grid.subdivisions`) a scene may ask for.
    pub max_subdivisions: u32,
    /// Most open sessions per token.
    pub max_sessions_per_token: usize,
    /// Most open sessions in the whole server.
    pub max_sessions: usize,
    /// Frames per second a session accepts (token bucket of this size, refilled at this rate).
    pub max_frames_per_second: f64,
    /// Sessions without any request for this long are closed, seconds (0: never).
    pub session_idle_timeout_s: u64,
    /// Longest registration of one frame, ms, whatever the uploaded scene or `budget_ms`
    /// says: the session's time budget is at most this (the best state so far is answered,
    /// flagged `time_budget`). A frame still running after 5 times this retires its session.
    pub max_frame_ms: f64,
    /// Most iterations or steps an uploaded scene may ask for in any one of
    /// `solver.max_newton_iterations`, `solver.load_steps`, `registration.max_icp_iterations`
    /// and `registration.penalty_steps`.
    pub max_solver_iterations: u32,
    /// Longest a client may take to send a request's headers, seconds (also the longest an
    /// idle keep-alive connection waits for its next request).
    pub header_read_timeout_s: f64,
    /// Longest a client may take to send a request's body, seconds (408 `request_timeout`).
    pub body_timeout_s: f64,
    /// Most open HTTP/WebSocket connections (more are closed at once).
    pub max_connections: usize,
    /// Most open HTTP/WebSocket connections from one client IP address.
    pub max_connections_per_address: usize,
    /// A WebSocket or gRPC stream that receives nothing (no frame, no pong) for this long is
    /// closed, seconds; the server pings WebSockets every third of it.
    pub stream_idle_timeout_s: f64,
    /// Memory the open sessions may hold together, MiB, by their estimates made at creation
    /// (docs/server.md, "Memory budget"); a session that does not fit is refused. 0 (the
    /// default): 75 % of the container's memory limit, or of the machine's memory.
    pub max_memory_mb: u64,
}

impl Default for LimitsConfig {
    fn default() -> Self {
        Self {
            max_body_bytes: 32 << 20,
            max_frame_points: 200_000,
            max_mesh_triangles: 200_000,
            max_grid_cells: 200_000,
            max_subdivisions: 4,
            max_sessions_per_token: 8,
            max_sessions: 64,
            max_frames_per_second: 60.0,
            session_idle_timeout_s: 3600,
            max_frame_ms: 1000.0,
            max_solver_iterations: 100,
            header_read_timeout_s: 10.0,
            body_timeout_s: 30.0,
            max_connections: 1024,
            max_connections_per_address: 64,
            max_memory_mb: 0,
            stream_idle_timeout_s: 120.0,
        }
    }
}

/// The whole configuration of `livereg serve`.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServerConfig {
    /// HTTP + WebSocket address (default `127.0.0.1:8080`; port 0 picks a free port).
    pub bind: SocketAddr,
    /// gRPC address (default `127.0.0.1:50051`); `None` turns gRPC off.
    pub grpc_bind: Option<SocketAddr>,
    /// Accepted bearer tokens.
    pub tokens: Vec<TokenEntry>,
    /// A file of tokens, one `name:token` (or bare `token`) per line; `#` comments.
    pub token_file: Option<PathBuf>,
    /// Development only: no token needed. Refused unless every bind address is loopback.
    pub insecure_loopback_dev: bool,
    /// Where uploaded scenes are kept while their session lives (created if missing).
    pub data_dir: PathBuf,
    /// Whether every session is recorded to `<recordings_dir>/<session id>.mcap` (default
    /// true; see docs/recording.md).
    pub record: bool,
    /// Where session recordings go (default `<data_dir>/recordings`; created if missing).
    pub recordings_dir: Option<PathBuf>,
    /// Most bytes the recordings directory may hold; the oldest finished recordings are
    /// removed above it (0: no limit).
    pub recordings_max_bytes: u64,
    /// Oldest a finished recording may be, hours, by its last change (0: no limit).
    pub recordings_max_age_h: f64,
    /// Longest a recorded result stays in the operating system's cache before it is forced
    /// to the disk (`fsync`), ms (0: after every result). Recordings are also synced when
    /// they finish.
    pub recordings_fsync_ms: u64,
    /// Frames registered at the same time (CPU-bound; default: the number of cores).
    pub worker_threads: usize,
    /// Threads of the async runtime that handles the network (default 2).
    pub io_threads: usize,
    /// Sessions being created at the same time (grid building is CPU-bound; default 1).
    pub max_concurrent_creates: usize,
    /// Seconds in-flight frames get to finish on shutdown.
    pub shutdown_grace_s: u64,
    /// Log format: `"text"` or `"json"`.
    pub log_format: String,
    /// Log filter (tracing `EnvFilter` syntax), e.g. `"info"` or `"livereg=debug"`.
    pub log_filter: String,
    /// Whether `/metrics` needs a token (default false: scraped from inside the cluster).
    pub metrics_require_token: bool,
    /// TLS for both HTTP and gRPC (`None`: plain TCP, e.g. behind a TLS-terminating proxy).
    pub tls: Option<TlsConfig>,
    /// OpenIGTLink address (`None`, the default: off; the protocol's port is 18944). A
    /// non-loopback address needs `tls` or `igtl_allow_remote` (docs/openigtlink.md).
    pub igtl_bind: Option<SocketAddr>,
    /// The scene OpenIGTLink sessions are built from, for devices without their own.
    pub igtl_scene: Option<PathBuf>,
    /// Scenes by the device name of the clouds (`[igtl_device_scenes]`, `Name = "scene.toml"`).
    pub igtl_device_scenes: std::collections::BTreeMap<String, PathBuf>,
    /// Serve OpenIGTLink on a non-loopback address without TLS (the protocol has no
    /// authentication: anyone who reaches the port can stream and read results).
    pub igtl_allow_remote: bool,
    /// The coordinates OpenIGTLink clients speak: `"ras"` (the default: 3D Slicer's world;
    /// x and y change sign between them and the LPS model) or `"lps"` (taken as they are).
    pub igtl_coordinates: IgtlCoordinates,
    /// Limits.
    pub limits: LimitsConfig,
}

impl Default for ServerConfig {
    fn default() -> Self {
        Self {
            bind: SocketAddr::from(([127, 0, 0, 1], 8080)),
            grpc_bind: Some(SocketAddr::from(([127, 0, 0, 1], 50051))),
            tokens: Vec::new(),
            token_file: None,
            insecure_loopback_dev: false,
            data_dir: std::env::temp_dir().join("livereg-server"),
            record: true,
            recordings_dir: None,
            recordings_max_bytes: 0,
            recordings_max_age_h: 0.0,
            recordings_fsync_ms: 1000,
            worker_threads: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(2),
            io_threads: 2,
            max_concurrent_creates: 1,
            shutdown_grace_s: 30,
            log_format: "text".into(),
            log_filter: "info".into(),
            metrics_require_token: false,
            tls: None,
            igtl_bind: None,
            igtl_scene: None,
            igtl_device_scenes: Default::default(),
            igtl_allow_remote: false,
            igtl_coordinates: IgtlCoordinates::Ras,
            limits: LimitsConfig::default(),
        }
    }
}

/// The patient coordinates of OpenIGTLink clients (the model's are LPS).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum IgtlCoordinates {
    /// Right-anterior-superior: 3D Slicer's world (the default).
    #[default]
    Ras,
    /// Left-posterior-superior: DICOM/ITK, and the model's own.
    Lps,
}

/// Environment variables read by [`ServerConfig::apply_env`], with the key each sets.
pub const ENV_VARS: &[(&str, &str)] = &[
    ("LIVEREG_BIND", "bind"),
    ("LIVEREG_GRPC_BIND", "grpc_bind (`off` disables gRPC)"),
    (
        "LIVEREG_IGTL_BIND",
        "igtl_bind (`off` disables OpenIGTLink)",
    ),
    ("LIVEREG_IGTL_SCENE", "igtl_scene"),
    (
        "LIVEREG_TOKENS",
        "tokens: comma-separated `name:token` or `token`",
    ),
    ("LIVEREG_TOKEN_FILE", "token_file"),
    ("LIVEREG_DATA_DIR", "data_dir"),
    ("LIVEREG_RECORD", "record (`true`/`false`)"),
    ("LIVEREG_RECORDINGS_DIR", "recordings_dir"),
    ("LIVEREG_WORKER_THREADS", "worker_threads"),
    ("LIVEREG_IO_THREADS", "io_threads"),
    ("LIVEREG_LOG", "log_filter"),
    ("LIVEREG_LOG_FORMAT", "log_format"),
    ("LIVEREG_TLS_CERT", "tls.cert"),
    ("LIVEREG_TLS_KEY", "tls.key"),
    ("LIVEREG_MAX_BODY_BYTES", "limits.max_body_bytes"),
    ("LIVEREG_MAX_FRAME_POINTS", "limits.max_frame_points"),
    (
        "LIVEREG_MAX_SESSIONS_PER_TOKEN",
        "limits.max_sessions_per_token",
    ),
    ("LIVEREG_MAX_SESSIONS", "limits.max_sessions"),
    ("LIVEREG_MAX_FPS", "limits.max_frames_per_second"),
];

fn parse_num<T: std::str::FromStr>(var: &str, v: &str) -> Result<T, String>
where
    T::Err: std::fmt::Display,
{
    v.trim()
        .parse::<T>()
        .map_err(|e| format!("{var}={v:?}: {e}"))
}

/// Tokens from `name:token` / `token` items. A bare token is named after its source and
/// position, `<source>-token-<n>` (`env-token-2`: the second item of `LIVEREG_TOKENS`), so
/// that bare tokens of two sources never share a name (a name owns sessions and a quota).
pub fn parse_token_list<'a>(items: impl Iterator<Item = &'a str>, source: &str) -> Vec<TokenEntry> {
    items
        .map(str::trim)
        .filter(|s| !s.is_empty() && !s.starts_with('#'))
        .enumerate()
        .map(|(i, s)| match s.split_once(':') {
            Some((name, token)) if !name.trim().is_empty() => TokenEntry {
                name: name.trim().to_string(),
                token: token.trim().to_string(),
            },
            _ => TokenEntry {
                name: format!("{source}-token-{}", i + 1),
                token: s.to_string(),
            },
        })
        .collect()
}

/// Refuses a token file that users other than its owner and group may read or write
/// (`chmod 600`, or `640` for a service group; Kubernetes: the Secret volume's
/// `defaultMode: 0440`). Unix only; elsewhere nothing is checked.
fn check_token_file_mode(path: &Path) -> Result<(), String> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let meta = std::fs::metadata(path)
            .map_err(|e| format!("{}: cannot read the token file: {e}", path.display()))?;
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o007 != 0 {
            return Err(format!(
                "{}: the token file is open to every user of the machine (mode {mode:04o}); restrict it with `chmod 600` (or 640 for a service group)",
                path.display()
            ));
        }
    }
    Ok(())
}

impl ServerConfig {
    /// The retention policy of the recordings directory (`recordings_max_bytes`,
    /// `recordings_max_age_h`); recordings changed in the last two minutes are never
    /// removed.
    pub fn recordings_retention(&self) -> crate::recording::retention::RetentionPolicy {
        crate::recording::retention::RetentionPolicy {
            max_bytes: self.recordings_max_bytes,
            max_age: (self.recordings_max_age_h > 0.0)
                .then(|| std::time::Duration::from_secs_f64(self.recordings_max_age_h * 3600.0)),
            min_age: std::time::Duration::from_secs(120),
        }
    }

    /// Where session recordings go: `recordings_dir`, or `<data_dir>/recordings`.
    pub fn recordings_path(&self) -> PathBuf {
        self.recordings_dir
            .clone()
            .unwrap_or_else(|| self.data_dir.join("recordings"))
    }

    /// Reads a TOML configuration file (unknown keys are errors naming the key).
    pub fn from_file(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("{}: cannot read the configuration: {e}", path.display()))?;
        toml::from_str(&text).map_err(|e| {
            format!(
                "{}: {}",
                path.display(),
                e.to_string().replace('\n', " ").trim()
            )
        })
    }

    /// Applies `LIVEREG_*` variables (see [`ENV_VARS`]) looked up with `get`.
    pub fn apply_env(&mut self, get: impl Fn(&str) -> Option<String>) -> Result<(), String> {
        if let Some(v) = get("LIVEREG_BIND") {
            self.bind = parse_num("LIVEREG_BIND", &v)?;
        }
        if let Some(v) = get("LIVEREG_IGTL_BIND") {
            self.igtl_bind = if v.trim().eq_ignore_ascii_case("off") {
                None
            } else {
                Some(parse_num("LIVEREG_IGTL_BIND", &v)?)
            };
        }
        if let Some(v) = get("LIVEREG_IGTL_SCENE") {
            self.igtl_scene = Some(PathBuf::from(v));
        }
        if let Some(v) = get("LIVEREG_GRPC_BIND") {
            self.grpc_bind = if v.trim().eq_ignore_ascii_case("off") {
                None
            } else {
                Some(parse_num("LIVEREG_GRPC_BIND", &v)?)
            };
        }
        if let Some(v) = get("LIVEREG_TOKENS") {
            self.tokens.extend(parse_token_list(v.split(','), "env"));
        }
        if let Some(v) = get("LIVEREG_TOKEN_FILE") {
            self.token_file = Some(PathBuf::from(v));
        }
        if let Some(v) = get("LIVEREG_DATA_DIR") {
            self.data_dir = PathBuf::from(v);
        }
        if let Some(v) = get("LIVEREG_RECORD") {
            self.record = parse_num("LIVEREG_RECORD", &v)?;
        }
        if let Some(v) = get("LIVEREG_RECORDINGS_DIR") {
            self.recordings_dir = Some(PathBuf::from(v));
        }
        if let Some(v) = get("LIVEREG_WORKER_THREADS") {
            self.worker_threads = parse_num("LIVEREG_WORKER_THREADS", &v)?;
        }
        if let Some(v) = get("LIVEREG_IO_THREADS") {
            self.io_threads = parse_num("LIVEREG_IO_THREADS", &v)?;
        }
        if let Some(v) = get("LIVEREG_LOG") {
            self.log_filter = v;
        }
        if let Some(v) = get("LIVEREG_LOG_FORMAT") {
            self.log_format = v;
        }
        match (get("LIVEREG_TLS_CERT"), get("LIVEREG_TLS_KEY")) {
            (Some(cert), Some(key)) => {
                self.tls = Some(TlsConfig {
                    cert: cert.into(),
                    key: key.into(),
                })
            }
            (None, None) => {}
            _ => return Err("LIVEREG_TLS_CERT and LIVEREG_TLS_KEY go together".into()),
        }
        if let Some(v) = get("LIVEREG_MAX_BODY_BYTES") {
            self.limits.max_body_bytes = parse_num("LIVEREG_MAX_BODY_BYTES", &v)?;
        }
        if let Some(v) = get("LIVEREG_MAX_FRAME_POINTS") {
            self.limits.max_frame_points = parse_num("LIVEREG_MAX_FRAME_POINTS", &v)?;
        }
        if let Some(v) = get("LIVEREG_MAX_SESSIONS_PER_TOKEN") {
            self.limits.max_sessions_per_token = parse_num("LIVEREG_MAX_SESSIONS_PER_TOKEN", &v)?;
        }
        if let Some(v) = get("LIVEREG_MAX_SESSIONS") {
            self.limits.max_sessions = parse_num("LIVEREG_MAX_SESSIONS", &v)?;
        }
        if let Some(v) = get("LIVEREG_MAX_FPS") {
            self.limits.max_frames_per_second = parse_num("LIVEREG_MAX_FPS", &v)?;
        }
        Ok(())
    }

    /// All tokens: the configured ones plus those of `token_file`.
    pub fn all_tokens(&self) -> Result<Vec<TokenEntry>, String> {
        let mut tokens = self.tokens.clone();
        if let Some(f) = &self.token_file {
            check_token_file_mode(f)?;
            let text = std::fs::read_to_string(f)
                .map_err(|e| format!("{}: cannot read the token file: {e}", f.display()))?;
            tokens.extend(parse_token_list(text.lines(), "file"));
        }
        Ok(tokens)
    }

    /// Checks the configuration: values in range, tokens long enough and unique, no
    /// unauthenticated mode off loopback.
    pub fn validate(&self) -> Result<(), String> {
        self.validate_access()?;
        self.validate_igtl()?;
        self.validate_limits()?;
        self.validate_logs_and_recordings()
    }

    /// The tokens (at least 16 characters, no token or name listed twice, no empty name) and
    /// the access mode: tokens, or loopback-only development.
    fn validate_access(&self) -> Result<(), String> {
        let tokens = self.all_tokens()?;
        for t in &tokens {
            if t.token.chars().count() < 16 {
                return Err(format!(
                    "token `{}` is shorter than 16 characters; use a long random secret (e.g. `openssl rand -hex 32`)",
                    t.name
                ));
            }
        }
        for (i, a) in tokens.iter().enumerate() {
            if tokens[..i].iter().any(|b| b.token == a.token) {
                return Err(format!("token `{}` is listed twice", a.name));
            }
            if tokens[..i].iter().any(|b| b.name == a.name) {
                return Err(format!(
                    "two tokens are named `{}` (across the configuration, LIVEREG_TOKENS and the token file): a name owns its sessions and quota, so names must be unique",
                    a.name
                ));
            }
            if a.name.trim().is_empty() {
                return Err("a token has an empty name".into());
            }
        }
        if self.insecure_loopback_dev {
            let mut addrs = vec![self.bind];
            addrs.extend(self.grpc_bind);
            if let Some(a) = addrs.iter().find(|a| !a.ip().is_loopback()) {
                return Err(format!(
                    "--insecure-loopback-dev needs loopback bind addresses, got {a}"
                ));
            }
        } else if tokens.is_empty() {
            return Err("no bearer tokens configured: set `tokens` in the configuration, LIVEREG_TOKENS or LIVEREG_TOKEN_FILE (or --insecure-loopback-dev for loopback-only development)".into());
        }
        Ok(())
    }

    /// The OpenIGTLink listener: a scene for its sessions, and TLS (or an explicit consent)
    /// when it listens beyond loopback.
    fn validate_igtl(&self) -> Result<(), String> {
        if let Some(a) = self.igtl_bind {
            if self.igtl_scene.is_none() && self.igtl_device_scenes.is_empty() {
                return Err(format!(
                    "igtl_bind = {a} needs a scene for its sessions: set igtl_scene (or igtl_device_scenes)"
                ));
            }
            if !a.ip().is_loopback() && self.tls.is_none() && !self.igtl_allow_remote {
                return Err(format!(
                    "igtl_bind = {a} is not a loopback address: OpenIGTLink has no authentication, \
                     so a remote listener needs TLS (tls.cert, tls.key; clients connect through a \
                     TLS tunnel, docs/openigtlink.md) or an explicit igtl_allow_remote = true"
                ));
            }
        }
        Ok(())
    }

    /// Thread counts and limits within their ranges; the first one out names itself.
    fn validate_limits(&self) -> Result<(), String> {
        let l = &self.limits;
        let checks: [(bool, &str); 13] = [
            (self.worker_threads >= 1, "worker_threads must be >= 1"),
            (self.io_threads >= 1, "io_threads must be >= 1"),
            (
                self.max_concurrent_creates >= 1,
                "max_concurrent_creates must be >= 1",
            ),
            (
                l.max_body_bytes >= 1024,
                "limits.max_body_bytes must be >= 1024",
            ),
            (
                l.max_frame_points >= 3,
                "limits.max_frame_points must be >= 3",
            ),
            (
                l.max_mesh_triangles >= 4,
                "limits.max_mesh_triangles must be >= 4",
            ),
            (l.max_grid_cells >= 1, "limits.max_grid_cells must be >= 1"),
            (
                l.max_sessions_per_token >= 1 && l.max_sessions >= 1,
                "limits.max_sessions and limits.max_sessions_per_token must be >= 1",
            ),
            (
                l.max_frames_per_second.is_finite() && l.max_frames_per_second > 0.0,
                "limits.max_frames_per_second must be > 0",
            ),
            (
                l.max_frame_ms.is_finite() && l.max_frame_ms > 0.0,
                "limits.max_frame_ms must be > 0",
            ),
            (
                l.max_solver_iterations >= 1,
                "limits.max_solver_iterations must be >= 1",
            ),
            (
                [l.header_read_timeout_s, l.body_timeout_s, l.stream_idle_timeout_s]
                    .iter()
                    .all(|t| t.is_finite() && *t > 0.0 && *t <= 86_400.0),
                "limits.header_read_timeout_s, body_timeout_s and stream_idle_timeout_s must be in (0, 86400] seconds",
            ),
            (
                l.max_connections >= 1 && l.max_connections_per_address >= 1,
                "limits.max_connections and max_connections_per_address must be >= 1",
            ),
        ];
        if let Some((_, m)) = checks.iter().find(|(ok, _)| !ok) {
            return Err((*m).to_string());
        }
        Ok(())
    }

    /// The log format and the recordings' age limit and directory.
    fn validate_logs_and_recordings(&self) -> Result<(), String> {
        if !matches!(self.log_format.as_str(), "text" | "json") {
            return Err(format!(
                "log_format must be \"text\" or \"json\", got {:?}",
                self.log_format
            ));
        }
        if !(self.recordings_max_age_h.is_finite() && self.recordings_max_age_h >= 0.0) {
            return Err(format!(
                "recordings_max_age_h must be >= 0 (0: keep recordings of any age), got {}",
                self.recordings_max_age_h
            ));
        }
        if let Some(d) = &self.recordings_dir {
            if d.as_os_str().is_empty() {
                return Err("recordings_dir must not be empty (leave it out for `<data_dir>/recordings`, or set `record = false` to record nothing)".into());
            }
            if self.record && d.is_file() {
                return Err(format!(
                    "recordings_dir {} is a file, not a directory",
                    d.display()
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn env_overrides_file_values_and_bad_values_name_the_variable() {
        let mut c: ServerConfig = toml::from_str(
            "bind = \"0.0.0.0:9000\"\n[limits]\nmax_frame_points = 10\n[[tokens]]\nname = \"or1\"\ntoken = \"0123456789abcdef0\"\n",
        )
        .unwrap();
        assert_eq!(c.limits.max_frame_points, 10);
        let env = |k: &str| match k {
            "LIVEREG_BIND" => Some("127.0.0.1:7000".to_string()),
            "LIVEREG_TOKENS" => Some("or2:fedcba9876543210f, bare-token-long-enough".to_string()),
            "LIVEREG_GRPC_BIND" => Some("off".to_string()),
            _ => None,
        };
        c.apply_env(env).unwrap();
        assert_eq!(c.bind.port(), 7000);
        assert_eq!(c.grpc_bind, None);
        assert_eq!(c.tokens.len(), 3);
        assert_eq!(c.tokens[1].name, "or2");
        assert_eq!(c.tokens[2].name, "env-token-2");
        c.validate().unwrap();
        let err = c
            .apply_env(|k| (k == "LIVEREG_MAX_FPS").then(|| "fast".to_string()))
            .unwrap_err();
        assert!(err.contains("LIVEREG_MAX_FPS"), "{err}");
        assert!(c.record);
        assert_eq!(c.recordings_path(), c.data_dir.join("recordings"));
        c.apply_env(|k| match k {
            "LIVEREG_RECORD" => Some("false".to_string()),
            "LIVEREG_RECORDINGS_DIR" => Some("/srv/rec".to_string()),
            _ => None,
        })
        .unwrap();
        assert!(!c.record);
        assert_eq!(c.recordings_path(), PathBuf::from("/srv/rec"));
        let err = c
            .apply_env(|k| (k == "LIVEREG_RECORD").then(|| "maybe".to_string()))
            .unwrap_err();
        assert!(err.contains("LIVEREG_RECORD"), "{err}");
        c.recordings_dir = Some(PathBuf::new());
        assert!(c.validate().unwrap_err().contains("recordings_dir"));
        c.recordings_dir = None;
        let unknown = toml::from_str::<ServerConfig>("bnid = \"x\"").unwrap_err();
        assert!(unknown.to_string().contains("bnid"));
    }

    #[test]
    fn no_tokens_is_refused_unless_loopback_dev() {
        let mut c = ServerConfig::default();
        assert!(c.validate().unwrap_err().contains("no bearer tokens"));
        c.insecure_loopback_dev = true;
        c.validate().unwrap();
        c.bind = "0.0.0.0:8080".parse().unwrap();
        assert!(c.validate().unwrap_err().contains("loopback"));
        c.bind = "127.0.0.1:8080".parse().unwrap();
        c.insecure_loopback_dev = false;
        c.tokens = parse_token_list(["short"].into_iter(), "env");
        assert!(c.validate().unwrap_err().contains("shorter than 16"));
    }

    /// OpenIGTLink has no authentication: a remote listener needs TLS or an explicit opt-in,
    /// and any listener needs a scene.
    #[test]
    fn openigtlink_binds_loopback_unless_tls_or_allowed() {
        let mut c = ServerConfig {
            insecure_loopback_dev: true,
            igtl_bind: Some("127.0.0.1:18944".parse().unwrap()),
            ..Default::default()
        };
        assert!(c.validate().unwrap_err().contains("igtl_scene"));
        c.igtl_scene = Some("scene.toml".into());
        c.validate().unwrap();
        c.insecure_loopback_dev = false;
        c.tokens = parse_token_list(["room:0123456789abcdef0123"].into_iter(), "env");
        c.igtl_bind = Some("0.0.0.0:18944".parse().unwrap());
        let e = c.validate().unwrap_err();
        assert!(
            e.contains("not a loopback address") && e.contains("igtl_allow_remote"),
            "{e}"
        );
        c.igtl_allow_remote = true;
        c.validate().unwrap();
        c.igtl_allow_remote = false;
        c.tls = Some(TlsConfig {
            cert: "c.pem".into(),
            key: "k.pem".into(),
        });
        c.validate().unwrap();
        let from_toml: ServerConfig = toml::from_str(
            "igtl_bind = \"127.0.0.1:18944\"\nigtl_scene = \"a.toml\"\n[igtl_device_scenes]\nLeftLobe = \"b.toml\"\n",
        )
        .unwrap();
        assert_eq!(
            from_toml.igtl_device_scenes["LeftLobe"],
            PathBuf::from("b.toml")
        );
        let mut env = ServerConfig::default();
        env.apply_env(|k| (k == "LIVEREG_IGTL_BIND").then(|| "127.0.0.1:1".to_string()))
            .unwrap();
        assert_eq!(env.igtl_bind, Some("127.0.0.1:1".parse().unwrap()));
    }

    /// Token names are unique across every source (bare tokens of the environment and of the
    /// token file are named apart), and a token file open to other users is refused.
    #[test]
    fn token_names_are_unique_and_the_token_file_private() {
        let dir = std::env::temp_dir().join(format!("livereg-tokens-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("tokens.txt");
        std::fs::write(
            &file,
            "# room tokens\nfile-bare-token-0123456789\nor1:0123456789abcdef-file\n",
        )
        .unwrap();
        let mut c = ServerConfig {
            token_file: Some(file.clone()),
            ..Default::default()
        };
        c.apply_env(|k| (k == "LIVEREG_TOKENS").then(|| "env-bare-token-0123456789".to_string()))
            .unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&file, std::fs::Permissions::from_mode(0o644)).unwrap();
            let e = c.validate().unwrap_err();
            assert!(
                e.contains("tokens.txt") && e.contains("0644") && e.contains("chmod 600"),
                "{e}"
            );
            std::fs::set_permissions(&file, std::fs::Permissions::from_mode(0o640)).unwrap();
        }
        c.validate().unwrap();
        let names: Vec<String> = c
            .all_tokens()
            .unwrap()
            .into_iter()
            .map(|t| t.name)
            .collect();
        assert_eq!(names, ["env-token-1", "file-token-1", "or1"]);
        // The same name from two sources is refused, naming it.
        c.tokens.push(TokenEntry {
            name: "or1".into(),
            token: "0123456789abcdef-config".into(),
        });
        let e = c.validate().unwrap_err();
        assert!(e.contains("`or1`") && e.contains("unique"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The configuration files shipped in `deploy/` parse (unknown keys are errors) and say
    /// what their comments promise: the Kubernetes ConfigMap turns TLS on.
    #[test]
    fn deploy_configurations_parse() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../deploy");
        let example = ServerConfig::from_file(&root.join("config.example.toml")).unwrap();
        assert_eq!(example.data_dir, PathBuf::from("/var/lib/livereg"));
        let yaml = std::fs::read_to_string(root.join("kubernetes/livereg.yaml")).unwrap();
        let start = yaml
            .find("config.toml: |")
            .expect("the ConfigMap's config.toml")
            + 14;
        let block: Vec<&str> = yaml[start..]
            .lines()
            .skip(1)
            .take_while(|l| l.starts_with("    "))
            .map(|l| &l[4..])
            .collect();
        let k8s: ServerConfig = toml::from_str(&block.join("\n")).unwrap();
        let tls = k8s.tls.expect("TLS on in the cluster");
        assert_eq!(tls.cert, PathBuf::from("/etc/livereg/tls/tls.crt"));
        assert_eq!(k8s.worker_threads, 2);
    }
}
