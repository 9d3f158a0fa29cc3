//! Topological and geometric checks of a triangle surface. This is a report, not a rejection:
//! an open or imperfect surface is still usable downstream.

use std::collections::HashMap;
use std::fmt;

use serde::Serialize;

use super::surface::TriSurface;

/// Counts describing the quality of a [`TriSurface`], as computed by [`validate`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SurfaceReport {
    /// Number of triangles.
    pub triangles: usize,
    /// Number of vertices.
    pub vertices: usize,
    /// Triangles referring to a vertex index that does not exist; they are left out of every
    /// other count.
    pub invalid_triangles: usize,
    /// Triangles with a repeated vertex index or an area at most `1e-12` times the squared mean
    /// edge length. Triangles with a repeated index are left out of the edge counts.
    pub degenerate_triangles: usize,
    /// Edges used by exactly one triangle.
    pub boundary_edges: usize,
    /// Boundary loops: connected components of the graph of boundary edges.
    pub holes: usize,
    /// Edges used by more than two triangles.
    pub non_manifold_edges: usize,
    /// Edges shared by exactly two triangles that traverse them in the same direction, i.e.
    /// where the orientation flips.
    pub inconsistent_edges: usize,
    /// Vertices not used by any triangle.
    pub unreferenced_vertices: usize,
    /// No boundary, non-manifold or inconsistent edge (and at least one valid triangle): the
    /// surface encloses a volume.
    pub watertight: bool,
    /// Enclosed volume by the divergence theorem, in the file's units³; positive when the
    /// normals point outwards (meaningful only if `watertight`).
    pub signed_volume: f64,
    /// Connected components of triangles (triangles sharing a vertex are connected).
    pub components: usize,
}

/// Disjoint sets over `0..n` with path halving.
struct UnionFind(Vec<usize>);

impl UnionFind {
    fn new(n: usize) -> Self {
        Self((0..n).collect())
    }

    fn find(&mut self, mut i: usize) -> usize {
        while self.0[i] != i {
            self.0[i] = self.0[self.0[i]];
            i = self.0[i];
        }
        i
    }

    fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        self.0[ra] = rb;
    }

    /// Number of distinct sets among `items`.
    fn count_sets(&mut self, items: impl Iterator<Item = usize>) -> usize {
        let mut roots: Vec<usize> = items.map(|i| self.find(i)).collect();
        roots.sort_unstable();
        roots.dedup();
        roots.len()
    }
}

/// Signed volume over the triangles whose indices are all valid (never panics).
fn safe_signed_volume(s: &TriSurface) -> f64 {
    let n = s.vertices.len();
    s.triangles
        .iter()
        .filter(|t| t.iter().all(|&i| i < n))
        .map(|t| {
            let [a, b, c] = t.map(|i| s.vertices[i].coords);
            a.dot(&b.cross(&c))
        })
        .sum::<f64>()
        / 6.0
}

/// Checks `surface` and counts its defects; never panics, whatever the indices.
pub fn validate(surface: &TriSurface) -> SurfaceReport {
    let n = surface.vertices.len();
    let valid: Vec<[usize; 3]> = surface
        .triangles
        .iter()
        .copied()
        .filter(|t| t.iter().all(|&i| i < n))
        .collect();
    let edge_vector = |a: usize, b: usize| surface.vertices[b] - surface.vertices[a];

    let edge_sum: f64 = valid
        .iter()
        .map(|&[a, b, c]| {
            edge_vector(a, b).norm() + edge_vector(b, c).norm() + edge_vector(c, a).norm()
        })
        .sum();
    let mean_edge = edge_sum / (3 * valid.len()).max(1) as f64;
    let area_tolerance = 1e-12 * mean_edge * mean_edge;
    let repeated = |&[a, b, c]: &[usize; 3]| a == b || b == c || c == a;
    let degenerate_triangles = valid
        .iter()
        .filter(|&&[a, b, c]| {
            repeated(&[a, b, c])
                || edge_vector(a, b).cross(&edge_vector(a, c)).norm() / 2.0 <= area_tolerance
        })
        .count();

    // Per undirected edge: number of uses, and uses in increasing minus decreasing direction.
    let mut edges: HashMap<(usize, usize), (usize, i64)> = HashMap::with_capacity(valid.len() * 2);
    let mut connected = UnionFind::new(n);
    let mut referenced = vec![false; n];
    for t in &valid {
        for &i in t {
            referenced[i] = true;
        }
        connected.union(t[0], t[1]);
        connected.union(t[1], t[2]);
        if repeated(t) {
            continue;
        }
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            let entry = edges.entry((a.min(b), a.max(b))).or_default();
            entry.0 += 1;
            entry.1 += if a < b { 1 } else { -1 };
        }
    }
    let count = |pred: fn(&(usize, i64)) -> bool| edges.values().filter(|e| pred(e)).count();
    let boundary_edges = count(|e| e.0 == 1);
    let non_manifold_edges = count(|e| e.0 > 2);
    let inconsistent_edges = count(|e| e.0 == 2 && e.1 != 0);

    let mut loops = UnionFind::new(n);
    for (&(a, b), _) in edges.iter().filter(|(_, e)| e.0 == 1) {
        loops.union(a, b);
    }
    let holes = loops.count_sets(edges.iter().filter(|(_, e)| e.0 == 1).map(|(&(a, _), _)| a));
    let components = connected.count_sets((0..n).filter(|&i| referenced[i]));

    let invalid_triangles = surface.triangles.len() - valid.len();
    SurfaceReport {
        triangles: surface.triangles.len(),
        vertices: n,
        invalid_triangles,
        degenerate_triangles,
        boundary_edges,
        holes,
        non_manifold_edges,
        inconsistent_edges,
        unreferenced_vertices: referenced.iter().filter(|&&r| !r).count(),
        watertight: !valid.is_empty()
            && invalid_triangles == 0
            && boundary_edges == 0
            && non_manifold_edges == 0
            && inconsistent_edges == 0,
        signed_volume: safe_signed_volume(surface),
        components,
    }
}

