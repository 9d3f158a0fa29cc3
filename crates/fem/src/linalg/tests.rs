//! Unit tests of the sparse linear algebra module.
#![allow(clippy::needless_range_loop)]

use super::testing::{
    cut_cell_grid_matrix, elasticity_grid_matrix, elasticity_grid_matrix_with, grid_pattern,
    hex8_stiffness, random_vector, relative_residual, with_scaled_nodes, Fixation,
};
use super::*;
use nalgebra::{DMatrix, DVector};

const ALL_KINDS: [SolverKind; 4] = [
    SolverKind::Auto,
    SolverKind::Cholesky,
    SolverKind::Ldlt,
    SolverKind::JacobiCg,
];

fn dense(k: &SymmetricCsc) -> DMatrix<f64> {
    let d = k.to_dense();
    DMatrix::from_fn(k.n, k.n, |i, j| d[i][j])
}

/// Independent reference: dense LU with partial pivoting (nalgebra).
fn dense_solve(k: &SymmetricCsc, b: &[f64]) -> Vec<f64> {
    let x = dense(k)
        .lu()
        .solve(&DVector::from_column_slice(b))
        .expect("dense reference solve");
    x.as_slice().to_vec()
}

fn rel_diff(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt();
    let den: f64 = b.iter().map(|y| y * y).sum::<f64>().sqrt();
    num / den
}

fn solve_with(
    kind: SolverKind,
    k: &SymmetricCsc,
    b: &[f64],
) -> (Result<SolveStats, LinalgError>, Vec<f64>) {
    let mut s = SparseSolver::new(kind);
    let mut x = vec![f64::NAN; k.n];
    let r = s.factorize(k).and_then(|_| s.solve(k, b, &mut x));
    (r, x)
}

// ---------------------------------------------------------------- helpers --

#[test]
fn hex8_stiffness_is_symmetric_psd_with_rigid_modes() {
    let ke = hex8_stiffness(1.0, 0.3, 1.0);
    for i in 0..24 {
        assert!(ke[i][i] > 0.0);
        for j in 0..24 {
            assert!((ke[i][j] - ke[j][i]).abs() < 1e-14);
        }
    }
    // Rigid-body modes (3 translations, 3 infinitesimal rotations) give zero force.
    let coords = |a: usize| [(a & 1) as f64, ((a >> 1) & 1) as f64, ((a >> 2) & 1) as f64];
    let mut modes = Vec::new();
    for c in 0..3 {
        modes.push(
            (0..24)
                .map(|d| if d % 3 == c { 1.0 } else { 0.0 })
                .collect::<Vec<_>>(),
        );
    }
    for (p, q) in [(0, 1), (1, 2), (2, 0)] {
        let mut u = vec![0.0; 24];
        for a in 0..8 {
            let x = coords(a);
            u[3 * a + p] = -x[q];
            u[3 * a + q] = x[p];
        }
        modes.push(u);
    }
    for u in &modes {
        for row in &ke {
            let f: f64 = row.iter().zip(u).map(|(k, v)| k * v).sum();
            assert!(f.abs() < 1e-12, "rigid mode gives force {f}");
        }
    }
    // Exactly 6 zero eigenvalues, the rest positive.
    let m = DMatrix::from_fn(24, 24, |i, j| ke[i][j]);
    let eig = m.symmetric_eigenvalues();
    let zero = eig.iter().filter(|&&l| l.abs() < 1e-10).count();
    let pos = eig.iter().filter(|&&l| l > 1e-3).count();
    assert_eq!((zero, pos), (6, 18), "eigenvalues {eig}");
    // Stiffness of a cube scales linearly with its edge: K(h) = h K(1).
    let ke2 = hex8_stiffness(1.0, 0.3, 2.0);
    assert!((ke2[5][7] - 2.0 * ke[5][7]).abs() < 1e-14);
}

#[test]
fn grid_matrix_is_spd_and_matches_dense_product() {
    let k = elasticity_grid_matrix(3);
    assert_eq!(k.n, 81);
    k.validate().unwrap();
    let d = dense(&k);
    assert!(d.clone().cholesky().is_some(), "grid matrix must be SPD");
    let x = random_vector(k.n, 1);
    let mut y = vec![0.0; k.n];
    k.mul_vec(&x, &mut y);
    let yd = &d * DVector::from_column_slice(&x);
    assert!(rel_diff(&y, yd.as_slice()) < 1e-14);
    let diag = k.diagonal();
    for i in 0..k.n {
        assert_eq!(diag[i], d[(i, i)]);
    }
    // Interior node of a 3×3×3 grid couples with all 27 nodes.
    // Its x-dof (39) column stores rows 39..81 of the lower triangle.
    assert_eq!(k.col_ptr[3 * 13 + 1] - k.col_ptr[3 * 13], 81 - 39);
}

