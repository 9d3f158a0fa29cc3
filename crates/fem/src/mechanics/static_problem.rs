//! The discrete static equilibrium problem on an immersed grid: total potential energy, its
//! gradient (residual) and Hessian (tangent) — thesis eq. 4.9–4.11 and 4.22.

use nalgebra::Vector3;

use super::assembly::{Assembler, CellFailure};
use super::cell_kernel::{Need, VolumetricIntegration};
use super::cut_cell_stabilization::add_cut_cell_stabilization;
use super::material::Material;
use super::penalty::PenaltySprings;
use crate::grid::WeightedCellGrid;
use crate::linalg::SymmetricCsc;

/// Hyperelastic body on a [`WeightedCellGrid`] under dead loads and penalty springs, in SI units
/// (m, N, Pa, J). At load factor `s` the total potential energy is
/// `Π(u) = W_int(u) + W_springs(u; s) − s f_extᵀ u`; the residual is `∇Π` and the tangent `∇²Π`.
///
/// The problem holds the body and its own conditions only (fixed regions, supports, dead
/// loads). Springs a caller adds for one solve — registration's data term — are passed to
/// [`StaticProblem::evaluate_with`] (and to the Newton solver) as arguments, never stored here.
#[derive(Clone)]
pub struct StaticProblem {
    /// The grid (its lengths are metres).
    pub grid: WeightedCellGrid,
    /// Material law and Lamé parameters.
    pub material: Material,
    /// How the volumetric part is integrated.
    pub volumetric: VolumetricIntegration,
    /// Dead external forces at full load, N (3 per node).
    pub external: Vec<f64>,
    /// The body's own penalty spring sets: fixed regions and elastic supports (N/m per
    /// spring). Not the springs of a registration's data term: those are arguments of
    /// [`StaticProblem::evaluate_with`].
    pub springs: Vec<PenaltySprings>,
    assembler: Assembler,
    body_cache: Option<BodyCache>,
    linear_stiffness: Option<LinearStiffness>,
}

/// The cells' stiffness `K` (N/m) of a small-strain linear body ([`Material::is_linear`]),
/// assembled once: its strain energy is `½ uᵀKu`, its internal force `Ku` and its tangent `K`
/// at every state (thesis eq. 4.9–4.11 with a quadratic energy density), so an evaluation is a
/// sparse product instead of a pass over every cell's integration points. Kept with what it
/// was assembled with (public fields of the problem, so checked at each use).
#[derive(Clone)]
struct LinearStiffness {
    material: Material,
    volumetric: VolumetricIntegration,
    matrix: SymmetricCsc,
    /// `Ku` of the last evaluation, N (scratch, reused).
    product: Vec<f64>,
}

/// The body's own strain energy and internal force at the last state whose force was
/// assembled. Springs and loads are cheap and change between calls (re-pairing, load factor),
/// the cells are not: a modified-Newton step whose line search assembled the force at the
/// accepted state, followed by a new residual there, needs the cells only once.
#[derive(Clone)]
struct BodyCache {
    /// The state, compared bit for bit.
    u: Vec<f64>,
    /// What the cells were evaluated with (public fields of the problem, so checked).
    material: Material,
    volumetric: VolumetricIntegration,
    /// Strain energy, J.
    strain: f64,
    /// Internal force of the cells alone, N.
    force: Vec<f64>,
}

impl BodyCache {
    fn holds(&self, u: &[f64], material: &Material, volumetric: VolumetricIntegration) -> bool {
        self.material == *material
            && self.volumetric == volumetric
            && self.u.len() == u.len()
            && self
                .u
                .iter()
                .zip(u)
                .all(|(a, b)| a.to_bits() == b.to_bits())
    }
}

/// What [`StaticProblem::evaluate`] returns.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evaluation {
    /// Total potential energy Π, J.
    pub potential: f64,
    /// Strain energy of the body alone, J.
    pub strain_energy: f64,
}

impl StaticProblem {
    /// A problem with no loads and no springs.
    pub fn new(
        grid: WeightedCellGrid,
        material: Material,
        volumetric: VolumetricIntegration,
    ) -> Self {
        let assembler = Assembler::new(&grid);
        let external = vec![0.0; 3 * grid.node_count()];
        Self {
            grid,
            material,
            volumetric,
            external,
            springs: Vec::new(),
            assembler,
            body_cache: None,
            linear_stiffness: None,
        }
    }

