//! Decimation of a closed triangle surface to a target triangle count by quadric-error edge
//! collapse (Garland & Heckbert 1997), keeping it a closed, consistently oriented 2-manifold.
//!
//! Each vertex carries the area-weighted sum of the quadrics of its original triangles' planes;
//! the cheapest edge is collapsed to the point minimising the summed quadric (or to the better
//! of its ends and midpoint when that point is ill-defined or far away). A collapse is refused
//! when:
//! * the **link condition** fails: the two ends must share exactly the two neighbours opposite
//!   the edge (otherwise the collapse pinches the surface: non-manifold edge or vertex, or a
//!   tetrahedron folded flat);
//! * a surviving triangle around the edge would **turn** by more than
//!   [`Decimation::max_normal_turn_degrees`] (folds, flips);
//! * a surviving triangle would become a sliver worse than [`Decimation::min_quality`] (and
//!   worse than it was), which also rules out degenerate triangles.
//!
//! Input that is not a closed manifold is returned unchanged.

use nalgebra::{Matrix3, Point3, Vector3};

use crate::mesh::{validate, TriSurface};

/// Parameters of [`decimate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decimation {
    /// Stop when at most this many triangles remain (fewer collapses may be possible).
    pub target_triangles: usize,
    /// Largest change of a triangle's normal a collapse may cause, degrees (default 75).
    pub max_normal_turn_degrees: f64,
    /// Smallest triangle quality `4√3·area / Σ edge²` (1 for equilateral) a collapse may create
    /// unless the triangle was already worse (default 0.05).
    pub min_quality: f64,
}

impl Default for Decimation {
    fn default() -> Self {
        Self {
            target_triangles: 20_000,
            max_normal_turn_degrees: 75.0,
            min_quality: 0.05,
        }
    }
}

/// Symmetric 4×4 quadric: a², ab, ac, ad, b², bc, bd, c², cd, d².
type Quadric = [f64; 10];

fn plane_quadric(n: &Vector3<f64>, d: f64, w: f64) -> Quadric {
    let (a, b, c) = (n.x, n.y, n.z);
    [
        w * a * a,
        w * a * b,
        w * a * c,
        w * a * d,
        w * b * b,
        w * b * c,
        w * b * d,
        w * c * c,
        w * c * d,
        w * d * d,
    ]
}

fn add(q: &mut Quadric, r: &Quadric) {
    for (a, b) in q.iter_mut().zip(r) {
        *a += b;
    }
}

fn eval(q: &Quadric, p: &Point3<f64>) -> f64 {
    let (x, y, z) = (p.x, p.y, p.z);
    q[0] * x * x
        + 2.0 * q[1] * x * y
        + 2.0 * q[2] * x * z
        + 2.0 * q[3] * x
        + q[4] * y * y
        + 2.0 * q[5] * y * z
        + 2.0 * q[6] * y
        + q[7] * z * z
        + 2.0 * q[8] * z
        + q[9]
}

/// The point minimising `q`, if well defined.
fn optimum(q: &Quadric) -> Option<Point3<f64>> {
    let a = Matrix3::new(q[0], q[1], q[2], q[1], q[4], q[5], q[2], q[5], q[7]);
    let scale = (q[0] + q[4] + q[7]) / 3.0;
    if scale.is_nan() || scale <= 0.0 || a.determinant().abs() < 1e-6 * scale * scale * scale {
        return None;
    }
    let x = a.try_inverse()? * -Vector3::new(q[3], q[6], q[8]);
    x.iter().all(|v| v.is_finite()).then(|| Point3::from(x))
}

struct State {
    pos: Vec<Point3<f64>>,
    quadric: Vec<Quadric>,
    tris: Vec<[u32; 3]>,
    tri_alive: Vec<bool>,
    /// Live triangles around each vertex.
    around: Vec<Vec<u32>>,
    alive_triangles: usize,
    cos_turn: f64,
    min_quality: f64,
}

fn quality(a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>) -> f64 {
    let area2 = (b - a).cross(&(c - a)).norm();
    let sq = (b - a).norm_squared() + (c - b).norm_squared() + (a - c).norm_squared();
    if sq == 0.0 {
        0.0
    } else {
        2.0 * 3f64.sqrt() * area2 / sq
    }
}

impl State {
    fn neighbours(&self, v: u32, out: &mut Vec<u32>) {
        out.clear();
        for &t in &self.around[v as usize] {
            for &w in &self.tris[t as usize] {
                if w != v && !out.contains(&w) {
                    out.push(w);
                }
            }
        }
    }

