//! Inside/outside classification of points against a triangle surface.

use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::Point3;

use super::aabb::Aabb;
use super::bvh::Bvh;
use super::holes::HoleCaps;
use super::line_crossings::ZLineIndex;
use super::tri_box::triangle_overlaps_box;
use super::winding::{self, ExpansionOrder, FastWinding, DEFAULT_BETA};

/// Errors detected when building an [`InsideTest`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GeometryError {
    /// A triangle refers to a vertex that does not exist.
    #[error("triangle {triangle} uses vertex {vertex}, but there are only {n_vertices} vertices")]
    VertexIndexOutOfRange {
        /// Index of the offending triangle.
        triangle: usize,
        /// The out-of-range vertex index.
        vertex: usize,
        /// Number of vertices supplied.
        n_vertices: usize,
    },
}

/// Maximum number of triangles per BVH leaf.
const LEAF_SIZE: usize = 4;

/// Half-width of the band around ½ in which [`InsideTest::contains`] recomputes the winding
/// number exactly instead of trusting the approximation.
const AMBIGUITY_BAND: f64 = 0.1;

/// Crossings kept on the stack in [`InsideTest::classify_line`] before spilling to the heap.
const INLINE_CROSSINGS: usize = 16;

/// Inside/outside classification of points against a triangle surface (lengths in the
/// surface's units).
///
/// "Inside" means generalised winding number ≥ ½ (Jacobson et al. 2013): for a closed,
/// outward-oriented surface this is the usual interior (nested or overlapping sheets count by
/// winding), and it degrades gracefully for surfaces with holes or flipped triangles.
///
/// Built once (O(n log n)), then shared between threads (`Send + Sync`):
/// * [`InsideTest::winding_number`]: BVH far-field (multipole) approximation, O(log n)-ish;
///   [`InsideTest::contains`] thresholds it at ½.
/// * [`InsideTest::classify_line`]: many points on one z-parallel line from the line's signed
///   crossings with the surface (exact predicates; hits on edges and vertices are resolved by
///   symbolic perturbation), with the winding number as fallback near holes.
/// * [`InsideTest::triangles_overlapping`]: triangles cutting a box (BVH + exact SAT test).
///
/// Points exactly on the surface are boundary cases: `contains` and `classify_line` may
/// disagree there (the winding number is fractional on the surface, e.g. ½ on a face, ¼ on a
/// convex cube edge, while the crossing count treats the line as moved infinitesimally towards
/// +x, then +y, and a crossing at exactly the query height as lying above it).
#[derive(Debug)]
pub struct InsideTest {
    /// Corners of the finite triangles, in input order (after dropping non-finite ones).
    tris: Vec<[Point3<f64>; 3]>,
    /// Input index of each entry of `tris`.
    tri_ids: Vec<usize>,
    /// True when no triangle was dropped (`tri_ids[i] == i`).
    identity_ids: bool,
    bvh: Bvh,
    fast: FastWinding,
    lines: ZLineIndex,
    /// Influence boxes of the hole caps (empty for closed surfaces).
    influence: Vec<Aabb>,
    boundary_edges: usize,
    beta: f64,
    order: ExpansionOrder,
    fallback_lines: AtomicUsize,
    fallback_points: AtomicUsize,
}

impl InsideTest {
    /// Builds the classifier for `triangles` (vertex indices into `vertices`, right-hand
    /// orientation = outward normal).
    ///
    /// Triangles with a non-finite corner are ignored.
    ///
    /// # Panics
    /// If a triangle refers to a vertex index `≥ vertices.len()` (see [`InsideTest::try_new`]).
    pub fn new(vertices: &[Point3<f64>], triangles: &[[usize; 3]]) -> Self {
        match Self::try_new(vertices, triangles) {
            Ok(t) => t,
            Err(e) => panic!("InsideTest::new: {e}"),
        }
    }

