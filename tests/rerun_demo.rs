//! `livereg demo --rerun FILE.rrd` (feature `rerun`): the .rrd file is read back by rerun's
//! Python SDK (`rerun-sdk` 0.36, installed by `scripts/test`) and holds the expected entities.
#![cfg(feature = "rerun")]

use std::path::Path;
use std::process::Command;

use serde_json::Value;

mod common;
use common::livereg;

#[test]
fn demo_writes_an_rrd_with_the_expected_entities() {
    let d = std::env::temp_dir().join(format!("livereg-rerun-demo-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let rrd = d.join("demo.rrd");
    let (code, stdout, stderr) = livereg(&[
        "demo",
        "--out",
        d.to_str().unwrap(),
        "--frames",
        "2",
        "--scenarios",
        "tool-push",
        "--rerun",
        rrd.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("tool-push"), "{stdout}");
    assert!(d.join("tool-push/recording.mcap").is_file());
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/check_rrd.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(&rrd)
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "rerun's Python SDK could not read the file (python3 -m pip install 'rerun-sdk==0.36.*'): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let entities: Vec<&str> = v["entities"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e.as_str().unwrap())
        .collect();
    let has = |e: &str| entities.contains(&e);
    for e in [
        "/tool-push/model/surface",
        "/tool-push/frame/cloud",
        "/tool-push/frame/surface",
        "/tool-push/frame/correspondences",
        "/tool-push/frame/targets",
        "/tool-push/metrics/wall_ms",
        "/tool-push/metrics/surface_rms",
        "/tool-push/metrics/tre_mean_mm",
    ] {
        assert!(has(e), "{e} missing from {entities:?}");
    }
    let structure = |suffix: &str| {
        entities
            .iter()
            .any(|e| e.starts_with("/tool-push/frame/structures/") && e.ends_with(suffix))
    };
    assert!(structure("/error") && structure("/truth"), "{entities:?}");
    assert!(entities
        .iter()
        .any(|e| e.starts_with("/tool-push/model/structures/")));
    assert_eq!(v["frames"], serde_json::json!([0, 1]), "{v}");
}
