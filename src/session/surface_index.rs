//! A deformed surface prepared for signed distances: the measure behind the session's tests of
//! what a frame is (at rest, still since the last frame, a pose that still fits; issue 18).
//!
//! A cloud point's signed distance is to its closest point ON the surface's triangles (found
//! around its nearest vertices, [`closest_anchor`]), positive outside by the interpolated
//! vertex normal there. Until session 36 it was the distance to the tangent plane at the
//! nearest vertex, which on a curved surface puts a point lying on it `≈ κ r² / 2` inside
//! (`κ` the curvature, `r` the distance to that vertex): on the indentation fixture's liver
//! (7 mm edges) the clouds of a liver at rest sat 0.17–0.19 mm inside on average, which at
//! 0.5 mm camera noise was enough for the rest test to see a change where there was none.
//! Lengths in metres.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::mesh::TriSurface;
use crate::registration::correspondences::rejection_threshold;
use crate::registration::surface_anchors::{closest_anchor, incident_triangles, SEARCH_VERTICES};
use crate::registration::IndexedPoints;
use crate::simulation::SceneModel;

/// A surface's vertices in a k-d tree with their triangles and unit outward vertex normals.
pub(super) struct SurfaceIndex {
    vertices: IndexedPoints,
    normals: Vec<Vector3<f64>>,
    triangles: Vec<[usize; 3]>,
    incident: Vec<Vec<usize>>,
}

impl SurfaceIndex {
    /// The surface of `model` deformed by `u` (m); `None` for an empty surface.
    pub(super) fn new(model: &SceneModel, u: &[f64]) -> Option<Self> {
        Self::of(
            model.surface_embedding.positions(u),
            &model.surface.triangles,
        )
    }

    /// The surface with vertices `x` (m) and `triangles`; `None` without vertices.
    fn of(x: Vec<Point3<f64>>, triangles: &[[usize; 3]]) -> Option<Self> {
        let normals = TriSurface::vertex_normals_at(&x, triangles);
        let incident = incident_triangles(x.len(), triangles);
        Some(Self {
            vertices: IndexedPoints::new(x)?,
            normals,
            triangles: triangles.to_vec(),
            incident,
        })
    }

    /// RMS distance (m) from `cloud` (m, model frame) to this surface after the mean + 2σ
    /// outlier rule; infinite when no point is kept.
    pub(super) fn fit_rms(&self, cloud: &[Point3<f64>]) -> f64 {
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
    /// closest point on the triangles around its nearest vertices, positive outside (module
    /// doc). A point whose triangles are all degenerate falls back to the tangent plane at its
    /// nearest vertex.
    pub(super) fn signed_distances(&self, cloud: &[Point3<f64>]) -> Vec<f64> {
        let x = &self.vertices.points;
        cloud
            .par_iter()
            .map_init(Vec::new, |seen, q| {
                let near = self.vertices.nearest_k(q, SEARCH_VERTICES);
                let closest = closest_anchor(
                    q,
                    x,
                    &self.triangles,
                    &self.incident,
                    near.iter().map(|(v, _)| *v),
                    seen,
                );
                let on_surface = closest.and_then(|(a, d2)| {
                    let n = a.normal(&self.normals, &self.triangles)?;
                    let gap = q - a.position(x, &self.triangles);
                    Some(d2.sqrt().copysign(n.dot(&gap)))
                });
                on_surface.unwrap_or_else(|| {
                    let i = near.first().map_or(0, |(v, _)| *v);
                    self.normals[i].dot(&(q - x[i]))
                })
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
    fn coarse_sphere() -> (TriSurface, SurfaceIndex) {
        let s = icosphere(Point3::origin(), 0.1, 1);
        let index = SurfaceIndex::of(s.vertices.clone(), &s.triangles).unwrap();
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
