//! Penalty springs from embedded points to imposed displacements (thesis eq. 4.18–4.22): fixed
//! regions, and the springs registration pulls the visible surface with.

use nalgebra::{Point3, Vector3};

use super::assembly::Assembler;
use super::loads::samples_by_triangle;
use crate::geometry::Aabb;
use crate::grid::{
    embedding::interpolate_one, EmbeddedPoint, Embedding, EmbeddingError, WeightedCellGrid,
};
use crate::linalg::SymmetricCsc;
use crate::mesh::TriSurface;

/// Springs of stiffness `k_j` (N/m) between embedded points and imposed displacements `d_j`
/// (m). Energy `Σ_j ½ k_j |u_j − s d_j|²` with `u_j = Hᵀu` the point's displacement and `s` the
/// load factor when `follows_load` (imposed displacements applied gradually), else 1.
/// The force on the grid is `H S` with `S_j = k_j (u_j − s d_j)` (the printed ‖·‖ of eq. 4.19
/// is a typo) and the stiffness `H (k I) Hᵀ` (eq. 4.21).
///
/// With `normals` given, spring `j` acts only along the unit vector `n_j` (a point-to-plane
/// spring: the point may slide freely in the plane through its target): energy
/// `½ k_j (n_j · (u_j − s d_j))²`, force `H (k_j n_j n_jᵀ (u_j − s d_j))`, stiffness
/// `H (k_j n_j n_jᵀ) Hᵀ`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PenaltySprings {
    /// Where the points are in the grid.
    pub embedding: Embedding,
    /// Imposed displacement of each point, m.
    pub target: Vec<Vector3<f64>>,
    /// Stiffness of each spring, N/m.
    pub stiffness: Vec<f64>,
    /// Whether the imposed displacements scale with the load factor.
    pub follows_load: bool,
    /// Unit direction of each spring (point-to-plane springs); `None`: isotropic springs.
    pub normals: Option<Vec<Vector3<f64>>>,
}

impl PenaltySprings {
    /// Springs holding the points of `embedding` at their rest positions.
    pub fn fixed(embedding: Embedding, stiffness: Vec<f64>) -> Self {
        let target = vec![Vector3::zeros(); embedding.len()];
        Self {
            embedding,
            target,
            stiffness,
            follows_load: false,
            normals: None,
        }
    }

    /// Springs holding the part of `surface` inside `region` at rest: the region is sampled
    /// at spacing `h/2` (h: cell edge) and a sample of area `A` gets `spring_density · A`
    /// (N/m; `spring_density` in N/m³), so the hold does not depend on the surface's
    /// triangulation. Returns `None` when the box holds no part of the surface.
    pub fn fixed_surface_region(
        grid: &WeightedCellGrid,
        surface: &TriSurface,
        region: &Aabb,
        spring_density: f64,
    ) -> Result<Option<Self>, EmbeddingError> {
        Self::surface_region(grid, surface, region, spring_density, false)
    }

    /// An elastic support (Winkler foundation) under the part of `surface` inside `region`:
    /// like [`PenaltySprings::fixed_surface_region`] (`spring_density` in N/m³, pascals per
    /// metre of displacement), but when `sliding` each spring acts along the rest normal of
    /// its triangle only, so the surface may slide along the support (an organ resting on
    /// others) while it is held against pushing into or lifting off it.
    pub fn support_surface_region(
        grid: &WeightedCellGrid,
        surface: &TriSurface,
        region: &Aabb,
        spring_density: f64,
        sliding: bool,
    ) -> Result<Option<Self>, EmbeddingError> {
        Self::surface_region(grid, surface, region, spring_density, sliding)
    }

    fn surface_region(
        grid: &WeightedCellGrid,
        surface: &TriSurface,
        region: &Aabb,
        spring_density: f64,
        sliding: bool,
    ) -> Result<Option<Self>, EmbeddingError> {
        let mut samples = samples_by_triangle(surface, region, 0.5 * grid.grid.cell_size);
        // Degenerate triangles have no normal to slide along.
        let normal = |t: usize| surface.scaled_normal(t).try_normalize(0.0);
        if sliding {
            samples.retain(|(t, _)| normal(*t).is_some());
        }
        if samples.is_empty() {
            return Ok(None);
        }
        let points: Vec<Point3<f64>> = samples.iter().map(|s| s.1.point).collect();
        let stiffness = samples.iter().map(|s| spring_density * s.1.area).collect();
        let mut springs = Self::fixed(Embedding::new(grid, &points)?, stiffness);
        if sliding {
            springs.normals = Some(
                samples
                    .iter()
                    .map(|(t, _)| normal(*t).expect("kept above"))
                    .collect(),
            );
        }
        Ok(Some(springs))
    }

