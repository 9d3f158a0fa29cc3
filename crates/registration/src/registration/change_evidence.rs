//! Does a cloud show a change of shape beyond its own noise? (Frames where the liver is at
//! rest, or has not moved since the last frame, must not end worse than no registration.)
//!
//! Registering a cloud that shows no deformation can only fit its noise: on the indentation
//! class, frames with the tool lifted end 0.2–0.3 mm from the truth when registered, where the
//! rest shape is exact. [`ChangeTest`] decides from the cloud alone whether the surface it is
//! compared with (the last registered state, or the rest shape) explains it:
//!
//! 1. the noise of the cloud, σ, from the cloud itself ([`cloud_noise_sigma`]): the RMS
//!    residual of a quadric fitted to each point's neighbourhood (a surface is smooth at that
//!    scale, its noise is not), the median over the points;
//! 2. the signed distance `dᵢ` of each cloud point to the surface along its normal, given;
//! 3. for each point, the median of `d` over its `k` nearest cloud points, for `k` in
//!    [`ChangeTest::neighbourhoods`]; under "no change" it is noise, of standard deviation
//!    1.2533 σ / √k (the median of normal samples);
//! 4. the statistic is the largest |median| over points and neighbourhoods in units of that
//!    deviation; the change is significant above [`ChangeTest::threshold`] (default 4: the
//!    chance that noise alone reaches it somewhere in a 500-point cloud is well under 1 %).
//!
//! A change of amplitude `A` spread over `k` points is found when `A ≳ 6 σ / √k`: with
//! σ = 1.5 mm and `k` = 32, about 1.6 mm; with `k` = 8, about 3.3 mm. Smaller changes are left
//! unregistered.
//!
//! [`ChangeTest::evaluate_against`] asks the same of two clouds: has the surface moved between
//! an earlier cloud and this one? Both are measured to one common surface and their local
//! medians over the same patch compared, so that what that surface does not explain in both
//! (a dent the grid cannot follow) cancels; the price is the second cloud's noise, about `√2`
//! on the deviation.
//! Lengths in metres.

use nalgebra::{Matrix3, Point3, SMatrix, SVector, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::correspondences::IndexedPoints;

/// Standard deviation of the median of `k` normal samples, in units of σ / √k (large-sample
/// value √(π/2)).
const MEDIAN_DEVIATION: f64 = 1.2533;

/// Neighbours of the quadric fits of [`cloud_noise_sigma`].
pub const NOISE_NEIGHBOURS: usize = 16;

/// Settings of the test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChangeTest {
    /// Neighbourhood sizes the local medians are taken over (default 8 and 32 points: a
    /// narrow dent and a broad change).
    pub neighbourhoods: Vec<usize>,
    /// The change is significant when the statistic exceeds this (default 5: under noise
    /// alone the largest of the overlapping local medians of a 500-point cloud reached 2.6–4.3
    /// in 20 trials, `tests` below).
    pub threshold: f64,
}

impl Default for ChangeTest {
    fn default() -> Self {
        Self {
            neighbourhoods: vec![8, 32],
            threshold: 5.0,
        }
    }
}

/// What [`ChangeTest::evaluate`] found.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ChangeEvidence {
    /// The cloud's noise along the surface normal, metres ([`cloud_noise_sigma`]).
    pub noise_sigma: f64,
    /// Largest local median of the signed distances in units of its deviation under "no
    /// change" (dimensionless).
    pub statistic: f64,
    /// `statistic` exceeds the threshold: the surface does not explain the cloud.
    pub significant: bool,
}

impl ChangeTest {
    /// Checks the settings.
    pub fn validate(&self) -> Result<(), String> {
        if self.neighbourhoods.is_empty() || self.neighbourhoods.iter().any(|&k| k < 3) {
            return Err(format!(
                "change test: neighbourhoods must be non-empty, each >= 3 points, got {:?}",
                self.neighbourhoods
            ));
        }
        if !(self.threshold.is_finite() && self.threshold > 0.0) {
            return Err(format!(
                "change test: threshold must be finite and > 0, got {}",
                self.threshold
            ));
        }
        Ok(())
    }

