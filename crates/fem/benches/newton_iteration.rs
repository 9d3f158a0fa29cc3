//! One Newton iteration on liver-sized grids (tangent + residual assembly, factorisation,
//! solve), split into its parts; and the tangent assembly cost of weighted-cell versus
//! finite-cell integration at 0 and 4 subdivision levels; and the residual of a linear body
//! through its kept stiffness against a neo-Hookean body's pass over its cells.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use livereg_fem::geometry::Aabb;
use livereg_fem::grid::{GridOptions, IntegrationMode, WeightedCellGrid};
use livereg_fem::linalg::{SolverKind, SparseSolver};
use livereg_fem::mechanics::{
    LawKind, Material, Need, PenaltySprings, StaticProblem, VolumetricIntegration,
};
use livereg_fem::mesh::primitives::icosphere;
use livereg_fem::mesh::TriSurface;
use nalgebra::Point3;

/// A liver-sized ellipsoid, 20 × 15 × 10 cm.
fn liver_like() -> TriSurface {
    let mut s = icosphere(Point3::origin(), 1.0, 5);
    for v in &mut s.vertices {
        v.x *= 0.10;
        v.y *= 0.075;
        v.z *= 0.05;
    }
    s
}

/// Neo-Hookean liver (E = 4.5 kPa, ν = 0.49) held on its lower back (a ligament-like region),
/// so that the tangent is positive definite as in a real solve.
fn problem(cell: f64, levels: u32, mode: IntegrationMode) -> StaticProblem {
    let surface = liver_like();
    let opts = GridOptions {
        cell_size: cell,
        subdivisions: levels,
        mode,
        ..GridOptions::default()
    };
    let grid = WeightedCellGrid::build(&surface, &opts).unwrap();
    let m = Material::from_young_poisson(LawKind::NeoHookean, 4500.0, 0.49).unwrap();
    let region = Aabb {
        min: Point3::new(-1.0, -1.0, -1.0),
        max: Point3::new(-0.05, 1.0, -0.02),
    };
    let held = PenaltySprings::fixed_surface_region(&grid, &surface, &region, 1e3 * 4500.0 / cell)
        .unwrap()
        .unwrap();
    let mut p = StaticProblem::new(grid, m, VolumetricIntegration::Reduced);
    p.springs = vec![held];
    p
}

fn bench_newton_iteration(c: &mut Criterion) {
    let mut group = c.benchmark_group("newton_iteration");
    group.sample_size(10);
    // ~1,000 and ~10,000 nodes.
    for cell in [0.0155, 0.0062] {
        let mut p = problem(cell, 4, IntegrationMode::WeightedCell);
        let nodes = p.grid.node_count();
        let n = p.dofs();
        // The rest state: a symmetric positive definite tangent, as near every equilibrium.
        let u = vec![0.0; n];
        let mut r = vec![0.0; n];
        let mut k = p.new_tangent();
        let mut solver =
            SparseSolver::new(SolverKind::Auto).with_node_coordinates(p.grid.node_coords.clone());
        let mut du = vec![0.0; n];
        p.evaluate(&u, 1.0, Need::Tangent, Some(&mut r), Some(&mut k))
            .unwrap();
        solver.factorize(&k).unwrap();
        eprintln!(
            "{nodes} nodes: {} dofs, {} cells, method {:?}, ordering {:?}, factor entries {}",
            n,
            p.grid.cells.len(),
            solver.factorized_method(),
            solver.fill_reducing_ordering(),
            solver.factor_nnz()
        );
        group.bench_function(BenchmarkId::new("assembly", nodes), |b| {
            b.iter(|| {
                p.evaluate(&u, 1.0, Need::Tangent, Some(&mut r), Some(&mut k))
                    .unwrap()
            })
        });
        group.bench_function(BenchmarkId::new("factorize", nodes), |b| {
            b.iter(|| solver.factorize(&k).unwrap())
        });
        // A non-zero right-hand side (the residual at rest is zero).
        let rhs: Vec<f64> = (0..n).map(|i| ((i as f64) * 0.37).sin()).collect();
        group.bench_function(BenchmarkId::new("solve", nodes), |b| {
            b.iter(|| solver.solve(&k, &rhs, &mut du).unwrap())
        });
        group.bench_function(BenchmarkId::new("full_iteration", nodes), |b| {
            b.iter(|| {
                p.evaluate(&u, 1.0, Need::Tangent, Some(&mut r), Some(&mut k))
                    .unwrap();
                solver.factorize(&k).unwrap();
                solver.solve(&k, &rhs, &mut du).unwrap();
            })
        });
    }
    group.finish();
}

