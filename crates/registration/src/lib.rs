//! livereg-registration: a liver model registered to intra-operative point clouds.
//!
//! What it offers:
//! - [`Model`]: what registration reads of a liver (the surface, its embedding in the immersed
//!   grid, the static problem, the holds, the [`EmbeddedStructure`]s), in SI units, with its
//!   [`ModelError`] and the [`DEFAULT_FIXED_PENALTY_FACTOR`] and [`DEFAULT_POINT_HOLD_FACTOR`]
//!   of its holds;
//! - [`registration`]: rigid ICP, correspondences, the biomechanical non-rigid ICP, the
//!   contact force and its refit, pose search and uncertainty, the change test;
//! - [`session`]: a [`Session`](session::Session) registering a stream of
//!   [`Frame`](session::Frame)s to one model (warm start, time budget, recovery), with its
//!   [`SessionSettings`](session::SessionSettings) and the settings' choices
//!   ([`DataTerm`](registration::DataTerm), [`PoseUpdate`](session::PoseUpdate),
//!   [`RigidMode`](session::RigidMode)).
//!
//! It stands on `livereg-fem` (surfaces, grid, mechanics) and knows no file format above the
//! surfaces: scene files map onto its settings and model from the crate above (`livereg-scene`).
//! Lengths are metres inside.
//!
//! # A session on a model
//!
//! ```
//! use livereg_fem::grid::Embedding;
//! use livereg_fem::mechanics::test_fixtures::cut_box;
//! use livereg_fem::mechanics::NewtonSettings;
//! use livereg_registration::session::{Frame, Session, SessionSettings};
//! use livereg_registration::Model;
//!
//! // A 10 × 5 × 6 cm box on 2 cm cells (metres), with no holds.
//! let (surface, problem) = cut_box(0.046);
//! let model = Model {
//!     length_scale: 1.0,
//!     surface_embedding: Embedding::new(&problem.grid, &surface.vertices).unwrap(),
//!     probes: Embedding::new(&problem.grid, &[]).unwrap(),
//!     surface: surface.clone(),
//!     problem,
//!     newton: NewtonSettings::default(),
//!     structures: Vec::new(),
//! };
//! // Rigid registration only: the model keeps its rest shape.
//! let settings = SessionSettings {
//!     non_rigid: false,
//!     ..SessionSettings::default()
//! };
//! let mut session = Session::new(model, settings, None);
//! // A frame: the box's own vertices, where the model is.
//! let frame = Frame {
//!     source: "frame-0".into(),
//!     points: surface.vertices.clone(),
//!     camera: None,
//! };
//! let result = session.register(&frame);
//! assert!(result.error.is_none(), "{:?}", result.error);
//! ```
#![warn(missing_docs)]
// The public API is what the crate root and its public modules offer: an item is `pub` only
// when a user of the crate can reach it, and every type a public item shows can be named.
#![warn(unnameable_types, unreachable_pub)]

// The numerics below: their modules keep the paths the registration code names them by.
#[cfg(test)]
use livereg_fem::random;
use livereg_fem::{geometry, grid, linalg, mechanics, mesh};

mod model;
pub mod registration;
pub mod session;

pub use model::{
    EmbeddedStructure, Model, ModelError, DEFAULT_FIXED_PENALTY_FACTOR, DEFAULT_POINT_HOLD_FACTOR,
};
