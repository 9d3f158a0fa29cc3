//! Round trips with the real clients against an in-process server on loopback: create, stream
//! 100 frames, read the results, close — over WebSocket (JSON and binary frames; Rust client),
//! gRPC (bidirectional stream; Rust client) and the Python client (stdlib only). Every result
//! equals `livereg register`'s on the same frame files.

use std::time::Instant;

use livereg::server::proto;

#[path = "../examples/client/lib.rs"]
mod client;
mod server_support;

use client::*;
use server_support::*;

const FRAMES: usize = 100;

async fn grpc_round_trip(
    addr: std::net::SocketAddr,
    scene: &SceneFiles,
    frames: &[(String, Vec<[f64; 3]>)],
) -> Vec<serde_json::Value> {
    let mut g = GrpcClient::connect(addr, TOKEN_A).await.unwrap();
    let info = g.create_session(scene).await.unwrap();
    assert_eq!(info.structures, ["targets"]);
    let (tx, rx) = tokio::sync::mpsc::channel::<proto::StreamRequest>(4);
    let mut out = g
        .inner
        .stream(g.req(tokio_stream::wrappers::ReceiverStream::new(rx)))
        .await
        .unwrap()
        .into_inner();
    let mut results = Vec::new();
    for (k, (name, pts)) in frames.iter().enumerate() {
        tx.send(proto::StreamRequest {
            session_id: if k == 0 {
                info.id.clone()
            } else {
                String::new()
            },
            frame: Some(frame_f64(k as u64, name, pts)),
        })
        .await
        .unwrap();
        let m = out.message().await.unwrap().expect("a response");
        match m.kind {
            Some(proto::stream_response::Kind::Result(r)) => {
                assert_eq!(r.seq, k as u64);
                assert_eq!(r.surface.len(), 3 * info.surface_vertices as usize);
                results.push(proto_to_record(&r));
            }
            other => panic!("frame {k}: {other:?}"),
        }
    }
    drop(tx);
    assert!(
        out.message().await.unwrap().is_none(),
        "stream ends after the client's end"
    );
    // A unary frame too, then close.
    let r = g
        .register(&info.id, 1000, "unary", &frames[0].1)
        .await
        .unwrap();
    assert_eq!(r.frame, FRAMES as u64);
    let closed = g.close_session(&info.id).await.unwrap();
    assert_eq!(closed.frames_registered, FRAMES as u64 + 1);
    results
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rust_and_python_clients_round_trip_100_frames_equal_to_register() {
    let t0 = Instant::now();
    let case = small_case("roundtrip", FRAMES);
    let c = case.clone();
    let want = tokio::task::spawn_blocking(move || reference(&c));
    let server = start(test_config("roundtrip")).await;
    let http_addr = server.http_addr;
    let grpc_addr = server.grpc_addr.unwrap();
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let frames = read_frames(&case.join("frames")).unwrap();
    assert_eq!(frames.len(), FRAMES);

    // Python (stdlib) over WebSocket with JSON frames, in a child process.
    let python = std::process::Command::new("python3")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    let py = if python {
        let token_file = case.join("token.txt");
        std::fs::write(&token_file, format!("room-a:{TOKEN_A}\n")).unwrap();
        let script = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/clients/python/livereg_client.py"
        );
        let out = case.join("python.jsonl");
        let args: Vec<String> = vec![
            script.into(),
            "--url".into(),
            format!("http://{http_addr}"),
            "--token-file".into(),
            token_file.display().to_string(),
            "roundtrip".into(),
            "--scene".into(),
            case.join("scene.toml").display().to_string(),
            "--frames".into(),
            case.join("frames").display().to_string(),
            "--out".into(),
            out.display().to_string(),
        ];
        Some(tokio::task::spawn_blocking(move || {
            let o = std::process::Command::new("python3")
                .args(&args)
                .output()
                .unwrap();
            assert!(
                o.status.success(),
                "python client failed: {}",
                String::from_utf8_lossy(&o.stderr)
            );
            std::fs::read_to_string(out)
                .unwrap()
                .lines()
                .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
                .collect::<Vec<_>>()
        }))
    } else {
        eprintln!("SKIPPED the Python client: python3 is not installed");
        None
    };

    // Rust: WebSocket JSON, WebSocket binary (f32-exact frames), gRPC stream, concurrently.
    let (s1, f1) = (scene.clone(), frames.clone());
    let ws_json = tokio::spawn(async move {
        let id = http_create_session(http_addr, TOKEN_A, &s1).await.unwrap();
        let (r, _) = ws_lockstep(http_addr, &id, TOKEN_A, &f1, false)
            .await
            .unwrap();
        let closed = http_close_session(http_addr, TOKEN_A, &id).await.unwrap();
        assert_eq!(closed["frames_registered"], FRAMES);
        r
    });
    let (s2, f2) = (scene.clone(), frames.clone());
    let ws_bin = tokio::spawn(async move {
        let id = http_create_session(http_addr, TOKEN_A, &s2).await.unwrap();
        let (r, _) = ws_lockstep(http_addr, &id, TOKEN_A, &f2, true)
            .await
            .unwrap();
        http_close_session(http_addr, TOKEN_A, &id).await.unwrap();
        r
    });
    let grpc = grpc_round_trip(grpc_addr, &scene, &frames).await;
    let ws_json = ws_json.await.unwrap();
    let ws_bin = ws_bin.await.unwrap();
    let want = want.await.unwrap();
    assert_eq!(want.len(), FRAMES);
    for (label, got) in [
        ("ws-json", &ws_json),
        ("ws-binary", &ws_bin),
        ("grpc", &grpc),
    ] {
        assert_eq!(got.len(), FRAMES, "{label}");
        for (g, w) in got.iter().zip(&want) {
            assert_matches_reference(g, w);
        }
    }
    // Sources: JSON frames and gRPC carry the file names, binary frames "frame-<seq>".
    assert_eq!(ws_json[3]["source"], "f003.xyz");
    assert_eq!(ws_bin[3]["source"], "frame-3");
    assert_eq!(grpc[3]["source"], "f003.xyz");
    if let Some(py) = py {
        let py = py.await.unwrap();
        assert_eq!(py.len(), FRAMES);
        for (g, w) in py.iter().zip(&want) {
            assert_matches_reference(g, w);
            assert_eq!(g["source"], w["source"]);
        }
    }
    server.shutdown().await.unwrap();
    eprintln!("round trips: {:.1} s", t0.elapsed().as_secs_f64());
}
