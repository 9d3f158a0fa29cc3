//! Brute-force point–surface distances (exact, O(triangles) per query), used to keep the
//! phantom's internal structures away from the liver surface.

use nalgebra::Point3;

use crate::mesh::TriSurface;

/// Closest point to `p` on the triangle `(a, b, c)` (any length units). For a degenerate
/// (zero-area) triangle whose point falls in no Voronoi region, its nearest corner.
pub fn closest_point_on_triangle(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> Point3<f64> {
    // Ericson, Real-Time Collision Detection, 5.1.5 (Voronoi regions of the triangle).
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = va + vb + vc;
    if denom.abs() <= f64::MIN_POSITIVE {
        // Degenerate (collinear) triangle: approximate by its nearest corner.
        return [*a, *b, *c]
            .into_iter()
            .min_by(|x, y| (x - p).norm_squared().total_cmp(&(y - p).norm_squared()))
            .unwrap_or(*a);
    }
    a + ab * (vb / denom) + ac * (vc / denom)
}

/// Unsigned distance from `p` to the nearest point of `surface`, in the surface's units
/// (brute force over all triangles; `f64::INFINITY` for a surface without triangles).
pub fn distance_to_surface(surface: &TriSurface, p: &Point3<f64>) -> f64 {
    (0..surface.triangles.len())
        .map(|t| {
            let [a, b, c] = surface.corners(t);
            (closest_point_on_triangle(p, &a, &b, &c) - p).norm_squared()
        })
        .fold(f64::INFINITY, f64::min)
        .sqrt()
}
