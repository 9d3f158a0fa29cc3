//! `livereg register` and `livereg eval` as users and scripts call them: results.jsonl in the
//! contract's shape, a broken frame recorded without stopping the run, and TRE figures checked
//! against a truth with a known offset.

use std::path::PathBuf;

use livereg::mesh::write_points;

use crate::common;
use crate::recording_case;
use common::livereg;

/// The shared ellipsoid scene ([`recording_case::case`]) with 4 frames bending it
/// progressively; the third frame file, `frames/f002.xyz`, is broken on line 2.
fn case(tag: &str) -> PathBuf {
    recording_case::case(&format!("register-{tag}"), 4)
}

#[test]
fn register_writes_one_contract_line_per_frame_and_survives_a_broken_file() {
    let d = case("lines");
    let out = d.join("out");
    let (code, stdout, stderr) = livereg(&[
        "register",
        d.join("scene.toml").to_str().unwrap(),
        "--frames",
        d.join("frames").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let summary: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(summary["frames"], 4);
    assert_eq!(summary["failed"], 1);
    let text = std::fs::read_to_string(out.join("results.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 4);
    for (k, l) in lines.iter().enumerate() {
        assert_eq!(l["frame"], k);
        assert_eq!(l["source"], format!("f{k:03}.xyz"));
        for key in ["wall_ms", "converged", "rigid", "diagnostics", "structures"] {
            assert!(l.get(key).is_some(), "frame {k} lacks {key}: {l}");
        }
        for key in ["icp_iterations", "newton_iterations", "surface_rms"] {
            assert!(l["diagnostics"].get(key).is_some(), "frame {k}: {key}");
        }
        assert_eq!(l["rigid"]["rotation"].as_array().unwrap().len(), 3);
        assert_eq!(l["structures"]["targets"].as_array().unwrap().len(), 3);
    }
    let err = lines[2]["diagnostics"]["error"].as_str().unwrap();
    assert!(err.contains("f002.xyz") && err.contains('2'), "{err}");
    assert_eq!(lines[2]["converged"], false);
    // The broken frame carries the last good state; the next frame registers again.
    assert_eq!(lines[2]["structures"], lines[1]["structures"]);
    assert!(lines[3]["diagnostics"].get("error").is_none());
    // The tip target (rest x = 35 mm) rises as the imposed bend says there, a (70/85)² with
    // a = 6 mm in the last frame (4.07 mm), within half a 20 mm cell's change of that field
    // along x (2a·70/85² × 10 mm = 1.16 mm): the grid interpolates the bend over a cell and
    // the field is not an elastic one (the session tests' `assert_follows_the_bend`).
    let z = |k: usize| lines[k]["structures"]["targets"][2][2].as_f64().unwrap();
    let (a, rise) = (6.0, z(3) - z(0));
    let expected = a * (70.0_f64 / 85.0).powi(2);
    let tolerance = 2.0 * a * 70.0 / 85.0_f64.powi(2) * 10.0;
    assert!(
        (rise - expected).abs() <= tolerance,
        "the tip target rose {rise:.2} mm; the bend gives {expected:.2} ± {tolerance:.2} mm"
    );
}

#[test]
fn eval_reports_a_known_offset_and_names_bad_input() {
    let d = case("eval");
    let out = d.join("out");
    let (code, _, stderr) = livereg(&[
        "register",
        d.join("scene.toml").to_str().unwrap(),
        "--frames",
        d.join("frames").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--rigid-only",
    ]);
    assert_eq!(code, 0, "{stderr}");
    // Truth: every result point moved by (3, 4, 0): TRE exactly 5 everywhere.
    let text = std::fs::read_to_string(out.join("results.jsonl")).unwrap();
    let mut truth = String::new();
    for l in text.lines() {
        let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
        for p in v["structures"]["targets"].as_array_mut().unwrap() {
            let x = p[0].as_f64().unwrap() + 3.0;
            let y = p[1].as_f64().unwrap() + 4.0;
            p[0] = x.into();
            p[1] = y.into();
        }
        let t = serde_json::json!({"frame": v["frame"], "structures": v["structures"]});
        truth.push_str(&format!("{t}\n"));
    }
    std::fs::write(d.join("truth.jsonl"), &truth).unwrap();
    let results = out.join("results.jsonl");
    let (code, stdout, stderr) = livereg(&[
        "eval",
        "--results",
        results.to_str().unwrap(),
        "--truth",
        d.join("truth.jsonl").to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    for key in ["mean", "median", "p95", "max"] {
        let v = report["overall"][key].as_f64().unwrap();
        assert!((v - 5.0).abs() < 1e-9, "{key} = {v}");
    }
    assert_eq!(report["overall"]["count"], 12);
    assert_eq!(report["failed_frames"], serde_json::json!([2]));
    // The table form names the structure.
    let (code, stdout, _) = livereg(&[
        "eval",
        "--results",
        results.to_str().unwrap(),
        "--truth",
        d.join("truth.jsonl").to_str().unwrap(),
    ]);
    assert_eq!(code, 0);
    assert!(stdout.contains("targets"), "{stdout}");
    // A truth with a broken line: one-line error naming file and line.
    std::fs::write(
        d.join("bad.jsonl"),
        format!(
            "{}{{\"frame\": 1}}\n",
            truth.lines().next().unwrap().to_owned() + "\n"
        ),
    )
    .unwrap();
    let (code, _, stderr) = livereg(&[
        "eval",
        "--results",
        results.to_str().unwrap(),
        "--truth",
        d.join("bad.jsonl").to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("bad.jsonl:2") && stderr.contains("structures"),
        "{stderr}"
    );
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
}

#[test]
fn register_rejects_a_missing_or_empty_frame_directory() {
    let d = case("nodir");
    let scene = d.join("scene.toml");
    let (code, _, stderr) = livereg(&[
        "register",
        scene.to_str().unwrap(),
        "--frames",
        d.join("nope").to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(stderr.contains("nope"), "{stderr}");
    std::fs::create_dir_all(d.join("empty")).unwrap();
    let (code, _, stderr) = livereg(&[
        "register",
        scene.to_str().unwrap(),
        "--frames",
        d.join("empty").to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(stderr.contains("no point files"), "{stderr}");
}

/// One frame's points as `.xyz`, as a hand-written legacy ASCII `.vtk` PolyData and as a `.vtp`
/// (written by the library): `register --frames` takes each, and the three registrations agree
/// to the digit; a directory mixing them with a note registers the point files and names the
/// note on stderr.
#[test]
fn register_takes_vtk_and_vtp_frames_and_names_the_files_it_skips() {
    let d = case("vtk");
    let points = livereg::mesh::read_points(&d.join("frames/f003.xyz")).unwrap();
    let mut legacy = format!(
        "# vtk DataFile Version 4.2\nframe 3\nASCII\nDATASET POLYDATA\nPOINTS {} double\n",
        points.len()
    );
    for p in &points {
        legacy.push_str(&format!("{} {} {}\n", p.x, p.y, p.z));
    }
    let run = |dir: &std::path::Path, tag: &str| {
        let out = d.join(format!("out-{tag}"));
        let (code, stdout, stderr) = livereg(&[
            "register",
            d.join("scene.toml").to_str().unwrap(),
            "--frames",
            dir.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_eq!(code, 0, "{tag}: {stderr}");
        let text = std::fs::read_to_string(out.join("results.jsonl")).unwrap();
        let lines: Vec<serde_json::Value> = text
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        (stdout, stderr, lines)
    };
    let mut structures = Vec::new();
    for tag in ["xyz", "vtk", "vtp"] {
        let dir = d.join(format!("only-{tag}"));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join(format!("frame.{}", tag.to_uppercase()));
        match tag {
            "xyz" => write_points(&file, &points).unwrap(),
            "vtk" => std::fs::write(&file, &legacy).unwrap(),
            _ => livereg::mesh::write_vtk(
                &file,
                &livereg::mesh::vtk::VtkPolyData {
                    points: &points,
                    triangles: &[],
                    arrays: &[],
                },
            )
            .unwrap(),
        }
        let (_, stderr, lines) = run(&dir, tag);
        assert_eq!(lines.len(), 1, "{tag}: {stderr}");
        assert!(
            lines[0]["diagnostics"].get("error").is_none(),
            "{tag}: {}",
            lines[0]
        );
        assert!(!stderr.contains("skipped"), "{tag}: {stderr}");
        structures.push(lines[0]["structures"].clone());
    }
    assert_eq!(structures[0], structures[1], "legacy .vtk against .xyz");
    assert_eq!(structures[0], structures[2], ".vtp against .xyz");

    let mixed = d.join("mixed");
    std::fs::create_dir_all(&mixed).unwrap();
    for tag in ["xyz", "vtk", "vtp"] {
        let from = d.join(format!("only-{tag}/frame.{}", tag.to_uppercase()));
        std::fs::copy(from, mixed.join(format!("f-{tag}.{tag}"))).unwrap();
    }
    std::fs::write(mixed.join("notes.md"), "camera notes\n").unwrap();
    let (stdout, stderr, lines) = run(&mixed, "mixed");
    let summary: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(summary["frames"], 3, "{stderr}");
    let sources: Vec<&str> = lines
        .iter()
        .map(|l| l["source"].as_str().unwrap())
        .collect();
    assert_eq!(sources, ["f-vtk.vtk", "f-vtp.vtp", "f-xyz.xyz"]);
    assert!(
        stderr.contains("notes.md") && stderr.contains("skipped 1 file"),
        "the note is named: {stderr}"
    );
}
