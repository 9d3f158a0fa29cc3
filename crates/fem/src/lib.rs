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
//! Lower modules never import higher ones, and nothing here imports the registration above
//! it (the `livereg` crate, which re-exports these modules under the same names). Inside the
//! mechanics everything is SI (m, N, Pa, J).
#![warn(missing_docs)]

pub mod geometry;
pub mod grid;
pub mod linalg;
pub mod mechanics;
pub mod mesh;
pub mod random;
pub mod stored_scalar;
