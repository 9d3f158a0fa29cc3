//! [`CloudNoise`]: a frame's cloud with its own noise.

use std::sync::Arc;

use nalgebra::Point3;

use crate::registration::change_evidence::{cloud_noise_sigma_near, ChangeTest};
use crate::registration::IndexedPoints;

/// A frame's cloud (model frame, m) with its own noise, for the tests of change
/// ([`ChangeTests`](super::change_tests::ChangeTests)) and the data term's weight
/// ([`NonRigidSettings::cloud_noise`](crate::registration::NonRigidSettings::cloud_noise)).
pub(super) struct CloudNoise {
    /// The cloud, indexed (the still window keeps it).
    pub(super) points: Arc<IndexedPoints>,
    /// [`ChangeTest::neighbours`] of each cloud point (empty without a test).
    pub(super) near: Vec<Vec<usize>>,
    /// [`cloud_noise_sigma`](crate::registration::change_evidence::cloud_noise_sigma), m.
    pub(super) sigma: f64,
}

impl CloudNoise {
    /// The noise of `aligned` (m) and its neighbours for `test` (none without a test);
    /// `None` for an empty cloud.
    pub(super) fn measure(aligned: &[Point3<f64>], test: Option<&ChangeTest>) -> Option<Self> {
        let points = IndexedPoints::new(aligned.to_vec())?;
        let near = test.map_or_else(Vec::new, |t| t.neighbours(&points));
        // The test's neighbour lists (32 nearest) hold the estimator's 16: one search.
        let sigma = cloud_noise_sigma_near(&points, &near);
        Some(Self {
            points: Arc::new(points),
            near,
            sigma,
        })
    }
}