fn bench_assembly_by_mode(c: &mut Criterion) {
    let mut group = c.benchmark_group("tangent_assembly");
    group.sample_size(10);
    for (mode, levels) in [
        (IntegrationMode::WeightedCell, 0),
        (IntegrationMode::WeightedCell, 4),
        (IntegrationMode::FiniteCell, 4),
    ] {
        let mut p = problem(0.0155, levels, mode);
        let n = p.dofs();
        let u = vec![0.0; n];
        let mut r = vec![0.0; n];
        let mut k = p.new_tangent();
        let label = format!(
            "{}-L{levels}-{}qp",
            mode.name(),
            p.grid.quadrature.total_points()
        );
        group.bench_function(label, |b| {
            b.iter(|| {
                p.evaluate(&u, 1.0, Need::Tangent, Some(&mut r), Some(&mut k))
                    .unwrap()
            })
        });
    }
    group.finish();
}

/// The residual (energy and internal force) at a strained state on ~1,000 nodes: the
/// small-strain linear law multiplies its kept stiffness, the neo-Hookean law evaluates every
/// integration point.
fn bench_residual_by_law(c: &mut Criterion) {
    let mut group = c.benchmark_group("residual");
    group.sample_size(10);
    for law in [LawKind::Linear, LawKind::NeoHookean] {
        let mut p = problem(0.0155, 4, IntegrationMode::WeightedCell);
        p.material = Material::from_young_poisson(law, 4500.0, 0.49).unwrap();
        let n = p.dofs();
        // Two states taken in turn: the problem keeps the cells' force of the last state.
        let states: Vec<Vec<f64>> = [0.37, 0.53]
            .iter()
            .map(|f| (0..n).map(|i| 1e-3 * ((i as f64) * f).sin()).collect())
            .collect();
        let mut r = vec![0.0; n];
        // The first evaluation assembles the linear body's kept stiffness.
        p.evaluate(&states[0], 1.0, Need::Force, Some(&mut r), None)
            .unwrap();
        let mut turn = 0;
        group.bench_function(format!("{law:?}"), |b| {
            b.iter(|| {
                turn = 1 - turn;
                p.evaluate(&states[turn], 1.0, Need::Force, Some(&mut r), None)
                    .unwrap()
            })
        });
    }
    group.finish();
}

fn bench_grid_build(c: &mut Criterion) {
    let mut group = c.benchmark_group("grid_build");
    group.sample_size(10);
    // A 20,480-triangle surface, 4 levels.
    let s = liver_like();
    assert_eq!(s.triangles.len(), 20_480);
    for cell in [0.0155, 0.0071] {
        let opts = GridOptions {
            cell_size: cell,
            subdivisions: 4,
            ..GridOptions::default()
        };
        group.bench_function(format!("20k-triangles-L4-h{cell}"), |b| {
            b.iter(|| WeightedCellGrid::build(&s, &opts).unwrap())
        });
    }
    group.finish();
}

criterion_group!(
    benches,
    bench_newton_iteration,
    bench_assembly_by_mode,
    bench_residual_by_law,
    bench_grid_build
);
criterion_main!(benches);
