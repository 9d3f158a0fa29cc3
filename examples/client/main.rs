//! Rust client of `livereg serve` (gRPC and WebSocket).
//!
//! ```sh
//! # one session, frames sent one after the other; prints latency and transport overhead,
//! # writes the results (results.jsonl lines plus the surface) to --out
//! cargo run --release --example client -- stream --http 127.0.0.1:8080 --grpc 127.0.0.1:50051 \
//!     --token-file tokens.txt --scene fixtures/liver_phantom/scene.toml --frames FRAMES_DIR \
//!     --transport ws|ws-binary|grpc [--binary-results] --out results.jsonl
//! # load: N sessions streaming at HZ for SECONDS over WebSocket (loopback only)
//! cargo run --release --example client -- load --http 127.0.0.1:8080 --token-file tokens.txt \
//!     --scene SCENE --frames FRAMES_DIR --sessions 8 --hz 30 --seconds 20 [--binary] \
//!     [--binary-results] [--phases spread|together]
//! ```
//! `--ca-cert CA.pem` talks TLS (https, wss, gRPC over TLS) to a server started with
//! `--tls-cert/--tls-key`, trusting only the CA's certificates; `--tls-name` is the name the
//! server's certificate must carry (default `localhost`).
//! `--binary-results` opens the WebSocket with `?results=binary`: results come back in the
//! compact binary result encoding (f32 coordinates; docs/server.md) instead of JSON.
//! The token is read from `--token-file` (first line, `name:token` or `token`) or the
//! `LIVEREG_TOKEN` environment variable.

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};

#[path = "lib.rs"]
mod client;
use client::*;

#[derive(Parser)]
struct Args {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(clap::Args, Clone)]
struct Common {
    /// HTTP/WebSocket address of the server.
    #[arg(long, default_value = "127.0.0.1:8080")]
    http: SocketAddr,
    /// gRPC address of the server.
    #[arg(long, default_value = "127.0.0.1:50051")]
    grpc: SocketAddr,
    /// Token file (first line `name:token` or `token`); else $LIVEREG_TOKEN.
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// Scene file (its directory holds the files it names).
    #[arg(long)]
    scene: PathBuf,
    /// Directory of point files, taken in lexical order.
    #[arg(long)]
    frames: PathBuf,
    /// TLS: PEM certificates of the CA that signed the server's certificate.
    #[arg(long)]
    ca_cert: Option<PathBuf>,
    /// TLS: the name the server's certificate must carry.
    #[arg(long, default_value = "localhost", requires = "ca_cert")]
    tls_name: String,
}

impl Common {
    /// The server's HTTP/WebSocket and gRPC endpoints (TLS with `--ca-cert`).
    fn endpoints(&self) -> Res<(Endpoint, Endpoint)> {
        let tls = match &self.ca_cert {
            Some(f) => {
                let pem = std::fs::read(f).map_err(|e| format!("{}: {e}", f.display()))?;
                Some(
                    ClientTls::new(&pem, &self.tls_name)
                        .map_err(|e| format!("{}: {e}", f.display()))?,
                )
            }
            None => None,
        };
        Ok((
            Endpoint {
                addr: self.http,
                tls: tls.clone(),
            },
            Endpoint {
                addr: self.grpc,
                tls,
            },
        ))
    }
}

#[derive(Subcommand)]
enum Cmd {
    /// One session, frames one after the other.
    Stream {
        #[command(flatten)]
        common: Common,
        /// ws (JSON frames), ws-binary (f32 frames) or grpc (bidirectional stream).
        #[arg(long, default_value = "ws")]
        transport: String,
        /// Where to write the results (one JSON object per line).
        #[arg(long)]
        out: Option<PathBuf>,
        /// WebSocket transports: ask for results in the binary result encoding (f32
        /// coordinates) instead of JSON.
        #[arg(long)]
        binary_results: bool,
    },
    /// Concurrent sessions at a fixed frame rate.
    Load {
        #[command(flatten)]
        common: Common,
        #[arg(long, default_value_t = 8)]
        sessions: usize,
        #[arg(long, default_value_t = 30.0)]
        hz: f64,
        #[arg(long, default_value_t = 20.0)]
        seconds: f64,
        /// Send frames in the binary encoding.
        #[arg(long)]
        binary: bool,
        /// Ask for results in the binary result encoding (f32 coordinates) instead of JSON.
        #[arg(long)]
        binary_results: bool,
        /// When the sessions send within the frame period: `spread` (session i of n at
        /// i/n of the period, as independent clients) or `together` (bursts of n frames).
        #[arg(long, default_value = "spread")]
        phases: String,
    },
}

