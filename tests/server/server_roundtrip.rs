//! Round trips with the real clients against an in-process server on loopback: create, stream
//! 100 frames, read the results, close — over WebSocket (JSON and binary frames; Rust client),
//! gRPC (bidirectional stream; Rust client) and the Python client (stdlib only). Every result
//! equals `livereg register`'s on the same frame files.

use std::time::Instant;

use livereg::server::proto;

use crate::client::*;
use crate::server_support::*;

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
    require_python();
    let py = {
        let case = case.clone();
        tokio::spawn(async move {
            python_roundtrip_results(&format!("http://{http_addr}"), &case, "python.jsonl", &[])
                .await
        })
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
    let py = py.await.unwrap();
    assert_eq!(py.len(), FRAMES);
    for (g, w) in py.iter().zip(&want) {
        assert_matches_reference(g, w);
        assert_eq!(g["source"], w["source"]);
    }
    server.shutdown().await.unwrap();
    eprintln!("round trips: {:.1} s", t0.elapsed().as_secs_f64());
}

/// `a` and `b` equal up to `b`'s rounding to f32 (half an f32 ulp, 2⁻²⁴ relative) plus the
/// run-to-run spread of registration (1e-6 scene units, as `same`).
fn close_f32(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-6 + b.abs() * f64::from(f32::EPSILON) / 2.0 * 1.0001
}

/// The arrays of points `got` (a binary result) and `want` (a JSON result): same lengths, each
/// coordinate [`close_f32`], and every coordinate of `got` an f32 (it came through f32).
fn assert_points_f32(got: &serde_json::Value, want: &serde_json::Value, at: &str) {
    let (g, w) = (got.as_array().unwrap(), want.as_array().unwrap());
    assert_eq!(g.len(), w.len(), "{at}: point counts");
    assert!(!g.is_empty(), "{at}: no points");
    for (i, (p, q)) in g.iter().zip(w).enumerate() {
        for k in 0..3 {
            let (a, b) = (p[k].as_f64().unwrap(), q[k].as_f64().unwrap());
            assert!(close_f32(a, b), "{at}[{i}][{k}]: {a} against {b}");
            assert_eq!(f64::from(a as f32), a, "{at}[{i}][{k}]: {a} is not an f32");
        }
    }
}

