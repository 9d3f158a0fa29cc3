//! The model surface as an ICP target: dense surface samples in a k-d tree, each remembering its
//! triangle so that a nearest sample can be refined to the closest point on that triangle.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};

use crate::geometry::closest_point_on_triangle;
use crate::mesh::TriSurface;
use crate::registration::IcpError;

/// Marks a sample that belongs to no triangle (an isolated vertex): it is its own closest point.
const NO_TRIANGLE: u32 = u32::MAX;

/// Most samples a target may hold (the k-d tree indexes items with `u32`); a finer `spacing`
/// is an error rather than an out-of-memory.
pub const MAX_SAMPLES: usize = 50_000_000;

/// The model surface prepared for closest-point queries: its vertices plus a regular barycentric
/// lattice on every triangle (so the density is uniform per unit area and the distance between
/// neighbouring samples is ≤ `spacing`), in a k-d tree.
///
/// Build it once per model and reuse it for every frame; it is immutable and `Sync`.
/// A query ([`ModelTarget::closest_point`]) finds the nearest sample, then projects the query
/// onto that sample's triangle: the result is never farther than the sample and, on a smooth
/// surface, is usually the exact closest surface point, so the discretisation error of the
/// sampling mostly disappears.
pub struct ModelTarget {
    tree: ImmutableKdTree<f64, 3>,
    samples: Vec<Point3<f64>>,
    sample_triangle: Vec<u32>,
    triangles: Vec<[Point3<f64>; 3]>,
    /// Unit normal of each triangle (zero for a degenerate triangle), for point-to-plane ICP.
    normals: Vec<Vector3<f64>>,
    /// Edge neighbours of each triangle (across edges bc, ca, ab), `NO_TRIANGLE` on a border.
    neighbours: Vec<[u32; 3]>,
    spacing: f64,
}

/// Most triangle-to-neighbour steps of the closest-point walk of [`ModelTarget::closest_point`].
const MAX_WALK_STEPS: usize = 8;

impl std::fmt::Debug for ModelTarget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ModelTarget")
            .field("samples", &self.samples.len())
            .field("triangles", &self.triangles.len())
            .field("spacing", &self.spacing)
            .finish()
    }
}

impl ModelTarget {
    /// Samples `surface` (metres) so that neighbouring samples are at most `spacing` metres apart
    /// along every triangle edge direction, and builds the k-d tree.
    ///
    /// Errors: `spacing` not finite and positive; a surface with no triangles, a triangle index
    /// out of range, or a non-finite vertex; more than [`MAX_SAMPLES`] samples.
    pub fn new(surface: &TriSurface, spacing: f64) -> Result<ModelTarget, IcpError> {
        check_surface(surface, spacing)?;
        let triangles: Vec<[Point3<f64>; 3]> = (0..surface.triangles.len())
            .map(|t| surface.corners(t))
            .collect();
        let subdivisions = lattice_subdivisions(&triangles, spacing, surface.vertices.len())?;
        let (samples, sample_triangle) = surface_samples(surface, &triangles, &subdivisions);
        let coords: Vec<[f64; 3]> = samples.iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree = ImmutableKdTree::new_from_slice(&coords).map_err(|e| {
            IcpError::InvalidModel(format!("could not build the model k-d tree: {e:?}"))
        })?;
        let neighbours = edge_neighbours(&surface.triangles);
        let normals = triangles
            .iter()
            .map(|[a, b, c]| {
                let n = (b - a).cross(&(c - a));
                let len = n.norm();
                if len > 0.0 && len.is_finite() {
                    n / len
                } else {
                    Vector3::zeros()
                }
            })
            .collect();
        Ok(ModelTarget {
            tree,
            samples,
            sample_triangle,
            triangles,
            normals,
            neighbours,
            spacing,
        })
    }

    /// Number of surface samples in the tree.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// `true` when there are no samples (never, for a target built by [`ModelTarget::new`]).
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The surface samples (metres).
    pub fn samples(&self) -> &[Point3<f64>] {
        &self.samples
    }

    /// The requested sample spacing, metres.
    pub fn spacing(&self) -> f64 {
        self.spacing
    }

