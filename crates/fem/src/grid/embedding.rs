//! Embedding of points in the grid: the sparse mapping H of thesis eq. 4.16.
//!
//! Each embedded point `j` sits in one active cell `e` with reference coordinates `ξ_j`; its
//! position follows the grid as `x_j = Σ_a N_a(ξ_j) x_a` (Hᵀ applied to grid positions), and a
//! force `f_j` at the point spreads onto the cell's nodes as `N_a(ξ_j) f_j` (H applied to point
//! forces, eq. 4.17, 4.19); a spring stiffness `k` at the point adds `k N_a N_b I` to the node
//! block `(a, b)` (eq. 4.21).

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::hex8::shape_values;
use super::weighted_cell_grid::WeightedCellGrid;

/// How far outside every active cell (in cells, measured from the nearest active cell's box)
/// a point may lie and still be embedded by extrapolating that cell's trilinear field.
/// Surface vertices of a rounded surface always fall inside active cells, so anything beyond
/// this is a point that does not belong to the model.
pub const MAX_OUTSIDE_DISTANCE_CELLS: f64 = 0.5;

/// Where one point sits in the grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmbeddedPoint {
    /// Active cell holding the point.
    pub cell: usize,
    /// The cell's 8 active nodes.
    pub nodes: [usize; 8],
    /// Trilinear weights `N_a(ξ)` (sum to 1; may fall outside `[0, 1]` for a point
    /// slightly outside the active cells, where the cell's field is extrapolated).
    pub weights: [f64; 8],
}

/// Errors embedding a point.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EmbeddingError {
    /// The point has a non-finite coordinate.
    #[error("point {index} has a non-finite coordinate")]
    NonFinite {
        /// Index of the point in its list.
        index: usize,
    },
    /// The point is too far from the model's active cells.
    #[error("point {index} at ({x}, {y}, {z}) lies {distance_cells:.2} cells outside the model's grid (at most {MAX_OUTSIDE_DISTANCE_CELLS} allowed)")]
    OutsideModel {
        /// Index of the point in its list.
        index: usize,
        /// x coordinate.
        x: f64,
        /// y coordinate.
        y: f64,
        /// z coordinate.
        z: f64,
        /// Distance to the nearest active cell, in cells.
        distance_cells: f64,
    },
}

/// A set of points embedded in a grid: the rows of H for these points.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Embedding {
    /// One entry per point, in the order given.
    pub points: Vec<EmbeddedPoint>,
    /// Rest positions of the points.
    pub rest: Vec<Point3<f64>>,
}

impl Embedding {
    /// Embeds `points` (rest positions, grid units) in `grid`. A point outside every active cell
    /// but within [`MAX_OUTSIDE_DISTANCE_CELLS`] of one is embedded in the nearest active cell
    /// by extrapolating its trilinear field; farther points are an error naming the point.
    pub fn new(grid: &WeightedCellGrid, points: &[Point3<f64>]) -> Result<Self, EmbeddingError> {
        // Each point is located on its own (in parallel); the first failure in order is reported.
        let embedded: Vec<Result<EmbeddedPoint, EmbeddingError>> = points
            .par_iter()
            .enumerate()
            .map(|(index, p)| embed_point(grid, p, index))
            .collect();
        let out = embedded.into_iter().collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            points: out,
            rest: points.to_vec(),
        })
    }

    /// Embeds those of `points` (rest positions, grid units) that [`Embedding::new`] accepts
    /// and returns them with the indices of the points kept, in order; the others are skipped.
    pub fn new_where_possible(
        grid: &WeightedCellGrid,
        points: &[Point3<f64>],
    ) -> (Self, Vec<usize>) {
        let mut out = Self::default();
        let mut kept = Vec::with_capacity(points.len());
        for (index, p) in points.iter().enumerate() {
            if let Ok(e) = embed_point(grid, p, index) {
                out.points.push(e);
                out.rest.push(*p);
                kept.push(index);
            }
        }
        (out, kept)
    }

    /// The embedding of the points numbered `ids` (indices into this one, in that order): the
    /// same rows of H, without locating the points again.
    pub fn select(&self, ids: &[usize]) -> Self {
        Self {
            points: ids.iter().map(|&i| self.points[i]).collect(),
            rest: ids.iter().map(|&i| self.rest[i]).collect(),
        }
    }

    /// Number of embedded points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Displacements of the embedded points from grid node displacements `u` (3 per node):
    /// `u_s = Hᵀ u`.
    pub fn interpolate(&self, u: &[f64]) -> Vec<Vector3<f64>> {
        self.points.iter().map(|e| interpolate_one(e, u)).collect()
    }

    /// Current positions of the embedded points for grid displacements `u`.
    pub fn positions(&self, u: &[f64]) -> Vec<Point3<f64>> {
        self.points
            .iter()
            .zip(&self.rest)
            .map(|(e, x)| x + interpolate_one(e, u))
            .collect()
    }

    /// Adds the grid forces `H f` of point forces `f` (one per point) to `grid_forces`
    /// (3 per node).
    pub fn spread_forces(&self, f: &[Vector3<f64>], grid_forces: &mut [f64]) {
        for (e, fj) in self.points.iter().zip(f) {
            for (n, w) in e.nodes.iter().zip(e.weights) {
                for d in 0..3 {
                    grid_forces[3 * n + d] += w * fj[d];
                }
            }
        }
    }
}