    /// The test for `cloud` (metres) whose points lie at the signed distances `signed` (m,
    /// one per point, along the surface's normal) from the surface compared with; `sigma`
    /// is the cloud's noise ([`cloud_noise_sigma`]). A cloud too small for the largest
    /// neighbourhood, a non-finite distance, or no noise estimate is always significant
    /// (registered).
    pub fn evaluate(&self, cloud: &IndexedPoints, signed: &[f64], sigma: f64) -> ChangeEvidence {
        self.evaluate_near(&self.neighbours(cloud), signed, sigma)
    }

    /// The nearest cloud points of each point of `cloud` (indices, nearest first, the point
    /// itself included), as many as the largest neighbourhood: what
    /// [`ChangeTest::evaluate_near`] needs, found once for several tests of one cloud.
    pub fn neighbours(&self, cloud: &IndexedPoints) -> Vec<Vec<usize>> {
        let k_max = self.k_max();
        if cloud.len() < k_max.max(3) {
            return Vec::new();
        }
        cloud
            .nearest_k_all(k_max)
            .into_iter()
            .map(|near| near.into_iter().map(|(j, _)| j).collect())
            .collect()
    }

    /// [`ChangeTest::evaluate`] with the neighbours `near` of each cloud point
    /// ([`ChangeTest::neighbours`]); significant when they do not match `signed`.
    pub fn evaluate_near(&self, near: &[Vec<usize>], signed: &[f64], sigma: f64) -> ChangeEvidence {
        let k_max = self.k_max();
        if near.len() < k_max.max(3)
            || signed.len() != near.len()
            || !lists_fit(near, signed.len(), k_max)
            || !testable(signed, sigma)
        {
            return ChangeEvidence::untestable(sigma);
        }
        let statistic = near
            .par_iter()
            .map_init(
                || Vec::with_capacity(k_max),
                |values: &mut Vec<f64>, list| {
                    let mut largest: f64 = 0.0;
                    for &k in &self.neighbourhoods {
                        values.clear();
                        values.extend(list.iter().take(k).map(|&j| signed[j]));
                        let m = median(values);
                        let deviation = MEDIAN_DEVIATION * sigma / (values.len() as f64).sqrt();
                        largest = largest.max(m.abs() / deviation);
                    }
                    largest
                },
            )
            .reduce(|| 0.0, f64::max);
        self.verdict(sigma, statistic)
    }

    /// The largest neighbourhood.
    fn k_max(&self) -> usize {
        self.neighbourhoods.iter().copied().max().unwrap_or(0)
    }

    /// The evidence for the largest normalised local median `statistic` of a cloud of noise
    /// `sigma` (m). A NaN statistic (no finite distance) counts as a change: the frame is
    /// registered.
    fn verdict(&self, sigma: f64, statistic: f64) -> ChangeEvidence {
        ChangeEvidence {
            noise_sigma: sigma,
            statistic,
            significant: statistic.is_nan() || statistic > self.threshold,
        }
    }
}

impl ChangeEvidence {
    /// What a test whose input cannot be tested reports: a change (the frame is registered).
    fn untestable(sigma: f64) -> Self {
        Self {
            noise_sigma: sigma,
            statistic: f64::INFINITY,
            significant: true,
        }
    }
}

/// Whether every list of `lists` (one per point) holds at least `k` indices, each below `len`.
fn lists_fit(lists: &[Vec<usize>], len: usize, k: usize) -> bool {
    lists
        .iter()
        .all(|n| n.len() >= k && n.iter().all(|&j| j < len))
}

/// Whether the distances `signed` (m) are all finite and the noise `sigma` (m) is positive.
fn testable(signed: &[f64], sigma: f64) -> bool {
    signed.iter().all(|d| d.is_finite()) && sigma > 0.0
}

