//! Measures of the phantom's shape that its tests check and `examples/phantom_numbers.rs`
//! prints: how thick the liver is across x, and how much of its surface lies in a box (the
//! ligament's share). Metres.

use crate::geometry::{Aabb, InsideTest};
use crate::mesh::TriSurface;

/// Largest total inside length (m) of `surface` along the z-lines at `x`, over 401 lines
/// evenly spaced in y across its bounding box: the organ's thickness through that sagittal
/// slice (a lobe's, where z-lines cross it). 0 for an empty surface.
pub fn max_thickness_at(surface: &TriSurface, x: f64) -> f64 {
    let Some((lo, hi)) = surface.bounding_box() else {
        return 0.0;
    };
    let inside = InsideTest::new(&surface.vertices, &surface.triangles);
    let mut crossings = Vec::new();
    let mut best: f64 = 0.0;
    for k in 0..=400 {
        let y = lo.y + (hi.y - lo.y) * k as f64 / 400.0;
        inside.line_crossings(x, y, &mut crossings);
        let mut depth = 0;
        let mut start = 0.0;
        let mut total = 0.0;
        for &(z, w) in &crossings {
            let before = depth;
            depth += w;
            if before < 1 && depth >= 1 {
                start = z;
            } else if before >= 1 && depth < 1 {
                total += z - start;
            }
        }
        best = best.max(total);
    }
    best
}

/// Area (m²) of the triangles of `surface` whose centroid lies inside `region`.
pub fn area_in_box(surface: &TriSurface, region: &Aabb) -> f64 {
    (0..surface.triangles.len())
        .filter(|&t| region.contains(&surface.centroid(t)))
        .map(|t| surface.triangle_area(t))
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::box_surface;
    use nalgebra::Point3;

    /// A 2 × 3 × 4 box: every z-line through it crosses 4 of inside; the box around its
    /// bottom face holds that face's area (6), half a box holds what its centroids reach.
    #[test]
    fn thickness_and_area_of_a_box_are_exact() {
        let s = box_surface(Point3::origin(), Point3::new(2.0, 3.0, 4.0), 4);
        assert!((max_thickness_at(&s, 1.0) - 4.0).abs() < 1e-12);
        assert_eq!(max_thickness_at(&s, 5.0), 0.0);
        let bottom = Aabb {
            min: Point3::new(-1.0, -1.0, -0.01),
            max: Point3::new(3.0, 4.0, 0.01),
        };
        assert!((area_in_box(&s, &bottom) - 6.0).abs() < 1e-12);
        let everything = Aabb {
            min: Point3::new(-1.0, -1.0, -1.0),
            max: Point3::new(3.0, 4.0, 5.0),
        };
        assert!((area_in_box(&s, &everything) - s.area()).abs() < 1e-12);
        assert!((s.area() - 2.0 * (6.0 + 8.0 + 12.0)).abs() < 1e-12);
        assert_eq!(max_thickness_at(&TriSurface::default(), 0.0), 0.0);
    }
}
