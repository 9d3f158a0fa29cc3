//! The cloud a frame registers: its input checks, thinning and isolated points removed.

use nalgebra::Point3;

use super::super::frame::{Frame, FrameError};
use super::super::frame_flag::FrameFlag;
use super::super::settings::SessionSettings;
use crate::registration::isolated_points::{
    isolated_mask, ISOLATION_MEDIAN_FACTOR, ISOLATION_NEIGHBOURS, ISOLATION_SIGMA,
};
use crate::registration::IndexedPoints;

/// The cloud of `frame` (scene units; `scale`: metres per scene unit) as the session
/// registers it: input checks (empty, non-finite: rejected), thinning to `max_cloud_points`
/// (flag `decimated`) and isolated-point removal (flag `isolated_removed`), per `settings`.
/// The cloud in metres, cloud frame.
pub(super) fn prepare_cloud(
    frame: &Frame,
    settings: &SessionSettings,
    scale: f64,
    flags: &mut Vec<FrameFlag>,
) -> Result<Vec<Point3<f64>>, FrameError> {
    if frame.points.is_empty() {
        return Err(FrameError::Empty);
    }
    if let Some(index) = crate::mesh::first_non_finite_point(&frame.points) {
        let p = frame.points[index];
        return Err(FrameError::NonFinite {
            index,
            x: p.x,
            y: p.y,
            z: p.z,
        });
    }
    let stride = frame
        .points
        .len()
        .div_ceil(settings.max_cloud_points.max(3));
    if stride > 1 {
        flags.push(FrameFlag::Decimated);
    }
    let cloud: Vec<Point3<f64>> = frame
        .points
        .iter()
        .step_by(stride)
        .map(|p| p * scale)
        .collect();
    let cloud = if settings.remove_isolated_points {
        let (kept, removed) = without_isolated_points(cloud);
        if removed > 0 {
            flags.push(FrameFlag::IsolatedRemoved);
        }
        kept
    } else {
        cloud
    };
    if cloud.len() < 3 {
        return Err(FrameError::Rigid(format!(
            "{} points; at least 3 are needed",
            cloud.len()
        )));
    }
    Ok(cloud)
}

/// `cloud` without its isolated points ([`isolated_mask`] with the module's constants), and
/// how many were removed.
fn without_isolated_points(cloud: Vec<Point3<f64>>) -> (Vec<Point3<f64>>, usize) {
    let n = cloud.len();
    let Some(indexed) = IndexedPoints::new(cloud.clone()) else {
        return (cloud, 0);
    };
    let mask = isolated_mask(
        &indexed,
        ISOLATION_NEIGHBOURS,
        ISOLATION_SIGMA,
        ISOLATION_MEDIAN_FACTOR,
    );
    let kept: Vec<Point3<f64>> = cloud
        .into_iter()
        .zip(&mask)
        .filter(|(_, &m)| !m)
        .map(|(p, _)| p)
        .collect();
    let removed = n - kept.len();
    (kept, removed)
}
