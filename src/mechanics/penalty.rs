//! Penalty springs from embedded points to imposed displacements (thesis eq. 4.18–4.22): fixed
//! regions, and the springs registration pulls the visible surface with.

use nalgebra::{Point3, Vector3};

use super::assembly::Assembler;
use super::loads::sample_surface_in_box;
use crate::geometry::Aabb;
use crate::grid::{embedding::interpolate_one, Embedding, EmbeddingError, WeightedCellGrid};
use crate::linalg::SymmetricCsc;
use crate::mesh::TriSurface;

/// Springs of stiffness `k_j` (N/m) between embedded points and imposed displacements `d_j`
/// (m). Energy `Σ_j ½ k_j |u_j − s d_j|²` with `u_j = Hᵀu` the point's displacement and `s` the
/// load factor when `follows_load` (imposed displacements applied gradually), else 1.
/// The force on the grid is `H S` with `S_j = k_j (u_j − s d_j)` (the printed ‖·‖ of eq. 4.19
/// is a typo) and the stiffness `H (k I) Hᵀ` (eq. 4.21).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PenaltySprings {
    /// Where the points are in the grid.
    pub embedding: Embedding,
    /// Imposed displacement of each point, m.
    pub target: Vec<Vector3<f64>>,
    /// Stiffness of each spring, N/m.
    pub stiffness: Vec<f64>,
    /// Whether the imposed displacements scale with the load factor.
    pub follows_load: bool,
}

impl PenaltySprings {
    /// Springs holding the points of `embedding` at their rest positions.
    pub fn fixed(embedding: Embedding, stiffness: Vec<f64>) -> Self {
        let target = vec![Vector3::zeros(); embedding.len()];
        Self {
            embedding,
            target,
            stiffness,
            follows_load: false,
        }
    }

    /// Springs holding the part of `surface` inside `region` at rest: the region is sampled
    /// at spacing `h/2` (h: cell edge) and a sample of area `A` gets `spring_density · A`
    /// (N/m; `spring_density` in N/m³), so the hold does not depend on the surface's
    /// triangulation. Returns `None` when the box holds no part of the surface.
    pub fn fixed_surface_region(
        grid: &WeightedCellGrid,
        surface: &TriSurface,
        region: &Aabb,
        spring_density: f64,
    ) -> Result<Option<Self>, EmbeddingError> {
        let samples = sample_surface_in_box(surface, region, 0.5 * grid.grid.cell_size);
        if samples.is_empty() {
            return Ok(None);
        }
        let points: Vec<Point3<f64>> = samples.iter().map(|s| s.point).collect();
        let stiffness = samples.iter().map(|s| spring_density * s.area).collect();
        Ok(Some(Self::fixed(Embedding::new(grid, &points)?, stiffness)))
    }

    fn imposed(&self, j: usize, load: f64) -> Vector3<f64> {
        if self.follows_load {
            self.target[j] * load
        } else {
            self.target[j]
        }
    }

    /// Spring energy (J) at grid displacements `u`; adds the grid forces `H S` to `force`
    /// (N) and the stiffness to `tangent` when given.
    pub fn accumulate(
        &self,
        assembler: &Assembler,
        u: &[f64],
        load: f64,
        force: Option<&mut [f64]>,
        tangent: Option<&mut SymmetricCsc>,
    ) -> f64 {
        let mut energy = 0.0;
        let mut force = force;
        for (j, e) in self.embedding.points.iter().enumerate() {
            let k = self.stiffness[j];
            let diff = interpolate_one(e, u) - self.imposed(j, load);
            energy += 0.5 * k * diff.norm_squared();
            if let Some(f) = force.as_deref_mut() {
                for (n, w) in e.nodes.iter().zip(e.weights) {
                    for d in 0..3 {
                        f[3 * n + d] += k * w * diff[d];
                    }
                }
            }
        }
        if let Some(t) = tangent {
            for (j, e) in self.embedding.points.iter().enumerate() {
                let k = self.stiffness[j];
                for a in 0..8 {
                    for b in 0..=a {
                        let v = k * e.weights[a] * e.weights[b];
                        for i in 0..3 {
                            t.values[assembler.cell_slot(e.cell, a, b, i, i)] += v;
                        }
                    }
                }
            }
        }
        energy
    }
}