    /// Number of unknowns (3 per active node).
    pub fn dofs(&self) -> usize {
        3 * self.grid.node_count()
    }

    /// The grid's cell edge `h`, m.
    pub fn cell_size(&self) -> f64 {
        self.grid.grid.cell_size
    }

    /// A zeroed matrix with the tangent's sparsity pattern.
    pub fn new_tangent(&self) -> SymmetricCsc {
        self.assembler.pattern().clone()
    }

    /// Adds the cut-cell step stabilisation of coefficient `gamma` (dimensionless), i.e.
    /// `γ μ h S`, with `S` a penalty on the non-affine (hourglass) part of each cut cell's
    /// displacement weighted by the cell's outside volume fraction, to a tangent `k` (N/m) of
    /// this problem's pattern.
    /// Not part of `Π`: for the matrix of a registration step only.
    pub fn add_cut_cell_stabilization(&self, gamma: f64, k: &mut SymmetricCsc) {
        if gamma > 0.0 {
            let c = gamma * self.material.mu * self.grid.grid.cell_size;
            add_cut_cell_stabilization(&self.grid, &self.assembler, c, k);
        }
    }

    /// The assembler (pattern and scatter maps).
    pub fn assembler(&self) -> &Assembler {
        &self.assembler
    }

    /// The resultant (N) of every force on the body other than a caller's extra springs at
    /// grid displacements `u` (m) and load factor `load`: the body's own spring sets
    /// ([`StaticProblem::springs`]: fixed regions, supports) and its dead loads. Internal
    /// forces sum to zero, so at an equilibrium with extra springs `E` their resultant
    /// ([`PenaltySprings::resultant`]) is exactly the negative of this: the load `E` applies
    /// is what the holds and loads balance.
    pub fn holds_and_loads_resultant(&self, u: &[f64], load: f64) -> Vector3<f64> {
        let mut total = self
            .springs
            .iter()
            .map(|s| s.resultant(u, load))
            .sum::<Vector3<f64>>();
        for node in self.external.chunks(3) {
            total += Vector3::new(node[0], node[1], node[2]) * load;
        }
        total
    }

    /// The volume-weighted root mean square over the cells of the Frobenius norm of the
    /// displacement gradient `∇u` (dimensionless) at grid displacements `u` (m), each cell's
    /// gradient taken at its centre and weighted by its quadrature weight (its material
    /// volume). Rotations count: a rigid turn by θ gives `2√2 sin(θ/2)`. Small-strain
    /// kinematics drop `½ ∇uᵀ∇u` against `∇u`, so a first-order estimate built on `u` is off
    /// by about half of it.
    pub fn displacement_gradient_rms(&self, u: &[f64]) -> f64 {
        let h = self.grid.grid.cell_size;
        let g = crate::grid::hex8::shape_gradients(&Vector3::zeros(), h);
        let (mut sum, mut volume) = (0.0, 0.0);
        for (c, cell) in self.grid.cells.iter().enumerate() {
            let w: f64 = self.grid.quadrature.cell(c).iter().map(|q| q.weight).sum();
            let mut grad = nalgebra::Matrix3::zeros();
            for (a, &n) in cell.nodes.iter().enumerate() {
                let ua = Vector3::new(u[3 * n], u[3 * n + 1], u[3 * n + 2]);
                grad += ua * g.row(a);
            }
            sum += w * grad.norm_squared();
            volume += w;
        }
        if volume > 0.0 {
            (sum / volume).sqrt()
        } else {
            0.0
        }
    }

    /// Evaluates Π at displacements `u` (m) and load factor `load`; writes the residual
    /// `∇Π` (N) into `residual` and the tangent (N/m) into `tangent` when `need` asks for them
    /// (both are overwritten). Fails on the first inverted cell. The body's own springs only:
    /// [`StaticProblem::evaluate_with`] with no extra springs.
    pub fn evaluate(
        &mut self,
        u: &[f64],
        load: f64,
        need: Need,
        residual: Option<&mut [f64]>,
        tangent: Option<&mut SymmetricCsc>,
    ) -> Result<Evaluation, CellFailure> {
        self.evaluate_with(u, load, &[], need, residual, tangent)
    }

