//! The cloud → surface data term of non-rigid ICP: every cloud point is paired with
//! its closest point on the model's current deformed surface — a point inside a triangle,
//! given by its barycentric weights (a [`SurfaceAnchor`]) — and the spring acts there. Every
//! point of a partial cloud has a counterpart on the whole model, but not the reverse, so this
//! direction needs no guess of which model points the camera saw: there is nothing to drag
//! onto the rim of a partial cloud, and a cloud point at the bottom of a deep dent pulls the
//! surface point above it however far it is. Lengths in metres.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::correspondences::{IndexedPoints, PairingRule};
use super::correspondences::{RIM_NEIGHBOURS, RIM_RATIO};
use crate::geometry::closest_barycentric;

/// A point of the model surface: a triangle and barycentric weights of its corners.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceAnchor {
    /// Triangle index.
    pub triangle: usize,
    /// Barycentric weights of the triangle's corners (sum 1).
    pub weights: [f64; 3],
}

impl SurfaceAnchor {
    /// The anchor's position on a surface whose vertices are at `x`.
    pub fn position(&self, x: &[Point3<f64>], triangles: &[[usize; 3]]) -> Point3<f64> {
        let t = triangles[self.triangle];
        Point3::from(
            x[t[0]].coords * self.weights[0]
                + x[t[1]].coords * self.weights[1]
                + x[t[2]].coords * self.weights[2],
        )
    }

    /// The unit normal there: the corners' `vertex_normals` interpolated with the weights and
    /// normalised; `None` where they cancel.
    pub fn normal(
        &self,
        vertex_normals: &[Vector3<f64>],
        triangles: &[[usize; 3]],
    ) -> Option<Vector3<f64>> {
        let t = triangles[self.triangle];
        let n = vertex_normals[t[0]] * self.weights[0]
            + vertex_normals[t[1]] * self.weights[1]
            + vertex_normals[t[2]] * self.weights[2];
        n.try_normalize(1e-12)
    }

    /// The corner with the largest weight.
    pub fn dominant_vertex(&self, triangles: &[[usize; 3]]) -> usize {
        let t = triangles[self.triangle];
        let k = (0..3)
            .max_by(|&a, &b| self.weights[a].total_cmp(&self.weights[b]))
            .unwrap_or(0);
        t[k]
    }
}

/// For each vertex, the triangles that use it.
pub fn incident_triangles(vertices: usize, triangles: &[[usize; 3]]) -> Vec<Vec<usize>> {
    let mut out = vec![Vec::new(); vertices];
    for (t, tri) in triangles.iter().enumerate() {
        for &v in tri {
            if v < vertices {
                out[v].push(t);
            }
        }
    }
    out
}

/// Vertices examined per cloud point: the closest surface point lies on a triangle around one
/// of the nearest few vertices on any mesh whose triangles are not much longer than wide.
pub(crate) const SEARCH_VERTICES: usize = 4;

/// The closest point to `q` on the triangles around the vertices `near` of a surface whose
/// vertices are at `x` (`incident`: [`incident_triangles`]), and its squared distance (m²).
/// Each triangle is projected onto once (`seen`: scratch space, cleared here). `None` when
/// no such triangle gives a finite point. With `near` the [`SEARCH_VERTICES`] nearest
/// vertices, it is the closest point of the whole surface on any mesh whose triangles are not
/// much longer than wide.
pub(crate) fn closest_anchor(
    q: &Point3<f64>,
    x: &[Point3<f64>],
    triangles: &[[usize; 3]],
    incident: &[Vec<usize>],
    near: impl IntoIterator<Item = usize>,
    seen: &mut Vec<usize>,
) -> Option<(SurfaceAnchor, f64)> {
    let mut best: Option<(SurfaceAnchor, f64)> = None;
    seen.clear();
    for v in near {
        for &t in &incident[v] {
            // Neighbouring vertices share triangles.
            if seen.contains(&t) {
                continue;
            }
            seen.push(t);
            let tri = triangles[t];
            let corners = [x[tri[0]], x[tri[1]], x[tri[2]]];
            let (w, _) = closest_barycentric(q, &corners);
            if !w.iter().all(|v| v.is_finite()) {
                continue;
            }
            let a = SurfaceAnchor {
                triangle: t,
                weights: w,
            };
            let d2 = (q - a.position(x, triangles)).norm_squared();
            if best.is_none_or(|(_, b)| d2 < b) {
                best = Some((a, d2));
            }
        }
    }
    best
}

