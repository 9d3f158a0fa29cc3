//! Recorder and reader round trip, truncation at every length, bad files.

use std::path::PathBuf;

use nalgebra::Point3;

use super::*;
use crate::geometry::Camera;
use crate::registration::RigidTransform;
use crate::scene::SceneFormat;
use crate::session::{Frame, FrameError, FrameResult, StageTimes};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("livereg-rec-unit-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

fn scene() -> SceneFiles {
    SceneFiles {
        name: "scene.toml".into(),
        format: SceneFormat::Toml,
        text: "units = \"mm\"\n".into(),
        files: vec![(
            "model.surface".into(),
            PathBuf::from("/x/body.stl"),
            (0..=255u8).collect(),
        )],
    }
}

fn frame(k: usize) -> Frame {
    Frame {
        source: format!("f{k}"),
        points: (0..50)
            .map(|i| Point3::new(0.1 * i as f64 + k as f64, 1.0 / 3.0, -2.5e-7 * i as f64))
            .collect(),
        camera: (k == 1).then(|| {
            Camera::new(
                Point3::new(0.0, 0.0, 300.0),
                Point3::origin(),
                nalgebra::Vector3::y(),
                60.0,
            )
            .unwrap()
        }),
    }
}

fn result(k: usize) -> FrameResult {
    FrameResult {
        frame: k,
        source: format!("f{k}"),
        wall_ms: 12.5,
        converged: true,
        model_to_cloud: RigidTransform::identity(),
        rigid_iterations: 3,
        icp_iterations: 5,
        newton_iterations: 5,
        factorizations: 1,
        surface_rms: 0.25,
        cloud_points: (50, 50),
        sources: 20,
        warm: k > 0,
        flags: vec![],
        warnings: vec![],
        error: (k == 2).then_some(FrameError::Empty),
        surface: vec![Point3::new(std::f64::consts::PI, 1e-300, -7.0 * k as f64); 4],
        structures: vec![("t".into(), vec![Point3::new(0.1, 0.2, 0.3 + k as f64)])],
        times: StageTimes::default(),
        contact_force: (k == 1).then(|| crate::registration::ContactForce {
            resultant: nalgebra::Vector3::new(0.5, -1.25, 0.0625),
            centre: Point3::new(10.0, -20.5, 3.0),
            expected_error: 0.375,
        }),
        pose_uncertainty: None,
        expected_error: Some(crate::registration::ErrorEstimate {
            expected: 0.75 + k as f64,
            ..Default::default()
        }),
    }
}

fn write(path: &std::path::Path, frames: usize) -> RecorderStats {
    let meta = RecordingMeta {
        command: "test".into(),
        ..Default::default()
    };
    let mut r = Recorder::create(path, &scene(), &meta, 1e-3, "mm").unwrap();
    for k in 0..frames {
        r.record_frame(&frame(k), 1_000 + k as u64).unwrap();
        r.record_result(&result(k)).unwrap();
    }
    r.record_unreadable_frame("bad.xyz", "bad.xyz:2: not a number", 5_000)
        .unwrap();
    r.finish().unwrap()
}

#[test]
fn base64_round_trips() {
    for n in 0..40 {
        let bytes: Vec<u8> = (0..n).map(|i| (i * 37 + 11) as u8).collect();
        assert_eq!(base64::decode(&base64::encode(&bytes)).unwrap(), bytes);
    }
    assert_eq!(base64::encode(b"Man"), "TWFu");
    assert_eq!(base64::encode(b"Ma"), "TWE=");
    assert!(base64::decode("TW*u").is_err());
}

#[test]
fn floats_survive_json_exactly() {
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    let values: Vec<f64> = (0..20_000)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            f64::from_bits(x >> 2) // finite, every exponent range
        })
        .collect();
    let back: Vec<f64> = serde_json::from_str(&serde_json::to_string(&values).unwrap()).unwrap();
    for (a, b) in values.iter().zip(&back) {
        assert_eq!(a.to_bits(), b.to_bits(), "{a:e}");
    }
}

