//! Coarse-to-fine start (thesis §5.5's proposed remedy for large deformations): the first
//! frame is registered on a coarser grid, whose displacement field, prolongated to the fine
//! grid's nodes, is the fine registration's starting state.

use crate::grid::{Embedding, EmbeddingError, WeightedCellGrid};

/// Trilinear prolongation of a coarse grid's nodal displacements to a fine grid's nodes:
/// each fine node is embedded in the coarse grid (the rows of the coarse H at the fine
/// nodes), so a displacement field the coarse grid represents exactly (any trilinear, hence
/// any affine, field) is carried over exactly.
#[derive(Debug, Clone)]
pub struct Prolongation {
    fine_nodes: Embedding,
}

impl Prolongation {
    /// The prolongation from `coarse` to `fine` (same physical frame, metres). Fails when a
    /// fine node lies farther than half a coarse cell outside the coarse grid's active cells
    /// (the two grids do not cover the same body).
    pub fn new(coarse: &WeightedCellGrid, fine: &WeightedCellGrid) -> Result<Self, EmbeddingError> {
        Ok(Self {
            fine_nodes: Embedding::new(coarse, &fine.node_positions())?,
        })
    }

    /// Fine nodal displacements (3 per fine node, m) from coarse ones (3 per coarse node, m).
    pub fn apply(&self, coarse_u: &[f64]) -> Vec<f64> {
        self.fine_nodes
            .interpolate(coarse_u)
            .iter()
            .flat_map(|d| [d.x, d.y, d.z])
            .collect()
    }

    /// Number of fine nodes.
    pub fn fine_nodes(&self) -> usize {
        self.fine_nodes.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridOptions;
    use crate::mesh::primitives;
    use nalgebra::{Matrix3, Point3, Vector3};

    fn grid(surface: &crate::mesh::TriSurface, h: f64) -> WeightedCellGrid {
        let options = GridOptions {
            cell_size: h,
            ..GridOptions::default()
        };
        WeightedCellGrid::build(surface, &options).unwrap()
    }

    #[test]
    fn an_affine_field_is_carried_over_exactly() {
        let surface = primitives::icosphere(Point3::origin(), 0.05, 3);
        let coarse = grid(&surface, 0.02);
        let fine = grid(&surface, 0.01);
        let p = Prolongation::new(&coarse, &fine).unwrap();
        assert_eq!(p.fine_nodes(), fine.node_count());
        let a = Matrix3::new(0.01, -0.02, 0.005, 0.03, 0.0, -0.01, 0.002, 0.004, -0.02);
        let b = Vector3::new(0.001, -0.002, 0.003);
        let field = |x: &Point3<f64>| a * x.coords + b;
        let coarse_u: Vec<f64> = coarse
            .node_positions()
            .iter()
            .flat_map(|x| {
                let d = field(x);
                [d.x, d.y, d.z]
            })
            .collect();
        let fine_u = p.apply(&coarse_u);
        for (n, x) in fine.node_positions().iter().enumerate() {
            let d = field(x);
            for k in 0..3 {
                assert!(
                    (fine_u[3 * n + k] - d[k]).abs() < 1e-12,
                    "node {n}: {} vs {}",
                    fine_u[3 * n + k],
                    d[k]
                );
            }
        }
    }
}
