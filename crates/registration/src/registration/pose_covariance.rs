//! How well a cloud determines the rigid pose: the covariance of a point-to-plane rigid fit
//! under its own residual noise, and the displacement of the model it implies.
//!
//! At the converged pose, the linearised point-to-plane least squares of rigid ICP
//! ([`RigidIcp`](super::RigidIcp)) is `min Σ_i (a_iᵀ ξ + r_i)²` with `ξ = (ω, t)` a small
//! rotation about the pairs' centroid `c` and a translation (model frame, metres), `p_i` a
//! cloud point moved onto the model, `n_i` the model normal at its closest point and
//! `a_i = ((p_i − c) × n_i, n_i)`. With independent normal residuals of variance `σ²`
//! (estimated as `Σ r_i² / (m − 6)` over the `m` kept pairs), the estimate's covariance is
//!
//! `C = σ² (Σ_i a_i a_iᵀ)⁻¹` (6 × 6; rad² and m²),
//!
//! the Gauss–Markov covariance of linear least squares. A model point `x` then moves by
//! `δx = ω × (x − c) + t = J(x) ξ`, `J(x) = [−[x − c]×, I]`, with mean squared length
//! `tr(J C Jᵀ)`. A patch that is nearly flat or nearly a surface of revolution leaves a
//! direction of `ξ` almost unseen, and `C` says so: on the tool-indentation class's 15 %
//! patches (500 points, 1.5 mm noise per axis) the rotation's 1σ is 1.6–2.5°, as large as the
//! pose errors measured there (1–4°; docs/pose.md#limits).
//!
//! What it leaves out: a residual that is not noise (a deformation the rigid fit cannot
//! follow, a systematic bias) and a wrong pose basin (flag `pose_ambiguous`); it is the noise's
//! share only, a lower bound on the pose's error.

use nalgebra::{Matrix3, Matrix6, Point3, Vector3, Vector6};

/// Covariance of a rigid pose fitted by point-to-plane pairs (module doc): rotation about
/// `centre` and translation, model frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseCovariance {
    /// The centroid of the pairs the rotation is about, model frame, m.
    pub centre: Point3<f64>,
    /// `C` over `(ω, t)`: rad², rad·m, m².
    pub matrix: Matrix6<f64>,
    /// The normal residual's standard deviation `σ`, m.
    pub sigma: f64,
}

impl PoseCovariance {
    /// The covariance of the fit whose kept pairs are cloud points `moved` onto the model (model
    /// frame, m), their closest model points `closest` and unit model normals `normals` there.
    /// `None` with fewer than 7 pairs with a normal, or normal equations that cannot be
    /// inverted (a plane, a sphere: some motion is not seen at all).
    pub fn from_pairs(
        moved: &[Point3<f64>],
        closest: &[Point3<f64>],
        normals: &[Vector3<f64>],
    ) -> Option<Self> {
        let kept: Vec<usize> = (0..moved.len())
            .filter(|&i| normals[i] != Vector3::zeros())
            .collect();
        let m = kept.len();
        if m < 7 {
            return None;
        }
        let centre =
            Point3::from(kept.iter().map(|&i| moved[i].coords).sum::<Vector3<f64>>() / m as f64);
        let mut information = Matrix6::zeros();
        let mut squares = 0.0;
        for &i in &kept {
            let n = normals[i];
            let arm = (moved[i] - centre).cross(&n);
            let a = Vector6::new(arm.x, arm.y, arm.z, n.x, n.y, n.z);
            information += a * a.transpose();
            squares += (moved[i] - closest[i]).dot(&n).powi(2);
        }
        let variance = squares / (m - 6) as f64;
        let eigen = information.symmetric_eigen();
        let (lo, hi) = (eigen.eigenvalues.min(), eigen.eigenvalues.max());
        if !(hi.is_finite() && hi > 0.0 && lo > 1e-12 * hi) {
            return None;
        }
        let matrix = information.try_inverse()? * variance;
        matrix.iter().all(|v| v.is_finite()).then_some(Self {
            centre,
            matrix,
            sigma: variance.sqrt(),
        })
    }

    /// The root mean square length (m) of the displacement of model point `x` (model frame,
    /// m) that the pose's uncertainty implies: `√tr(J(x) C J(x)ᵀ)` (module doc).
    pub fn displacement_std(&self, x: &Point3<f64>) -> f64 {
        let r = x - self.centre;
        let skew = -r.cross_matrix();
        let rr: Matrix3<f64> = self.matrix.fixed_view::<3, 3>(0, 0).into_owned();
        let rt: Matrix3<f64> = self.matrix.fixed_view::<3, 3>(0, 3).into_owned();
        let tt: Matrix3<f64> = self.matrix.fixed_view::<3, 3>(3, 3).into_owned();
        let trace = (skew * rr * skew.transpose()).trace() + 2.0 * (skew * rt).trace() + tt.trace();
        trace.max(0.0).sqrt()
    }

