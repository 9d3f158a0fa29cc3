//! Global search of the rigid pose when the start is only roughly known.
//!
//! Rigid ICP is a local method: from a start some tens of degrees off, a partial patch of a
//! smooth organ can slide into a wrong minimum and stop there *converged* (measured on the
//! phantom: a 30 % patch turned by 30° ended 43–88° off in 10 of 27 runs, each with
//! `converged: true`). [`PoseSearch`] adds a multi-start search around the start:
//!
//! 1. ICP from the start itself, exactly as without the search (the *plain* fit);
//! 2. coarse ICP (a few iterations, a subsample of the cloud) from the start turned about the
//!    cloud's centroid by each of [`PoseSearch::angles_deg`] about each of the 13 symmetry axes
//!    of a cube, both ways (26 starts per angle), run in parallel;
//! 3. the [`PoseSearch::refine_count`] best distinct coarse poses are refined by full ICP;
//! 4. every refined fit is scored by the truncated mean square distance of the best-fitting
//!    [`PoseSearch::score_share`] of the cloud ([`trimmed_score`]): unlike ICP's own inlier
//!    RMS, a pose cannot score well by declaring most of the points it does not fit outliers,
//!    and unlike the whole cloud's score, a deformed part of the organ does not decide. A
//!    searched pose replaces the plain fit only when it is a different pose and scores below
//!    [`PoseSearch::replace_ratio`] × the plain fit's score; when the best and the next distinct pose score within
//!    [`PoseSearch::ambiguity_ratio`] of each other, the result says the pose is ambiguous.
//!
//! Lengths in metres, angles in degrees where named so.

use nalgebra::{Point3, Rotation3, Unit, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use crate::registration::{IcpError, IcpResult, ModelTarget, RigidIcp, RigidTransform};

/// Settings of the multi-start pose search. `Default` gives the measured defaults.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PoseSearch {
    /// Angles by which the start is turned about the cloud's centroid, degrees (default every
    /// 30° up to a half turn, so that no orientation is more than about 30° from a start);
    /// each about the 13 symmetry axes of a cube, both ways (a half turn one way).
    pub angles_deg: Vec<f64>,
    /// Cloud points used by the coarse fits (every k-th point; default 256).
    pub sample_points: usize,
    /// Iterations of each coarse fit (default 15).
    pub coarse_iterations: usize,
    /// Distinct coarse poses refined by full ICP (default 4).
    pub refine_count: usize,
    /// Truncation of the score: distances beyond this count as this, metres (default 5 mm).
    pub truncation: f64,
    /// A searched pose replaces the plain fit only when its score is below this fraction of
    /// the plain fit's (default 0.8).
    pub replace_ratio: f64,
    /// The pose is flagged ambiguous when the next distinct pose scores below this multiple of
    /// the best (default 1.25).
    pub ambiguity_ratio: f64,
    /// Two poses are distinct when their rotations differ by more than this, degrees (default
    /// 5), or their translations by more than `distinct_shift` metres.
    pub distinct_angle_deg: f64,
    /// See `distinct_angle_deg`, metres (default 5 mm).
    pub distinct_shift: f64,
    /// The share of the cloud the refined fits are scored on: the points that fit best
    /// ([`trimmed_score`], default 0.75). A cloud of a deformed organ (a dent, a lifted lobe)
    /// puts its deformed part off the rest surface at the right pose; charged in full, those
    /// points let a pose turned onto another, smooth part of the surface score better than
    /// the right one (a dented liver's first frame ended 110° off). Scored on the best three
    /// quarters, the right pose fits its undeformed part to the noise while a wrong pose fits
    /// no large share of the cloud that well.
    pub score_share: f64,
}

impl Default for PoseSearch {
    fn default() -> Self {
        Self {
            angles_deg: vec![30.0, 60.0, 90.0, 120.0, 150.0, 180.0],
            sample_points: 256,
            coarse_iterations: 15,
            refine_count: 4,
            truncation: 0.005,
            replace_ratio: 0.8,
            ambiguity_ratio: 1.25,
            distinct_angle_deg: 5.0,
            distinct_shift: 0.005,
            score_share: 0.75,
        }
    }
}

