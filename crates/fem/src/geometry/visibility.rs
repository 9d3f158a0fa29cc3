//! Line-of-sight visibility of points on a triangle surface from a [`Camera`], by ray casting
//! against a parry3d BVH. Lengths in metres.
//!
//! parry3d works in `f32` (glam types); the surface is re-centred on its bounding-box centre
//! before conversion so that the single-precision round-off stays far below the visibility
//! tolerance (about 1e-7 of the surface size).

use nalgebra::Point3;
use parry3d::math::Vector;
use parry3d::query::{Ray, RayCast};
use parry3d::shape::TriMesh;
use rayon::prelude::*;

use super::camera::Camera;
use super::view_error::ViewError;
use crate::mesh::TriSurface;

/// Relative part of the visibility tolerance (times the bounding-box diagonal).
const REL_TOLERANCE: f64 = 1e-6;
/// Absolute part of the visibility tolerance, metres.
const ABS_TOLERANCE: f64 = 1e-5;

/// A surface prepared for visibility queries (the ray-casting BVH is built once).
pub struct VisibleSurface {
    mesh: TriMesh,
    /// Offset subtracted from every coordinate before conversion to `f32`, metres.
    centre: Point3<f64>,
    /// The surface's own vertices, metres (for [`VisibleSurface::visible_vertices`]).
    vertices: Vec<Point3<f64>>,
    /// How much earlier than a point a surface hit may be and still count as that point.
    tolerance: f64,
}

impl std::fmt::Debug for VisibleSurface {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VisibleSurface")
            .field("triangles", &self.mesh.num_triangles())
            .field("vertices", &self.vertices.len())
            .field("tolerance", &self.tolerance)
            .finish()
    }
}

/// Checks that `surface` is non-empty, finite and has in-range indices.
pub fn check_surface(surface: &TriSurface) -> Result<(), ViewError> {
    if surface.triangles.is_empty() || surface.vertices.is_empty() {
        return Err(ViewError::EmptySurface {
            vertices: surface.vertices.len(),
            triangles: surface.triangles.len(),
        });
    }
    if let Some(i) = crate::mesh::first_non_finite_point(&surface.vertices) {
        return Err(ViewError::InvalidSurface(format!(
            "vertex {i} has a non-finite coordinate {:?}",
            surface.vertices[i].coords.as_slice()
        )));
    }
    let n = surface.vertices.len();
    if n > u32::MAX as usize {
        return Err(ViewError::InvalidSurface(format!(
            "{n} vertices is more than the ray caster's 32-bit indices allow"
        )));
    }
    if let Some((t, tri)) = surface
        .triangles
        .iter()
        .enumerate()
        .find(|(_, tri)| tri.iter().any(|&i| i >= n))
    {
        return Err(ViewError::InvalidSurface(format!(
            "triangle {t} {tri:?} indexes past the {n} vertices"
        )));
    }
    Ok(())
}

impl VisibleSurface {
    /// Builds the ray-casting structure for `surface` (metres). Fails on an empty surface,
    /// out-of-range indices or non-finite coordinates.
    pub fn new(surface: &TriSurface) -> Result<Self, ViewError> {
        check_surface(surface)?;
        let (lo, hi) = surface.bounding_box().expect("non-empty surface");
        let centre = nalgebra::center(&lo, &hi);
        let diagonal = (hi - lo).norm();
        let verts: Vec<Vector> = surface
            .vertices
            .iter()
            .map(|v| to_glam(&(v - centre)))
            .collect();
        let idx: Vec<[u32; 3]> = surface
            .triangles
            .iter()
            .map(|t| [t[0] as u32, t[1] as u32, t[2] as u32])
            .collect();
        let mesh = TriMesh::new(verts, idx)
            .map_err(|e| ViewError::InvalidSurface(format!("ray-casting mesh: {e:?}")))?;
        Ok(Self {
            mesh,
            centre,
            vertices: surface.vertices.clone(),
            tolerance: REL_TOLERANCE * diagonal + ABS_TOLERANCE,
        })
    }

    /// The visibility tolerance, metres: a surface hit up to this much in front of a point
    /// still counts as the point itself (`1e-6 × bounding-box diagonal + 1e-5 m`).
    pub fn tolerance(&self) -> f64 {
        self.tolerance
    }

    /// Whether each of `points` (metres, normally on the surface) is visible from `camera`:
    /// inside its field-of-view cone, and the first surface hit along the ray from the camera
    /// towards the point is the point itself (no hit more than [`Self::tolerance`] before
    /// it). Computed in parallel; the result does not depend on the number of threads. The
    /// camera should be valid ([`Camera::validate`]); an invalid one sees nothing.
    pub fn visible(&self, camera: &Camera, points: &[Point3<f64>]) -> Vec<bool> {
        points
            .par_iter()
            .with_min_len(64)
            .map(|p| self.is_visible(camera, p))
            .collect()
    }

    /// [`Self::visible`] for the surface's own vertices (the registration source points).
    pub fn visible_vertices(&self, camera: &Camera) -> Vec<bool> {
        self.visible(camera, &self.vertices)
    }

    /// Visibility of a single point (see [`Self::visible`]).
    pub fn is_visible(&self, camera: &Camera, p: &Point3<f64>) -> bool {
        if !camera.in_field_of_view(p) {
            return false;
        }
        let d = p - camera.position;
        let dist = d.norm();
        let max_toi = dist - self.tolerance;
        if max_toi <= 0.0 {
            return true;
        }
        let ray = Ray::new(
            to_glam(&(camera.position - self.centre)),
            to_glam(&(d / dist)),
        );
        self.mesh
            .cast_local_ray(&ray, max_toi as f32, false)
            .is_none()
    }
}

/// nalgebra (f64) to parry/glam (f32) vector.
fn to_glam(v: &nalgebra::Vector3<f64>) -> Vector {
    Vector::new(v.x as f32, v.y as f32, v.z as f32)
}
