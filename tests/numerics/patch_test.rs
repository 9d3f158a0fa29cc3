//! Patch tests on full cells: uniform strain is reproduced to rounding.

use crate::common;

use common::*;
use livereg::grid::IntegrationMode;
use livereg::mechanics::{LawKind, Need, VolumetricIntegration};
use livereg::mesh::primitives::box_surface;
use nalgebra::{DVector, Matrix3, Point3};

/// Displacement gradient of the uniform strain used below.
fn gradient() -> Matrix3<f64> {
    Matrix3::new(0.02, -0.01, 0.005, 0.015, -0.03, 0.01, -0.004, 0.008, 0.025)
}

/// Grid-aligned box of 4 × 4 × 4 full cells, 125 nodes of which 27 interior.
fn box_problem(law: LawKind, vol: VolumetricIntegration) -> livereg::mechanics::StaticProblem {
    let s = box_surface(Point3::new(0.0, 0.0, 0.0), Point3::new(0.04, 0.04, 0.04), 4);
    problem(
        &s,
        &options(0.01, 2, IntegrationMode::WeightedCell),
        material(law, 3000.0, 0.45),
        vol,
    )
}

fn interior(p: &livereg::mechanics::StaticProblem, n: usize) -> bool {
    let d = p.grid.grid.dims;
    let c = p.grid.node_coords[n];
    (0..3).all(|k| c[k] > 0 && c[k] < d[k])
}

#[test]
fn box_grid_has_only_full_cells() {
    let p = box_problem(LawKind::Linear, VolumetricIntegration::Reduced);
    let stats = p.grid.stats();
    assert_eq!((stats.cells, stats.cut_cells, stats.nodes), (64, 0, 125));
    assert!((stats.volume - 0.04f64.powi(3)).abs() < 1e-15);
}

/// Form A: under any uniform deformation the interior nodes carry no internal force.
#[test]
fn uniform_deformation_leaves_interior_nodes_in_equilibrium() {
    let g = gradient() * 10.0; // large strain for the nonlinear laws
    for law in LAWS {
        for vol in [VolumetricIntegration::Reduced, VolumetricIntegration::Full] {
            let mut p = box_problem(law, vol);
            let n = p.grid.node_count();
            let mut u = vec![0.0; 3 * n];
            for a in 0..n {
                let x = p.grid.node_position(a).coords;
                let d = g * x;
                u[3 * a..3 * a + 3].copy_from_slice(d.as_slice());
            }
            let mut r = vec![0.0; 3 * n];
            p.evaluate(&u, 0.0, Need::Force, Some(&mut r), None)
                .expect("no inversion");
            let scale = r.iter().map(|v| v.abs()).fold(0.0, f64::max);
            assert!(scale > 0.0);
            for a in (0..n).filter(|&a| interior(&p, a)) {
                for d in 0..3 {
                    assert!(
                        r[3 * a + d].abs() <= 1e-11 * scale,
                        "{law:?} {vol:?}: node {a} force {}",
                        r[3 * a + d]
                    );
                }
            }
        }
    }
}

/// Form B: boundary nodes prescribed by a uniform strain, interior solved: exact.
#[test]
fn prescribed_boundary_reproduces_uniform_strain_inside() {
    let g = gradient();
    let mut p = box_problem(LawKind::Linear, VolumetricIntegration::Reduced);
    let n = p.grid.node_count();
    let mut k = p.new_tangent();
    let u0 = vec![0.0; 3 * n];
    p.evaluate(&u0, 0.0, Need::Tangent, None, Some(&mut k))
        .unwrap();
    let kd = dense(&k);
    let free: Vec<usize> = (0..3 * n).filter(|&i| interior(&p, i / 3)).collect();
    let fixed: Vec<usize> = (0..3 * n).filter(|&i| !interior(&p, i / 3)).collect();
    let exact = |i: usize| (g * p.grid.node_position(i / 3).coords)[i % 3];
    let ub = DVector::from_iterator(fixed.len(), fixed.iter().map(|&i| exact(i)));
    let kii = kd.select_rows(&free).select_columns(&free);
    let kib = kd.select_rows(&free).select_columns(&fixed);
    let ui = kii.cholesky().expect("SPD").solve(&(-(kib * ub)));
    for (slot, &i) in free.iter().enumerate() {
        assert!(
            (ui[slot] - exact(i)).abs() < 1e-12,
            "dof {i}: {} vs {}",
            ui[slot],
            exact(i)
        );
    }
}