// ------------------------------------------------------------------- csc --

#[test]
fn position_finds_both_triangles_and_rejects_missing() {
    let k = grid_pattern(3);
    let p = k.position(10, 4).unwrap();
    assert_eq!(k.position(4, 10), Some(p));
    assert_eq!(k.row_idx[p], 10);
    assert!(p >= k.col_ptr[4] && p < k.col_ptr[5]);
    // Nodes 0 and 26 (opposite corners) are not coupled.
    assert_eq!(k.position(3 * 26, 0), None);
    assert_eq!(k.position(1000, 0), None);
    for j in 0..k.n {
        assert_eq!(k.position(j, j), Some(k.col_ptr[j]));
    }
}

#[test]
fn from_triplets_sums_duplicates_and_mirrors() {
    let k = SymmetricCsc::from_triplets(
        3,
        &[
            (0, 0, 2.0),
            (0, 1, -1.0),
            (1, 0, -0.5),
            (2, 2, 1.0),
            (0, 0, 1.0),
        ],
    )
    .unwrap();
    assert_eq!(k.col_ptr, vec![0, 2, 3, 4]);
    assert_eq!(k.row_idx, vec![0, 1, 1, 2]);
    assert_eq!(k.values, vec![3.0, -1.5, 0.0, 1.0]);
    assert!(matches!(
        SymmetricCsc::from_triplets(2, &[(2, 0, 1.0)]),
        Err(LinalgError::InvalidPattern(_))
    ));
}

#[test]
fn zero_values_keeps_pattern() {
    let mut k = elasticity_grid_matrix(2);
    let id = k.pattern_id();
    k.zero_values();
    assert!(k.values.iter().all(|&v| v == 0.0));
    assert_eq!(k.pattern_id(), id);
}

#[test]
fn pattern_id_depends_on_pattern_only() {
    let a = elasticity_grid_matrix(3);
    let mut b = a.clone();
    b.values.iter_mut().for_each(|v| *v *= 3.0);
    assert_eq!(a.pattern_id(), b.pattern_id());
    assert_ne!(a.pattern_id(), grid_pattern(4).pattern_id());
    // Same n and nnz, one row index moved.
    let c = SymmetricCsc::from_pattern(3, vec![0, 2, 3, 4], vec![0, 1, 1, 2]).unwrap();
    let d = SymmetricCsc::from_pattern(3, vec![0, 2, 3, 4], vec![0, 2, 1, 2]).unwrap();
    assert_ne!(c.pattern_id(), d.pattern_id());
}

fn invalid_msg(r: Result<SymmetricCsc, LinalgError>) -> String {
    match r {
        Err(LinalgError::InvalidPattern(m)) => m,
        other => panic!("expected InvalidPattern, got {other:?}"),
    }
}

#[test]
fn invalid_patterns_are_rejected_with_message() {
    // Unsorted rows in column 0.
    let m = invalid_msg(SymmetricCsc::from_pattern(
        3,
        vec![0, 3, 4, 5],
        vec![0, 2, 1, 1, 2],
    ));
    assert!(m.contains("not strictly increasing"), "{m}");
    // Duplicate row.
    let m = invalid_msg(SymmetricCsc::from_pattern(
        2,
        vec![0, 3, 4],
        vec![0, 1, 1, 1],
    ));
    assert!(m.contains("not strictly increasing"), "{m}");
    // Missing diagonal in column 1.
    let m = invalid_msg(SymmetricCsc::from_pattern(
        3,
        vec![0, 1, 2, 3],
        vec![0, 2, 2],
    ));
    assert!(m.contains("diagonal"), "{m}");
    // Empty column.
    let m = invalid_msg(SymmetricCsc::from_pattern(2, vec![0, 1, 1], vec![0]));
    assert!(m.contains("diagonal"), "{m}");
    // Out of bounds.
    let m = invalid_msg(SymmetricCsc::from_pattern(2, vec![0, 2, 3], vec![0, 5, 1]));
    assert!(m.contains("out of bounds"), "{m}");
    // Upper-triangular entry.
    let m = invalid_msg(SymmetricCsc::from_pattern(2, vec![0, 1, 3], vec![0, 0, 1]));
    assert!(m.contains("above the diagonal"), "{m}");
    // Wrong col_ptr length / end.
    let m = invalid_msg(SymmetricCsc::from_pattern(2, vec![0, 1], vec![0]));
    assert!(m.contains("col_ptr has length"), "{m}");
    let m = invalid_msg(SymmetricCsc::from_pattern(2, vec![0, 1, 3], vec![0, 1]));
    assert!(m.contains("row_idx has length"), "{m}");
    // A struct built by hand with a bad pattern is rejected by factorize.
    let bad = SymmetricCsc {
        n: 2,
        col_ptr: vec![0, 2, 3],
        row_idx: vec![1, 0, 1],
        values: vec![1.0, 0.0, 1.0],
    };
    for kind in ALL_KINDS {
        let mut s = SparseSolver::new(kind);
        assert!(
            matches!(s.factorize(&bad), Err(LinalgError::InvalidPattern(_))),
            "{kind:?}"
        );
    }
}

