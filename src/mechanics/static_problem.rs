//! The discrete static equilibrium problem on an immersed grid: total potential energy, its
//! gradient (residual) and Hessian (tangent) — thesis eq. 4.9–4.11 and 4.22.

use super::assembly::{Assembler, CellFailure};
use super::cell_kernel::{Need, VolumetricIntegration};
use super::material::Material;
use super::penalty::PenaltySprings;
use crate::grid::WeightedCellGrid;
use crate::linalg::SymmetricCsc;

/// Hyperelastic body on a [`WeightedCellGrid`] under dead loads and penalty springs, in SI units
/// (m, N, Pa, J). At load factor `s` the total potential energy is
/// `Π(u) = W_int(u) + W_springs(u; s) − s f_extᵀ u`; the residual is `∇Π` and the tangent `∇²Π`.
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
    /// Penalty spring sets (fixed regions, registration targets).
    pub springs: Vec<PenaltySprings>,
    assembler: Assembler,
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
        }
    }

    /// Number of unknowns (3 per active node).
    pub fn dofs(&self) -> usize {
        3 * self.grid.node_count()
    }

    /// A zeroed matrix with the tangent's sparsity pattern.
    pub fn new_tangent(&self) -> SymmetricCsc {
        self.assembler.pattern().clone()
    }

    /// The assembler (pattern and scatter maps).
    pub fn assembler(&self) -> &Assembler {
        &self.assembler
    }

    /// Evaluates Π at displacements `u` (m) and load factor `load`; writes the residual
    /// `∇Π` (N) into `residual` and the tangent (N/m) into `tangent` when `need` asks for them
    /// (both are overwritten). Fails on the first inverted cell.
    pub fn evaluate(
        &mut self,
        u: &[f64],
        load: f64,
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
        let strain = self.assembler.assemble(
            &self.grid,
            &self.material,
            self.volumetric,
            u,
            need,
            residual.as_deref_mut(),
            tangent.as_deref_mut(),
        )?;
        let mut potential = strain;
        for s in &self.springs {
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
        Ok(Evaluation {
            potential,
            strain_energy: strain,
        })
    }
}
