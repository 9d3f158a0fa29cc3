//! Rigid iterative closest point (thesis alg. 2): aligns an intra-operative point cloud to the
//! model surface.
//!
//! Each iteration: every cloud point, moved by the current estimate, is paired with its closest
//! point on the model ([`ModelTarget::closest_point`]); pairs farther than
//! `max_correspondence_distance` are dropped, then (trimmed ICP) all but the best
//! `trim_fraction` of the cloud, then those farther than mean + `outlier_sigma` · standard
//! deviation of the remaining pair distances (the thesis's "twice the standard deviation" rule,
//! read as a band above the mean, re-applied to the fresh pair distances every iteration; with
//! `robust_pruning`, median + `outlier_sigma` · 1.4826 MAD instead); the kept
//! pairs give the update:
//!
//! - [`IcpMetric::PointToPlane`] (default): one Gauss–Newton step of the linearised
//!   small-rotation least squares `Σ ((ω × (pᵢ − c) + t + pᵢ − qᵢ) · nᵢ)²` (6×6 normal equations,
//!   `nᵢ` the normal of the model triangle holding the closest point `qᵢ`, `c` the centroid of the
//!   kept points). Converges in a handful of iterations because the cloud may slide along the
//!   surface. Falls back to Kabsch when the normal equations are singular (e.g. a planar cloud).
//! - [`IcpMetric::PointToPoint`]: the best rigid motion of the kept pairs ([`kabsch()`], thesis
//!   alg. 2), with Anderson acceleration.
//!
//! It stops when the update changes the pose by less than `rotation_tolerance` (radians) and
//! `translation_tolerance` (metres, displacement of the cloud centroid), or when the mean squared
//! distance of the kept pairs changes by at most `relative_tolerance` relative to the previous
//! iteration, or after `max_iterations`.
//!
//! The cloud is the moving side because a partial cloud has a counterpart for every point on the
//! full model surface, not the other way round.

use std::collections::VecDeque;

use nalgebra::{DMatrix, DVector, Matrix6, Point3, Rotation3, Vector3, Vector6};
use rayon::prelude::*;
use serde::Serialize;
use thiserror::Error;

use crate::registration::correspondences::{rejection_threshold, robust_threshold};
use crate::registration::{kabsch, ModelTarget, PoseCovariance, RigidTransform};

/// What can go wrong in rigid registration. Messages say what is wrong and where.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum IcpError {
    /// The point cloud has no points.
    #[error("the point cloud is empty: rigid registration needs at least 3 points")]
    EmptyCloud,
    /// A cloud point has a NaN or infinite coordinate.
    #[error("cloud point {index} has a non-finite coordinate: [{}, {}, {}]", point[0], point[1], point[2])]
    NonFiniteCloudPoint {
        /// Index of the first offending point in the cloud.
        index: usize,
        /// Its coordinates, metres.
        point: [f64; 3],
    },
    /// The initial transform has a NaN or infinite entry.
    #[error("the initial rigid transform has a non-finite entry")]
    NonFiniteInitial,
    /// Too few pairs survived outlier rejection to fit a rigid motion.
    #[error(
        "only {inliers} of {total} cloud points were kept as inliers at ICP iteration \
         {iteration} (at least {needed} needed): the cloud is too far from the model, too \
         small, or max_correspondence_distance / trim_fraction are too strict"
    )]
    TooFewInliers {
        /// The iteration (0 = at the initial transform).
        iteration: usize,
        /// Pairs kept.
        inliers: usize,
        /// Pairs required ([`RigidIcp::min_inliers`], at least 3).
        needed: usize,
        /// Cloud size.
        total: usize,
    },
    /// The kept pairs are degenerate (cloud points coincident or collinear).
    #[error(
        "the {inliers} inlier cloud points at ICP iteration {iteration} are coincident or \
         collinear: the rigid motion is undetermined"
    )]
    Degenerate {
        /// The iteration (0 = at the initial transform).
        iteration: usize,
        /// Pairs kept.
        inliers: usize,
    },
    /// A setting of [`RigidIcp`] or [`ModelTarget::new`] is out of range.
    #[error("invalid rigid ICP setting: {0}")]
    InvalidSetting(String),
    /// The model surface cannot serve as a target.
    #[error("invalid model surface for rigid ICP: {0}")]
    InvalidModel(String),
}

