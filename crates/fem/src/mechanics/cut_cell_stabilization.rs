//! Cut-cell step stabilisation: a constant penalty matrix on the non-affine (hourglass) part
//! of each cut cell's displacement,
//!
//! `½ uᵀ (c S) u = ½ γ μ h Σ_{cut cells c} (1 − f_c) Σ_{i=1..3} u_{c,i}ᵀ P u_{c,i}`,
//!
//! with `γ` dimensionless (`solver.step_stabilization`), `μ` the shear modulus (Pa), `h` the
//! cell edge (m), `f_c` the cell's inside volume fraction, `u_{c,i}` the 8 nodal displacements
//! (m) of component `i`, and `P = I − A Aᵀ/8` the orthogonal projector of the 8 corner values
//! onto the complement of the affine fields (`A` holds `1, ξ, η, ζ` at the corners, whose
//! columns are orthogonal with squared norm 8).
//!
//! It is added to the *tangents factorised to serve several steps* of
//! [`NewtonSolver::improve`] (registration's warm frames), never to the energy or the
//! residual, so the model's equilibrium is unchanged: it is a fixed point of the stabilised
//! steps, and a modified Newton iteration with any positive definite matrix and a line search
//! converges to it. The price is the rate in the damped modes: the non-affine motion of badly
//! cut cells approaches equilibrium linearly and slowly
//! (`tests/numerics/newton_robustness.rs`: 200 stabilised steps from rest to a 6 cm bend end
//! 0.29 mm from the equilibrium at well-held nodes and 1.8 mm at the badly cut cells' nodes,
//! against 10⁻¹¹ m without), which a registration's small frame-to-frame changes make
//! tolerable. A fresh factorisation is exact and needs none (cold frames get none).
//!
//! Why: a node whose cells are all badly cut is held only by the fictitious weight `α`
//! (`grid.min_fraction`) of their outside parts: soft and, under a hyperelastic law, so
//! nonlinear that a kept factorisation's step overshoots at those nodes by one to two orders
//! of magnitude (1,443-node phantom: curvature along the step up to 40 times the
//! factorisation's, ≥ 99 % of the step's norm on such nodes); the line search then cuts the
//! whole step and the solver refactorises. `c S` holds those nodes to their cell's affine
//! motion within a step, and being constant it never goes stale in a kept factorisation.
//!
//! Why not in the energy: as a model term it stiffens exactly the badly cut cells a coarse
//! grid's thin lobe is made of. On the phantom's 22.5 mm grid the forward solution of a
//! pneumoperitoneum load fell from 20.2 mm to 17.2 mm at γ = 1 and to 9.4 mm at γ = 100
//! (truth 23.8 mm).
//!
//! Every affine displacement (rigid motions and uniform strains) has `P u = 0`, so the step
//! is not damped in those modes however large the rotation; for a smooth field `P u = O(h²)`.
//! The penalty stays inside each cell, so the tangent's sparsity pattern (and the factor's
//! fill) is unchanged.
//!
//! [`NewtonSolver::improve`]: super::NewtonSolver::improve

use super::assembly::Assembler;
use crate::grid::hex8::CORNERS;
use crate::grid::{IntegrationMode, WeightedCellGrid};
use crate::linalg::SymmetricCsc;

/// The projector `P = I − A Aᵀ/8` onto the non-affine modes of the 8 corner values
/// (dimensionless, symmetric, idempotent, rank 4).
pub(crate) fn non_affine_projector() -> [[f64; 8]; 8] {
    let mut p = [[0.0; 8]; 8];
    for (a, row) in p.iter_mut().enumerate() {
        for (b, v) in row.iter_mut().enumerate() {
            let (ca, cb) = (CORNERS[a], CORNERS[b]);
            let affine = 1.0 + ca[0] * cb[0] + ca[1] * cb[1] + ca[2] * cb[2];
            *v = f64::from(u8::from(a == b)) - affine / 8.0;
        }
    }
    p
}

