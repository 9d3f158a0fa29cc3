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
//! `solve_columns` pass (the contact force's three unit loads).
//!
//! Run: `cargo bench --bench linear_solvers -- --warm-up-time 1 --measurement-time 3`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use livereg::linalg::testing::{
    ball, elasticity_grid_matrix, grid_node_coordinates, node_set_elasticity_matrix, random_vector,
};
use livereg::linalg::{SolverKind, SparseSolver, SymmetricCsc};
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

criterion_group!(
    benches,
    bench_linear_solvers,
    bench_several_right_hand_sides
);
criterion_main!(benches);
