//! livereg-fem: the numerics below livereg's registration, framework-free (no I/O beyond
//! surface files, no server, no session).
//!
//! The modules follow the data's path:
//! - [`stored_scalar`]: numbers as binary files store them (the readers' shared decoding);
//! - [`mesh`]: triangle surfaces and point files (reading, validation, primitives);
//! - [`geometry`]: boxes, triangle–box overlap, inside/outside tests, visibility;
//! - [`grid`]: the immersed weighted-cell grid, its quadrature and the embedding H;
//! - [`linalg`]: sparse symmetric matrices and linear solvers;
//! - [`mechanics`]: materials, the hexahedral cell, assembly, loads, penalties, Newton;
//! - [`random`]: the seeded generator every test and the synthetic data draw from.
//!
//! Each module offers its types and functions at its front (`geometry::InsideTest`,
//! `grid::WeightedCellGrid`, `mechanics::StaticProblem`, `mesh::read_surface`, ...); the
//! submodules that are public are namespaces of their own: [`geometry::shapes`] and
//! [`mesh::primitives`] (simple closed surfaces), [`geometry::visibility`],
//! [`grid::hex8`] (the trilinear cell), [`mechanics::loads`], [`mechanics::material`],
//! [`mesh::vtk`], [`linalg::testing`] (test matrices), and `mechanics::test_fixtures` (small
//! cut-box problems, with the `test-fixtures` feature).
//!
//! Lower modules never import higher ones, and nothing here imports the registration above
//! it (the `livereg` crate, which re-exports these modules under the same names). Inside the
//! mechanics everything is SI (m, N, Pa, J).
//!
//! # The weighted-cell grid, the discretisation everything above stands on
//!
//! A closed surface is immersed in a regular grid of hexahedral cells; each cell the surface
//! cuts carries the share of its volume that lies inside, measured by subdividing it, so the
//! grid's cells together hold the body's volume:
//!
//! ```
//! use livereg_fem::grid::{GridOptions, WeightedCellGrid};
//! use livereg_fem::mesh::primitives::icosphere;
//! use nalgebra::Point3;
//!
//! // A ball of radius 5 cm (metres), in cells of 1 cm.
//! let ball = icosphere(Point3::origin(), 0.05, 3);
//! let options = GridOptions {
//!     cell_size: 0.01,
//!     ..GridOptions::default()
//! };
//! let grid = WeightedCellGrid::build(&ball, &options).expect("a closed surface");
//! let stats = grid.stats();
//! let volume = ball.signed_volume();
//! assert!(stats.cut_cells > 0 && stats.cells > stats.cut_cells);
//! let error = (stats.volume - volume).abs() / volume;
//! assert!(error < 1e-3, "{} m³ against {volume} m³", stats.volume);
//! ```
#![warn(missing_docs)]
// The public API is what the crate root and its public modules offer: an item is `pub` only
// when a user of the crate can reach it, and every type a public item shows can be named.
#![warn(unnameable_types, unreachable_pub)]

pub mod geometry;
pub mod grid;
pub mod linalg;
pub mod mechanics;
pub mod mesh;
pub mod random;
pub mod stored_scalar;
