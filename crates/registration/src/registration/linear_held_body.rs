//! The contact refit's held body for a small-strain linear law, solved without factorising it.
//!
//! A linear body `K u = f` whose `m` embedded points are held by springs of stiffness `k`
//! towards displacements `t` is in equilibrium at `(K + k Nᵀ N) u = f + k Nᵀ t` (`N`: the
//! points' rows of the embedding, thesis eq. 4.16; the springs' stiffness, eq. 4.21). With the
//! free state `u₀ = K⁻¹ f` and the compliance columns `Z = K⁻¹ Nᵀ` (the body's response to a unit
//! force at each held point), the Woodbury identity gives
//!
//! `u = u₀ + Z S⁻¹ (t − N u₀)`, with `S = I / k + N Z`,
//!
//! a `3m × 3m` dense system. `K` is the body's rest tangent (cells and its own springs), which a
//! linear law keeps at every state; it is factorised once per model ([`RestCompliance`]). A
//! surface vertex's three columns are kept ([`HeldColumns`]), so a frame solves only for the
//! vertices it holds for the first time: a sequence's contact region moves little from frame
//! to frame, and most of the seen vertices a warm frame holds were held before. The state is
//! exact for every slide of the held region (no Newton iteration, no convergence to reach),
//! and affine in the targets. Lengths in metres, forces in newtons.

use std::collections::HashMap;

use nalgebra::{Cholesky, DMatrix, DVector, Dyn, Point3, Vector3};

use super::contact_force::RestCompliance;
use crate::grid::Embedding;
use crate::mechanics::{Need, StaticProblem};

/// The most memory (bytes) the kept compliance columns may take; beyond it the columns of
/// vertices the current frame does not hold are dropped. A vertex takes 3 × 8 bytes per
/// unknown: 109 KB on the warped liver's derived cells (4,551 unknowns), so about 600
/// vertices, several times the 80-odd seen vertices one contact region holds.
pub(crate) const HELD_COLUMNS_BUDGET_BYTES: usize = 64 << 20;

/// The most surface vertices (`vertices`, m) within `radius` (m) of one of them: how many one
/// contact region can hold. Every fourth vertex is tried as the centre.
pub(crate) fn most_vertices_within(vertices: &[Point3<f64>], radius: f64) -> usize {
    let r2 = radius * radius;
    vertices
        .iter()
        .step_by(4)
        .map(|c| {
            vertices
                .iter()
                .filter(|v| (*v - c).norm_squared() < r2)
                .count()
        })
        .max()
        .unwrap_or(0)
}

/// Compliance columns `K⁻¹ Nᵀ` of surface vertices (three per vertex, one per axis) and the
/// free state `u₀ = K⁻¹ f`, kept across frames for one model.
#[derive(Debug, Default)]
pub struct HeldColumns {
    /// Unknowns of the model the columns were solved for.
    dofs: usize,
    /// Per surface vertex: its three columns (axis x, y, z), each `dofs` long, m/N.
    columns: HashMap<usize, Vec<f64>>,
    /// The loads `f` (N) the free state was solved for, and the free state `u₀` (m).
    free: Option<(Vec<f64>, Vec<f64>)>,
}

impl HeldColumns {
    /// An empty cache.
    pub fn new() -> Self {
        Self::default()
    }

    /// Vertices whose columns are kept.
    pub fn len(&self) -> usize {
        self.columns.len()
    }

    /// Whether no column is kept.
    pub fn is_empty(&self) -> bool {
        self.columns.is_empty()
    }

    /// Drops everything when the model's unknowns changed.
    fn fit_to(&mut self, dofs: usize) {
        if self.dofs != dofs {
            *self = Self {
                dofs,
                ..Self::default()
            };
        }
    }

