//! livereg: biomechanical registration of a deforming liver for surgical augmented reality.
//!
//! The modules follow the data's path:
//! - [`stored_scalar`]: numbers as binary files store them (the readers' shared decoding);
//! - [`mesh`]: triangle surfaces and point files (reading, validation, primitives);
//! - [`geometry`]: boxes, triangle–box overlap, inside/outside tests;
//! - [`grid`]: the immersed weighted-cell grid, its quadrature and the embedding H;
//! - [`linalg`]: sparse symmetric matrices and linear solvers;
//! - [`mechanics`]: materials, the hexahedral cell, assembly, loads, penalties, Newton;
//! - [`scene`]: the scene file; [`simulation`]: a scene turned into a solved model, and the
//!   scene mapped onto the registration's model, sessions and settings ([`simulation::FromScene`]);
//! - [`scenarios`]: reference problems from the source texts (tests, benchmarks);
//! - [`registration`]: rigid ICP and the biomechanical non-rigid ICP;
//! - [`session`]: a model registered frame after frame (warm start, time budget, recovery);
//! - [`phantom`]: the bundled liver phantom (surface, vessel targets, tumour, ligament);
//! - [`segmentation`]: NIfTI/NRRD labelmaps turned into surfaces (liver, tumour) and vessel points;
//! - [`synthetic`]: a virtual camera producing partial, noisy point clouds (tests, benchmarks);
//! - [`evaluation`]: results and truth formats, target registration error;
//! - [`benchmark`]: speed against accuracy — configuration sweeps, stability matrix;
//! - [`charts`]: charts (TRE against ms per frame, Pareto front);
//! - [`recording`]: MCAP recordings of sessions and their replay;
//! - `visualisation` (feature `rerun`): 3D logging to rerun;
//! - [`server`]: the registration server (HTTP, WebSocket, gRPC) for AR displays;
//! - [`cli`]: the command line.
//!
//! Most of these modules live in the workspace's crates and are re-exported here under the
//! same names: `stored_scalar`, `mesh`, `geometry`, `grid`, `linalg`, `mechanics` and `random`
//! are `livereg-fem`'s (crates/fem); `registration` and `session` are
//! `livereg-registration`'s (crates/registration); `scene`, `segmentation`, `simulation`,
//! `evaluation` and `recording` are `livereg-scene`'s (crates/scene); `server` and
//! `openigtlink` are `livereg-server`'s (crates/server). This crate itself holds the command
//! line, the bench, the charts, the phantom, the synthetic data and the visualisation. Lower
//! layers never import higher ones; the crates make that a compiler fact. Inside the mechanics
//! everything is SI (m, N, Pa, J).
//!
//! # The core path: scene → model → session → frame → result
//!
//! ```
//! use std::path::Path;
//!
//! use livereg::mesh::read_obj;
//! use livereg::scene::load_scene;
//! use livereg::session::{Frame, Session};
//! use livereg::simulation::FromScene;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/liver_phantom");
//! // The scene file names the liver surface, its internal structures, the material and the
//! // ligament; loading it reads and checks every file it names.
//! let scene = load_scene(&dir.join("scene.toml"))?;
//! // The model: the immersed grid, the hyperelastic problem, the structures' embedding.
//! let mut session = Session::from_scene(&scene)?;
//! // A camera frame: here every fifth vertex of the liver's own rest surface (scene units,
//! // mm), a perfect cloud of a liver that has not moved.
//! let liver = read_obj(&dir.join("liver.obj"))?;
//! let frame = Frame {
//!     source: "frame-0".into(),
//!     points: liver.vertices.iter().step_by(5).copied().collect(),
//!     camera: None,
//! };
//! let result = session.register(&frame);
//! assert!(result.error.is_none(), "{:?}", result.error);
//! // Where every structure is now, in the cloud's frame and scene units: a liver that has not
//! // moved leaves them where they were (the model works in metres inside).
//! let scale = session.model.length_scale;
//! for ((name, now), structure) in result.structures.iter().zip(&session.model.structures) {
//!     for (p, rest) in now.iter().zip(&structure.embedding.rest) {
//!         let moved_mm = (p - rest / scale).norm();
//!         assert!(moved_mm < 0.5, "{name} moved by {moved_mm} mm");
//!     }
//! }
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]

// The numerics below the registration live in the `livereg-fem` crate (crates/fem); their
// modules keep their paths here.
pub use livereg_fem::{geometry, grid, linalg, mechanics, mesh, random, stored_scalar};
// Registration and sessions live in the `livereg-registration` crate (crates/registration);
// their modules keep their paths here. The scene maps onto them in `simulation`.
pub use livereg_registration::{registration, session};
// The scene layer (scene files, segmentation, scene → model and session, result records,
// recordings) lives in the `livereg-scene` crate (crates/scene).
pub use livereg_scene::{evaluation, recording, scene, segmentation, simulation};
// The registration server and the OpenIGTLink codec live in the `livereg-server` crate
// (crates/server).
pub use livereg_server as server;
pub use livereg_server::openigtlink;

pub mod benchmark;
pub mod charts;
pub mod cli;
pub mod phantom;
pub mod scenarios;
#[cfg(test)]
mod session_tests;
pub mod synthetic;
#[cfg(feature = "rerun")]
pub mod visualisation;
