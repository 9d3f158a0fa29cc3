//! The thesis's cylinder experiments (§4.6): bending of a 60 cm neo-Hookean cylinder under a
//! dead end-face traction, and stretching of a 5 cm one to three times its length.

mod common;

use common::*;
use livereg::grid::{Embedding, IntegrationMode};
use livereg::mechanics::loads::traction_forces;
use livereg::mechanics::{LawKind, NewtonSettings, NewtonSolver, Outcome, SolveReport, VolumetricIntegration};
use livereg::mesh::primitives::cylinder_surface;
use nalgebra::{Point3, Vector3};

const RADIUS: f64 = 0.05;
const YOUNG: f64 = 5000.0;

/// Points along the cylinder's axis and on its skin where displacements are compared.
fn bending_samples(length: f64) -> Vec<Point3<f64>> {
    let mut v = Vec::new();
    for i in 1..=12 {
        let z = length * i as f64 / 12.0 - 1e-3;
        v.push(Point3::new(0.0, 0.0, z));
        v.push(Point3::new(0.0, 0.8 * RADIUS, z));
        v.push(Point3::new(0.8 * RADIUS, 0.0, z));
    }
    v
}

/// Cylinder bending: base held, 30 Pa downward (−y) dead traction on the top face.
/// Returns the solve report and the displacements of [`bending_samples`].
pub fn bending(h: f64, levels: u32, mode: IntegrationMode) -> (SolveReport, Vec<Vector3<f64>>) {
    let length = 0.6;
    let s = cylinder_surface(RADIUS, 0.0, length, 48, 36);
    let mut p = problem(&s, &options(h, levels, mode), material(LawKind::NeoHookean, YOUNG, 0.3), VolumetricIntegration::Reduced);
    p.springs = vec![hold(&p, &s, aabb([-1.0, -1.0, -1e-4], [1.0, 1.0, 1e-4]), 1e3, YOUNG)];
    let mut f = vec![0.0; p.dofs()];
    let n = traction_forces(&p.grid, &s, &aabb([-1.0, -1.0, length - 1e-4], [1.0, 1.0, length + 1e-4]), Vector3::new(0.0, -30.0, 0.0), &mut f).unwrap();
    assert!(n > 0);
    p.external = f;
    let settings = NewtonSettings { load_steps: 10, max_iterations: 25, residual_tolerance: 1e-8, ..NewtonSettings::default() };
    let u0 = vec![0.0; p.dofs()];
    let report = NewtonSolver::new(settings).solve(&mut p, &u0);
    let d = Embedding::new(&p.grid, &bending_samples(length)).unwrap().interpolate(&report.u);
    (report, d)
}

/// Relative L2 difference of two displacement sample sets.
fn rel_diff(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y).norm_squared()).sum();
    let den: f64 = b.iter().map(|y| y.norm_squared()).sum();
    (num / den).sqrt()
}

#[test]
#[ignore = "exploration: prints timings"]
fn bending_explore() {
    for (h, l) in [(0.025, 2), (0.0167, 2), (0.0125, 2)] {
        for mode in [IntegrationMode::WeightedCell, IntegrationMode::FiniteCell] {
            let t = std::time::Instant::now();
            let (r, d) = bending(h, l, mode);
            let tip = d[d.len() - 3];
            println!("h={h} L={l} {mode:?}: {:?} iters {} steps {} bis {} tip {tip:?} {:.1}s", r.outcome, r.newton_iterations, r.load_steps, r.bisections, t.elapsed().as_secs_f64());
        }
    }
}

#[test]
fn stretching_to_three_times_the_length_solves_at_every_level() {
    let length = 0.05;
    let s = cylinder_surface(RADIUS, 0.0, length, 48, 8);
    for levels in 0..=4 {
        let mut p = problem(&s, &options(0.0125, levels, IntegrationMode::WeightedCell), material(LawKind::NeoHookean, YOUNG, 0.3), VolumetricIntegration::Reduced);
        let cells = p.grid.stats().cells;
        // Both end faces pulled along their normals by one length each: total 3×.
        let mut bottom = hold(&p, &s, aabb([-1.0, -1.0, -1e-4], [1.0, 1.0, 1e-4]), 1e3, YOUNG);
        bottom.target = vec![Vector3::new(0.0, 0.0, -0.5 * length * 2.0); bottom.embedding.len()];
        bottom.follows_load = true;
        let mut top = hold(&p, &s, aabb([-1.0, -1.0, length - 1e-4], [1.0, 1.0, length + 1e-4]), 1e3, YOUNG);
        top.target = vec![Vector3::new(0.0, 0.0, 0.5 * length * 2.0); top.embedding.len()];
        top.follows_load = true;
        p.springs = vec![bottom, top];
        let settings = NewtonSettings { load_steps: 10, ..NewtonSettings::default() };
        let u0 = vec![0.0; p.dofs()];
        let r = NewtonSolver::new(settings).solve(&mut p, &u0);
        assert_eq!(r.outcome, Outcome::Converged, "level {levels}: {:?}", r.message);
        assert_eq!(p.grid.stats().cells, cells, "no cell removed");
        // Top face centre moved by ~ +L, bottom by ~ −L.
        let e = Embedding::new(&p.grid, &[Point3::new(0.0, 0.0, length - 1e-3), Point3::new(0.0, 0.0, 1e-3)]).unwrap();
        let d = e.interpolate(&r.u);
        println!("level {levels}: {} cells, {} iterations, {} bisections, top {:.4}, bottom {:.4}", cells, r.newton_iterations, r.bisections, d[0].z, d[1].z);
        assert!((d[0].z - length).abs() < 0.05 * length && (d[1].z + length).abs() < 0.05 * length);
    }
}