    /// Target point and cost of collapsing `u`–`v`.
    fn plan(&self, u: u32, v: u32) -> (Point3<f64>, f64) {
        let mut q = self.quadric[u as usize];
        add(&mut q, &self.quadric[v as usize]);
        let (pu, pv) = (self.pos[u as usize], self.pos[v as usize]);
        let mid = Point3::from((pu.coords + pv.coords) / 2.0);
        let len = (pu - pv).norm();
        if let Some(x) = optimum(&q) {
            if (x - mid).norm() <= len {
                return (x, eval(&q, &x).max(0.0));
            }
        }
        [pu, pv, mid]
            .into_iter()
            .map(|p| (p, eval(&q, &p).max(0.0)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap()
    }

    /// Whether moving the corners `u` and `v` of the triangles around them to `x` keeps every
    /// surviving triangle's orientation and shape.
    fn geometry_ok(&self, u: u32, v: u32, x: &Point3<f64>) -> bool {
        for &w in &[u, v] {
            for &t in &self.around[w as usize] {
                let tri = self.tris[t as usize];
                if tri.contains(&u) && tri.contains(&v) {
                    continue;
                }
                let old = tri.map(|i| self.pos[i as usize]);
                let new = tri.map(|i| if i == w { *x } else { self.pos[i as usize] });
                let n_old = (old[1] - old[0]).cross(&(old[2] - old[0]));
                let n_new = (new[1] - new[0]).cross(&(new[2] - new[0]));
                let (lo, ln) = (n_old.norm(), n_new.norm());
                if ln == 0.0 || n_old.dot(&n_new) < self.cos_turn * lo * ln {
                    return false;
                }
                let q_new = quality(&new[0], &new[1], &new[2]);
                if q_new < self.min_quality && q_new < quality(&old[0], &old[1], &old[2]) {
                    return false;
                }
            }
        }
        true
    }

    /// Collapses `v` into `u` at `x`.
    fn collapse(&mut self, u: u32, v: u32, x: Point3<f64>) {
        let around_v = std::mem::take(&mut self.around[v as usize]);
        for &t in &around_v {
            let tri = &mut self.tris[t as usize];
            if tri.contains(&u) {
                self.tri_alive[t as usize] = false;
                self.alive_triangles -= 1;
            } else {
                for i in tri.iter_mut() {
                    if *i == v {
                        *i = u;
                    }
                }
                self.around[u as usize].push(t);
            }
        }
        for &t in &around_v {
            if !self.tri_alive[t as usize] {
                for w in self.tris[t as usize] {
                    if w != v {
                        let alive = &self.tri_alive;
                        self.around[w as usize].retain(|&s| alive[s as usize]);
                    }
                }
            }
        }
        let qv = self.quadric[v as usize];
        add(&mut self.quadric[u as usize], &qv);
        self.pos[u as usize] = x;
    }
}

/// Decimates a closed manifold surface to at most `params.target_triangles` triangles where the
/// checks allow it (see the module documentation); a surface that is not watertight, or
/// already small enough, is returned unchanged.
pub fn decimate(surface: &TriSurface, params: &Decimation) -> TriSurface {
    if surface.triangles.len() <= params.target_triangles.max(4) || !validate(surface).watertight {
        return surface.clone();
    }
    decimate_closed(surface, params)
}

/// At most this fraction of the vertices is removed in one round.
const ROUND_FRACTION: usize = 6;

/// [`decimate`] of a surface known to be a closed, consistently oriented manifold.
///
/// Collapses go in rounds rather than through one priority queue (whose pops, cache misses in
/// a heap of millions of stale entries, took most of the time): each round computes every
/// edge's cost, sorts them, and collapses in that order, skipping edges next to a collapse
/// already done in the round (their costs changed), until the target or a sixth of the
/// vertices is reached. The costs used are therefore always current, as in the greedy order.
pub(crate) fn decimate_closed(surface: &TriSurface, params: &Decimation) -> TriSurface {
    let target = params.target_triangles.max(4);
    if surface.triangles.len() <= target {
        return surface.clone();
    }
    let mut st = State::new(surface, params);
    st.collapse_to(target);
    st.surface()
}

impl State {
    /// The decimation state of `surface`: every triangle alive and listed around its corners,
    /// each vertex with the area-weighted quadrics of its triangles' planes.
    fn new(surface: &TriSurface, params: &Decimation) -> Self {
        let n = surface.vertices.len();
        let mut st = State {
            pos: surface.vertices.clone(),
            quadric: vec![[0.0; 10]; n],
            tris: surface
                .triangles
                .iter()
                .map(|t| t.map(|i| i as u32))
                .collect(),
            tri_alive: vec![true; surface.triangles.len()],
            around: Vec::new(),
            alive_triangles: surface.triangles.len(),
            cos_turn: params.max_normal_turn_degrees.to_radians().cos(),
            min_quality: params.min_quality,
        };
        st.reserve_around();
        st.add_triangles();
        st
    }

    /// Empty lists of triangles around each vertex, sized for its valence.
    fn reserve_around(&mut self) {
        let mut valence = vec![0u32; self.pos.len()];
        for t in &self.tris {
            for &i in t {
                valence[i as usize] += 1;
            }
        }
        self.around = valence
            .iter()
            .map(|&c| Vec::with_capacity(c as usize + 2))
            .collect();
    }

    /// Adds each triangle's plane quadric, weighted by its area (in squared input units), to
    /// its corners, and lists the triangle around them.
    fn add_triangles(&mut self) {
        for (ti, t) in self.tris.iter().enumerate() {
            let [a, b, c] = t.map(|i| self.pos[i as usize]);
            let normal = (b - a).cross(&(c - a));
            let area2 = normal.norm();
            if area2 > 0.0 {
                let unit = normal / area2;
                let q = plane_quadric(&unit, -unit.dot(&a.coords), area2 / 2.0);
                for &i in t {
                    add(&mut self.quadric[i as usize], &q);
                }
            }
            for &i in t {
                self.around[i as usize].push(ti as u32);
            }
        }
    }

    /// Collapses edges in rounds, cheapest first, until at most `target` triangles remain or a
    /// round collapses nothing. In a round, at most a [`ROUND_FRACTION`]th of the vertices go,
    /// and no edge touching the neighbourhood of an earlier collapse of the round is taken.
    fn collapse_to(&mut self, target: usize) {
        let n = self.pos.len();
        let mut locked = vec![0u32; n];
        let mut alive_vertices = n;
        let mut edges: Vec<(f64, u32, u32)> = Vec::new();
        let (mut nu, mut nv) = (Vec::new(), Vec::new());
        for round in 1u32.. {
            if self.alive_triangles <= target {
                break;
            }
            self.sorted_edges(&mut edges);
            let needed = (self.alive_triangles - target).div_ceil(2);
            let limit = needed.min(alive_vertices / ROUND_FRACTION).max(1);
            let mut done = 0;
            for &(_, u, v) in &edges {
                if done == limit || self.alive_triangles <= target {
                    break;
                }
                if locked[u as usize] == round || locked[v as usize] == round {
                    continue;
                }
                if !self.collapse_if_allowed(u, v, &mut nu, &mut nv) {
                    continue;
                }
                alive_vertices -= 1;
                done += 1;
                locked[u as usize] = round;
                for &w in nu.iter().chain(&nv) {
                    locked[w as usize] = round;
                }
            }
            if done == 0 {
                break;
            }
        }
    }

    /// Every live edge once (`u < v`) with its collapse cost, into `edges`, sorted by cost
    /// and then by ends.
    fn sorted_edges(&self, edges: &mut Vec<(f64, u32, u32)>) {
        edges.clear();
        for (t, tri) in self.tris.iter().enumerate() {
            if !self.tri_alive[t] {
                continue;
            }
            for (a, b) in [(tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])] {
                // Each edge of a closed oriented surface appears once in each direction.
                if a < b {
                    edges.push((self.plan(a, b).1, a, b));
                }
            }
        }
        edges.sort_unstable_by(|x, y| {
            x.0.total_cmp(&y.0)
                .then_with(|| (x.1, x.2).cmp(&(y.1, y.2)))
        });
    }

    /// Collapses `u`–`v` at its planned point if the surface stays large enough, the link
    /// condition holds and the geometry checks pass; whether it did. `nu` and `nv` receive
    /// the neighbours of `u` and `v` before the collapse.
    fn collapse_if_allowed(
        &mut self,
        u: u32,
        v: u32,
        nu: &mut Vec<u32>,
        nv: &mut Vec<u32>,
    ) -> bool {
        self.neighbours(u, nu);
        self.neighbours(v, nv);
        if nu.len() < 3 || nv.len() < 3 || self.alive_triangles <= 4 {
            return false;
        }
        // Link condition: the ends share exactly the two vertices opposite the edge.
        if nu.iter().filter(|w| nv.contains(w)).count() != 2 {
            return false;
        }
        let (x, _) = self.plan(u, v);
        if !self.geometry_ok(u, v, &x) {
            return false;
        }
        self.collapse(u, v, x);
        true
    }

    /// The live triangles and the vertices they use, renumbered in order of first use.
    fn surface(&self) -> TriSurface {
        let mut index = vec![usize::MAX; self.pos.len()];
        let mut vertices = Vec::new();
        let mut triangles = Vec::with_capacity(self.alive_triangles);
        for (t, tri) in self.tris.iter().enumerate() {
            if !self.tri_alive[t] {
                continue;
            }
            triangles.push(tri.map(|i| {
                let i = i as usize;
                if index[i] == usize::MAX {
                    index[i] = vertices.len();
                    vertices.push(self.pos[i]);
                }
                index[i]
            }));
        }
        TriSurface::new(vertices, triangles)
    }
}