    /// [`StaticProblem::evaluate`] with the spring sets `extra` (N/m; e.g. a registration's
    /// data term) added to the body's own: their energy (J) enters Π, their forces (N) the
    /// residual and their stiffness (N/m) the tangent, exactly as if they were in
    /// [`StaticProblem::springs`] after the body's own sets.
    ///
    /// The cells' energy and force at the last state whose force was assembled are kept: an
    /// energy or residual evaluation at exactly that state (bit for bit, same material) adds
    /// only the springs and loads to them.
    pub fn evaluate_with(
        &mut self,
        u: &[f64],
        load: f64,
        extra: &[PenaltySprings],
        need: Need,
        residual: Option<&mut [f64]>,
        tangent: Option<&mut SymmetricCsc>,
    ) -> Result<Evaluation, CellFailure> {
        let mut residual = residual;
        let mut tangent = tangent;
        if let Some(r) = residual.as_deref_mut() {
            r.fill(0.0);
        }
        if let Some(k) = tangent.as_deref_mut() {
            k.zero_values();
        }
        let strain = if self.material.is_linear() {
            self.linear_strain_energy(u, need, residual.as_deref_mut(), tangent.as_deref_mut())?
        } else {
            self.cells_strain_energy(u, need, residual.as_deref_mut(), tangent.as_deref_mut())?
        };
        Ok(self.add_springs_and_loads(strain, u, load, extra, need, residual, tangent))
    }

    /// The cells' strain energy (J) at `u` (m), their internal force (N) into `residual` and
    /// tangent (N/m) into `tangent` as `need` asks (both zeroed by the caller), by a pass over
    /// their integration points, or from the kept force when `u` is the last state whose
    /// force was assembled ([`BodyCache`]).
    fn cells_strain_energy(
        &mut self,
        u: &[f64],
        need: Need,
        mut residual: Option<&mut [f64]>,
        tangent: Option<&mut SymmetricCsc>,
    ) -> Result<f64, CellFailure> {
        let cached = self
            .body_cache
            .as_ref()
            .filter(|c| need <= Need::Force && c.holds(u, &self.material, self.volumetric));
        if let Some(c) = cached {
            if let (true, Some(r)) = (need >= Need::Force, residual.as_deref_mut()) {
                r.copy_from_slice(&c.force);
            }
            return Ok(c.strain);
        }
        let strain = self.assembler.assemble(
            &self.grid,
            &self.material,
            self.volumetric,
            u,
            need,
            residual.as_deref_mut(),
            tangent,
        )?;
        if let (true, Some(r)) = (need >= Need::Force, residual.as_deref()) {
            let mut c = self.body_cache.take().unwrap_or_else(|| BodyCache {
                u: Vec::new(),
                material: self.material,
                volumetric: self.volumetric,
                strain,
                force: Vec::new(),
            });
            c.u.clear();
            c.u.extend_from_slice(u);
            c.force.clear();
            c.force.extend_from_slice(r);
            c.material = self.material;
            c.volumetric = self.volumetric;
            c.strain = strain;
            self.body_cache = Some(c);
        }
        Ok(strain)
    }

    /// [`StaticProblem::cells_strain_energy`] of a small-strain linear body, through its kept
    /// stiffness ([`LinearStiffness`], assembled on first use or when the material or the
    /// integration changed).
    fn linear_strain_energy(
        &mut self,
        u: &[f64],
        need: Need,
        residual: Option<&mut [f64]>,
        tangent: Option<&mut SymmetricCsc>,
    ) -> Result<f64, CellFailure> {
        let stiffness = self.linear_stiffness()?;
        stiffness.matrix.mul_vec(u, &mut stiffness.product);
        let strain = 0.5
            * u.iter()
                .zip(&stiffness.product)
                .map(|(a, b)| a * b)
                .sum::<f64>();
        if let (true, Some(r)) = (need >= Need::Force, residual) {
            r.copy_from_slice(&stiffness.product);
        }
        if let (true, Some(k)) = (need >= Need::Tangent, tangent) {
            if k.col_ptr == stiffness.matrix.col_ptr && k.row_idx == stiffness.matrix.row_idx {
                k.values.copy_from_slice(&stiffness.matrix.values);
            } else {
                self.assembler.assemble(
                    &self.grid,
                    &self.material,
                    self.volumetric,
                    u,
                    Need::Tangent,
                    None,
                    Some(&mut *k),
                )?;
            }
        }
        Ok(strain)
    }

