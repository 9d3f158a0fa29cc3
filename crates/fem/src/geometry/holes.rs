//! Boundary of a triangle surface and virtual caps that close it.
//!
//! The boundary is the 1-chain `∂M = Σ_t ∂t` of directed edges: an undirected edge used
//! `k` times as `a → b` and `l` times as `b → a` is a boundary edge of multiplicity `k − l`.
//! It is empty for a closed, consistently oriented surface (any number of sheets, touching or
//! not). Vertices are identified by exact coordinates, so unwelded duplicates of a vertex are
//! the same point here.
//!
//! Each connected component of the boundary (a cycle) is closed by a cone from its centroid:
//! triangle `(apex, b, a)` for every boundary edge `a → b`. Then `M ∪ caps` is closed and for
//! any point `p`, `w_M(p) = w_{M∪caps}(p) − Ω_caps(p) / 4π`. Since `|Ω_cap(p)| ≤ area / d²`
//! (`d` = distance from `p` to the cap), outside the cap's *influence box* the correction is
//! smaller than ½ and the decision `w_M ≥ ½` equals the integer decision `w_{M∪caps} ≥ 1`.

use std::collections::HashMap;

use nalgebra::{Point3, Vector3};

use super::aabb::Aabb;

/// Fraction of 2π that the summed solid angles of all caps may reach outside the influence
/// boxes (the decision needs strictly less than 2π, i.e. a winding correction below ½).
const SOLID_ANGLE_BUDGET: f64 = 0.9;

/// Virtual triangles closing the holes of a surface, and the regions where they matter.
#[derive(Clone, Debug, Default)]
pub(crate) struct HoleCaps {
    /// Cap triangles (outward orientation consistent with the surface) with multiplicities.
    pub triangles: Vec<([Point3<f64>; 3], i32)>,
    /// One box per boundary component: outside all of them the caps' solid angle is below
    /// `0.9 · 2π` in total.
    pub influence: Vec<Aabb>,
    /// Number of boundary edges (counted with multiplicity).
    pub boundary_edges: usize,
}