impl SurfaceReport {
    /// Whether the surface can be used downstream at all: it has at least one non-degenerate
    /// triangle and no invalid index. Open or imperfect surfaces are usable (see [`Self::warnings`]).
    pub fn is_usable(&self) -> bool {
        self.invalid_triangles == 0 && self.degenerate_triangles < self.triangles
    }

    /// Human-readable descriptions of every defect found; empty for a clean closed surface with
    /// outward normals.
    pub fn warnings(&self) -> Vec<String> {
        let mut w = Vec::new();
        if self.triangles == 0 {
            w.push("the surface has no triangles".to_owned());
        }
        if self.invalid_triangles > 0 {
            w.push(format!(
                "{} triangles refer to vertices that do not exist",
                self.invalid_triangles
            ));
        }
        if self.boundary_edges > 0 {
            w.push(format!(
                "the surface is open: {} boundary edges forming {} holes",
                self.boundary_edges, self.holes
            ));
        }
        if self.non_manifold_edges > 0 {
            w.push(format!(
                "{} non-manifold edges (used by more than two triangles)",
                self.non_manifold_edges
            ));
        }
        if self.inconsistent_edges > 0 {
            w.push(format!(
                "{} edges between triangles of opposite orientation (not fixed automatically)",
                self.inconsistent_edges
            ));
        }
        if self.degenerate_triangles > 0 {
            w.push(format!(
                "{} degenerate triangles (repeated vertex or near-zero area)",
                self.degenerate_triangles
            ));
        }
        if self.unreferenced_vertices > 0 {
            w.push(format!(
                "{} vertices are not used by any triangle",
                self.unreferenced_vertices
            ));
        }
        if self.components > 1 {
            w.push(format!("{} separate components", self.components));
        }
        if self.watertight && self.signed_volume < 0.0 {
            w.push(
                "the normals point inwards (negative volume); orient_outward fixes this".to_owned(),
            );
        }
        w
    }
}

impl fmt::Display for SurfaceReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} triangles on {} vertices in {} component(s); {}: {} boundary edges forming {} \
             hole(s), {} non-manifold and {} inconsistently oriented edges; {} degenerate and {} \
             invalid triangles; {} unreferenced vertices; signed volume {:.6e}.",
            self.triangles,
            self.vertices,
            self.components,
            if self.watertight {
                "watertight"
            } else {
                "not watertight"
            },
            self.boundary_edges,
            self.holes,
            self.non_manifold_edges,
            self.inconsistent_edges,
            self.degenerate_triangles,
            self.invalid_triangles,
            self.unreferenced_vertices,
            self.signed_volume,
        )
    }
}