// ---------------------------------------------------------------- solver --

#[test]
fn every_kind_solves_and_matches_dense_reference() {
    let k = elasticity_grid_matrix(4); // 192 dofs
    let b = random_vector(k.n, 7);
    let reference = dense_solve(&k, &b);
    for kind in ALL_KINDS {
        let (r, x) = solve_with(kind, &k, &b);
        let stats = r.unwrap_or_else(|e| panic!("{kind:?}: {e}"));
        let res = relative_residual(&k, &x, &b);
        assert!(res < 1e-9, "{kind:?}: residual {res}");
        assert!((stats.relative_residual - res).abs() < 1e-9 + 1e-3 * res);
        let err = rel_diff(&x, &reference);
        // The penalty makes K ill-conditioned (κ ~ 1e10): allow for it in CG.
        let tol = if kind == SolverKind::JacobiCg {
            1e-4
        } else {
            1e-8
        };
        assert!(err < tol, "{kind:?}: forward error vs dense {err}");
        match kind {
            SolverKind::JacobiCg => {
                assert_eq!(stats.method, "jacobi-cg");
                assert!(stats.iterations > 0);
            }
            SolverKind::Ldlt => assert_eq!(stats.method, "ldlt-bunch-kaufman"),
            _ => assert_eq!(stats.method, "cholesky"),
        }
        if kind != SolverKind::JacobiCg {
            assert_eq!(stats.iterations, 0, "{kind:?}: no CG iterations for direct");
        }
    }
}

#[test]
fn every_kind_solves_clamped_block_accurately() {
    let k = elasticity_grid_matrix_with(6, Fixation::BottomFace, 1e8); // 648 dofs
    let b = random_vector(k.n, 3);
    let reference = dense_solve(&k, &b);
    for kind in ALL_KINDS {
        let (r, x) = solve_with(kind, &k, &b);
        r.unwrap_or_else(|e| panic!("{kind:?}: {e}"));
        assert!(relative_residual(&k, &x, &b) < 1e-9, "{kind:?}");
        assert!(
            rel_diff(&x, &reference) < 1e-7,
            "{kind:?}: {}",
            rel_diff(&x, &reference)
        );
    }
}

#[test]
fn auto_resolves_by_size_and_serde_names() {
    let s = SparseSolver::new(SolverKind::Auto);
    assert_eq!(s.chosen_method(100), SolverKind::Cholesky);
    assert_eq!(s.chosen_method(AUTO_DIRECT_MAX_DOFS), SolverKind::Cholesky);
    assert_eq!(
        s.chosen_method(AUTO_DIRECT_MAX_DOFS + 1),
        SolverKind::JacobiCg
    );
    assert_eq!(
        SparseSolver::new(SolverKind::Ldlt).chosen_method(10),
        SolverKind::Ldlt
    );
    assert_eq!(
        SparseSolver::new(SolverKind::JacobiCg).chosen_method(10),
        SolverKind::JacobiCg
    );
    for (kind, name) in [
        (SolverKind::Auto, "\"auto\""),
        (SolverKind::Cholesky, "\"cholesky\""),
        (SolverKind::Ldlt, "\"ldlt\""),
        (SolverKind::JacobiCg, "\"jacobi-cg\""),
    ] {
        assert_eq!(serde_json::to_string(&kind).unwrap(), name);
        assert_eq!(serde_json::from_str::<SolverKind>(name).unwrap(), kind);
    }
    assert_eq!(SolverKind::default(), SolverKind::Auto);
}