    /// Solves the columns of the vertices of `ids` (embedded by `surface_embedding`) that are
    /// not kept yet, in one pass over the factor; drops the columns of other vertices first
    /// when keeping them all would exceed [`HELD_COLUMNS_BUDGET_BYTES`].
    fn ensure(
        &mut self,
        compliance: &mut RestCompliance,
        surface_embedding: &Embedding,
        ids: &[usize],
    ) -> Result<(), String> {
        let n = self.dofs;
        let missing: Vec<usize> = ids
            .iter()
            .copied()
            .filter(|v| !self.columns.contains_key(v))
            .collect();
        if missing.is_empty() {
            return Ok(());
        }
        let per_vertex = 3 * n * std::mem::size_of::<f64>();
        if (self.columns.len() + missing.len()) * per_vertex > HELD_COLUMNS_BUDGET_BYTES {
            self.columns.retain(|v, _| ids.contains(v));
        }
        if let Some(v) = missing.iter().find(|&&v| v >= surface_embedding.len()) {
            return Err(format!("held vertex {v} is not a surface vertex"));
        }
        // Column (j, axis): the grid forces of a unit force along `axis` at vertex j.
        let mut b = vec![0.0; 3 * n * missing.len()];
        for (column, (v, axis)) in b.chunks_mut(n).zip(
            missing
                .iter()
                .flat_map(|&v| (0..3).map(move |axis| (v, axis))),
        ) {
            surface_embedding
                .select(&[v])
                .spread_forces(&[Vector3::ith(axis, 1.0)], column);
        }
        let mut x = vec![0.0; b.len()];
        compliance.solve_columns(&b, &mut x, 3 * missing.len())?;
        if !x.iter().all(|v| v.is_finite()) {
            return Err("a compliance column is not finite".into());
        }
        for (j, &v) in missing.iter().enumerate() {
            self.columns
                .insert(v, x[3 * j * n..3 * (j + 1) * n].to_vec());
        }
        Ok(())
    }

    /// The free state `u₀ = K⁻¹ f` (m) of `problem` at full load, `f` its dead loads and its
    /// own springs' pull towards their targets (the negated residual at `u = 0`); solved again
    /// only when `f` changed.
    fn free_state(
        &mut self,
        compliance: &mut RestCompliance,
        problem: &mut StaticProblem,
    ) -> Result<&[f64], String> {
        let n = self.dofs;
        let mut residual = vec![0.0; n];
        problem
            .evaluate(&vec![0.0; n], 1.0, Need::Force, Some(&mut residual), None)
            .map_err(|e| format!("free state: cell {}: {}", e.cell, e.error))?;
        let f: Vec<f64> = residual.iter().map(|r| -r).collect();
        let stale = self.free.as_ref().is_none_or(|(kept, _)| *kept != f);
        if stale {
            let mut u0 = vec![0.0; n];
            if f.iter().any(|v| *v != 0.0) {
                compliance.solve_columns(&f, &mut u0, 1)?;
            }
            if !u0.iter().all(|v| v.is_finite()) {
                return Err("the free state is not finite".into());
            }
            self.free = Some((f, u0));
        }
        Ok(&self.free.as_ref().expect("set above").1)
    }
}

/// The held body of one refit: the held points' compliance and the factorised `S`.
pub struct LinearHeldBody<'a> {
    /// The held points' embedding (rest positions, m).
    embedding: Embedding,
    /// The held points' columns, point after point, axis after axis (m/N).
    columns: Vec<&'a [f64]>,
    /// The free state `u₀`, m.
    free: &'a [f64],
    /// `N u₀` at the held points, m.
    free_at_held: Vec<Vector3<f64>>,
    /// Cholesky factor of `S = I / k + N Z`.
    system: Cholesky<f64, Dyn>,
}