    /// The same hold with the springs of each grid cell lumped into one: a spring of their
    /// summed stiffness on the stiffness-weighted mean of their displacements (trilinear
    /// weights averaged; rest position and imposed displacement averaged alike). `n` isotropic
    /// springs in one cell constrain `3n` of its 24 unknowns, so eight or more clamp the whole
    /// cell and a hold given as many points reaches a cell beyond them; lumped, each cell is
    /// held by three constraints whatever the number of points. Point-to-plane springs
    /// (`normals`) are returned unchanged.
    pub fn lumped_per_cell(&self) -> Self {
        if self.normals.is_some() {
            return self.clone();
        }
        let mut order: Vec<usize> = Vec::new();
        let mut slot = std::collections::HashMap::new();
        for (j, e) in self.embedding.points.iter().enumerate() {
            slot.entry(e.cell).or_insert_with(|| {
                order.push(j);
                order.len() - 1
            });
        }
        let m = order.len();
        let mut points: Vec<EmbeddedPoint> =
            order.iter().map(|&j| self.embedding.points[j]).collect();
        points.iter_mut().for_each(|e| e.weights = [0.0; 8]);
        let mut rest = vec![Vector3::zeros(); m];
        let mut target = vec![Vector3::zeros(); m];
        let mut stiffness = vec![0.0; m];
        for (j, e) in self.embedding.points.iter().enumerate() {
            let c = slot[&e.cell];
            let k = self.stiffness[j];
            stiffness[c] += k;
            rest[c] += self.embedding.rest[j].coords * k;
            target[c] += self.target[j] * k;
            for (w, wj) in points[c].weights.iter_mut().zip(e.weights) {
                *w += k * wj;
            }
        }
        for c in 0..m {
            // A cell whose springs sum to zero stiffness holds nothing: plain means.
            let total = if stiffness[c] > 0.0 {
                stiffness[c]
            } else {
                1.0
            };
            rest[c] /= total;
            target[c] /= total;
            points[c].weights.iter_mut().for_each(|w| *w /= total);
        }
        Self {
            embedding: Embedding {
                points,
                rest: rest.into_iter().map(Point3::from).collect(),
            },
            target,
            stiffness,
            follows_load: self.follows_load,
            normals: None,
        }
    }

    fn imposed(&self, j: usize, load: f64) -> Vector3<f64> {
        if self.follows_load {
            self.target[j] * load
        } else {
            self.target[j]
        }
    }

    /// The resultant (N) of the forces these springs apply to the body at grid displacements
    /// `u` (m) and load factor `load`: `−Σ_j k_j (u_j − s d_j)` (along `n_j` for point-to-plane
    /// springs). The negated sum over the grid of the force [`PenaltySprings::accumulate`]
    /// adds, since each point's weights sum to 1.
    pub fn resultant(&self, u: &[f64], load: f64) -> Vector3<f64> {
        let mut total = Vector3::zeros();
        for (j, e) in self.embedding.points.iter().enumerate() {
            let mut diff = interpolate_one(e, u) - self.imposed(j, load);
            if let Some(n) = self.normals.as_ref().map(|n| n[j]) {
                diff = n * n.dot(&diff);
            }
            total -= diff * self.stiffness[j];
        }
        total
    }

