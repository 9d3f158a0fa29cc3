//! `livereg replay`: the same build replaying its own recording reports zero difference; a
//! deliberately changed parameter is reported as a difference and fails the tolerance.

use std::path::Path;

use serde_json::Value;

use crate::common;
use crate::recording_case;
use common::livereg;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `livereg register` on the case `d`'s frames into `d/out`, recording to `rec`, with the
/// `extra` arguments; it must succeed.
fn register_recorded(d: &Path, out: &str, rec: &Path, extra: &[&str]) {
    let (scene, frames, out) = (d.join("scene.toml"), d.join("frames"), d.join(out));
    let mut args = vec![
        "register",
        s(&scene),
        "--frames",
        s(&frames),
        "--out",
        s(&out),
        "--record",
        s(rec),
    ];
    args.extend_from_slice(extra);
    let (code, _, stderr) = livereg(&args);
    assert_eq!(code, 0, "{stderr}");
}

#[test]
fn replay_is_identical_and_a_changed_parameter_is_a_difference() {
    let d = recording_case::case("replay", 4);
    let rec = d.join("rec.mcap");
    register_recorded(&d, "out", &rec, &[]);
    // Move the original files away: the recording must be self-contained.
    std::fs::rename(d.join("body.obj"), d.join("body.obj.moved")).unwrap();

    let out = d.join("replay");
    let (code, stdout, stderr) = livereg(&["replay", s(&rec), "--json", "--out", s(&out)]);
    assert_eq!(code, 0, "{stderr}");
    let r: Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(r["frames"], 4);
    assert_eq!(r["identical"], true, "{r}");
    assert_eq!(r["max_surface_mm"], 0.0);
    assert_eq!(r["max_structures_mm"], 0.0);
    assert_eq!(r["status_changes"], 0);
    assert_eq!(r["per_frame"].as_array().unwrap().len(), 4);
    assert!(out.join("results.jsonl").is_file() && out.join("replay.json").is_file());
    // The table form, with the same verdict.
    let (code, stdout, _) = livereg(&["replay", s(&rec), "--speed", "realtime"]);
    assert_eq!(code, 0);
    assert!(stdout.contains("identical"), "{stdout}");
    assert_eq!(stdout.lines().count(), 6, "{stdout}");

    // A changed parameter. (Not Young's modulus: the registration is driven by imposed
    // displacements with penalties proportional to E, so E alone changes nothing — measured.)
    let (code, stdout, stderr) = livereg(&[
        "replay",
        s(&rec),
        "--json",
        "--set",
        "material.poisson_ratio=0.3",
    ]);
    assert_ne!(
        code, 0,
        "a changed parameter must fail the default tolerance"
    );
    assert!(stderr.contains("beyond the tolerance"), "{stderr}");
    let r: Value = serde_json::from_str(stdout.trim()).unwrap();
    let surface = r["max_surface_mm"].as_f64().unwrap();
    assert!(surface > 1e-3, "{r}");
    assert_eq!(r["identical"], false);
    // ... and a tolerance above the difference accepts it.
    let (code, _, stderr) = livereg(&[
        "replay",
        s(&rec),
        "--set",
        "material.poisson_ratio=0.3",
        "--tolerance",
        &format!(
            "{}",
            2.0 * surface.max(r["max_structures_mm"].as_f64().unwrap())
        ),
    ]);
    assert_eq!(code, 0, "{stderr}");
    // A recording made under a time budget: the replay names the frames the budget cut
    // short (their results depend on the recording machine's speed).
    std::fs::rename(d.join("body.obj.moved"), d.join("body.obj")).unwrap();
    let budget_rec = d.join("budget.mcap");
    register_recorded(&d, "budget-out", &budget_rec, &["--budget-ms", "0.001"]);
    let cut = std::fs::read_to_string(d.join("budget-out/results.jsonl"))
        .unwrap()
        .lines()
        .filter(|l| {
            let v: Value = serde_json::from_str(l).unwrap();
            v["diagnostics"]["flags"]
                .as_array()
                .is_some_and(|f| f.iter().any(|f| f == "time_budget"))
        })
        .count();
    assert!(cut > 0, "a 1 µs budget cuts the non-rigid frames short");
    let (_, stdout, stderr) = livereg(&["replay", s(&budget_rec), "--json"]);
    assert!(stderr.contains("time budget"), "{stderr}");
    let r: Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(r["time_budget_frames"], cut, "{r}");
    let marked = r["per_frame"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["recorded_time_budget"] == true)
        .count();
    assert_eq!(marked, cut, "{r}");
    // A bad key is named.
    let (code, _, stderr) = livereg(&["replay", s(&rec), "--set", "material.youngs=1"]);
    assert_ne!(code, 0);
    assert!(stderr.contains("youngs"), "{stderr}");
}
