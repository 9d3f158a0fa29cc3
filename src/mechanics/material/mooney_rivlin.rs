//! Compressible Mooney–Rivlin hyperelasticity (seed 003; `method.md` §2), with the ratio of
//! its two moduli fixed at seed 003's liver values (C10 = 0.16 kPa, C01 = 0.14 kPa).
//!
//! `W = C10 (I₁ − 3) + C01 (I₂ − 3) − d ln J + e/2 (ln J)²` (J/m³), `C = FᵀF`, `I₁ = tr C`,
//! `I₂ = ½(I₁² − tr C²)`, `J = det F`, with
//! * `C10 = a μ/2`, `C01 = b μ/2`, `a = 0.16/0.30`, `b = 0.14/0.30` (so `2(C10 + C01) = μ`),
//! * `d = (a + 2b) μ` (the stress vanishes at `F = I`),
//! * `e = λ − 2bμ` (the small-strain limit is linear elasticity with exactly the Lamé
//!   parameters `μ`, `λ`, like every other law here).
//!
//! The scene's `E` and `ν` set `μ` and `λ`; seed 003's ratio `C10 : C01` sets how much of the
//! shear stiffness comes from `I₂`, which stiffens the law in compression and shear beyond
//! neo-Hookean (`b = 0` is the neo-Hookean law of eq. 2.9 exactly). Used as a ground truth
//! that is none of the registration laws (`TruthModel::law`), and available to scenes.
//!
//! * S-form: `S = 2C10 I + 2C01 (I₁ I − C) + (e ln J − d) C⁻¹`,
//!   `ℂ = 4C01 (I⊗I − 𝕀ˢʸᵐ) + e C⁻¹⊗C⁻¹ + 2(d − e ln J) C⁻¹⊙C⁻¹` (Pa).
//! * F-form (hot path), `H = F⁻ᵀ`, `B = FFᵀ`:
//!   `P = 2C10 F + 2C01 (I₁ F − F C) + (e ln J − d) H`,
//!   `∂P_iJ/∂F_kL = (2C10 + 2C01 I₁) δ_ik δ_JL + 4C01 F_iJ F_kL
//!   − 2C01 (δ_ik C_JL + F_iL F_kJ + B_ik δ_JL) + e H_iJ H_kL + (d − e ln J) H_iL H_kJ` (Pa).
//!
//! Shear part: the terms in μ; volumetric part: `λ/2 (ln J)²`.
//! `J ≤ 0` → [`MaterialError::Inverted`], as for neo-Hookean.

use super::neo_hookean::kinematics;
use super::{Lame, Law, Mat3, MaterialError, PointResponse, Tangent9, Voigt6, VOIGT};

/// Share `a = C10 / (C10 + C01)` of seed 003's liver moduli (C10 = 0.16 kPa, C01 = 0.14 kPa).
pub const MOONEY_RIVLIN_C10_SHARE: f64 = 0.16 / 0.30;

/// Zero-sized marker for the Mooney–Rivlin law.
pub(super) struct MooneyRivlin;

/// The law's coefficients for Lamé parameters `p` (Pa): `(C10, C01, d, e)`.
#[inline(always)]
fn coefficients(p: Lame) -> (f64, f64, f64, f64) {
    let a = MOONEY_RIVLIN_C10_SHARE;
    let b = 1.0 - a;
    (
        0.5 * a * p.mu,
        0.5 * b * p.mu,
        (a + 2.0 * b) * p.mu,
        p.lambda - 2.0 * b * p.mu,
    )
}

/// Energy (J/m³) and `P` (Pa) from `F`, `ln J` and `H = F⁻ᵀ`; also returns `C` and `I₁`.
#[inline(always)]
fn energy_and_pk1(p: Lame, f: &Mat3, ln_j: f64, h: &Mat3) -> (f64, Mat3, Mat3, f64) {
    let (c10, c01, d, e) = coefficients(p);
    let c = f.tr_mul(f);
    let i1 = c.trace();
    let i2 = 0.5 * (i1 * i1 - c.norm_squared());
    let energy = c10 * (i1 - 3.0) + c01 * (i2 - 3.0) - d * ln_j + 0.5 * e * ln_j * ln_j;
    let pk1 = f * (2.0 * c10 + 2.0 * c01 * i1) - (f * c) * (2.0 * c01) + h * (e * ln_j - d);
    (energy, pk1, c, i1)
}