/// What [`PoseSearch::search`] found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PoseSearchResult {
    /// The chosen fit.
    pub best: IcpResult,
    /// Its [`trimmed_score`], m².
    pub score: f64,
    /// The plain fit's score (from the start itself), m²; infinite when that fit failed.
    pub plain_score: f64,
    /// Whether a searched pose replaced the plain fit.
    pub replaced_plain: bool,
    /// Score of the best pose distinct from the chosen one, m² (`None`: every fit found the
    /// same pose).
    pub runner_up_score: Option<f64>,
    /// Rotation between the chosen pose and that runner-up, degrees.
    pub runner_up_angle_deg: Option<f64>,
    /// The runner-up scores within [`PoseSearch::ambiguity_ratio`] of the best: the cloud does
    /// not tell these poses apart.
    pub ambiguous: bool,
    /// ICP fits run (plain, coarse and refined).
    pub fits: usize,
    /// ICP iterations over all fits.
    pub iterations: usize,
}

impl PoseSearch {
    /// Checks the settings' ranges.
    pub fn validate(&self) -> Result<(), IcpError> {
        let bad = |m: String| Err(IcpError::InvalidSetting(format!("pose search: {m}")));
        if let Some(a) = self
            .angles_deg
            .iter()
            .find(|a| !(a.is_finite() && **a > 0.0 && **a <= 180.0))
        {
            return bad(format!("angles must be in (0, 180] degrees, got {a}"));
        }
        if self.sample_points < 6 {
            return bad(format!(
                "sample_points must be >= 6, got {}",
                self.sample_points
            ));
        }
        for (name, v) in [
            ("truncation", self.truncation),
            ("distinct_shift", self.distinct_shift),
            ("distinct_angle_deg", self.distinct_angle_deg),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("{name} must be finite and > 0, got {v}"));
            }
        }
        if !(self.replace_ratio > 0.0 && self.replace_ratio <= 1.0) {
            return bad(format!(
                "replace_ratio must be in (0, 1], got {}",
                self.replace_ratio
            ));
        }
        if !(self.score_share > 0.0 && self.score_share <= 1.0) {
            return bad(format!(
                "score_share must be in (0, 1], got {}",
                self.score_share
            ));
        }
        if !(self.ambiguity_ratio.is_finite() && self.ambiguity_ratio >= 1.0) {
            return bad(format!(
                "ambiguity_ratio must be finite and >= 1, got {}",
                self.ambiguity_ratio
            ));
        }
        Ok(())
    }

    /// The multi-start search of the cloud → model motion around `initial` (see the module
    /// documentation). `icp` gives the settings of every fit (the coarse ones with
    /// [`PoseSearch::coarse_iterations`] at most). Errors: invalid settings, or the plain fit's
    /// error when no fit at all succeeded.
    pub fn search(
        &self,
        icp: &RigidIcp,
        target: &ModelTarget,
        cloud: &[Point3<f64>],
        initial: RigidTransform,
    ) -> Result<PoseSearchResult, IcpError> {
        self.validate()?;
        let plain = icp.register(target, cloud, Some(initial));
        let mut fits = 1;
        let mut iterations = plain.as_ref().map_or(0, |r| r.iterations);
        let plain_score = plain
            .as_ref()
            .map_or(f64::INFINITY, |r| self.score(target, cloud, r));

        // Coarse fits from the turned starts, on a subsample.
        let stride = cloud.len().div_ceil(self.sample_points).max(1);
        let sample: Vec<Point3<f64>> = cloud.iter().step_by(stride).copied().collect();
        let centre = centroid(&initial.apply_all(cloud));
        let starts = self.starts(&initial, &centre);
        let coarse_icp = RigidIcp {
            max_iterations: self.coarse_iterations.min(icp.max_iterations),
            ..icp.clone()
        };
        let coarse: Vec<(RigidTransform, f64, usize)> = starts
            .par_iter()
            .filter_map(|start| {
                let r = coarse_icp.register(target, &sample, Some(*start)).ok()?;
                let s = truncated_score(target, &sample, &r.cloud_to_model, self.truncation);
                Some((r.cloud_to_model, s, r.iterations))
            })
            .collect();
        fits += starts.len();
        iterations += coarse.iter().map(|c| c.2).sum::<usize>();

        // Refine the best distinct coarse poses on the whole cloud.
        let mut order: Vec<usize> = (0..coarse.len()).collect();
        order.sort_by(|&a, &b| coarse[a].1.total_cmp(&coarse[b].1));
        let mut picked: Vec<RigidTransform> = Vec::new();
        for &i in &order {
            if picked.len() >= self.refine_count {
                break;
            }
            if picked.iter().all(|p| self.distinct(p, &coarse[i].0)) {
                picked.push(coarse[i].0);
            }
        }
        let refined: Vec<Result<IcpResult, IcpError>> = picked
            .par_iter()
            .map(|p| icp.register(target, cloud, Some(*p)))
            .collect();
        fits += picked.len();

        let mut candidates: Vec<(IcpResult, f64)> = Vec::new();
        for r in refined.into_iter().flatten() {
            iterations += r.iterations;
            let s = self.score(target, cloud, &r);
            candidates.push((r, s));
        }
        candidates.sort_by(|a, b| a.1.total_cmp(&b.1));

        let (best, score, replaced_plain) = match (&plain, candidates.first()) {
            (Ok(p), Some((c, s)))
                if *s < self.replace_ratio * plain_score
                    && self.distinct(&p.cloud_to_model, &c.cloud_to_model) =>
            {
                (*c, *s, true)
            }
            (Ok(p), _) => (*p, plain_score, false),
            (Err(_), Some((c, s))) => (*c, *s, true),
            (Err(e), None) => return Err(e.clone()),
        };
        // The best pose distinct from the chosen one, among every fit.
        let runner_up = candidates
            .iter()
            .map(|(r, s)| (r.cloud_to_model, *s))
            .chain(plain.as_ref().ok().map(|p| (p.cloud_to_model, plain_score)))
            .filter(|(t, _)| self.distinct(t, &best.cloud_to_model))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        Ok(PoseSearchResult {
            best,
            score,
            plain_score,
            replaced_plain,
            runner_up_score: runner_up.map(|r| r.1),
            runner_up_angle_deg: runner_up
                .map(|r| r.0.rotation_angle_to(&best.cloud_to_model).to_degrees()),
            ambiguous: runner_up.is_some_and(|r| r.1 < self.ambiguity_ratio * score),
            fits,
            iterations,
        })
    }

    /// The starts: `initial` followed by a turn about `centre` (model frame) by each angle
    /// about each of the 13 symmetry axes of a cube, both ways.
    fn starts(&self, initial: &RigidTransform, centre: &Point3<f64>) -> Vec<RigidTransform> {
        let mut axes: Vec<Vector3<f64>> = Vec::with_capacity(13);
        for x in -1i32..=1 {
            for y in -1i32..=1 {
                for z in -1i32..=1 {
                    let v = Vector3::new(x as f64, y as f64, z as f64);
                    // One of each ± pair: the first non-zero component positive.
                    let first = [x, y, z].into_iter().find(|c| *c != 0);
                    if first == Some(1) {
                        axes.push(v);
                    }
                }
            }
        }
        let mut out = Vec::with_capacity(axes.len() * 2 * self.angles_deg.len());
        for &angle in &self.angles_deg {
            for axis in &axes {
                // A half turn is the same both ways.
                let signs: &[f64] = if angle >= 180.0 { &[1.0] } else { &[1.0, -1.0] };
                for &sign in signs {
                    let r = Rotation3::from_axis_angle(
                        &Unit::new_normalize(*axis),
                        sign * angle.to_radians(),
                    );
                    // p ↦ c + R (p − c), after the initial motion.
                    let turn = RigidTransform::new(r, centre.coords - r * centre.coords);
                    out.push(turn.compose(initial));
                }
            }
        }
        out
    }

    /// Whether two cloud → model motions are different poses.
    fn distinct(&self, a: &RigidTransform, b: &RigidTransform) -> bool {
        a.rotation_angle_to(b).to_degrees() > self.distinct_angle_deg
            || a.translation_distance_to(b) > self.distinct_shift
    }

    fn score(&self, target: &ModelTarget, cloud: &[Point3<f64>], r: &IcpResult) -> f64 {
        trimmed_score(
            target,
            cloud,
            &r.cloud_to_model,
            self.truncation,
            self.score_share,
        )
    }
}

