//! The scene file: what to simulate and register (contract: "Scene file").
//!
//! A scene is TOML (or the same structure as JSON). [`load_scene`] reads it, rejects unknown
//! keys and bad values with messages naming the file, the key and the value, resolves every
//! path against the scene file's directory and checks the files exist.
//!
//! Units: every length in the scene and in the files it names is in scene units
//! ([`Units`], default metres) and results are written in scene units; material constants,
//! tractions, gravity and spring stiffnesses are SI (Pa, kg/m³, m/s², N/m). See
//! [`LoadedScene::length_scale`]. The full reference is `docs/scene.md`.

pub(crate) mod derived_model;
mod error;
mod load;
mod output;
mod types;
mod validate;

#[cfg(test)]
mod tests;

pub use error::{Problem, SceneError};
pub use load::{load_scene, load_scene_str, parse_scene, LoadedScene, SceneFormat};
pub use output::{GridSummary, ProbeResult, SimulateReport};
pub use types::{
    defaults, BoundarySpec, BoxRegion, Camera, DataTerm, FixedRegion, FixedSpec, GridSpec,
    IntegrationMode, Label, Labels, LawKind, LoadSpec, MaterialSpec, ModelSpec, PointSource,
    PoseUpdate, ProbeSpec, RegistrationSpec, RigidMode, Scene, SolverKind, SolverSpec,
    StructureSpec, SupportSpec, TractionSpec, Units, Vec3, VolumetricIntegration,
};
pub use validate::{
    validate_scene, MAX_BISECTIONS, MAX_LOAD_STEPS, MAX_STEP_STABILIZATION, MAX_SUBDIVISIONS,
    POINT_EXTENSIONS, SURFACE_EXTENSIONS,
};
