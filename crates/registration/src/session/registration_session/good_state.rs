//! [`GoodState`]: the last state a frame ended in successfully, the one every frame starts
//! from and every result reports.

use nalgebra::Point3;

use super::super::frame::FrameResult;
use crate::model::Model;
use crate::registration::{ContactForce, ErrorEstimate, RigidTransform};

/// The last state a frame ended in successfully: the displacement (m), the pose and what was
/// measured of them. A failed frame leaves it as it was.
#[derive(Debug, Clone)]
pub(super) struct GoodState {
    /// Grid displacements, m.
    pub(super) u: Vec<f64>,
    /// Model → cloud pose.
    pub(super) model_to_cloud: RigidTransform,
    /// Whether a frame has succeeded since the start or the last reset.
    pub(super) registered: bool,
    /// The last good frame's cloud as registered (metres, cloud frame, after thinning): its
    /// centroid and fit are where a lost pose is searched first
    /// ([`PoseTracker::reacquire_pose`](super::pose_tracker::PoseTracker::reacquire_pose)).
    pub(super) cloud: Option<Vec<Point3<f64>>>,
    /// The surface loads the last good frame's registration needed (model frame, SI).
    pub(super) contact_force: Option<ContactForce>,
    /// The pose was committed by a global search that found another pose about as good
    /// (flag `pose_ambiguous`); every frame holding it says so too.
    pub(super) pose_ambiguous: bool,
    /// The pose's uncertainty when it was fitted (m,
    /// [`fitted_pose_uncertainty`](super::pose_tracker::fitted_pose_uncertainty)); `None`
    /// when the pose was given (`rigid = "none"`) or its fit did not determine it.
    pub(super) pose_uncertainty: Option<f64>,
    /// The expected error of the good state (m,
    /// [`FrameSuccess::error_estimate`](super::frame_success::FrameSuccess::error_estimate));
    /// `None` before the first good frame.
    pub(super) expected_error: Option<ErrorEstimate>,
}

impl GoodState {
    /// The state before any frame: displacements `u` (m; the rest shape, zeros), the identity
    /// pose, nothing registered or estimated.
    pub(super) fn at_rest(u: Vec<f64>) -> Self {
        GoodState {
            u,
            model_to_cloud: RigidTransform::identity(),
            registered: false,
            cloud: None,
            contact_force: None,
            pose_ambiguous: false,
            pose_uncertainty: None,
            expected_error: None,
        }
    }

    /// RMS distance (m) between the surface vertices of `model` at displacement `u` and at
    /// this state's.
    pub(super) fn surface_change_rms(&self, model: &Model, u: &[f64]) -> f64 {
        let now = model.surface_embedding.positions(u);
        let last = model.surface_embedding.positions(&self.u);
        let sum: f64 = now
            .iter()
            .zip(&last)
            .map(|(p, q)| (p - q).norm_squared())
            .sum();
        (sum / now.len().max(1) as f64).sqrt()
    }

    /// This state's surface, structures and contact force on `model` into `result`, in the
    /// cloud frame and scene units.
    pub(super) fn write_positions(&self, model: &Model, result: &mut FrameResult) {
        let scale = model.length_scale;
        let pose = self.model_to_cloud;
        let out = |p: &Point3<f64>| pose.apply(p) / scale;
        result.surface = model
            .surface_embedding
            .positions(&self.u)
            .iter()
            .map(out)
            .collect();
        result.structures = model
            .structures
            .iter()
            .map(|s| {
                (
                    s.name.clone(),
                    s.embedding.positions(&self.u).iter().map(out).collect(),
                )
            })
            .collect();
        result.contact_force = self.contact_force.map(|c| ContactForce {
            resultant: pose.apply_vector(&c.resultant),
            centre: out(&c.centre),
            expected_error: c.expected_error,
        });
    }
}
