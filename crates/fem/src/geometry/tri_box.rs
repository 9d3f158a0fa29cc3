//! Exact triangle–box overlap test (separating axis theorem, Akenine-Möller 2001).

use nalgebra::{Point3, Vector3};

use super::aabb::Aabb;

/// True when the closed triangle `tri` and the closed box `b` share at least one point.
///
/// Separating axis theorem with the 13 axes of Akenine-Möller ("Fast 3D triangle-box overlap
/// testing", 2001): the 3 box normals, the triangle normal and the 9 cross products of box and
/// triangle edge directions. Touching (a vertex on a face, an edge along an edge, a triangle
/// lying in a face plane) counts as overlap: a pair is reported disjoint only when some axis
/// separates the projections by a strictly positive gap.
///
/// The projections are taken in the original coordinates (no translation to the box centre), so
/// the box-axis tests and the tests along axes with zero components compare (products of) the
/// input coordinates themselves: touching configurations of axis-aligned geometry are decided
/// exactly. Elsewhere, exactly touching configurations are decided up to rounding. Degenerate (zero-area) triangles are handled correctly (a segment or point against
/// the box). An empty box overlaps nothing.
pub fn triangle_overlaps_box(tri: &[Point3<f64>; 3], b: &Aabb) -> bool {
    if b.is_empty() {
        return false;
    }
    let [v0, v1, v2] = tri;
    // 1. Box face normals: compare the triangle's bounding box with the box.
    for i in 0..3 {
        let lo = v0[i].min(v1[i]).min(v2[i]);
        let hi = v0[i].max(v1[i]).max(v2[i]);
        if lo > b.max[i] || hi < b.min[i] {
            return false;
        }
    }
    let edges = [v1 - v0, v2 - v1, v0 - v2];
    // 2. Triangle normal: all corners project to the same value (up to rounding).
    let n = edges[0].cross(&edges[1]);
    let p = n.dot(&v0.coords);
    if interval_separated(&n, p, p, b) {
        return false;
    }
    // 3. Cross products of box axes with triangle edges: e_i × edge = axis with a zero component.
    //    The two corners of the edge project to the same value, so only the edge's first corner
    //    and the opposite corner are projected (Akenine-Möller's shortcut).
    for (j, e) in edges.iter().enumerate() {
        let on = &tri[j].coords;
        let off = &tri[(j + 2) % 3].coords;
        let axes = [
            Vector3::new(0.0, -e.z, e.y),
            Vector3::new(e.z, 0.0, -e.x),
            Vector3::new(-e.y, e.x, 0.0),
        ];
        for a in &axes {
            let (p_on, p_off) = (a.dot(on), a.dot(off));
            if interval_separated(a, p_on.min(p_off), p_on.max(p_off), b) {
                return false;
            }
        }
    }
    true
}