fn token(c: &Common) -> Res<String> {
    let raw = match &c.token_file {
        Some(f) => std::fs::read_to_string(f).map_err(|e| format!("{}: {e}", f.display()))?,
        None => std::env::var("LIVEREG_TOKEN").map_err(|_| "give --token-file or LIVEREG_TOKEN")?,
    };
    let line = raw
        .lines()
        .find(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .unwrap_or("");
    Ok(line
        .split_once(':')
        .map(|(_, t)| t)
        .unwrap_or(line)
        .trim()
        .to_string())
}

async fn grpc_stream(
    c: &Common,
    token: &str,
    frames: &[(String, Vec<[f64; 3]>)],
    scene: &SceneFiles,
) -> Res<(Vec<serde_json::Value>, Vec<(f64, f64)>)> {
    use livereg::server::proto;
    let mut g = GrpcClient::connect_endpoint(&c.endpoints()?.1, token).await?;
    let info = g.create_session(scene).await.map_err(|e| e.to_string())?;
    let (tx, rx) = tokio::sync::mpsc::channel::<proto::StreamRequest>(4);
    let mut out = g
        .inner
        .stream(g.req(tokio_stream::wrappers::ReceiverStream::new(rx)))
        .await
        .map_err(|e| e.to_string())?
        .into_inner();
    let mut results = Vec::new();
    let mut times = Vec::new();
    for (k, (name, pts)) in frames.iter().enumerate() {
        let t = Instant::now();
        tx.send(proto::StreamRequest {
            session_id: info.id.clone(),
            frame: Some(frame_f64(k as u64, name, pts)),
        })
        .await
        .map_err(|e| e.to_string())?;
        let m = out
            .message()
            .await
            .map_err(|e| e.to_string())?
            .ok_or("stream ended")?;
        match m.kind {
            Some(proto::stream_response::Kind::Result(r)) => {
                times.push((t.elapsed().as_secs_f64() * 1e3, r.wall_ms));
                let mut v = proto_to_record(&r);
                v["surface_vertices"] = (r.surface.len() / 3).into();
                results.push(v);
            }
            other => return Err(format!("frame {k}: {other:?}")),
        }
    }
    drop(tx);
    g.close_session(&info.id).await.map_err(|e| e.to_string())?;
    Ok((results, times))
}

async fn run(args: Args) -> Res<()> {
    match args.cmd {
        Cmd::Stream {
            common,
            transport,
            out,
            binary_results,
        } => {
            let token = token(&common)?;
            let scene = SceneFiles::read(&common.scene)?;
            let frames = read_frames(&common.frames)?;
            let (results, times) = match transport.as_str() {
                "grpc" if binary_results => {
                    return Err(
                        "--binary-results is for the WebSocket transports (ws, ws-binary)".into(),
                    )
                }
                "grpc" => grpc_stream(&common, &token, &frames, &scene).await?,
                "ws" | "ws-binary" => {
                    let http = common.endpoints()?.0;
                    let id = http_create_session(&http, &token, &scene).await?;
                    let r = ws_lockstep_with(
                        &http,
                        &id,
                        &token,
                        &frames,
                        transport == "ws-binary",
                        binary_results,
                    )
                    .await?;
                    http_close_session(&http, &token, &id).await?;
                    r
                }
                other => return Err(format!("--transport {other:?}: ws, ws-binary or grpc")),
            };
            if let Some(path) = out {
                let mut f = std::fs::File::create(&path).map_err(|e| e.to_string())?;
                for r in &results {
                    writeln!(f, "{r}").map_err(|e| e.to_string())?;
                }
            }
            // The first frame is cold: statistics over the warm ones.
            let warm = &times[1.min(times.len())..];
            let mut e2e: Vec<f64> = warm.iter().map(|t| t.0).collect();
            let mut wall: Vec<f64> = warm.iter().map(|t| t.1).collect();
            let mut over: Vec<f64> = warm.iter().map(|t| t.0 - t.1).collect();
            for v in [&mut e2e, &mut wall, &mut over] {
                v.sort_by(f64::total_cmp);
            }
            println!(
                "{}",
                serde_json::json!({
                    "transport": transport, "binary_results": binary_results,
                    "frames": results.len(),
                    "cold_first_frame_ms": times.first().map(|t| t.0),
                    "e2e_p50_ms": pct(&e2e, 0.5), "e2e_p95_ms": pct(&e2e, 0.95),
                    "registration_p50_ms": pct(&wall, 0.5),
                    "overhead_p50_ms": pct(&over, 0.5), "overhead_p95_ms": pct(&over, 0.95),
                    "overhead_max_ms": over.last(),
                })
            );
        }
        Cmd::Load {
            common,
            sessions,
            hz,
            seconds,
            binary,
            binary_results,
            phases,
        } => {
            let phases = match phases.as_str() {
                "spread" => Phases::Spread,
                "together" => Phases::Together,
                other => return Err(format!("--phases {other:?}: spread or together")),
            };
            if !common.http.ip().is_loopback() {
                return Err("the load test only targets loopback addresses".into());
            }
            let token = token(&common)?;
            let scene = SceneFiles::read(&common.scene)?;
            let frames = read_frames(&common.frames)?;
            let spec = LoadSpec {
                sessions,
                hz,
                duration: Duration::from_secs_f64(seconds.clamp(0.1, 600.0)),
                binary,
                binary_results,
                phases,
            };
            let rep = load_test(common.endpoints()?.0, &token, &scene, &frames, &spec).await?;
            println!(
                "{}",
                serde_json::to_string_pretty(&rep).map_err(|e| e.to_string())?
            );
        }
    }
    Ok(())
}

#[tokio::main]
async fn main() -> std::process::ExitCode {
    match run(Args::parse()).await {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("client: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