impl Law for MooneyRivlin {
    fn energy(p: Lame, f: &Mat3) -> Result<f64, MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        Ok(energy_and_pk1(p, f, ln_j, &h).0)
    }

    fn pk1(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        Ok(energy_and_pk1(p, f, ln_j, &h).1)
    }

    fn energy_pk1(p: Lame, f: &Mat3) -> Result<(f64, Mat3), MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        let (w, pk1, _, _) = energy_and_pk1(p, f, ln_j, &h);
        Ok((w, pk1))
    }

    fn response(p: Lame, f: &Mat3) -> Result<PointResponse, MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        let (energy, pk1, c, i1) = energy_and_pk1(p, f, ln_j, &h);
        let (c10, c01, d, e) = coefficients(p);
        let b = f * f.transpose();
        let diag = 2.0 * c10 + 2.0 * c01 * i1;
        let g = d - e * ln_j;
        let tangent = Tangent9::from_fn(|r, s| {
            let (i, jj) = (r / 3, r % 3);
            let (k, ll) = (s / 3, s % 3);
            let mut v = 4.0 * c01 * f[(i, jj)] * f[(k, ll)] - 2.0 * c01 * f[(i, ll)] * f[(k, jj)]
                + e * h[(i, jj)] * h[(k, ll)]
                + g * h[(i, ll)] * h[(k, jj)];
            if i == k {
                v -= 2.0 * c01 * c[(jj, ll)];
                if jj == ll {
                    v += diag;
                }
            }
            if jj == ll {
                v -= 2.0 * c01 * b[(i, k)];
            }
            v
        });
        Ok(PointResponse {
            energy,
            pk1,
            tangent,
        })
    }

    /// `S = 2C10 I + 2C01 (I₁ I − C) + (e ln J − d) C⁻¹`, `C⁻¹ = HᵀH`.
    fn pk2(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        let (c10, c01, d, e) = coefficients(p);
        let c = f.tr_mul(f);
        let c_inv = h.tr_mul(&h);
        Ok(
            Mat3::identity() * (2.0 * c10 + 2.0 * c01 * c.trace()) - c * (2.0 * c01)
                + c_inv * (e * ln_j - d),
        )
    }

    /// `ℂ_IJKL = 4C01 (δ_IJ δ_KL − ½(δ_IK δ_JL + δ_IL δ_JK)) + e C⁻¹_IJ C⁻¹_KL
    /// + (d − e ln J)(C⁻¹_IK C⁻¹_JL + C⁻¹_IL C⁻¹_JK)`.
    fn material_tangent(p: Lame, f: &Mat3) -> Result<Voigt6, MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        let (_, c01, d, e) = coefficients(p);
        let ci = h.tr_mul(&h);
        let g = d - e * ln_j;
        let delta = |x: usize, y: usize| if x == y { 1.0 } else { 0.0 };
        Ok(Voigt6::from_fn(|a, b| {
            let (i, j) = VOIGT[a];
            let (k, l) = VOIGT[b];
            4.0 * c01
                * (delta(i, j) * delta(k, l)
                    - 0.5 * (delta(i, k) * delta(j, l) + delta(i, l) * delta(j, k)))
                + e * ci[(i, j)] * ci[(k, l)]
                + g * (ci[(i, k)] * ci[(j, l)] + ci[(i, l)] * ci[(j, k)])
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::super::{LawKind, Material, Part};
    use super::*;
    use nalgebra::Vector3;

    fn mat() -> Material {
        Material::from_young_poisson(LawKind::MooneyRivlin, 4500.0, 0.45).unwrap()
    }

    /// Simple shear `F = I + γ e₁⊗e₂` keeps `J = 1` and `I₁ = I₂ = 3 + γ²`, so
    /// `W = (C10 + C01) γ² = μγ²/2` and the shear stress `P₁₂ = 2(C10 + C01) γ = μγ` exactly
    /// (the Mooney–Rivlin shear response is linear). The normal stresses tell it from
    /// neo-Hookean: `σ₁₁ − σ₂₂ = μγ²` for both, `σ₂₂ − σ₃₃ = −2C01 γ²` (zero for neo-Hookean).
    #[test]
    fn mooney_rivlin_simple_shear_closed_form() {
        let m = mat();
        let (c10, c01) = (
            0.5 * MOONEY_RIVLIN_C10_SHARE * m.mu,
            0.5 * (1.0 - MOONEY_RIVLIN_C10_SHARE) * m.mu,
        );
        for &gamma in &[0.01, 0.3, 1.0] {
            let mut f = Mat3::identity();
            f[(0, 1)] = gamma;
            let w = m.energy(&f, Part::Full).unwrap();
            assert!((w - (c10 + c01) * gamma * gamma).abs() <= 1e-12 * m.mu);
            let s = m.pk2(&f, Part::Full).unwrap();
            // C = [[1, γ, 0], [γ, 1 + γ², 0], [0, 0, 1]], C⁻¹ = [[1 + γ², −γ, 0], [−γ, 1, 0], [0, 0, 1]]
            // S = 2C10 I + 2C01 (I₁ I − C) − d C⁻¹ with ln J = 0.
            let d = (MOONEY_RIVLIN_C10_SHARE + 2.0 * (1.0 - MOONEY_RIVLIN_C10_SHARE)) * m.mu;
            let s11 =
                2.0 * c10 + 2.0 * c01 * (3.0 + gamma * gamma - 1.0) - d * (1.0 + gamma * gamma);
            let s22 = 2.0 * c10 + 2.0 * c01 * (3.0 + gamma * gamma - 1.0 - gamma * gamma) - d;
            let s12 = -2.0 * c01 * gamma + d * gamma;
            assert!((s[(0, 0)] - s11).abs() <= 1e-12 * m.mu, "γ {gamma}");
            assert!((s[(1, 1)] - s22).abs() <= 1e-12 * m.mu, "γ {gamma}");
            assert!((s[(0, 1)] - s12).abs() <= 1e-12 * m.mu, "γ {gamma}");
            // Cauchy stress σ = F S Fᵀ / J (J = 1): shear μγ for every γ, and the normal
            // stress differences of the Mooney–Rivlin solid in simple shear.
            let sigma = f * s * f.transpose();
            let tol = 1e-12 * m.mu;
            assert!((sigma[(0, 1)] - m.mu * gamma).abs() <= tol, "γ {gamma}");
            let g2 = gamma * gamma;
            assert!(
                (sigma[(0, 0)] - sigma[(1, 1)] - m.mu * g2).abs() <= tol,
                "γ {gamma}"
            );
            assert!(
                (sigma[(1, 1)] - sigma[(2, 2)] + 2.0 * c01 * g2).abs() <= tol,
                "γ {gamma}"
            );
        }
    }

    /// With `C01 = 0` the law is neo-Hookean (eq. 2.9): check through the difference of the
    /// two energies, which must be exactly the `C01` terms.
    #[test]
    fn mooney_rivlin_minus_neo_hookean_is_the_c01_terms() {
        let m = mat();
        let nh = Material {
            law: LawKind::NeoHookean,
            ..m
        };
        let b = 1.0 - MOONEY_RIVLIN_C10_SHARE;
        let f = Mat3::new(1.3, 0.2, -0.1, 0.05, 0.8, 0.3, -0.2, 0.1, 1.1);
        let c = f.tr_mul(&f);
        let (i1, j) = (c.trace(), f.determinant());
        let i2 = 0.5 * (i1 * i1 - c.norm_squared());
        // W_MR − W_NH = C01 (I₂ − 3) + (a/2 − 1/2) μ (I₁ − 3) − (a + 2b − 1) μ ln J − bμ (ln J)²
        let a = MOONEY_RIVLIN_C10_SHARE;
        let expect = 0.5 * b * m.mu * (i2 - 3.0) + 0.5 * (a - 1.0) * m.mu * (i1 - 3.0)
            - (a + 2.0 * b - 1.0) * m.mu * j.ln()
            - b * m.mu * j.ln() * j.ln();
        let diff = m.energy(&f, Part::Full).unwrap() - nh.energy(&f, Part::Full).unwrap();
        assert!(
            (diff - expect).abs() <= 1e-12 * m.wave_speed_modulus(),
            "{diff} {expect}"
        );
    }

    /// `det F ≤ 0` is an `Inverted` error from every entry point, never a number.
    #[test]
    fn mooney_rivlin_rejects_inverted() {
        let m = mat();
        let f = Mat3::from_diagonal(&Vector3::new(1.0, 1.0, -0.5));
        for part in [Part::Full, Part::Shear, Part::Volumetric] {
            assert!(matches!(
                m.energy(&f, part),
                Err(MaterialError::Inverted { .. })
            ));
            assert!(matches!(
                m.response(&f, part),
                Err(MaterialError::Inverted { .. })
            ));
            assert!(matches!(
                m.pk2(&f, part),
                Err(MaterialError::Inverted { .. })
            ));
        }
    }
}
