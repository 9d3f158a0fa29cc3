//! Surface normals at a physical length scale, for the point-to-plane springs of the cloud →
//! surface data term.
//!
//! A point-to-plane spring pulls its surface point along the surface normal only, so the
//! normal decides the direction of every pull. Interpolated vertex normals are normals at the
//! scale of the mesh's own triangles: the same shape triangulated four times finer gives a
//! nearly faceted normal field (inside every old triangle the normal is that triangle's), and
//! a surface the registration has wrinkled at the scale of its grid cells turns its vertex
//! normals with the wrinkles. Both made the registration depend on how the surface was
//! triangulated (issue 19: the same phantom geometry, midpoint-subdivided from 5,120 to
//! 81,920 triangles, registered 23 % worse on the pneumoperitoneum).
//!
//! [`NormalsAtScale`] averages the interpolated vertex-normal field over a ball of fixed
//! radius around the point instead: the surface is sampled at rest at half the radius
//! (a triangle larger than that is split, [`samples_by_triangle`]), the samples inside the
//! ball are chosen at rest (the deformation is smooth at that scale), and each adds the
//! current interpolated normal at its place times the area it stands for. So the average is
//! over the *area* inside the ball whatever the size of the triangles that make it up; on a
//! mesh whose triangles are larger than the ball it is the interpolated normal itself (a
//! facet's own normal would be worse: measured in docs/registration.md). The radius is a length of
//! the organ, not of its mesh: [`NormalsAtScale::default_radius`], 0.125 × the cube root of
//! the enclosed volume (about 1.3 cm for a liver), chosen on two liver surfaces and five
//! scenario classes in docs/registration.md ("Normals at the organ's scale"). Lengths in
//! metres.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};

use crate::geometry::Aabb;
use crate::mechanics::loads::samples_by_triangle;
use crate::mesh::TriSurface;

use super::model_target::closest_barycentric;

/// The radius as a fraction of the cube root of the surface's enclosed volume.
pub const RADIUS_PER_VOLUME_ROOT: f64 = 0.125;

/// Normals of a triangulated surface averaged over balls of one radius (see the module).
#[derive(Debug)]
pub struct NormalsAtScale {
    radius: f64,
    /// Rest positions of the surface samples, indexed.
    samples: ImmutableKdTree<f64, 3>,
    /// Per sample: its triangle, its barycentric weights there, and the area it stands for
    /// (m²).
    shares: Vec<(usize, [f64; 3], f64)>,
    triangles: usize,
}

/// Sample spacing as a fraction of the radius: a ball holds a dozen samples or more.
const SPACING_PER_RADIUS: f64 = 0.5;

/// Heap bytes per surface sample (its k-d tree entry and its triangle, weights and area).
pub const BYTES_PER_SAMPLE: usize = 72;

impl NormalsAtScale {
    /// Averages over balls of `radius` (m) around rest positions of the surface whose rest
    /// vertices are `rest` and triangles `triangles`. `None` without triangles or with a
    /// radius that is not a positive finite length.
    pub fn new(rest: &[Point3<f64>], triangles: &[[usize; 3]], radius: f64) -> Option<Self> {
        if triangles.is_empty() || !(radius.is_finite() && radius > 0.0) {
            return None;
        }
        let surface = TriSurface {
            vertices: rest.to_vec(),
            triangles: triangles.to_vec(),
        };
        let everywhere = Aabb {
            min: Point3::from([f64::NEG_INFINITY; 3]),
            max: Point3::from([f64::INFINITY; 3]),
        };
        let samples = samples_by_triangle(&surface, &everywhere, SPACING_PER_RADIUS * radius);
        let coords: Vec<[f64; 3]> = samples
            .iter()
            .map(|(_, s)| [s.point.x, s.point.y, s.point.z])
            .collect();
        let shares = samples
            .iter()
            .map(|&(t, s)| {
                let (w, _) = closest_barycentric(&s.point, &surface.corners(t));
                let w = if w.iter().all(|v| v.is_finite()) {
                    w
                } else {
                    [1.0 / 3.0; 3]
                };
                (t, w, s.area)
            })
            .collect();
        let samples = ImmutableKdTree::new_from_slice(&coords).ok()?;
        Some(Self {
            radius,
            samples,
            shares,
            triangles: triangles.len(),
        })
    }

