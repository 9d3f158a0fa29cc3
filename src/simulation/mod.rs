//! From a scene file to a solved model: building the SI model and running `simulate`.

pub mod model;
pub mod simulate;

pub use model::{EmbeddedStructure, ModelError, SceneModel};
pub use simulate::{simulate_scene, SimulateError};
