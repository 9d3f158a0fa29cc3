//! livereg-scene: the scene layer, between the registration and the services.
//!
//! What it offers:
//! - [`scene`]: the scene file (TOML or JSON): [`scene::load_scene`] reads it, checks every
//!   key and file it names, and gives a [`scene::LoadedScene`];
//! - [`segmentation`]: NIfTI/NRRD labelmaps turned into surfaces (liver, tumour) and vessel
//!   points, for scenes whose model is derived from a labelmap;
//! - [`simulation`]: a scene turned into the registration's [`Model`](simulation::Model), its
//!   [`Session`](livereg_registration::session::Session)s and their settings
//!   ([`simulation::FromScene`], [`simulation::session_settings`]), and `simulate`;
//! - [`evaluation`]: results and truth formats, target registration error;
//! - [`recording`]: MCAP recordings of sessions and their replay, and the retention of a
//!   directory of them ([`recording::retention`]).
//!
//! It stands on `livereg-fem` and `livereg-registration`, and holds no service (no async
//! runtime, HTTP or gRPC) and no charts: the server's crate and the command line stand on it.
//!
//! # A scene's session
//!
//! ```
//! use std::path::Path;
//!
//! use livereg_registration::session::Session;
//! use livereg_scene::scene::load_scene;
//! use livereg_scene::simulation::FromScene;
//!
//! let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/liver_phantom");
//! let scene = load_scene(&dir.join("scene.toml")).unwrap();
//! let session = Session::from_scene(&scene).unwrap();
//! assert_eq!(session.model.structures.len(), scene.scene.model.structures.len());
//! ```
#![warn(missing_docs)]
// The public API is what the crate root and its public modules offer: an item is `pub` only
// when a user of the crate can reach it, and every type a public item shows can be named.
#![warn(unnameable_types, unreachable_pub)]

// The layers below: their modules keep the paths this crate's code names them by.
use livereg_fem::{geometry, grid, linalg, mechanics, mesh, stored_scalar};
use livereg_registration::{registration, session};

pub mod evaluation;
pub mod recording;
pub mod scene;
pub mod segmentation;
pub mod simulation;