/// The error metric minimised by each ICP update.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub enum IcpMetric {
    /// Squared distances between paired points, solved exactly by [`kabsch()`] (thesis alg. 2),
    /// with Anderson acceleration. Slow on smooth surfaces (the cloud creeps tangentially).
    PointToPoint,
    /// Squared distances of the cloud points to the tangent planes of their closest model
    /// triangles, one linearised (small-rotation) Gauss–Newton step per iteration.
    #[default]
    PointToPlane,
}

/// Most step halvings of the point-to-plane line search per iteration.
const MAX_HALVINGS: usize = 1;

/// Ratio of the smallest to the largest eigenvalue of the point-to-plane normal equations
/// (rotation scaled by the cloud radius) below which the step falls back to [`kabsch()`].
const PLANE_DEGENERACY_RATIO: f64 = 1e-9;

/// Settings of rigid ICP. Lengths in metres. `Default` gives the thesis's settings with the
/// point-to-plane update.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RigidIcp {
    /// Most updates (default 50). 0 only evaluates the initial transform.
    pub max_iterations: usize,
    /// The update's error metric (default [`IcpMetric::PointToPlane`]).
    pub metric: IcpMetric,
    /// Stop when the mean squared inlier distance changes by at most this fraction of its
    /// previous value (default 1e-6); ≥ 0.
    pub relative_tolerance: f64,
    /// Stop when an update rotates the cloud by less than this, radians (default 1e-5) and moves
    /// its centroid by less than `translation_tolerance`; ≥ 0.
    pub rotation_tolerance: f64,
    /// See `rotation_tolerance`; metres (default 1e-6); ≥ 0.
    pub translation_tolerance: f64,
    /// Reject pairs farther than mean + `k` · standard deviation of the pair distances
    /// (thesis: twice the standard deviation, default `Some(2.0)`); `None` keeps them; > 0.
    pub outlier_sigma: Option<f64>,
    /// The band of `outlier_sigma` is median + `k` · 1.4826 MAD of the pair distances instead
    /// of mean + `k` · σ ([`robust_threshold`](super::correspondences::robust_threshold)):
    /// gross outliers do not widen it. Default false (the thesis's rule); see
    /// `registration.robust_pruning` in docs/scene.md for what it measured.
    pub robust_pruning: bool,
    /// Trimmed ICP: keep only the closest `fraction` of the cloud's pairs each iteration
    /// (before the sigma rule), for clouds that overlap the model only partly, e.g. `Some(0.4)`
    /// when about half the cloud lies on the model. Default `None`; in (0, 1].
    pub trim_fraction: Option<f64>,
    /// Drop pairs farther than this, metres (default `None`); > 0.
    pub max_correspondence_distance: Option<f64>,
    /// Fewest inliers accepted (default 3, values below 3 act as 3).
    pub min_inliers: usize,
}

impl Default for RigidIcp {
    fn default() -> Self {
        RigidIcp {
            max_iterations: 50,
            metric: IcpMetric::default(),
            relative_tolerance: 1e-6,
            rotation_tolerance: 1e-5,
            translation_tolerance: 1e-6,
            outlier_sigma: Some(2.0),
            robust_pruning: false,
            trim_fraction: None,
            max_correspondence_distance: None,
            min_inliers: 3,
        }
    }
}

/// The outcome of [`RigidIcp::register`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct IcpResult {
    /// The estimated motion taking cloud points onto the model surface.
    pub cloud_to_model: RigidTransform,
    /// Its inverse: the motion of the model into the cloud (what the pipeline applies to the
    /// model).
    pub model_to_cloud: RigidTransform,
    /// Updates performed.
    pub iterations: usize,
    /// Root mean square distance of the inlier pairs at the returned transform, metres.
    pub rms: f64,
    /// Fraction of cloud points kept as inliers at the returned transform, in [0, 1].
    pub inlier_fraction: f64,
    /// `true` when the pose-change or relative-MSE test stopped the iterations (not
    /// `max_iterations`).
    pub converged: bool,
    /// How well the kept pairs determine the pose under their own residual noise
    /// ([`PoseCovariance`]); `None` when they do not determine it at all (a plane, a sphere,
    /// fewer than 7 pairs).
    #[serde(skip)]
    pub covariance: Option<PoseCovariance>,
}

