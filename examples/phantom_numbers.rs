//! The bundled liver phantom's numbers (`livereg::phantom::liver_phantom`, metres): triangle
//! and vertex counts, bounding box, volume and area, thickness across x, the ligament box's
//! share of the surface, how deep the vessel targets and the tumour lie. docs/registration.md
//! ("Phantom") and fixtures/README.md quote them. Run:
//!
//! `cargo run --release --example phantom_numbers`

use livereg::phantom::{area_in_box, distance_to_surface, liver_phantom, max_thickness_at};

fn main() {
    let p = liver_phantom();
    let s = &p.surface;
    let Some((lo, hi)) = s.bounding_box() else {
        eprintln!("the phantom has no surface");
        std::process::exit(1);
    };
    let e = hi - lo;
    println!(
        "triangles {} vertices {}",
        s.triangles.len(),
        s.vertices.len()
    );
    println!("bbox {lo:?} {hi:?} extents {e:?} m");
    println!(
        "volume {:.4} L, area {:.5} m²",
        s.signed_volume() * 1000.0,
        s.area()
    );
    for f in [0.1, 0.25, 0.5, 0.7, 0.85, 0.95] {
        println!(
            "thickness at {:.0} % of x: {:.4} m",
            f * 100.0,
            max_thickness_at(s, lo.x + f * e.x)
        );
    }
    println!(
        "ligament {:?}, share of the surface {:.4}",
        p.ligament,
        area_in_box(s, &p.ligament) / s.area()
    );
    let targets = p.targets.iter().map(|t| distance_to_surface(s, t));
    println!(
        "targets {}, nearest to the surface {:.4} m",
        p.targets.len(),
        targets.fold(f64::INFINITY, f64::min)
    );
    let tumour = p.tumour.vertices.iter().map(|t| distance_to_surface(s, t));
    println!(
        "tumour nearest to the surface {:.4} m, bbox {:?}",
        tumour.fold(f64::INFINITY, f64::min),
        p.tumour.bounding_box()
    );
}