    /// The root mean square over `points` (model frame, m) of [`Self::displacement_std`], m:
    /// the model's 1σ misplacement from the pose alone.
    pub fn rms_displacement_std(&self, points: &[Point3<f64>]) -> f64 {
        if points.is_empty() {
            return 0.0;
        }
        let sum: f64 = points
            .iter()
            .map(|p| self.displacement_std(p).powi(2))
            .sum();
        (sum / points.len() as f64).sqrt()
    }

    /// The 1σ of the rotation about its worst-determined axis, radians.
    pub fn rotation_std(&self) -> f64 {
        let rr: Matrix3<f64> = self.matrix.fixed_view::<3, 3>(0, 0).into_owned();
        rr.symmetric_eigen().eigenvalues.max().max(0.0).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::icosphere;
    use crate::random::Rng;
    use crate::registration::{ModelTarget, RigidIcp};

    #[test]
    fn the_predicted_spread_matches_the_spread_of_repeated_fits() {
        // An ellipsoid (8 × 5.6 × 4 cm, 1,280 triangles) and a cap of it within 35 mm of the end
        // of its long axis: curved, but its rotations about the axis barely seen. The same
        // 300 surface points, with fresh 1.5 mm noise per axis 150 times, fitted from the true
        // pose. The model's misplacement over the fits (root mean square over trials and
        // vertices of |T⁻¹x − x|) against the covariance each fit predicts (the root mean
        // square of the fits' predictions): the Gauss–Markov covariance of the linearised
        // fit, so the two agree to the sampling error of 150 trials and the linearisation.
        let mut surface = icosphere(Point3::origin(), 1.0, 3);
        surface
            .vertices
            .iter_mut()
            .for_each(|v| *v = Point3::new(0.08 * v.x, 0.056 * v.y, 0.04 * v.z));
        let target = ModelTarget::new(&surface, 0.002).unwrap();
        let tip = Point3::new(0.08, 0.0, 0.0);
        let mut rng = Rng::new(7);
        // Points on the triangles themselves, so that the true pose fits them exactly.
        let mut patch = Vec::new();
        while patch.len() < 300 {
            let t = surface.triangles[rng.below(surface.triangles.len())];
            let (a, b) = (rng.uniform(), rng.uniform());
            let (a, b) = if a + b > 1.0 {
                (1.0 - a, 1.0 - b)
            } else {
                (a, b)
            };
            let [p, q, r] = t.map(|v| surface.vertices[v].coords);
            let on = Point3::from(p + (q - p) * a + (r - p) * b);
            if (on - tip).norm() < 0.035 {
                patch.push(on);
            }
        }
        let icp = RigidIcp::default();
        let (mut observed, mut predicted, mut rotation) = (0.0, 0.0, 0.0);
        let trials = 150;
        for _ in 0..trials {
            let cloud: Vec<_> = patch
                .iter()
                .map(|p| p + rng.gaussian_vector(0.0015))
                .collect();
            let fit = icp.register(&target, &cloud, None).unwrap();
            let c = fit.covariance.expect("a curved patch determines the pose");
            let moved = fit.model_to_cloud;
            observed += surface
                .vertices
                .iter()
                .map(|x| (moved.apply(x) - x).norm_squared())
                .sum::<f64>()
                / surface.vertices.len() as f64;
            predicted += c.rms_displacement_std(&surface.vertices).powi(2);
            rotation += c.rotation_std().to_degrees();
        }
        let observed = (observed / trials as f64).sqrt();
        let predicted = (predicted / trials as f64).sqrt();
        let ratio = predicted / observed;
        println!(
            "model misplacement over {trials} fits: {:.3} mm observed, {:.3} mm predicted (ratio {ratio:.2}); rotation 1σ {:.2}°",
            observed * 1e3,
            predicted * 1e3,
            rotation / trials as f64
        );
        assert!(
            observed > 2e-4,
            "the patch leaves the pose uncertain: {observed}"
        );
        assert!((0.5..1.0).contains(&ratio), "ratio {ratio:.2}");
    }

    #[test]
    fn a_plane_leaves_the_pose_undetermined() {
        let moved: Vec<Point3<f64>> = (0..50)
            .map(|i| Point3::new((i % 7) as f64 * 0.01, (i / 7) as f64 * 0.01, 0.0))
            .collect();
        let normals = vec![Vector3::z(); moved.len()];
        assert!(PoseCovariance::from_pairs(&moved, &moved, &normals).is_none());
        assert!(PoseCovariance::from_pairs(&moved[..6], &moved[..6], &normals[..6]).is_none());
    }
}
