//! Registration of the pre-operative liver model to intra-operative point clouds.
//!
//! This module holds the RIGID stage (thesis alg. 2): [`RigidTransform`] (a proper rigid motion,
//! metres and radians), [`kabsch()`] (weighted least-squares rigid fit of paired points),
//! [`ModelTarget`] (the model surface densely sampled into a k-d tree, built once per model and
//! reused across frames) and [`RigidIcp`] (iterative closest point aligning a cloud to the
//! model, with the thesis's outlier rule and optional trimming; point-to-plane updates by
//! default, Kabsch point-to-point selectable via [`IcpMetric`]).
//!
//! ```
//! use livereg_fem::mesh::primitives::icosphere;
//! use livereg_registration::registration::{ModelTarget, RigidIcp, RigidTransform};
//! use nalgebra::{Point3, Rotation3, Vector3};
//!
//! let mut model = icosphere(Point3::origin(), 1.0, 3);
//! for v in &mut model.vertices {
//!     // a 20 × 15 × 10 cm ellipsoid with a lump, so the fit is unique
//!     *v = Point3::new(0.10 * v.x, 0.075 * v.y, 0.05 * v.z) + 0.02 * v.x.max(0.0).powi(8) * v.coords;
//! }
//! let target = ModelTarget::new(&model, 0.004).unwrap();
//! let truth = RigidTransform::new(
//!     Rotation3::from_axis_angle(&Vector3::z_axis(), 0.1),
//!     Vector3::new(0.01, 0.0, 0.005),
//! );
//! let cloud: Vec<_> = model.vertices.iter().map(|p| truth.apply(p)).collect();
//! let result = RigidIcp::default().register(&target, &cloud, None).unwrap();
//! assert!(result.model_to_cloud.rotation_angle_to(&truth) < 0.01);
//! ```

pub mod change_evidence;
pub mod coarse_to_fine;
pub mod contact_force;
pub mod contact_refit;
pub mod correspondences;
pub mod error_estimate;
pub mod isolated_points;
pub mod kabsch;
pub mod model_target;
pub mod non_rigid_icp;
pub mod pose_covariance;
pub mod pose_search;
pub mod pose_share;
pub mod rigid_icp;
pub mod rigid_transform;
pub mod surface_anchors;
pub mod surface_distances;
pub mod surface_normals;

#[cfg(test)]
mod test_support;
#[cfg(test)]
mod tests;

pub use coarse_to_fine::Prolongation;
pub use contact_force::{ContactForce, RestCompliance};
pub use correspondences::{Correspondences, IndexedPoints, PairingRule};
pub use error_estimate::{expected_error, ErrorEstimate, ErrorEvidence};
pub use kabsch::kabsch;
pub use model_target::ModelTarget;
pub use non_rigid_icp::{
    register_non_rigid, DataTerm, NonRigidError, NonRigidIcp, NonRigidReport, NonRigidSettings,
    NonRigidTimings,
};
pub use pose_covariance::PoseCovariance;
pub use pose_search::{PoseSearch, PoseSearchResult};
pub use rigid_icp::{IcpError, IcpMetric, IcpResult, RigidIcp};
pub use rigid_transform::RigidTransform;
pub use surface_distances::{SurfaceDistances, SurfaceTopology};
