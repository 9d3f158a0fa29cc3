//! Scale-out on one machine: two `livereg serve` processes behind a real nginx,
//! configured from `deploy/nginx/livereg.conf` (consistent hashing on `X-Livereg-Session`, as
//! the Kubernetes Ingress asks ingress-nginx). Sixteen sessions created through the proxy,
//! half over HTTP and half over gRPC, each stay on one backend over HTTP, WebSocket and gRPC;
//! then the backend holding the Python client's session is drained (SIGTERM) in mid-stream,
//! and every session it held moves to the other backend, Rust (WebSocket and gRPC) and Python
//! alike, with every frame answered.
//!
//! nginx comes from the OS packages (`scripts/test` installs it); without it this test fails.

use std::collections::BTreeSet;
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::client::*;
use crate::server_support::*;

/// A `livereg serve` process on loopback.
struct Backend {
    child: Child,
    /// HTTP, WebSocket and gRPC (the backend serves gRPC on its HTTP port too).
    http: SocketAddr,
}

impl Drop for Backend {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn spawn_backend(dir: &Path, name: &str) -> Backend {
    let config = dir.join(format!("{name}.toml"));
    std::fs::write(
        &config,
        format!(
            "bind = \"127.0.0.1:0\"\ngrpc_bind = \"127.0.0.1:0\"\ndata_dir = {:?}\nrecord = false\nworker_threads = 2\nshutdown_grace_s = 10\nlog_format = \"json\"\nlog_filter = \"info\"\n[[tokens]]\nname = \"room-a\"\ntoken = \"{TOKEN_A}\"\n[limits]\nmax_frames_per_second = 1000.0\nmax_sessions_per_token = 64\nmax_sessions = 64\n",
            s(&dir.join(format!("data-{name}")))
        ),
    )
    .unwrap();
    let mut serve = Command::new(env!("CARGO_BIN_EXE_livereg"));
    serve.args(["serve", "--config", s(&config)]);
    let (child, listening) = spawn_serve(serve);
    let http = http_addr_of(&listening);
    Backend { child, http }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// nginx from `deploy/nginx/livereg.conf` in front of `backends`: its HTTP and gRPC addresses.
fn start_nginx(dir: &Path, backends: &[&Backend]) -> (Child, SocketAddr, SocketAddr) {
    let template = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/nginx/livereg.conf"),
    )
    .unwrap();
    let prefix = dir.join("nginx");
    std::fs::create_dir_all(&prefix).unwrap();
    let (hp, gp) = (free_port(), free_port());
    let servers = backends
        .iter()
        .map(|b| format!("        server {} max_fails=1 fail_timeout=10s;", b.http))
        .collect::<Vec<_>>()
        .join("\n");
    let conf = template
        .replace("{{PREFIX}}", s(&prefix))
        .replace("{{BACKENDS}}", &servers)
        .replace("{{HTTP_LISTEN}}", &format!("127.0.0.1:{hp}"))
        .replace("{{GRPC_LISTEN}}", &format!("127.0.0.1:{gp}"));
    assert!(!conf.contains("{{"), "unfilled template field");
    let path = prefix.join("nginx.conf");
    std::fs::write(&path, conf).unwrap();
    let child = Command::new("nginx")
        .args([
            "-c",
            s(&path),
            "-p",
            s(&prefix),
            "-e",
            s(&prefix.join("error.log")),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("nginx runs (Debian package nginx-light; scripts/test installs it)");
    let http: SocketAddr = format!("127.0.0.1:{hp}").parse().unwrap();
    let grpc: SocketAddr = format!("127.0.0.1:{gp}").parse().unwrap();
    let t = Instant::now();
    while std::net::TcpStream::connect(http).is_err() || std::net::TcpStream::connect(grpc).is_err()
    {
        assert!(t.elapsed() < Duration::from_secs(20), "nginx did not start");
        std::thread::sleep(Duration::from_millis(50));
    }
    (child, http, grpc)
}

/// The session ids a backend holds for room A, asked directly (not through the proxy).
async fn held(b: SocketAddr) -> BTreeSet<String> {
    let r = http(
        b,
        "GET",
        "/v1/sessions",
        &[("Authorization", &format!("Bearer {TOKEN_A}"))],
        b"",
    )
    .await
    .unwrap();
    r.json()["sessions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["id"].as_str().unwrap().to_string())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_stay_on_their_backend_and_move_when_it_drains() {
    const SESSIONS: usize = 16;
    const FRAMES: usize = 40;
    let case = small_case("scale", FRAMES);
    let py_case = small_case("scale-py", 150);
    let dir = temp_dir("scale-out");
    let a = spawn_backend(&dir, "a");
    let b = spawn_backend(&dir, "b");
    let (mut nginx, proxy, proxy_grpc) = start_nginx(&dir, &[&a, &b]);
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let frames = read_frames(&case.join("frames")).unwrap();
    let mut g = GrpcClient::connect(proxy_grpc, TOKEN_A).await.unwrap();

    // Routing: half the sessions created over HTTP, half over gRPC, each then used over
    // WebSocket and gRPC. A request that reached the wrong backend would be answered
    // `not_found` and counted as a move.
    let mut sessions = Vec::new();
    for i in 0..SESSIONS {
        let mut m = if i % 2 == 0 {
            MovingSession::create(proxy, TOKEN_A, &scene).await.unwrap()
        } else {
            let id = new_client_session_id();
            g.create_session_with_id(&scene, &id).await.unwrap();
            MovingSession {
                ep: proxy.into(),
                token: TOKEN_A.into(),
                scene: scene.clone(),
                id,
                moves: 0,
                give_up: Duration::from_secs(60),
                pace: Duration::ZERO,
            }
        };
        let r = m.stream_ws(&frames[..3]).await.unwrap();
        assert_eq!(r.len(), 3);
        let r = m.register_grpc(&mut g, &frames[3..6]).await.unwrap();
        assert_eq!(r.len(), 3);
        assert_eq!(m.moves, 0, "session {i} was routed to a backend without it");
        sessions.push(m);
    }
    let (on_a, on_b) = (held(a.http).await, held(b.http).await);
    let all: BTreeSet<String> = sessions.iter().map(|m| m.id.clone()).collect();
    assert!(on_a.is_disjoint(&on_b));
    assert_eq!(
        on_a.union(&on_b).cloned().collect::<BTreeSet<_>>(),
        all,
        "every session on exactly one backend"
    );
    assert!(
        !on_a.is_empty() && !on_b.is_empty(),
        "the hash spreads sessions"
    );

    // The Python client streams a long session through the proxy, following moves.
    let token_file = dir.join("token.txt");
    std::fs::write(&token_file, format!("room-a:{TOKEN_A}\n")).unwrap();
    let py_out = dir.join("python.jsonl");
    let python = Command::new("python3")
        .args([
            PYTHON_CLIENT,
            "--url",
            &format!("http://{proxy}"),
            "--token-file",
            s(&token_file),
            "roundtrip",
            "--scene",
            s(&py_case.join("scene.toml")),
            "--frames",
            s(&py_case.join("frames")),
            "--out",
            s(&py_out),
            "--transport",
            "ws-binary",
            "--follow-moves",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3 runs");
    // Its session is the one neither list had: the backend holding it is the one to drain.
    let t = Instant::now();
    let (drained, kept, python_id) = loop {
        let (na, nb) = (held(a.http).await, held(b.http).await);
        if let Some(id) = na.difference(&all).next() {
            break (a.http, b.http, id.clone());
        }
        if let Some(id) = nb.difference(&all).next() {
            break (b.http, a.http, id.clone());
        }
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "the Python session never appeared"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    let moving: BTreeSet<String> = held(drained).await.intersection(&all).cloned().collect();
    assert!(
        !moving.is_empty(),
        "the drained backend holds Rust sessions too"
    );

    // Every Rust session streams on: 12 over WebSocket, 4 over gRPC.
    let mut streams = tokio::task::JoinSet::new();
    for (i, mut m) in sessions.into_iter().enumerate() {
        // At a camera's pace (30 Hz), so that the drain below lands mid-stream however fast
        // the machine registers (unpaced, a session could finish its 40 frames first).
        m.pace = Duration::from_millis(33);
        let f = frames.clone();
        let grpc_ep = proxy_grpc;
        streams.spawn(async move {
            let n = if i % 4 == 3 {
                let mut g = GrpcClient::connect(grpc_ep, TOKEN_A).await.unwrap();
                m.register_grpc(&mut g, &f).await.map(|r| r.len())
            } else {
                m.stream_ws(&f).await.map(|r| {
                    for (k, v) in r.iter().enumerate() {
                        assert_eq!(v["seq"], k as u64, "results in order, each once");
                    }
                    r.len()
                })
            };
            (m.id.clone(), m.moves, n)
        });
    }
    // Drain mid-stream: SIGTERM, as Kubernetes does on scale-down or a rolling update.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let pid = if drained == a.http {
        a.child.id()
    } else {
        b.child.id()
    };
    let killed = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status()
        .unwrap();
    assert!(killed.success());

    let mut moved = 0;
    while let Some(r) = streams.join_next().await {
        let (id, moves, n) = r.unwrap();
        let n = n.unwrap_or_else(|e| panic!("session {id}: {e}"));
        assert_eq!(n, FRAMES, "session {id}: every frame answered");
        if moving.contains(&id) {
            assert!(
                moves >= 1,
                "session {id} was on the drained backend and did not move"
            );
            moved += 1;
        } else {
            assert_eq!(moves, 0, "session {id} moved although its backend stayed");
        }
    }
    assert_eq!(
        moved,
        moving.len(),
        "100 % of the drained backend's sessions moved"
    );
    let out = tokio::task::spawn_blocking(move || python.wait_with_output().unwrap())
        .await
        .unwrap();
    assert!(
        out.status.success(),
        "python: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["session"], python_id.as_str());
    assert_eq!(summary["frames"], 150, "{summary}");
    assert!(summary["moves"].as_u64().unwrap() >= 1, "{summary}");
    let lines = std::fs::read_to_string(&py_out).unwrap();
    assert_eq!(lines.lines().count(), 150);
    // The moved sessions now live on the other backend.
    let now_kept = held(kept).await;
    assert!(moving.is_subset(&now_kept));
    assert!(now_kept.contains(&python_id));
    eprintln!(
        "scale-out: {} sessions, {} on the drained backend, all moved; Python moved {} time(s); frames lost 0",
        SESSIONS,
        moving.len(),
        summary["moves"]
    );
    let _ = nginx.kill();
    let _ = nginx.wait();
    drop((a, b));
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&case);
    let _ = std::fs::remove_dir_all(&py_case);
}
