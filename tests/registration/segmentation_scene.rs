//! `model.segmentation` in a scene: the model is derived from a labelmap on load (an NRRD
//! written here byte by byte from its specification), cached, registered, recorded, and the
//! recording replays from the derived files it holds.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use livereg::mesh::{read_points, validate, write_points};
use livereg::scene::load_scene;
use nalgebra::Point3;

use crate::common;

/// A 64³ NRRD of 1 mm voxels (origin −32 mm): label 1 a ball of radius 24 mm, label 2 a ball
/// of 5 mm inside it at (8, 0, 0), label 3 a rod along y at x = −10 mm, z = 0 (radius 2 mm).
fn write_nrrd(path: &Path) {
    let n = 64usize;
    let mut data = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let p = [i as f64 - 32.0, j as f64 - 32.0, k as f64 - 32.0];
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                let t = ((p[0] - 8.0).powi(2) + p[1] * p[1] + p[2] * p[2]).sqrt();
                let rod = ((p[0] + 10.0).powi(2) + p[2] * p[2]).sqrt();
                data.push(if t <= 5.0 {
                    2u8
                } else if rod <= 2.0 && p[1].abs() <= 15.0 {
                    3
                } else if r <= 24.0 {
                    1
                } else {
                    0
                });
            }
        }
    }
    let header = format!(
        "NRRD0004\ntype: uint8\ndimension: 3\nspace: left-posterior-superior\nsizes: {n} {n} {n}\n\
         space directions: (1,0,0) (0,1,0) (0,0,1)\nkinds: domain domain domain\nencoding: raw\n\
         space origin: (-32,-32,-32)\nSegment0_Name:=liver\nSegment0_LabelValue:=1\n\
         Segment1_Name:=tumour\nSegment1_LabelValue:=2\nSegment2_Name:=portal vein\n\
         Segment2_LabelValue:=3\n\n"
    );
    let mut bytes = header.into_bytes();
    bytes.extend_from_slice(&data);
    std::fs::write(path, bytes).unwrap();
}

