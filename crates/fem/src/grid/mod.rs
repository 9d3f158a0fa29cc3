//! The immersed grid: background cells, active cells and their quadrature, and the embedding of
//! points (thesis ch. 4).

pub mod embedding;
pub mod hex8;
pub mod quadrature;
pub mod regular_grid;
pub mod weighted_cell_grid;

pub use embedding::{EmbeddedPoint, Embedding, EmbeddingError};
pub use quadrature::{CellQuadratures, IntegrationMode, QuadPoint};
pub use regular_grid::RegularGrid;
pub use weighted_cell_grid::{ActiveCell, GridError, GridOptions, GridStats, WeightedCellGrid};