/// The pairs of one ICP iteration, cloud → surface.
#[derive(Debug, Clone, PartialEq)]
pub struct AnchoredPairs {
    /// Where each kept pair acts on the model surface.
    pub anchors: Vec<SurfaceAnchor>,
    /// The anchor's corner with the largest weight (what convergence and the factorisation's
    /// spring set track).
    pub dominant: Vec<usize>,
    /// Unit outward normal of the surface at each anchor (interpolated vertex normals).
    pub normals: Vec<Vector3<f64>>,
    /// Imposed motion of each anchor along its normal, m: `n · (q − a)` with `q` the cloud
    /// point and `a` the anchor's current position.
    pub offsets: Vec<f64>,
    /// Index of each kept pair's cloud point.
    pub cloud_index: Vec<usize>,
    /// RMS distance of the kept pairs, m.
    pub rms: f64,
}

/// Cloud neighbours whose pair lengths decide whether a long pair is a deformation the model
/// has not followed yet or an outlier ([`CoherentPairs`]).
pub(crate) const COHERENCE_NEIGHBOURS: usize = 8;

/// The pair length of every cloud point, to tell a long pair that belongs to a coherent
/// region of long pairs (the cloud shows the surface somewhere the model has not reached: a
/// dent, a lifted lobe) from an outlier among points the model fits. The length-based outlier
/// rule alone cannot: on a noise-free cloud its threshold is a fraction of a millimetre, and
/// every point of a dent the registration has not yet reached was dropped, so it never was
/// reached (a force-driven 50 mm dent on the indentation liver ended 10 mm short).
struct CoherentPairs<'a> {
    cloud: &'a IndexedPoints,
    /// Pair length of each cloud point, m (NaN: not paired).
    length: Vec<f64>,
}

impl<'a> CoherentPairs<'a> {
    fn new(cloud: &'a IndexedPoints, found: &[(usize, SurfaceAnchor, f64)]) -> Self {
        let mut length = vec![f64::NAN; cloud.len()];
        for &(j, _, d) in found {
            length[j] = d;
        }
        Self { cloud, length }
    }

    /// Whether cloud point `j`, `d` (m) from the surface, lies among [`COHERENCE_NEIGHBOURS`]
    /// cloud neighbours whose median pair length is at least half its own: a region of the
    /// cloud off the surface as a whole, not a lone point off it.
    fn holds(&self, j: usize, d: f64) -> bool {
        let mut near: Vec<f64> = self
            .cloud
            .nearest_k(&self.cloud.points[j], COHERENCE_NEIGHBOURS + 1)
            .into_iter()
            .filter(|&(k, _)| k != j)
            .map(|(k, _)| self.length[k])
            .filter(|v| v.is_finite())
            .collect();
        if near.len() < COHERENCE_NEIGHBOURS / 2 {
            return false;
        }
        let mid = near.len() / 2;
        let median = *near.select_nth_unstable_by(mid, f64::total_cmp).1;
        median >= 0.5 * d
    }
}

