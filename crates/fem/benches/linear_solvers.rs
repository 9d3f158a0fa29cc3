//! Criterion benchmarks of the sparse linear solvers on 3-dof linear-elasticity
//! grid matrices (27-point stencil):
//! boxes of ~1,000 nodes (10³ grid, 3,000 dofs) and ~10,000 nodes (22³ grid,
//! 31,944 dofs) with the four bottom corners fixed, and balls of ~1,000 and
//! ~10,000 nodes (`testing::node_set_elasticity_matrix`, bottom layer fixed).
//!
//! Each iteration times what one Newton iteration pays: `factorize` (numeric
//! factorisation with the symbolic analysis reused, or preconditioner set-up)
//! plus `solve`. The `*-with-analysis` cases also include the symbolic
//! analysis (first Newton iteration on a new grid). `cholesky` uses the AMD
//! ordering, `cholesky-nd` the geometric nested dissection from the node
//! coordinates (`SparseSolver::with_node_coordinates`); the factor sizes
//! (`factor_nnz`) of both are printed to stderr.
//!
//! `three-rhs` times three right-hand sides solved one by one against one
//! `solve_columns` pass (the contact force's three unit loads); `mixed-precision` one
//! factorisation and the eight solves it serves in warm frames, f64 against single precision.
//!
//! Run: `cargo bench --bench linear_solvers -- --warm-up-time 1 --measurement-time 3`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use livereg_fem::linalg::testing::{
    ball, elasticity_grid_matrix, grid_node_coordinates, node_set_elasticity_matrix, random_vector,
};
use livereg_fem::linalg::{SolverKind, SparseSolver, SymmetricCsc};
use livereg_fem::mechanics::MIXED_PRECISION_TOLERANCE;
use std::hint::black_box;

/// Solver variants: (benchmark name, kind, use node coordinates).
const VARIANTS: [(&str, SolverKind, bool); 3] = [
    ("cholesky", SolverKind::Cholesky, false),
    ("cholesky-nd", SolverKind::Cholesky, true),
    ("jacobi-cg", SolverKind::JacobiCg, false),
];

fn solver(kind: SolverKind, coords: Option<&[[usize; 3]]>) -> SparseSolver {
    let s = SparseSolver::new(kind);
    match coords {
        Some(c) => s.with_node_coordinates(c.to_vec()),
        None => s,
    }
}

fn bench_linear_solvers(c: &mut Criterion) {
    let mut cases: Vec<(String, SymmetricCsc, Vec<[usize; 3]>)> = Vec::new();
    for (m, label) in [(10usize, "1k-nodes"), (22, "10k-nodes")] {
        cases.push((
            label.to_string(),
            elasticity_grid_matrix(m),
            grid_node_coordinates(m),
        ));
    }
    for (extent, centre, radius) in [(14, 6, 6.3), (30, 14, 13.6)] {
        let (k, coords) = node_set_elasticity_matrix(extent, ball(centre, radius));
        let label = format!("ball-{}-nodes", coords.len());
        cases.push((label, k, coords));
    }
    for (label, k, coords) in &cases {
        let b = random_vector(k.n, 42);
        let mut group = c.benchmark_group(format!("linear_solvers/{label}-{}dofs", k.n));
        group.sample_size(10);
        for (name, kind, nd) in VARIANTS {
            let mut solver = solver(kind, nd.then_some(coords.as_slice()));
            let mut x = vec![0.0; k.n];
            solver.factorize(k).expect("factorize");
            if kind != SolverKind::JacobiCg {
                eprintln!(
                    "{label} ({} dofs) {name}: ordering {:?}, factor_nnz {}",
                    k.n,
                    solver.fill_reducing_ordering(),
                    solver.factor_nnz()
                );
            }
            group.bench_function(BenchmarkId::new(name, "factorize+solve"), |bench| {
                bench.iter(|| {
                    solver.factorize(black_box(k)).expect("factorize");
                    let stats = solver.solve(k, black_box(&b), &mut x).expect("solve");
                    black_box(stats.relative_residual)
                })
            });
        }
        let mut x = vec![0.0; k.n];
        for (name, nd) in [
            ("cholesky-with-analysis", false),
            ("cholesky-nd-with-analysis", true),
        ] {
            group.bench_function(BenchmarkId::new(name, "factorize+solve"), |bench| {
                bench.iter(|| {
                    let mut solver = solver(SolverKind::Cholesky, nd.then_some(coords.as_slice()));
                    solver.factorize(black_box(k)).expect("factorize");
                    let stats = solver.solve(k, black_box(&b), &mut x).expect("solve");
                    black_box(stats.relative_residual)
                })
            });
        }
        group.finish();
    }
}

