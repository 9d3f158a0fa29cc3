//! A patient model from a labelmap registers like the model it was segmented from: the
//! bundled phantom (liver and tumour) is voxelised with a rotated, anisotropic affine, written
//! as NIfTI (`.nii.gz`) and NRRD (`.seg.nrrd`) by the independent writers nibabel and pynrrd,
//! turned back into a liver surface by `livereg model`, and the phantom's synthetic sequences
//! are registered with that surface in place of the phantom's. The mean TRE must stay within
//! 10 % of the phantom's own, plus a tenth of a voxel.
//!
//! By default: the tool-push scenario, 10 frames, 1 mm and 2 mm voxels (CI). Fewer frames load
//! the liver in larger steps, and a 3-frame sequence's TRE is mostly its cold first frame's
//! rigid pose, whose sub-voxel changes move it by tens of percent (docs/segmentation.md). The
//! measurement of every scenario: `LIVEREG_SEG_SCENARIOS=all cargo nextest run --test
//! registration a_labelmap_model --no-capture`.
//!
//! `LIVEREG_SEG_KEEP=1` keeps the files (labelmaps, models, results) and prints where.
//!
//! Needs the Python peers nibabel and pynrrd (`scripts/test` installs them; fails without).

use std::path::{Path, PathBuf};

use livereg::mesh::read_obj;
use livereg::segmentation::voxelise_into;
use livereg::synthetic::{generate_sequence, write_sequence, ScenarioKind, SequenceSpec};
use nalgebra::{Rotation3, Vector3};
use serde_json::Value;

use crate::common;

fn env_or(key: &str, default: &str) -> String {
    std::env::var(key).unwrap_or_else(|_| default.to_string())
}

/// Voxelises the phantom (liver 1, tumour 2) at `h` mm and has Python write it; the
/// directory holding `sform.nii.gz` and `liver.seg.nrrd`.
fn labelmaps(phantom: &Path, h: f64, out: &Path) -> PathBuf {
    let liver = read_obj(&phantom.join("liver.obj")).unwrap();
    let tumour = read_obj(&phantom.join("tumour.obj")).unwrap();
    let rotation = Rotation3::from_euler_angles(0.15, -0.1, 0.35);
    let (dims, affine) =
        common::labelmaps::grid_for(&liver, Vector3::new(h, h, 1.25 * h), rotation);
    let mut labels = vec![0u16; dims.iter().product()];
    voxelise_into(&liver, dims, &affine, &mut labels, 1).unwrap();
    voxelise_into(&tumour, dims, &affine, &mut labels, 2).unwrap();
    let dir = out.join(format!("labelmap-{h}mm"));
    common::labelmaps::write_with_python(&dir, &labels, dims, &affine);
    dir
}

fn run(args: &[&str]) -> String {
    let (code, out, err) = common::livereg(args);
    assert_eq!(code, 0, "livereg {args:?}: {err}");
    out
}

/// Mean TRE (mm) of registering `frames` with `scene` against `truth`.
fn mean_tre(scene: &Path, frames: &Path, truth: &Path, out: &Path) -> f64 {
    let s = |p: &Path| p.to_str().unwrap().to_string();
    run(&[
        "register",
        &s(scene),
        "--frames",
        &s(frames),
        "--out",
        &s(out),
    ]);
    let report = run(&[
        "eval",
        "--results",
        &s(&out.join("results.jsonl")),
        "--truth",
        &s(truth),
        "--json",
    ]);
    let v: Value = serde_json::from_str(&report).expect("eval prints JSON");
    v["summary"]["mean"]
        .as_f64()
        .or_else(|| v["overall"]["mean"].as_f64())
        .unwrap_or_else(|| panic!("no mean TRE in {v}"))
}