/// Pairs every point of `cloud` with its closest point on the surface (`x`: current vertex
/// positions, `triangles`, `incident`: [`incident_triangles`], `vertex_normals`: unit outward
/// normals at `x`), looking only at triangles with a corner flagged in `allowed` when given
/// (the vertices the camera sees), except that with [`PairingRule::hidden_match`] a point
/// lying on a hidden part of the surface pairs there. Pairs farther than the rule's threshold
/// (mean + kσ, or median + k·1.4826 MAD, of the pair distances) are dropped unless their cloud
/// neighbours lie as far off the surface; pairs farther than
/// `max_pair_distance` always. `None` when fewer than 3 pairs remain.
pub fn pair_cloud_to_surface(
    x: &[Point3<f64>],
    triangles: &[[usize; 3]],
    incident: &[Vec<usize>],
    vertex_normals: &[Vector3<f64>],
    allowed: Option<&[bool]>,
    cloud: &IndexedPoints,
    rule: &PairingRule,
) -> Option<AnchoredPairs> {
    let searchable: Vec<usize> = (0..x.len())
        .filter(|&v| allowed.is_none_or(|a| a[v]) && !incident[v].is_empty())
        .collect();
    let index = IndexedPoints::new(searchable.iter().map(|&v| x[v]).collect())?;
    // The whole surface, for cloud points the visible part does not explain.
    let hidden = match (allowed, rule.hidden_match) {
        (Some(_), Some(tolerance)) => {
            let all: Vec<usize> = (0..x.len()).filter(|&v| !incident[v].is_empty()).collect();
            IndexedPoints::new(all.iter().map(|&v| x[v]).collect()).map(|i| (i, all, tolerance))
        }
        _ => None,
    };
    // Each cloud point is paired on its own: in parallel, in the cloud's order.
    let found: Vec<(usize, SurfaceAnchor, f64)> = cloud
        .points
        .par_iter()
        .enumerate()
        .map_init(
            || Vec::with_capacity(4 * SEARCH_VERTICES * 8),
            |seen: &mut Vec<usize>, (j, q)| {
                let near = index
                    .nearest_k(q, SEARCH_VERTICES)
                    .into_iter()
                    .map(|(k, _)| searchable[k]);
                let visible = closest_anchor(q, x, triangles, incident, near, seen)
                    .map(|(a, d2)| (j, a, d2.sqrt()));
                let Some((index_all, all, tolerance)) = &hidden else {
                    return visible;
                };
                let near = index_all
                    .nearest_k(q, SEARCH_VERTICES)
                    .into_iter()
                    .map(|(k, _)| all[k]);
                match closest_anchor(q, x, triangles, incident, near, seen) {
                    Some((a, d2))
                        if d2.sqrt() <= *tolerance
                            && visible.as_ref().is_none_or(|v| v.2 > d2.sqrt() + tolerance) =>
                    {
                        Some((j, a, d2.sqrt()))
                    }
                    _ => visible,
                }
            },
        )
        .flatten()
        .collect();
    let dists: Vec<f64> = found.iter().map(|f| f.2).collect();
    let limit = rule.limit(&dists);
    let coherent = rule
        .keep_coherent
        .then(|| CoherentPairs::new(cloud, &found));
    let cap = rule.max_pair_distance.unwrap_or(f64::INFINITY);
    let mut out = AnchoredPairs {
        anchors: Vec::new(),
        dominant: Vec::new(),
        normals: Vec::new(),
        offsets: Vec::new(),
        cloud_index: Vec::new(),
        rms: 0.0,
    };
    let mut sum2 = 0.0;
    for (j, a, d) in found {
        if d > cap || (d > limit && !coherent.as_ref().is_some_and(|c| c.holds(j, d))) {
            continue;
        }
        let Some(n) = a.normal(vertex_normals, triangles) else {
            continue;
        };
        out.offsets
            .push(n.dot(&(cloud.points[j] - a.position(x, triangles))));
        out.normals.push(n);
        out.dominant.push(a.dominant_vertex(triangles));
        out.anchors.push(a);
        out.cloud_index.push(j);
        sum2 += d * d;
    }
    if rule.keep_coherent {
        sum2 += pull_up_uncovered_vertices(
            x,
            &searchable,
            incident,
            triangles,
            vertex_normals,
            cloud,
            (limit, cap),
            &mut out,
        );
    }
    if out.anchors.len() < 3 {
        return None;
    }
    out.rms = (sum2 / out.anchors.len() as f64).sqrt();
    Some(out)
}