#[test]
fn symbolic_analysis_is_reused_for_same_pattern() {
    for kind in ALL_KINDS {
        let k1 = elasticity_grid_matrix(4);
        let mut k2 = k1.clone();
        // Different values, same pattern: scale and perturb the diagonal.
        k2.values.iter_mut().for_each(|v| *v *= 1.5);
        for j in 0..k2.n {
            k2.values[k2.col_ptr[j]] += 0.1 * (1 + j % 5) as f64;
        }
        let b = random_vector(k1.n, 11);
        let mut s = SparseSolver::new(kind);
        assert_eq!(s.symbolic_analyses(), 0);
        let mut x = vec![0.0; k1.n];
        s.factorize(&k1).unwrap();
        s.solve(&k1, &b, &mut x).unwrap();
        assert!(relative_residual(&k1, &x, &b) < 1e-9, "{kind:?}");
        let x1 = x.clone();
        s.factorize(&k2).unwrap();
        assert_eq!(
            s.symbolic_analyses(),
            1,
            "{kind:?}: analysis recomputed for same pattern"
        );
        s.solve(&k2, &b, &mut x).unwrap();
        assert!(relative_residual(&k2, &x, &b) < 1e-9, "{kind:?}");
        assert!(rel_diff(&x, &dense_solve(&k2, &b)) < 1e-4, "{kind:?}");
        assert!(
            rel_diff(&x, &x1) > 1e-3,
            "{kind:?}: second solve must use new values"
        );
        // Refactorising the same matrix again does not analyse either.
        s.factorize(&k1).unwrap();
        assert_eq!(s.symbolic_analyses(), 1);
        // A new pattern triggers a new analysis.
        let k3 = elasticity_grid_matrix(3);
        s.factorize(&k3).unwrap();
        assert_eq!(s.symbolic_analyses(), 2, "{kind:?}");
        let b3 = random_vector(k3.n, 12);
        let mut x3 = vec![0.0; k3.n];
        s.solve(&k3, &b3, &mut x3).unwrap();
        assert!(relative_residual(&k3, &x3, &b3) < 1e-9, "{kind:?}");
        // Solving with a matrix of another pattern than the factorised one fails.
        assert!(matches!(
            s.solve(&k1, &b, &mut x),
            Err(LinalgError::InvalidPattern(_))
        ));
    }
}

/// SPD grid matrix with the diagonal 3×3 block of one interior node negated.
fn indefinite_matrix() -> SymmetricCsc {
    let mut k = elasticity_grid_matrix(5);
    let node = 2 + 5 * (2 + 5 * 2);
    for a in 0..3 {
        for b in 0..=a {
            let p = k.position(3 * node + a, 3 * node + b).unwrap();
            k.values[p] = -k.values[p];
        }
    }
    k
}

#[test]
fn cholesky_falls_back_on_indefinite_matrix() {
    let k = indefinite_matrix();
    let eig = dense(&k).symmetric_eigenvalues();
    assert!(
        eig.iter().any(|&l| l < 0.0),
        "test matrix must be indefinite"
    );
    let b = random_vector(k.n, 5);
    let reference = dense_solve(&k, &b);
    for (kind, method) in [
        (SolverKind::Cholesky, "cholesky-fallback-ldlt-bunch-kaufman"),
        (SolverKind::Auto, "cholesky-fallback-ldlt-bunch-kaufman"),
        (SolverKind::Ldlt, "ldlt-bunch-kaufman"),
    ] {
        let (r, x) = solve_with(kind, &k, &b);
        let stats = r.unwrap_or_else(|e| panic!("{kind:?}: {e}"));
        assert_eq!(stats.method, method);
        let res = relative_residual(&k, &x, &b);
        assert!(res < 1e-9, "{kind:?}: residual {res}");
        assert!(rel_diff(&x, &reference) < 1e-7, "{kind:?}");
    }
    // CG: the negative diagonal is detected when preparing the preconditioner.
    let mut s = SparseSolver::new(SolverKind::JacobiCg);
    assert_eq!(s.factorize(&k), Err(LinalgError::NotPositiveDefinite));
}

#[test]
fn a_positive_definite_only_factorisation_leaves_an_indefinite_matrix_unfactorised() {
    // Indefinite: no factorisation (no Bunch–Kaufman fallback), and a solve says so.
    let k = indefinite_matrix();
    let b = random_vector(k.n, 7);
    let mut s = SparseSolver::new(SolverKind::Cholesky);
    assert_eq!(s.factorize_if_positive_definite(&k), Ok(false));
    assert_eq!(s.factorized_method(), None);
    let mut x = vec![0.0; k.n];
    assert_eq!(s.solve(&k, &b, &mut x), Err(LinalgError::NotFactorized));
    // The same solver then factorises a positive definite matrix of the same pattern as
    // `factorize` does: Cholesky, and the dense reference's solution.
    let spd = elasticity_grid_matrix(5);
    assert_eq!(s.factorize_if_positive_definite(&spd), Ok(true));
    assert_eq!(s.factorized_method(), Some("cholesky"));
    let stats = s.solve(&spd, &b, &mut x).unwrap();
    assert_eq!(stats.method, "cholesky");
    assert!(rel_diff(&x, &dense_solve(&spd, &b)) < 1e-9);
    // An explicit LDLᵀ solver factorises the indefinite matrix as `factorize` does.
    let mut l = SparseSolver::new(SolverKind::Ldlt);
    assert_eq!(l.factorize_if_positive_definite(&k), Ok(true));
    l.solve(&k, &b, &mut x).unwrap();
    assert!(rel_diff(&x, &dense_solve(&k, &b)) < 1e-7);
}