    /// Spring energy (J) at grid displacements `u`; adds the grid forces `H S` to `force`
    /// (N) and the stiffness to `tangent` when given.
    pub fn accumulate(
        &self,
        assembler: &Assembler,
        u: &[f64],
        load: f64,
        force: Option<&mut [f64]>,
        tangent: Option<&mut SymmetricCsc>,
    ) -> f64 {
        let mut energy = 0.0;
        let mut force = force;
        let normal = |j: usize| self.normals.as_ref().map(|n| n[j]);
        for (j, e) in self.embedding.points.iter().enumerate() {
            let k = self.stiffness[j];
            let mut diff = interpolate_one(e, u) - self.imposed(j, load);
            if let Some(n) = normal(j) {
                diff = n * n.dot(&diff);
            }
            energy += 0.5 * k * diff.norm_squared();
            if let Some(f) = force.as_deref_mut() {
                for (n, w) in e.nodes.iter().zip(e.weights) {
                    for d in 0..3 {
                        f[3 * n + d] += k * w * diff[d];
                    }
                }
            }
        }
        if let Some(t) = tangent {
            for (j, e) in self.embedding.points.iter().enumerate() {
                let k = self.stiffness[j];
                let n = normal(j);
                for a in 0..8 {
                    for b in 0..=a {
                        let v = k * e.weights[a] * e.weights[b];
                        match n {
                            None => {
                                for i in 0..3 {
                                    t.values[assembler.cell_slot(e.cell, a, b, i, i)] += v;
                                }
                            }
                            Some(n) => {
                                for i in 0..3 {
                                    let cols = if a == b { 0..=i } else { 0..=2 };
                                    for c in cols {
                                        t.values[assembler.cell_slot(e.cell, a, b, i, c)] +=
                                            v * n[i] * n[c];
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        energy
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mechanics::test_fixtures::cut_box;
    use crate::mechanics::{Need, StaticProblem};

    /// A 10 × 10 × 6 cm box on 2 cm cells (cut: the box is offset from the grid lines), with
    /// a support of density `k` under its bottom face.
    fn supported_box(k: f64, sliding: bool) -> StaticProblem {
        let (s, mut p) = cut_box(0.096);
        let bottom = Aabb::new(Point3::new(-1.0, -1.0, -1.0), Point3::new(1.0, 1.0, 0.0015));
        let support = PenaltySprings::support_surface_region(&p.grid, &s, &bottom, k, sliding)
            .unwrap()
            .expect("the bottom face is in the box");
        p.springs.push(support);
        p
    }

    /// The resultant is the negated sum of the grid force `accumulate` adds, for isotropic
    /// and point-to-plane springs, with and without a load-following target.
    #[test]
    fn the_resultant_is_the_negated_sum_of_the_grid_force() {
        let (s, p) = cut_box(0.076);
        let points: Vec<Point3<f64>> = s.vertices.iter().step_by(3).copied().collect();
        let embedding = Embedding::new(&p.grid, &points).unwrap();
        let n = embedding.len();
        let u: Vec<f64> = (0..p.dofs())
            .map(|i| 1e-3 * ((i as f64) * 0.37).sin())
            .collect();
        for (normals, follows_load) in [(false, false), (true, true)] {
            let springs = PenaltySprings {
                target: (0..n)
                    .map(|j| Vector3::new(1e-3, -2e-3, 0.5e-3 * j as f64))
                    .collect(),
                stiffness: (0..n).map(|j| 100.0 + j as f64).collect(),
                follows_load,
                normals: normals.then(|| {
                    (0..n)
                        .map(|j| Vector3::new(1.0, j as f64, 2.0).normalize())
                        .collect()
                }),
                embedding: embedding.clone(),
            };
            let mut force = vec![0.0; p.dofs()];
            springs.accumulate(p.assembler(), &u, 0.6, Some(&mut force), None);
            let mut sum = Vector3::zeros();
            for node in force.chunks(3) {
                sum += Vector3::new(node[0], node[1], node[2]);
            }
            let r = springs.resultant(&u, 0.6);
            assert!(
                (r + sum).norm() <= 1e-12 * sum.norm(),
                "resultant {r:?} against grid force sum {sum:?}"
            );
        }
    }

    /// Potential of a rigid translation `d` (the body stores no strain energy).
    fn energy_of_translation(p: &mut StaticProblem, d: Vector3<f64>) -> f64 {
        let u: Vec<f64> = (0..p.grid.node_count())
            .flat_map(|_| [d.x, d.y, d.z])
            .collect();
        p.evaluate(&u, 1.0, Need::Energy, None, None)
            .unwrap()
            .potential
    }

    #[test]
    fn a_support_stores_half_k_area_d_squared_and_a_sliding_one_only_across() {
        // Winkler foundation under a 10 × 10 cm face: a rigid shift d stores ½ k A d² in every
        // direction, or only for the normal part when the support slides.
        let (k, area, d) = (1e5, 0.1 * 0.1, 1e-3);
        let expect = 0.5 * k * area * d * d;
        let mut fixed = supported_box(k, false);
        let mut sliding = supported_box(k, true);
        for dir in [Vector3::x(), Vector3::y(), Vector3::z()] {
            let e = energy_of_translation(&mut fixed, dir * d);
            assert!((e - expect).abs() < 1e-9 * expect, "{e} vs {expect}");
        }
        let across = energy_of_translation(&mut sliding, Vector3::z() * d);
        assert!(
            (across - expect).abs() < 1e-9 * expect,
            "{across} vs {expect}"
        );
        for dir in [Vector3::x(), Vector3::y()] {
            let along = energy_of_translation(&mut sliding, dir * d);
            assert!(along.abs() < 1e-12 * expect, "sliding stores {along}");
        }
        // Tilted: only the normal component counts.
        let tilted = Vector3::new(3.0, -2.0, 1.0).normalize() * d;
        let e = energy_of_translation(&mut sliding, tilted);
        assert!((e - expect * (tilted.z / d).powi(2)).abs() < 1e-9 * expect);
    }

    #[test]
    fn lumping_holds_each_cells_mean_displacement_with_the_summed_stiffness() {
        // 6 × 6 points on the bottom face of the cut box (several per cell), stiffness varying.
        let (_, p) = cut_box(0.096);
        let points: Vec<Point3<f64>> = (0..36)
            .map(|i| {
                Point3::new(
                    0.008 + 0.016 * (i % 6) as f64,
                    -0.003,
                    0.004 + 0.011 * (i / 6) as f64,
                )
            })
            .collect();
        let k: Vec<f64> = (0..36).map(|i| 100.0 + 10.0 * i as f64).collect();
        let held = PenaltySprings::fixed(Embedding::new(&p.grid, &points).unwrap(), k.clone());
        let lumped = held.lumped_per_cell();
        let mut cells: Vec<usize> = held.embedding.points.iter().map(|e| e.cell).collect();
        cells.sort_unstable();
        cells.dedup();
        assert_eq!(lumped.embedding.len(), cells.len());
        assert!(cells.len() < points.len(), "several points per cell");
        // A smooth non-rigid field: the lumped energy is ½ Σ_c K_c |Σ_j k_j u_j / K_c|² with
        // u_j the original points' displacements, and smaller than the original by Jensen.
        let u: Vec<f64> = (0..3 * p.grid.node_count())
            .map(|i| 1e-3 * ((0.37 * i as f64).sin() + 0.2))
            .collect();
        let assembler = Assembler::new(&p.grid);
        let moved = held.embedding.interpolate(&u);
        let expected: f64 = cells
            .iter()
            .map(|&c| {
                let (mut kc, mut sum) = (0.0, Vector3::zeros());
                for (j, e) in held.embedding.points.iter().enumerate() {
                    if e.cell == c {
                        kc += k[j];
                        sum += moved[j] * k[j];
                    }
                }
                0.5 * kc * (sum / kc).norm_squared()
            })
            .sum();
        let got = lumped.accumulate(&assembler, &u, 1.0, None, None);
        assert!(
            (got - expected).abs() < 1e-12 * expected,
            "{got} vs {expected}"
        );
        let original = held.accumulate(&assembler, &u, 1.0, None, None);
        assert!(got < 0.9 * original, "{got} vs {original}");
        // A rigid shift stores the same energy either way: ½ (Σ k) d².
        let d = Vector3::new(1e-3, -2e-3, 0.5e-3);
        let shift: Vec<f64> = (0..p.grid.node_count())
            .flat_map(|_| [d.x, d.y, d.z])
            .collect();
        let rigid = 0.5 * k.iter().sum::<f64>() * d.norm_squared();
        for springs in [&held, &lumped] {
            let e = springs.accumulate(&assembler, &shift, 1.0, None, None);
            assert!((e - rigid).abs() < 1e-12 * rigid, "{e} vs {rigid}");
        }
    }
}
