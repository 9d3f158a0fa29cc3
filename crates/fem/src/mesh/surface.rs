//! Closed triangle surfaces: the pre-operative liver model and internal structure meshes.

use nalgebra::{Point3, Vector3};

/// A triangle surface in scene units: vertex positions and counter-clockwise (outward-normal)
/// triangles indexing into them.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TriSurface {
    /// Vertex positions, in scene units.
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as vertex indices, oriented so that the right-hand normal points outwards.
    pub triangles: Vec<[usize; 3]>,
}

impl TriSurface {
    /// Creates a surface from vertices and triangles (indices are not checked here; readers and
    /// [`crate::mesh::validate()`] check them).
    pub fn new(vertices: Vec<Point3<f64>>, triangles: Vec<[usize; 3]>) -> Self {
        Self {
            vertices,
            triangles,
        }
    }

    /// The three corner positions of triangle `t`.
    pub fn corners(&self, t: usize) -> [Point3<f64>; 3] {
        let [a, b, c] = self.triangles[t];
        [self.vertices[a], self.vertices[b], self.vertices[c]]
    }

    /// Area-weighted normal of triangle `t` (its length is twice the area), in units².
    pub fn scaled_normal(&self, t: usize) -> Vector3<f64> {
        let [a, b, c] = self.corners(t);
        (b - a).cross(&(c - a))
    }

    /// Unit outward normal at each vertex: the sum of the area-weighted normals of the
    /// triangles around it, normalised (zero for a vertex in no triangle of positive area).
    pub fn vertex_normals(&self) -> Vec<Vector3<f64>> {
        Self::vertex_normals_at(&self.vertices, &self.triangles)
    }

    /// [`TriSurface::vertex_normals`] of these triangles with the vertices at `positions`
    /// (a deformed state of the surface, without building it).
    pub fn vertex_normals_at(
        positions: &[Point3<f64>],
        triangles: &[[usize; 3]],
    ) -> Vec<Vector3<f64>> {
        let mut n = vec![Vector3::zeros(); positions.len()];
        for &[a, b, c] in triangles {
            let m = (positions[b] - positions[a]).cross(&(positions[c] - positions[a]));
            for v in [a, b, c] {
                n[v] += m;
            }
        }
        for v in &mut n {
            *v = v.try_normalize(0.0).unwrap_or_else(Vector3::zeros);
        }
        n
    }

    /// Axis-aligned bounding box `(min, max)` of the vertices; `None` for an empty surface.
    pub fn bounding_box(&self) -> Option<(Point3<f64>, Point3<f64>)> {
        let first = *self.vertices.first()?;
        Some(
            self.vertices
                .iter()
                .fold((first, first), |(lo, hi), p| (lo.inf(p), hi.sup(p))),
        )
    }

    /// Multiplies every coordinate by `factor` (unit conversion).
    pub fn scale(&mut self, factor: f64) {
        for v in &mut self.vertices {
            v.coords *= factor;
        }
    }

    /// Area of triangle `t`, in units² (half its scaled normal's length).
    pub fn triangle_area(&self, t: usize) -> f64 {
        0.5 * self.scaled_normal(t).norm()
    }

    /// Centroid of triangle `t` (the mean of its corners).
    pub fn centroid(&self, t: usize) -> Point3<f64> {
        let [a, b, c] = self.corners(t);
        Point3::from((a.coords + b.coords + c.coords) / 3.0)
    }

    /// Total area of the triangles, in units².
    pub fn area(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| self.triangle_area(t))
            .sum()
    }

    /// Enclosed volume by the divergence theorem, in units³ (positive when normals point out).
    ///
    /// The triple products are summed before the single division by 6, so a mesh with integer
    /// coordinates (e.g. the unit cube) gets its exact volume.
    pub fn signed_volume(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t);
                a.coords.dot(&b.coords.cross(&c.coords))
            })
            .sum::<f64>()
            / 6.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::icosphere;

    #[test]
    fn a_right_triangle_has_half_its_legs_product_as_area_and_the_corners_mean_as_centroid() {
        let s = TriSurface::new(
            vec![
                Point3::new(0.0, 0.0, 1.0),
                Point3::new(3.0, 0.0, 1.0),
                Point3::new(0.0, 2.0, 1.0),
            ],
            vec![[0, 1, 2]],
        );
        assert_eq!(s.triangle_area(0), 3.0);
        assert_eq!(s.area(), 3.0);
        assert!((s.centroid(0) - Point3::new(1.0, 2.0 / 3.0, 1.0)).norm() < 1e-15);
    }

    #[test]
    fn vertex_normals_of_a_sphere_are_radial() {
        let c = Point3::new(0.3, -0.1, 0.2);
        let s = icosphere(c, 2.0, 3);
        let n = s.vertex_normals();
        for (p, n) in s.vertices.iter().zip(&n) {
            let radial = (p - c).normalize();
            assert!((n.norm() - 1.0).abs() < 1e-12);
            // The icosphere's vertex fan is nearly symmetric: within a degree of radial.
            assert!(n.dot(&radial) > 1f64.to_radians().cos(), "{n} vs {radial}");
        }
    }
}
