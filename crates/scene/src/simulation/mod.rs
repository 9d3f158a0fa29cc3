//! From a scene file to a solved model: building the SI model, mapping the scene onto the
//! registration's model, sessions and settings, and running `simulate`.

pub(crate) mod from_scene;
pub(crate) mod model;
pub(crate) mod point_hold;
pub(crate) mod simulate;

pub use from_scene::{session_settings, FromScene};
pub use livereg_registration::{DEFAULT_FIXED_PENALTY_FACTOR, DEFAULT_POINT_HOLD_FACTOR};
pub use model::{build_model, EmbeddedStructure, Model, ModelError, SceneModel};
pub use point_hold::{area_per_point, point_hold_stiffness, AREA_NEIGHBOURS};
pub use simulate::{simulate_scene, SimulateError};