/// The weight `1 − f_c` of cell `c` in the stabilisation: its outside fraction for a cut cell,
/// 0 for a full one and for every cell in full-cell mode (cut cells count as full there and
/// have no weak nodes).
pub(crate) fn cell_weight(grid: &WeightedCellGrid, c: usize) -> f64 {
    let cell = &grid.cells[c];
    if grid.options.mode == IntegrationMode::FullCell || !cell.cut {
        return 0.0;
    }
    (1.0 - cell.fraction).clamp(0.0, 1.0)
}

/// Adds `c S` to `tangent` (N/m, through `assembler`'s cell scatter maps, built for `grid`),
/// with `c = γ μ h` (Pa·m): `½ c uᵀ S u` is the penalty of the module's formula.
pub(crate) fn add_cut_cell_stabilization(
    grid: &WeightedCellGrid,
    assembler: &Assembler,
    c: f64,
    tangent: &mut SymmetricCsc,
) {
    let p = non_affine_projector();
    for cell in 0..grid.cells.len() {
        let w = c * cell_weight(grid, cell);
        if w == 0.0 {
            continue;
        }
        for (a, row) in p.iter().enumerate() {
            for (b, pab) in row.iter().enumerate().take(a + 1) {
                for i in 0..3 {
                    tangent.values[assembler.cell_slot(cell, a, b, i, i)] += w * pab;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix3, Point3, Rotation3, Vector3};

    use super::*;
    use crate::grid::GridOptions;
    use crate::mesh::primitives::icosphere;

    /// A ball of radius 5 cm on cells of edge `h` (m), shifted so that cells are cut unevenly.
    fn ball(h: f64) -> WeightedCellGrid {
        let s = icosphere(Point3::new(0.0013, -0.0021, 0.0007), 0.05, 4);
        WeightedCellGrid::build(
            &s,
            &GridOptions {
                cell_size: h,
                ..Default::default()
            },
        )
        .unwrap()
    }

    fn field(grid: &WeightedCellGrid, f: impl Fn(Vector3<f64>) -> Vector3<f64>) -> Vec<f64> {
        grid.node_positions()
            .iter()
            .flat_map(|p| {
                let d = f(p.coords);
                [d.x, d.y, d.z]
            })
            .collect()
    }

    /// `½ uᵀ (c S) u` (J) and `c S u` (N) from the assembled matrix.
    fn energy_and_force(grid: &WeightedCellGrid, c: f64, u: &[f64]) -> (f64, Vec<f64>) {
        let a = Assembler::new(grid);
        let mut k = a.pattern().clone();
        add_cut_cell_stabilization(grid, &a, c, &mut k);
        let mut f = vec![0.0; u.len()];
        k.mul_vec(u, &mut f);
        let e = 0.5 * u.iter().zip(&f).map(|(x, y)| x * y).sum::<f64>();
        (e, f)
    }

    #[test]
    fn projector_is_the_orthogonal_projector_onto_four_non_affine_modes() {
        let p = non_affine_projector();
        let mut trace = 0.0;
        for a in 0..8 {
            trace += p[a][a];
            for b in 0..8 {
                assert_eq!(p[a][b], p[b][a]);
                let pp: f64 = (0..8).map(|k| p[a][k] * p[k][b]).sum();
                assert!((pp - p[a][b]).abs() < 1e-15, "idempotent");
            }
        }
        assert!(
            (trace - 4.0).abs() < 1e-14,
            "rank 4: 8 corners − 4 affine modes"
        );
        // The trilinear mode ξηζ is orthogonal to the affine ones: P keeps it whole.
        let xyz: Vec<f64> = CORNERS.iter().map(|c| c[0] * c[1] * c[2]).collect();
        for a in 0..8 {
            let pa: f64 = (0..8).map(|b| p[a][b] * xyz[b]).sum();
            assert!((pa - xyz[a]).abs() < 1e-15);
        }
    }

    #[test]
    fn affine_motions_cost_nothing_however_large() {
        let grid = ball(0.02);
        assert!(grid.stats().cut_cells > 20);
        // A 60° rotation about a skew axis, a 20 % stretch and a 3 cm translation.
        let r = Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, -0.5)),
            1.05,
        );
        let a =
            r.matrix() * Matrix3::from_diagonal(&Vector3::new(1.2, 0.9, 1.0)) - Matrix3::identity();
        let b = Vector3::new(0.03, -0.01, 0.02);
        let u = field(&grid, |x| a * x + b);
        let c = 1e5;
        let (e, f) = energy_and_force(&grid, c, &u);
        // A node's force scale if its cells were bent: c × |u| ≈ 1e5 × 0.05.
        assert!(e.abs() < 1e-9, "energy {e}");
        assert!(
            f.iter().all(|v| v.abs() < 1e-9),
            "max force {:e}",
            f.iter().fold(0.0f64, |m, v| m.max(v.abs()))
        );
    }

    #[test]
    fn one_displaced_node_costs_a_quarter_of_its_cut_cells_weights() {
        // P_aa = 1 − (1 + 3)/8 = 1/2, so moving one node by δ costs ½ c δ² Σ w_c / 2 over the
        // cut cells around it, and pulls it back with c δ Σ w_c / 2.
        let grid = ball(0.02);
        let (node, cells): (usize, Vec<f64>) = (0..grid.node_count())
            .map(|n| {
                let w = (0..grid.cells.len())
                    .filter(|&c| grid.cells[c].nodes.contains(&n))
                    .map(|c| cell_weight(&grid, c))
                    .filter(|&w| w > 0.0)
                    .collect::<Vec<_>>();
                (n, w)
            })
            .find(|(_, w)| w.len() >= 2)
            .unwrap();
        let sum_w: f64 = cells.iter().sum();
        let (c, delta) = (3.0e4, 0.004);
        let mut u = vec![0.0; 3 * grid.node_count()];
        u[3 * node + 1] = delta;
        let (e, f) = energy_and_force(&grid, c, &u);
        let expect = c * delta * delta * sum_w / 4.0;
        assert!((e - expect).abs() < 1e-12 * expect, "{e} vs {expect}");
        assert!((f[3 * node + 1] - c * delta * sum_w / 2.0).abs() < 1e-9);
        assert_eq!(f[3 * node], 0.0, "components do not couple");
    }

    #[test]
    fn the_matrix_is_positive_semi_definite() {
        // Non-affine fields of every kind cost something, never less than nothing.
        let grid = ball(0.025);
        let c = 2.0e4;
        for k in 0..6 {
            let w = 40.0 + 17.0 * k as f64;
            let u = field(&grid, |x| {
                Vector3::new(
                    (w * x.y).sin(),
                    (w * x.z + 1.0).cos(),
                    (w * x.x * x.y).sin(),
                ) * 1e-3
            });
            let (e, _) = energy_and_force(&grid, c, &u);
            assert!(e > 0.0, "field {k}: energy {e}");
        }
    }

    #[test]
    fn vanishes_as_h_cubed_for_a_smooth_field() {
        // P u = O(h²) per cell for a smooth u, S per cell O(h⁵), on O(h⁻²) cut cells: halving
        // h divides S by about 8 (the cut cells' fractions vary, hence the band).
        let smooth = |x: Vector3<f64>| Vector3::new(x.y * x.z, x.x * x.x, x.x * x.y) * 4.0;
        let energy = |h: f64| {
            let g = ball(h);
            let u = field(&g, smooth);
            energy_and_force(&g, 1e4 * h, &u).0
        };
        let (coarse, fine) = (energy(0.02), energy(0.01));
        let ratio = coarse / fine;
        assert!(
            coarse > 0.0 && (5.0..13.0).contains(&ratio),
            "ratio {ratio}"
        );
    }
}
