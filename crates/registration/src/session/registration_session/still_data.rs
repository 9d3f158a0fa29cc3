//! [`StillData`]: what the non-rigid stage registers.

use nalgebra::Point3;

/// What the non-rigid stage registers: the points of the still window (model frame, m) and
/// the weight of each one's spring
/// ([`NonRigidSettings::data_weight`](crate::registration::NonRigidSettings::data_weight)).
pub(super) struct StillData {
    /// The still window's clouds, together: model frame, m.
    pub(super) points: Vec<Point3<f64>>,
    /// The weight of each point's spring (`1/n` for a window of `n` clouds).
    pub(super) weight: f64,
    /// The frame's cloud noise (m,
    /// [`cloud_noise_sigma`](crate::registration::change_evidence::cloud_noise_sigma)), which
    /// weakens the automatic penalty ramp
    /// ([`NonRigidSettings::cloud_noise`](crate::registration::NonRigidSettings::cloud_noise));
    /// `None` when not measured.
    pub(super) noise: Option<f64>,
}