impl ChangeTest {
    /// Has the surface moved between a reference cloud and this one? `signed`: this cloud's
    /// signed distances (m) to a surface; `reference_signed`: the reference cloud's to the
    /// SAME surface, so that what it does not explain in both cancels. For each point `i` of
    /// this cloud and each neighbourhood size `k`, the median of `signed` over its `k`
    /// nearest points of this cloud (`near[i]`, [`ChangeTest::neighbours`]) is compared with
    /// the median of `reference_signed` over its `k` nearest points of the reference cloud
    /// (`reference_near[i]`, nearest first): the same patch of surface seen twice. Under "no
    /// change" the difference is noise of standard deviation 1.2533 σ √(2 / k) (two
    /// independent clouds of noise `sigma`, m). The statistic is the largest difference in
    /// those units, significant above [`ChangeTest::threshold`]. A list too short or out of
    /// range, a distance that is not finite or no noise estimate counts as a change.
    pub fn evaluate_against(
        &self,
        near: &[Vec<usize>],
        signed: &[f64],
        reference_near: &[Vec<usize>],
        reference_signed: &[f64],
        sigma: f64,
    ) -> ChangeEvidence {
        let k_max = self.k_max();
        if near.len() < k_max.max(3)
            || signed.len() != near.len()
            || reference_near.len() != near.len()
            || !lists_fit(near, signed.len(), k_max)
            || !lists_fit(reference_near, reference_signed.len(), k_max)
            || !testable(signed, sigma)
            || !testable(reference_signed, sigma)
        {
            return ChangeEvidence::untestable(sigma);
        }
        let statistic = near
            .par_iter()
            .zip(reference_near)
            .map_init(
                || (Vec::with_capacity(k_max), Vec::with_capacity(k_max)),
                |(here, there): &mut (Vec<f64>, Vec<f64>), (list, reference_list)| {
                    let mut largest: f64 = 0.0;
                    for &k in &self.neighbourhoods {
                        here.clear();
                        here.extend(list.iter().take(k).map(|&j| signed[j]));
                        there.clear();
                        there.extend(reference_list.iter().take(k).map(|&j| reference_signed[j]));
                        let deviation = MEDIAN_DEVIATION * sigma * (2.0 / k as f64).sqrt();
                        let difference = median(here) - median(there);
                        largest = largest.max(difference.abs() / deviation);
                    }
                    largest
                },
            )
            .reduce(|| 0.0, f64::max);
        self.verdict(sigma, statistic)
    }

    /// For each point of `cloud` (m), its nearest points of `reference` (indices, nearest
    /// first), as many as the largest neighbourhood: the `reference_near` of
    /// [`ChangeTest::evaluate_against`].
    pub fn neighbours_in(
        &self,
        cloud: &[Point3<f64>],
        reference: &IndexedPoints,
    ) -> Vec<Vec<usize>> {
        let k_max = self.k_max();
        cloud
            .par_iter()
            .map(|p| {
                reference
                    .nearest_k(p, k_max)
                    .into_iter()
                    .map(|(j, _)| j)
                    .collect()
            })
            .collect()
    }
}

/// The noise of `cloud` (metres) along its surface's normal: at each point, a quadric
/// `z = a + b x + c y + d x² + e x y + f y²` is fitted by least squares to its
/// [`NOISE_NEIGHBOURS`] nearest points in their principal frame (z along the smallest
/// principal axis), and the residual variance is corrected for the 6 fitted parameters; the
/// result is the square root of the median over the points, corrected to a mean (the median
/// of a χ² with `n` degrees of freedom is about `n (1 − 2/(9n))³`). 0 when the cloud has fewer
/// than [`NOISE_NEIGHBOURS`] points.
pub fn cloud_noise_sigma(cloud: &IndexedPoints) -> f64 {
    cloud_noise_sigma_near(cloud, &[])
}

/// [`cloud_noise_sigma`] reusing neighbour lists already found (`near[i]`: the nearest points
/// of point `i`, nearest first, itself included, e.g. [`ChangeTest::neighbours`]) when each
/// holds at least [`NOISE_NEIGHBOURS`]; otherwise it searches the cloud itself. The same
/// number either way (the first neighbours of a longer list are the nearest ones).
pub fn cloud_noise_sigma_near(cloud: &IndexedPoints, near: &[Vec<usize>]) -> f64 {
    let k = NOISE_NEIGHBOURS;
    if cloud.len() < k {
        return 0.0;
    }
    let reuse = near.len() == cloud.len()
        && near
            .iter()
            .all(|n| n.len() >= k && n.iter().all(|&j| j < cloud.len()));
    let dof = (k - 6) as f64;
    let mut variances: Vec<f64> = cloud
        .points
        .par_iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let near: Vec<Point3<f64>> = if reuse {
                near[i][..k].iter().map(|&j| cloud.points[j]).collect()
            } else {
                cloud
                    .nearest_k(p, k)
                    .iter()
                    .map(|&(j, _)| cloud.points[j])
                    .collect()
            };
            quadric_residual(&near).map(|ss| ss / dof)
        })
        .collect();
    if variances.is_empty() {
        return 0.0;
    }
    let m = median(&mut variances);
    let median_factor = (1.0 - 2.0 / (9.0 * dof)).powi(3);
    (m / median_factor).sqrt()
}

