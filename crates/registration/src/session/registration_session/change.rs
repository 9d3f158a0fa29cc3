//! What changed since the last frame: the rest test (a cloud that shows the rest shape) and
//! the still window (clouds of the same view registered together; docs/frames.md).

use super::*;

impl Session {
    /// The rest shape, kept without registering when it explains the frame's cloud
    /// (`aligned`, metres, model frame) within the cloud's own noise
    /// ([`SessionSettings::rest_test`]; flag `at_rest`): registering a liver at rest can only
    /// fit noise. `None` (register) otherwise. Returns the displacement (zero), the fit RMS
    /// (m) and a zero contact force.
    pub(super) fn rest_shape_if_unchanged(
        &mut self,
        aligned: &[Point3<f64>],
        noise: Option<&CloudNoise>,
        flags: &mut Vec<FrameFlag>,
    ) -> Option<(Vec<f64>, f64, Option<ContactForce>)> {
        let test = self.settings.rest_test.clone()?;
        let noise = noise?;
        let rest = vec![0.0; self.good.u.len()];
        let d = self
            .rest_surface
            .get_or_init(|| deformed_surface(&self.model, &self.surface_topology, &rest))
            .as_ref()?
            .signed_distances(aligned);
        if test.evaluate_near(&noise.near, &d, noise.sigma).significant {
            return None;
        }
        flags.push(FrameFlag::AtRest);
        // The solvers' warm state belongs to the shape left behind.
        self.non_rigid_cold.invalidate();
        self.non_rigid_warm.invalidate();
        let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
        let force = ContactForce {
            resultant: nalgebra::Vector3::zeros(),
            centre: centroid(aligned),
        };
        Some((rest, rms, Some(force)))
    }

    /// The data of the non-rigid stage: the frame's cloud `aligned` (model frame, m) seen by
    /// `camera` joins the still window ([`StillWindow`]) when it shows the surface where the
    /// window's first cloud showed it, within its `noise` ([`Session::same_as_window`]; a warm
    /// frame, the same camera, [`SessionSettings::still_frames`] > 1),
    /// and the stage registers the window's union, each spring at `1/n` of its stiffness
    /// (flag `still:<n>` for `n` > 1). Otherwise the window starts again with this cloud.
    /// Returns the new window (the session keeps it only if the frame succeeds: a failed
    /// frame leaves no trace) and the data.
    pub(super) fn still_frames(
        &self,
        aligned: &[Point3<f64>],
        camera: Option<Camera>,
        noise: Option<&CloudNoise>,
        flags: &mut Vec<FrameFlag>,
    ) -> (StillWindow, StillData) {
        let max_frames = self.settings.still_frames.max(1);
        let Some(noise) = noise else {
            // No noise measured (an empty cloud): alone, the window cleared.
            let data = StillData {
                points: aligned.to_vec(),
                weight: 1.0,
                noise: None,
            };
            return (StillWindow::default(), data);
        };
        // A new camera restarts the window in `admit` whatever the test says: the test (about
        // 1.5 ms) is made only for the window's own camera.
        let unchanged = max_frames > 1
            && self.good.registered
            && camera == self.still.camera()
            && self.same_as_window(noise);
        let mut still = self.still.clone();
        let n = still.admit(
            noise.points.clone(),
            camera,
            unchanged,
            max_frames,
            self.settings.max_cloud_points,
        );
        if n > 1 {
            flags.push(FrameFlag::Still(n));
        }
        let data = StillData {
            points: still.union(),
            weight: 1.0 / n as f64,
            noise: Some(noise.sigma).filter(|s| *s > 0.0),
        };
        (still, data)
    }

    /// Whether the frame's cloud (`noise`: the cloud, model frame, m, its neighbour lists and
    /// noise) shows the surface where the still window's first cloud showed it: both measured
    /// to the last good surface, their local medians compared
    /// ([`ChangeTest::evaluate_against`]). False without the test, a window or a surface.
    pub(super) fn same_as_window(&self, noise: &CloudNoise) -> bool {
        let (Some(test), Some(first)) = (&self.settings.rest_test, self.still.first()) else {
            return false;
        };
        let Some(surface) = self.good_surface() else {
            return false;
        };
        let cloud = &noise.points.points;
        let first_near = test.neighbours_in(cloud, first);
        let d = surface.signed_distances(cloud);
        let d_first = surface.signed_distances(&first.points);
        !test
            .evaluate_against(&noise.near, &d, &first_near, &d_first, noise.sigma)
            .significant
    }
}

/// A re-acquired pose that is the held one shifted by the cloud centroid's motion is kept
/// without ICP when the cloud's fit there is at most this times the last frame's fit at the
/// held pose, plus [`SAME_VIEW_FIT_SLACK`].
pub(super) const SAME_VIEW_FIT_RATIO: f64 = 1.2;

/// See [`SAME_VIEW_FIT_RATIO`], metres (a new frame's noise changes the fit by a fraction of
/// a millimetre).
pub(super) const SAME_VIEW_FIT_SLACK: f64 = 0.5e-3;

/// A frame's cloud with its own noise, for the tests of change
/// ([`Session::rest_shape_if_unchanged`], [`Session::still_frames`]) and the data term's
/// weight ([`NonRigidSettings::cloud_noise`]).
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

/// What the non-rigid stage registers: the points of the still window (model frame, m) and
/// the weight of each one's spring ([`NonRigidSettings::data_weight`]).
pub(super) struct StillData {
    pub(super) points: Vec<Point3<f64>>,
    pub(super) weight: f64,
    /// The frame's cloud noise (m, [`cloud_noise_sigma`](crate::registration::change_evidence::cloud_noise_sigma)), which weakens the automatic
    /// penalty ramp ([`NonRigidSettings::cloud_noise`]); `None` when not measured.
    pub(super) noise: Option<f64>,
}
