//! The fixed (ligament) region: falciform/triangular ligaments and the vena cava attachment
//! on the upper back of the liver.

use crate::geometry::Aabb;
use crate::mesh::TriSurface;

/// The box, in metres, holding the part of the surface that keeps its rest position: the
/// posterior-superior strip of the liver `surface` (back 25 % of its depth, top 45 % of its
/// height, from 28 % to 66 % of its right→left extent), slightly enlarged outwards so that
/// the surface there is well inside. Holds roughly 3–8 % of the surface area.
pub fn ligament_box(surface: &TriSurface) -> Aabb {
    let Some((lo, hi)) = surface.bounding_box() else {
        return Aabb::EMPTY;
    };
    let e = hi - lo;
    let margin = 0.005;
    let a = nalgebra::Point3::new(lo.x + 0.28 * e.x, lo.y - margin, lo.z + 0.55 * e.z);
    let b = nalgebra::Point3::new(lo.x + 0.66 * e.x, lo.y + 0.25 * e.y, hi.z + margin);
    Aabb::new(
        super::liver_surface::quantize(a),
        super::liver_surface::quantize(b),
    )
}