impl<'a> LinearHeldBody<'a> {
    /// The body of the linear `problem` (rest tangent factorised in `compliance`) with the
    /// surface vertices `held_ids` (embedded by `surface_embedding`) held by springs of
    /// `stiffness` (N/m); the columns come from and go to `cache`. Fails (with why) when the
    /// problem's law is not linear, a solve fails, or `S` is not positive definite.
    pub fn new(
        problem: &mut StaticProblem,
        compliance: &mut RestCompliance,
        cache: &'a mut HeldColumns,
        surface_embedding: &Embedding,
        held_ids: &[usize],
        stiffness: f64,
    ) -> Result<Self, String> {
        if !problem.material.is_linear() {
            return Err("the held body's law is not linear".into());
        }
        if !(stiffness.is_finite() && stiffness > 0.0) {
            return Err(format!("hold stiffness {stiffness} N/m is not positive"));
        }
        if compliance.dofs() != problem.dofs() {
            return Err("the rest compliance is of another model".into());
        }
        cache.fit_to(problem.dofs());
        cache.ensure(compliance, surface_embedding, held_ids)?;
        cache.free_state(compliance, problem)?;
        let cache: &'a HeldColumns = cache;
        let embedding = surface_embedding.select(held_ids);
        let free = &cache.free.as_ref().expect("solved above").1;
        let columns: Vec<&'a [f64]> = held_ids
            .iter()
            .flat_map(|v| cache.columns[v].chunks(cache.dofs))
            .collect();
        let m = 3 * held_ids.len();
        // S = I/k + N Z: column j of N Z is column j of Z read at the held points.
        let mut s = DMatrix::<f64>::zeros(m, m);
        for (j, column) in columns.iter().enumerate() {
            for (i, at) in embedding.interpolate(column).iter().enumerate() {
                s.fixed_view_mut::<3, 1>(3 * i, j).copy_from(at);
            }
        }
        // N Z is symmetric in exact arithmetic (Maxwell–Betti); take its symmetric part.
        let s = (&s + s.transpose()) * 0.5 + DMatrix::identity(m, m) / stiffness;
        let system = s
            .cholesky()
            .ok_or("the held points' compliance system is not positive definite")?;
        let free_at_held = embedding.interpolate(free);
        Ok(Self {
            embedding,
            columns,
            free,
            free_at_held,
            system,
        })
    }

    /// Held points.
    pub fn len(&self) -> usize {
        self.embedding.len()
    }

    /// Whether no point is held.
    pub fn is_empty(&self) -> bool {
        self.embedding.is_empty()
    }

