//! What the phantom's three synthetic scenarios give with their defaults
//! (`SequenceSpec::phantom_default`, 10 frames, the default finite-cell truth): per scenario
//! the load and the truth's size and solve time; per frame the load fraction, the largest
//! surface displacement, the truth's Newton iterations and time, the cloud's size, and the
//! target error left by the best rigid fit of the surface the camera sees (the truth's
//! surface vertices within 4 mm of an inlier, fitted rest → deformed with Kabsch): what rigid
//! alignment alone can at best achieve from the cloud. Run:
//!
//! `cargo run --release --example phantom_sequences`

use livereg::registration::kabsch;
use livereg::scene::load_scene;
use livereg::synthetic::{generate_sequence, ScenarioKind, SequenceSpec};
use nalgebra::Point3;

fn main() -> Result<(), String> {
    let dir =
        std::env::temp_dir().join(format!("livereg-phantom-sequences-{}", std::process::id()));
    livereg::phantom::write_phantom(&dir).map_err(|e| e.to_string())?;
    let scene = load_scene(&dir.join("scene.toml")).map_err(|e| e.to_string())?;
    for kind in ScenarioKind::ALL {
        let spec = SequenceSpec::phantom_default(kind);
        let seq = generate_sequence(&scene, &spec).map_err(|e| format!("{kind}: {e}"))?;
        println!(
            "{kind}: {} {}, truth {} nodes {} cells, {:.0} ms",
            spec.magnitude,
            kind.magnitude_unit(),
            seq.truth_nodes,
            seq.truth_cells,
            seq.truth_ms,
        );
        let rest: Vec<Point3<f64>> = seq
            .rest_structures
            .iter()
            .flat_map(|(_, r)| r.iter().copied())
            .collect();
        for (k, f) in seq.frames.iter().enumerate() {
            let truth: Vec<Point3<f64>> = f
                .truth_structures
                .iter()
                .flat_map(|(_, r)| r.iter().copied())
                .collect();
            let inliers = f.inliers();
            let seen: Vec<usize> = (0..f.truth_surface.len())
                .filter(|&i| {
                    inliers
                        .iter()
                        .any(|p| (p - f.truth_surface[i]).norm() < 4e-3)
                })
                .collect();
            let a: Vec<Point3<f64>> = seen.iter().map(|&i| seq.rest_surface[i]).collect();
            let b: Vec<Point3<f64>> = seen.iter().map(|&i| f.truth_surface[i]).collect();
            let fit = kabsch(&a, &b, None).ok_or(format!("{kind} frame {k}: no rigid fit"))?;
            let tre = rest
                .iter()
                .zip(&truth)
                .map(|(p, q)| (fit.apply(p) - q).norm())
                .sum::<f64>()
                / rest.len() as f64;
            println!(
                "  frame {k}: load {:.3}, max displacement {:.1} mm, {} Newton iterations, {:.0} ms, {} points ({} outliers), target TRE after a rigid fit of the seen surface {:.2} mm",
                f.load_fraction,
                f.max_displacement * 1e3,
                f.newton_iterations,
                f.solve_ms,
                f.cloud.len(),
                f.outliers,
                tre * 1e3
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