/// Reusable buffers of one registration.
struct Workspace {
    /// Closest model point, squared distance and model triangle normal of each cloud point.
    pairs: Vec<(Point3<f64>, f64, Vector3<f64>)>,
    /// Indices of pairs under consideration / kept.
    keep: Vec<usize>,
    /// `keep` of the previous iteration (point-to-plane backtracking).
    prev_keep: Vec<usize>,
    src: Vec<Point3<f64>>,
    dst: Vec<Point3<f64>>,
}

/// The state [`RigidIcp::register`] carries from one iteration to the next.
struct Iterate {
    /// The current cloud → model estimate.
    estimate: RigidTransform,
    /// Anderson acceleration of the point-to-point fixed-point iteration.
    accel: Anderson,
    /// The last iteration's inlier mean squared distance, m².
    previous_mse: Option<f64>,
    /// The plain ICP step behind an accelerated estimate, to fall back to.
    plain_step: Option<RigidTransform>,
    /// The last update moved the pose by less than the pose tolerances.
    pose_converged: bool,
    /// The estimate before the last point-to-plane update, for backtracking.
    previous_estimate: Option<RigidTransform>,
    /// Iterations done.
    iterations: usize,
}

impl RigidIcp {
    /// Checks the settings' ranges.
    pub fn validate(&self) -> Result<(), IcpError> {
        let bad = |msg: String| Err(IcpError::InvalidSetting(msg));
        if !(self.relative_tolerance.is_finite() && self.relative_tolerance >= 0.0) {
            return bad(format!(
                "relative_tolerance must be finite and >= 0, got {}",
                self.relative_tolerance
            ));
        }
        for (name, v) in [
            ("rotation_tolerance", self.rotation_tolerance),
            ("translation_tolerance", self.translation_tolerance),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!("{name} must be finite and >= 0, got {v}"));
            }
        }
        if let Some(k) = self.outlier_sigma {
            if !(k.is_finite() && k > 0.0) {
                return bad(format!("outlier_sigma must be finite and > 0, got {k}"));
            }
        }
        if let Some(f) = self.trim_fraction {
            if !(f > 0.0 && f <= 1.0) {
                return bad(format!("trim_fraction must be in (0, 1], got {f}"));
            }
        }
        if let Some(d) = self.max_correspondence_distance {
            if d.is_nan() || d <= 0.0 {
                return bad(format!(
                    "max_correspondence_distance must be > 0 metres, got {d}"
                ));
            }
        }
        Ok(())
    }

    /// Aligns `cloud` (metres) to the model surface.
    ///
    /// `initial` is the starting estimate of the cloud → model motion (the same direction as
    /// [`IcpResult::cloud_to_model`]): the previous frame's `cloud_to_model` for warm start, or
    /// the inverse of a tracked model pose; `None` starts from the identity.
    ///
    /// Errors: empty cloud, non-finite cloud coordinate (naming the index), non-finite initial
    /// transform, invalid settings, too few inliers, degenerate inliers. Never panics; the loop
    /// is bounded by `max_iterations`.
    pub fn register(
        &self,
        model: &ModelTarget,
        cloud: &[Point3<f64>],
        initial: Option<RigidTransform>,
    ) -> Result<IcpResult, IcpError> {
        let start = self.checked_start(model, cloud, initial)?;
        let needed = self.min_inliers.max(3);
        let mut ws = Workspace {
            pairs: Vec::with_capacity(cloud.len()),
            keep: Vec::with_capacity(cloud.len()),
            prev_keep: Vec::with_capacity(cloud.len()),
            src: Vec::with_capacity(cloud.len()),
            dst: Vec::with_capacity(cloud.len()),
        };
        let mut it = Iterate {
            estimate: start,
            accel: Anderson::new(cloud, &start),
            previous_mse: None,
            plain_step: None,
            pose_converged: false,
            previous_estimate: None,
            iterations: 0,
        };
        loop {
            let mse = self.pair_at_estimate(model, cloud, &mut it, &mut ws);
            let inliers = ws.keep.len();
            if inliers < needed {
                return Err(IcpError::TooFewInliers {
                    iteration: it.iterations,
                    inliers,
                    needed,
                    total: cloud.len(),
                });
            }
            let converged = it.pose_converged
                || it
                    .previous_mse
                    .is_some_and(|prev| (prev - mse).abs() <= self.relative_tolerance * prev);
            if converged || it.iterations >= self.max_iterations {
                let cloud_to_model = it.estimate;
                return Ok(IcpResult {
                    cloud_to_model,
                    model_to_cloud: cloud_to_model.inverse(),
                    iterations: it.iterations,
                    rms: mse.sqrt(),
                    inlier_fraction: inliers as f64 / cloud.len() as f64,
                    converged,
                    covariance: pose_covariance(cloud, &it.estimate, &ws),
                });
            }
            let step = self.plain_step(cloud, &it.estimate, &mut ws, it.iterations)?;
            self.advance(&mut it, step, &mut ws);
            it.previous_mse = Some(mse);
        }
    }

    /// The settings, the cloud (not empty, finite), the start (`initial`, or the identity;
    /// finite) and the model (not empty) checked: the start's cloud → model motion.
    fn checked_start(
        &self,
        model: &ModelTarget,
        cloud: &[Point3<f64>],
        initial: Option<RigidTransform>,
    ) -> Result<RigidTransform, IcpError> {
        self.validate()?;
        if cloud.is_empty() {
            return Err(IcpError::EmptyCloud);
        }
        if let Some(index) = crate::mesh::first_non_finite_point(cloud) {
            let p = cloud[index];
            return Err(IcpError::NonFiniteCloudPoint {
                index,
                point: [p.x, p.y, p.z],
            });
        }
        let estimate = initial.unwrap_or_default();
        if !estimate.is_finite() {
            return Err(IcpError::NonFiniteInitial);
        }
        if model.is_empty() {
            return Err(IcpError::InvalidModel(
                "the model target has no samples".into(),
            ));
        }
        Ok(estimate)
    }

    /// Pairs the cloud at the current estimate ([`RigidIcp::match_and_select`]) and returns
    /// the inliers' mean squared distance (m²), after two safeguards: an extrapolated
    /// estimate that made the fit worse is replaced by the plain step behind it, and a
    /// point-to-plane step that moved the last inliers farther from the surface is halved
    /// (up to [`MAX_HALVINGS`] times).
    fn pair_at_estimate(
        &self,
        model: &ModelTarget,
        cloud: &[Point3<f64>],
        it: &mut Iterate,
        ws: &mut Workspace,
    ) -> f64 {
        let mut mse = self.match_and_select(model, cloud, &it.estimate, ws);
        if let (Some(plain), Some(prev)) = (it.plain_step, it.previous_mse) {
            if mse.is_nan() || mse > prev {
                // The extrapolation made things worse: take the plain step instead.
                it.estimate = plain;
                it.accel.reset(&it.estimate);
                mse = self.match_and_select(model, cloud, &it.estimate, ws);
            }
        }
        if let (Some(before), Some(prev)) = (it.previous_estimate, it.previous_mse) {
            // Point-to-plane line search: the Gauss–Newton step can overshoot across the
            // facet edges of the model (a 2-cycle that never meets the tolerances); halve it
            // while the previous iteration's inliers got farther from the surface.
            for _ in 0..MAX_HALVINGS {
                let same_set = ws.prev_keep.iter().map(|&i| ws.pairs[i].1).sum::<f64>()
                    / ws.prev_keep.len() as f64;
                if same_set <= prev {
                    break;
                }
                it.estimate = it.accel.interpolate(&before, &it.estimate, 0.5);
                mse = self.match_and_select(model, cloud, &it.estimate, ws);
            }
        }
        mse
    }

    /// The plain ICP step from `estimate` over the kept pairs: point-to-plane Gauss–Newton,
    /// or (point-to-point, or a degenerate plane system) the Kabsch fit of the pairs.
    fn plain_step(
        &self,
        cloud: &[Point3<f64>],
        estimate: &RigidTransform,
        ws: &mut Workspace,
        iteration: usize,
    ) -> Result<RigidTransform, IcpError> {
        let plane_step = match self.metric {
            IcpMetric::PointToPlane => point_to_plane_step(cloud, estimate, ws),
            IcpMetric::PointToPoint => None,
        };
        if let Some(step) = plane_step {
            return Ok(step);
        }
        ws.src.clear();
        ws.dst.clear();
        for &i in &ws.keep {
            ws.src.push(cloud[i]);
            ws.dst.push(ws.pairs[i].0);
        }
        kabsch(&ws.src, &ws.dst, None).ok_or(IcpError::Degenerate {
            iteration,
            inliers: ws.keep.len(),
        })
    }

    /// Takes the plain `step`: decides pose convergence on its fixed-point residual, keeps the
    /// estimate before it for the point-to-plane line search, and (point-to-point, not yet
    /// converged) extrapolates it with Anderson acceleration, keeping the plain step to fall
    /// back to.
    fn advance(&self, it: &mut Iterate, step: RigidTransform, ws: &mut Workspace) {
        // The fixed-point residual of the plain step decides convergence (an extrapolated
        // estimate is then not needed).
        let (rotation, shift) = it.accel.pose_change(&it.estimate, &step);
        it.pose_converged =
            rotation < self.rotation_tolerance && shift < self.translation_tolerance;
        it.previous_estimate = None;
        if self.metric == IcpMetric::PointToPlane {
            it.previous_estimate = Some(it.estimate);
            ws.prev_keep.clone_from(&ws.keep);
        }
        let accelerated = match self.metric {
            IcpMetric::PointToPoint if !it.pose_converged => it.accel.next(&it.estimate, &step),
            _ => None,
        };
        match accelerated {
            Some(extrapolated) => {
                it.estimate = extrapolated;
                it.plain_step = Some(step);
            }
            None => {
                it.estimate = step;
                it.plain_step = None;
            }
        }
        it.iterations += 1;
    }

    /// Pairs every cloud point (moved by `estimate`) with its closest model point, fills
    /// `ws.keep` with the inliers and returns their mean squared distance (m²).
    fn match_and_select(
        &self,
        model: &ModelTarget,
        cloud: &[Point3<f64>],
        estimate: &RigidTransform,
        ws: &mut Workspace,
    ) -> f64 {
        cloud
            .par_iter()
            .with_min_len(256)
            .map(|p| model.closest_point_with_normal(&estimate.apply(p)))
            .collect_into_vec(&mut ws.pairs);
        let pairs = &ws.pairs;
        let keep = &mut ws.keep;
        keep.clear();
        match self.max_correspondence_distance {
            Some(d) => {
                let d2 = d * d;
                keep.extend((0..pairs.len()).filter(|&i| pairs[i].1 <= d2));
            }
            None => keep.extend(0..pairs.len()),
        }
        if let Some(fraction) = self.trim_fraction {
            let wanted = ((fraction * pairs.len() as f64).round() as usize).max(3);
            if wanted < keep.len() {
                keep.select_nth_unstable_by(wanted - 1, |&a, &b| pairs[a].1.total_cmp(&pairs[b].1));
                keep.truncate(wanted);
            }
        }
        if let (Some(k), true) = (self.outlier_sigma, keep.len() > 1) {
            let d: Vec<f64> = keep.iter().map(|&i| pairs[i].1.sqrt()).collect();
            let limit = if self.robust_pruning {
                robust_threshold(&d, k)
            } else {
                rejection_threshold(&d, k)
            };
            let limit2 = limit * limit;
            keep.retain(|&i| pairs[i].1 <= limit2);
        }
        if keep.is_empty() {
            return f64::INFINITY;
        }
        keep.iter().map(|&i| pairs[i].1).sum::<f64>() / keep.len() as f64
    }
}

