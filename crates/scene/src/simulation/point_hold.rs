//! The default hold of a surface given as points (a ligament given as the vertices it
//! covers, picked points): a layer of tissue half a cell thick, a spring of `β E A / h` per
//! point ([`point_hold_stiffness`], β = [`DEFAULT_POINT_HOLD_FACTOR`]), with A the surface
//! area the point stands for ([`area_per_point`]).
//!
//! The area is a `k`-nearest-neighbour density estimate on the surface, `Aᵢ = π dₖ(i)² / k`,
//! with `dₖ(i)` the distance from point `i` to its `k`-th nearest other point and `k` =
//! [`AREA_NEIGHBOURS`] (fewer when the set is smaller): a disc of radius `dₖ` around the point
//! holds `k` other points, so each stands for `1/k` of it. Points on the set's rim have
//! neighbours on one side only and stand for more than their share: on the tetrahedral
//! meshes' ligament discs of `fixtures/liver_force` (70–110 vertices, 4,000–5,100 mm² by their
//! triangles' areas) the estimate sums to 1.23–1.27 times the vertices' own area (one third of
//! each incident triangle). The bias is the same on every disc, so a stiffness per unit area
//! built on it scales with the disc alike.

use nalgebra::Point3;

use crate::registration::IndexedPoints;
use livereg_registration::DEFAULT_POINT_HOLD_FACTOR;

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
        || points.iter().all(|p| *p == points[0])
    {
        return None;
    }
    let k = AREA_NEIGHBOURS.min(points.len() - 1);
    // Each point's k + 1 nearest: itself (or a point on it) and its k nearest others.
    let nearest = IndexedPoints::new(points.to_vec())?.nearest_k_all(k + 1);
    Some(
        nearest
            .iter()
            .map(|nn| {
                let d = nn.last().map_or(0.0, |&(_, d)| d);
                std::f64::consts::PI * d * d / k as f64
            })
            .collect(),
    )
}

/// The default spring (N/m) of each point of a surface held as `points` (m): `β E A / h`, with
/// β = [`DEFAULT_POINT_HOLD_FACTOR`], `young` E (Pa), `h` the cell edge (m) and A the surface
/// area the point stands for ([`area_per_point`]), so the hold is a stiffness per unit area
/// (β E / h, a layer of tissue h / β thick) whatever the points' density. A single point
/// stands for a cell face, h².
pub fn point_hold_stiffness(points: &[Point3<f64>], young: f64, h: f64) -> Vec<f64> {
    let per_area = DEFAULT_POINT_HOLD_FACTOR * young / h;
    match area_per_point(points) {
        Some(areas) => areas.into_iter().map(|a| per_area * a).collect(),
        None => vec![per_area * h * h; points.len()],
    }
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
        let mut rng = livereg_fem::random::Rng::new(7);
        for n in [200, 2000] {
            let pts: Vec<Point3<f64>> = (0..n)
                .map(|_| Point3::new(rng.uniform(), rng.uniform(), 0.0))
                .collect();
            let total: f64 = area_per_point(&pts).unwrap().iter().sum();
            assert!((0.9..1.5).contains(&total), "n = {n}: {total}");
        }
    }

    /// A dense set (a 150 × 150 lattice, 22,500 points): the same areas as a small patch of
    /// the same lattice away from the rim.
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

    /// The default spring of a held point is `β E A / h`: per unit area `β E / h` whatever
    /// the points' spacing, and a cell face `h²` for a single point.
    #[test]
    fn a_held_point_gets_its_area_times_the_layers_stiffness_per_area() {
        let (young, h) = (4500.0, 0.0115);
        let per_area = DEFAULT_POINT_HOLD_FACTOR * young / h;
        for s in [0.002, 0.007] {
            let square: Vec<Point3<f64>> = (0..9)
                .flat_map(|i| (0..9).map(move |j| Point3::new(i as f64 * s, j as f64 * s, 0.0)))
                .collect();
            let k = point_hold_stiffness(&square, young, h);
            let centre = 4 * 9 + 4;
            let area = std::f64::consts::PI * 2.0 * s * s / 6.0;
            assert!((k[centre] - per_area * area).abs() < 1e-9 * per_area * area);
        }
        assert_eq!(
            point_hold_stiffness(&[Point3::origin()], young, h),
            vec![per_area * h * h]
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