    /// [`RADIUS_PER_VOLUME_ROOT`] × the cube root of the volume the closed surface `rest`,
    /// `triangles` encloses (m); `None` when the volume is not positive (an open or
    /// inside-out surface).
    pub fn default_radius(rest: &[Point3<f64>], triangles: &[[usize; 3]]) -> Option<f64> {
        let volume: f64 = triangles
            .iter()
            .map(|&[a, b, c]| rest[a].coords.dot(&rest[b].coords.cross(&rest[c].coords)) / 6.0)
            .sum();
        (volume.is_finite() && volume > 0.0).then(|| RADIUS_PER_VOLUME_ROOT * volume.cbrt())
    }

    /// Surface samples held (their heap is about [`BYTES_PER_SAMPLE`] each).
    pub fn samples(&self) -> usize {
        self.shares.len()
    }

    /// The averaging radius, m.
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// Whether this was built for a surface of `triangles` triangles.
    pub fn fits(&self, triangles: usize) -> bool {
        self.triangles == triangles
    }

    /// The unit normal at the surface point whose rest position is `rest_point`, with the
    /// unit vertex normals now `vertex_normals`: the normalised sum, over the samples whose
    /// rest position lies within the radius, of the normal interpolated at the sample times
    /// its area; `fallback` (the caller's local normal) when that sum vanishes or no sample is
    /// that close.
    pub fn at(
        &self,
        rest_point: &Point3<f64>,
        vertex_normals: &[Vector3<f64>],
        triangles: &[[usize; 3]],
        fallback: Vector3<f64>,
    ) -> Vector3<f64> {
        let near = self
            .samples
            .query(&[rest_point.x, rest_point.y, rest_point.z])
            .within::<SquaredEuclidean<f64>>(self.radius * self.radius)
            .execute();
        let n = vertex_normals;
        let sum = near.iter().fold(Vector3::zeros(), |s, nb| {
            let (t, w, area) = self.shares[nb.item as usize];
            let [a, b, c] = triangles[t];
            s + (n[a] * w[0] + n[b] * w[1] + n[c] * w[2]) * area
        });
        sum.try_normalize(0.0).unwrap_or(fallback)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::icosphere;
    use crate::mesh::TriSurface;

    /// Midpoint subdivision: every triangle into four, the same piecewise-flat shape.
    fn subdivide(s: &TriSurface) -> TriSurface {
        let mut vertices = s.vertices.clone();
        let mut mid = std::collections::HashMap::new();
        let mut m = |a: usize, b: usize, v: &mut Vec<Point3<f64>>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push(nalgebra::center(&v[a], &v[b]));
                v.len() - 1
            })
        };
        let mut triangles = Vec::new();
        for &[a, b, c] in &s.triangles {
            let (ab, bc, ca) = (
                m(a, b, &mut vertices),
                m(b, c, &mut vertices),
                m(c, a, &mut vertices),
            );
            triangles.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
        }
        TriSurface {
            vertices,
            triangles,
        }
    }

    fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
        a.normalize()
            .dot(&b.normalize())
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
    }

    /// Points on the faces of a coarse sphere (level 2, 320 triangles, radius 0.1 m):
    /// averaged over a ball of 0.125 × ∛V the normal is within 1.5° of the sphere's radial
    /// direction, and the same faceted shape triangulated 16 times finer gives the same
    /// normals within a degree; the interpolated vertex normals of the fine triangulation stay
    /// more than 3° off (faceted), which is what this type is for.
    #[test]
    fn normals_follow_the_shape_not_its_triangulation() {
        let coarse = icosphere(Point3::origin(), 0.1, 2);
        let fine = subdivide(&subdivide(&coarse));
        let r = NormalsAtScale::default_radius(&coarse.vertices, &coarse.triangles).unwrap();
        let expected = RADIUS_PER_VOLUME_ROOT * (4.0 / 3.0 * std::f64::consts::PI).cbrt() * 0.1;
        assert!((r / expected - 1.0).abs() < 0.02, "{r} vs {expected}");
        let n_coarse = NormalsAtScale::new(&coarse.vertices, &coarse.triangles, r).unwrap();
        let n_fine = NormalsAtScale::new(&fine.vertices, &fine.triangles, r).unwrap();
        let vertex_normals = fine.vertex_normals();
        let coarse_normals = coarse.vertex_normals();
        let (mut worst_scale, mut worst_between, mut worst_vertex) = (0.0f64, 0.0f64, 0.0f64);
        for &[a, b, c] in fine.triangles.iter().step_by(7) {
            // A point inside the fine triangle, off its corners.
            let w = [0.2, 0.3, 0.5];
            let p = Point3::from(
                fine.vertices[a].coords * w[0]
                    + fine.vertices[b].coords * w[1]
                    + fine.vertices[c].coords * w[2],
            );
            let radial = p.coords;
            let z = Vector3::zeros();
            let from_coarse = n_coarse.at(&p, &coarse_normals, &coarse.triangles, z);
            let from_fine = n_fine.at(&p, &vertex_normals, &fine.triangles, z);
            let interpolated =
                vertex_normals[a] * w[0] + vertex_normals[b] * w[1] + vertex_normals[c] * w[2];
            worst_scale = worst_scale.max(angle_deg(&from_fine, &radial));
            worst_between = worst_between.max(angle_deg(&from_fine, &from_coarse));
            worst_vertex = worst_vertex.max(angle_deg(&interpolated, &radial));
        }
        // Measured: 0.92° from radial (the 320-face polyhedron is not a sphere), 0.71°
        // between the triangulations (4.2° when whole triangles were counted by their
        // centroids), 4.07° for the fine mesh's interpolated vertex normals.
        assert!(worst_scale < 1.5, "{worst_scale}° from radial");
        assert!(
            worst_between < 1.0,
            "{worst_between}° between triangulations"
        );
        assert!(
            worst_vertex > 3.0,
            "the faceted vertex normals were {worst_vertex}° off"
        );
    }

    /// A flat square stays flat: every normal is the plane's, and the current vertex normals
    /// (here of the square rotated) decide it, not the rest ones.
    #[test]
    fn the_current_state_turns_the_normals() {
        let mut vertices = Vec::new();
        for i in 0..11 {
            for j in 0..11 {
                vertices.push(Point3::new(0.01 * i as f64, 0.01 * j as f64, 0.0));
            }
        }
        let mut triangles = Vec::new();
        for i in 0..10 {
            for j in 0..10 {
                let v = i * 11 + j;
                triangles.push([v, v + 11, v + 12]);
                triangles.push([v, v + 12, v + 1]);
            }
        }
        let n = NormalsAtScale::new(&vertices, &triangles, 0.02).unwrap();
        let rot = nalgebra::Rotation3::from_euler_angles(0.4, -0.2, 0.9);
        let moved: Vec<Point3<f64>> = vertices.iter().map(|p| rot * p).collect();
        let p = Point3::new(0.05, 0.05, 0.0);
        let normals = crate::mesh::TriSurface::vertex_normals_at(&moved, &triangles);
        let got = n.at(&p, &normals, &triangles, Vector3::zeros());
        assert!(angle_deg(&got, &(rot * Vector3::z())) < 1e-9);
        // Far from every sample: the fallback.
        let far = n.at(
            &Point3::new(1.0, 1.0, 1.0),
            &normals,
            &triangles,
            Vector3::x(),
        );
        assert_eq!(far, Vector3::x());
        assert!(NormalsAtScale::new(&vertices, &triangles, 0.0).is_none());
    }
}