#[test]
fn cg_detects_indefinite_matrix_with_positive_diagonal() {
    // K − σ I with σ below the smallest diagonal entry but far above λ_min:
    // positive diagonal, yet indefinite (like geometric stiffness far from
    // equilibrium).
    let mut k = elasticity_grid_matrix(5);
    let dmin = k.diagonal().into_iter().fold(f64::INFINITY, f64::min);
    let sigma = 0.3 * dmin;
    for j in 0..k.n {
        let p = k.col_ptr[j];
        k.values[p] -= sigma;
    }
    let eig = dense(&k).symmetric_eigenvalues();
    assert!(eig.iter().filter(|&&l| l < 0.0).count() >= 2);
    assert!(k.diagonal().iter().all(|&d| d > 0.0));
    let b = random_vector(k.n, 9);
    let mut s = SparseSolver::new(SolverKind::JacobiCg);
    s.factorize(&k).unwrap();
    let mut x = vec![f64::NAN; k.n];
    let err = s.solve(&k, &b, &mut x).unwrap_err();
    assert!(
        matches!(
            err,
            LinalgError::NotPositiveDefinite | LinalgError::NotConverged { .. }
        ),
        "{err:?}"
    );
    assert!(x.iter().all(|v| v.is_finite()), "x must never contain NaN");
    // The direct solver handles it through the fallback.
    let (r, x) = solve_with(SolverKind::Cholesky, &k, &b);
    let stats = r.unwrap();
    assert_eq!(stats.method, "cholesky-fallback-ldlt-bunch-kaufman");
    assert!(relative_residual(&k, &x, &b) < 1e-9);
    assert!(rel_diff(&x, &dense_solve(&k, &b)) < 1e-7);
}

#[test]
fn ill_conditioned_scaling_is_handled() {
    // Scale the dofs of a few nodes (tiny cut cells) by 1e-8 symmetrically.
    let k0 = elasticity_grid_matrix_with(5, Fixation::BottomFace, 1e8);
    let (k, scale) = with_scaled_nodes(&k0, &[31, 62, 93, 124], 1e-8);
    // Exact relation: (S K0 S) (S⁻¹ x0) = S b0.
    let b0 = random_vector(k0.n, 21);
    let x0 = dense_solve(&k0, &b0);
    let b: Vec<f64> = b0.iter().zip(&scale).map(|(v, s)| v * s).collect();
    let expected: Vec<f64> = x0.iter().zip(&scale).map(|(v, s)| v / s).collect();
    for kind in ALL_KINDS {
        let (r, x) = solve_with(kind, &k, &b);
        let stats = r.unwrap_or_else(|e| panic!("{kind:?}: {e}"));
        let res = relative_residual(&k, &x, &b);
        assert!(res < 1e-9, "{kind:?}: residual {res}");
        // Forward error in the unscaled variables (S x ≈ x0).
        let sx: Vec<f64> = x.iter().zip(&scale).map(|(v, s)| v * s).collect();
        assert!(
            rel_diff(&sx, &x0) < 1e-6,
            "{kind:?}: {}",
            rel_diff(&sx, &x0)
        );
        assert!(rel_diff(&x, &expected) < 1e-6, "{kind:?}");
        if kind == SolverKind::JacobiCg {
            assert!(stats.iterations < 2000, "Jacobi must undo the scaling");
        }
    }
}

/// Backward error `‖b − Kx‖∞ / (‖K‖∞ ‖x‖∞ + ‖b‖∞)`.
fn backward_error(k: &SymmetricCsc, x: &[f64], b: &[f64]) -> f64 {
    let mut y = vec![0.0; k.n];
    k.mul_vec(x, &mut y);
    let inf = |v: &[f64]| v.iter().fold(0.0f64, |a, x| a.max(x.abs()));
    let r: Vec<f64> = y.iter().zip(b).map(|(y, b)| b - y).collect();
    let mut row_sums = vec![0.0; k.n];
    for j in 0..k.n {
        for p in k.col_ptr[j]..k.col_ptr[j + 1] {
            let i = k.row_idx[p];
            row_sums[i] += k.values[p].abs();
            if i != j {
                row_sums[j] += k.values[p].abs();
            }
        }
    }
    inf(&r) / (inf(&row_sums) * inf(x) + inf(b))
}