#[test]
fn a_labelmap_model_registers_like_the_phantom() {
    let root = std::env::temp_dir().join(format!("livereg-segreg-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let phantom = root.join("phantom");
    livereg::phantom::write_phantom(&phantom).unwrap();
    let loaded = livereg::scene::load_scene(&phantom.join("scene.toml")).unwrap();
    let scale = loaded.length_scale();
    let frames: usize = env_or("LIVEREG_SEG_FRAMES", "10").parse().unwrap();
    let scenarios = match env_or("LIVEREG_SEG_SCENARIOS", "tool-push").as_str() {
        "all" => vec![
            ScenarioKind::Pneumoperitoneum,
            ScenarioKind::GravityPose,
            ScenarioKind::ToolPush,
        ],
        _ => vec![ScenarioKind::ToolPush],
    };
    let voxels: Vec<f64> = env_or("LIVEREG_SEG_VOXELS", "1,2")
        .split(',')
        .map(|v| v.trim().parse().unwrap())
        .collect();
    let scene_text = std::fs::read_to_string(phantom.join("scene.toml")).unwrap();
    let mut failures = Vec::new();
    for kind in scenarios {
        let dir = root.join(kind.name());
        let mut spec = SequenceSpec::phantom_default(kind);
        spec.frames = frames;
        let seq = generate_sequence(&loaded, &spec).unwrap();
        write_sequence(&seq, &dir, scale).unwrap();
        let (frames_dir, truth) = (dir.join("frames"), dir.join("truth.jsonl"));
        let reference = mean_tre(
            &phantom.join("scene.toml"),
            &frames_dir,
            &truth,
            &dir.join("phantom-out"),
        );
        for &h in &voxels {
            let maps = labelmaps(&phantom, h, &root);
            for (file, label) in [("sform.nii.gz", "1"), ("liver.seg.nrrd", "liver")] {
                let model = root.join(format!("model-{h}mm-{file}"));
                let triangles = env_or("LIVEREG_SEG_TRIANGLES", "20000");
                let smoothing = env_or("LIVEREG_SEG_SMOOTHING", "20");
                let summary: Value = serde_json::from_str(&run(&[
                    "model",
                    maps.join(file).to_str().unwrap(),
                    "--label",
                    label,
                    "--target-triangles",
                    &triangles,
                    "--smoothing",
                    &smoothing,
                    "--out",
                    model.to_str().unwrap(),
                ]))
                .unwrap();
                assert_eq!(summary["watertight"], true, "{summary}");
                // The phantom's scene, its liver replaced by the labelmap's.
                let surface = model.join("liver.obj");
                let text = scene_text.replace(
                    "surface = \"liver.obj\"",
                    &format!("surface = {:?}", surface.to_str().unwrap()),
                );
                assert_ne!(text, scene_text);
                let scene = phantom.join(format!("scene-{h}mm-{file}.toml"));
                std::fs::write(&scene, text).unwrap();
                let tre = mean_tre(
                    &scene,
                    &frames_dir,
                    &truth,
                    &dir.join(format!("out-{h}-{file}")),
                );
                eprintln!(
                    "{}: mean TRE phantom model {reference:.3} mm, from {file} at {h} mm voxels {tre:.3} mm ({:+.1} %)",
                    kind.name(),
                    100.0 * (tre / reference - 1.0)
                );
                // The bound's 10 %, plus a tenth of a voxel: a model made of voxels is only
                // known to within them (the full measurement, 10 frames of every scenario,
                // is in docs/segmentation.md).
                if tre > 1.1 * reference + 0.1 * h {
                    failures.push(format!(
                        "{} {h} mm {file}: {tre:.3} vs {reference:.3}",
                        kind.name()
                    ));
                }
            }
        }
    }
    if std::env::var_os("LIVEREG_SEG_KEEP").is_none() {
        let _ = std::fs::remove_dir_all(&root);
    } else {
        eprintln!("kept {}", root.display());
    }
    assert!(
        failures.is_empty(),
        "TRE beyond 10 % of the phantom's: {failures:?}"
    );
}
