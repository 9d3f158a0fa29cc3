//! The clouds of the frames since the liver last moved, registered together.
//!
//! Between two motions of the tool the liver is still, and each new cloud is the same surface
//! seen again through new noise. Registered alone, every frame refits its own noise and the
//! overlay trembles: on the tool-indentation class, ten frames of press-slide (neo-Hookean)
//! with the tool held still score 0.35–0.76 mm each against an unchanged truth. The window
//! keeps the clouds (model frame, metres) of the frames whose cloud showed no change against
//! the window's first cloud (below) and that the same camera saw; the session
//! registers their union with each spring at `1/n` of its stiffness
//! ([`NonRigidSettings::data_weight`](crate::registration::NonRigidSettings::data_weight)), so
//! the data term weighs as one frame's against the body while its noise averages over `n`
//! frames. A frame that shows a change, a new camera, a reset or a frame kept at rest starts
//! the window again. Measured in docs/frames.md#still-frames.
//!
//! "No change" is judged against the window's first cloud, not against the last registered
//! shape: both clouds are measured to that shape and their local medians
//! compared ([`ChangeTest::evaluate_against`](crate::registration::change_evidence::ChangeTest::evaluate_against)),
//! so that what the model cannot follow (a dent narrower than a cell) cancels instead of
//! reading as motion; and every cloud of the window is then within the noise of its first.

use std::sync::Arc;

use nalgebra::Point3;

use crate::geometry::Camera;
use crate::registration::IndexedPoints;

/// The clouds of the newest frames that showed no change (see the module).
#[derive(Debug, Clone, Default)]
pub struct StillWindow {
    /// Oldest first (model frame, metres), indexed for the test against the first; shared, a
    /// window is cloned per frame.
    clouds: Vec<Arc<IndexedPoints>>,
    /// The camera of the newest cloud (`None`: none given).
    camera: Option<Camera>,
}

impl StillWindow {
    /// Adds the cloud of a new frame (`cloud`, model frame, m) seen by `camera`. With
    /// `unchanged` (it shows no change against the window's first cloud,
    /// [`StillWindow::first`]) and the same camera as the window's, it joins the window, which
    /// then keeps the newest clouds up to `max_frames` and `max_points` points in all (always
    /// the new cloud); otherwise the window starts again with it. Returns the number of clouds
    /// the window now holds.
    pub fn admit(
        &mut self,
        cloud: Arc<IndexedPoints>,
        camera: Option<Camera>,
        unchanged: bool,
        max_frames: usize,
        max_points: usize,
    ) -> usize {
        if !(unchanged && camera == self.camera) {
            self.clouds.clear();
        }
        self.camera = camera;
        self.clouds.push(cloud);
        let mut points = 0;
        let mut keep = 0;
        for c in self.clouds.iter().rev() {
            if keep == max_frames.max(1) || (keep > 0 && points + c.len() > max_points) {
                break;
            }
            points += c.len();
            keep += 1;
        }
        self.clouds.drain(..self.clouds.len() - keep);
        self.clouds.len()
    }

    /// The window's first (oldest) cloud: what a new frame must not differ from to join.
    pub fn first(&self) -> Option<&IndexedPoints> {
        self.clouds.first().map(Arc::as_ref)
    }

    /// The camera of the newest cloud (`None`: none given).
    pub fn camera(&self) -> Option<Camera> {
        self.camera
    }

    /// Forgets every cloud: the next frame starts a new window.
    pub fn clear(&mut self) {
        self.clouds.clear();
        self.camera = None;
    }

    /// Clouds held.
    pub fn len(&self) -> usize {
        self.clouds.len()
    }

    /// Whether no cloud is held.
    pub fn is_empty(&self) -> bool {
        self.clouds.is_empty()
    }

    /// Every point of the clouds held, oldest cloud first (model frame, m).
    pub fn union(&self) -> Vec<Point3<f64>> {
        self.clouds
            .iter()
            .flat_map(|c| c.points.iter().copied())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(tag: f64, n: usize) -> Arc<IndexedPoints> {
        let points = (0..n).map(|i| Point3::new(tag, i as f64, 0.0)).collect();
        Arc::new(IndexedPoints::new(points).unwrap())
    }

    #[test]
    fn still_clouds_gather_up_to_the_frame_and_point_caps() {
        let mut w = StillWindow::default();
        assert_eq!(w.admit(cloud(0.0, 10), None, true, 3, 100), 1);
        assert_eq!(w.admit(cloud(1.0, 10), None, true, 3, 100), 2);
        assert_eq!(w.admit(cloud(2.0, 10), None, true, 3, 100), 3);
        // The frame cap drops the oldest.
        assert_eq!(w.admit(cloud(3.0, 10), None, true, 3, 100), 3);
        let u = w.union();
        assert_eq!(u.len(), 30);
        assert_eq!((u[0].x, u[29].x), (1.0, 3.0));
        // The first cloud, what a new frame is compared with, is the oldest kept.
        assert_eq!(w.first().unwrap().points[0].x, 1.0);
        // The point cap: 25 points hold two clouds of 10, the newest first.
        assert_eq!(w.admit(cloud(4.0, 10), None, true, 8, 25), 2);
        assert_eq!(w.union()[0].x, 3.0);
        // A cloud larger than the cap alone is still kept.
        assert_eq!(w.admit(cloud(5.0, 40), None, true, 8, 25), 1);
        assert_eq!(w.union().len(), 40);
    }

    #[test]
    fn a_change_a_new_camera_or_a_clear_starts_again() {
        let mut w = StillWindow::default();
        w.admit(cloud(0.0, 5), None, true, 4, 100);
        w.admit(cloud(1.0, 5), None, true, 4, 100);
        assert_eq!(w.admit(cloud(2.0, 5), None, false, 4, 100), 1);
        assert_eq!(w.union()[0].x, 2.0);
        let camera = Camera::looking_at(Point3::new(0.0, 0.0, 1.0), Point3::origin()).unwrap();
        assert_eq!(w.admit(cloud(3.0, 5), Some(camera), true, 4, 100), 1);
        assert_eq!(w.admit(cloud(4.0, 5), Some(camera), true, 4, 100), 2);
        w.clear();
        assert!(w.is_empty());
        // A window of one frame never gathers.
        assert_eq!(w.admit(cloud(5.0, 5), None, true, 1, 100), 1);
        assert_eq!(w.admit(cloud(6.0, 5), None, true, 1, 100), 1);
    }
}