#[test]
fn cut_cells_with_tiny_volume_are_solved_backward_stably() {
    // Cells of two grid layers keep only 1e-6 of their stiffness: κ(K) far
    // beyond 1e12, not repaired by diagonal scaling.
    let k = cut_cell_grid_matrix(6, Fixation::BottomCorners, 1e8, 1e-6);
    let b = random_vector(k.n, 31);
    for kind in [SolverKind::Cholesky, SolverKind::Ldlt] {
        let (r, x) = solve_with(kind, &k, &b);
        r.unwrap_or_else(|e| panic!("{kind:?}: {e}"));
        let be = backward_error(&k, &x, &b);
        assert!(be < 1e-15, "{kind:?}: backward error {be}");
    }
    // Jacobi CG either converges or says it did not; never NaN.
    let mut s = SparseSolver::new(SolverKind::JacobiCg).with_cg_settings(1e-10, 3000);
    s.factorize(&k).unwrap();
    let mut x = vec![0.0; k.n];
    match s.solve(&k, &b, &mut x) {
        Ok(st) => assert!(relative_residual(&k, &x, &b) <= 1.01e-10, "{st:?}"),
        // The residual is computed with a different summation order here, and
        // it is dominated by cancellation (ε ‖K‖ ‖x‖), hence the 5 %.
        Err(LinalgError::NotConverged {
            relative_residual: r,
            ..
        }) => {
            let mine = relative_residual(&k, &x, &b);
            assert!(
                r.is_finite() && (mine - r).abs() <= 0.05 * r,
                "{r} vs {mine}"
            )
        }
        Err(e) => panic!("unexpected {e}"),
    }
    assert!(x.iter().all(|v| v.is_finite()));
}

#[test]
fn results_do_not_depend_on_thread_count() {
    let k = elasticity_grid_matrix(13); // 6591 dofs: parallel dense kernels
    let b = random_vector(k.n, 4);
    let run = |threads: usize, kind: SolverKind| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let (r, x) = solve_with(kind, &k, &b);
            r.unwrap();
            x
        })
    };
    for kind in [SolverKind::Cholesky, SolverKind::Ldlt, SolverKind::JacobiCg] {
        let x1 = run(1, kind);
        let x2 = run(2, kind);
        let d = rel_diff(&x2, &x1);
        assert!(d <= 1e-12, "{kind:?}: 1 vs 2 threads differ by {d}");
    }
    // CG with the parallel kernels (n ≥ 8192) is bitwise reproducible.
    let k = elasticity_grid_matrix(15); // 10125 dofs
    let b = random_vector(k.n, 4);
    let run_cg = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut s = SparseSolver::new(SolverKind::JacobiCg).with_cg_settings(1e-8, 400);
            s.factorize(&k).unwrap();
            let mut x = vec![0.0; k.n];
            let stats = s.solve(&k, &b, &mut x);
            (x, stats.map(|s| (s.iterations, s.relative_residual)))
        })
    };
    let (x1, s1) = run_cg(1);
    let (x2, s2) = run_cg(2);
    assert!(x1 == x2, "CG solutions differ between 1 and 2 threads");
    assert_eq!(s1, s2);
}

#[test]
fn solver_can_move_between_threads() {
    fn assert_send<T: Send>() {}
    fn assert_sync<T: Sync>() {}
    assert_send::<SparseSolver>();
    assert_sync::<SparseSolver>();
    assert_send::<SymmetricCsc>();
    assert_sync::<SymmetricCsc>();
}

#[test]
fn zero_rhs_gives_zero_solution() {
    let k = elasticity_grid_matrix(3);
    for kind in ALL_KINDS {
        let (r, x) = solve_with(kind, &k, &vec![0.0; k.n]);
        let stats = r.unwrap();
        assert!(x.iter().all(|&v| v == 0.0));
        assert_eq!((stats.iterations, stats.refinement_steps), (0, 0));
        assert_eq!(stats.relative_residual, 0.0);
    }
}

