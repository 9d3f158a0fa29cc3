//! `livereg bench --indentation` with more than one configuration: the JSON holds every
//! configuration's rows with finite errors, and the speed-versus-accuracy chart is written as
//! PNG and SVG (its points: `benchmark::indentation::tests`); `livereg bench --force-truths`
//! grades as `register` and `eval` do.

use serde_json::Value;

use crate::common;
use common::livereg;

#[test]
fn the_indentation_sweep_writes_its_rows_and_its_chart() {
    let d = std::env::temp_dir().join(format!("livereg-bench-ind-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let (code, stdout, stderr) = livereg(&[
        "bench",
        "--indentation",
        "--variants",
        "no-camera",
        "--scenarios",
        "two-sites",
        "--truth-law",
        "linear",
        "--frame-count",
        "4",
        "--repeats",
        "1",
        "--only",
        "default,cell x2",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("cell x2 two-sites/linear/no-camera"),
        "{stdout}"
    );
    let rows: Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("indentation.json")).unwrap())
            .unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 2, "one case × two configurations");
    for r in rows {
        let mean = r["mean_mm"].as_f64().unwrap();
        let none = r["none_mean_mm"].as_f64().unwrap();
        assert!(mean.is_finite() && none.is_finite() && mean > 0.0, "{r}");
        assert_eq!(r["frames"].as_array().unwrap().len(), 4);
    }
    let png = std::fs::read(d.join("indentation.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    let svg = std::fs::read_to_string(d.join("indentation.svg")).unwrap();
    assert!(
        svg.contains("<svg") && svg.contains("indentation"),
        "{svg:.300}"
    );
    std::fs::remove_dir_all(&d).ok();
}

/// `livereg bench --force-truths` grades a case as `register` followed by `eval` does: the
/// first tuning case's mean node error over its first three frames equals `eval`'s mean over
/// the same registration, and no registration is worse. The table names the set.
#[test]
fn the_force_truths_bench_grades_as_register_and_eval_do() {
    let d = std::env::temp_dir().join(format!("livereg-bench-force-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let (code, stdout, stderr) = livereg(&[
        "bench",
        "--force-truths",
        "--set",
        "tuning",
        "--frame-count",
        "3",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("| all tuning (48 frames) |"), "{stdout}");
    let rows: Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("force-truths.json")).unwrap())
            .unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 16, "the sixteen tuning cases");
    let first = &rows[0];
    assert_eq!(first["set"], "tuning");
    let case = first["case"].as_str().unwrap();
    let (liver, name) = case.split_once('/').unwrap();
    let law = name.split_once('_').unwrap().1;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/liver_force");
    let case_dir = root.join(liver).join(name);
    let frames = d.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for k in 0..3 {
        let f = format!("frame_{k:03}.xyz");
        std::fs::copy(case_dir.join("frames").join(&f), frames.join(&f)).unwrap();
    }
    let truth: String = std::fs::read_to_string(case_dir.join("truth.jsonl"))
        .unwrap()
        .lines()
        .take(3)
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(d.join("truth.jsonl"), truth).unwrap();
    let out = d.join("out");
    let (code, _, stderr) = livereg(&[
        "register",
        root.join(liver)
            .join(format!("scene_{law}.toml"))
            .to_str()
            .unwrap(),
        "--frames",
        frames.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let (code, stdout, stderr) = livereg(&[
        "eval",
        "--results",
        out.join("results.jsonl").to_str().unwrap(),
        "--truth",
        d.join("truth.jsonl").to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let report: Value = serde_json::from_str(stdout.trim()).unwrap();
    let eval_mean = report["overall"]["mean"].as_f64().unwrap();
    let bench_mean = first["mean_mm"].as_f64().unwrap();
    assert!(
        (bench_mean - eval_mean).abs() < 1e-6,
        "bench {bench_mean} mm, register + eval {eval_mean} mm"
    );
    let none = first["none_mm"].as_f64().unwrap();
    assert!(none > bench_mean, "no registration {none} mm");
    for f in first["frames"].as_array().unwrap() {
        assert!(f["dent_mm"].as_f64().is_some_and(f64::is_finite), "{f}");
    }
    std::fs::remove_dir_all(&d).ok();
}