/// One Gauss–Newton step of point-to-plane ICP from `estimate` over the kept pairs of `ws`:
/// minimises `Σ ((ω × (pᵢ − c) + t + pᵢ − qᵢ) · nᵢ)²` over the small rotation `ω` about the
/// centroid `c` of the kept moved points `pᵢ` and the translation `t` (6×6 normal equations,
/// rotation scaled by the RMS radius for conditioning), then applies the exact rotation
/// `exp(ω)`. `None` when fewer than 6 pairs have a normal or the equations are (nearly)
/// singular ([`PLANE_DEGENERACY_RATIO`]): the caller falls back to Kabsch.
fn point_to_plane_step(
    cloud: &[Point3<f64>],
    estimate: &RigidTransform,
    ws: &Workspace,
) -> Option<RigidTransform> {
    let usable = ws
        .keep
        .iter()
        .filter(|&&i| ws.pairs[i].2 != Vector3::zeros())
        .count();
    if usable < 6 {
        return None;
    }
    let moved = |i: usize| estimate.apply(&cloud[i]).coords;
    let mut c = Vector3::zeros();
    for &i in &ws.keep {
        c += moved(i);
    }
    c /= ws.keep.len() as f64;
    let mut spread = 0.0;
    for &i in &ws.keep {
        spread += (moved(i) - c).norm_squared();
    }
    let radius = (spread / ws.keep.len() as f64).sqrt();
    if radius.is_nan() || radius <= 0.0 {
        return None;
    }
    let mut a = Matrix6::zeros();
    let mut b = Vector6::zeros();
    for &i in &ws.keep {
        let (q, _, n) = ws.pairs[i];
        if n == Vector3::zeros() {
            continue;
        }
        let p = moved(i);
        let rot = (p - c).cross(&n) / radius;
        let j = Vector6::new(rot.x, rot.y, rot.z, n.x, n.y, n.z);
        let r = (p - q.coords).dot(&n);
        a += j * j.transpose();
        b += j * r;
    }
    let eigen = a.symmetric_eigen();
    let (lo, hi) = (eigen.eigenvalues.min(), eigen.eigenvalues.max());
    if !(hi.is_finite() && hi > 0.0 && lo > PLANE_DEGENERACY_RATIO * hi) {
        return None;
    }
    let x = a.cholesky()?.solve(&(-b));
    let rotation = Rotation3::new(Vector3::new(x[0], x[1], x[2]) / radius);
    let translation = Vector3::new(x[3], x[4], x[5]);
    // x ↦ R (x − c) + c + t
    let increment = RigidTransform::new(rotation, c + translation - rotation * c);
    let next = increment.compose(estimate).renormalized();
    next.is_finite().then_some(next)
}

