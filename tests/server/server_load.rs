//! Load on loopback: 8 sessions streaming over WebSocket at 30 Hz for 3 s (small scene). What
//! is asserted is behaviour, not speed: no errors, every frame answered or counted as skipped
//! (newest wins), and the server's own accounting agreeing with what the clients saw (each
//! registered frame waited for a slot once; nothing is left queued). The latencies are printed
//! only: performance is measured in release by the example client's `load` command against
//! `livereg serve` (docs/server.md, "Load"), not asserted in a debug-build test.

use std::time::Duration;

use crate::client::*;
use crate::server_support::*;

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
) -> (LoadReport, [u64; 3], [u64; 3]) {
    let mut cfg = test_config(&format!("load-{}", seconds as u64));
    cfg.worker_threads = worker_threads;
    cfg.limits.max_frames_per_second = 60.0;
    let server = start(cfg).await;
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let single = single_session(server.http_addr, &scene, &frames[..frames.len().min(12)]).await;
    let before = accounting(&server.metrics_text());
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
    let m = server.metrics_text();
    assert!(m.contains("livereg_sessions 0"), "sessions left open");
    let after = accounting(&m);
    server.shutdown().await.unwrap();
    eprintln!(
        "single session: registration p50 {:.1} ms, p95 {:.1} ms, transport overhead p50 {:.2} ms",
        single.0, single.1, single.2
    );
    eprintln!("load: {}", serde_json::to_string_pretty(&rep).unwrap());
    (rep, before, after)
}

/// The value of the metric line starting with `key` (e.g. `livereg_frames_total{outcome="skipped"}`)
/// in the Prometheus text `text`; 0 when absent (a counter never incremented).
fn metric(text: &str, key: &str) -> u64 {
    text.lines()
        .find_map(|l| l.strip_prefix(key)?.trim().parse::<f64>().ok())
        .map_or(0, |v| v as u64)
}

/// Frames registered, skipped and slot waits counted by the server, as metrics text.
fn accounting(text: &str) -> [u64; 3] {
    [
        metric(text, "livereg_frames_total{outcome=\"registered\"}"),
        metric(text, "livereg_frames_total{outcome=\"skipped\"}"),
        metric(text, "livereg_queue_wait_seconds_count"),
    ]
}

fn check(rep: &LoadReport, before: [u64; 3], after: [u64; 3]) {
    assert_eq!(rep.errors, 0, "errors: {:?}", rep.error_samples);
    assert!(rep.results >= 8, "too few results: {rep:?}");
    // Every frame sent is either answered or counted as skipped (newest wins).
    assert_eq!(rep.results + rep.skipped, rep.sent, "{rep:?}");
    let [registered, skipped, waits] = [0, 1, 2].map(|i| after[i] - before[i]);
    // The server registered every answered frame plus each session's warm-up frame, skipped
    // exactly the frames the clients were told about, and every registered frame left the
    // queue (a frame still waiting would have no wait recorded).
    assert_eq!(
        registered,
        rep.results + rep.sessions as u64,
        "server registered {registered}, clients got {} results + {} warm-ups",
        rep.results,
        rep.sessions
    );
    assert_eq!(skipped, rep.skipped, "server skipped {skipped}: {rep:?}");
    assert_eq!(
        waits, registered,
        "slot waits {waits} for {registered} frames"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn eight_sessions_at_30_hz_for_3_s_every_frame_accounted_for() {
    let case = small_case("load", 30);
    let frames = read_frames(&case.join("frames")).unwrap();
    let (rep, before, after) = run_load(&case, &frames, 3.0, 2).await;
    check(&rep, before, after);
}
