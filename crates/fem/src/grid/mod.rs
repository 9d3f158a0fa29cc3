//! The immersed grid: background cells, active cells and their quadrature, and the embedding of
//! points (thesis ch. 4).

pub(crate) mod derived_cell_size;
pub(crate) mod embedding;
pub mod hex8;
pub(crate) mod quadrature;
pub(crate) mod regular_grid;
pub(crate) mod weighted_cell_grid;

pub use derived_cell_size::{derived_cell_size, CELLS_PER_CUBE_ROOT};
pub use embedding::{EmbeddedPoint, Embedding, EmbeddingError, MAX_OUTSIDE_DISTANCE_CELLS};
pub use quadrature::{CellQuadratures, IntegrationMode, QuadPoint};
pub use regular_grid::RegularGrid;
pub use weighted_cell_grid::{ActiveCell, GridError, GridOptions, GridStats, WeightedCellGrid};