/// Displacement of one embedded point.
pub(crate) fn interpolate_one(e: &EmbeddedPoint, u: &[f64]) -> Vector3<f64> {
    let mut v = Vector3::zeros();
    for (n, w) in e.nodes.iter().zip(e.weights) {
        v += Vector3::new(u[3 * n], u[3 * n + 1], u[3 * n + 2]) * w;
    }
    v
}

fn embed_point(
    grid: &WeightedCellGrid,
    p: &Point3<f64>,
    index: usize,
) -> Result<EmbeddedPoint, EmbeddingError> {
    if !crate::mesh::is_finite_point(p) {
        return Err(EmbeddingError::NonFinite { index });
    }
    let g = &grid.grid;
    let f = g.fractional_cell(p);
    // Candidate cells: the containing cell (clamped into the grid) and its neighbours.
    let base: [i64; 3] = [0, 1, 2].map(|d| (f[d].floor() as i64).clamp(0, g.dims[d] as i64 - 1));
    if let Some(c) = g.locate(p).and_then(|c| grid.active_cell_at(c)) {
        return Ok(make(grid, c, p));
    }
    let mut best: Option<(f64, usize)> = None;
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let c = [base[0] + dx, base[1] + dy, base[2] + dz];
                if (0..3).any(|d| c[d] < 0 || c[d] >= g.dims[d] as i64) {
                    continue;
                }
                let c = c.map(|v| v as usize);
                if let Some(a) = grid.active_cell_at(c) {
                    // Distance (in cells) from p to the cell's box.
                    let d2: f64 = (0..3)
                        .map(|d| {
                            let lo = c[d] as f64;
                            let excess = (lo - f[d]).max(f[d] - (lo + 1.0)).max(0.0);
                            excess * excess
                        })
                        .sum();
                    if best.is_none_or(|(b, _)| d2 < b) {
                        best = Some((d2, a));
                    }
                }
            }
        }
    }
    match best {
        Some((d2, a)) if d2.sqrt() <= MAX_OUTSIDE_DISTANCE_CELLS => Ok(make(grid, a, p)),
        other => Err(EmbeddingError::OutsideModel {
            index,
            x: p.x,
            y: p.y,
            z: p.z,
            distance_cells: other.map_or(f64::INFINITY, |(d2, _)| d2.sqrt()),
        }),
    }
}

fn make(grid: &WeightedCellGrid, cell: usize, p: &Point3<f64>) -> EmbeddedPoint {
    let c = &grid.cells[cell];
    let xi = grid.grid.to_reference(c.coords, p);
    EmbeddedPoint {
        cell,
        nodes: c.nodes,
        weights: shape_values(&xi),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mechanics::test_fixtures::cut_box;

    /// Selecting points of an embedding gives what embedding those points afresh gives.
    #[test]
    fn a_selection_is_the_embedding_of_the_selected_points() {
        let (surface, problem) = cut_box(0.05);
        let all = Embedding::new(&problem.grid, &surface.vertices).unwrap();
        let ids = [7, 2, 2, surface.vertices.len() - 1];
        let chosen: Vec<Point3<f64>> = ids.iter().map(|&i| surface.vertices[i]).collect();
        assert_eq!(
            all.select(&ids),
            Embedding::new(&problem.grid, &chosen).unwrap()
        );
    }
}
