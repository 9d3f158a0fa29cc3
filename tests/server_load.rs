//! Bounded load tests on loopback: concurrent sessions streaming over WebSocket at 30 Hz. The
//! short one (8 sessions × 3 s, small scene) runs with `cargo test`; the full one of the issue
//! (8 sessions × 20 s on the liver phantom) is ignored and meant for a release build:
//! `cargo test --release --test server_load -- --ignored --nocapture`.

use std::time::Duration;

#[path = "../examples/client/lib.rs"]
mod client;
mod server_support;

use client::*;
use server_support::*;

/// Single-session registration time: warm frames sent one after the other (ms: p50, p95 of
/// the registration, p50 of the transport overhead e2e − registration).
async fn single_session(
    addr: std::net::SocketAddr,
    scene: &SceneFiles,
    frames: &[(String, Vec<[f64; 3]>)],
) -> (f64, f64, f64) {
    let id = http_create_session(addr, TOKEN_A, scene).await.unwrap();
    let (_, times) = ws_lockstep(addr, &id, TOKEN_A, frames, false)
        .await
        .unwrap();
    http_close_session(addr, TOKEN_A, &id).await.unwrap();
    let warm = &times[1..];
    let mut wall: Vec<f64> = warm.iter().map(|t| t.1).collect();
    let mut over: Vec<f64> = warm.iter().map(|t| t.0 - t.1).collect();
    wall.sort_by(f64::total_cmp);
    over.sort_by(f64::total_cmp);
    (pct(&wall, 0.5), pct(&wall, 0.95), pct(&over, 0.5))
}

async fn run_load(
    case: &std::path::Path,
    frames: &[(String, Vec<[f64; 3]>)],
    seconds: f64,
    worker_threads: usize,
) -> (LoadReport, (f64, f64, f64)) {
    let mut cfg = test_config(&format!("load-{}", seconds as u64));
    cfg.worker_threads = worker_threads;
    cfg.limits.max_frames_per_second = 60.0;
    let server = start(cfg).await;
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let single = single_session(server.http_addr, &scene, &frames[..frames.len().min(12)]).await;
    let spec = LoadSpec {
        sessions: 8,
        hz: 30.0,
        duration: Duration::from_secs_f64(seconds),
        binary: true,
        binary_results: false,
        phases: Phases::Spread,
    };
    let rep = load_test(server.http_addr, TOKEN_A, &scene, frames, &spec)
        .await
        .unwrap();
    let m = server.state().metrics.render();
    assert!(m.contains("livereg_sessions 0"), "sessions left open");
    server.shutdown().await.unwrap();
    eprintln!(
        "single session: registration p50 {:.1} ms, p95 {:.1} ms, transport overhead p50 {:.2} ms",
        single.0, single.1, single.2
    );
    eprintln!("load: {}", serde_json::to_string_pretty(&rep).unwrap());
    (rep, single)
}

fn check(rep: &LoadReport, single: (f64, f64, f64), factor: f64, slack_ms: f64) {
    assert_eq!(rep.errors, 0, "errors: {:?}", rep.error_samples);
    assert!(rep.results >= 8, "too few results: {rep:?}");
    // Every frame sent is either answered or counted as skipped (newest wins).
    assert_eq!(rep.results + rep.skipped, rep.sent, "{rep:?}");
    let bound = factor * single.1 + slack_ms;
    assert!(
        rep.e2e_p95_ms <= bound,
        "p95 end-to-end {:.1} ms exceeds {bound:.1} ms ({factor} x single-session p95 {:.1} ms + {slack_ms} ms)",
        rep.e2e_p95_ms,
        single.1
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn eight_sessions_at_30_hz_for_3_s_no_errors_bounded_latency() {
    let case = small_case("load", 30);
    let frames = read_frames(&case.join("frames")).unwrap();
    let (rep, single) = run_load(&case, &frames, 3.0, 2).await;
    // Debug build on a shared 2-core machine: a loose bound; the release numbers are in
    // docs/server.md.
    check(&rep, single, 3.0, 150.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "20 s of load on the phantom; run in release: cargo test --release --test server_load -- --ignored --nocapture"]
async fn eight_sessions_at_30_hz_for_20_s_on_the_phantom() {
    let dir = temp_dir("load-phantom");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_livereg"))
        .args([
            "demo",
            "--out",
            dir.to_str().unwrap(),
            "--frames",
            "12",
            "--scenarios",
            "tool-push",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let case = dir.join("phantom");
    let frames = read_frames(&dir.join("tool-push/frames")).unwrap();
    let (rep, single) = run_load(&case, &frames, 20.0, 2).await;
    check(&rep, single, 2.0, 0.0);
}
