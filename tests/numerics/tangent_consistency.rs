//! The assembled tangent is the derivative of the assembled residual, and the residual the
//! derivative of the potential, for every law, in cut cells (weighted- and finite-cell) and with
//! penalty springs; rigid motions produce no internal force.

use crate::common;

use common::*;
use livereg::grid::{Embedding, IntegrationMode};
use livereg::mechanics::{LawKind, Need, PenaltySprings, StaticProblem, VolumetricIntegration};
use livereg::mesh::primitives::icosphere;
use nalgebra::{Point3, Rotation3, Vector3};

const R: f64 = 0.05;

/// A sphere of radius 5 cm on 2 cm cells (every boundary cell is cut), with a held cap,
/// springs pulling random embedded points to random targets, and point-to-plane springs
/// (stiff along random normals only) on the same points.
fn sphere_problem(
    law: LawKind,
    mode: IntegrationMode,
    vol: VolumetricIntegration,
) -> StaticProblem {
    let s = icosphere(Point3::new(0.003, -0.002, 0.001), R, 3);
    let young = 4500.0;
    let mut p = problem(&s, &options(0.02, 2, mode), material(law, young, 0.45), vol);
    assert!(p.grid.stats().cut_cells > 10);
    let held = hold(
        &p,
        &s,
        aabb([-1.0, -1.0, -1.0], [1.0, 1.0, -0.035]),
        1e3,
        young,
    );
    let mut rng = Rng(42);
    let pts: Vec<Point3<f64>> = (0..20)
        .map(|_| Point3::new(rng.next(), rng.next(), rng.next()) * 0.6 * R)
        .collect();
    let emb = Embedding::new(&p.grid, &pts).unwrap();
    let pull = PenaltySprings {
        target: (0..20)
            .map(|_| Vector3::new(rng.next(), rng.next(), rng.next()) * 0.01)
            .collect(),
        stiffness: (0..20).map(|_| 50.0 * (1.5 + rng.next())).collect(),
        embedding: emb.clone(),
        follows_load: true,
        normals: None,
    };
    // Point-to-plane springs on the same points: stiffness only along random unit normals.
    let slide = PenaltySprings {
        target: (0..20)
            .map(|_| Vector3::new(rng.next(), rng.next(), rng.next()) * 0.01)
            .collect(),
        stiffness: (0..20).map(|_| 80.0 * (1.5 + rng.next())).collect(),
        embedding: emb,
        follows_load: false,
        normals: Some(
            (0..20)
                .map(|_| Vector3::new(rng.next(), rng.next(), rng.next() + 0.1).normalize())
                .collect(),
        ),
    };
    p.springs = vec![held, pull, slide];
    let n = p.dofs();
    p.external = rng.vec(n, 1e-3);
    p
}

fn check(law: LawKind, mode: IntegrationMode, vol: VolumetricIntegration, amplitude: f64) {
    let mut p = sphere_problem(law, mode, vol);
    let n = p.dofs();
    let mut rng = Rng(7);
    let u = rng.vec(n, amplitude);
    let load = 0.7;
    let mut r = vec![0.0; n];
    let mut k = p.new_tangent();
    let e0 = p
        .evaluate(&u, load, Need::Tangent, Some(&mut r), Some(&mut k))
        .expect("valid state");
    assert!(e0.potential.is_finite());
    for trial in 0..3 {
        let v = Rng(100 + trial).vec(n, 1.0);
        let mut kv = vec![0.0; n];
        k.mul_vec(&v, &mut kv);
        let eps = 1e-7;
        let shifted =
            |s: f64| -> Vec<f64> { u.iter().zip(&v).map(|(a, b)| a + s * eps * b).collect() };
        let (mut rp, mut rm) = (vec![0.0; n], vec![0.0; n]);
        let ep = p
            .evaluate(&shifted(1.0), load, Need::Force, Some(&mut rp), None)
            .unwrap();
        let em = p
            .evaluate(&shifted(-1.0), load, Need::Force, Some(&mut rm), None)
            .unwrap();
        let scale = kv.iter().map(|x| x.abs()).fold(0.0, f64::max);
        let err = (0..n)
            .map(|i| ((rp[i] - rm[i]) / (2.0 * eps) - kv[i]).abs())
            .fold(0.0, f64::max);
        assert!(
            err <= 1e-6 * scale,
            "{law:?} {mode:?} {vol:?}: tangent error {err:e} vs {scale:e}"
        );
        let rv: f64 = r.iter().zip(&v).map(|(a, b)| a * b).sum();
        let fd = (ep.potential - em.potential) / (2.0 * eps);
        assert!(
            (fd - rv).abs() <= 1e-6 * rv.abs().max(1e-12),
            "{law:?}: residual vs energy {fd:e} {rv:e}"
        );
    }
}

#[test]
fn tangent_matches_finite_differences_for_every_law_in_cut_cells() {
    for law in LAWS {
        for mode in [IntegrationMode::WeightedCell, IntegrationMode::FiniteCell] {
            check(law, mode, VolumetricIntegration::Reduced, 2e-3);
        }
        check(
            law,
            IntegrationMode::WeightedCell,
            VolumetricIntegration::Full,
            2e-3,
        );
    }
}

#[test]
fn tangent_matches_finite_differences_at_large_strain() {
    for law in [LawKind::Svk, LawKind::NeoHookean, LawKind::Corotated] {
        check(
            law,
            IntegrationMode::WeightedCell,
            VolumetricIntegration::Reduced,
            4e-3,
        );
    }
}

#[test]
fn rigid_motions_produce_no_internal_force() {
    let rot = Rotation3::from_euler_angles(0.7, -1.1, 2.3);
    let t = Vector3::new(0.3, -0.2, 0.05);
    for law in LAWS {
        let mut p = sphere_problem(
            law,
            IntegrationMode::WeightedCell,
            VolumetricIntegration::Reduced,
        );
        p.springs.clear();
        let n = p.grid.node_count();
        let mut u = vec![0.0; 3 * n];
        for a in 0..n {
            let x = p.grid.node_position(a).coords;
            let d = rot * x + t - x;
            u[3 * a..3 * a + 3].copy_from_slice(d.as_slice());
        }
        let mut r = vec![0.0; 3 * n];
        let e = p
            .evaluate(&u, 0.0, Need::Force, Some(&mut r), None)
            .unwrap();
        let fmax = r.iter().map(|v| v.abs()).fold(0.0, f64::max);
        // Scale: the force a 1 % strain would give on a cell face, E h².
        let scale = 4500.0 * 0.02f64.powi(2) * 0.01;
        if law == LawKind::Linear {
            // Small-strain elasticity is not rotation invariant: the test can tell.
            assert!(
                fmax > scale,
                "linear law should show spurious rotation forces"
            );
        } else {
            assert!(
                fmax < 1e-9 * scale,
                "{law:?}: force {fmax:e} under rigid motion"
            );
            assert!(
                e.strain_energy.abs() < 1e-12,
                "{law:?}: energy {:e}",
                e.strain_energy
            );
        }
    }
}