/// Three right-hand sides with one kept factorisation (the contact force's unit loads, every
/// frame): one `solve` each against one `solve_columns` pass over the factor, on the 1,000-node
/// ball (nested dissection).
fn bench_several_right_hand_sides(c: &mut Criterion) {
    let (k, coords) = node_set_elasticity_matrix(14, ball(6, 6.3));
    let mut solver = solver(SolverKind::Cholesky, Some(&coords));
    solver.factorize(&k).expect("factorize");
    let n = k.n;
    let b: Vec<f64> = (0..3).flat_map(|s| random_vector(n, 50 + s)).collect();
    let mut x = vec![0.0; 3 * n];
    let mut group = c.benchmark_group(format!("linear_solvers/three-rhs-{n}dofs"));
    group.sample_size(20);
    group.bench_function("solve x3", |bench| {
        bench.iter(|| {
            for (bj, xj) in b.chunks(n).zip(x.chunks_mut(n)) {
                black_box(solver.solve(&k, black_box(bj), xj).expect("solve"));
            }
        })
    });
    group.bench_function("solve_columns", |bench| {
        bench.iter(|| {
            black_box(
                solver
                    .solve_columns(&k, black_box(&b), &mut x, 3)
                    .expect("solve"),
            )
        })
    });
    group.finish();
}

/// What a kept factorisation costs over its life in warm frames (one factorisation, then
/// [`REUSED_SOLVES`] solves: the warm reuse cap) in f64 and in single precision refined to
/// `MIXED_PRECISION_TOLERANCE`, on boxes of 7³ to 15³ nodes (1,029 to 10,125 unknowns; the
/// phantom's warm grid has 1,020, the indentation liver's 4,539): where mixed precision
/// starts to pay.
fn bench_mixed_precision(c: &mut Criterion) {
    for m in [7usize, 10, 12, 15] {
        let k = elasticity_grid_matrix(m);
        let coords = grid_node_coordinates(m);
        let b = random_vector(k.n, 7);
        let mut x = vec![0.0; k.n];
        let mut group = c.benchmark_group(format!("linear_solvers/mixed-precision-{}dofs", k.n));
        group.sample_size(10);
        for (name, tol) in [
            ("f64", None),
            ("f32-refined", Some(MIXED_PRECISION_TOLERANCE)),
        ] {
            let mut solver = solver(SolverKind::Cholesky, Some(&coords));
            solver.set_single_precision(tol);
            solver.factorize(&k).expect("factorize");
            group.bench_function(
                format!("factorize + {REUSED_SOLVES} solves, {name}"),
                |bench| {
                    bench.iter(|| {
                        solver.factorize(black_box(&k)).expect("factorize");
                        for _ in 0..REUSED_SOLVES {
                            black_box(solver.solve(&k, black_box(&b), &mut x).expect("solve"));
                        }
                    })
                },
            );
        }
        group.finish();
    }
}

/// Solves one warm factorisation serves (`NonRigidSettings::warm`'s `factor_reuse`).
const REUSED_SOLVES: usize = 8;

criterion_group!(
    benches,
    bench_linear_solvers,
    bench_several_right_hand_sides,
    bench_mixed_precision
);
criterion_main!(benches);
