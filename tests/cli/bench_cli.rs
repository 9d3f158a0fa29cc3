//! `livereg bench` as CI runs it: the quick sweep's JSON has finite numbers for
//! every configuration and a chart; the reduced stability matrix has no crash and no
//! non-finite output, and every cell whose truth could be simulated has numbers.

use serde_json::Value;

use crate::common;
use common::livereg;

fn out_dir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("livereg-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Every number inside `v` (recursively) is finite; names the path of the first that is not.
fn assert_numbers_finite(v: &Value, path: &str) {
    match v {
        Value::Number(n) => {
            let x = n.as_f64().unwrap();
            assert!(x.is_finite(), "{path} = {x}");
        }
        Value::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, x)| assert_numbers_finite(x, &format!("{path}[{i}]"))),
        Value::Object(o) => o
            .iter()
            .for_each(|(k, x)| assert_numbers_finite(x, &format!("{path}.{k}"))),
        _ => {}
    }
}

#[test]
fn quick_sweep_reports_finite_numbers_for_every_configuration_and_draws_the_chart() {
    let d = out_dir("bench-quick");
    let (code, stdout, stderr) = livereg(&["bench", "--quick", "--out", d.to_str().unwrap()]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("default"), "{stdout}");
    let v: Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("bench.json")).unwrap()).unwrap();
    // serde_json writes NaN/inf as null: a null metric would be a non-finite number.
    let configs = v["configs"].as_array().unwrap();
    assert!(configs.len() >= 5, "{v}");
    assert_numbers_finite(&v["rigid_only"], "rigid_only");
    let rigid_worst = v["rigid_only"]["tre_max_mm"].as_f64().unwrap();
    for c in configs {
        let m = &c["metrics"];
        assert!(
            m.is_object(),
            "{} has no numbers: {}",
            c["name"],
            c["error"]
        );
        for key in [
            "tre_mean_mm",
            "tre_p95_mm",
            "tre_max_mm",
            "surface_rms_mm",
            "ms_p50",
            "ms_p95",
            "newton_per_frame",
            "failure_rate",
        ] {
            assert!(m[key].is_number(), "{}.{key} = {}", c["name"], m[key]);
        }
        assert_numbers_finite(c, c["name"].as_str().unwrap());
        assert_eq!(m["frames"], 3);
        // The tool pushes a vessel target by centimetres (the workload's largest surface
        // motion: 31.7 mm), which rigid alignment cannot follow: its worst target is 7.2 mm
        // off. Every model must follow part of the push: measured worst targets 1.8–4.6 mm
        // (0.25–0.64 of rigid's; default 3.5 mm).
        let worst = m["tre_max_mm"].as_f64().unwrap();
        assert!(
            worst < 0.8 * rigid_worst,
            "{}: worst target {worst:.2} mm against rigid's {rigid_worst:.2} mm",
            c["name"]
        );
    }
    // The default's mean, over targets most of which barely move on these three frames:
    // near rigid's, not the ~28 mm of an unregistered model. Measured 0.64 against 0.41 mm:
    // on a push loaded in three steps the non-rigid stage moves the still targets by a few
    // tenths of a millimetre (the contact refit's factorisation budget alone moves the mean
    // between 0.58 and 0.64 mm); over the 10-frame scenarios it is 0.52 against 1.63 mm
    // (docs/bench.md).
    let default = configs.iter().find(|c| c["default"] == true).unwrap();
    let tre = default["metrics"]["tre_mean_mm"].as_f64().unwrap();
    let rigid_tre = v["rigid_only"]["tre_mean_mm"].as_f64().unwrap();
    assert!(
        tre <= 2.0 * rigid_tre,
        "default mean TRE {tre:.3} mm against rigid's {rigid_tre:.3} mm"
    );
    assert_eq!(
        configs.iter().filter(|c| c["default"] == true).count(),
        1,
        "exactly one default configuration"
    );
    // The front is not empty and the fastest configuration is on it (nothing is faster).
    let fastest = configs
        .iter()
        .min_by(|a, b| {
            a["metrics"]["ms_p50"]
                .as_f64()
                .unwrap()
                .total_cmp(&b["metrics"]["ms_p50"].as_f64().unwrap())
        })
        .unwrap();
    assert_eq!(fastest["pareto"], true, "{}", fastest["name"]);
    let png = std::fs::read(d.join("bench.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    let svg = std::fs::read_to_string(d.join("bench.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("default"));
}