    /// The nearest surface sample to `p` (metres) and its squared distance (m²).
    pub fn nearest_sample(&self, p: &Point3<f64>) -> (usize, f64) {
        let nn = self
            .tree
            .query(&[p.x, p.y, p.z])
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        (nn.item as usize, nn.distance)
    }

    /// A closest point of the model surface to `p` and its squared distance (m²): the nearest
    /// sample refined to the closest point of that sample's triangle, then walked across edges
    /// to neighbouring triangles while that gets strictly closer (at most 8 steps). Never
    /// farther than the nearest sample; exact whenever the walk reaches the closest triangle.
    pub fn closest_point(&self, p: &Point3<f64>) -> (Point3<f64>, f64) {
        let (q, d2, _) = self.closest(p);
        (q, d2)
    }

    /// [`ModelTarget::closest_point`] plus the unit normal of the model triangle the closest
    /// point lies on (for point-to-plane ICP; orientation follows the triangle's winding). The
    /// normal is zero when the closest point is an isolated vertex or its triangle is degenerate.
    pub fn closest_point_with_normal(&self, p: &Point3<f64>) -> (Point3<f64>, f64, Vector3<f64>) {
        let (q, d2, t) = self.closest(p);
        let normal = if t == NO_TRIANGLE {
            Vector3::zeros()
        } else {
            self.normals[t as usize]
        };
        (q, d2, normal)
    }

    /// The unit normal of triangle `t` of the model (zero for a degenerate triangle); `None` when
    /// `t` is out of range.
    pub fn triangle_normal(&self, t: usize) -> Option<Vector3<f64>> {
        self.normals.get(t).copied()
    }

    /// The closest point, its squared distance and the triangle it lies on (`NO_TRIANGLE` for an
    /// isolated vertex sample).
    fn closest(&self, p: &Point3<f64>) -> (Point3<f64>, f64, u32) {
        let (i, d2) = self.nearest_sample(p);
        let mut t = self.sample_triangle[i];
        let mut best = (self.samples[i], d2, t);
        if t == NO_TRIANGLE {
            return best;
        }
        let (q, inside) = closest_point_on_triangle(p, &self.triangles[t as usize]);
        let dq = (p - q).norm_squared();
        if dq.is_nan() || dq > best.1 {
            return best;
        }
        best = (q, dq, t);
        if inside {
            return best;
        }
        for _ in 0..MAX_WALK_STEPS {
            let mut next = None;
            for &n in &self.neighbours[t as usize] {
                if n == NO_TRIANGLE {
                    continue;
                }
                let (q, inside) = closest_point_on_triangle(p, &self.triangles[n as usize]);
                let dq = (p - q).norm_squared();
                if dq < best.1 {
                    best = (q, dq, n);
                    next = Some((n, inside));
                }
            }
            match next {
                Some((n, false)) => t = n,
                _ => break,
            }
        }
        best
    }
}

/// For each triangle, the triangle across each of its edges (opposite corners 0, 1, 2), or
/// `NO_TRIANGLE` on a border (non-manifold edges: any one of the others).
fn edge_neighbours(triangles: &[[usize; 3]]) -> Vec<[u32; 3]> {
    let mut edges: Vec<(usize, usize, u32, u8)> = Vec::with_capacity(3 * triangles.len());
    for (t, tri) in triangles.iter().enumerate() {
        for k in 0..3 {
            let (u, v) = (tri[(k + 1) % 3], tri[(k + 2) % 3]);
            edges.push((u.min(v), u.max(v), t as u32, k as u8));
        }
    }
    edges.sort_unstable();
    let mut out = vec![[NO_TRIANGLE; 3]; triangles.len()];
    let mut start = 0;
    while start < edges.len() {
        let mut end = start + 1;
        while end < edges.len() && edges[end].0 == edges[start].0 && edges[end].1 == edges[start].1
        {
            end += 1;
        }
        for a in start..end {
            let other = if a + 1 < end { a + 1 } else { start };
            if other != a {
                let (_, _, t, k) = edges[a];
                out[t as usize][k as usize] = edges[other].2;
            }
        }
        start = end;
    }
    out
}