/// Sum of squared residuals of the least-squares quadric through `points` in their principal
/// frame; `None` when the fit is singular.
fn quadric_residual(points: &[Point3<f64>]) -> Option<f64> {
    let n = points.len() as f64;
    let c = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
    let cov = points
        .iter()
        .map(|p| (p.coords - c) * (p.coords - c).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let eig = cov.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let (ex, ey, ez) = (
        eig.eigenvectors.column(order[0]).into_owned(),
        eig.eigenvectors.column(order[1]).into_owned(),
        eig.eigenvectors.column(order[2]).into_owned(),
    );
    let mut ata = SMatrix::<f64, 6, 6>::zeros();
    let mut atb = SVector::<f64, 6>::zeros();
    let local: Vec<(SVector<f64, 6>, f64)> = points
        .iter()
        .map(|p| {
            let d = p.coords - c;
            let (x, y, z) = (d.dot(&ex), d.dot(&ey), d.dot(&ez));
            (SVector::<f64, 6>::from([1.0, x, y, x * x, x * y, y * y]), z)
        })
        .collect();
    for (row, z) in &local {
        ata += row * row.transpose();
        atb += row * *z;
    }
    let coef = ata.cholesky()?.solve(&atb);
    Some(
        local
            .iter()
            .map(|(row, z)| (z - row.dot(&coef)).powi(2))
            .sum(),
    )
}

/// The median of `v` (reordered); NaN when empty.
fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    /// A 12 × 12 cm patch of a sphere of radius 8 cm (curved like a liver), 500 points, with
    /// normal noise `sigma`, and a Gaussian bump of `bump` metres (width 1.5 cm) at its
    /// centre; the signed distances to the sphere along its normal.
    fn patch(sigma: f64, bump: f64, seed: u64) -> (IndexedPoints, Vec<f64>) {
        let mut rng = Rng::new(seed);
        let r = 0.08;
        let mut pts = Vec::new();
        let mut signed = Vec::new();
        for _ in 0..500 {
            let (x, y) = (rng.uniform_in(-0.06, 0.06), rng.uniform_in(-0.06, 0.06));
            let n = Vector3::new(x, y, r).normalize();
            let h = bump * (-(x * x + y * y) / (2.0 * 0.015f64.powi(2))).exp();
            let p = Point3::from(n * r) + rng.gaussian_vector(sigma) + n * h;
            signed.push((p.coords.norm() - r).clamp(-1.0, 1.0));
            pts.push(p);
        }
        (IndexedPoints::new(pts).unwrap(), signed)
    }

    #[test]
    fn the_noise_is_measured_from_the_cloud_alone() {
        for sigma in [0.5e-3, 1.5e-3, 3e-3] {
            let (cloud, _) = patch(sigma, 0.0, 1);
            let s = cloud_noise_sigma(&cloud);
            // Isotropic noise σ per axis is σ along the normal; the fit sees it within 20 %.
            assert!((s / sigma - 1.0).abs() < 0.2, "σ {sigma}: measured {s}");
        }
    }

    /// The change test's neighbour lists give the estimator the same neighbours as its own
    /// search, so the same σ; lists too short (or none) fall back to the search.
    #[test]
    fn the_noise_from_the_change_tests_neighbours_is_the_noise() {
        for seed in 0..3 {
            let (cloud, _) = patch(1.5e-3, 0.0, 50 + seed);
            let own = cloud_noise_sigma(&cloud);
            let near = ChangeTest::default().neighbours(&cloud);
            assert_eq!(cloud_noise_sigma_near(&cloud, &near), own);
            let short = ChangeTest {
                neighbourhoods: vec![8],
                threshold: 5.0,
            }
            .neighbours(&cloud);
            assert_eq!(cloud_noise_sigma_near(&cloud, &short), own);
            assert_eq!(cloud_noise_sigma_near(&cloud, &[]), own);
        }
    }

    #[test]
    fn noise_alone_is_not_a_change_and_a_bump_of_twice_the_noise_is() {
        let test = ChangeTest::default();
        let (mut false_alarms, mut worst) = (0, 0.0f64);
        for seed in 0..20 {
            let (cloud, signed) = patch(1.5e-3, 0.0, seed);
            let e = test.evaluate(&cloud, &signed, cloud_noise_sigma(&cloud));
            worst = worst.max(e.statistic);
            false_alarms += usize::from(e.significant);
        }
        // Measured: 2.6–4.3 over these 20 clouds.
        assert_eq!(false_alarms, 0, "largest statistic {worst}");
        for seed in 0..5 {
            let (cloud, signed) = patch(1.5e-3, 3e-3, 100 + seed);
            let e = test.evaluate(&cloud, &signed, cloud_noise_sigma(&cloud));
            assert!(e.significant, "a 3 mm bump under 1.5 mm noise: {e:?}");
        }
    }

    /// [`ChangeTest::evaluate_against`] of a cloud against a reference cloud, both measured
    /// to the sphere without the bump.
    fn against(
        test: &ChangeTest,
        (cloud, signed): &(IndexedPoints, Vec<f64>),
        (reference, reference_signed): &(IndexedPoints, Vec<f64>),
    ) -> ChangeEvidence {
        let near = test.neighbours(cloud);
        let reference_near = test.neighbours_in(&cloud.points, reference);
        let sigma = cloud_noise_sigma(cloud);
        test.evaluate_against(&near, signed, &reference_near, reference_signed, sigma)
    }

    /// The surface the clouds are measured to lacks a 6 mm bump both clouds show (a dent the
    /// model did not follow): measured to it alone, every cloud is a change; against each
    /// other, two clouds of the same surface are not, and a bump grown by 5 mm is.
    #[test]
    fn what_the_surface_does_not_explain_in_both_clouds_cancels() {
        let test = ChangeTest::default();
        let (mut false_alarms, mut worst) = (0, 0.0f64);
        for seed in 0..20 {
            let reference = patch(1.5e-3, 6e-3, 200 + seed);
            let again = patch(1.5e-3, 6e-3, 300 + seed);
            let alone = test.evaluate(&again.0, &again.1, cloud_noise_sigma(&again.0));
            assert!(alone.significant, "the bump alone: {alone:?}");
            let e = against(&test, &again, &reference);
            worst = worst.max(e.statistic);
            false_alarms += usize::from(e.significant);
        }
        // Measured: 2.9–4.8 over these 20 pairs (11–16 for each cloud alone): the bump's slope
        // between the two clouds' samples, a 6 mm rise over 1.5 cm, adds to the noise.
        assert_eq!(false_alarms, 0, "largest statistic {worst}");
        // Measured: 7.5–14.2.
        for seed in 0..5 {
            let reference = patch(1.5e-3, 6e-3, 400 + seed);
            let grown = patch(1.5e-3, 11e-3, 500 + seed);
            let e = against(&test, &grown, &reference);
            assert!(
                e.significant,
                "the bump grown by 5 mm under 1.5 mm noise: {e:?}"
            );
        }
        // Lists that do not fit the clouds are a change, never a panic; a cloud against itself
        // is none.
        let (cloud, signed) = patch(1.5e-3, 0.0, 1);
        let near = test.neighbours(&cloud);
        let e = |reference_near: &[Vec<usize>], reference: &[f64]| {
            test.evaluate_against(&near, &signed, reference_near, reference, 1.5e-3)
        };
        assert!(e(&near[..10], &signed).significant);
        assert!(e(&near, &signed[..10]).significant);
        assert_eq!(e(&near, &signed).statistic, 0.0);
    }

    #[test]
    fn settings_out_of_range_are_named() {
        let bad = ChangeTest {
            neighbourhoods: vec![2],
            ..ChangeTest::default()
        };
        assert!(bad.validate().unwrap_err().contains("neighbourhoods"));
        let bad = ChangeTest {
            threshold: f64::NAN,
            ..ChangeTest::default()
        };
        assert!(bad.validate().unwrap_err().contains("threshold"));
    }
}
