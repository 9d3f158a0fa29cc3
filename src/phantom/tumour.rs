//! A small ellipsoidal tumour inside the right lobe.

use nalgebra::{Point3, Vector3};

use super::liver_surface::{liver_map, quantize};
use crate::mesh::primitives::icosphere;
use crate::mesh::TriSurface;

/// Tumour semi-axes in metres (x, y, z): a 2.6 × 2.2 × 2.0 cm ellipsoid.
pub const TUMOUR_SEMI_AXES: [f64; 3] = [0.013, 0.011, 0.010];

/// Icosphere subdivision levels of the tumour mesh (level 2: 320 triangles).
pub const TUMOUR_LEVELS: usize = 2;

/// Centre of the tumour in metres: a fixed point deep in the right lobe (the image under
/// [`liver_map`] of reference point (−0.5, 0.15, 0.1)).
pub fn tumour_centre() -> Point3<f64> {
    quantize(liver_map(Vector3::new(-0.5, 0.15, 0.1)))
}

/// The tumour surface in metres: an ellipsoid with semi-axes [`TUMOUR_SEMI_AXES`] around
/// [`tumour_centre`]; closed, watertight, outward-oriented, 320 triangles.
pub fn tumour_surface() -> TriSurface {
    let c = tumour_centre();
    let sphere = icosphere(Point3::origin(), 1.0, TUMOUR_LEVELS);
    let [a, b, d] = TUMOUR_SEMI_AXES;
    let vertices = sphere
        .vertices
        .iter()
        .map(|p| {
            let n = p.coords.normalize();
            quantize(c + Vector3::new(a * n.x, b * n.y, d * n.z))
        })
        .collect();
    TriSurface::new(vertices, sphere.triangles)
}
