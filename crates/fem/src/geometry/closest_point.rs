//! The closest point of a triangle to a point (Ericson, *Real-Time Collision Detection*,
//! 5.1.5: by the Voronoi regions of its corners and edges), as barycentric weights or as a
//! point. Every closest-point query on a triangle surface in livereg goes through it: the
//! rigid stage's target, the data term's anchors, the normals at scale, the session's signed
//! distances and the phantom's clearances. Any length units.

use nalgebra::{Point3, Vector3};

/// The closest point of triangle `[a, b, c]` to `p` (Ericson, *Real-Time Collision Detection*
/// 5.1.5, by Voronoi regions), and whether it is interior (not on an edge or corner). Degenerate
/// triangles may give non-finite results; the caller checks.
pub fn closest_point_on_triangle(p: &Point3<f64>, tri: &[Point3<f64>; 3]) -> (Point3<f64>, bool) {
    let (w, inside) = closest_barycentric(p, tri);
    let [a, b, c] = tri;
    (
        Point3::from(a.coords * w[0] + b.coords * w[1] + c.coords * w[2]),
        inside,
    )
}

/// Barycentric weights (summing to 1, each in `[0, 1]`) of the closest point of triangle
/// `[a, b, c]` to `p` (Ericson, *Real-Time Collision Detection* 5.1.5, by Voronoi regions), and
/// whether it is interior (not on an edge or corner). Degenerate triangles may give
/// non-finite weights; the caller checks.
pub fn closest_barycentric(p: &Point3<f64>, [a, b, c]: &[Point3<f64>; 3]) -> ([f64; 3], bool) {
    let ab: Vector3<f64> = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return ([1.0, 0.0, 0.0], false);
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return ([0.0, 1.0, 0.0], false);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let t = d1 / (d1 - d3);
        return ([1.0 - t, t, 0.0], false);
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return ([0.0, 0.0, 1.0], false);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let t = d2 / (d2 - d6);
        return ([1.0 - t, 0.0, t], false);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return ([0.0, 1.0 - t, t], false);
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    ([1.0 - v - w, v, w], true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    /// The closest point against a reference computed another way: the nearest of a dense
    /// barycentric lattice over the triangle (spacing 1/400 of the edges), for points all
    /// around it (each Voronoi region: corners, edges, the inside, above and below).
    #[test]
    fn the_closest_point_is_the_nearest_of_a_dense_sampling() {
        let mut rng = Rng::new(5115);
        let n = 400;
        for _ in 0..60 {
            let tri = [
                rng.point_in_cube(-1.0, 1.0),
                rng.point_in_cube(-1.0, 1.0),
                rng.point_in_cube(-1.0, 1.0),
            ];
            let [a, b, c] = tri;
            let longest = (b - a).norm().max((c - b).norm()).max((a - c).norm());
            for _ in 0..20 {
                let p = rng.point_in_cube(-2.0, 2.0);
                let (w, _) = closest_barycentric(&p, &tri);
                assert!(
                    w.iter().all(|v| (-1e-12..=1.0 + 1e-12).contains(v)),
                    "{w:?}"
                );
                assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                let (q, _) = closest_point_on_triangle(&p, &tri);
                let d = (p - q).norm();
                let mut sampled = f64::INFINITY;
                for i in 0..=n {
                    for j in 0..=(n - i) {
                        let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
                        let s = a + (b - a) * u + (c - a) * v;
                        sampled = sampled.min((p - s).norm());
                    }
                }
                // Never farther than any sample, and the lattice is within its spacing of
                // every point of the triangle.
                assert!(d <= sampled + 1e-12, "{d} > {sampled}");
                assert!(d >= sampled - longest / n as f64, "{d} << {sampled}");
            }
        }
    }

    #[test]
    fn a_point_above_the_inside_projects_onto_the_plane_and_is_flagged_inside() {
        let tri = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
        ];
        let (w, inside) = closest_barycentric(&Point3::new(0.25, 0.25, 0.7), &tri);
        assert!(inside);
        assert!((w[0] - 0.5).abs() < 1e-15 && (w[1] - 0.25).abs() < 1e-15);
        let (q, inside) = closest_point_on_triangle(&Point3::new(2.0, 2.0, -1.0), &tri);
        assert!(!inside);
        assert!((q - Point3::new(0.5, 0.5, 0.0)).norm() < 1e-15);
    }
}
