//! The small scene and frames the register, recording, replay and VTK tests share
//! (`register_cli.rs`, `recording_cli.rs`, `replay_cli.rs`, `vtk_files.rs`).
#![allow(dead_code)]

use std::path::PathBuf;

use livereg::mesh::primitives::icosphere;
use livereg::mesh::{write_obj, write_points};
use nalgebra::{Point3, Vector3};

/// A clamped ellipsoid scene in mm with 3 targets and `frames` frames bending it (cycling),
/// the third frame file broken.
pub fn case(tag: &str, frames: usize) -> PathBuf {
    let d = std::env::temp_dir().join(format!("livereg-reccli-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(d.join("frames")).unwrap();
    let mut s = icosphere(Point3::origin(), 1.0, 3);
    for v in &mut s.vertices {
        *v = Point3::new(50.0 * v.x, 37.5 * v.y, 25.0 * v.z);
    }
    write_obj(&d.join("body.obj"), &s).unwrap();
    let targets = [
        Point3::new(-20.0, 0.0, 0.0),
        Point3::new(10.0, 5.0, 0.0),
        Point3::new(35.0, 0.0, -3.0),
    ];
    write_points(&d.join("targets.xyz"), &targets).unwrap();
    std::fs::write(
        d.join("scene.toml"),
        r#"units = "mm"
[model]
surface = "body.obj"
[[model.structures]]
name = "targets"
points = "targets.xyz"
[grid]
cell_size = 20.0
subdivisions = 2
[material]
law = "neo-hookean"
young_modulus = 4500.0
poisson_ratio = 0.45
[[boundary.fixed]]
box = [[-60.0, -60.0, -60.0], [-35.0, 60.0, 60.0]]
[registration]
rigid = "icp"
"#,
    )
    .unwrap();
    for k in 0..frames {
        let a = 2.0 * (k % 4) as f64;
        let pts: Vec<Point3<f64>> = s
            .vertices
            .iter()
            .map(|p| {
                let t = ((p.x + 35.0) / 85.0).max(0.0);
                p + Vector3::new(0.0, 0.0, a * t * t)
            })
            .collect();
        write_points(&d.join(format!("frames/f{k:03}.xyz")), &pts).unwrap();
    }
    std::fs::write(d.join("frames/f002.xyz"), "1 2 3\n4 five 6\n").unwrap();
    d
}