/// True when the interval `[tmin, tmax]` (a triangle's projection onto `axis`) is strictly
/// disjoint from the projection of the box onto `axis`.
#[inline]
fn interval_separated(axis: &Vector3<f64>, tmin: f64, tmax: f64, b: &Aabb) -> bool {
    let mut bmin = 0.0;
    let mut bmax = 0.0;
    for i in 0..3 {
        let lo = axis[i] * b.min[i];
        let hi = axis[i] * b.max[i];
        if axis[i] >= 0.0 {
            bmin += lo;
            bmax += hi;
        } else {
            bmin += hi;
            bmax += lo;
        }
    }
    tmin > bmax || tmax < bmin
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::random::Rng;

    fn p(x: f64, y: f64, z: f64) -> Point3<f64> {
        Point3::new(x, y, z)
    }

    fn unit_box() -> Aabb {
        Aabb::new(p(0.0, 0.0, 0.0), p(1.0, 1.0, 1.0))
    }

    /// Reference: clip the triangle polygon against the six half-spaces of the box
    /// (Sutherland–Hodgman); the triangle overlaps the box iff something is left.
    fn clip_reference(tri: &[Point3<f64>; 3], b: &Aabb) -> bool {
        let mut poly: Vec<Point3<f64>> = tri.to_vec();
        for axis in 0..3 {
            for (sign, bound) in [(1.0, b.max[axis]), (-1.0, b.min[axis])] {
                // Keep sign * (x - bound) <= 0.
                let f = |q: &Point3<f64>| sign * (q[axis] - bound);
                let mut next = Vec::new();
                for i in 0..poly.len() {
                    let a = poly[i];
                    let c = poly[(i + 1) % poly.len()];
                    let (fa, fc) = (f(&a), f(&c));
                    if fa <= 0.0 {
                        next.push(a);
                    }
                    if (fa < 0.0 && fc > 0.0) || (fa > 0.0 && fc < 0.0) {
                        let t = fa / (fa - fc);
                        next.push(a + (c - a) * t);
                    }
                }
                poly = next;
                if poly.is_empty() {
                    return false;
                }
            }
        }
        true
    }

    #[test]
    fn random_cases_match_clipping_reference() {
        let mut rng = Rng::new(0x1234_5678_9abc_def1);
        let mut decided = 0;
        let (mut hits, mut misses) = (0, 0);
        for _ in 0..20_000 {
            let c = rng.point_in_cube(-1.0, 1.0);
            let h =
                nalgebra::Vector3::new(rng.uniform_in(0.05, 0.6), rng.uniform_in(0.05, 0.6), 0.3);
            let b = Aabb::new(c - h, c + h);
            let scale = rng.uniform_in(0.1, 2.0);
            let base = c + rng.point_in_cube(-1.0, 1.0).coords;
            let tri = [
                base,
                base + rng.point_in_cube(-1.0, 1.0).coords * scale,
                base + rng.point_in_cube(-1.0, 1.0).coords * scale,
            ];
            let got = triangle_overlaps_box(&tri, &b);
            // Decide only cases that are robust to rounding: overlap with the shrunk box
            // implies overlap, no overlap with the grown box implies a miss.
            let delta = 1e-9;
            if clip_reference(&tri, &b.expanded(-delta)) {
                assert!(got, "missed overlap: {tri:?} {b:?}");
                decided += 1;
                hits += 1;
            } else if !clip_reference(&tri, &b.expanded(delta)) {
                assert!(!got, "false overlap: {tri:?} {b:?}");
                decided += 1;
                misses += 1;
            }
            // Dense samples on the triangle inside the box imply overlap.
            for _ in 0..8 {
                let (mut u, mut v) = (rng.uniform(), rng.uniform());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let q = tri[0] + (tri[1] - tri[0]) * u + (tri[2] - tri[0]) * v;
                if b.contains(&q) {
                    assert!(got);
                }
            }
        }
        assert!(decided > 19_900, "decided {decided}");
        assert!(
            hits > 2_000 && misses > 2_000,
            "hits {hits} misses {misses}"
        );
    }

    #[test]
    fn touching_cases_count_as_overlap() {
        let b = unit_box();
        // Vertex exactly on a face, rest outside.
        assert!(triangle_overlaps_box(
            &[p(1.0, 0.5, 0.5), p(2.0, 0.0, 0.0), p(2.0, 1.0, 1.0)],
            &b
        ));
        // Vertex exactly on a corner.
        assert!(triangle_overlaps_box(
            &[p(1.0, 1.0, 1.0), p(2.0, 1.0, 3.0), p(1.5, 3.0, 1.0)],
            &b
        ));
        // Edge lying along a box edge (triangle outside otherwise).
        assert!(triangle_overlaps_box(
            &[p(1.0, 0.0, 0.0), p(1.0, 0.0, 1.0), p(2.0, -1.0, 0.5)],
            &b
        ));
        // Edge crossing a box edge at a single point (skew), no vertex inside.
        assert!(triangle_overlaps_box(
            &[p(1.5, -0.5, 0.5), p(0.5, 0.5, 0.5), p(1.5, -0.5, 3.0)],
            &b
        ));
        // Triangle lying in the plane of a face, overlapping it.
        assert!(triangle_overlaps_box(
            &[p(0.5, 0.5, 1.0), p(3.0, 0.5, 1.0), p(0.5, 3.0, 1.0)],
            &b
        ));
        // Triangle in a face plane touching only the face's corner.
        assert!(triangle_overlaps_box(
            &[p(1.0, 1.0, 1.0), p(3.0, 1.0, 1.0), p(1.0, 3.0, 1.0)],
            &b
        ));
        // Large triangle slicing through the box with all vertices outside.
        assert!(triangle_overlaps_box(
            &[p(-5.0, -5.0, 0.5), p(10.0, -5.0, 0.5), p(-5.0, 10.0, 0.5)],
            &b
        ));
        // Triangle containing the box's diagonal corner region: plane x+y+z = 1.5.
        assert!(triangle_overlaps_box(
            &[p(1.5, 0.0, 0.0), p(0.0, 1.5, 0.0), p(0.0, 0.0, 1.5)],
            &b
        ));
        // Plane x + y + z = 3 touches only the corner (1,1,1).
        assert!(triangle_overlaps_box(
            &[p(3.0, 0.0, 0.0), p(0.0, 3.0, 0.0), p(0.0, 0.0, 3.0)],
            &b
        ));
        // Degenerate triangles: a segment through the box and a point on a face.
        assert!(triangle_overlaps_box(
            &[p(-1.0, 0.5, 0.5), p(2.0, 0.5, 0.5), p(2.0, 0.5, 0.5)],
            &b
        ));
        assert!(triangle_overlaps_box(
            &[p(0.5, 0.0, 0.5), p(0.5, 0.0, 0.5), p(0.5, 0.0, 0.5)],
            &b
        ));
    }

    #[test]
    fn near_misses_are_separated() {
        let b = unit_box();
        let e = 1e-12;
        // Just beyond a face.
        assert!(!triangle_overlaps_box(
            &[p(1.0 + e, 0.5, 0.5), p(2.0, 0.0, 0.0), p(2.0, 1.0, 1.0)],
            &b
        ));
        // Plane x + y + z = 3 + e misses the corner (only the normal axis separates).
        let t = 3.0 + 4.0 * e;
        assert!(!triangle_overlaps_box(
            &[p(t, 0.0, 0.0), p(0.0, t, 0.0), p(0.0, 0.0, t)],
            &b
        ));
        // Degenerate triangle (segment) on the line x - y = 1 + d passing just outside the
        // box edge x = 1, y = 0: its bounding box overlaps the box and its normal is zero, so
        // only an edge cross axis separates it.
        let d = 1e-9;
        assert!(!triangle_overlaps_box(
            &[
                p(0.5, -0.5 - d, 0.5),
                p(2.0, 1.0 - d, 0.5),
                p(2.0, 1.0 - d, 0.5)
            ],
            &b
        ));
        // The same segment moved onto the edge touches it.
        assert!(triangle_overlaps_box(
            &[p(0.5, -0.5, 0.5), p(2.0, 1.0, 0.5), p(2.0, 1.0, 0.5)],
            &b
        ));
        // A proper (vertical) triangle through that line, beside the edge.
        assert!(!triangle_overlaps_box(
            &[
                p(0.5, -0.5 - d, 0.5),
                p(2.0, 1.0 - d, 0.5),
                p(1.25, 0.25 - d, 3.0)
            ],
            &b
        ));
        // Empty box.
        assert!(!triangle_overlaps_box(
            &[p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0), p(0.0, 1.0, 0.0)],
            &Aabb::EMPTY
        ));
    }
}
