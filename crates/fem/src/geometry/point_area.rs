//! The surface area each point of a set stands for, when the set samples a surface (a
//! ligament given as the vertices it covers, picked points): a `k`-nearest-neighbour density
//! estimate on the surface, `Aᵢ = π dₖ(i)² / k`, with `dₖ(i)` the distance from point `i` to
//! its `k`-th nearest other point and `k` = [`AREA_NEIGHBOURS`] (fewer when the set is
//! smaller). A disc of radius `dₖ` around the point holds `k` other points, so each stands for
//! `1/k` of it.
//!
//! Points on the set's rim have neighbours on one side only and stand for more than their
//! share: on the tetrahedral meshes' ligament discs of `fixtures/liver_force` (70–110
//! vertices, 4,000–5,100 mm² by their triangles' areas) the estimate sums to 1.23–1.27 times
//! the vertices' own area (one third of each incident triangle). The bias is the same on
//! every disc, so a stiffness per unit area built on it scales with the disc alike.
//! Lengths in the points' units, areas in their square.

use nalgebra::Point3;

use super::neighbour_grid::{MAX_CELLS_PER_POINT, MIN_CELLS};
use super::NeighbourGrid;

/// Neighbours the density estimate counts (`k`): six, the ring around a vertex of an even
/// triangulation.
pub const AREA_NEIGHBOURS: usize = 6;

/// The area (square of the points' unit) each of `points` stands for: `π dₖ² / k`, `k` =
/// [`AREA_NEIGHBOURS`] or the number of other points if fewer. `None` when the set has fewer
/// than two distinct points (no spacing to estimate an area from) or a coordinate is not
/// finite. A point that coincides with `k` others stands for no area.
pub fn area_per_point(points: &[Point3<f64>]) -> Option<Vec<f64>> {
    if points.len() < 2
        || points
            .iter()
            .any(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return None;
    }
    let k = AREA_NEIGHBOURS.min(points.len() - 1);
    let (lo, hi) = points
        .iter()
        .fold((points[0], points[0]), |(lo, hi), p| (lo.inf(p), hi.sup(p)));
    let extent = (hi - lo).max();
    if extent <= 0.0 {
        return None;
    }
    // Cells about the spacing of points spread evenly over a surface as large as the set's
    // box, but no more of them than the neighbour grid allows (a dense set spans few cells
    // more than a sparse one); the pairwise scan below only serves a set the grid refuses.
    let n = points.len() as f64;
    let spacing = (extent * extent / n).sqrt();
    let most_cells = (MAX_CELLS_PER_POINT as f64 * n + MIN_CELLS as f64).cbrt() - 1.0;
    let cell = spacing.max(extent / most_cells.max(1.0));
    let nearest: Vec<f64> = match NeighbourGrid::new(points, cell) {
        Some(grid) => {
            let mut scratch = Vec::new();
            (0..points.len())
                .map(|i| kth_distance(&grid.k_nearest_of(i, k + 1, &mut scratch)))
                .collect()
        }
        None => points
            .iter()
            .map(|p| {
                let mut d: Vec<f64> = points.iter().map(|q| (q - p).norm()).collect();
                d.sort_by(f64::total_cmp);
                d[k]
            })
            .collect(),
    };
    Some(
        nearest
            .into_iter()
            .map(|d| std::f64::consts::PI * d * d / k as f64)
            .collect(),
    )
}

/// The distance to the last of a point's nearest (the point itself first).
fn kth_distance(nearest: &[(usize, f64)]) -> f64 {
    nearest.last().map_or(0.0, |&(_, d)| d)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points of an even triangular lattice of spacing `s` (each vertex has six neighbours at
    /// `s`, the next six at `√3 s`) stand for `π s² / 6` each away from the rim, against the
    /// lattice's own `(√3 / 2) s²` per vertex: 0.60 of it. On a square lattice of spacing `s`
    /// (four at `s`, four at `√2 s`), `π 2 s² / 6` against `s²`: 1.05.
    #[test]
    fn an_even_lattice_stands_for_its_spacing_squared() {
        let s = 0.7;
        let mut tri = Vec::new();
        let mut square = Vec::new();
        for i in 0..21 {
            for j in 0..21 {
                let x = i as f64 * s + if j % 2 == 1 { 0.5 * s } else { 0.0 };
                tri.push(Point3::new(x, j as f64 * s * 3f64.sqrt() / 2.0, 1.0));
                square.push(Point3::new(i as f64 * s, 2.0, j as f64 * s));
            }
        }
        let centre = 10 * 21 + 10;
        let a = area_per_point(&tri).unwrap();
        let expected = std::f64::consts::PI * s * s / 6.0;
        assert!(
            (a[centre] - expected).abs() < 1e-12 * expected,
            "{}",
            a[centre]
        );
        let a = area_per_point(&square).unwrap();
        let expected = std::f64::consts::PI * 2.0 * s * s / 6.0;
        assert!(
            (a[centre] - expected).abs() < 1e-12 * expected,
            "{}",
            a[centre]
        );
        // The total grows with the set's area: a lattice four times as large stands for
        // about four times the area (rim points aside).
        let sum_small: f64 = area_per_point(&square[..21 * 10]).unwrap().iter().sum();
        let sum_large: f64 = area_per_point(&square).unwrap().iter().sum();
        assert!(sum_large > 1.8 * sum_small, "{sum_small} {sum_large}");
    }

    /// Uniform random points on a unit square: the estimate's sum is close to the square's
    /// area (the rim adds a little), whatever the number of points.
    #[test]
    fn random_points_on_a_square_sum_to_about_its_area() {
        let mut rng = crate::random::Rng::new(7);
        for n in [200, 2000] {
            let pts: Vec<Point3<f64>> = (0..n)
                .map(|_| Point3::new(rng.uniform(), rng.uniform(), 0.0))
                .collect();
            let total: f64 = area_per_point(&pts).unwrap().iter().sum();
            assert!((0.9..1.5).contains(&total), "n = {n}: {total}");
        }
    }

    /// A dense set (a 150 × 150 lattice, 22,500 points, far more cells at its own spacing than
    /// the neighbour grid allows) is answered on the grid, as the pairwise scan would: the same
    /// areas as a small patch of the same lattice away from the rim.
    #[test]
    fn a_dense_set_has_the_areas_of_its_spacing() {
        let s = 0.1;
        let dense: Vec<Point3<f64>> = (0..150)
            .flat_map(|i| (0..150).map(move |j| Point3::new(i as f64 * s, j as f64 * s, 0.3)))
            .collect();
        let a = area_per_point(&dense).unwrap();
        let expected = std::f64::consts::PI * 2.0 * s * s / 6.0;
        let centre = 75 * 150 + 75;
        assert!(
            (a[centre] - expected).abs() < 1e-9 * expected,
            "{}",
            a[centre]
        );
    }

    #[test]
    fn too_few_or_degenerate_points_have_no_area() {
        assert!(area_per_point(&[]).is_none());
        assert!(area_per_point(&[Point3::origin()]).is_none());
        assert!(area_per_point(&[Point3::origin(), Point3::origin()]).is_none());
        assert!(area_per_point(&[Point3::origin(), Point3::new(f64::NAN, 0.0, 0.0)]).is_none());
        let two = area_per_point(&[Point3::origin(), Point3::new(0.0, 2.0, 0.0)]).unwrap();
        assert_eq!(two, vec![4.0 * std::f64::consts::PI; 2]);
    }
}