/// Adds to `out` a pair for every vertex of `vertices` (at `x`) that lies farther than
/// `limit` (m) below the cloud where the cloud covers it: its nearest cloud point is not on
/// the rim of the seen patch and lies outward along the vertex normal. Cloud → surface pairs
/// alone never pull such a vertex: every cloud point above a hollow of the model (a dent the
/// tool has left) is closer to the hollow's rim than to its floor, so the hollow would stay.
/// Pairs longer than `cap` (m) are not made. Returns the sum of the added pairs' squared
/// lengths, m².
#[allow(clippy::too_many_arguments)]
fn pull_up_uncovered_vertices(
    x: &[Point3<f64>],
    vertices: &[usize],
    incident: &[Vec<usize>],
    triangles: &[[usize; 3]],
    vertex_normals: &[Vector3<f64>],
    cloud: &IndexedPoints,
    (limit, cap): (f64, f64),
    out: &mut AnchoredPairs,
) -> f64 {
    let mut sum2 = 0.0;
    for &v in vertices {
        let (j, d) = cloud.nearest(&x[v]);
        let n = vertex_normals[v];
        let offset = n.dot(&(cloud.points[j] - x[v]));
        // Mostly along the outward normal: the cloud shows the surface above this vertex.
        if d <= limit || d > cap || offset < 0.7 * d || cloud.is_rim(j, RIM_NEIGHBOURS, RIM_RATIO) {
            continue;
        }
        let Some(&t) = incident[v].first() else {
            continue;
        };
        let corner = triangles[t].iter().position(|&c| c == v).unwrap_or(0);
        let mut weights = [0.0; 3];
        weights[corner] = 1.0;
        out.anchors.push(SurfaceAnchor {
            triangle: t,
            weights,
        });
        out.normals.push(n);
        out.offsets.push(offset);
        out.dominant.push(v);
        out.cloud_index.push(j);
        sum2 += d * d;
    }
    sum2
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::icosphere;
    use crate::mesh::TriSurface;

    fn loose() -> PairingRule {
        PairingRule {
            alpha: 1.0,
            outlier_sigma: 1e3,
            robust: false,
            max_pair_distance: None,
            min_outlier_distance: 0.0,
            hidden_match: None,
            keep_coherent: false,
        }
    }

    /// On a sphere of radius R, a point at radius r pairs with the surface point on its ray:
    /// the anchor lies (within the chordal error of the triangulation) at radius R in the
    /// point's direction, and the imposed offset along the outward normal is r − R.
    #[test]
    fn points_off_a_sphere_pair_with_the_point_on_their_ray() {
        let r0 = 0.1;
        let s: TriSurface = icosphere(Point3::origin(), r0, 3);
        let normals = s.vertex_normals();
        let incident = incident_triangles(s.vertices.len(), &s.triangles);
        let dirs: Vec<Vector3<f64>> = (0..40)
            .map(|k| {
                let t = k as f64 * 0.7;
                Vector3::new(t.cos() * (1.3 * t).sin(), (1.3 * t).cos(), t.sin()).normalize()
            })
            .collect();
        let radii: Vec<f64> = (0..40)
            .map(|k| r0 + 0.01 * ((k % 5) as f64 - 2.0))
            .collect();
        let cloud = IndexedPoints::new(
            dirs.iter()
                .zip(&radii)
                .map(|(d, r)| Point3::from(d * *r))
                .collect(),
        )
        .unwrap();
        let p = pair_cloud_to_surface(
            &s.vertices,
            &s.triangles,
            &incident,
            &normals,
            None,
            &cloud,
            &loose(),
        )
        .unwrap();
        assert_eq!(p.anchors.len(), 40);
        // Chordal error of a level-3 icosphere of radius 0.1: under 1 mm.
        for (s_i, &j) in p.cloud_index.iter().enumerate() {
            let a = p.anchors[s_i].position(&s.vertices, &s.triangles);
            assert!((a.coords.normalize() - dirs[j]).norm() < 0.02, "direction");
            assert!((p.offsets[s_i] - (radii[j] - r0)).abs() < 1.2e-3, "offset");
            assert!((p.weights_sum(s_i) - 1.0).abs() < 1e-12);
        }
    }

    impl AnchoredPairs {
        fn weights_sum(&self, s: usize) -> f64 {
            self.anchors[s].weights.iter().sum()
        }
    }

    /// Only triangles with an allowed corner are searched, and the distance cap drops pairs.
    #[test]
    fn allowed_vertices_and_the_cap_restrict_the_pairs() {
        let s: TriSurface = icosphere(Point3::origin(), 0.1, 2);
        let normals = s.vertex_normals();
        let incident = incident_triangles(s.vertices.len(), &s.triangles);
        // Cloud: points just outside the +z cap.
        let cloud = IndexedPoints::new(
            s.vertices
                .iter()
                .filter(|v| v.z > 0.07)
                .map(|v| Point3::from(v.coords * 1.05))
                .collect(),
        )
        .unwrap();
        // Allow only the −z half: every anchor must lie on a triangle touching it.
        let allowed: Vec<bool> = s.vertices.iter().map(|v| v.z < 0.0).collect();
        let p = pair_cloud_to_surface(
            &s.vertices,
            &s.triangles,
            &incident,
            &normals,
            Some(&allowed),
            &cloud,
            &loose(),
        )
        .unwrap();
        for a in &p.anchors {
            assert!(s.triangles[a.triangle].iter().any(|&v| allowed[v]));
        }
        let capped = PairingRule {
            max_pair_distance: Some(0.001),
            ..loose()
        };
        assert!(pair_cloud_to_surface(
            &s.vertices,
            &s.triangles,
            &incident,
            &normals,
            None,
            &cloud,
            &capped
        )
        .is_none());
    }

    /// A cloud point lying on a part of the surface the mask calls hidden pairs there (zero
    /// offset) with `hidden_match`, not with the far visible part; a point off the hidden part
    /// by more than the tolerance still pairs with the visible part only.
    #[test]
    fn a_point_on_the_hidden_surface_pairs_where_it_lies() {
        let s: TriSurface = icosphere(Point3::origin(), 0.1, 2);
        let normals = s.vertex_normals();
        let incident = incident_triangles(s.vertices.len(), &s.triangles);
        // Triangle centroids of the +z cap: on the surface itself.
        let on_cap: Vec<Point3<f64>> = s
            .triangles
            .iter()
            .map(|t| {
                Point3::from(
                    (s.vertices[t[0]].coords + s.vertices[t[1]].coords + s.vertices[t[2]].coords)
                        / 3.0,
                )
            })
            .filter(|c| c.z > 0.07)
            .collect();
        let off_cap: Vec<Point3<f64>> = on_cap
            .iter()
            .map(|c| Point3::from(c.coords * 1.05))
            .collect();
        let allowed: Vec<bool> = s.vertices.iter().map(|v| v.z < 0.0).collect();
        let rule = PairingRule {
            hidden_match: Some(1e-3),
            ..loose()
        };
        let pair = |points: &[Point3<f64>]| {
            pair_cloud_to_surface(
                &s.vertices,
                &s.triangles,
                &incident,
                &normals,
                Some(&allowed),
                &IndexedPoints::new(points.to_vec()).unwrap(),
                &rule,
            )
            .unwrap()
        };
        let on = pair(&on_cap);
        assert_eq!(on.anchors.len(), on_cap.len());
        for (a, o) in on.anchors.iter().zip(&on.offsets) {
            assert!(
                s.triangles[a.triangle].iter().all(|&v| !allowed[v]),
                "hidden anchor"
            );
            assert!(o.abs() < 1e-12, "offset {o}");
        }
        assert!(on.rms < 1e-12);
        let off = pair(&off_cap);
        for a in &off.anchors {
            assert!(s.triangles[a.triangle].iter().any(|&v| allowed[v]));
        }
    }
}
