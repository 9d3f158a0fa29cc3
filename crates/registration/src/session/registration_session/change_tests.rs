//! [`ChangeTests`]: what changed since the last frame, the rest test (a cloud that shows the
//! rest shape) and the still test with its window (clouds of the same view registered
//! together; docs/frames.md).

use nalgebra::Point3;

use super::super::frame_flag::FrameFlag;
use super::super::still_window::StillWindow;
use super::cloud_noise::CloudNoise;
use super::session_view::SessionView;
use super::still_data::StillData;
use crate::geometry::Camera;
use crate::registration::pose_search::centroid;
use crate::registration::ContactForce;

/// The tests of what changed since the last frame, on a cloud in the model frame (metres)
/// measured against the model's surfaces within the cloud's own noise
/// ([`SessionSettings::rest_test`](super::super::settings::SessionSettings::rest_test)): does
/// the rest shape explain it (the rest test), and does it show the surface where the still
/// window's first cloud showed it (the still test)? Owns the still window: the clouds of the
/// frames since the liver last moved, registered together.
#[derive(Default)]
pub(super) struct ChangeTests {
    /// The clouds of the frames since the liver last moved ([`StillWindow`]).
    still: StillWindow,
}

impl ChangeTests {
    /// Forgets the still window.
    pub(super) fn clear(&mut self) {
        self.still.clear();
    }

    /// Keeps `still`, the window of a frame that succeeded, as the window the next frame
    /// joins.
    pub(super) fn keep(&mut self, still: StillWindow) {
        self.still = still;
    }

    /// The rest shape, kept without registering when it explains the frame's cloud
    /// (`aligned`, metres, model frame) within the cloud's own noise
    /// ([`SessionSettings::rest_test`](super::super::settings::SessionSettings::rest_test);
    /// flag `at_rest`): registering a liver at rest can only fit noise. `None` (register)
    /// otherwise. Returns the displacement (zero), the fit RMS (m) and a zero contact force.
    pub(super) fn rest_shape_if_unchanged(
        &self,
        view: &SessionView<'_>,
        aligned: &[Point3<f64>],
        noise: Option<&CloudNoise>,
        flags: &mut Vec<FrameFlag>,
    ) -> Option<(Vec<f64>, f64, Option<ContactForce>)> {
        let test = view.settings.rest_test.clone()?;
        let noise = noise?;
        let rest = vec![0.0; view.good.u.len()];
        let d = view.surfaces.rest(view.model)?.signed_distances(aligned);
        if test.evaluate_near(&noise.near, &d, noise.sigma).significant {
            return None;
        }
        flags.push(FrameFlag::AtRest);
        let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
        let force = ContactForce {
            resultant: nalgebra::Vector3::zeros(),
            centre: centroid(aligned),
            expected_error: 0.0,
        };
        Some((rest, rms, Some(force)))
    }

    /// The data of the non-rigid stage: the frame's cloud `aligned` (model frame, m) seen by
    /// `camera` joins the still window ([`StillWindow`]) when it shows the surface where the
    /// window's first cloud showed it, within its `noise` ([`ChangeTests::same_as_window`]; a
    /// warm frame, the same camera, more than one
    /// [`SessionSettings::still_frames`](super::super::settings::SessionSettings::still_frames)),
    /// and the stage registers the window's union, each spring at `1/n` of its stiffness
    /// (flag `still:<n>` for `n` > 1). Otherwise the window starts again with this cloud.
    /// Returns the new window (kept only if the frame succeeds, [`ChangeTests::keep`]: a
    /// failed frame leaves no trace) and the data.
    pub(super) fn still_frames(
        &self,
        view: &SessionView<'_>,
        aligned: &[Point3<f64>],
        camera: Option<Camera>,
        noise: Option<&CloudNoise>,
        flags: &mut Vec<FrameFlag>,
    ) -> (StillWindow, StillData) {
        let max_frames = view.settings.still_frames.max(1);
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
            && view.good.registered
            && camera == self.still.camera()
            && self.same_as_window(view, noise);
        let mut still = self.still.clone();
        let n = still.admit(
            noise.points.clone(),
            camera,
            unchanged,
            max_frames,
            view.settings.max_cloud_points,
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
    /// ([`ChangeTest::evaluate_against`](crate::registration::change_evidence::ChangeTest::evaluate_against)).
    /// False without the test, a window or a surface.
    fn same_as_window(&self, view: &SessionView<'_>, noise: &CloudNoise) -> bool {
        let (Some(test), Some(first)) = (&view.settings.rest_test, self.still.first()) else {
            return false;
        };
        let Some(surface) = view.good_surface() else {
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
