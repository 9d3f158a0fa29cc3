//! Integration rules on active cells: weighted-cell, finite-cell and full-cell (thesis §4.4–4.5).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// How cut cells (cells the surface passes through) are integrated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum IntegrationMode {
    /// The 8 Gauss points of the cell, the weight of point `I` scaled by the inside volume
    /// fraction of its first-level sub-cell (thesis eq. 4.12–4.13). Same cost as a full cell.
    #[default]
    WeightedCell,
    /// The Gauss points of the inside leaf sub-cells of the octree (thesis eq. 4.6–4.8).
    FiniteCell,
    /// Cut cells are integrated as if they were entirely inside ("sparse grid", level 0).
    FullCell,
}

impl IntegrationMode {
    /// The scene-file name of the mode.
    pub fn name(self) -> &'static str {
        match self {
            IntegrationMode::WeightedCell => "weighted-cell",
            IntegrationMode::FiniteCell => "finite-cell",
            IntegrationMode::FullCell => "full-cell",
        }
    }
}

/// One integration point of a cell: reference coordinates `xi ∈ [-1, 1]³` and the weight that
/// multiplies the integrand, which already includes the Jacobian: a volume (length³).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuadPoint {
    /// Reference coordinates in the cell.
    pub xi: Vector3<f64>,
    /// Integration weight, length³ (Gauss weight × det J × inside fraction).
    pub weight: f64,
}

/// Integration points of every active cell, stored contiguously (`offsets[c]..offsets[c+1]`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CellQuadratures {
    /// Start of each cell's points in `points`; `len = cells + 1`.
    pub offsets: Vec<usize>,
    /// All integration points.
    pub points: Vec<QuadPoint>,
}

impl CellQuadratures {
    /// The integration points of cell `c`.
    pub fn cell(&self, c: usize) -> &[QuadPoint] {
        &self.points[self.offsets[c]..self.offsets[c + 1]]
    }

    /// Number of cells described.
    pub fn cells(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Total number of integration points (the cost driver of every tangent assembly).
    pub fn total_points(&self) -> usize {
        self.points.len()
    }

    /// Sum of the weights of cell `c`: the volume it integrates, length³.
    pub fn cell_volume(&self, c: usize) -> f64 {
        self.cell(c).iter().map(|q| q.weight).sum()
    }
}
