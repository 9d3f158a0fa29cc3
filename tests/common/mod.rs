//! Helpers shared by the whole-flow tests.
#![allow(dead_code)]

pub mod labelmaps;

use livereg::geometry::Aabb;
use livereg::grid::{GridOptions, IntegrationMode, WeightedCellGrid};
use livereg::linalg::SymmetricCsc;
use livereg::mechanics::{LawKind, Material, PenaltySprings, StaticProblem, VolumetricIntegration};
use livereg::mesh::TriSurface;
use livereg::session::FrameResult;
use nalgebra::{DMatrix, Point3};

/// Every law.
pub const LAWS: [LawKind; 5] = LawKind::ALL;

/// Grid options with the given cell size, levels and mode (α = 1e-4, no offset).
pub fn options(cell_size: f64, subdivisions: u32, mode: IntegrationMode) -> GridOptions {
    GridOptions {
        cell_size,
        subdivisions,
        mode,
        min_fraction: 1e-4,
        origin_offset: [0.0; 3],
    }
}

/// A problem on `surface` with the given grid options and material.
pub fn problem(
    surface: &TriSurface,
    opts: &GridOptions,
    material: Material,
    vol: VolumetricIntegration,
) -> StaticProblem {
    let grid = WeightedCellGrid::build(surface, opts).expect("grid builds");
    StaticProblem::new(grid, material, vol)
}

/// Material from E (Pa) and ν.
pub fn material(law: LawKind, young: f64, poisson: f64) -> Material {
    Material::from_young_poisson(law, young, poisson).expect("valid material")
}

/// Springs holding the part of the surface inside `region`, density κE/h.
pub fn hold(
    problem: &StaticProblem,
    surface: &TriSurface,
    region: Aabb,
    kappa: f64,
    young: f64,
) -> PenaltySprings {
    let h = problem.grid.grid.cell_size;
    PenaltySprings::fixed_surface_region(&problem.grid, surface, &region, kappa * young / h)
        .expect("embeds")
        .expect("region holds part of the surface")
}

/// Axis-aligned box from two corners.
pub fn aabb(min: [f64; 3], max: [f64; 3]) -> Aabb {
    Aabb {
        min: Point3::from(min),
        max: Point3::from(max),
    }
}

/// The full symmetric dense matrix of a lower-triangle CSC matrix.
pub fn dense(k: &SymmetricCsc) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(k.n, k.n);
    for c in 0..k.n {
        for p in k.col_ptr[c]..k.col_ptr[c + 1] {
            let r = k.row_idx[p];
            m[(r, c)] = k.values[p];
            m[(c, r)] = k.values[p];
        }
    }
    m
}

/// Deterministic pseudo-random numbers in [-1, 1) (xorshift).
pub struct Rng(pub u64);

impl Rng {
    /// Next number in [-1, 1).
    pub fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }

    /// A vector of `n` numbers scaled by `s`.
    pub fn vec(&mut self, n: usize, s: f64) -> Vec<f64> {
        (0..n).map(|_| s * self.next()).collect()
    }
}

/// Runs the `livereg` binary built for this test run with `args`; returns the exit code (−1
/// when killed by a signal), stdout and stderr.
pub fn livereg(args: &[&str]) -> (i32, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_livereg"))
        .args(args)
        .output()
        .expect("binary runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Target registration error of one frame: the mean distance, in scene units, of the frame
/// result's registered structure points (scene units, cloud frame) to the truth structures
/// (`(name, points)` in metres, same order; `scale` metres per scene unit). Panics if the
/// structures do not match by name.
pub fn frame_tre(r: &FrameResult, truth: &[(String, Vec<Point3<f64>>)], scale: f64) -> f64 {
    let (mut sum, mut n) = (0.0, 0);
    for ((name, p), (truth_name, t)) in r.structures.iter().zip(truth) {
        assert_eq!(name, truth_name, "structures in a different order");
        for (x, y) in p.iter().zip(t) {
            sum += (x - y / scale).norm();
            n += 1;
        }
    }
    sum / n as f64
}
