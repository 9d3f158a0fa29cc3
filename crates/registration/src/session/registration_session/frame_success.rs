//! [`FrameSuccess`]: a frame that succeeded, the state it leaves and its counters.

use nalgebra::Point3;

use super::super::still_window::StillWindow;
use crate::model::Model;
use crate::registration::{
    expected_error, ContactForce, ErrorEstimate, ErrorEvidence, RigidTransform, SurfaceDistances,
};

/// A successful frame's new state and counters: what the session commits as its good state
/// and reports in the frame's result.
pub(super) struct FrameSuccess {
    /// Grid displacements, m.
    pub(super) u: Vec<f64>,
    /// Model → cloud pose.
    pub(super) model_to_cloud: RigidTransform,
    /// Whether the non-rigid ICP converged (true without it).
    pub(super) converged: bool,
    /// Rigid ICP iterations.
    pub(super) rigid_iterations: usize,
    /// Non-rigid ICP iterations, the coarse start's and recovery's included.
    pub(super) icp_iterations: usize,
    /// Newton iterations.
    pub(super) newton_iterations: usize,
    /// Factorisations.
    pub(super) factorizations: usize,
    /// RMS distance (m) of the non-rigid ICP's kept source points to the cloud at its last
    /// pairing (without it: the fit RMS).
    pub(super) surface_rms: f64,
    /// Points registered (after thinning and isolated points).
    pub(super) used_points: usize,
    /// The cloud as registered: metres, cloud frame.
    pub(super) cloud: Vec<Point3<f64>>,
    /// Source points the non-rigid ICP used in its last iteration.
    pub(super) sources: usize,
    /// The solver's warnings.
    pub(super) warnings: Vec<String>,
    /// The contact force (model frame, SI), if estimated.
    pub(super) contact_force: Option<ContactForce>,
    /// The still window with this frame's cloud (empty for a frame without the non-rigid
    /// stage): it replaces the session's when the frame succeeds.
    pub(super) still: StillWindow,
    /// The surface index of `u` the frame's fit built (`None` when it built none): the next
    /// frame's good surface ([`ModelSurfaces::keep_good`](super::model_surfaces::ModelSurfaces::keep_good)).
    pub(super) surface: Option<SurfaceDistances>,
    /// RMS distance of the cloud to the registered surface after the outlier rule, m.
    pub(super) fit_rms: f64,
    /// The cloud's measured noise, m (0 when not measured).
    pub(super) noise: f64,
}

impl FrameSuccess {
    /// A frame that ends without the non-rigid stage (rigid only, or kept at rest): the shape
    /// `u` (m), the pose, the rigid iterations, the cloud (m, cloud frame), the fit RMS (m)
    /// and the contact force.
    pub(super) fn without_non_rigid(
        u: Vec<f64>,
        model_to_cloud: RigidTransform,
        rigid_iterations: usize,
        cloud: Vec<Point3<f64>>,
        surface_rms: f64,
        contact_force: Option<ContactForce>,
    ) -> Self {
        FrameSuccess {
            u,
            model_to_cloud,
            converged: true,
            rigid_iterations,
            icp_iterations: 0,
            newton_iterations: 0,
            factorizations: 0,
            surface_rms,
            used_points: cloud.len(),
            cloud,
            sources: 0,
            warnings: Vec::new(),
            contact_force,
            still: StillWindow::default(),
            surface: None,
            fit_rms: surface_rms,
            noise: 0.0,
        }
    }

    /// The expected error of this frame on `model` when its pose has the uncertainty
    /// `pose_uncertainty` (m) and the contact refit did or did not explain its field
    /// (`contact_explained`): the evidence of [`ErrorEvidence`] from the registered
    /// displacement of the structures, the fit of the cloud and its noise, metres.
    pub(super) fn error_estimate(
        &self,
        model: &Model,
        pose_uncertainty: Option<f64>,
        contact_explained: bool,
    ) -> ErrorEstimate {
        let (mut sum, mut count) = (0.0, 0usize);
        for s in &model.structures {
            for d in s.embedding.interpolate(&self.u) {
                sum += d.norm_squared();
                count += 1;
            }
        }
        expected_error(&ErrorEvidence {
            pose_uncertainty: pose_uncertainty.unwrap_or(0.0),
            displacement_rms: (sum / count.max(1) as f64).sqrt(),
            fit_rms: self.fit_rms,
            noise: self.noise,
            contact_explained,
        })
    }
}
