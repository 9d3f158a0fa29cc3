//! Criterion benchmarks of the sparse linear solvers on 3-dof linear-elasticity
//! grid matrices (27-point stencil, four bottom corners fixed):
//! ~1,000 nodes (10³ grid, 3,000 dofs) and ~10,000 nodes (22³ grid, 31,944 dofs).
//!
//! Each iteration times what one Newton iteration pays: `factorize` (numeric
//! factorisation with the symbolic analysis reused, or preconditioner set-up)
//! plus `solve`. The `cholesky-with-analysis` case also includes the symbolic
//! analysis (first Newton iteration on a new grid).
//!
//! Run: `cargo bench --bench linear_solvers -- --warm-up-time 1 --measurement-time 3`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use livereg::linalg::testing::{elasticity_grid_matrix, random_vector};
use livereg::linalg::{SolverKind, SparseSolver};
use std::hint::black_box;

fn bench_linear_solvers(c: &mut Criterion) {
    for (m, label) in [(10usize, "1k-nodes"), (22, "10k-nodes")] {
        let k = elasticity_grid_matrix(m);
        let b = random_vector(k.n, 42);
        let mut group = c.benchmark_group(format!("linear_solvers/{label}-{}dofs", k.n));
        group.sample_size(10);
        for (name, kind) in [
            ("cholesky", SolverKind::Cholesky),
            ("jacobi-cg", SolverKind::JacobiCg),
        ] {
            let mut solver = SparseSolver::new(kind);
            let mut x = vec![0.0; k.n];
            solver.factorize(&k).expect("factorize");
            group.bench_function(BenchmarkId::new(name, "factorize+solve"), |bench| {
                bench.iter(|| {
                    solver.factorize(black_box(&k)).expect("factorize");
                    let stats = solver.solve(&k, black_box(&b), &mut x).expect("solve");
                    black_box(stats.relative_residual)
                })
            });
        }
        let mut x = vec![0.0; k.n];
        group.bench_function(
            BenchmarkId::new("cholesky-with-analysis", "factorize+solve"),
            |bench| {
                bench.iter(|| {
                    let mut solver = SparseSolver::new(SolverKind::Cholesky);
                    solver.factorize(black_box(&k)).expect("factorize");
                    let stats = solver.solve(&k, black_box(&b), &mut x).expect("solve");
                    black_box(stats.relative_residual)
                })
            },
        );
        group.finish();
    }
}

criterion_group!(benches, bench_linear_solvers);
criterion_main!(benches);