/// The checks [`ModelTarget::new`] makes before sampling: `spacing` finite and positive; the
/// surface with triangles, finite vertices, triangle indices in range and fewer triangles
/// than [`NO_TRIANGLE`].
fn check_surface(surface: &TriSurface, spacing: f64) -> Result<(), IcpError> {
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(IcpError::InvalidSetting(format!(
            "model sample spacing must be finite and > 0 metres, got {spacing}"
        )));
    }
    if surface.triangles.is_empty() {
        return Err(IcpError::InvalidModel(
            "the model surface has no triangles".into(),
        ));
    }
    if let Some(i) = crate::mesh::first_non_finite_point(&surface.vertices) {
        return Err(IcpError::InvalidModel(format!(
            "model vertex {i} has a non-finite coordinate: {:?}",
            surface.vertices[i].coords.as_slice()
        )));
    }
    let nv = surface.vertices.len();
    if let Some(t) = surface
        .triangles
        .iter()
        .position(|t| t.iter().any(|&v| v >= nv))
    {
        return Err(IcpError::InvalidModel(format!(
            "model triangle {t} indexes vertex {:?} but there are only {nv} vertices",
            surface.triangles[t]
        )));
    }
    if surface.triangles.len() >= NO_TRIANGLE as usize {
        return Err(IcpError::InvalidModel("too many triangles".into()));
    }
    Ok(())
}

/// Lattice subdivisions per triangle: its longest edge divided into steps of at most
/// `spacing` (m). Errors when the lattices and the `vertices` together would need more than
/// [`MAX_SAMPLES`] samples.
fn lattice_subdivisions(
    triangles: &[[Point3<f64>; 3]],
    spacing: f64,
    vertices: usize,
) -> Result<Vec<usize>, IcpError> {
    let subdivisions: Vec<usize> = triangles
        .iter()
        .map(|[a, b, c]| {
            let longest = (b - a).norm().max((c - b).norm()).max((a - c).norm());
            (longest / spacing).ceil().max(1.0)
        })
        .map(|n| {
            if n > MAX_SAMPLES as f64 {
                usize::MAX
            } else {
                n as usize
            }
        })
        .collect();
    let lattice_points: f64 = subdivisions
        .iter()
        .map(|&n| (n as f64 + 1.0) * (n as f64 + 2.0) / 2.0)
        .sum();
    if lattice_points + vertices as f64 > MAX_SAMPLES as f64 {
        return Err(IcpError::InvalidSetting(format!(
            "model sample spacing {spacing} m would need ~{lattice_points:.0} samples \
             (more than {MAX_SAMPLES}); use a coarser spacing"
        )));
    }
    Ok(subdivisions)
}