#[test]
fn cg_reports_not_converged_with_achieved_residual() {
    let k = elasticity_grid_matrix(6);
    let b = random_vector(k.n, 8);
    let mut s = SparseSolver::new(SolverKind::JacobiCg).with_cg_settings(1e-12, 5);
    s.factorize(&k).unwrap();
    let mut x = vec![0.0; k.n];
    match s.solve(&k, &b, &mut x) {
        Err(LinalgError::NotConverged {
            iterations,
            relative_residual: r,
        }) => {
            assert_eq!(iterations, 5);
            assert!(r > 1e-12 && r < 1.0, "{r}");
            assert!((relative_residual(&k, &x, &b) - r).abs() < 1e-8);
        }
        other => panic!("expected NotConverged, got {other:?}"),
    }
    assert!(x.iter().all(|v| v.is_finite()));
}

#[test]
fn singular_and_non_finite_inputs_are_reported() {
    // A zero row/column (dof 1 not coupled and no stiffness).
    let k = SymmetricCsc::from_triplets(3, &[(0, 0, 2.0), (2, 0, -1.0), (2, 2, 2.0)]).unwrap();
    let b = [1.0, 1.0, 1.0];
    for kind in ALL_KINDS {
        let mut s = SparseSolver::new(kind);
        assert_eq!(s.factorize(&k), Err(LinalgError::Singular), "{kind:?}");
        let mut x = [0.0; 3];
        assert_eq!(s.solve(&k, &b, &mut x), Err(LinalgError::NotFactorized));
    }
    // Rank-deficient without zero diagonal: [[1, 1], [1, 1]] is caught by the
    // pivot check (direct) or ends without NaN (CG).
    let k = SymmetricCsc::from_triplets(2, &[(0, 0, 1.0), (1, 0, 1.0), (1, 1, 1.0)]).unwrap();
    for kind in [SolverKind::Cholesky, SolverKind::Ldlt] {
        let mut s = SparseSolver::new(kind);
        assert_eq!(s.factorize(&k), Err(LinalgError::Singular), "{kind:?}");
    }
    // NaN in the matrix or the right-hand side.
    let mut k = elasticity_grid_matrix(2);
    let b = random_vector(k.n, 1);
    for kind in ALL_KINDS {
        let mut s = SparseSolver::new(kind);
        s.factorize(&k).unwrap();
        let mut x = vec![0.0; k.n];
        let mut bad_b = b.clone();
        bad_b[3] = f64::NAN;
        assert_eq!(s.solve(&k, &bad_b, &mut x), Err(LinalgError::NonFinite));
        assert!(x.iter().all(|v| v.is_finite()));
        // Wrong lengths.
        assert!(matches!(
            s.solve(&k, &b[1..], &mut x),
            Err(LinalgError::InvalidPattern(_))
        ));
    }
    k.values[5] = f64::INFINITY;
    for kind in ALL_KINDS {
        let mut s = SparseSolver::new(kind);
        assert_eq!(s.factorize(&k), Err(LinalgError::NonFinite));
    }
    // Solve before factorize.
    let mut s = SparseSolver::new(SolverKind::Cholesky);
    let mut x = vec![0.0; k.n];
    assert_eq!(s.solve(&k, &b, &mut x), Err(LinalgError::NotFactorized));
}

#[test]
fn tiny_and_one_by_one_systems() {
    let k = SymmetricCsc::from_triplets(1, &[(0, 0, 4.0)]).unwrap();
    for kind in ALL_KINDS {
        let (r, x) = solve_with(kind, &k, &[2.0]);
        r.unwrap();
        assert!((x[0] - 0.5).abs() < 1e-15, "{kind:?}");
    }
    let k = SymmetricCsc::from_triplets(2, &[(0, 0, 0.0), (1, 0, 1.0), (1, 1, 0.0)]).unwrap();
    // [[0, 1], [1, 0]]: indefinite with zero diagonal; Bunch–Kaufman 2×2 pivot.
    for kind in [SolverKind::Cholesky, SolverKind::Ldlt] {
        let (r, x) = solve_with(kind, &k, &[1.0, 2.0]);
        r.unwrap_or_else(|e| panic!("{kind:?}: {e}"));
        assert!(
            (x[0] - 2.0).abs() < 1e-14 && (x[1] - 1.0).abs() < 1e-14,
            "{kind:?}: {x:?}"
        );
    }
}

