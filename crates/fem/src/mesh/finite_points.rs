//! Finiteness of points: the check every input path (mesh and point files, clouds, frames,
//! model surfaces) makes before geometry sees a point, so that a NaN or ±∞ coordinate is
//! refused with its index instead of reaching the numerics.

use nalgebra::Point3;

/// Whether every coordinate of `p` is finite (neither NaN nor ±∞).
pub fn is_finite_point(p: &Point3<f64>) -> bool {
    p.iter().all(|c| c.is_finite())
}

/// The index of the first point of `points` with a non-finite coordinate; `None` when all
/// are finite.
pub fn first_non_finite_point(points: &[Point3<f64>]) -> Option<usize> {
    points.iter().position(|p| !is_finite_point(p))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nan_and_infinities_are_not_finite_and_the_first_is_named() {
        assert!(is_finite_point(&Point3::new(0.0, 1.0, -2.0)));
        assert!(is_finite_point(&Point3::new(
            f64::MAX,
            f64::MIN_POSITIVE,
            -0.0
        )));
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert!(!is_finite_point(&Point3::new(0.0, bad, 0.0)));
            assert!(!is_finite_point(&Point3::new(bad, 0.0, 0.0)));
            assert!(!is_finite_point(&Point3::new(0.0, 0.0, bad)));
        }
        let points = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, f64::NAN, 0.0),
            Point3::new(f64::INFINITY, 0.0, 0.0),
        ];
        assert_eq!(first_non_finite_point(&points), Some(1));
        assert_eq!(first_non_finite_point(&points[..1]), None);
        assert_eq!(first_non_finite_point(&[]), None);
    }
}