    /// Like [`InsideTest::new`], but reports out-of-range vertex indices as an error.
    pub fn try_new(
        vertices: &[Point3<f64>],
        triangles: &[[usize; 3]],
    ) -> Result<Self, GeometryError> {
        let mut tris = Vec::with_capacity(triangles.len());
        let mut tri_ids = Vec::with_capacity(triangles.len());
        for (k, t) in triangles.iter().enumerate() {
            if let Some(&v) = t.iter().find(|&&v| v >= vertices.len()) {
                return Err(GeometryError::VertexIndexOutOfRange {
                    triangle: k,
                    vertex: v,
                    n_vertices: vertices.len(),
                });
            }
            let c = t.map(|i| vertices[i]);
            if c.iter().all(crate::mesh::is_finite_point) {
                tris.push(c);
                tri_ids.push(k);
            }
        }
        // The BVH/winding data and the line index are independent: build them concurrently.
        let ((bvh, fast), (caps, lines)) = rayon::join(
            || {
                let boxes: Vec<Aabb> = tris.iter().map(Aabb::from_points).collect();
                let bvh = Bvh::build(&boxes, LEAF_SIZE);
                let fast = FastWinding::new(&bvh, &tris);
                (bvh, fast)
            },
            || {
                let caps = HoleCaps::new(&tris);
                let lines = ZLineIndex::new(
                    tris.iter()
                        .map(|t| (*t, 1))
                        .chain(caps.triangles.iter().copied()),
                );
                (caps, lines)
            },
        );
        Ok(InsideTest {
            identity_ids: tri_ids.len() == triangles.len(),
            tris,
            tri_ids,
            bvh,
            fast,
            lines,
            influence: caps.influence,
            boundary_edges: caps.boundary_edges,
            beta: DEFAULT_BETA,
            order: ExpansionOrder::SecondOrder,
            fallback_lines: AtomicUsize::new(0),
            fallback_points: AtomicUsize::new(0),
        })
    }

    /// Sets the accuracy of the fast winding number: a BVH node is replaced by its far-field
    /// expansion of the given `order` when the query is farther than `beta` × node radius.
    /// Default: β = 2, [`ExpansionOrder::SecondOrder`] (max error ≈ 0.006 away from the
    /// surface; the dipole alone gives ≈ 0.05 at β = 2, see [`FastWinding::eval`]).
    ///
    /// # Panics
    /// If `beta` is not finite and > 1.
    pub fn with_accuracy(mut self, beta: f64, order: ExpansionOrder) -> Self {
        assert!(
            beta.is_finite() && beta > 1.0,
            "beta must be > 1, got {beta}"
        );
        self.beta = beta;
        self.order = order;
        self
    }

    /// Number of (finite) triangles in use.
    pub fn num_triangles(&self) -> usize {
        self.tris.len()
    }

    /// Bounding box of the surface ([`Aabb::EMPTY`] without triangles).
    pub fn bounds(&self) -> Aabb {
        self.bvh.bounds()
    }

    /// True when the surface has no boundary: every edge (vertices identified by exact
    /// coordinates) is used as often in one direction as in the other.
    pub fn is_closed(&self) -> bool {
        self.boundary_edges == 0
    }

    /// Number of boundary edges (net unmatched directed edges, with multiplicity).
    pub fn boundary_edges(&self) -> usize {
        self.boundary_edges
    }

    /// Generalised winding number at `p` (dimensionless): ≈1 inside a closed outward surface,
    /// ≈0 outside, fractional near holes and ½ on the surface.
    ///
    /// BVH far-field approximation (Barill et al. 2018): a node farther than β × its radius
    /// contributes its far-field expansion (dipole plus first- and second-order terms by
    /// default), nearer triangles their exact solid angles (Van Oosterom–Strackee).
    /// Error ≲ 0.006 for the default β = 2 away from the surface
    /// (see [`InsideTest::with_accuracy`]).
    pub fn winding_number(&self, p: &Point3<f64>) -> f64 {
        self.fast.eval(&self.bvh, p, self.beta, self.order)
    }

    /// Like [`InsideTest::winding_number`] with an explicit accuracy parameter `beta` (> 1)
    /// and expansion `order`.
    pub fn winding_number_with(&self, p: &Point3<f64>, beta: f64, order: ExpansionOrder) -> f64 {
        self.fast.eval(&self.bvh, p, beta, order)
    }

    /// Exact generalised winding number at `p` (sum of all solid angles / 4π), O(n).
    pub fn winding_number_exact(&self, p: &Point3<f64>) -> f64 {
        winding::winding_number_brute(&self.tris, p)
    }

