//! Surface normals at a physical length scale, for the point-to-plane springs of the cloud →
//! surface data term.
//!
//! A point-to-plane spring pulls its surface point along the surface normal only, so the
//! normal decides the direction of every pull. Interpolated vertex normals are normals at the
//! scale of the mesh's own triangles: the same shape triangulated four times finer gives a
//! nearly faceted normal field (inside every old triangle the normal is that triangle's), and
//! a surface the registration has wrinkled at the scale of its grid cells turns its vertex
//! normals with the wrinkles. Both make the registration depend on how the surface is
//! triangulated (with vertex normals, the same phantom geometry midpoint-subdivided from
//! 5,120 to 81,920 triangles registers 23 % worse on the pneumoperitoneum).
//!
//! [`NormalsAtScale`] averages the interpolated vertex-normal field over a ball of fixed
//! radius around each vertex instead, and the pairing interpolates these smoothed vertex
//! normals. The surface is sampled at rest at half the radius (a triangle larger than that is
//! split, [`samples_by_triangle`]) and the samples are gathered into cells of half the radius
//! (clusters); which clusters lie within the radius of each vertex, and their weights (a
//! smooth kernel of the distance), are found once, at rest (the
//! deformation is smooth at that scale). Per evaluation, each cluster sums the current
//! interpolated normal at its samples times their areas, and each vertex the sums of its
//! clusters: a cost of samples plus vertices × clusters in reach, whatever the cloud. So the
//! average is over the *area* near the vertex whatever the size of the triangles that make it
//! up; on a mesh whose triangles are larger than the ball it is the vertex normal itself (a
//! facet's own normal would be worse: measured in docs/data-term.md). The radius is a length of
//! the organ, not of its mesh: [`NormalsAtScale::default_radius`], 0.125 × the cube root of
//! the enclosed volume (about 1.3 cm for a liver), chosen on two liver surfaces and five
//! scenario classes in docs/data-term.md#normals-at-the-organs-scale. Lengths in
//! metres.

use std::collections::HashMap;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::geometry::Aabb;
use crate::mechanics::loads::samples_by_triangle;
use crate::mesh::TriSurface;

use crate::geometry::closest_barycentric;

/// The radius as a fraction of the cube root of the surface's enclosed volume.
pub const RADIUS_PER_VOLUME_ROOT: f64 = 0.125;

/// Normals of a triangulated surface averaged over balls of one radius (see the module).
#[derive(Debug, Clone)]
pub struct NormalsAtScale {
    radius: f64,
    /// Per sample: its triangle, its barycentric weights there, and the area it stands for
    /// (m²).
    samples: Vec<(usize, [f64; 3], f64)>,
    /// Cluster of each sample.
    sample_cluster: Vec<u32>,
    clusters: usize,
    /// Clusters within the radius of each vertex with their kernel weights, compressed: those
    /// of vertex `v` are `reach[reach_start[v]..reach_start[v + 1]]`.
    reach_start: Vec<usize>,
    reach: Vec<(u32, f32)>,
    triangles: usize,
}

/// Sample spacing and cluster cell as fractions of the radius.
const SPACING_PER_RADIUS: f64 = 0.5;

/// Heap bytes per surface sample (its triangle, weights, area and cluster).
pub const BYTES_PER_SAMPLE: usize = 48;

/// Heap bytes per entry of a vertex's clusters in reach.
pub const BYTES_PER_REACH: usize = 8;