/// Mean over every point of `cloud` (moved by `cloud_to_model`) of its squared distance to
/// the model surface, each capped at `truncation²`, m²: a robust fit score that, unlike an
/// inlier RMS, charges a pose for the points it leaves off the surface.
pub fn truncated_score(
    target: &ModelTarget,
    cloud: &[Point3<f64>],
    cloud_to_model: &RigidTransform,
    truncation: f64,
) -> f64 {
    if cloud.is_empty() {
        return f64::INFINITY;
    }
    let cap = truncation * truncation;
    let sum: f64 = cloud
        .par_iter()
        .with_min_len(256)
        .map(|p| target.closest_point(&cloud_to_model.apply(p)).1.min(cap))
        .sum();
    sum / cloud.len() as f64
}

/// Mean over the `share` (in (0, 1]) of the points of `cloud` (moved by `cloud_to_model`)
/// that lie nearest the model surface of their squared distance to it, each capped at
/// `truncation²`, m²: [`truncated_score`] of the best-fitting part of the cloud, so that a
/// deformed part of the organ does not decide the pose. `share` 1 is [`truncated_score`].
pub fn trimmed_score(
    target: &ModelTarget,
    cloud: &[Point3<f64>],
    cloud_to_model: &RigidTransform,
    truncation: f64,
    share: f64,
) -> f64 {
    if cloud.is_empty() {
        return f64::INFINITY;
    }
    let cap = truncation * truncation;
    let mut d2: Vec<f64> = cloud
        .par_iter()
        .with_min_len(256)
        .map(|p| target.closest_point(&cloud_to_model.apply(p)).1.min(cap))
        .collect();
    let keep = ((share.clamp(0.0, 1.0) * d2.len() as f64).ceil() as usize).clamp(1, d2.len());
    if keep < d2.len() {
        d2.select_nth_unstable_by(keep - 1, f64::total_cmp);
    }
    d2[..keep].iter().sum::<f64>() / keep as f64
}

