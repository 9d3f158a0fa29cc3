//! Signed crossings of lines parallel to the z axis with a triangle set.
//!
//! A line `{(x, y, z) : z ∈ ℝ}` crosses a triangle when `(x, y)` lies in the triangle's
//! projection onto the (x, y) plane. Hits exactly on a projected edge or vertex are resolved by
//! symbolic perturbation (the line is moved to `(x + ε, y + ε²)`, see
//! [`super::predicates::orient2d_perturbed`]) with exact orientation signs. The perturbed line
//! is in general position with respect to every input point, so the crossings reported for a
//! closed (cycle) surface always sum to zero, whichever edges and vertices the line passes
//! through, and a running sum of crossings equals the winding number of the perturbed line's
//! points.

use nalgebra::Point3;

use super::bucket_grid::BucketGrid;
use super::predicates::{orient2d, orient2d_perturbed};

/// Projected triangle, counter-clockwise in (x, y), with its crossing weight.
#[derive(Clone, Copy, Debug)]
struct LineTri {
    /// `[x_min, y_min, x_max, y_max]` of the projection.
    rect: [f64; 4],
    /// Projected corners, counter-clockwise.
    xy: [[f64; 2]; 3],
    /// z of the corners (same order as `xy`).
    z: [f64; 3],
    /// Signed crossing weight: +m when the upward line enters the surface through the triangle
    /// (outward normal pointing down), −m when it leaves, with m the triangle's multiplicity.
    weight: i32,
}

/// Index of a triangle set for crossing queries along z-parallel lines: projected triangles in
/// a [`BucketGrid`] over (x, y).
#[derive(Clone, Debug, Default)]
pub(crate) struct ZLineIndex {
    tris: Vec<LineTri>,
    grid: BucketGrid,
}

impl ZLineIndex {
    /// Indexes `tris`, each given as its corners (right-hand orientation = outward normal) and
    /// a multiplicity (how many times it counts, may be negative). Triangles with non-finite
    /// corners and triangles whose projection has exactly zero area (vertical ones, which a
    /// perturbed line never crosses) are dropped.
    pub(crate) fn new<I>(tris: I) -> Self
    where
        I: IntoIterator<Item = ([Point3<f64>; 3], i32)>,
    {
        let mut out = Vec::new();
        for (t, mult) in tris {
            if mult == 0 || !t.iter().all(crate::mesh::is_finite_point) {
                continue;
            }
            let mut xy = [[t[0].x, t[0].y], [t[1].x, t[1].y], [t[2].x, t[2].y]];
            let mut z = [t[0].z, t[1].z, t[2].z];
            let (_, s) = orient2d(xy[0], xy[1], xy[2]);
            if s == 0 {
                continue;
            }
            if s < 0 {
                xy.swap(1, 2);
                z.swap(1, 2);
            }
            // Counter-clockwise projection ⇔ normal z > 0 ⇔ the upward line leaves.
            let weight = -i32::from(s) * mult;
            let rect = [
                xy[0][0].min(xy[1][0]).min(xy[2][0]),
                xy[0][1].min(xy[1][1]).min(xy[2][1]),
                xy[0][0].max(xy[1][0]).max(xy[2][0]),
                xy[0][1].max(xy[1][1]).max(xy[2][1]),
            ];
            out.push(LineTri {
                rect,
                xy,
                z,
                weight,
            });
        }
        let rects: Vec<[f64; 4]> = out.iter().map(|t| t.rect).collect();
        ZLineIndex {
            grid: BucketGrid::build(&rects, 1.0),
            tris: out,
        }
    }

    /// Calls `f(z, weight)` for every crossing of the line through `(x, y)` parallel to z, in
    /// no particular order: `z` is the crossing height (interpolated in the triangle's plane,
    /// clamped to its z range) and `weight` is +m when the line, going towards +z, enters the
    /// surface and −m when it leaves.
    #[inline]
    pub(crate) fn for_each_crossing(&self, x: f64, y: f64, mut f: impl FnMut(f64, i32)) {
        let p = [x, y];
        for &k in self.grid.candidates(x, y) {
            let t = &self.tris[k as usize];
            if x < t.rect[0] || x > t.rect[2] || y < t.rect[1] || y > t.rect[3] {
                continue;
            }
            let (e2, s2) = orient2d_perturbed(t.xy[0], t.xy[1], p);
            if s2 <= 0 {
                continue;
            }
            let (e0, s0) = orient2d_perturbed(t.xy[1], t.xy[2], p);
            if s0 <= 0 {
                continue;
            }
            let (e1, s1) = orient2d_perturbed(t.xy[2], t.xy[0], p);
            if s1 <= 0 {
                continue;
            }
            // Barycentric weights of corners 0, 1, 2 (non-negative up to rounding).
            let (w0, w1, w2) = (e0.max(0.0), e1.max(0.0), e2.max(0.0));
            let sum = w0 + w1 + w2;
            let zmin = t.z[0].min(t.z[1]).min(t.z[2]);
            let zmax = t.z[0].max(t.z[1]).max(t.z[2]);
            let z = if sum > 0.0 {
                ((w0 * t.z[0] + w1 * t.z[1] + w2 * t.z[2]) / sum).clamp(zmin, zmax)
            } else {
                (t.z[0] + t.z[1] + t.z[2]) / 3.0
            };
            f(z, t.weight);
        }
    }
}
