//! A triangle surface (typically the model's, deformed) prepared for signed distances of
//! points to it: the measure behind the session's tests of what a frame is (at rest, still
//! since the last frame, a pose that still fits) and its gate.
//!
//! A cloud point's signed distance is to its closest point ON the surface's triangles (found
//! on the triangles around its nearest vertex, [`closest_anchor`]), positive outside by the
//! interpolated vertex normal there. The distance to the tangent plane at the nearest vertex
//! would put a point lying on a curved surface `≈ κ r² / 2` inside (`κ` the curvature, `r`
//! the distance to that vertex): on the indentation fixture's liver (7 mm edges) the clouds
//! of a liver at rest would sit 0.17–0.19 mm inside on average, which at 0.5 mm camera noise
//! is enough for the rest test to see a change where there is none.
//! Lengths in metres.

use std::sync::Arc;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::correspondences::{rejection_threshold, IndexedPoints};
use super::surface_anchors::{closest_anchor, incident_triangles};
use crate::mesh::TriSurface;

/// What [`SurfaceDistances`] needs of a surface that does not change as it deforms: its
/// triangles and the triangles around each vertex. Built once per model.
#[derive(Debug, Clone)]
pub struct SurfaceTopology {
    triangles: Vec<[usize; 3]>,
    incident: Vec<Vec<usize>>,
}

impl SurfaceTopology {
    /// The topology of a surface of `vertices` vertices and outward-oriented `triangles`.
    pub fn new(vertices: usize, triangles: &[[usize; 3]]) -> Self {
        Self {
            triangles: triangles.to_vec(),
            incident: incident_triangles(vertices, triangles),
        }
    }

    /// The heap it holds, bytes (for a session's memory estimate).
    pub fn heap_bytes(&self) -> usize {
        let lists: usize = self
            .incident
            .iter()
            .map(|l| l.capacity() * std::mem::size_of::<usize>())
            .sum();
        self.triangles.capacity() * std::mem::size_of::<[usize; 3]>()
            + self.incident.capacity() * std::mem::size_of::<Vec<usize>>()
            + lists
    }
}

/// A surface's vertices in a k-d tree with their unit outward vertex normals and its
/// [`SurfaceTopology`].
pub struct SurfaceDistances {
    vertices: IndexedPoints,
    normals: Vec<Vector3<f64>>,
    topology: Arc<SurfaceTopology>,
}

impl SurfaceDistances {
    /// The surface with vertices `x` (m) and `topology`; `None` without vertices or when
    /// `topology` is of another vertex count.
    pub fn new(x: Vec<Point3<f64>>, topology: Arc<SurfaceTopology>) -> Option<Self> {
        if topology.incident.len() != x.len() {
            return None;
        }
        let normals = TriSurface::vertex_normals_at(&x, &topology.triangles);
        Some(Self {
            vertices: IndexedPoints::new(x)?,
            normals,
            topology,
        })
    }

    /// Index of the surface vertex nearest `p` (m).
    pub fn nearest_vertex(&self, p: &Point3<f64>) -> usize {
        self.vertices.nearest(p).0
    }

    /// Unit outward vertex normals of the surface.
    pub fn vertex_normals(&self) -> &[Vector3<f64>] {
        &self.normals
    }

    /// RMS distance (m) from `cloud` (m, model frame) to this surface after the mean + 2σ
    /// outlier rule; infinite when no point is kept.
    pub fn fit_rms(&self, cloud: &[Point3<f64>]) -> f64 {
        let d: Vec<f64> = self
            .signed_distances(cloud)
            .into_iter()
            .map(f64::abs)
            .collect();
        let limit = rejection_threshold(&d, 2.0);
        let kept: Vec<f64> = d.into_iter().filter(|&v| v <= limit).collect();
        if kept.is_empty() {
            return f64::INFINITY;
        }
        (kept.iter().map(|v| v * v).sum::<f64>() / kept.len() as f64).sqrt()
    }