/// The covariance of the pose `estimate` from the kept pairs of `ws` (matched at `estimate`).
fn pose_covariance(
    cloud: &[Point3<f64>],
    estimate: &RigidTransform,
    ws: &Workspace,
) -> Option<PoseCovariance> {
    let moved: Vec<Point3<f64>> = ws.keep.iter().map(|&i| estimate.apply(&cloud[i])).collect();
    let closest: Vec<Point3<f64>> = ws.keep.iter().map(|&i| ws.pairs[i].0).collect();
    let normals: Vec<Vector3<f64>> = ws.keep.iter().map(|&i| ws.pairs[i].2).collect();
    PoseCovariance::from_pairs(&moved, &closest, &normals)
}

/// Past iterates kept by the Anderson acceleration.
const ANDERSON_DEPTH: usize = 5;

/// Anderson acceleration of the ICP fixed-point map (Pavlov et al., "AA-ICP", ICRA 2018).
///
/// Plain point-to-point ICP creeps when the cloud slides along a smooth surface (hundreds of
/// iterations from a 30° offset). The ICP step `x ↦ G(x)` is treated as a fixed-point map on
/// the six pose parameters (rotation vector relative to a reference rotation, scaled by the
/// cloud's RMS radius so that it is in metres like the translation; and the image of the cloud
/// centroid), and the next estimate is the combination of the last few `G(xᵢ)` that minimises
/// the combined residual `G(x) − x`. The caller falls back to the plain step whenever the
/// extrapolated estimate has a larger mean squared distance.
struct Anderson {
    centroid: Vector3<f64>,
    radius: f64,
    reference: Rotation3<f64>,
    /// `(G(xᵢ), G(xᵢ) − xᵢ)`, oldest first.
    history: VecDeque<(Vector6<f64>, Vector6<f64>)>,
}

