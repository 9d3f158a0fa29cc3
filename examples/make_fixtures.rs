//! Regenerates the bundled scenes' meshes and point files in `fixtures/` (deterministic).
//! Run: `cargo run --example make_fixtures`.

use std::path::Path;

use livereg::mesh::primitives::{cylinder_surface, icosphere};
use livereg::mesh::{write_obj, write_points};
use nalgebra::Point3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");

    // Thesis §4.6 cylinder, in centimetres: radius 5, length 60, axis +z from z = 0.
    let dir = root.join("cylinder_bending");
    std::fs::create_dir_all(&dir)?;
    write_obj(
        &dir.join("cylinder.obj"),
        &cylinder_surface(5.0, 0.0, 60.0, 48, 36),
    )?;

    // A liver-lobe-like solid in millimetres: an ellipsoid 200 × 150 × 100 mm that thins
    // towards +x into a lobe, with a few internal target points.
    let dir = root.join("lobe_gravity");
    std::fs::create_dir_all(&dir)?;
    let mut lobe = icosphere(Point3::origin(), 1.0, 4);
    for v in &mut lobe.vertices {
        let thin = 0.55 + 0.45 * (1.0 - v.x) / 2.0;
        *v = Point3::new(100.0 * v.x, 75.0 * v.y, 50.0 * v.z * thin);
    }
    write_obj(&dir.join("lobe.obj"), &lobe)?;
    let targets = [
        Point3::new(-40.0, 0.0, 0.0),
        Point3::new(0.0, 20.0, 5.0),
        Point3::new(40.0, -15.0, 0.0),
        Point3::new(70.0, 0.0, 0.0),
        Point3::new(-60.0, -30.0, -10.0),
    ];
    write_points(&dir.join("targets.xyz"), &targets)?;
    // The liver phantom: surface, vessel targets, tumour, ligament, scene (mm).
    livereg::phantom::write_phantom(&root.join("liver_phantom"))?;

    println!("fixtures written under {}", root.display());
    Ok(())
}