#[test]
fn a_recording_reads_back_exactly() {
    let path = tmp("round.mcap");
    let stats = write(&path, 3);
    assert_eq!((stats.frames, stats.results), (4, 3));
    let rec = Recording::open(&path).unwrap();
    assert!(rec.finished && rec.truncated_tail.is_none());
    assert_eq!(rec.session.command, "test");
    assert_eq!(rec.session.units, "mm");
    assert_eq!(rec.scene_files().unwrap(), {
        let mut s = scene();
        s.files[0].1 = PathBuf::from("/x/body.stl");
        s
    });
    assert_eq!(rec.frames.len(), 4);
    assert_eq!(rec.complete_frames(), 3);
    for k in 0..3 {
        assert_eq!(rec.frames[k].to_frame().unwrap(), frame(k));
        assert_eq!(rec.frames[k].timestamp_ns, 1_000 + k as u64);
        let r = &rec.results[k];
        assert_eq!(
            r.record,
            crate::evaluation::ResultRecord::from_frame(&result(k), 1e-3)
        );
        assert_eq!(r.surface.len(), 12);
        assert_eq!(r.surface[0], std::f64::consts::PI);
        assert_eq!(r.surface[1], 1e-300);
    }
    assert!(rec.frames[3].to_frame().is_none());
    assert_eq!(
        rec.frames[3].input_error.as_deref(),
        Some("bad.xyz:2: not a number")
    );
}

#[test]
fn every_truncation_reads_or_fails_cleanly_and_keeps_whole_frames() {
    let path = tmp("cut.mcap");
    write(&path, 3);
    let bytes = std::fs::read(&path).unwrap();
    let full = Recording::open(&path).unwrap();
    let mut best_seen = 0;
    for len in 0..bytes.len() {
        match Recording::from_bytes(&path, &bytes[..len]) {
            Ok(r) => {
                assert!(!r.finished || len == bytes.len());
                // Whatever is recovered is exact, and frames come with their results except
                // possibly the last one.
                assert!(r.frames.len() >= r.results.len());
                for (k, res) in r.results.iter().enumerate() {
                    assert_eq!(res, &full.results[k]);
                    assert_eq!(r.frames[k], full.frames[k]);
                }
                best_seen = best_seen.max(r.complete_frames());
            }
            Err(e) => {
                let m = e.to_string();
                assert!(m.contains("cut.mcap"), "{m}");
            }
        }
    }
    assert_eq!(best_seen, 3);
}

#[test]
fn bad_files_are_named_errors() {
    let path = tmp("not.mcap");
    std::fs::write(&path, b"hello, this is not mcap at all").unwrap();
    let e = Recording::open(&path).unwrap_err().to_string();
    assert!(
        e.contains("not.mcap") && e.contains("not an MCAP file"),
        "{e}"
    );
    let e = Recording::open(&tmp("missing.mcap"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.mcap"), "{e}");
    // A valid MCAP file without the livereg channels.
    let path = tmp("other.mcap");
    {
        let mut w = mcap::Writer::new(std::io::BufWriter::new(
            std::fs::File::create(&path).unwrap(),
        ))
        .unwrap();
        let ch = w
            .add_channel(0, "/chatter", "json", &Default::default())
            .unwrap();
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: 0,
                log_time: 0,
                publish_time: 0,
            },
            b"{}",
        )
        .unwrap();
        w.finish().unwrap();
    }
    let e = Recording::open(&path).unwrap_err().to_string();
    assert!(
        e.contains("other.mcap") && e.contains("not a livereg recording"),
        "{e}"
    );
}

#[test]
fn scene_overrides_are_applied_and_checked() {
    let d = std::env::temp_dir().join(format!("livereg-rec-scene-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    let s = crate::mesh::primitives::icosphere(Point3::origin(), 10.0, 1);
    crate::mesh::write_obj(&d.join("b.obj"), &s).unwrap();
    std::fs::write(
        d.join("s.toml"),
        "units = \"mm\"\n[model]\nsurface = \"b.obj\"\n[grid]\ncell_size = 5.0\n[material]\nyoung_modulus = 4500.0\npoisson_ratio = 0.45\n",
    )
    .unwrap();
    let loaded = crate::scene::load_scene(&d.join("s.toml")).unwrap();
    let files = SceneFiles::from_loaded(&loaded).unwrap();
    assert_eq!(files.files.len(), 1);
    let out = d.join("replayed");
    let back = files
        .materialize(
            &out,
            &["registration.alpha=0.5".into(), "grid.cell_size = 4".into()],
        )
        .unwrap();
    assert_eq!(back.scene.registration.as_ref().unwrap().alpha, 0.5);
    assert_eq!(back.scene.grid.cell_size, 4.0);
    assert_eq!(back.scene.material, loaded.scene.material);
    let e = files
        .materialize(&d.join("r2"), &["grid.cellsize=4".into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("cellsize"), "{e}");
    let e = files
        .materialize(&d.join("r3"), &["novalue".into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("KEY=VALUE"), "{e}");
}