/// The surface's samples and the triangle each lies on: the vertices first (each with one
/// incident triangle), then each triangle's lattice of `subdivisions` steps, its points
/// strictly inside and those on an edge (u → v) only from the triangle where u < v, so the
/// shared edge of a closed surface is sampled once (by either neighbour's lattice, both fine
/// enough).
fn surface_samples(
    surface: &TriSurface,
    triangles: &[[Point3<f64>; 3]],
    subdivisions: &[usize],
) -> (Vec<Point3<f64>>, Vec<u32>) {
    let nv = surface.vertices.len();
    let mut samples = Vec::new();
    let mut sample_triangle = Vec::new();
    let mut vertex_triangle = vec![NO_TRIANGLE; nv];
    for (t, tri) in surface.triangles.iter().enumerate() {
        for &v in tri {
            if vertex_triangle[v] == NO_TRIANGLE {
                vertex_triangle[v] = t as u32;
            }
        }
    }
    samples.extend_from_slice(&surface.vertices);
    sample_triangle.extend_from_slice(&vertex_triangle);
    for (t, (tri, &n)) in surface.triangles.iter().zip(subdivisions).enumerate() {
        let [a, b, c] = triangles[t];
        let nf = n as f64;
        for i in 0..=n {
            for j in 0..=(n - i) {
                let k = n - i - j;
                let zeros = (i == 0) as u8 + (j == 0) as u8 + (k == 0) as u8;
                if zeros >= 2 {
                    continue; // a corner: already a vertex sample
                }
                if zeros == 1 {
                    // On the edge opposite the zero weight: (b,c) if i = 0, (c,a) if j = 0,
                    // (a,b) if k = 0 (the triangle's own orientation).
                    let (u, v) = if i == 0 {
                        (tri[1], tri[2])
                    } else if j == 0 {
                        (tri[2], tri[0])
                    } else {
                        (tri[0], tri[1])
                    };
                    if u > v {
                        continue;
                    }
                }
                let p = Point3::from(
                    (i as f64 * a.coords + j as f64 * b.coords + k as f64 * c.coords) / nf,
                );
                samples.push(p);
                sample_triangle.push(t as u32);
            }
        }
    }
    (samples, sample_triangle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::icosphere;
    use crate::registration::test_support::Rng;

    #[test]
    fn samples_respect_spacing_and_refinement_is_exact_on_triangles() {
        let sphere = icosphere(Point3::origin(), 0.1, 2);
        let spacing = 0.01;
        let target = ModelTarget::new(&sphere, spacing).unwrap();
        assert!(target.len() > sphere.vertices.len());
        // Every point of every triangle is within spacing of a sample (lattice covering radius
        // ≤ spacing / √3 for the step ≤ spacing; checked loosely).
        let mut rng = Rng::new(9);
        for _ in 0..2000 {
            let t = rng.below(sphere.triangles.len());
            let p = rng.point_on_triangle(&sphere.corners(t));
            let (_, d2) = target.nearest_sample(&p);
            assert!(d2.sqrt() <= spacing, "{}", d2.sqrt());
            // A point on the surface is its own closest point after refinement (up to round-off;
            // its nearest sample may lie on a neighbouring triangle, then the refinement is only
            // no worse than the sample).
            let (q, dq) = target.closest_point(&p);
            assert!(dq <= d2 && (q - p).norm() <= d2.sqrt() + 1e-15);
        }
        // Points off the surface: the refined distance approaches the true distance to the
        // polyhedron (which is ≥ the exact brute-force distance, equal when the right triangle
        // holds the nearest sample).
        let mut exact_hits = 0;
        for _ in 0..500 {
            let dir = rng.unit_vector();
            let p = Point3::from(dir * rng.uniform_in(0.08, 0.12));
            let brute = (0..sphere.triangles.len())
                .map(|t| (p - closest_point_on_triangle(&p, &sphere.corners(t)).0).norm())
                .fold(f64::INFINITY, f64::min);
            let (_, d2) = target.closest_point(&p);
            assert!(d2.sqrt() >= brute - 1e-12);
            assert!(d2.sqrt() <= brute + spacing);
            exact_hits += (d2.sqrt() - brute < 1e-9) as usize;
        }
        assert!(exact_hits > 450, "{exact_hits} of 500 exact");
    }

    #[test]
    fn closest_point_normal_is_the_triangle_normal() {
        let sphere = icosphere(Point3::origin(), 0.1, 3);
        let target = ModelTarget::new(&sphere, 0.005).unwrap();
        let mut rng = Rng::new(13);
        for _ in 0..500 {
            let p = Point3::from(rng.unit_vector() * rng.uniform_in(0.09, 0.11));
            let (q, d2, n) = target.closest_point_with_normal(&p);
            assert_eq!((q, d2), target.closest_point(&p));
            assert!((n.norm() - 1.0).abs() < 1e-12);
            // The facet normal of a fine icosphere is nearly radial.
            assert!(n.dot(&q.coords.normalize()).abs() > 0.99);
        }
        assert!(target.triangle_normal(sphere.triangles.len()).is_none());
    }

    #[test]
    fn rejects_bad_models() {
        let sphere = icosphere(Point3::origin(), 0.1, 1);
        let msg = ModelTarget::new(&sphere, 0.0).unwrap_err().to_string();
        assert!(msg.contains("spacing"), "{msg}");
        let empty = TriSurface::default();
        let msg = ModelTarget::new(&empty, 0.01).unwrap_err().to_string();
        assert!(msg.contains("no triangles"), "{msg}");
        let mut nan = sphere.clone();
        nan.vertices[7].y = f64::NAN;
        let msg = ModelTarget::new(&nan, 0.01).unwrap_err().to_string();
        assert!(msg.contains("vertex 7"), "{msg}");
        let mut bad = sphere.clone();
        bad.triangles[3][1] = 10_000;
        let msg = ModelTarget::new(&bad, 0.01).unwrap_err().to_string();
        assert!(msg.contains("triangle 3"), "{msg}");
        let msg = ModelTarget::new(&sphere, 1e-7).unwrap_err().to_string();
        assert!(msg.contains("coarser"), "{msg}");
    }
}