fn dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("livereg-segscene-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

const SCENE: &str = r#"units = "mm"
[model]
segmentation = "seg.nrrd"
label = "liver"
target_triangles = 3000
[[model.structures]]
name = "tumour"
mesh_label = 2
[[model.structures]]
name = "vessels"
points_label = ["portal vein"]
[[model.structures]]
name = "targets"
points = "targets.xyz"
[grid]
cell_size = 12.0
subdivisions = 1
[material]
law = "neo-hookean"
young_modulus = 4500.0
poisson_ratio = 0.45
[[boundary.fixed]]
box = [[-40.0, -40.0, -40.0], [-16.0, 40.0, 40.0]]
[registration]
rigid = "icp"
"#;

#[test]
fn a_scene_derives_its_model_from_a_labelmap_once_and_records_it() {
    let d = dir("load");
    write_nrrd(&d.join("seg.nrrd"));
    write_points(
        &d.join("targets.xyz"),
        &[Point3::new(0.0, 0.0, 0.0), Point3::new(10.0, 5.0, 0.0)],
    )
    .unwrap();
    std::fs::write(d.join("scene.toml"), SCENE).unwrap();
    let loaded = load_scene(&d.join("scene.toml")).unwrap();
    let m = &loaded.scene.model;
    assert!(
        m.segmentation.is_none(),
        "the loaded scene is an ordinary one"
    );
    let surface = livereg::mesh::read_surface(&m.surface).unwrap();
    let report = validate(&surface);
    assert!(report.watertight, "{report:?}");
    let v = report.signed_volume;
    let ball = 4.0 / 3.0 * PI * 24f64.powi(3);
    assert!(
        (v / ball - 1.0).abs() < 0.03,
        "volume {v} vs the ball's {ball}"
    );
    assert!(
        surface.triangles.len() <= 3000,
        "{}",
        surface.triangles.len()
    );
    let tumour = livereg::mesh::read_surface(m.structures[0].mesh.as_ref().unwrap()).unwrap();
    let c = tumour
        .vertices
        .iter()
        .fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords)
        / tumour.vertices.len() as f64;
    assert!(
        (c - nalgebra::Vector3::new(8.0, 0.0, 0.0)).norm() < 0.5,
        "tumour centre {c}"
    );
    let vessels = read_points(m.structures[1].points.as_ref().unwrap()).unwrap();
    assert!(vessels
        .iter()
        .all(|p| ((p.x + 10.0).powi(2) + p.z * p.z).sqrt() <= 2.0 + 1e-9));
    assert!(
        m.surface.starts_with(d.join(".livereg-derived")),
        "{}",
        m.surface.display()
    );
    // Loaded again: the same derived files, not derived anew.
    let modified = std::fs::metadata(&m.surface).unwrap().modified().unwrap();
    let again = load_scene(&d.join("scene.toml")).unwrap();
    assert_eq!(again.scene.model.surface, m.surface);
    assert_eq!(
        std::fs::metadata(&m.surface).unwrap().modified().unwrap(),
        modified
    );

    // Registered with a recording; the recording replays from the derived files it holds.
    std::fs::create_dir_all(d.join("frames")).unwrap();
    for k in 0..2 {
        let pts: Vec<Point3<f64>> = surface
            .vertices
            .iter()
            .filter(|p| p.z > 0.0)
            .map(|p| p + nalgebra::Vector3::new(0.5 * k as f64, 0.0, 0.0))
            .collect();
        write_points(&d.join(format!("frames/f{k}.xyz")), &pts).unwrap();
    }
    let s = |p: PathBuf| p.to_str().unwrap().to_string();
    let (code, _, err) = common::livereg(&[
        "register",
        &s(d.join("scene.toml")),
        "--frames",
        &s(d.join("frames")),
        "--out",
        &s(d.join("out")),
        "--record",
        &s(d.join("run.mcap")),
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = common::livereg(&["replay", &s(d.join("run.mcap")), "--json"]);
    assert_eq!(code, 0, "replay: {err} {out}");
}

#[test]
fn segmentation_keys_are_checked() {
    let d = dir("bad");
    write_nrrd(&d.join("seg.nrrd"));
    std::fs::write(d.join("targets.xyz"), "0 0 0\n").unwrap();
    let cases = [
        (
            SCENE.replace("label = \"liver\"\n", ""),
            vec!["model.label", "needs the organ's `label`"],
        ),
        (
            SCENE.replace("label = \"liver\"", "label = \"spleen\""),
            vec!["model.segmentation", "spleen"],
        ),
        (
            SCENE.replace(
                "segmentation = \"seg.nrrd\"",
                "segmentation = \"seg.nrrd\"\nsurface = \"x.obj\"",
            ),
            vec!["model", "both `surface` and `segmentation`"],
        ),
        (
            SCENE.replace("mesh_label = 2", "mesh_label = 2\nmesh = \"t.obj\""),
            vec!["model.structures[0]", "more than one of"],
        ),
        (
            SCENE.replace("seg.nrrd", "seg.png"),
            vec!["model.segmentation", "unsupported labelmap format"],
        ),
        (
            SCENE.replace("mesh_label = 2", "mesh_label = 9"),
            vec![
                "model.segmentation",
                "seg.nrrd",
                "[9]",
                "labels present: [1, 2, 3]",
            ],
        ),
    ];
    for (text, needles) in cases {
        std::fs::write(d.join("scene.toml"), &text).unwrap();
        let e = load_scene(&d.join("scene.toml")).unwrap_err().to_string();
        for n in needles {
            assert!(e.contains(n), "{n:?} missing from: {e}");
        }
    }
}

/// The contract's form, `livereg model LABELMAP --out DIR`: the model read off the labelmap's
/// segments (the liver, a tumour as a mesh, the portal vein as points), and a scene that loads.
#[test]
fn model_without_labels_reads_the_segments() {
    let d = dir("model");
    write_nrrd(&d.join("seg.nrrd"));
    let out = d.join("model");
    let (code, stdout, err) = common::livereg(&[
        "model",
        d.join("seg.nrrd").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let summary: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(summary["watertight"], true);
    let v = summary["volume_ml"].as_f64().unwrap();
    let ball = 4.0 / 3.0 * PI * 24f64.powi(3) * 1e-3;
    assert!((v / ball - 1.0).abs() < 0.03, "{v} mL vs {ball}");
    let loaded = load_scene(&out.join("scene.toml")).unwrap();
    let names: Vec<&str> = loaded
        .scene
        .model
        .structures
        .iter()
        .map(|s| s.name.as_str())
        .collect();
    assert_eq!(names, ["tumour", "portal vein"]);
    assert!(loaded.scene.model.structures[0].mesh.is_some());
    let vessels = read_points(loaded.scene.model.structures[1].points.as_ref().unwrap()).unwrap();
    assert!(vessels
        .iter()
        .all(|p| ((p.x + 10.0).powi(2) + p.z * p.z).sqrt() <= 2.0 + 1e-9));
    // --mesh without --label is refused with the reason.
    let (code, _, err) = common::livereg(&[
        "model",
        d.join("seg.nrrd").to_str().unwrap(),
        "--mesh",
        "t=2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(err.contains("--label"), "{err}");
}
