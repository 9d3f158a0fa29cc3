//! Every served session writes one MCAP recording: a WebSocket session on the
//! phantom is read back frame for frame and replays with zero difference; a `livereg serve`
//! killed (SIGKILL) in the middle of a stream leaves a recording holding every frame whose
//! result the client had received; a `livereg serve` whose disk fills up mid-stream goes on
//! unrecorded, says so, and leaves every frame answered before the disk filled readable.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use livereg::recording::Recording;
use serde_json::Value;

use crate::client::*;
use crate::server_support::*;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Checks that the recording's result `k` is the result the client received.
fn assert_recorded(rec: &Recording, k: usize, got: &Value) {
    assert_eq!(rec.frames[k].frame, k);
    assert_eq!(rec.results[k].record.frame, k);
    let recorded = serde_json::to_value(&rec.results[k].record).unwrap();
    same(&recorded, got, &format!("frame {k}")).unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_served_session_is_recorded_and_replays_identically() {
    const N: usize = 3;
    let case = temp_dir("rec-phantom");
    let frames = phantom_case(&case, N);
    // The test configuration's time budget is one no frame reaches (a cut frame's result
    // depends on the machine's speed); the loop below checks that none did.
    let cfg = test_config("rec-phantom");
    let recordings = cfg.data_dir.join("recordings");
    let server = start(cfg).await;
    let addr = server.http_addr;
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();

    // The create response names the recording.
    let info = http_create_session_info(addr, TOKEN_A, &scene)
        .await
        .unwrap();
    let id = info["id"].as_str().unwrap().to_string();
    // Its file name in the recordings directory, never the server's path.
    let name = info["recording"].as_str().expect("recording file name");
    assert_eq!(name, format!("{id}.mcap"));
    let path = recordings.join(name);
    assert!(path.is_file());

    let mut ws = WsClient::connect(addr, &id, TOKEN_A).await.unwrap();
    let mut got = Vec::new();
    for (k, pts) in frames.iter().enumerate() {
        ws.send_json(k as u64, &format!("f{k}"), pts).await.unwrap();
        match ws.next().await {
            Some(WsEvent::Result(v)) => got.push(v),
            other => panic!("frame {k}: {other:?}"),
        }
    }
    ws.close().await;
    let status = http_close_session(addr, TOKEN_A, &id).await.unwrap();
    assert_eq!(status["recording"], info["recording"]);
    // Shutdown waits for the session's worker, which finishes the recording.
    server.shutdown().await.unwrap();

    let rec = Recording::open(&path).unwrap();
    assert!(rec.finished, "{}", rec.describe());
    assert_eq!(rec.frames.len(), N);
    assert_eq!(rec.results.len(), N);
    assert_eq!(rec.session.command, "serve");
    assert_eq!(rec.session.notes.get("session"), Some(&id));
    // The owner is the token's name (never the token).
    assert_eq!(
        rec.session.notes.get("owner").map(String::as_str),
        Some("room-a")
    );
    for (k, v) in got.iter().enumerate() {
        assert!(
            !rec.results[k]
                .record
                .diagnostics
                .flags
                .iter()
                .any(|f| f == "time_budget"),
            "frame {k} was cut by the time budget: {:?}",
            rec.results[k].record.diagnostics
        );
        assert_recorded(&rec, k, v);
        assert_eq!(rec.frames[k].points.len(), 3 * frames[k].len());
        assert_eq!(
            rec.results[k].surface.len(),
            3 * info["surface_vertices"].as_u64().unwrap() as usize
        );
    }

    // Replay through this build: zero difference.
    let c = path.clone();
    let o = tokio::task::spawn_blocking(move || {
        Command::new(env!("CARGO_BIN_EXE_livereg"))
            .args(["replay", s(&c), "--json"])
            .output()
            .unwrap()
    })
    .await
    .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "replay: {stderr}");
    let report: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(report["frames"], N, "{report}");
    assert_eq!(report["time_budget_frames"], 0, "{report}");
    assert_eq!(report["identical"], true, "{report}");
    let _ = std::fs::remove_dir_all(&case);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recording_can_be_turned_off() {
    let case = small_case("rec-off", 1);
    let mut cfg = test_config("rec-off");
    cfg.record = false;
    let data = cfg.data_dir.clone();
    let server = start(cfg).await;
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let id = http_create_session(server.http_addr, TOKEN_A, &scene)
        .await
        .unwrap();
    let status = http_close_session(server.http_addr, TOKEN_A, &id)
        .await
        .unwrap();
    assert!(status["recording"].is_null(), "{status}");
    server.shutdown().await.unwrap();
    assert!(!data.join("recordings").exists());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_server_leaves_every_frame_whose_result_was_sent() {
    const FRAMES: usize = 40;
    const KILL_AFTER: usize = 3; // the result of frame 3 received, then SIGKILL
    let case = small_case("rec-kill", FRAMES);
    let frames = read_frames(&case.join("frames")).unwrap();
    let dir = temp_dir("rec-kill-server");
    let recordings = dir.join("my-recordings");
    let config = dir.join("serve.toml");
    std::fs::write(
        &config,
        format!(
            "bind = \"127.0.0.1:0\"\ndata_dir = {:?}\nrecordings_dir = {:?}\nworker_threads = 1\nlog_format = \"json\"\nlog_filter = \"info\"\n[[tokens]]\nname = \"room-a\"\ntoken = \"{TOKEN_A}\"\n[limits]\nmax_frames_per_second = 1000.0\n",
            s(&dir.join("data")),
            s(&recordings)
        ),
    )
    .unwrap();
    let mut serve = Command::new(env!("CARGO_BIN_EXE_livereg"));
    serve.args(["serve", "--config", s(&config), "--grpc-bind", "off"]);
    let (mut child, listening) = spawn_serve(serve);
    let addr = http_addr_of(&listening);

    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let id = http_create_session(addr, TOKEN_A, &scene).await.unwrap();
    let path = recordings.join(format!("{id}.mcap"));
    let mut ws = WsClient::connect(addr, &id, TOKEN_A).await.unwrap();
    let mut got = Vec::new();
    let t0 = Instant::now();
    for (k, (name, pts)) in frames.iter().enumerate() {
        ws.send_json(k as u64, name, pts).await.unwrap();
        match ws.next().await {
            Some(WsEvent::Result(v)) => got.push(v),
            other => panic!("frame {k}: {other:?}"),
        }
        if k == KILL_AFTER {
            // Send the next frame so the server is busy with it, then kill.
            ws.send_json(k as u64 + 1, &frames[k + 1].0, &frames[k + 1].1)
                .await
                .unwrap();
            child.kill().unwrap(); // SIGKILL
            break;
        }
    }
    child.wait().unwrap();
    assert_eq!(got.len(), KILL_AFTER + 1);
    assert!(t0.elapsed() < Duration::from_secs(300));

    let rec = Recording::open(&path).unwrap();
    assert!(!rec.finished, "killed before finishing: {}", rec.describe());
    assert!(
        rec.complete_frames() >= got.len(),
        "{} results received, {}",
        got.len(),
        rec.describe()
    );
    for (k, v) in got.iter().enumerate() {
        assert_recorded(&rec, k, v);
    }
    eprintln!(
        "server kill test: {} results received at the kill; {}",
        got.len(),
        rec.describe()
    );
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&case);
}

/// Starts `livereg serve --config config` whose files may not grow past `max_file_bytes`
/// (RLIMIT_FSIZE, with SIGXFSZ ignored: a write past the limit fails with EFBIG, as a full
/// disk fails with ENOSPC), set by Python's `resource` module before it execs the server; the
/// `http_addr` of its `listening` line.
fn serve_with_file_limit(
    config: &Path,
    max_file_bytes: u64,
) -> (std::process::Child, std::net::SocketAddr) {
    let mut cmd = Command::new("python3");
    cmd.args([
        "-c",
        "import os, resource, signal, sys\n\
         signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n\
         n = int(sys.argv[1])\n\
         resource.setrlimit(resource.RLIMIT_FSIZE, (n, n))\n\
         os.execv(sys.argv[2], sys.argv[2:])",
        &max_file_bytes.to_string(),
        env!("CARGO_BIN_EXE_livereg"),
        "serve",
        "--config",
        s(config),
        "--grpc-bind",
        "off",
    ]);
    let (child, listening) = spawn_serve(cmd);
    (child, http_addr_of(&listening))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_stops_the_recording_not_the_session() {
    const FRAMES: usize = 10;
    let case = small_case("rec-full", FRAMES);
    let frames = read_frames(&case.join("frames")).unwrap();
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();

    // Calibration, in process and unlimited: the recording's size after creation and per
    // frame, so that the limit below falls after the third frame whatever the encoding.
    let cfg = test_config("rec-full-calibrate");
    let cal_dir = cfg.data_dir.join("recordings");
    let server = start(cfg).await;
    let id = http_create_session(server.http_addr, TOKEN_A, &scene)
        .await
        .unwrap();
    let path = cal_dir.join(format!("{id}.mcap"));
    let created = std::fs::metadata(&path).unwrap().len();
    let (_, _) = ws_lockstep(server.http_addr, &id, TOKEN_A, &frames[..2], false)
        .await
        .unwrap();
    let per_frame = (std::fs::metadata(&path).unwrap().len() - created) / 2;
    server.shutdown().await.unwrap();
    let limit = created + 3 * per_frame + per_frame / 2;

    let dir = temp_dir("rec-full-server");
    let recordings = dir.join("recordings");
    let config = dir.join("serve.toml");
    std::fs::write(
        &config,
        format!(
            "bind = \"127.0.0.1:0\"\ndata_dir = {:?}\nrecordings_dir = {:?}\nrecordings_fsync_ms = 0\nworker_threads = 1\nlog_format = \"json\"\nlog_filter = \"info\"\n[[tokens]]\nname = \"room-a\"\ntoken = \"{TOKEN_A}\"\n[limits]\nmax_frames_per_second = 1000.0\n",
            s(&dir.join("data")),
            s(&recordings)
        ),
    )
    .unwrap();
    let (mut child, addr) = serve_with_file_limit(&config, limit);
    let id = http_create_session(addr, TOKEN_A, &scene).await.unwrap();
    let (got, _) = ws_lockstep(addr, &id, TOKEN_A, &frames, false)
        .await
        .unwrap();
    // Every frame was answered and registered: the session went on.
    assert_eq!(got.len(), FRAMES);
    for v in &got {
        assert!(
            v["diagnostics"].get("error").is_none(),
            "{}",
            v["diagnostics"]
        );
    }
    // Its description says the recording stopped, without the server's path.
    let r = http(
        addr,
        "GET",
        &format!("/v1/sessions/{id}"),
        &[("Authorization", &format!("Bearer {TOKEN_A}"))],
        b"",
    )
    .await
    .unwrap();
    let why = r.json()["recording_error"]
        .as_str()
        .expect("recording_error in the description")
        .to_string();
    assert!(why.contains("recording stopped"), "{why}");
    assert!(!why.contains(s(&dir)), "server path in {why}");
    let metrics =
        String::from_utf8(http(addr, "GET", "/metrics", &[], b"").await.unwrap().body).unwrap();
    assert!(
        metrics.contains("livereg_recording_errors_total{stage=\"write\"} 1"),
        "{metrics}"
    );
    child.kill().unwrap();
    child.wait().unwrap();

    // The recording holds the frames answered before the disk filled, each as answered.
    let rec = Recording::open(&recordings.join(format!("{id}.mcap"))).unwrap();
    let kept = rec.complete_frames();
    assert!(
        (3..FRAMES).contains(&kept),
        "{kept} frames kept with room for 3.5: {}",
        rec.describe()
    );
    for (k, v) in got.iter().enumerate().take(kept) {
        assert_recorded(&rec, k, v);
    }
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&case);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_retention_policy_removes_old_recordings() {
    let case = small_case("rec-retain", 1);
    let mut cfg = test_config("rec-retain");
    let recordings = cfg.data_dir.join("recordings");
    std::fs::create_dir_all(&recordings).unwrap();
    let now = std::time::SystemTime::now();
    let aged = |name: &str, bytes: usize, age_h: u64| {
        let p = recordings.join(name);
        std::fs::write(&p, vec![0u8; bytes]).unwrap();
        let f = std::fs::File::options().write(true).open(&p).unwrap();
        f.set_modified(now - Duration::from_secs(age_h * 3600))
            .unwrap();
        p
    };
    let month_old = aged("old-session.mcap", 1000, 24 * 31);
    let day_old = aged("recent-session.mcap", 1000, 24);
    let not_a_recording = aged("operator-notes.txt", 1000, 24 * 365);
    cfg.recordings_max_age_h = 24.0 * 30.0;
    let server = start(cfg).await;
    // The policy runs at start: the month-old recording goes, the rest stays.
    let t0 = Instant::now();
    while month_old.exists() && t0.elapsed() < Duration::from_secs(20) {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(
        !month_old.exists(),
        "a recording past recordings_max_age_h was kept"
    );
    assert!(day_old.exists() && not_a_recording.exists());
    let m = String::from_utf8(
        http(server.http_addr, "GET", "/metrics", &[], b"")
            .await
            .unwrap()
            .body,
    )
    .unwrap();
    assert!(
        m.contains("livereg_recordings_removed_total{reason=\"age\"} 1"),
        "{m}"
    );
    // Sessions go on recording beside the policy.
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let id = http_create_session(server.http_addr, TOKEN_A, &scene)
        .await
        .unwrap();
    assert!(recordings.join(format!("{id}.mcap")).is_file());
    server.shutdown().await.unwrap();
    let _ = std::fs::remove_dir_all(&case);
}