/// Flips every triangle if the signed volume is negative, so the normals of a closed surface
/// point outwards; returns whether it flipped. Only the global orientation is fixed: triangles
/// oriented inconsistently with their neighbours are reported by [`validate`]
/// (`inconsistent_edges`), not fixed.
pub fn orient_outward(surface: &mut TriSurface) -> bool {
    let flip = safe_signed_volume(surface) < 0.0;
    if flip {
        for t in &mut surface.triangles {
            t.swap(1, 2);
        }
    }
    flip
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::fixtures::{cube, octahedron};
    use nalgebra::{Point3, Vector3};

    #[test]
    fn closed_meshes_are_watertight() {
        for mesh in [cube(), octahedron()] {
            let r = validate(&mesh);
            assert!(r.watertight, "{r}");
            assert!(r.is_usable());
            assert!(r.warnings().is_empty(), "{:?}", r.warnings());
            assert_eq!(
                (
                    r.boundary_edges,
                    r.holes,
                    r.non_manifold_edges,
                    r.inconsistent_edges
                ),
                (0, 0, 0, 0)
            );
            assert_eq!(
                (
                    r.degenerate_triangles,
                    r.unreferenced_vertices,
                    r.components
                ),
                (0, 0, 1)
            );
        }
        let r = validate(&cube());
        assert_eq!((r.triangles, r.vertices, r.signed_volume), (12, 8, 1.0));
        assert_eq!(
            r.to_string(),
            "12 triangles on 8 vertices in 1 component(s); watertight: 0 boundary edges forming 0 \
             hole(s), 0 non-manifold and 0 inconsistently oriented edges; 0 degenerate and 0 \
             invalid triangles; 0 unreferenced vertices; signed volume 1.000000e0."
        );
    }

    #[test]
    fn missing_triangle_is_one_hole() {
        let mut mesh = cube();
        mesh.triangles.remove(5);
        let r = validate(&mesh);
        assert_eq!((r.boundary_edges, r.holes), (3, 1));
        assert!(!r.watertight);
        assert!(r.is_usable());
        assert!(r.warnings()[0].contains("3 boundary edges forming 1 holes"));
    }

    #[test]
    fn two_holes_are_counted_separately() {
        let mut mesh = cube();
        // Remove the top face (z = 1) and the bottom face (z = 0): an open tube.
        mesh.triangles.retain(|t| {
            let z: Vec<f64> = t.iter().map(|&i| mesh.vertices[i].z).collect();
            !(z.iter().all(|&z| z == 0.0) || z.iter().all(|&z| z == 1.0))
        });
        let r = validate(&mesh);
        assert_eq!((r.triangles, r.boundary_edges, r.holes), (8, 8, 2));
    }

    #[test]
    fn cubes_sharing_an_edge_make_it_non_manifold() {
        // A second cube touching the first only along the edge x = 1, y = 1 (vertices 2 and 6).
        let mut mesh = cube();
        let a = cube();
        let offset = mesh.vertices.len();
        let shift = Vector3::new(1.0, 1.0, 0.0);
        // Reuse the shared corners so that the edge really is shared: the other cube's corners
        // 0 and 4 are at (1, 1, 0) and (1, 1, 1).
        let map = |i: usize| match i {
            0 => 2,
            4 => 6,
            _ => offset + i,
        };
        mesh.vertices.extend(a.vertices.iter().map(|p| p + shift));
        mesh.triangles
            .extend(a.triangles.iter().map(|t| t.map(map)));
        let r = validate(&mesh);
        assert_eq!(r.non_manifold_edges, 1, "{r}");
        assert_eq!(r.inconsistent_edges, 0);
        assert_eq!(r.boundary_edges, 0);
        assert!(!r.watertight);
        assert_eq!(r.components, 1);
        assert_eq!(r.unreferenced_vertices, 2);
        assert_eq!(r.signed_volume, 2.0);
    }

    #[test]
    fn flipped_triangle_gives_inconsistent_edges() {
        let mut mesh = cube();
        mesh.triangles[3].swap(1, 2);
        let r = validate(&mesh);
        assert_eq!(r.inconsistent_edges, 3);
        assert_eq!((r.boundary_edges, r.non_manifold_edges), (0, 0));
        assert!(!r.watertight);
        assert!(r
            .warnings()
            .iter()
            .any(|w| w.contains("opposite orientation")));
    }

    #[test]
    fn degenerate_and_invalid_triangles_are_counted() {
        let mut mesh = cube();
        mesh.vertices.push(Point3::new(0.5, 0.0, 0.0)); // on the edge 0-1
        mesh.triangles.push([0, 1, 8]); // zero area
        mesh.triangles.push([0, 0, 1]); // repeated index
        mesh.triangles.push([0, 1, 99]); // invalid
        let r = validate(&mesh);
        assert_eq!(r.degenerate_triangles, 2, "{r}");
        assert_eq!(r.invalid_triangles, 1);
        assert!(!r.is_usable());
        assert!(!r.watertight);
        assert_eq!(r.signed_volume, 1.0);
    }

    #[test]
    fn orient_outward_flips_inverted_surfaces_only() {
        let mut mesh = cube();
        for t in &mut mesh.triangles {
            t.swap(0, 1);
        }
        let r = validate(&mesh);
        assert!(r.watertight);
        assert_eq!(r.signed_volume, -1.0);
        assert!(r.warnings()[0].contains("inwards"));
        assert!(orient_outward(&mut mesh));
        assert_eq!(mesh.signed_volume(), 1.0);
        assert!(!orient_outward(&mut mesh));
        assert_eq!(mesh.signed_volume(), 1.0);
    }

    #[test]
    fn empty_and_unreferenced() {
        let r = validate(&TriSurface::default());
        assert!(!r.watertight && !r.is_usable());
        assert_eq!(r.components, 0);
        let mut mesh = octahedron();
        mesh.vertices.push(Point3::origin());
        let r = validate(&mesh);
        assert_eq!(r.unreferenced_vertices, 1);
        assert!(r.watertight);
    }
}