    /// The linear body's kept stiffness, assembled when missing or stale.
    fn linear_stiffness(&mut self) -> Result<&mut LinearStiffness, CellFailure> {
        let kept = match self.linear_stiffness.take() {
            Some(k) if k.material == self.material && k.volumetric == self.volumetric => k,
            _ => {
                let mut matrix = self.assembler.pattern().clone();
                let zero = vec![0.0; self.dofs()];
                self.assembler.assemble(
                    &self.grid,
                    &self.material,
                    self.volumetric,
                    &zero,
                    Need::Tangent,
                    None,
                    Some(&mut matrix),
                )?;
                LinearStiffness {
                    material: self.material,
                    volumetric: self.volumetric,
                    matrix,
                    product: zero,
                }
            }
        };
        Ok(self.linear_stiffness.insert(kept))
    }

    /// The total potential of a body of strain energy `strain` (J) at `u` (m) and load factor
    /// `load`: its own and the `extra` springs' energies, forces and stiffnesses added to
    /// `residual` and `tangent` as `need` asks, less the dead loads' work (their forces
    /// subtracted from `residual`).
    #[allow(clippy::too_many_arguments)]
    fn add_springs_and_loads(
        &self,
        strain: f64,
        u: &[f64],
        load: f64,
        extra: &[PenaltySprings],
        need: Need,
        mut residual: Option<&mut [f64]>,
        mut tangent: Option<&mut SymmetricCsc>,
    ) -> Evaluation {
        let mut potential = strain;
        for s in self.springs.iter().chain(extra) {
            potential += s.accumulate(
                &self.assembler,
                u,
                load,
                if need >= Need::Force {
                    residual.as_deref_mut()
                } else {
                    None
                },
                if need >= Need::Tangent {
                    tangent.as_deref_mut()
                } else {
                    None
                },
            );
        }
        let mut work = 0.0;
        for (f, x) in self.external.iter().zip(u) {
            work += f * x;
        }
        potential -= load * work;
        if let (true, Some(r)) = (need >= Need::Force, residual) {
            for (ri, f) in r.iter_mut().zip(&self.external) {
                *ri -= load * f;
            }
        }
        Evaluation {
            potential,
            strain_energy: strain,
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::mechanics::{test_fixtures, LawKind};

    /// A cut 10 × 8 × 6 cm box on 2 cm cells, neo-Hookean, with dead loads.
    fn cut_box() -> StaticProblem {
        let (_, mut p) = test_fixtures::cut_box(0.076);
        p.external = (0..p.dofs()).map(|i| ((i as f64) * 0.7).sin()).collect();
        p
    }

    /// A smooth non-trivial displacement field (m), scaled by `s`.
    fn field(p: &StaticProblem, s: f64) -> Vec<f64> {
        p.grid
            .node_coords
            .iter()
            .flat_map(|ijk| {
                let x = ijk.map(|i| i as f64 * 0.02);
                let d = Vector3::new(x[1] * x[2], -0.5 * x[0] * x[1], 0.3 * x[0] * x[0]) * s;
                [d.x, d.y, d.z]
            })
            .collect()
    }

    fn force(p: &mut StaticProblem, u: &[f64], load: f64) -> (f64, Vec<f64>) {
        let mut r = vec![0.0; p.dofs()];
        let e = p
            .evaluate(u, load, Need::Force, Some(&mut r), None)
            .unwrap();
        (e.potential, r)
    }

    #[test]
    fn repeated_evaluations_at_one_state_equal_a_fresh_problems() {
        // The cached cell forces must give bit-for-bit what a problem that never saw the
        // state computes, whatever the load factor and the springs in between.
        let mut warm = cut_box();
        let u1 = field(&warm, 2.0);
        let u2 = field(&warm, -1.5);
        force(&mut warm, &u1, 1.0);
        for (u, load) in [(&u1, 0.5), (&u1, 1.0), (&u2, 1.0), (&u2, 0.25), (&u1, 0.75)] {
            let (e_warm, r_warm) = force(&mut warm, u, load);
            let energy_warm = warm.evaluate(u, load, Need::Energy, None, None).unwrap();
            let mut fresh = cut_box();
            let (e_fresh, r_fresh) = force(&mut fresh, u, load);
            assert_eq!(e_warm.to_bits(), e_fresh.to_bits());
            assert_eq!(energy_warm.potential.to_bits(), e_fresh.to_bits());
            assert!(r_warm
                .iter()
                .zip(&r_fresh)
                .all(|(a, b)| a.to_bits() == b.to_bits()));
            assert!(
                r_warm.iter().any(|v| v.abs() > 1e-6),
                "a loaded, strained state"
            );
        }
        // A new material at the same state is evaluated anew.
        let (_, before) = force(&mut warm, &u1, 1.0);
        warm.material = Material::from_young_poisson(LawKind::NeoHookean, 9000.0, 0.45).unwrap();
        let (_, after) = force(&mut warm, &u1, 1.0);
        let mut fresh = cut_box();
        fresh.material = warm.material;
        let (_, expect) = force(&mut fresh, &u1, 1.0);
        assert_ne!(before, after);
        assert_eq!(after, expect);
    }

    /// A linear body's kept stiffness gives what a pass over its cells gives: energy, force
    /// and tangent at a strained, loaded state with springs, to rounding; a changed modulus
    /// is assembled anew. The cell pass is the assembler's own, called directly.
    #[test]
    fn a_linear_bodys_kept_stiffness_equals_its_cells() {
        use crate::grid::Embedding;
        let mut p = cut_box();
        p.material = Material::from_young_poisson(LawKind::Linear, 4500.0, 0.45).unwrap();
        let u = field(&p, 2.0);
        let points: Vec<nalgebra::Point3<f64>> = [[0.02, 0.0, 0.03], [0.08, 0.05, 0.02]]
            .iter()
            .map(|c| nalgebra::Point3::new(c[0], c[1], c[2]))
            .collect();
        let springs = PenaltySprings {
            embedding: Embedding::new(&p.grid, &points).unwrap(),
            target: vec![Vector3::new(1e-3, -2e-3, 5e-4); 2],
            stiffness: vec![30.0; 2],
            follows_load: false,
            normals: None,
        };
        let cells = |p: &mut StaticProblem, u: &[f64]| {
            let mut r = vec![0.0; p.dofs()];
            let mut k = p.new_tangent();
            let (material, volumetric) = (p.material, p.volumetric);
            let e = p
                .assembler
                .assemble(
                    &p.grid,
                    &material,
                    volumetric,
                    u,
                    Need::Tangent,
                    Some(&mut r),
                    Some(&mut k),
                )
                .unwrap();
            (e, r, k)
        };
        for young in [4500.0, 20000.0] {
            p.material = Material::from_young_poisson(LawKind::Linear, young, 0.45).unwrap();
            for need in [Need::Energy, Need::Force, Need::Tangent] {
                let mut r = vec![0.0; p.dofs()];
                let mut k = p.new_tangent();
                let kept = p
                    .evaluate_with(
                        &u,
                        0.7,
                        std::slice::from_ref(&springs),
                        need,
                        Some(&mut r),
                        Some(&mut k),
                    )
                    .unwrap();
                let (e, mut r_cells, mut k_cells) = cells(&mut p, &u);
                let expected = p.add_springs_and_loads(
                    e,
                    &u,
                    0.7,
                    std::slice::from_ref(&springs),
                    Need::Tangent,
                    Some(&mut r_cells),
                    Some(&mut k_cells),
                );
                assert!(e > 0.0);
                assert!(
                    (kept.strain_energy - e).abs() <= 1e-12 * e,
                    "{kept:?} against {e}"
                );
                assert!((kept.potential - expected.potential).abs() <= 1e-12 * e);
                let close = |a: &[f64], b: &[f64]| {
                    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    scale > 0.0 && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-12 * scale)
                };
                if need >= Need::Force {
                    assert!(close(&r, &r_cells), "force at E = {young}");
                }
                if need >= Need::Tangent {
                    assert!(close(&k.values, &k_cells.values), "tangent at E = {young}");
                }
            }
        }
    }

    /// Global balance, an independent conservation law: at the equilibrium Newton reaches, a
    /// pull by extra springs is exactly what the body's holds and dead loads balance
    /// (internal forces sum to zero); off equilibrium the two differ.
    #[test]
    fn at_equilibrium_extra_springs_balance_the_holds_and_loads() {
        use crate::grid::Embedding;
        use crate::mechanics::{NewtonSettings, NewtonSolver};
        let (surface, mut p) = test_fixtures::cut_box(0.076);
        let end = |keep: &dyn Fn(f64) -> bool| -> Vec<nalgebra::Point3<f64>> {
            surface
                .vertices
                .iter()
                .filter(|v| keep(v.x))
                .copied()
                .collect()
        };
        let held = end(&|x| x < 0.004);
        let pulled = end(&|x| x > 0.102);
        p.springs = vec![PenaltySprings::fixed(
            Embedding::new(&p.grid, &held).unwrap(),
            vec![1e4; held.len()],
        )];
        p.external = (0..p.dofs())
            .map(|i| if i % 3 == 2 { -2e-4 } else { 0.0 })
            .collect();
        let pull = PenaltySprings {
            embedding: Embedding::new(&p.grid, &pulled).unwrap(),
            target: vec![Vector3::new(4e-3, 1e-3, 2e-3); pulled.len()],
            stiffness: vec![50.0; pulled.len()],
            follows_load: false,
            normals: None,
        };
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        let mut u = vec![0.0; p.dofs()];
        let report = solver.improve(&mut p, std::slice::from_ref(&pull), &mut u, 50);
        assert!(report.converged, "{report:?}");
        let applied = pull.resultant(&u, 1.0);
        let balanced = p.holds_and_loads_resultant(&u, 1.0);
        assert!(
            applied.norm() > 1e-3,
            "the pull must load the body: {applied:?}"
        );
        assert!(
            (applied + balanced).norm() <= 1e-6 * applied.norm(),
            "pull {applied:?} against holds and loads {balanced:?}"
        );
        let half: Vec<f64> = u.iter().map(|v| 0.5 * v).collect();
        let off = pull.resultant(&half, 1.0) + p.holds_and_loads_resultant(&half, 1.0);
        assert!(off.norm() > 0.1 * applied.norm(), "off balance: {off:?}");
    }

    /// The displacement gradient's RMS against analytic values: a uniform gradient `A`
    /// (u = A x) gives ‖A‖ in every cell, a rigid turn by θ gives 2√2 sin(θ/2), a
    /// translation 0.
    #[test]
    fn the_displacement_gradient_rms_matches_uniform_fields() {
        let (_, p) = test_fixtures::cut_box(0.076);
        let h = p.grid.grid.cell_size;
        let affine = |m: nalgebra::Matrix3<f64>, t: Vector3<f64>| -> Vec<f64> {
            p.grid
                .node_coords
                .iter()
                .flat_map(|ijk| {
                    let x = Vector3::from(ijk.map(|i| i as f64 * h));
                    let d = m * x + t;
                    [d.x, d.y, d.z]
                })
                .collect()
        };
        let a = nalgebra::Matrix3::new(0.01, 0.02, 0.0, -0.03, 0.0, 0.05, 0.0, 0.01, -0.02);
        let g = p.displacement_gradient_rms(&affine(a, Vector3::new(1.0, 2.0, 3.0)));
        assert!(
            (g - a.norm()).abs() < 1e-12 * a.norm(),
            "{g} against {}",
            a.norm()
        );
        let theta: f64 = 0.4;
        let turn = nalgebra::Rotation3::from_axis_angle(&Vector3::y_axis(), theta);
        let g = p.displacement_gradient_rms(&affine(
            turn.into_inner() - nalgebra::Matrix3::identity(),
            Vector3::zeros(),
        ));
        let expected = 2.0 * 2f64.sqrt() * (theta / 2.0).sin();
        assert!((g - expected).abs() < 1e-12, "{g} against {expected}");
        assert_eq!(
            p.displacement_gradient_rms(&affine(nalgebra::Matrix3::zeros(), Vector3::x())),
            0.0
        );
    }
}
