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
        if let Ok(h) = std::env::var("BED") {
            spec.truth.bed_stiffness = h.parse().unwrap();
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
            let all_rest: Vec<Point3<f64>> = seq
                .rest_structures
                .iter()
                .flat_map(|(_, r)| r.iter().copied())
                .collect();
            let all_truth: Vec<Point3<f64>> = f
                .truth_structures
                .iter()
                .flat_map(|(_, r)| r.iter().copied())
                .collect();
            let best = crate::registration::kabsch(&all_rest, &all_truth, None).unwrap();
            let best_tre = all_rest
                .iter()
                .zip(&all_truth)
                .map(|(a, b)| (best.apply(a) - b).norm())
                .sum::<f64>()
                / all_rest.len() as f64;
            let best_s =
                crate::registration::kabsch(&seq.rest_surface, &f.truth_surface, None).unwrap();
            let best_s_tre = seq.rest_structures[0]
                .1
                .iter()
                .zip(&f.truth_structures[0].1)
                .map(|(a, b)| (best_s.apply(a) - b).norm())
                .sum::<f64>()
                / seq.rest_structures[0].1.len() as f64;
            let vis: Vec<usize> = (0..f.truth_surface.len())
                .filter(|&i| inl.iter().any(|p| (p - f.truth_surface[i]).norm() < 4e-3))
                .collect();
            let rs: Vec<Point3<f64>> = vis.iter().map(|&i| seq.rest_surface[i]).collect();
            let ts: Vec<Point3<f64>> = vis.iter().map(|&i| f.truth_surface[i]).collect();
            let best_v = crate::registration::kabsch(&rs, &ts, None).unwrap();
            let vis_tre = all_rest
                .iter()
                .zip(&all_truth)
                .map(|(a, b)| (best_v.apply(a) - b).norm())
                .sum::<f64>()
                / all_rest.len() as f64;
            println!("  frame {k}: {} visible vertices; structure TRE after rigid fit of the visible vertices {:.2} mm", vis.len(), vis_tre * 1e3);
            println!("  frame {k}: best rigid TRE on structures {:.2} mm, vessel TRE after surface-vertex rigid fit {:.2} mm", best_tre * 1e3, best_s_tre * 1e3);
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
    let f_full = model.problem.external.clone();
    let mut solver = NewtonSolver::new(model.newton);
    let mut u = vec![0.0; model.problem.dofs()];
    let steps: usize = std::env::var("STEPS").map_or(5, |s| s.parse().unwrap());
    for k in 1..=steps {
        let s = k as f64 / steps as f64;
        model.problem.external = f_full.iter().map(|f| f * s).collect();
        for it in 0..40 {
            let t = Instant::now();
            let r = solver.improve(&mut model.problem, &mut u, 1);
            println!(
                "  load {s:.2} it {it}: rel {:.3e} conv {} fail {:?} {:.0} ms",
                r.relative_residual,
                r.converged,
                r.failure,
                t.elapsed().as_secs_f64() * 1e3
            );
            if r.converged {
                break;
            }
        }
    }
    let r_u = u;
    let max = model
        .surface_embedding
        .interpolate(&r_u)
        .iter()
        .map(|d| d.norm())
        .fold(0.0, f64::max);
    println!("max disp {:.1} mm", max * 1e3);
}