/// A binary result (decoded to the JSON shape) against the JSON result of the same frame: the
/// same keys, the same metadata, the same surface and structures to f32 precision.
fn assert_binary_matches_json(got: &serde_json::Value, want: &serde_json::Value) {
    let at = format!("frame {}", want["frame"]);
    let keys = |v: &serde_json::Value| {
        let mut k: Vec<String> = v.as_object().unwrap().keys().cloned().collect();
        k.sort();
        k
    };
    assert_eq!(keys(got), keys(want), "{at}: keys");
    for key in ["type", "seq", "frame", "source", "converged", "skipped"] {
        assert_eq!(got[key], want[key], "{at}.{key}");
    }
    same(&want["rigid"], &got["rigid"], &format!("{at}.rigid")).unwrap();
    for key in [
        "icp_iterations",
        "newton_iterations",
        "surface_rms",
        "flags",
        "error",
    ] {
        same(
            &want["diagnostics"][key],
            &got["diagnostics"][key],
            &format!("{at}.diagnostics.{key}"),
        )
        .unwrap();
    }
    assert_points_f32(&got["surface"], &want["surface"], &format!("{at}.surface"));
    let ws = want["structures"].as_object().unwrap();
    assert_eq!(keys(&got["structures"]), keys(&want["structures"]));
    for (name, pts) in ws {
        assert_points_f32(
            &got["structures"][name],
            pts,
            &format!("{at}.structures.{name}"),
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn binary_results_equal_json_results_to_f32_precision() {
    const N: usize = 12;
    let case = small_case("binary-results", N);
    let server = start(test_config("binary-results")).await;
    let addr = server.http_addr;
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let frames = read_frames(&case.join("frames")).unwrap();

    // A bad `results` value or an unknown parameter is refused before the upgrade.
    let id = http_create_session(addr, TOKEN_A, &scene).await.unwrap();
    let auth = format!("Bearer {TOKEN_A}");
    for (query, names) in [("results=xml", "xml"), ("result=binary", "result")] {
        let r = http(
            addr,
            "GET",
            &format!("/v1/sessions/{id}/stream?{query}"),
            &[("Authorization", &auth)],
            b"",
        )
        .await
        .unwrap();
        assert_eq!(r.status, 400, "{query}");
        let msg = r.json()["error"]["message"].as_str().unwrap().to_string();
        assert!(msg.contains(names), "{query}: {msg}");
    }

    // The same binary frames (f32) with JSON results and with binary results, each in its own
    // session; then the Python client with binary results.
    let (json, _) = ws_lockstep_with(addr, &id, TOKEN_A, &frames, true, false)
        .await
        .unwrap();
    http_close_session(addr, TOKEN_A, &id).await.unwrap();
    let id = http_create_session(addr, TOKEN_A, &scene).await.unwrap();
    let (binary, _) = ws_lockstep_with(addr, &id, TOKEN_A, &frames, true, true)
        .await
        .unwrap();
    http_close_session(addr, TOKEN_A, &id).await.unwrap();
    assert_eq!(json.len(), N);
    assert_eq!(binary.len(), N);
    for (b, j) in binary.iter().zip(&json) {
        assert_binary_matches_json(b, j);
    }
    // The frames bend the body: the comparison is not between rest shapes.
    assert_ne!(json[0]["surface"], json[3]["surface"]);

    // POST /frames answers in the binary encoding with `?results=binary` (the same binary
    // frames, a fresh session); a bad value is a 400 naming it.
    let id = http_create_session(addr, TOKEN_A, &scene).await.unwrap();
    let path = format!("/v1/sessions/{id}/frames");
    let r = http(
        addr,
        "POST",
        &format!("{path}?results=yaml"),
        &[("Authorization", &auth)],
        b"{}",
    )
    .await
    .unwrap();
    assert_eq!(r.status, 400);
    assert!(r.json()["error"]["message"]
        .as_str()
        .unwrap()
        .contains("yaml"));
    for (k, (_, pts)) in frames.iter().enumerate() {
        let f32s: Vec<[f32; 3]> = pts.iter().map(|p| p.map(|c| c as f32)).collect();
        let body = livereg::server::codec::encode_binary_frame(k as u64, &f32s, None);
        let r = http(
            addr,
            "POST",
            &format!("{path}?results=binary"),
            &[
                ("Authorization", &auth),
                ("Content-Type", "application/octet-stream"),
            ],
            &body,
        )
        .await
        .unwrap();
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        assert_eq!(
            r.headers.get("content-type").map(String::as_str),
            Some("application/octet-stream")
        );
        let msg = livereg::server::result_codec::decode_binary_result(&r.body).unwrap();
        assert_binary_matches_json(&binary_result_to_json(&msg), &json[k]);
    }
    http_close_session(addr, TOKEN_A, &id).await.unwrap();

    require_python();
    let url = format!("http://{addr}");
    let py = python_roundtrip_results(
        &url,
        &case,
        "python-binary.jsonl",
        &["--transport", "ws-binary", "--binary-results"],
    )
    .await;
    assert_eq!(py.len(), N);
    for (p, j) in py.iter().zip(&json) {
        assert_binary_matches_json(p, j);
    }

    // The Python client's single frames (JSON, full precision) with JSON and with binary
    // results: the same registrations, the second at f32 precision.
    let http_json =
        python_roundtrip_results(&url, &case, "python-http.jsonl", &["--transport", "http"]).await;
    let http_binary = python_roundtrip_results(
        &url,
        &case,
        "python-http-binary.jsonl",
        &["--transport", "http", "--binary-results"],
    )
    .await;
    assert_eq!(http_json.len(), N);
    assert_eq!(http_binary.len(), N);
    for (b, j) in http_binary.iter().zip(&http_json) {
        assert_binary_matches_json(b, j);
    }

    // The Python decoder on a message of the server's encoder, whole and truncated.
    let msg: livereg::server::codec::ResultMessage =
        serde_json::from_value(json[5].clone()).unwrap();
    let bytes = livereg::server::result_codec::encode_binary_result(&msg).unwrap();
    let file = case.join("result.bin");
    let decode = |b: &[u8]| {
        std::fs::write(&file, b).unwrap();
        std::process::Command::new("python3")
            .args([PYTHON_CLIENT, "decode-result", file.to_str().unwrap()])
            .output()
            .unwrap()
    };
    let o = decode(&bytes);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let decoded: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_binary_matches_json(&decoded, &json[5]);
    for cut in [bytes.len() - 1, bytes.len() / 2, 10] {
        let o = decode(&bytes[..cut]);
        assert_eq!(o.status.code(), Some(1), "truncated to {cut}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("binary result:"), "truncated to {cut}: {err}");
    }
    server.shutdown().await.unwrap();
}