#[test]
fn single_precision_factors_are_refined_to_the_asked_tolerance_or_fall_back_to_f64() {
    // A badly scaled SPD matrix (tiny cut cells: dofs scaled by 1e-4) that f32 alone solves
    // only to ~1e-5; refinement in f64 must reach the asked residual and agree with the
    // dense reference.
    let k0 = elasticity_grid_matrix_with(6, Fixation::BottomFace, 1e8);
    let (k, _) = with_scaled_nodes(&k0, &[40, 81, 122], 1e-4);
    let b = random_vector(k.n, 33);
    let reference = dense_solve(&k, &b);
    for tol in [1e-6, 1e-10] {
        let mut s = SparseSolver::new(SolverKind::Cholesky);
        s.set_single_precision(Some(tol));
        s.factorize(&k).unwrap();
        assert_eq!(s.factorized_method(), Some("cholesky-f32"));
        let mut x = vec![0.0; k.n];
        let stats = s.solve(&k, &b, &mut x).unwrap();
        let res = relative_residual(&k, &x, &b);
        assert!(res <= tol, "tol {tol}: residual {res}");
        assert_eq!(stats.relative_residual, res);
        assert!(
            stats.refinement_steps >= 1,
            "f32 alone is not that accurate"
        );
        assert!(rel_diff(&x, &reference) < 1e3 * tol, "tol {tol}");
    }
    // Off again: the next factorisation is f64 and solves to rounding.
    let mut s = SparseSolver::new(SolverKind::Cholesky);
    s.set_single_precision(Some(1e-6));
    s.set_single_precision(None);
    s.factorize(&k).unwrap();
    assert_eq!(s.factorized_method(), Some("cholesky"));
    // An indefinite matrix (negative diagonal block) is not factorised in f32: the f64 path
    // falls back to LBLᵀ as before.
    let k = indefinite_matrix();
    let b = random_vector(k.n, 34);
    let mut s = SparseSolver::new(SolverKind::Cholesky);
    s.set_single_precision(Some(1e-6));
    s.factorize(&k).unwrap();
    assert_eq!(
        s.factorized_method(),
        Some("cholesky-fallback-ldlt-bunch-kaufman")
    );
    let mut x = vec![0.0; k.n];
    s.solve(&k, &b, &mut x).unwrap();
    assert!(relative_residual(&k, &x, &b) < 1e-9);
}

#[test]
fn several_columns_solve_like_each_column_alone_and_match_the_dense_reference() {
    // Three right-hand sides in one pass over the factor (and one zero column) must give what
    // the dense reference gives for each, for every kind and factor: f64 LLᵀ, LBLᵀ (explicit
    // and as the fallback of an indefinite matrix), f32 with refinement, CG column by column.
    let spd = elasticity_grid_matrix(4);
    let cases: Vec<(&str, SymmetricCsc, SolverKind, Option<f64>)> = vec![
        ("auto", spd.clone(), SolverKind::Auto, None),
        ("ldlt", spd.clone(), SolverKind::Ldlt, None),
        ("cg", spd.clone(), SolverKind::JacobiCg, None),
        ("f32", spd, SolverKind::Cholesky, Some(1e-10)),
        ("fallback", indefinite_matrix(), SolverKind::Cholesky, None),
    ];
    for (name, k, kind, single) in cases {
        let n = k.n;
        let mut b = Vec::new();
        for seed in [11, 12, 13] {
            b.extend(random_vector(n, seed));
        }
        b.extend(vec![0.0; n]);
        let mut s = SparseSolver::new(kind);
        s.set_single_precision(single);
        s.factorize(&k).unwrap();
        let mut x = vec![f64::NAN; 4 * n];
        let stats = s
            .solve_columns(&k, &b, &mut x, 4)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let tol = if kind == SolverKind::JacobiCg {
            1e-4
        } else {
            1e-8
        };
        let mut worst: f64 = 0.0;
        for (bj, xj) in b.chunks(n).zip(x.chunks(n)).take(3) {
            let err = rel_diff(xj, &dense_solve(&k, bj));
            assert!(err < tol, "{name}: forward error vs dense {err}");
            worst = worst.max(relative_residual(&k, xj, bj));
        }
        assert!(x[3 * n..].iter().all(|&v| v == 0.0), "{name}: zero column");
        assert!(
            (stats.relative_residual - worst).abs() <= 1e-3 * worst + 1e-15,
            "{name}: reported {} against the worst column's {worst}",
            stats.relative_residual
        );
    }
    // Shapes that do not match are an error, not a panic.
    let k = elasticity_grid_matrix(3);
    let mut s = SparseSolver::new(SolverKind::Cholesky);
    s.factorize(&k).unwrap();
    let mut x = vec![0.0; 2 * k.n];
    let e = s
        .solve_columns(&k, &vec![1.0; 2 * k.n - 1], &mut x, 2)
        .unwrap_err();
    assert!(e.to_string().contains("solve_columns"), "{e}");
}