    /// The equilibrium (grid displacements, m) with the held points pulled towards the
    /// displacements `targets` (m, one per held point): `u₀ + Z S⁻¹ (t − N u₀)`.
    pub fn solve(&self, targets: &[Vector3<f64>]) -> Vec<f64> {
        let m = 3 * self.len();
        let mut r = DVector::<f64>::zeros(m);
        for (i, (t, f)) in targets.iter().zip(&self.free_at_held).enumerate() {
            for c in 0..3 {
                r[3 * i + c] = t[c] - f[c];
            }
        }
        let y = self.system.solve(&r);
        let mut u = self.free.to_vec();
        for (column, &yj) in self.columns.iter().zip(y.iter()) {
            for (ui, zi) in u.iter_mut().zip(column.iter()) {
                *ui += yj * zi;
            }
        }
        u
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::SolverKind;
    use crate::mechanics::test_fixtures::cut_box_held_at_end;
    use crate::mechanics::{LawKind, Material, NewtonSettings, NewtonSolver, PenaltySprings};

    /// The held body solved through the compliance columns is the held system solved
    /// directly: Newton on the assembled `K + k NᵀN` (its own factorisation, one step for a
    /// linear law, iterated to 1e-12) gives the same state within 1e-9 of the motion, with a
    /// dead load on the body (the free state `u₀` counts) and for two held sets in turn (the
    /// second reuses the first's columns). The body: a 10 × 6 × 5 cm box on 2 cm cut cells,
    /// its end face fixed, a patch of its top face within 3.5 cm of a point pushed 5 mm and slid.
    #[test]
    fn the_held_body_through_its_compliance_is_the_held_system_solved_directly() {
        let (s, mut problem) = cut_box_held_at_end(0.05, 1e3);
        problem.material = Material::from_young_poisson(LawKind::Linear, 4500.0, 0.45).unwrap();
        for (i, f) in problem.external.iter_mut().enumerate() {
            if i % 3 == 1 {
                *f = -0.002;
            }
        }
        let surface = Embedding::new(&problem.grid, &s.vertices).unwrap();
        let mut compliance = RestCompliance::new(&mut problem, SolverKind::default()).unwrap();
        let mut cache = HeldColumns::new();
        let stiffness = 2e3;
        for (centre, slide) in [
            (
                Point3::new(0.08, 0.05, 0.03),
                Vector3::new(0.002, 0.0, -0.001),
            ),
            (
                Point3::new(0.07, 0.05, 0.035),
                Vector3::new(-0.001, 0.0, 0.003),
            ),
        ] {
            let held: Vec<usize> = (0..s.vertices.len())
                .filter(|&v| (s.vertices[v] - centre).norm() < 0.035)
                .collect();
            assert!(held.len() >= 6, "{}", held.len());
            let targets: Vec<Vector3<f64>> = held
                .iter()
                .map(|_| Vector3::new(0.0, -0.005, 0.0) + slide)
                .collect();
            let body = LinearHeldBody::new(
                &mut problem,
                &mut compliance,
                &mut cache,
                &surface,
                &held,
                stiffness,
            )
            .unwrap();
            let through = body.solve(&targets);
            let springs = PenaltySprings {
                embedding: surface.select(&held),
                target: targets.clone(),
                stiffness: vec![stiffness; held.len()],
                follows_load: false,
                normals: None,
            };
            let mut direct = vec![0.0; problem.dofs()];
            let mut solver = NewtonSolver::new(NewtonSettings {
                residual_tolerance: 1e-12,
                step_stabilization: 0.0,
                ..NewtonSettings::default()
            });
            let report = solver.improve(
                &mut problem,
                std::slice::from_ref(&springs),
                &mut direct,
                20,
            );
            assert!(report.converged, "{report:?}");
            let motion = direct.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let apart = direct
                .iter()
                .zip(&through)
                .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
            println!(
                "{} held, {} columns kept: motion {motion:.3e} m, apart {apart:.3e} m",
                held.len(),
                cache.len()
            );
            assert!(motion > 1e-3, "{motion}");
            assert!(apart < 1e-9 * motion.max(1e-3), "{apart} against {motion}");
        }
    }

    /// A contact region of radius 1.5 cm on a square lattice of 1 cm holds a vertex, its four
    /// neighbours at 1 cm and its four diagonal ones at 1.41 cm: nine, wherever the lattice
    /// leaves a full neighbourhood.
    #[test]
    fn a_region_on_a_square_lattice_holds_nine_vertices() {
        let lattice: Vec<Point3<f64>> = (0..10)
            .flat_map(|i| (0..10).map(move |j| Point3::new(0.01 * i as f64, 0.01 * j as f64, 0.0)))
            .collect();
        assert_eq!(most_vertices_within(&lattice, 0.015), 9);
        assert_eq!(most_vertices_within(&lattice, 0.005), 1);
        assert_eq!(most_vertices_within(&[], 0.015), 0);
    }

    /// A law that is not linear has no such body: the caller solves it by Newton.
    #[test]
    fn a_law_that_is_not_linear_is_refused() {
        let (s, mut problem) = cut_box_held_at_end(0.05, 1e3);
        problem.material = Material::from_young_poisson(LawKind::NeoHookean, 4500.0, 0.45).unwrap();
        let surface = Embedding::new(&problem.grid, &s.vertices).unwrap();
        let mut compliance = RestCompliance::new(&mut problem, SolverKind::default()).unwrap();
        let mut cache = HeldColumns::new();
        let refused = LinearHeldBody::new(
            &mut problem,
            &mut compliance,
            &mut cache,
            &surface,
            &[0, 1, 2],
            1e3,
        );
        assert!(refused.is_err());
        assert!(cache.is_empty());
    }
}
