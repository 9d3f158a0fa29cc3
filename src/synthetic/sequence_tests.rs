//! Tests of synthetic sequences on the bundled phantom.

use super::*;
use crate::scene::load_scene;
use std::time::Instant;

fn phantom_scene(tag: &str) -> LoadedScene {
    let d = std::env::temp_dir().join(format!("livereg-seq-{}-{tag}", std::process::id()));
    crate::phantom::write_phantom(&d).unwrap();
    load_scene(&d.join("scene.toml")).unwrap()
}

#[test]
#[ignore]
fn explore() {
    let scene = phantom_scene("explore");
    let kinds: Vec<ScenarioKind> = match std::env::var("KIND") {
        Ok(k) => vec![ScenarioKind::from_name(&k).unwrap()],
        Err(_) => ScenarioKind::ALL.to_vec(),
    };
    for kind in kinds {
        let mut spec = SequenceSpec::phantom_default(kind);
        if let Ok(m) = std::env::var("MAG") {
            spec.magnitude = m.parse().unwrap();
        }
        if let Ok(h) = std::env::var("H") {
            spec.truth.cell_size = h.parse().unwrap();
        }
        if let Ok(h) = std::env::var("SUB") {
            spec.truth.subdivisions = h.parse().unwrap();
        }
        if let Ok(h) = std::env::var("FRAMES") {
            spec.frames = h.parse().unwrap();
        }
        let seq = generate_sequence(&scene, &spec).unwrap();
        println!(
            "{kind}: magnitude {} {}, truth {} nodes {} cells, {:.0} ms; load {:?}",
            spec.magnitude,
            kind.magnitude_unit(),
            seq.truth_nodes,
            seq.truth_cells,
            seq.truth_ms,
            seq.load
        );
        let rest_cam = seq.rest_surface_in_camera();
        for (k, f) in seq.frames.iter().enumerate() {
            let truth = seq.truth_surface(k);
            let inl: Vec<_> = f
                .cloud
                .iter()
                .zip(&f.is_outlier)
                .filter(|(_, &o)| !o)
                .map(|(p, _)| *p)
                .collect();
            let d_truth: f64 = inl
                .iter()
                .map(|p| crate::phantom::distance_to_surface(&truth, p))
                .sum::<f64>()
                / inl.len() as f64;
            let d_rest: Vec<f64> = inl
                .iter()
                .map(|p| crate::phantom::distance_to_surface(&rest_cam, p))
                .collect();
            let mean_rest = d_rest.iter().sum::<f64>() / d_rest.len() as f64;
            let far = d_rest.iter().filter(|&&d| d > 3e-3).count() as f64 / d_rest.len() as f64;
            let tre: Vec<f64> = f
                .truth_structures
                .iter()
                .zip(&seq.rest_structures)
                .map(|((_, t), (_, r))| {
                    t.iter()
                        .zip(r)
                        .map(|(a, b)| (a - seq.model_to_camera.apply(b)).norm())
                        .sum::<f64>()
                        / t.len() as f64
                })
                .collect();
            println!(
                "  frame {k}: s {:.3} max disp {:.1} mm, {} it {:.0} ms, {} pts ({} out), inlier dist truth {:.2} mm rest {:.2} mm (>3mm {:.0}%), struct disp {:?} mm",
                f.load_fraction,
                f.max_displacement * 1e3,
                f.newton_iterations,
                f.solve_ms,
                f.cloud.len(),
                f.outliers,
                d_truth * 1e3,
                mean_rest * 1e3,
                far * 100.0,
                tre.iter().map(|t| (t * 1e4).round() / 10.0).collect::<Vec<_>>()
            );
        }
    }
}

#[test]
#[ignore]
fn explore_solve() {
    let scene = phantom_scene("explore-solve");
    let kind = ScenarioKind::from_name(&std::env::var("KIND").unwrap()).unwrap();
    let mut spec = SequenceSpec::phantom_default(kind);
    if let Ok(m) = std::env::var("MAG") {
        spec.magnitude = m.parse().unwrap();
    }
    if let Ok(h) = std::env::var("H") {
        spec.truth.cell_size = h.parse().unwrap();
    }
    if let Ok(h) = std::env::var("SUB") {
        spec.truth.subdivisions = h.parse().unwrap();
    }
    if let Ok(h) = std::env::var("NU") {
        spec.truth.poisson_ratio = h.parse().unwrap();
    }
    let t = Instant::now();
    let truth_scene = spec.truth.apply_to(&scene);
    let mut model = SceneModel::build(&truth_scene).unwrap();
    println!(
        "build {:.0} ms, {} nodes {} cells",
        t.elapsed().as_secs_f64() * 1e3,
        model.problem.grid.node_count(),
        model.problem.grid.cells.len()
    );
    let load = ScenarioLoad::for_surface(kind, spec.magnitude, &model.surface, 1060.0);
    let f = load.forces(&model.problem.grid, &model.surface).unwrap();
    model.problem.external = f;
    let mut settings = model.newton;
    if let Ok(h) = std::env::var("STEPS") {
        settings.load_steps = h.parse().unwrap();
    }
    let mut solver = NewtonSolver::new(settings);
    let u0 = vec![0.0; model.problem.dofs()];
    let r = solver.solve(&mut model.problem, &u0);
    for h in &r.history {
        println!("  {:?}", h);
    }
    let max = model
        .surface_embedding
        .interpolate(&r.u)
        .iter()
        .map(|d| d.norm())
        .fold(0.0, f64::max);
    println!(
        "{:?} {:?} load {} its {} bisections {} {:.0} ms max disp {:.1} mm",
        r.outcome,
        r.message,
        r.load_reached,
        r.newton_iterations,
        r.bisections,
        r.wall_ms,
        max * 1e3
    );
}