    /// True when `p` is inside: winding number ≥ ½.
    ///
    /// Uses the fast winding number, and the exact one when the fast value is within 0.1 of ½
    /// (only near the surface or near holes), so the decision equals the exact one whenever
    /// the approximation error is below 0.1.
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        let w = self.winding_number(p);
        if (w - 0.5).abs() < AMBIGUITY_BAND {
            self.winding_number_exact(p) >= 0.5
        } else {
            w >= 0.5
        }
    }

    /// Signed crossings of the line through `(x, y)` parallel to z with the surface, sorted by
    /// height: `(z, weight)` with weight +1 where the line (going towards +z) enters and −1
    /// where it leaves (±m for repeated triangles). Includes crossings with the virtual caps
    /// that close holes, if any. `out` is cleared first.
    pub fn line_crossings(&self, x: f64, y: f64, out: &mut Vec<(f64, i32)>) {
        out.clear();
        self.lines.for_each_crossing(x, y, |z, w| out.push((z, w)));
        out.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    }

    /// Classifies points on the line `{(x, y, z)}` parallel to the z axis: after the call,
    /// `out[k]` is true when `(x, y, zs[k])` is inside (`out` is cleared first; `zs` may be in
    /// any order).
    ///
    /// The line's signed crossings with the surface are found through a 2D bucket grid over
    /// (x, y); the point at height z is inside when the sum of the crossings strictly below z
    /// is ≥ 1. Hits on edges and vertices are decided with exact predicates and a consistent
    /// symbolic perturbation, so for a closed surface the crossings always sum to zero and the
    /// result equals the winding-number decision for every point not on the surface.
    ///
    /// Surfaces with holes are closed by virtual cone caps; points inside a cap's influence
    /// box (where the cap could change the decision) are classified with
    /// [`InsideTest::contains`]. A line whose crossings do not sum to zero (not expected with
    /// exact predicates; kept as a safety net) is classified entirely with `contains`. Both
    /// count towards [`InsideTest::fallback_lines`].
    pub fn classify_line(&self, x: f64, y: f64, zs: &[f64], out: &mut Vec<bool>) {
        out.clear();
        if zs.is_empty() {
            return;
        }
        let mut inline = [(0.0f64, 0i32); INLINE_CROSSINGS];
        let mut n = 0usize;
        let mut spill: Vec<(f64, i32)> = Vec::new();
        self.lines.for_each_crossing(x, y, |z, w| {
            if n < INLINE_CROSSINGS {
                inline[n] = (z, w);
            } else {
                if spill.is_empty() {
                    spill.extend_from_slice(&inline);
                }
                spill.push((z, w));
            }
            n += 1;
        });
        let crossings: &mut [(f64, i32)] = if n <= INLINE_CROSSINGS {
            &mut inline[..n]
        } else {
            &mut spill
        };
        let total: i32 = crossings.iter().map(|c| c.1).sum();
        if total != 0 {
            self.fallback_lines.fetch_add(1, Ordering::Relaxed);
            self.fallback_points.fetch_add(zs.len(), Ordering::Relaxed);
            out.extend(zs.iter().map(|&z| self.contains(&Point3::new(x, y, z))));
            return;
        }
        // Insertion sort for the usual few crossings, then prefix sums in place of the weights.
        if crossings.len() > INLINE_CROSSINGS {
            crossings.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        } else {
            for i in 1..crossings.len() {
                let mut j = i;
                while j > 0 && crossings[j - 1].0 > crossings[j].0 {
                    crossings.swap(j - 1, j);
                    j -= 1;
                }
            }
        }
        let mut acc = 0;
        for c in crossings.iter_mut() {
            acc += c.1;
            c.1 = acc;
        }
        let crossings: &[(f64, i32)] = crossings;
        match crossings.len() {
            0 => out.resize(zs.len(), false),
            2 if crossings[0].1 == 1 => {
                // The common case: one interval (z0, z1].
                let (z0, z1) = (crossings[0].0, crossings[1].0);
                out.extend(zs.iter().map(|&z| z > z0 && z <= z1));
            }
            _ => out.extend(zs.iter().map(|&z| {
                let k = crossings.partition_point(|c| c.0 < z);
                k > 0 && crossings[k - 1].1 >= 1
            })),
        }
        if !self.influence.is_empty() {
            self.refine_near_holes(x, y, zs, out);
        }
    }

    /// Re-classifies with the winding number the points of a line that lie in a hole cap's
    /// influence box.
    fn refine_near_holes(&self, x: f64, y: f64, zs: &[f64], out: &mut [bool]) {
        let mut used = 0;
        for b in &self.influence {
            if !(b.min.x <= x && x <= b.max.x && b.min.y <= y && y <= b.max.y) {
                continue;
            }
            for (k, &z) in zs.iter().enumerate() {
                if b.min.z <= z && z <= b.max.z {
                    out[k] = self.contains(&Point3::new(x, y, z));
                    used += 1;
                }
            }
        }
        if used > 0 {
            self.fallback_lines.fetch_add(1, Ordering::Relaxed);
            self.fallback_points.fetch_add(used, Ordering::Relaxed);
        }
    }

    /// Indices (into the input `triangles`) of the triangles that overlap the closed box `b`
    /// (exact separating-axis test, touching counts), found through the BVH, in increasing
    /// order. `out` is cleared first.
    pub fn triangles_overlapping(&self, b: &Aabb, out: &mut Vec<usize>) {
        out.clear();
        self.bvh.visit_overlapping(b, |i| {
            if triangle_overlaps_box(&self.tris[i], b) {
                out.push(self.tri_ids[i]);
            }
        });
        out.sort_unstable();
    }

    /// Indices (into the input `triangles`) of the triangles whose bounding box intersects the
    /// closed box `b`: a conservative superset of [`InsideTest::triangles_overlapping`],
    /// in increasing order. `out` is cleared first.
    pub fn triangles_bbox_overlapping(&self, b: &Aabb, out: &mut Vec<usize>) {
        out.clear();
        self.bvh.visit_overlapping(b, |i| out.push(self.tri_ids[i]));
        out.sort_unstable();
    }

    /// Filters candidate triangles (input indices, e.g. the result of
    /// [`InsideTest::triangles_overlapping`] for a parent box) down to those overlapping `b`;
    /// order is preserved. Cheaper than a BVH query when refining a box recursively.
    /// `out` is cleared first.
    pub fn filter_overlapping(&self, candidates: &[usize], b: &Aabb, out: &mut Vec<usize>) {
        out.clear();
        for &t in candidates {
            if let Some(i) = self.position(t) {
                if triangle_overlaps_box(&self.tris[i], b) {
                    out.push(t);
                }
            }
        }
    }

    /// The corners of input triangle `t`, or `None` if it was dropped (non-finite corner) or
    /// does not exist.
    pub fn triangle(&self, t: usize) -> Option<[Point3<f64>; 3]> {
        self.position(t).map(|i| self.tris[i])
    }

    /// Position in `tris` of input triangle `t`.
    #[inline]
    fn position(&self, t: usize) -> Option<usize> {
        if self.identity_ids {
            (t < self.tris.len()).then_some(t)
        } else {
            self.tri_ids.binary_search(&t).ok()
        }
    }

    /// Number of lines so far for which [`InsideTest::classify_line`] used the winding number
    /// for at least one point (diagnostic; counts across all threads).
    pub fn fallback_lines(&self) -> usize {
        self.fallback_lines.load(Ordering::Relaxed)
    }

    /// Number of points so far that [`InsideTest::classify_line`] classified with the winding
    /// number instead of crossings (diagnostic).
    pub fn fallback_points(&self) -> usize {
        self.fallback_points.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_send_sync<T: Send + Sync>() {}

    #[test]
    fn is_send_and_sync() {
        assert_send_sync::<InsideTest>();
    }

    #[test]
    fn bad_index_is_reported() {
        let v = [Point3::origin(); 3];
        let e = InsideTest::try_new(&v, &[[0, 1, 3]]).unwrap_err();
        assert_eq!(
            e,
            GeometryError::VertexIndexOutOfRange {
                triangle: 0,
                vertex: 3,
                n_vertices: 3
            }
        );
    }

    #[test]
    fn non_finite_triangles_are_dropped_but_indices_kept() {
        let (mut v, mut t) = crate::geometry::shapes::icosphere(1, 1.0);
        v.push(Point3::new(f64::NAN, 0.0, 0.0));
        let bad = v.len() - 1;
        t.insert(3, [0, 1, bad]);
        let inside = InsideTest::new(&v, &t);
        assert_eq!(inside.num_triangles(), t.len() - 1);
        assert!(inside.triangle(3).is_none());
        let b = Aabb::new(Point3::new(-2.0, -2.0, -2.0), Point3::new(2.0, 2.0, 2.0));
        let mut all = Vec::new();
        inside.triangles_overlapping(&b, &mut all);
        let want: Vec<usize> = (0..t.len()).filter(|&k| k != 3).collect();
        assert_eq!(all, want);
        let mut filtered = Vec::new();
        inside.filter_overlapping(&(0..t.len()).collect::<Vec<_>>(), &b, &mut filtered);
        assert_eq!(filtered, want);
        assert!(inside.contains(&Point3::origin()));
        let mut out = Vec::new();
        inside.classify_line(0.01, 0.02, &[-2.0, 0.0, 2.0], &mut out);
        assert_eq!(out, [false, true, false]);
        assert!(inside.is_closed());
    }

    #[test]
    fn empty_surface_contains_nothing() {
        let t = InsideTest::new(&[], &[]);
        let mut out = Vec::new();
        t.classify_line(0.0, 0.0, &[0.0, 1.0], &mut out);
        assert_eq!(out, [false, false]);
        assert!(!t.contains(&Point3::origin()));
        assert!(t.is_closed());
    }
}
