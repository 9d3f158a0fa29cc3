//! VTK files against the reference implementation, VTK itself (the `vtk` Python package,
//! installed by `scripts/test`): what livereg writes (`write_vtk`, `register --vtk`) VTK reads
//! back with the same points and cells; what VTK writes in each of its encodings livereg
//! reads back as the surface VTK was given. The tests fail, not skip, without `vtk`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use livereg::mesh::vtk::{PointArray, VtkPolyData};
use livereg::mesh::{read_obj, read_surface, write_vtk, TriSurface};
use serde_json::Value;

use crate::common;
use crate::recording_case;

fn phantom_liver() -> (PathBuf, TriSurface) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/liver_phantom/liver.obj");
    let surface = read_obj(&path).unwrap();
    (path, surface)
}

fn temp(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("livereg-vtk-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs tests/python/vtk_check.py with `args`; its stdout as JSON.
fn vtk_check(args: &[&str]) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/vtk_check.py");
    let out = Command::new("python3")
        .arg(&script)
        .args(args)
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "the VTK check failed (is `vtk` installed? python3 -m pip install vtk==9.7.1): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON value")
}

fn points_of(v: &Value) -> Vec<[f64; 3]> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let c: Vec<f64> = p
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            [c[0], c[1], c[2]]
        })
        .collect()
}

fn cells_of(v: &Value) -> Vec<Vec<usize>> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|c| {
            c.as_array()
                .unwrap()
                .iter()
                .map(|i| i.as_u64().unwrap() as usize)
                .collect()
        })
        .collect()
}