impl NormalsAtScale {
    /// Averages over balls of `radius` (m) around the rest vertices `rest` of the surface of
    /// `triangles`. `None` without triangles or with a radius that is not a positive finite
    /// length.
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
        let cell = SPACING_PER_RADIUS * radius;
        let raw = samples_by_triangle(&surface, &everywhere, cell);
        // Clusters: the samples' cells, each placed at its samples' area-weighted centre.
        let mut cell_of: HashMap<[i64; 3], u32> = HashMap::new();
        let mut centre: Vec<(Vector3<f64>, f64)> = Vec::new();
        let mut samples = Vec::with_capacity(raw.len());
        let mut sample_cluster = Vec::with_capacity(raw.len());
        for &(t, s) in &raw {
            let key = [0, 1, 2].map(|d| (s.point[d] / cell).floor() as i64);
            let next = centre.len() as u32;
            let c = *cell_of.entry(key).or_insert(next);
            if c == next {
                centre.push((Vector3::zeros(), 0.0));
            }
            centre[c as usize].0 += s.point.coords * s.area;
            centre[c as usize].1 += s.area;
            let (w, _) = closest_barycentric(&s.point, &surface.corners(t));
            let w = if w.iter().all(|v| v.is_finite()) {
                w
            } else {
                [1.0 / 3.0; 3]
            };
            samples.push((t, w, s.area));
            sample_cluster.push(c);
        }
        let points: Vec<[f64; 3]> = centre
            .iter()
            .map(|(p, a)| {
                let p = if *a > 0.0 { p / *a } else { *p };
                [p.x, p.y, p.z]
            })
            .collect();
        let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&points).ok()?;
        let mut reach_start = Vec::with_capacity(rest.len() + 1);
        let mut reach = Vec::new();
        reach_start.push(0);
        for p in rest {
            for nb in tree
                .query(&[p.x, p.y, p.z])
                .within::<SquaredEuclidean<f64>>(radius * radius)
                .execute()
            {
                // A smooth kernel (biweight, (1 − d²/r²)²): a cluster entering or leaving the
                // ball changes the sum by nothing, so the field is smooth across the cells.
                let q = 1.0 - nb.distance / (radius * radius);
                reach.push((nb.item, (q * q) as f32));
            }
            reach_start.push(reach.len());
        }
        Some(Self {
            radius,
            samples,
            sample_cluster,
            clusters: centre.len(),
            reach_start,
            reach,
            triangles: triangles.len(),
        })
    }

    /// [`RADIUS_PER_VOLUME_ROOT`] × the cube root of the volume the closed surface `rest`,
    /// `triangles` encloses (m); `None` when the volume is not positive (an open or
    /// inside-out surface).
    pub fn default_radius(rest: &[Point3<f64>], triangles: &[[usize; 3]]) -> Option<f64> {
        let volume = crate::geometry::shapes::signed_volume(rest, triangles);
        (volume.is_finite() && volume > 0.0).then(|| RADIUS_PER_VOLUME_ROOT * volume.cbrt())
    }

    /// The averaging radius, m.
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// Whether this was built for a surface of `triangles` triangles.
    pub fn fits(&self, triangles: usize) -> bool {
        self.triangles == triangles
    }

    /// Surface samples held.
    pub fn samples(&self) -> usize {
        self.samples.len()
    }

    /// Heap bytes held (about [`BYTES_PER_SAMPLE`] per sample and [`BYTES_PER_REACH`] per
    /// vertex–cluster entry).
    pub fn heap_bytes(&self) -> usize {
        BYTES_PER_SAMPLE * self.samples.len() + BYTES_PER_REACH * self.reach.len()
    }

    /// The smoothed unit normal at every vertex, given the current unit vertex normals
    /// `vertex_normals` of the surface of `triangles`: the normalised sum, over the clusters
    /// within the radius of the vertex at rest, weighted by the biweight kernel of their rest
    /// distance, of the normal interpolated at their samples times the samples' areas; the
    /// vertex's own normal where that sum vanishes. Interpolate
    /// the result with a point's barycentric weights for the normal at the point.
    pub fn smooth(
        &self,
        vertex_normals: &[Vector3<f64>],
        triangles: &[[usize; 3]],
    ) -> Vec<Vector3<f64>> {
        let n = vertex_normals;
        let mut cluster = vec![Vector3::zeros(); self.clusters];
        for (&(t, w, area), &c) in self.samples.iter().zip(&self.sample_cluster) {
            let [a, b, d] = triangles[t];
            cluster[c as usize] += (n[a] * w[0] + n[b] * w[1] + n[d] * w[2]) * area;
        }
        (0..n.len())
            .into_par_iter()
            .map(|v| {
                let sum = self.reach[self.reach_start[v]..self.reach_start[v + 1]]
                    .iter()
                    .fold(Vector3::zeros(), |s, &(c, w)| {
                        s + cluster[c as usize] * f64::from(w)
                    });
                sum.try_normalize(0.0).unwrap_or(n[v])
            })
            .collect()
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

    /// The smoothed normals of `s` interpolated at the point `w` of triangle `t`.
    fn at(n: &NormalsAtScale, s: &TriSurface, t: usize, w: [f64; 3]) -> Vector3<f64> {
        let smoothed = n.smooth(&s.vertex_normals(), &s.triangles);
        let [a, b, c] = s.triangles[t];
        smoothed[a] * w[0] + smoothed[b] * w[1] + smoothed[c] * w[2]
    }

    /// Points on the faces of a coarse sphere (level 2, 320 triangles, radius 0.1 m), each
    /// inside one of its triangles and inside one triangle of the same faceted shape
    /// triangulated 16 times finer: averaged over a ball of 0.125 × ∛V the two normals agree
    /// within a degree and lie within 1.5° of the sphere's radial direction, while the fine
    /// mesh's interpolated vertex normals stay more than 3° off (faceted), which is what this
    /// type is for.
    #[test]
    fn normals_follow_the_shape_not_its_triangulation() {
        let coarse = icosphere(Point3::origin(), 0.1, 2);
        let fine = subdivide(&subdivide(&coarse));
        let r = NormalsAtScale::default_radius(&coarse.vertices, &coarse.triangles).unwrap();
        let expected = RADIUS_PER_VOLUME_ROOT * (4.0 / 3.0 * std::f64::consts::PI).cbrt() * 0.1;
        assert!((r / expected - 1.0).abs() < 0.02, "{r} vs {expected}");
        let n_coarse = NormalsAtScale::new(&coarse.vertices, &coarse.triangles, r).unwrap();
        let n_fine = NormalsAtScale::new(&fine.vertices, &fine.triangles, r).unwrap();
        let fine_vertex = fine.vertex_normals();
        let (mut worst_scale, mut worst_between, mut worst_vertex) = (0.0f64, 0.0f64, 0.0f64);
        // Fine triangle 16 k + j lies inside coarse triangle k (two midpoint subdivisions).
        for (k, &[a, b, c]) in fine.triangles.iter().enumerate().step_by(7) {
            let w = [0.2, 0.3, 0.5];
            let p = Point3::from(
                fine.vertices[a].coords * w[0]
                    + fine.vertices[b].coords * w[1]
                    + fine.vertices[c].coords * w[2],
            );
            let coarse_t = k / 16;
            let corners = coarse.corners(coarse_t);
            let (wc, _) = closest_barycentric(&p, &corners);
            let from_fine = at(&n_fine, &fine, k, w);
            let from_coarse = at(&n_coarse, &coarse, coarse_t, wc);
            let interpolated =
                fine_vertex[a] * w[0] + fine_vertex[b] * w[1] + fine_vertex[c] * w[2];
            worst_scale = worst_scale.max(angle_deg(&from_fine, &p.coords));
            worst_between = worst_between.max(angle_deg(&from_fine, &from_coarse));
            worst_vertex = worst_vertex.max(angle_deg(&interpolated, &p.coords));
        }
        // Measured: 1.08° from radial (the 320-face polyhedron is not a sphere), 0.89°
        // between the triangulations (2.5° with a hard cut-off at the ball's edge instead of
        // the biweight kernel), 4.07° for the fine mesh's interpolated vertex normals.
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

    /// A flat square stays flat: every smoothed normal is the plane's, and the current vertex
    /// normals (here of the square rotated) decide it, not the rest ones.
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
        let normals = TriSurface::vertex_normals_at(&moved, &triangles);
        let smoothed = n.smooth(&normals, &triangles);
        for (v, m) in smoothed.iter().enumerate() {
            assert!(angle_deg(m, &(rot * Vector3::z())) < 1e-9, "vertex {v}");
        }
        assert!(NormalsAtScale::new(&vertices, &triangles, 0.0).is_none());
    }
}
