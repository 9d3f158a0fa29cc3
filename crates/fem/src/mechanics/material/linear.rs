//! Small-strain linear elasticity.
//!
//! `ε = sym(F) − I`, `W = μ ε:ε + λ/2 (tr ε)²` (J/m³),
//! `P = σ = 2μ ε + λ tr(ε) I` (Pa), constant tangent
//! `∂P_iJ/∂F_kL = μ(δ_ik δ_JL + δ_iL δ_Jk) + λ δ_iJ δ_kL` (Pa).
//! Not rotation invariant (by design: it is the geometrically linear model).

use super::{isotropic_voigt, Lame, Law, Mat3, MaterialError, PointResponse, Tangent9, Voigt6};

/// Zero-sized marker for the small-strain law.
pub(super) struct Linear;

/// Small strain `ε = sym(F) − I` (dimensionless).
#[inline(always)]
fn strain(f: &Mat3) -> Mat3 {
    (f + f.transpose()) * 0.5 - Mat3::identity()
}

/// `σ = 2με + λ tr(ε) I` (Pa).
#[inline(always)]
fn stress(p: Lame, eps: &Mat3) -> Mat3 {
    let mut s = eps * (2.0 * p.mu);
    let vol = p.lambda * eps.trace();
    s[(0, 0)] += vol;
    s[(1, 1)] += vol;
    s[(2, 2)] += vol;
    s
}

/// The constant small-strain tangent (Pa) in [`Tangent9`] layout.
#[inline(always)]
pub(super) fn tangent(p: Lame) -> Tangent9 {
    // column-major storage `cols[3k+L][3i+J]`
    let mut cols = [[0.0f64; 9]; 9];
    for i in 0..3 {
        for j in 0..3 {
            // μ δ_ik δ_JL
            cols[3 * i + j][3 * i + j] += p.mu;
            // μ δ_iL δ_Jk
            cols[3 * j + i][3 * i + j] += p.mu;
        }
        for k in 0..3 {
            // λ δ_iJ δ_kL
            cols[3 * k + k][3 * i + i] += p.lambda;
        }
    }
    Tangent9::from_data(nalgebra::ArrayStorage(cols))
}

impl Law for Linear {
    fn energy(p: Lame, f: &Mat3) -> Result<f64, MaterialError> {
        let eps = strain(f);
        let tr = eps.trace();
        Ok(p.mu * eps.norm_squared() + 0.5 * p.lambda * tr * tr)
    }

    fn pk1(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        Ok(stress(p, &strain(f)))
    }

    fn energy_pk1(p: Lame, f: &Mat3) -> Result<(f64, Mat3), MaterialError> {
        let eps = strain(f);
        let tr = eps.trace();
        Ok((
            p.mu * eps.norm_squared() + 0.5 * p.lambda * tr * tr,
            stress(p, &eps),
        ))
    }

    #[inline]
    fn response(p: Lame, f: &Mat3) -> Result<PointResponse, MaterialError> {
        let eps = strain(f);
        let tr = eps.trace();
        Ok(PointResponse {
            energy: p.mu * eps.norm_squared() + 0.5 * p.lambda * tr * tr,
            pk1: stress(p, &eps),
            tangent: tangent(p),
        })
    }

    /// Small-strain theory has a single stress measure: returns σ.
    fn pk2(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        Ok(stress(p, &strain(f)))
    }

    /// `dσ/dε`, constant.
    fn material_tangent(p: Lame, _f: &Mat3) -> Result<Voigt6, MaterialError> {
        Ok(isotropic_voigt(p))
    }
}

#[cfg(test)]
mod tests {
    use super::super::{LawKind, Material, Part};
    use super::*;

    /// σ is linear in the displacement gradient and ignores its skew part.
    #[test]
    fn linear_stress_is_symmetric_and_ignores_spin() {
        let m = Material {
            law: LawKind::Linear,
            mu: 3.0,
            lambda: 5.0,
        };
        let g = Mat3::new(0.1, 0.02, -0.03, 0.04, -0.05, 0.06, 0.07, 0.08, 0.09);
        let w = Mat3::new(0.0, 0.3, -0.2, -0.3, 0.0, 0.1, 0.2, -0.1, 0.0);
        let p1 = m.pk1(&(Mat3::identity() + g), Part::Full).unwrap();
        let p2 = m.pk1(&(Mat3::identity() + g + w), Part::Full).unwrap();
        assert!((p1 - p2).amax() < 1e-14);
        assert!((p1 - p1.transpose()).amax() < 1e-14);
        // uniaxial strain ε11 = 0.1 → σ11 = (λ+2μ)·0.1, σ22 = λ·0.1
        let f = Mat3::from_diagonal(&nalgebra::Vector3::new(1.1, 1.0, 1.0));
        let s = m.pk1(&f, Part::Full).unwrap();
        assert!((s[(0, 0)] - 1.1).abs() < 1e-12);
        assert!((s[(1, 1)] - 0.5).abs() < 1e-12);
        assert_eq!(m.pk2(&f, Part::Full).unwrap(), s);
    }
}
