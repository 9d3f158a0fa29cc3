//! Registration of the pre-operative liver model to intra-operative point clouds.
//!
//! This module holds the RIGID stage (thesis alg. 2): [`RigidTransform`] (a proper rigid motion,
//! metres and radians), [`kabsch()`] (weighted least-squares rigid fit of paired points),
//! [`ModelTarget`] (the model surface densely sampled into a k-d tree, built once per model and
//! reused across frames) and [`RigidIcp`] (iterative closest point aligning a cloud to the
//! model, with the thesis's outlier rule and optional trimming; point-to-plane updates by
//! default, Kabsch point-to-point selectable via [`IcpMetric`]).
//!
//! Beyond the rigid stage, everything is offered here at the module's front: the biomechanical
//! non-rigid ICP ([`NonRigidIcp`], [`register_non_rigid`], [`NonRigidSettings`], [`DataTerm`]),
//! correspondences ([`IndexedPoints`], [`PairingRule`], [`pair_cloud_to_surface`]), the
//! contact force ([`ContactForce`], [`RestCompliance`]) and its refit ([`refit_at_contact`]),
//! pose search and uncertainty ([`PoseSearch`], [`PoseCovariance`]), the change test
//! ([`ChangeTest`]), the expected error ([`expected_error`]), and the rules and constants their
//! documentation cites.
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

pub(crate) mod change_evidence;
pub(crate) mod coarse_to_fine;
pub(crate) mod contact_force;
pub(crate) mod contact_refit;
pub(crate) mod correspondences;
pub(crate) mod error_estimate;
pub(crate) mod isolated_points;
pub(crate) mod kabsch;
pub(crate) mod linear_held_body;
pub(crate) mod model_target;
pub(crate) mod non_rigid_icp;
pub(crate) mod pose_covariance;
pub(crate) mod pose_search;
pub(crate) mod pose_share;
pub(crate) mod rigid_icp;
pub(crate) mod rigid_transform;
pub(crate) mod surface_anchors;
pub(crate) mod surface_distances;
pub(crate) mod surface_normals;

#[cfg(test)]
mod test_support;
#[cfg(test)]
mod tests;

pub use change_evidence::{
    cloud_noise_sigma, cloud_noise_sigma_near, ChangeEvidence, ChangeTest, NOISE_NEIGHBOURS,
};
pub use coarse_to_fine::Prolongation;
pub use contact_force::{ContactForce, FittedLoad, RestCompliance, MIN_FIT_POINTS};
pub use contact_refit::{
    refit_at_contact, ContactRefit, ContactRefitSettings, RefitInput, RefitSkip,
};
pub use correspondences::{
    rejection_threshold, robust_threshold, Correspondences, IndexedPoints, PairingRule,
};
pub use error_estimate::{
    expected_error, ErrorEstimate, ErrorEvidence, NOISE_IMPRINT, UNSEEN_SHARE,
    UNSEEN_SHARE_EXPLAINED,
};
pub use isolated_points::{isolated_mask, neighbour_spacing};
pub use kabsch::{kabsch, DEGENERACY_RATIO};
pub use linear_held_body::{HeldColumns, LinearHeldBody};
pub use model_target::{ModelTarget, MAX_SAMPLES};
pub use non_rigid_icp::{
    noise_weight, register_non_rigid, DataTerm, NonRigidError, NonRigidIcp, NonRigidReport,
    NonRigidSettings, NonRigidTimings, NormalScale, LOCAL_MOTION_FACTOR, MIN_NOISE_WEIGHT,
    PENALTY_END_PER_EH, PENALTY_START_PER_EH, REFERENCE_NOISE, RELAX_NEWTON_ITERATIONS,
};
pub use pose_covariance::PoseCovariance;
pub use pose_search::{trimmed_score, truncated_score, PoseSearch, PoseSearchResult};
pub use pose_share::rigid_share_of_deformation;
pub use rigid_icp::{IcpError, IcpMetric, IcpResult, RigidIcp};
pub use rigid_transform::{RigidTransform, ROTATION_TOLERANCE};
pub use surface_anchors::{
    incident_triangles, pair_cloud_to_surface, AnchoredPairs, SurfaceAnchor,
};
pub use surface_distances::{SurfaceDistances, SurfaceTopology};
pub use surface_normals::{
    NormalsAtScale, BYTES_PER_REACH, BYTES_PER_SAMPLE, RADIUS_PER_VOLUME_ROOT,
};
