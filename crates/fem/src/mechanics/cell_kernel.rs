//! Energy, internal force and tangent of one hexahedral cell (thesis eq. 2.26–2.27, 4.10–4.11),
//! with selective reduced integration of the volumetric (λ) terms against volumetric locking.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use serde::{Deserialize, Serialize};

use super::material::{Material, MaterialError, Part};
use crate::grid::hex8::shape_gradients;
use crate::grid::QuadPoint;

/// Element force vector: 8 nodes × 3 components, node-major (N).
pub(crate) type CellForce = SVector<f64, 24>;
/// Element tangent: 24 × 24, node-major (N/m).
pub(crate) type CellTangent = SMatrix<f64, 24, 24>;

/// How the volumetric (λ-multiplied) part of the strain energy is integrated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum VolumetricIntegration {
    /// One point at the cell centre carrying the whole cell weight (selective reduced
    /// integration): trilinear hexahedra do not lock as ν → 0.5. The shear part keeps the
    /// cell's full rule, which controls the hourglass modes of the reduced part.
    #[default]
    Reduced,
    /// The same points as the shear part (locks for ν near 0.5; for comparison).
    Full,
}

/// What to compute for a cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Need {
    /// Strain energy only.
    Energy,
    /// Energy and internal force.
    Force,
    /// Energy, internal force and tangent.
    Tangent,
    /// Energy, internal force and the tangent made positive semi-definite per integration
    /// point ([`Material::response_projected`]): a descent direction for Newton.
    ProjectedTangent,
}

/// Energy (J), internal force (N) and tangent (N/m) of one cell.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct CellResponse {
    /// Strain energy of the cell, J (with lengths in m and moduli in Pa).
    pub energy: f64,
    /// Internal nodal forces `R_a = ∫ P ∇N_a dV`.
    pub force: CellForce,
    /// Tangent `K_ab = ∫ ∇N_aᵀ (∂P/∂F) ∇N_b dV`.
    pub tangent: CellTangent,
}

impl Default for CellResponse {
    fn default() -> Self {
        Self {
            energy: 0.0,
            force: CellForce::zeros(),
            tangent: CellTangent::zeros(),
        }
    }
}

/// Evaluates a cell of edge `h` with nodal displacements `u` at its integration points.
/// Fails with the material's error when a point is inverted (or non-finite).
pub(crate) fn evaluate_cell(
    material: &Material,
    volumetric: VolumetricIntegration,
    h: f64,
    u: &[Vector3<f64>; 8],
    points: &[QuadPoint],
    need: Need,
    out: &mut CellResponse,
) -> Result<(), MaterialError> {
    out.energy = 0.0;
    if need >= Need::Force {
        out.force.fill(0.0);
    }
    if need >= Need::Tangent {
        out.tangent.fill(0.0);
    }
    let part = match volumetric {
        VolumetricIntegration::Reduced => Part::Shear,
        VolumetricIntegration::Full => Part::Full,
    };
    let mut total_weight = 0.0;
    for q in points {
        total_weight += q.weight;
        point_contribution(material, part, h, u, &q.xi, q.weight, need, out)?;
    }
    if volumetric == VolumetricIntegration::Reduced && total_weight > 0.0 {
        point_contribution(
            material,
            Part::Volumetric,
            h,
            u,
            &Vector3::zeros(),
            total_weight,
            need,
            out,
        )?;
    }
    Ok(())
}

/// Adds the contribution of one integration point to `out`.
#[allow(clippy::too_many_arguments)]
fn point_contribution(
    material: &Material,
    part: Part,
    h: f64,
    u: &[Vector3<f64>; 8],
    xi: &Vector3<f64>,
    w: f64,
    need: Need,
    out: &mut CellResponse,
) -> Result<(), MaterialError> {
    let g = shape_gradients(xi, h);
    let mut f = Matrix3::identity();
    for a in 0..8 {
        for i in 0..3 {
            for j in 0..3 {
                f[(i, j)] += u[a][i] * g[(a, j)];
            }
        }
    }
    match need {
        Need::Energy => out.energy += w * material.energy(&f, part)?,
        Need::Force => {
            let (energy, p) = material.energy_pk1(&f, part)?;
            out.energy += w * energy;
            add_force(&p, &g, w, &mut out.force);
        }
        Need::Tangent | Need::ProjectedTangent => {
            let r = if need == Need::ProjectedTangent {
                material.response_projected(&f, part)?
            } else {
                material.response(&f, part)?
            };
            out.energy += w * r.energy;
            add_force(&r.pk1, &g, w, &mut out.force);
            // M_a[i][3k+L] = Σ_J g_aJ A[3i+J][3k+L]; K_ab[i][k] = Σ_L M_a[i][3k+L] g_bL.
            let a9 = &r.tangent;
            let mut m = [[[0.0f64; 9]; 3]; 8];
            for (a, ma) in m.iter_mut().enumerate() {
                for (i, row) in ma.iter_mut().enumerate() {
                    for (col, v) in row.iter_mut().enumerate() {
                        *v = w
                            * (g[(a, 0)] * a9[(3 * i, col)]
                                + g[(a, 1)] * a9[(3 * i + 1, col)]
                                + g[(a, 2)] * a9[(3 * i + 2, col)]);
                    }
                }
            }
            for (a, ma) in m.iter().enumerate() {
                for b in 0..=a {
                    for (i, row) in ma.iter().enumerate() {
                        for k in 0..3 {
                            let v = row[3 * k] * g[(b, 0)]
                                + row[3 * k + 1] * g[(b, 1)]
                                + row[3 * k + 2] * g[(b, 2)];
                            out.tangent[(3 * a + i, 3 * b + k)] += v;
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

fn add_force(p: &Matrix3<f64>, g: &SMatrix<f64, 8, 3>, w: f64, force: &mut CellForce) {
    for a in 0..8 {
        for i in 0..3 {
            force[3 * a + i] +=
                w * (p[(i, 0)] * g[(a, 0)] + p[(i, 1)] * g[(a, 1)] + p[(i, 2)] * g[(a, 2)]);
        }
    }
}
