//! Synthetic camera for tests and benchmarks: turns a (deformed) closed triangle surface, in
//! metres, into the partial, noisy point cloud an intra-operative depth camera would capture.
//!
//! * [`Camera`]: position, target, up hint and circular field-of-view cone.
//! * [`VisibleSurface`]: ray-cast line-of-sight visibility of points (or of the surface's own
//!   vertices, the registration source points) from a camera.
//! * [`synthesize_cloud`] with a [`CloudSpec`]: area-uniform sampling, visibility, optional
//!   patch restriction, Gaussian noise, uniform outliers and a rigid offset, deterministic
//!   for a seed ([`Rng`]).
//!
//! ```
//! use livereg::mesh::primitives::icosphere;
//! use livereg::synthetic::{synthesize_cloud, Camera, CloudSpec};
//! use nalgebra::Point3;
//!
//! let liver = icosphere(Point3::origin(), 0.08, 3);
//! let camera = Camera::looking_at(Point3::new(0.0, -0.3, 0.0), Point3::origin()).unwrap();
//! let spec = CloudSpec { density_per_cm2: 2.0, noise_sigma: 0.5e-3, seed: 1, ..Default::default() };
//! let cloud = synthesize_cloud(&liver, &camera, &spec).unwrap();
//! assert!(cloud.visible_area < 0.5 * cloud.surface_area);
//! ```

pub mod error;
pub mod indentation;
pub mod point_cloud;
pub mod sequence;

#[cfg(test)]
mod tests;

/// The camera and the visibility test live in [`crate::geometry`] (registration uses them too).
pub use crate::geometry::{Camera, VisibleSurface, DEFAULT_FOV_DEG};
pub use crate::random::Rng;
pub use error::SynthError;
pub use point_cloud::{synthesize_cloud, CloudSpec, SyntheticCloud, MAX_SAMPLES, OUTLIER_MARGIN};
pub use sequence::{
    frame_seed, generate_sequence, load_fraction, solve_truth, write_sequence, ScenarioKind,
    ScenarioLoad, SequenceError, SequenceSpec, SolvedTruth, SyntheticFrame, SyntheticSequence,
    TruthModel,
};