#[test]
fn reduced_stability_matrix_has_no_crash_and_no_non_finite_output() {
    let d = out_dir("bench-stability");
    let (code, stdout, stderr) = livereg(&[
        "bench",
        "--stability",
        "--quick",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("| noise |"), "{stdout}");
    let v: Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("stability.json")).unwrap()).unwrap();
    assert_eq!(v["crashes"], 0, "{v}");
    assert_eq!(v["non_finite_frames"], 0, "{v}");
    let cells = v["cells"].as_array().unwrap();
    // 7 axes × 2 values × 2 methods.
    assert_eq!(cells.len(), 28);
    for c in cells {
        let what = format!("{} {} {}", c["axis"], c["label"], c["method"]);
        assert_eq!(c["crashed"], false, "{what}: {}", c["error"]);
        // Only a truth that could not be simulated excuses a cell from having numbers.
        if !c["metrics"].is_object() {
            let e = c["error"].as_str().unwrap_or("");
            assert!(e.starts_with("truth"), "{what}: {e}");
            continue;
        }
        assert_numbers_finite(c, &what);
        // Registered, not merely finite: the mean target error is a small share of the
        // deformation the cell's truth applies (measured at most 0.09 of its largest surface
        // motion, the 10 % visible cell: 3.0 mm of 31.7 mm; an unregistered model is ~28 mm
        // off through the camera's pose alone).
        let tre = c["metrics"]["tre_mean_mm"].as_f64().unwrap();
        let motion = c["max_displacement_mm"].as_f64().unwrap();
        assert!(
            tre < 0.25 * motion,
            "{what}: mean TRE {tre:.2} mm against a {motion:.1} mm deformation"
        );
    }
    let md = std::fs::read_to_string(d.join("stability.md")).unwrap();
    for axis in [
        "noise",
        "outliers",
        "visible",
        "deformation",
        "grid-offset",
        "poisson",
        "penalty",
    ] {
        assert!(md.contains(&format!("| {axis} |")), "{axis} missing:\n{md}");
    }
}

