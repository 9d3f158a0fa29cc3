//! St Venant–Kirchhoff hyperelasticity (thesis eq. 2.8).
//!
//! `E = ½(FᵀF − I)`, `W = λ/2 (tr E)² + μ tr(E²)` (J/m³),
//! `S = λ tr(E) I + 2μ E`, `P = F S` (Pa),
//! `∂P_iJ/∂F_kL = δ_ik S_JL + F_iI ℂ_IJKL F_kK` with
//! `ℂ = λ I⊗I + 2μ 𝕀ˢʸᵐ`, which expands to
//! `δ_ik S_JL + λ F_iJ F_kL + μ (B_ik δ_JL + F_iL F_kJ)`, `B = F Fᵀ`.
//! Defined for every `F` (including inverted ones).

use super::{isotropic_voigt, Lame, Law, Mat3, MaterialError, PointResponse, Tangent9, Voigt6};

/// Zero-sized marker for the St Venant–Kirchhoff law.
pub(super) struct Svk;

/// Green–Lagrange strain `E = ½(FᵀF − I)`.
#[inline(always)]
fn green(f: &Mat3) -> Mat3 {
    (f.tr_mul(f) - Mat3::identity()) * 0.5
}

/// `S = λ tr(E) I + 2μE` (Pa) and the energy (J/m³).
#[inline(always)]
fn pk2_and_energy(p: Lame, e: &Mat3) -> (Mat3, f64) {
    let tr = e.trace();
    let mut s = e * (2.0 * p.mu);
    let vol = p.lambda * tr;
    s[(0, 0)] += vol;
    s[(1, 1)] += vol;
    s[(2, 2)] += vol;
    let w = 0.5 * p.lambda * tr * tr + p.mu * e.norm_squared();
    (s, w)
}

impl Law for Svk {
    fn energy(p: Lame, f: &Mat3) -> Result<f64, MaterialError> {
        Ok(pk2_and_energy(p, &green(f)).1)
    }

    fn pk1(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        Ok(f * pk2_and_energy(p, &green(f)).0)
    }

    fn energy_pk1(p: Lame, f: &Mat3) -> Result<(f64, Mat3), MaterialError> {
        let (s, w) = pk2_and_energy(p, &green(f));
        Ok((w, f * s))
    }

    #[inline]
    fn response(p: Lame, f: &Mat3) -> Result<PointResponse, MaterialError> {
        let (s, energy) = pk2_and_energy(p, &green(f));
        let pk1 = f * s;
        let (mu, la) = (p.mu, p.lambda);
        let fa: [[f64; 3]; 3] = f.transpose().into(); // fa[i][J] = F_iJ
        let sa: [[f64; 3]; 3] = s.into(); // symmetric
        let mut b = [[0.0f64; 3]; 3]; // B = F Fᵀ
        for i in 0..3 {
            for k in 0..3 {
                b[i][k] = fa[i][0] * fa[k][0] + fa[i][1] * fa[k][1] + fa[i][2] * fa[k][2];
            }
        }
        // A[(3i+J),(3k+L)] = δ_ik S_JL + λ F_iJ F_kL + μ (B_ik δ_JL + F_iL F_kJ);
        // `cols[c][r]` is column-major storage of A.
        let mut cols = [[0.0f64; 9]; 9];
        for k in 0..3 {
            for l in 0..3 {
                let col = &mut cols[3 * k + l];
                for i in 0..3 {
                    for j in 0..3 {
                        let mut v = la * fa[i][j] * fa[k][l] + mu * fa[i][l] * fa[k][j];
                        if j == l {
                            v += mu * b[i][k];
                        }
                        if i == k {
                            v += sa[j][l];
                        }
                        col[3 * i + j] = v;
                    }
                }
            }
        }
        let tangent = Tangent9::from_data(nalgebra::ArrayStorage(cols));
        Ok(PointResponse {
            energy,
            pk1,
            tangent,
        })
    }

    fn pk2(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        Ok(pk2_and_energy(p, &green(f)).0)
    }

    /// Constant `λ I⊗I + 2μ 𝕀ˢʸᵐ`.
    fn material_tangent(p: Lame, _f: &Mat3) -> Result<Voigt6, MaterialError> {
        Ok(isotropic_voigt(p))
    }
}

#[cfg(test)]
mod tests {
    use super::super::{LawKind, Material, Part};
    use super::*;

    /// Closed-form uniaxial check: F = diag(s,1,1) → E11 = (s²−1)/2,
    /// S11 = (λ+2μ)E11, S22 = λE11, P11 = s·S11.
    #[test]
    fn svk_uniaxial_closed_form() {
        let m = Material {
            law: LawKind::Svk,
            mu: 2.0,
            lambda: 7.0,
        };
        let s = 1.3;
        let f = Mat3::from_diagonal(&nalgebra::Vector3::new(s, 1.0, 1.0));
        let e11 = 0.5 * (s * s - 1.0);
        let p = m.pk1(&f, Part::Full).unwrap();
        assert!((p[(0, 0)] - s * 11.0 * e11).abs() < 1e-12);
        assert!((p[(1, 1)] - 7.0 * e11).abs() < 1e-12);
        let w = m.energy(&f, Part::Full).unwrap();
        assert!((w - (3.5 * e11 * e11 + 2.0 * e11 * e11)).abs() < 1e-12);
        // SVK is defined for inverted F (point reflection has E = 0).
        let r = m.response(&(-Mat3::identity()), Part::Full).unwrap();
        assert!(r.energy.abs() < 1e-14 && r.pk1.amax() < 1e-14);
    }
}
