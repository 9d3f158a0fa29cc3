//! Brute-force point–surface distances (exact, O(triangles) per query), used to keep the
//! phantom's internal structures away from the liver surface.

use nalgebra::Point3;

use crate::geometry::closest_point_on_triangle;
use crate::mesh::TriSurface;

/// Unsigned distance from `p` to the nearest point of `surface`, in the surface's units
/// (brute force over all triangles; `f64::INFINITY` for a surface without triangles).
pub fn distance_to_surface(surface: &TriSurface, p: &Point3<f64>) -> f64 {
    (0..surface.triangles.len())
        .map(|t| {
            let (q, _) = closest_point_on_triangle(p, &surface.corners(t));
            (q - p).norm_squared()
        })
        // A degenerate triangle may give no point; its neighbours hold its place.
        .filter(|d2| d2.is_finite())
        .fold(f64::INFINITY, f64::min)
        .sqrt()
}