#[test]
fn vtk_reads_what_livereg_writes_with_the_same_points_and_cells() {
    let (_, liver) = phantom_liver();
    let d = temp("write");
    let values: Vec<f64> = (0..liver.vertices.len()).map(|i| i as f64 * 0.25).collect();
    let arrays = [PointArray {
        name: "error_mm".into(),
        components: 1,
        values: values.clone(),
    }];
    let files = [d.join("liver.vtp"), d.join("liver.vtk")];
    for f in &files {
        write_vtk(
            f,
            &VtkPolyData {
                points: &liver.vertices,
                triangles: &liver.triangles,
                arrays: &arrays,
            },
        )
        .unwrap();
    }
    let args: Vec<&str> = std::iter::once("read")
        .chain(files.iter().map(|f| f.to_str().unwrap()))
        .collect();
    let read = vtk_check(&args);
    for f in &files {
        let r = &read[f.to_str().unwrap()];
        assert_eq!(r["point_type"], "double", "{}", f.display());
        let pts = points_of(&r["points"]);
        let expected: Vec<[f64; 3]> = liver.vertices.iter().map(|p| [p.x, p.y, p.z]).collect();
        assert_eq!(pts, expected, "{}: points differ", f.display());
        let polys = cells_of(&r["polys"]);
        let tris: Vec<Vec<usize>> = liver.triangles.iter().map(|t| t.to_vec()).collect();
        assert_eq!(polys, tris, "{}: cells differ", f.display());
        assert!(cells_of(&r["verts"]).is_empty());
        let got: Vec<f64> = r["arrays"]["error_mm"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        assert_eq!(got, values, "{}: point array", f.display());
    }
}

#[test]
fn livereg_reads_every_encoding_vtk_writes() {
    let (obj, liver) = phantom_liver();
    let d = temp("read");
    let made = vtk_check(&["write", obj.to_str().unwrap(), d.to_str().unwrap()]);
    assert!(made["strips"].as_u64().unwrap() > 10, "{made}");
    for name in [
        "vtk_default.vtp",
        "vtk_raw.vtp",
        "vtk_binary_inline.vtp",
        "vtk_ascii.vtp",
        "vtk_binary.vtk",
        "vtk_ascii.vtk",
    ] {
        let s = read_surface(&d.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(s.triangles, liver.triangles, "{name}");
        if name.contains("ascii") {
            // ASCII keeps VTK's printed digits only.
            for (a, b) in s.vertices.iter().zip(&liver.vertices) {
                assert!((a - b).norm() < 1e-6, "{name}: {a} vs {b}");
            }
        } else {
            assert_eq!(s.vertices, liver.vertices, "{name}");
        }
    }
    // Strips: another triangulation of the same closed, outward surface.
    let s = read_surface(&d.join("vtk_strips.vtp")).unwrap();
    assert_eq!(s.triangles.len(), liver.triangles.len());
    let report = livereg::mesh::validate(&s);
    assert!(report.watertight, "{report:?}");
    let (v, v0) = (s.signed_volume(), liver.signed_volume());
    assert!((v - v0).abs() < 1e-9 * v0.abs(), "strip volume {v} vs {v0}");
}

#[test]
fn register_writes_a_paraview_series_that_vtk_reads() {
    let d = recording_case::case("vtk", 3);
    // The surface again as a mesh structure: its deformed vertices are in results.jsonl.
    let scene = std::fs::read_to_string(d.join("scene.toml")).unwrap();
    let scene = scene.replace(
        "[grid]",
        "[[model.structures]]\nname = \"surface copy\"\nmesh = \"body.obj\"\n[grid]",
    );
    std::fs::write(d.join("scene.toml"), scene).unwrap();
    let out = d.join("out");
    let vtk_dir = d.join("vtk");
    let (code, _, stderr) = common::livereg(&[
        "register",
        d.join("scene.toml").to_str().unwrap(),
        "--frames",
        d.join("frames").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--vtk",
        vtk_dir.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let results: Vec<Value> = std::fs::read_to_string(out.join("results.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(results.len(), 3);
    let body = read_obj(&d.join("body.obj")).unwrap();
    let body_tris: Vec<Vec<usize>> = body.triangles.iter().map(|t| t.to_vec()).collect();
    let mut series = BTreeMap::new();
    for (object, stem) in [
        ("liver", "liver"),
        ("targets", "targets"),
        ("surface copy", "surface_copy"),
    ] {
        let entries = vtk_check(&["pvd", vtk_dir.join(format!("{stem}.pvd")).to_str().unwrap()]);
        let entries = entries.as_array().unwrap();
        assert_eq!(entries.len(), 3, "{stem}.pvd");
        for (k, e) in entries.iter().enumerate() {
            assert_eq!(e["timestep"].as_f64().unwrap(), k as f64);
            assert_eq!(e["file"], format!("{stem}_{k:06}.vtp"));
        }
        series.insert(object, stem);
    }
    let files: Vec<String> = (0..3)
        .flat_map(|k| {
            series
                .values()
                .map(|stem| {
                    vtk_dir
                        .join(format!("{stem}_{k:06}.vtp"))
                        .to_str()
                        .unwrap()
                        .to_string()
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let args: Vec<&str> = std::iter::once("read")
        .chain(files.iter().map(String::as_str))
        .collect();
    let read = vtk_check(&args);
    for (k, result) in results.iter().enumerate() {
        let file = |stem: &str| &read[vtk_dir.join(format!("{stem}_{k:06}.vtp")).to_str().unwrap()];
        let structure = |name: &str| -> Vec<[f64; 3]> { points_of(&result["structures"][name]) };
        // The liver's deformed vertices are the mesh structure's (the same embedding).
        let liver = file("liver");
        let copy = structure("surface copy");
        let pts = points_of(&liver["points"]);
        assert_eq!(pts.len(), copy.len());
        for (a, b) in pts.iter().zip(&copy) {
            let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
            assert!(d < 1e-9, "frame {k}: liver vertex {a:?} vs structure {b:?}");
        }
        assert_eq!(cells_of(&liver["polys"]), body_tris, "frame {k}");
        assert_eq!(
            points_of(&file("surface_copy")["points"]),
            copy,
            "frame {k}"
        );
        assert_eq!(cells_of(&file("surface_copy")["polys"]), body_tris);
        // Targets: points as vertex cells, exactly results.jsonl's.
        let targets = file("targets");
        assert_eq!(
            points_of(&targets["points"]),
            structure("targets"),
            "frame {k}"
        );
        assert_eq!(cells_of(&targets["verts"]), vec![vec![0], vec![1], vec![2]]);
        // The recording case's third frame file is broken: written with the last good state
        // and marked failed.
        let failed = result["diagnostics"].get("error").is_some();
        assert_eq!(liver["arrays"].get("failed").is_some(), failed, "frame {k}");
    }
    assert!(
        results[2]["diagnostics"].get("error").is_some(),
        "the case's third frame is broken"
    );
}
