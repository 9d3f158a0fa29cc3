//! Taubin λ|μ smoothing (Taubin 1995, "A signal processing approach to fair surface design"):
//! alternating a shrinking Laplacian step (λ > 0) and an inflating one (μ < −λ) low-pass
//! filters the surface without the shrinkage of plain Laplacian smoothing. Uniform (umbrella)
//! weights; the connectivity is unchanged.

use nalgebra::Point3;

use crate::mesh::TriSurface;

/// Parameters of [`taubin_smooth`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Taubin {
    /// Number of λ|μ pairs.
    pub iterations: usize,
    /// The shrinking factor, 0 < λ < 1 (default 0.5).
    pub lambda: f64,
    /// The inflating factor, μ < −λ (default −0.53: pass-band k = 1/λ + 1/μ ≈ 0.11).
    pub mu: f64,
}

impl Default for Taubin {
    fn default() -> Self {
        Self {
            iterations: 20,
            lambda: 0.5,
            mu: -0.53,
        }
    }
}

/// Neighbour lists in compressed form: neighbours of `v` are `adj[start[v]..start[v + 1]]`.
pub(crate) struct Adjacency {
    pub(crate) start: Vec<usize>,
    pub(crate) adj: Vec<u32>,
}

impl Adjacency {
    pub(crate) fn new(n: usize, triangles: &[[usize; 3]]) -> Self {
        let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(triangles.len() * 6);
        for t in triangles {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                pairs.push((a as u32, b as u32));
                pairs.push((b as u32, a as u32));
            }
        }
        pairs.sort_unstable();
        pairs.dedup();
        let mut start = vec![0usize; n + 1];
        for &(a, _) in &pairs {
            start[a as usize + 1] += 1;
        }
        for v in 0..n {
            start[v + 1] += start[v];
        }
        Self {
            start,
            adj: pairs.into_iter().map(|(_, b)| b).collect(),
        }
    }
}

/// Smooths `surface` in place with `params.iterations` λ|μ pairs.
pub fn taubin_smooth(surface: &mut TriSurface, params: &Taubin) {
    if params.iterations == 0 || surface.triangles.is_empty() {
        return;
    }
    let n = surface.vertices.len();
    let graph = Adjacency::new(n, &surface.triangles);
    let mut next = surface.vertices.clone();
    for _ in 0..params.iterations {
        for factor in [params.lambda, params.mu] {
            let cur = &surface.vertices;
            for (v, out) in next.iter_mut().enumerate() {
                let nb = &graph.adj[graph.start[v]..graph.start[v + 1]];
                if nb.is_empty() {
                    *out = cur[v];
                    continue;
                }
                let mut sum = nalgebra::Vector3::zeros();
                for &w in nb {
                    sum += cur[w as usize].coords;
                }
                let mean = sum / nb.len() as f64;
                *out = Point3::from(cur[v].coords + factor * (mean - cur[v].coords));
            }
            std::mem::swap(&mut surface.vertices, &mut next);
        }
    }
}