    /// Signed distance (m) of each point of `cloud` (m, model frame) to the surface: to its
    /// closest point on the triangles around its nearest vertex, positive outside (module
    /// doc). That is the closest point of the whole surface wherever the point's nearest
    /// vertex is a corner of the triangle under it, which holds on meshes without obtuse
    /// triangles; elsewhere the point next to it on a shared edge (a second-order difference
    /// near the surface). A point whose triangles are all degenerate falls back to the tangent
    /// plane at its nearest vertex.
    pub fn signed_distances(&self, cloud: &[Point3<f64>]) -> Vec<f64> {
        let x = &self.vertices.points;
        let SurfaceTopology {
            triangles,
            incident,
        } = &*self.topology;
        cloud
            .par_iter()
            .map_init(Vec::new, |seen, q| {
                let (v, _) = self.vertices.nearest(q);
                let on_surface =
                    closest_anchor(q, x, triangles, incident, [v], seen).and_then(|(a, d2)| {
                        let n = a.normal(&self.normals, triangles)?;
                        let gap = q - a.position(x, triangles);
                        Some(d2.sqrt().copysign(n.dot(&gap)))
                    });
                on_surface.unwrap_or_else(|| self.normals[v].dot(&(q - x[v])))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::icosphere;
    use crate::random::Rng;

    /// A coarse sphere (80 triangles, 10 cm): its facets sag well below the tangent planes
    /// at their corners, so a distance measured to those planes would show it.
    fn coarse_sphere() -> (TriSurface, SurfaceDistances) {
        let s = icosphere(Point3::origin(), 0.1, 1);
        let topology = SurfaceTopology::new(s.vertices.len(), &s.triangles);
        let index = SurfaceDistances::new(s.vertices.clone(), Arc::new(topology)).unwrap();
        (s, index)
    }

    #[test]
    fn points_on_the_triangles_are_on_the_surface() {
        let (s, index) = coarse_sphere();
        let mut rng = Rng::new(36);
        let points: Vec<Point3<f64>> = (0..400)
            .map(|_| {
                let t = rng.below(s.triangles.len());
                rng.point_on_triangle(&s.corners(t))
            })
            .collect();
        let d = index.signed_distances(&points);
        let worst = d.iter().map(|v| v.abs()).fold(0.0, f64::max);
        assert!(worst < 1e-12, "largest |d| {worst:e} m");
        // The measure it replaced: the tangent plane at the nearest vertex puts the same
        // points millimetres inside (the sag of a 6 cm facet), so the test can tell them apart.
        let plane: f64 = points
            .iter()
            .map(|q| {
                let (i, _) = index.vertices.nearest(q);
                index.normals[i].dot(&(q - index.vertices.points[i]))
            })
            .sum::<f64>()
            / points.len() as f64;
        assert!(plane < -1e-3, "tangent-plane mean {plane:e} m");
        assert!((index.fit_rms(&points)) < 1e-12);
    }

    #[test]
    fn points_along_a_facets_normal_are_at_their_height_with_its_sign() {
        let (s, index) = coarse_sphere();
        let mut rng = Rng::new(3636);
        for _ in 0..200 {
            let t = rng.below(s.triangles.len());
            let [a, b, c] = s.corners(t);
            // Well inside the facet, so that its foot is the closest surface point.
            let (w0, w1) = (rng.uniform_in(0.2, 0.4), rng.uniform_in(0.2, 0.4));
            let w = [w0, w1, 1.0 - w0 - w1];
            let foot = Point3::from(a.coords * w[0] + b.coords * w[1] + c.coords * w[2]);
            let n = (b - a).cross(&(c - a)).normalize();
            let h = rng.uniform_in(-2e-3, 2e-3);
            let d = index.signed_distances(&[foot + n * h])[0];
            assert!(
                (d - h).abs() < 1e-12,
                "triangle {t}: height {h:e}, distance {d:e}"
            );
        }
    }
}