/// The mean of `points` (the origin when empty).
pub(crate) fn centroid(points: &[Point3<f64>]) -> Point3<f64> {
    let n = points.len().max(1) as f64;
    Point3::from(points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::icosphere;
    use crate::registration::test_support::{add_noise, liver, sample_surface, Rng};

    /// A patch of a quarter of the surface around `+z` (the side a camera above would see),
    /// with 1 mm noise, moved by `truth⁻¹` (so `truth` is the cloud → model motion).
    fn patch(
        surface: &crate::mesh::TriSurface,
        truth: &RigidTransform,
        seed: u64,
    ) -> Vec<Point3<f64>> {
        let mut rng = Rng::new(seed);
        let mut cloud = sample_surface(&mut rng, surface, 400, |p| p.z > 0.02 && p.x > -0.02);
        add_noise(&mut rng, &mut cloud, 1e-3);
        truth.inverse().apply_all(&cloud)
    }

    /// Turned by `deg` about an axis through the patch's centroid, shifted by 1 cm.
    fn turned(cloud_centre: Point3<f64>, deg: f64, rng: &mut Rng) -> RigidTransform {
        let r =
            Rotation3::from_axis_angle(&Unit::new_normalize(rng.unit_vector()), deg.to_radians());
        let c = cloud_centre.coords;
        // cloud → model: the inverse of a turn about the centroid plus a shift.
        RigidTransform::new(r, c - r * c + rng.unit_vector() * 0.01).inverse()
    }

    #[test]
    fn turned_patches_of_an_asymmetric_surface_are_found_and_not_ambiguous() {
        let model = liver();
        let target = ModelTarget::new(&model, 0.004).unwrap();
        let icp = RigidIcp::default();
        let mut rng = Rng::new(7);
        let centre = Point3::new(0.03, 0.0, 0.04);
        let mut plain_wrong = 0;
        for k in 0..4 {
            let truth = turned(centre, 100.0, &mut rng);
            let cloud = patch(&model, &truth, k);
            let found = PoseSearch::default()
                .search(&icp, &target, &cloud, RigidTransform::identity())
                .unwrap();
            let angle = found
                .best
                .cloud_to_model
                .rotation_angle_to(&truth)
                .to_degrees();
            let shift = found.best.cloud_to_model.translation_distance_to(&truth);
            let plain = icp.register(&target, &cloud, None).unwrap();
            plain_wrong += usize::from(plain.cloud_to_model.rotation_angle_to(&truth) > 0.1);
            assert!(
                angle < 1.5 && shift < 2e-3,
                "case {k}: {angle:.2}°, {:.2} mm",
                shift * 1e3
            );
            assert!(!found.ambiguous, "case {k}: {found:?}");
            // A searched pose replaced the plain fit only if that fit was wrong.
            assert_eq!(
                found.replaced_plain,
                plain.cloud_to_model.rotation_angle_to(&truth) > 0.1
            );
            assert!(found.fits > 100 && found.score < 3e-6, "{found:?}");
        }
        // A 100° turn is outside plain ICP's basin on this surface.
        assert!(plain_wrong >= 2, "plain ICP wrong in {plain_wrong} of 4");
    }

    #[test]
    fn a_surface_of_revolution_leaves_the_pose_ambiguous() {
        // A spheroid: every turn about its axis (z) fits a patch around the pole equally well.
        let mut model = icosphere(Point3::origin(), 1.0, 4);
        for v in &mut model.vertices {
            *v = Point3::new(0.08 * v.x, 0.08 * v.y, 0.05 * v.z);
        }
        let target = ModelTarget::new(&model, 0.004).unwrap();
        let truth = RigidTransform::identity();
        let mut rng = Rng::new(3);
        let mut cloud = sample_surface(&mut rng, &model, 400, |p| p.z > 0.02 && p.x > 0.0);
        add_noise(&mut rng, &mut cloud, 1e-3);
        let found = PoseSearch::default()
            .search(&RigidIcp::default(), &target, &cloud, truth)
            .unwrap();
        assert!(found.ambiguous, "{found:?}");
        assert!(found.runner_up_angle_deg.unwrap() > 5.0, "{found:?}");
    }

    #[test]
    fn settings_out_of_range_are_named() {
        let bad = [
            PoseSearch {
                angles_deg: vec![0.0],
                ..PoseSearch::default()
            },
            PoseSearch {
                sample_points: 2,
                ..PoseSearch::default()
            },
            PoseSearch {
                truncation: f64::NAN,
                ..PoseSearch::default()
            },
            PoseSearch {
                replace_ratio: 1.5,
                ..PoseSearch::default()
            },
            PoseSearch {
                ambiguity_ratio: 0.5,
                ..PoseSearch::default()
            },
        ];
        for (p, name) in bad.iter().zip([
            "angles",
            "sample_points",
            "truncation",
            "replace_ratio",
            "ambiguity_ratio",
        ]) {
            let e = p.validate().unwrap_err().to_string();
            assert!(e.contains(name), "{e}");
        }
    }
}