impl Anderson {
    fn new(cloud: &[Point3<f64>], estimate: &RigidTransform) -> Self {
        let n = cloud.len() as f64;
        let centroid = cloud.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
        let radius = (cloud
            .iter()
            .map(|p| (p.coords - centroid).norm_squared())
            .sum::<f64>()
            / n)
            .sqrt();
        Anderson {
            centroid,
            radius: if radius > 0.0 && radius.is_finite() {
                radius
            } else {
                1.0
            },
            reference: estimate.rotation,
            history: VecDeque::with_capacity(ANDERSON_DEPTH + 1),
        }
    }

    /// The rotation angle (radians) between `a` and `b` and the distance (metres) between their
    /// images of the cloud centroid.
    fn pose_change(&self, a: &RigidTransform, b: &RigidTransform) -> (f64, f64) {
        let shift = (a.apply_vector(&self.centroid) + a.translation)
            - (b.apply_vector(&self.centroid) + b.translation);
        (a.rotation_angle_to(b), shift.norm())
    }

    /// The pose a fraction `s` of the way from `a` to `b` (rotation by slerp, the image of the
    /// cloud centroid linearly).
    fn interpolate(&self, a: &RigidTransform, b: &RigidTransform, s: f64) -> RigidTransform {
        let ca = a.apply_vector(&self.centroid) + a.translation;
        let cb = b.apply_vector(&self.centroid) + b.translation;
        let rotation = a.rotation.slerp(&b.rotation, s);
        let c = ca + (cb - ca) * s;
        RigidTransform::new(rotation, c - rotation * self.centroid).renormalized()
    }