impl HoleCaps {
    /// Computes the boundary chain of `tris` and the cones closing it.
    pub(crate) fn new(tris: &[[Point3<f64>; 3]]) -> Self {
        // Weld vertices by exact coordinates (−0 and +0 identified).
        let key = |p: &Point3<f64>| {
            [
                (p.x + 0.0).to_bits(),
                (p.y + 0.0).to_bits(),
                (p.z + 0.0).to_bits(),
            ]
        };
        let mut ids: HashMap<[u64; 3], u32> = HashMap::with_capacity(tris.len() / 2 + 3);
        let mut points: Vec<Point3<f64>> = Vec::with_capacity(tris.len() / 2 + 3);
        let mut edges: Vec<(u32, u32, i32)> = Vec::with_capacity(3 * tris.len());
        for t in tris {
            let v = t.map(|p| {
                *ids.entry(key(&p)).or_insert_with(|| {
                    points.push(p);
                    (points.len() - 1) as u32
                })
            });
            for (a, b) in [(v[0], v[1]), (v[1], v[2]), (v[2], v[0])] {
                if a < b {
                    edges.push((a, b, 1));
                } else if b < a {
                    edges.push((b, a, -1));
                }
            }
        }
        edges.sort_unstable_by_key(|&(a, b, _)| (a, b));
        // Net directed boundary edges (from, to, multiplicity > 0).
        let mut boundary: Vec<(u32, u32, i32)> = Vec::new();
        let mut i = 0;
        while i < edges.len() {
            let (a, b, _) = edges[i];
            let mut net = 0;
            while i < edges.len() && edges[i].0 == a && edges[i].1 == b {
                net += edges[i].2;
                i += 1;
            }
            match net.cmp(&0) {
                std::cmp::Ordering::Greater => boundary.push((a, b, net)),
                std::cmp::Ordering::Less => boundary.push((b, a, -net)),
                std::cmp::Ordering::Equal => {}
            }
        }
        if boundary.is_empty() {
            return HoleCaps::default();
        }
        // Connected components of the boundary graph (union-find on vertices).
        let mut parent: HashMap<u32, u32> = HashMap::new();
        fn find(parent: &mut HashMap<u32, u32>, x: u32) -> u32 {
            let mut r = x;
            while let Some(&p) = parent.get(&r) {
                if p == r {
                    break;
                }
                r = p;
            }
            // Path compression.
            let mut y = x;
            while y != r {
                let next = parent[&y];
                parent.insert(y, r);
                y = next;
            }
            r
        }
        for &(a, b, _) in &boundary {
            parent.entry(a).or_insert(a);
            parent.entry(b).or_insert(b);
            let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
            if ra != rb {
                parent.insert(ra.max(rb), ra.min(rb));
            }
        }
        let mut component_of: HashMap<u32, usize> = HashMap::new();
        let mut components: Vec<Vec<(u32, u32, i32)>> = Vec::new();
        for &e in &boundary {
            let r = find(&mut parent, e.0);
            let c = *component_of.entry(r).or_insert_with(|| {
                components.push(Vec::new());
                components.len() - 1
            });
            components[c].push(e);
        }
        let n_comp = components.len() as f64;
        let mut caps = HoleCaps {
            boundary_edges: boundary.iter().map(|e| e.2 as usize).sum(),
            ..HoleCaps::default()
        };
        for comp in &components {
            let mut sum = Vector3::zeros();
            let mut weight = 0.0;
            for &(a, _, m) in comp {
                sum += points[a as usize].coords * m as f64;
                weight += m as f64;
            }
            let apex = Point3::from(sum / weight);
            let mut area = 0.0;
            let mut bounds = Aabb::from_points(&[apex]);
            for &(a, b, m) in comp {
                let (pa, pb) = (points[a as usize], points[b as usize]);
                caps.triangles.push(([apex, pb, pa], m));
                area += m as f64 * 0.5 * (pb - apex).cross(&(pa - apex)).norm();
                bounds.grow(&pa);
                bounds.grow(&pb);
            }
            // Σ_k area_k / d_k² < budget · 2π when every d_k² > n · area_k / (budget · 2π).
            let margin = (n_comp * area / (SOLID_ANGLE_BUDGET * 2.0 * std::f64::consts::PI)).sqrt();
            // A small relative pad keeps points within rounding of the box's faces inside it.
            let pad = 1e-9 * bounds.extents().norm();
            caps.influence.push(bounds.expanded(margin + pad));
        }
        caps
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes;

    fn corners(v: &[Point3<f64>], t: &[[usize; 3]]) -> Vec<[Point3<f64>; 3]> {
        t.iter().map(|t| t.map(|i| v[i])).collect()
    }

    #[test]
    fn closed_surfaces_have_no_boundary() {
        let (v, t) = shapes::icosphere(2, 1.0);
        assert!(HoleCaps::new(&corners(&v, &t)).triangles.is_empty());
        // Unwelded copy (every triangle has its own vertices) is still closed.
        let soup: Vec<[Point3<f64>; 3]> = corners(&v, &t);
        assert_eq!(HoleCaps::new(&soup).boundary_edges, 0);
    }

    #[test]
    fn open_sphere_is_capped() {
        let (v, t) = shapes::icosphere(3, 1.0);
        let kept: Vec<[usize; 3]> = t
            .iter()
            .copied()
            .filter(|f| f.iter().any(|&i| v[i].z < 0.8))
            .collect();
        let tris = corners(&v, &kept);
        let caps = HoleCaps::new(&tris);
        assert!(caps.boundary_edges > 0);
        assert_eq!(caps.influence.len(), 1);
        // Surface plus caps is closed.
        let mut all = tris.clone();
        all.extend(caps.triangles.iter().map(|(c, _)| *c));
        assert_eq!(HoleCaps::new(&all).boundary_edges, 0);
    }
}
