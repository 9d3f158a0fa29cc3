//! `livereg bench --indentation` with more than one configuration: the JSON holds every
//! configuration's rows with finite errors, and the speed-versus-accuracy chart is written as
//! PNG and SVG (its points: `benchmark::indentation::tests`).

use serde_json::Value;

mod common;
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
