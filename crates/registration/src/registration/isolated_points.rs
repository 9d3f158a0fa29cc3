//! Removal of isolated cloud points before registration (statistical outlier removal on the
//! cloud alone, as in point-cloud libraries' "statistical outlier removal"): a point whose
//! mean distance to its nearest neighbours is far above the cloud's typical spacing lies
//! away from any sampled surface (a reflection, a smoke particle, a mismatched stereo pixel).
//!
//! It needs no model, so it cannot mistake a real local deformation (a lifted lobe, still a
//! densely sampled surface) for an outlier, which is why the non-rigid stage cannot simply
//! prune its pairs with median/MAD (docs/scene.md, `registration.robust_pruning`). It keeps
//! outliers within about one spacing of the surface; those pull little. Lengths in metres.

use rayon::prelude::*;

use super::correspondences::{robust_threshold, IndexedPoints};

/// Neighbours whose mean distance measures a point's spacing.
pub(crate) const ISOLATION_NEIGHBOURS: usize = 8;

/// A point is isolated when its spacing exceeds median + this × 1.4826 MAD of all spacings …
pub(crate) const ISOLATION_SIGMA: f64 = 3.0;

/// … and also this multiple of the median spacing: a cloud whose density varies (a camera
/// sees far surfaces sparser) keeps its sparse parts unless they are this much sparser than
/// the typical point.
pub(crate) const ISOLATION_MEDIAN_FACTOR: f64 = 2.5;

/// Mean distance of every point to its `k` nearest other points, metres (0 for a cloud with
/// a single point).
pub fn neighbour_spacing(cloud: &IndexedPoints, k: usize) -> Vec<f64> {
    cloud
        .points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let nn = cloud.nearest_k(p, k + 1);
            let others: Vec<f64> = nn.iter().filter(|n| n.0 != i).map(|n| n.1).collect();
            if others.is_empty() {
                0.0
            } else {
                others.iter().sum::<f64>() / others.len() as f64
            }
        })
        .collect()
}

/// Which points of `cloud` are isolated: their [`neighbour_spacing`] (over `k` neighbours)
/// exceeds both median + `sigma` × 1.4826 MAD of the spacings and `median_factor` × their
/// median. Clouds of fewer than `k + 2` points are left whole (no statistics to judge by).
pub fn isolated_mask(cloud: &IndexedPoints, k: usize, sigma: f64, median_factor: f64) -> Vec<bool> {
    if cloud.len() < k + 2 {
        return vec![false; cloud.len()];
    }
    let spacing = neighbour_spacing(cloud, k);
    let mut sorted = spacing.clone();
    let (_, median, _) = sorted.select_nth_unstable_by(spacing.len() / 2, f64::total_cmp);
    let limit = robust_threshold(&spacing, sigma).max(median_factor * *median);
    spacing.iter().map(|&s| s > limit).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;
    use nalgebra::Point3;

    /// A 20 × 20 cm plate sampled every 5 mm (a surface at ~4 samples/cm²), with a gentle
    /// density change along x (spacing 4 mm at one edge, 6.5 mm at the other) like a camera's
    /// falloff with depth.
    fn plate() -> Vec<Point3<f64>> {
        let mut points = Vec::new();
        let mut x: f64 = 0.0;
        while x < 0.2 {
            let step = 0.004 + 0.0025 * x / 0.2;
            let mut y = 0.0;
            while y < 0.2 {
                points.push(Point3::new(x, y, 0.001 * (40.0 * x).sin()));
                y += step;
            }
            x += step;
        }
        points
    }

    #[test]
    fn far_outliers_go_and_the_surface_stays() {
        let surface = plate();
        let n = surface.len();
        // 30 % of the final cloud uniform in a box 3 cm beyond the plate's sides and 5 cm
        // above and below it (outliers ~2 cm apart).
        let outliers = (n as f64 * 0.3 / 0.7).round() as usize;
        let mut rng = Rng::new(7);
        let mut points = surface.clone();
        for _ in 0..outliers {
            points.push(Point3::new(
                rng.uniform_in(-0.03, 0.23),
                rng.uniform_in(-0.03, 0.23),
                rng.uniform_in(-0.05, 0.05),
            ));
        }
        let cloud = IndexedPoints::new(points.clone()).unwrap();
        let mask = isolated_mask(
            &cloud,
            ISOLATION_NEIGHBOURS,
            ISOLATION_SIGMA,
            ISOLATION_MEDIAN_FACTOR,
        );
        let surface_lost = mask[..n].iter().filter(|&&m| m).count();
        assert_eq!(surface_lost, 0, "surface points removed");
        // An outlier farther than 2 cm from the plate has no surface point among its
        // neighbours: most must go (6 % stay here: those with outlier neighbours as close
        // as 2.5 × the plate's spacing; denser background noise is not "isolated").
        let far: Vec<usize> = (n..points.len())
            .filter(|&i| points[i].z.abs() > 0.02)
            .collect();
        assert!(far.len() > 200, "{} far outliers", far.len());
        let far_kept = far.iter().filter(|&&i| !mask[i]).count();
        assert!(
            far_kept * 100 <= 12 * far.len(),
            "{far_kept} of {} far outliers kept",
            far.len()
        );
        // Those within 5 mm of the plate are as close as its own noise would put samples:
        // most of them stay.
        let near: Vec<usize> = (n..points.len())
            .filter(|&i| points[i].z.abs() < 0.005 && (0.0..0.2).contains(&points[i].x))
            .filter(|&i| (0.0..0.2).contains(&points[i].y))
            .collect();
        let near_kept = near.iter().filter(|&&i| !mask[i]).count();
        assert!(
            near_kept * 2 >= near.len(),
            "{near_kept} of {} kept",
            near.len()
        );
    }

    #[test]
    fn a_clean_cloud_and_a_tiny_one_are_left_whole() {
        let cloud = IndexedPoints::new(plate()).unwrap();
        let mask = isolated_mask(&cloud, 8, 3.0, 2.5);
        assert!(mask.iter().all(|&m| !m));
        let tiny = IndexedPoints::new(vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0)]).unwrap();
        assert_eq!(isolated_mask(&tiny, 8, 3.0, 2.5), vec![false, false]);
        // The spacing of a regular row is its step.
        let row =
            IndexedPoints::new((0..10).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect()).unwrap();
        let s = neighbour_spacing(&row, 2);
        assert!(
            (s[5] - 1.0).abs() < 1e-12 && (s[0] - 1.5).abs() < 1e-12,
            "{s:?}"
        );
    }
}
