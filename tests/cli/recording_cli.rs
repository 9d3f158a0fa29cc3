//! Recordings end to end through the binary: `register --record` read back by the `mcap`
//! Python package (channels, schemas, counts, payloads), `register --frames FILE.mcap`, a
//! SIGKILL mid-stream leaving a readable file with every frame reported done, and bad files.
//!
//! The Python checks need `python3 -m pip install mcap` (`scripts/test` sets it up).

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use livereg::recording::Recording;
use serde_json::Value;

use crate::common;
use crate::recording_case;
use common::livereg;
use recording_case::case;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Runs tests/python/check_recording.py on `file`.
fn python_read(file: &Path, stream: bool) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/check_recording.py");
    let mut cmd = Command::new("python3");
    cmd.arg(&script).arg(file);
    if stream {
        cmd.arg("--stream");
    }
    let out = cmd.output().expect("python3 runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "the Python mcap reader failed (is `mcap` installed? python3 -m pip install mcap): {stderr}"
    );
    serde_json::from_slice(&out.stdout).expect("one JSON object")
}

fn jsonl(path: &Path) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

#[test]
fn register_records_a_file_that_the_python_mcap_reader_decodes() {
    let d = case("py", 4);
    let rec = d.join("rec.mcap");
    let out = d.join("out");
    let (code, _, stderr) = livereg(&[
        "register",
        s(&d.join("scene.toml")),
        "--frames",
        s(&d.join("frames")),
        "--out",
        s(&out),
        "--record",
        s(&rec),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let py = python_read(&rec, false);
    let summary = &py["summary"];
    assert_eq!(
        summary["topics"],
        serde_json::json!(["/frames", "/results", "/scene", "/session"])
    );
    let counts = &summary["channel_message_counts"];
    assert_eq!(counts["/session"], 1);
    assert_eq!(counts["/scene"], 1);
    assert_eq!(counts["/frames"], 4);
    assert_eq!(counts["/results"], 4);
    assert_eq!(summary["message_count"], 10);
    // One chunk for the header messages, one per frame (closed after each result).
    assert_eq!(summary["chunks"], 5);
    assert_eq!(py["counts"], counts.clone());
    for (topic, name) in [
        ("/session", "livereg.Session"),
        ("/scene", "livereg.Scene"),
        ("/frames", "livereg.Frame"),
        ("/results", "livereg.Result"),
    ] {
        assert_eq!(py["channels"][topic]["message_encoding"], "json");
        assert_eq!(py["channels"][topic]["schema"], name);
        assert_eq!(py["schemas"][name]["encoding"], "jsonschema");
        assert_eq!(py["schemas"][name]["title"], name);
    }
    // Payloads: the scene with its two files, the frames' points, the results.
    assert_eq!(py["session"]["command"], "register");
    assert_eq!(py["session"]["units"], "mm");
    let scene = &py["scene"];
    assert_eq!(scene["name"], "scene.toml");
    assert_eq!(scene["files"][0][0], "model.surface");
    assert_eq!(scene["files"][0][1], "body.obj");
    assert_eq!(
        scene["files"][0][2],
        std::fs::metadata(d.join("body.obj")).unwrap().len()
    );
    assert_eq!(scene["files"][1][0], "model.structures[0].points");
    let frames = py["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 4);
    assert_eq!(frames[0]["points"], 642);
    assert_eq!(frames[2]["points"], 0); // the broken file: recorded with its error
    assert_eq!(frames[0]["timestamp_ns"], frames[0]["log_time"]);
    let results = py["results"].as_array().unwrap();
    let lines = jsonl(&out.join("results.jsonl"));
    for (k, r) in results.iter().enumerate() {
        assert_eq!(r["frame"], k);
        assert_eq!(r["source"], lines[k]["source"]);
        assert_eq!(r["surface_vertices"], 642);
        assert_eq!(r["structures"]["targets"], 3);
        for key in ["rigid", "diagnostics", "structures", "wall_ms", "converged"] {
            assert!(
                r["keys"].as_array().unwrap().iter().any(|x| x == key),
                "{key}"
            );
        }
    }
    // The recorded results are the results.jsonl lines, value for value.
    let recording = Recording::open(&rec).unwrap();
    assert!(recording.finished);
    for (k, r) in recording.results.iter().enumerate() {
        assert_eq!(serde_json::to_value(&r.record).unwrap(), lines[k]);
    }
    // The first frame's points are the file's, exactly.
    let pts = livereg::mesh::read_points(&d.join("frames/f000.xyz")).unwrap();
    assert_eq!(
        py["frames"][0]["first_point"],
        serde_json::json!([pts[0].x, pts[0].y, pts[0].z])
    );
}

#[test]
fn register_takes_a_recording_as_input_with_the_same_results() {
    let d = case("input", 4);
    let rec = d.join("rec.mcap");
    let scene = d.join("scene.toml");
    let run = |frames: &Path, out: &Path, extra: &[&str]| {
        let mut args = vec![
            "register",
            s(&scene),
            "--frames",
            s(frames),
            "--out",
            s(out),
        ];
        args.extend_from_slice(extra);
        let (code, _, stderr) = livereg(&args);
        assert_eq!(code, 0, "{stderr}");
        jsonl(&out.join("results.jsonl"))
    };
    let a = run(&d.join("frames"), &d.join("a"), &["--record", s(&rec)]);
    let b = run(&rec, &d.join("b"), &[]);
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x["source"], y["source"]);
        assert_eq!(x["structures"], y["structures"], "same inputs, same build");
        assert_eq!(x["rigid"], y["rigid"]);
        assert_eq!(x["diagnostics"]["error"], y["diagnostics"]["error"]);
    }
}

#[test]
fn a_killed_recording_holds_every_frame_reported_done() {
    let d = case("kill", 400);
    let rec = d.join("rec.mcap");
    let out = d.join("out");
    let mut child = Command::new(env!("CARGO_BIN_EXE_livereg"))
        .args([
            "register",
            s(&d.join("scene.toml")),
            "--frames",
            s(&d.join("frames")),
            "--out",
            s(&out),
            "--record",
            s(&rec),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let results = out.join("results.jsonl");
    let start = Instant::now();
    loop {
        let done = std::fs::read_to_string(&results)
            .map(|t| t.lines().count())
            .unwrap_or(0);
        if done >= 6 {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(300),
            "no progress in 300 s"
        );
        assert!(
            child.try_wait().unwrap().is_none(),
            "finished before the kill"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let reported = jsonl(&results);
    let reported_done = reported.len();
    assert!((6..400).contains(&reported_done));

    // Our reader: unfinished, every reported frame recovered, exactly as reported.
    let r = Recording::open(&rec).unwrap();
    assert!(!r.finished);
    assert!(r.complete_frames() >= reported_done, "{}", r.describe());
    for (k, line) in reported.iter().enumerate() {
        assert_eq!(serde_json::to_value(&r.results[k].record).unwrap(), *line);
    }
    eprintln!(
        "kill test: {reported_done} results.jsonl lines at the kill; {}",
        r.describe()
    );
    // The Python reader, sequentially (there is no summary to seek with).
    let py = python_read(&rec, true);
    assert!(py["results"].as_array().unwrap().len() >= reported_done);
    assert!(py["frames"].as_array().unwrap().len() >= reported_done);
    assert_eq!(py["scene"]["name"], "scene.toml");
    // Replay of the cut recording: every recovered frame, identical.
    let (code, stdout, stderr) = livereg(&["replay", s(&rec), "--json"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.contains("unfinished recording"), "{stderr}");
    let report: Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(report["frames"], r.complete_frames());
    assert_eq!(report["identical"], true);
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn bad_recordings_are_clear_errors() {
    let d = case("bad", 4);
    let scene = d.join("scene.toml");
    std::fs::write(d.join("junk.mcap"), "not a recording at all").unwrap();
    for args in [
        vec!["replay", s(&d.join("junk.mcap"))],
        vec![
            "register",
            s(&scene),
            "--frames",
            s(&d.join("junk.mcap")),
            "--out",
            s(&d.join("o")),
        ],
    ] {
        let (code, _, stderr) = livereg(&args);
        assert_ne!(code, 0);
        assert!(
            stderr.contains("junk.mcap") && stderr.contains("not an MCAP file"),
            "{stderr}"
        );
        assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    }
    let (code, _, stderr) = livereg(&["replay", s(&d.join("absent.mcap"))]);
    assert_ne!(code, 0);
    assert!(stderr.contains("absent.mcap"), "{stderr}");
    // A recording cut inside its first chunk: no scene.
    let rec = d.join("rec.mcap");
    let (code, _, stderr) = livereg(&[
        "register",
        s(&scene),
        "--frames",
        s(&d.join("frames")),
        "--out",
        s(&d.join("o2")),
        "--record",
        s(&rec),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let bytes = std::fs::read(&rec).unwrap();
    std::fs::write(d.join("cut.mcap"), &bytes[..200]).unwrap();
    let (code, _, stderr) = livereg(&["replay", s(&d.join("cut.mcap"))]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("cut.mcap") && stderr.contains("/session"),
        "{stderr}"
    );
    // Without the rerun feature the flag says how to get it.
    if !cfg!(feature = "rerun") {
        let (code, _, stderr) = livereg(&["replay", s(&rec), "--rerun", s(&d.join("x.rrd"))]);
        assert_ne!(code, 0);
        assert!(stderr.contains("--features rerun"), "{stderr}");
    }
}
