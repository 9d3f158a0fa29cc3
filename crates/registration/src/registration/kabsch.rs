//! Weighted least-squares rigid fit of paired points (Kabsch / Umeyama without scale).

use nalgebra::{Matrix3, Point3, Vector3};

use crate::registration::RigidTransform;

/// Ratio of the second to the largest singular value of the weighted cross-covariance below
/// which the pairs are treated as degenerate (collinear or coincident): the rotation about the
/// line would be undetermined.
pub const DEGENERACY_RATIO: f64 = 1e-9;

/// The proper rigid motion `T` minimising `Σ wᵢ |T(sourceᵢ) − targetᵢ|²` (SVD of the weighted
/// cross-covariance, with the reflection fix so that `det R = +1`). Lengths in metres.
///
/// `weights` (optional; all 1 when `None`) must have one finite, non-negative entry per pair
/// with a positive sum. Returns `None`, never panicking, when the slices differ in length, there
/// are fewer than 3 pairs (or fewer than 3 with positive weight), a value is non-finite, or the
/// points are degenerate (coincident or collinear; see [`DEGENERACY_RATIO`]).
pub fn kabsch(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    weights: Option<&[f64]>,
) -> Option<RigidTransform> {
    let n = source.len();
    if n != target.len() || n < 3 {
        return None;
    }
    let weight = |i: usize| weights.map_or(1.0, |w| w[i]);
    if let Some(w) = weights {
        if w.len() != n || w.iter().any(|x| !x.is_finite() || *x < 0.0) {
            return None;
        }
        if w.iter().filter(|x| **x > 0.0).count() < 3 {
            return None;
        }
    }
    let mut total = 0.0;
    let mut cs = Vector3::zeros();
    let mut ct = Vector3::zeros();
    for i in 0..n {
        let w = weight(i);
        total += w;
        cs += w * source[i].coords;
        ct += w * target[i].coords;
    }
    if total.is_nan() || total <= 0.0 {
        return None;
    }
    cs /= total;
    ct /= total;
    let mut h = Matrix3::zeros();
    for i in 0..n {
        let w = weight(i);
        if w > 0.0 {
            h += w * (source[i].coords - cs) * (target[i].coords - ct).transpose();
        }
    }
    if h.iter().any(|x| !x.is_finite()) || !cs.iter().chain(ct.iter()).all(|x| x.is_finite()) {
        return None;
    }
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut sv = svd.singular_values.as_slice().to_vec();
    sv.sort_by(|a, b| b.total_cmp(a));
    if sv[0].is_nan() || sv[0] <= 0.0 || sv[1] <= DEGENERACY_RATIO * sv[0] {
        return None;
    }
    // H = U Σ Vᵀ; R = V diag(1, 1, d) Uᵀ with d = sign(det(V Uᵀ)) so that det R = +1. The sign
    // flip goes on the smallest singular value's column (nalgebra does not sort them).
    let v = v_t.transpose();
    let mut d = Matrix3::identity();
    if (v * u.transpose()).determinant() < 0.0 {
        let smallest = svd.singular_values.imin();
        d[(smallest, smallest)] = -1.0;
    }
    let r = v * d * u.transpose();
    let mut rotation = nalgebra::Rotation3::from_matrix_unchecked(r);
    rotation.renormalize();
    let translation = ct - rotation * cs;
    let t = RigidTransform::new(rotation, translation);
    t.is_finite().then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registration::test_support::Rng;
    use nalgebra::{Rotation3, Unit};

    fn random_points(rng: &mut Rng, n: usize) -> Vec<Point3<f64>> {
        (0..n)
            .map(|_| {
                Point3::new(
                    rng.uniform_in(-0.1, 0.1),
                    rng.uniform_in(-0.1, 0.1),
                    rng.uniform_in(-0.1, 0.1),
                )
            })
            .collect()
    }

    fn truth() -> RigidTransform {
        RigidTransform::new(
            Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(0.3, 1.0, -0.4)), 2.5),
            Vector3::new(0.04, -0.03, 0.02),
        )
    }

    #[test]
    fn recovers_exact_transform() {
        let mut rng = Rng::new(1);
        let t = truth();
        for n in [3, 4, 50] {
            let src = random_points(&mut rng, n);
            let dst = t.apply_all(&src);
            let fit = kabsch(&src, &dst, None).unwrap();
            assert!(fit.rotation_angle_to(&t) < 1e-12, "n = {n}");
            assert!(fit.translation_distance_to(&t) < 1e-12, "n = {n}");
            assert!((fit.rotation.matrix().determinant() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn weights_select_the_consistent_pairs() {
        let mut rng = Rng::new(2);
        let t = truth();
        let src = random_points(&mut rng, 40);
        let mut dst = t.apply_all(&src);
        // Corrupt the last 10 pairs; zero weight must ignore them exactly.
        for p in dst.iter_mut().skip(30) {
            p.x += 0.05;
        }
        let mut w = vec![1.0; 40];
        w[30..].iter_mut().for_each(|x| *x = 0.0);
        // Uneven positive weights on the good pairs do not matter for exact data.
        w[..30]
            .iter_mut()
            .enumerate()
            .for_each(|(i, x)| *x = 0.5 + i as f64);
        let fit = kabsch(&src, &dst, Some(&w)).unwrap();
        assert!(fit.rotation_angle_to(&t) < 1e-12 && fit.translation_distance_to(&t) < 1e-12);
        // Unweighted, the corruption shows.
        let plain = kabsch(&src, &dst, None).unwrap();
        assert!(plain.translation_distance_to(&t) > 1e-3);
    }

    #[test]
    fn weighted_fit_matches_duplicated_pairs() {
        // Integer weight k ≡ the pair repeated k times.
        let mut rng = Rng::new(3);
        let src = random_points(&mut rng, 12);
        let dst: Vec<_> = random_points(&mut rng, 12);
        let w: Vec<f64> = (0..12).map(|i| (i % 3 + 1) as f64).collect();
        let (mut s2, mut d2) = (Vec::new(), Vec::new());
        for i in 0..12 {
            for _ in 0..(i % 3 + 1) {
                s2.push(src[i]);
                d2.push(dst[i]);
            }
        }
        let a = kabsch(&src, &dst, Some(&w)).unwrap();
        let b = kabsch(&s2, &d2, None).unwrap();
        assert!(a.rotation_angle_to(&b) < 1e-12 && a.translation_distance_to(&b) < 1e-12);
    }

    #[test]
    fn handles_reflection_case() {
        // Noisy planar data can make the unconstrained optimum a reflection; the fit stays proper.
        let mut rng = Rng::new(4);
        let src: Vec<_> = (0..20)
            .map(|_| Point3::new(rng.uniform_in(-1.0, 1.0), rng.uniform_in(-1.0, 1.0), 0.0))
            .collect();
        let dst: Vec<_> = src
            .iter()
            .map(|p| Point3::new(-p.x, p.y, 1e-3 * p.x))
            .collect();
        let fit = kabsch(&src, &dst, None).unwrap();
        assert!((fit.rotation.matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn rejects_degenerate_input() {
        let p = |x: f64, y: f64, z: f64| Point3::new(x, y, z);
        let two = [p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0)];
        assert!(kabsch(&two, &two, None).is_none());
        let line: Vec<_> = (0..10).map(|i| p(i as f64, 2.0 * i as f64, 0.0)).collect();
        assert!(kabsch(&line, &line, None).is_none(), "collinear");
        let same = vec![p(1.0, 2.0, 3.0); 5];
        assert!(kabsch(&same, &same, None).is_none(), "coincident");
        let tri = [p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0), p(0.0, 1.0, 0.0)];
        assert!(
            kabsch(&tri, &tri, None).is_some(),
            "3 non-collinear points suffice"
        );
        assert!(kabsch(&tri, &tri[..2], None).is_none(), "length mismatch");
        assert!(
            kabsch(&tri, &tri, Some(&[1.0, 1.0])).is_none(),
            "weight count"
        );
        assert!(
            kabsch(&tri, &tri, Some(&[1.0, -1.0, 1.0])).is_none(),
            "negative weight"
        );
        assert!(
            kabsch(&tri, &tri, Some(&[1.0, 0.0, 1.0])).is_none(),
            "two weighted pairs"
        );
        let mut nan = tri;
        nan[1].y = f64::NAN;
        assert!(kabsch(&nan, &tri, None).is_none(), "NaN");
    }
}