#[test]
fn calibrate_picks_the_cheapest_model_meeting_the_target_and_it_holds_on_fresh_frames() {
    let d = out_dir("calibrate");
    livereg::phantom::write_phantom(&d).unwrap();
    let scene = d.join("scene.toml");
    let target = 2.5;
    let (code, stdout, stderr) = livereg(&[
        "calibrate",
        scene.to_str().unwrap(),
        "--target-tre",
        &target.to_string(),
        "--quick",
        "--frames",
        "3",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let v: Value = serde_json::from_str(stdout.trim()).unwrap();
    // The prediction meets the target, and so do the fresh frames (other seeds and loads).
    assert!(
        v["predicted"]["tre_mean_mm"].as_f64().unwrap() <= target,
        "{v}"
    );
    let fresh = v["validated"]["tre_mean_mm"].as_f64().unwrap();
    assert!(fresh <= target, "fresh frames: {fresh} mm > {target} mm");
    assert_eq!(v["validated_meets_goal"], true);
    // The chosen one is the cheapest of the candidates that met the target.
    let chosen_ms = v["predicted"]["ms_p50"].as_f64().unwrap();
    for c in v["candidates"].as_array().unwrap() {
        let m = &c["metrics"];
        if m["tre_mean_mm"].as_f64().unwrap() <= target && m["failed_frames"] == 0 {
            assert!(
                m["ms_p50"].as_f64().unwrap() >= chosen_ms,
                "{} is cheaper",
                c["name"]
            );
        }
    }
    // The written scene loads and holds the chosen model.
    let written = std::path::PathBuf::from(v["scene"].as_str().unwrap());
    assert_eq!(written, d.join("scene.calibrated.toml"));
    let loaded = livereg::scene::load_scene(&written).unwrap();
    let cell_mm = loaded.scene.grid.cell_size; // the phantom is in mm
    assert!(
        (cell_mm - v["config"]["cell_size_mm"].as_f64().unwrap()).abs() < 1e-9,
        "{cell_mm}"
    );
    assert_eq!(
        loaded.scene.grid.integration.name(),
        v["config"]["integration"].as_str().unwrap()
    );
    // The rest of the scene is unchanged: structures, fixed regions, camera.
    let original = livereg::scene::load_scene(&scene).unwrap();
    assert_eq!(loaded.scene.model, original.scene.model);
    assert_eq!(loaded.scene.boundary, original.scene.boundary);
    assert_eq!(loaded.scene.registration, original.scene.registration);
}

#[test]
fn calibrate_and_bench_reject_bad_options_with_a_reason() {
    let d = out_dir("calibrate-bad");
    livereg::phantom::write_phantom(&d).unwrap();
    let scene = d.join("scene.toml");
    let s = scene.to_str().unwrap();
    for (args, needle) in [
        (vec!["calibrate", s, "--target-tre", "-1"], "--target-tre"),
        (vec!["calibrate", s], "--target-tre"),
        (
            vec!["calibrate", "/nonexistent/scene.toml", "--budget-ms", "50"],
            "nonexistent",
        ),
        (
            vec!["bench", "--only", "nope", "--out", d.to_str().unwrap()],
            "nope",
        ),
        (
            vec!["bench", "--scenarios", "nope", "--out", d.to_str().unwrap()],
            "nope",
        ),
        (
            vec![
                "bench",
                "--truth-law",
                "ogden",
                "--out",
                d.to_str().unwrap(),
            ],
            "ogden",
        ),
    ] {
        let (code, _, stderr) = livereg(&args);
        assert_ne!(code, 0, "{args:?}");
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}

/// `--truth-law` changes the law the ground truth is simulated with (the truth moves
/// differently), and bench.json says which law graded the configurations.
#[test]
fn truth_law_changes_the_ground_truth_and_is_recorded() {
    let mut max_disp = Vec::new();
    for law in ["neo-hookean", "mooney-rivlin"] {
        let d = out_dir(&format!("bench-truth-{law}"));
        let (code, _, stderr) = livereg(&[
            "bench",
            "--quick",
            "--only",
            "default",
            "--truth-law",
            law,
            "--out",
            d.to_str().unwrap(),
        ]);
        assert_eq!(code, 0, "{stderr}");
        let v: Value =
            serde_json::from_str(&std::fs::read_to_string(d.join("bench.json")).unwrap()).unwrap();
        let w = &v["workloads"][0];
        assert_eq!(w["truth_law"], law, "{w}");
        assert_numbers_finite(&v["configs"][0], law);
        max_disp.push(w["max_displacement_mm"].as_f64().unwrap());
    }
    // Same load and small-strain moduli, different laws: the truths differ, by a fraction.
    let rel = (max_disp[0] - max_disp[1]).abs() / max_disp[0];
    assert!(rel > 1e-4 && rel < 0.3, "max displacements {max_disp:?}");
}

/// `bench --indentation --stability` end to end, cut to one sequence, one variant
/// and one frame per cell: it writes both files, every cell of the reduced matrix has numbers
/// (no crash, no non-finite output) and the table names every axis.
#[test]
fn indentation_stability_matrix_writes_every_cell() {
    let d = out_dir("bench-indentation-stability");
    let (code, stdout, stderr) = livereg(&[
        "bench",
        "--indentation",
        "--stability",
        "--quick",
        "--scenarios",
        "two-sites",
        "--variants",
        "no-camera",
        "--frame-count",
        "1",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let v: Value = serde_json::from_str(
        &std::fs::read_to_string(d.join("stability-indentation.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(v["crashes"], 0, "{v}");
    assert_eq!(v["non_finite_frames"], 0, "{v}");
    assert_eq!(v["sequences"][0][2], serde_json::json!([49]), "{v}");
    let cells = v["cells"].as_array().unwrap();
    // 6 axes × 2 values × 1 variant.
    assert_eq!(cells.len(), 12);
    for c in cells {
        let what = format!("{} {}", c["axis"], c["label"]);
        assert!(c["metrics"].is_object(), "{what}: {}", c["error"]);
        assert_numbers_finite(c, &what);
        assert_eq!(c["metrics"]["frames"], 1, "{what}");
    }
    let md = std::fs::read_to_string(d.join("stability-indentation.md")).unwrap();
    assert!(stdout.contains("| no-camera |"), "{stdout}");
    for axis in [
        "noise",
        "visible",
        "cloud-size",
        "outliers",
        "poisson",
        "law",
    ] {
        assert!(md.contains(&format!("| {axis} |")), "{axis} missing:\n{md}");
    }
}
