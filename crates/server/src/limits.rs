//! Limits on what one client may ask for: points per frame, frames per second (token bucket),
//! mesh and grid size of an uploaded scene. Each refusal is an [`ApiError`] with its status
//! (413 for sizes, 429 for rates, 422 for unusable frames) and a message naming the limit.

use std::time::Instant;

use super::config::LimitsConfig;
use super::error::ApiError;
use crate::session::Frame;

/// Token bucket: `capacity` frames at once, refilled at `rate` frames per second.
#[derive(Debug, Clone)]
pub(crate) struct RateLimiter {
    capacity: f64,
    rate: f64,
    tokens: f64,
    last: Instant,
}

impl RateLimiter {
    /// A full bucket of `per_second` tokens refilled at `per_second` per second.
    pub(crate) fn new(per_second: f64) -> Self {
        Self {
            capacity: per_second.max(1.0),
            rate: per_second,
            tokens: per_second.max(1.0),
            last: Instant::now(),
        }
    }

    /// Takes one token at time `now`; false when the bucket is empty.
    pub(crate) fn try_acquire(&mut self, now: Instant) -> bool {
        let dt = now.saturating_duration_since(self.last).as_secs_f64();
        self.last = now;
        self.tokens = (self.tokens + dt * self.rate).min(self.capacity);
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// 429 `rate_limited` for a session over its frame rate.
pub(crate) fn rate_limited(limit: f64) -> ApiError {
    ApiError::too_many(
        "rate_limited",
        format!("more than {limit} frames per second for this session; send fewer frames (the newest frame wins anyway)"),
    )
}

/// Largest coordinate magnitude a frame's point may have, scene units (1,000 km in a
/// millimetre scene): beyond it squared distances lose all precision long before any real
/// camera could produce such a point.
pub(crate) const MAX_COORDINATE: f64 = 1e9;

/// Checks a decoded frame before it reaches a session: not empty, every coordinate finite and
/// within ±[`MAX_COORDINATE`], at most `limits.max_frame_points` points.
pub(crate) fn check_frame(frame: &Frame, limits: &LimitsConfig) -> Result<(), ApiError> {
    if frame.points.is_empty() {
        return Err(ApiError::invalid_frame("the frame holds no points"));
    }
    if frame.points.len() > limits.max_frame_points {
        return Err(ApiError::too_large(
            "too_many_points",
            format!(
                "the frame has {} points, more than the limit of {} (limits.max_frame_points)",
                frame.points.len(),
                limits.max_frame_points
            ),
        ));
    }
    if let Some(i) = crate::mesh::first_non_finite_point(&frame.points) {
        let p = frame.points[i];
        return Err(ApiError::invalid_frame(format!(
            "point {i} has a non-finite coordinate ({}, {}, {})",
            p.x, p.y, p.z
        )));
    }
    if let Some((i, p)) = frame
        .points
        .iter()
        .enumerate()
        .find(|(_, p)| p.coords.iter().any(|c| c.abs() > MAX_COORDINATE))
    {
        return Err(ApiError::invalid_frame(format!(
            "point {i} ({:e}, {:e}, {:e}) is out of range: coordinates must be within ±{MAX_COORDINATE:e} scene units",
            p.x, p.y, p.z
        )));
    }
    if let Some(c) = &frame.camera {
        let ok = [c.position.coords, c.look_at.coords, c.up]
            .iter()
            .all(|v| v.iter().all(|x| x.is_finite()));
        if !ok {
            return Err(ApiError::invalid_frame(
                "the camera has a non-finite coordinate",
            ));
        }
    }
    Ok(())
}

/// Checks the work an uploaded scene asks for per frame: every iteration or step count of
/// its solver and registration at most `limits.max_solver_iterations` (413 `work_too_large`
/// naming the key).
pub(crate) fn check_scene_work(
    limits: &LimitsConfig,
    scene: &crate::scene::Scene,
) -> Result<(), ApiError> {
    let mut counts = vec![
        (
            "solver.max_newton_iterations",
            scene.solver.max_newton_iterations,
        ),
        ("solver.load_steps", scene.solver.load_steps),
    ];
    if let Some(r) = &scene.registration {
        counts.push(("registration.max_icp_iterations", r.max_icp_iterations));
        counts.push(("registration.penalty_steps", r.penalty_steps));
    }
    match counts
        .into_iter()
        .find(|(_, n)| *n > limits.max_solver_iterations)
    {
        Some((key, n)) => Err(ApiError::too_large(
            "work_too_large",
            format!(
                "{key} = {n} exceeds the limit of {} (limits.max_solver_iterations)",
                limits.max_solver_iterations
            ),
        )),
        None => Ok(()),
    }
}

/// Checks a scene's size before its grid is built: triangles of a mesh, octree levels, and the
/// number of grid cells its bounding box (`min`, `max`, scene units) asks for at `cell_size`.
pub(crate) fn check_scene_size(
    limits: &LimitsConfig,
    mesh_name: &str,
    triangles: usize,
    subdivisions: u32,
    bbox: Option<([f64; 3], [f64; 3])>,
    cell_size: f64,
) -> Result<(), ApiError> {
    if triangles > limits.max_mesh_triangles {
        return Err(ApiError::too_large(
            "mesh_too_large",
            format!(
                "`{mesh_name}` has {triangles} triangles, more than the limit of {} (limits.max_mesh_triangles)",
                limits.max_mesh_triangles
            ),
        ));
    }
    if subdivisions > limits.max_subdivisions {
        return Err(ApiError::too_large(
            "grid_too_large",
            format!(
                "grid.subdivisions = {subdivisions} exceeds the limit of {} (limits.max_subdivisions)",
                limits.max_subdivisions
            ),
        ));
    }
    if let Some((lo, hi)) = bbox {
        if cell_size.is_finite() && cell_size > 0.0 {
            let cells: f64 = (0..3)
                .map(|k| ((hi[k] - lo[k]) / cell_size).ceil().max(1.0) + 1.0)
                .product();
            if cells.is_nan() || cells > limits.max_grid_cells as f64 {
                return Err(ApiError::too_large(
                    "grid_too_large",
                    format!(
                        "grid.cell_size = {cell_size} gives about {cells:.0} cells over the surface's bounding box, more than the limit of {} (limits.max_grid_cells); use a larger cell size",
                        limits.max_grid_cells
                    ),
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use std::time::Duration;

    #[test]
    fn bucket_refills_at_its_rate() {
        let mut r = RateLimiter::new(2.0);
        let t0 = Instant::now();
        assert!(r.try_acquire(t0));
        assert!(r.try_acquire(t0));
        assert!(!r.try_acquire(t0));
        assert!(r.try_acquire(t0 + Duration::from_millis(600)));
        assert!(!r.try_acquire(t0 + Duration::from_millis(700)));
    }

    #[test]
    fn frames_are_checked_and_errors_name_the_problem() {
        let l = LimitsConfig {
            max_frame_points: 2,
            ..Default::default()
        };
        let f = |pts: Vec<Point3<f64>>| Frame {
            source: "x".into(),
            points: pts,
            camera: None,
        };
        assert_eq!(
            check_frame(&f(vec![]), &l).unwrap_err().code,
            "invalid_frame"
        );
        let e = check_frame(
            &f(vec![Point3::origin(), Point3::new(0.0, f64::NAN, 0.0)]),
            &l,
        )
        .unwrap_err();
        assert!(e.message.contains("point 1"), "{}", e.message);
        let e = check_frame(&f(vec![Point3::new(1e300, 0.0, 0.0)]), &l).unwrap_err();
        assert!(e.message.contains("out of range"), "{}", e.message);
        check_frame(&f(vec![Point3::new(-0.99e9, 0.0, 0.0)]), &l).unwrap();
        let e = check_frame(&f(vec![Point3::origin(); 3]), &l).unwrap_err();
        assert_eq!(e.status.as_u16(), 413);
        check_frame(&f(vec![Point3::origin(); 2]), &l).unwrap();
        let e = check_scene_size(
            &LimitsConfig::default(),
            "s",
            10,
            3,
            Some(([0.0; 3], [1.0; 3])),
            0.001,
        )
        .unwrap_err();
        assert_eq!(e.code, "grid_too_large");
    }
}