    /// Forgets the history and re-anchors the rotation parameters at `estimate`.
    fn reset(&mut self, estimate: &RigidTransform) {
        self.history.clear();
        self.reference = estimate.rotation;
    }

    fn params(&self, t: &RigidTransform) -> Vector6<f64> {
        let w = log_rotation(&(t.rotation * self.reference.inverse())) * self.radius;
        let c = t.rotation * self.centroid + t.translation;
        Vector6::new(w.x, w.y, w.z, c.x, c.y, c.z)
    }

    fn transform(&self, x: &Vector6<f64>) -> RigidTransform {
        let w = Vector3::new(x[0], x[1], x[2]) / self.radius;
        let rotation = Rotation3::new(w) * self.reference;
        let translation = Vector3::new(x[3], x[4], x[5]) - rotation * self.centroid;
        RigidTransform::new(rotation, translation).renormalized()
    }

    /// Records the plain step `current → step` and returns the accelerated estimate, or `None`
    /// when there is not enough history yet (or the extrapolation is unusable).
    fn next(&mut self, current: &RigidTransform, step: &RigidTransform) -> Option<RigidTransform> {
        let x = self.params(current);
        let g = self.params(step);
        if x.rows(0, 3).norm() > 2.0 * self.radius || g.rows(0, 3).norm() > 2.0 * self.radius {
            // Far from the reference rotation (log map ambiguity near π): start over.
            self.reset(step);
            return None;
        }
        if self.history.len() > ANDERSON_DEPTH {
            self.history.pop_front();
        }
        self.history.push_back((g, g - x));
        let k = self.history.len() - 1;
        if k == 0 {
            return None;
        }
        let (g_last, f_last) = self.history[k];
        let mut df = DMatrix::zeros(6, k);
        let mut dg = DMatrix::zeros(6, k);
        for j in 0..k {
            let (g0, f0) = self.history[j];
            let (g1, f1) = self.history[j + 1];
            df.set_column(j, &(f1 - f0));
            dg.set_column(j, &(g1 - g0));
        }
        let rhs = DVector::from_column_slice(f_last.as_slice());
        let scale = df.amax();
        if scale.is_nan() || scale <= 0.0 {
            return None;
        }
        let gamma = df.svd(true, true).solve(&rhs, 1e-10 * scale).ok()?;
        let x_new = g_last - Vector6::from_iterator((dg * gamma).iter().copied());
        let t = self.transform(&x_new);
        t.is_finite().then_some(t)
    }
}

/// The rotation vector (axis · angle, radians) of `r`, accurate near the identity.
fn log_rotation(r: &Rotation3<f64>) -> Vector3<f64> {
    let m = r.matrix();
    let v = Vector3::new(
        m[(2, 1)] - m[(1, 2)],
        m[(0, 2)] - m[(2, 0)],
        m[(1, 0)] - m[(0, 1)],
    ) / 2.0;
    let s = v.norm();
    let c = (m.trace() - 1.0) / 2.0;
    if s < 1e-12 {
        return if c > 0.0 { v } else { r.scaled_axis() };
    }
    v * (s.atan2(c) / s)
}
