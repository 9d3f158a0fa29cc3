//! Compressible Mooney–Rivlin hyperelasticity (seed 003; `method.md` §2), with the ratio of
//! its two moduli fixed at seed 003's liver values (C10 = 0.16 kPa, C01 = 0.14 kPa), in the
//! isochoric/volumetric split of finite-element codes:
//!
//! `W = C10 (Ī₁ − 3) + C01 (Ī₂ − 3) + κ/2 (ln J)²` (J/m³), `C = FᵀF`, `J = det F`,
//! `Ī₁ = J^(−2/3) I₁`, `Ī₂ = J^(−4/3) I₂`, `I₁ = tr C`, `I₂ = ½(I₁² − tr C²)`, with
//! * `C10 = a μ/2`, `C01 = b μ/2`, `a = 0.16/0.30`, `b = 1 − a` (so `2(C10 + C01) = μ`),
//! * `κ = λ + 2μ/3`, the bulk modulus,
//!
//! so that at small strain it is linear elasticity with exactly the Lamé parameters `μ`, `λ`,
//! like every other law here. The scene's `E` and `ν` set `μ` and `λ`; seed 003's ratio sets
//! how much of the shear stiffness comes from `Ī₂`, which stiffens the law in shear and
//! compression beyond neo-Hookean (simple shear: `σ₂₂ − σ₃₃ = −2C01 γ²`, zero for a
//! neo-Hookean solid). Used as a ground truth that is none of the registration laws
//! (`TruthModel::law`), and available to scenes.
//!
//! F-form, `H = F⁻ᵀ`, `B = FFᵀ`, `α = J^(−2/3)`, `G = I₁F − FC`:
//! * `P = 2C10 α (F − I₁/3 H) + 2C01 α² (G − ⅔ I₂ H) + κ ln J H`;
//! * `∂P_iJ/∂F_kL = 2C10 α T₁ + 2C01 α² T₂ + κ (H_iJ H_kL − ln J H_iL H_kJ)` (Pa), with
//!   `T₁ = δ_ik δ_JL − ⅔(F_iJ H_kL + H_iJ F_kL) + 2/9 I₁ H_iJ H_kL + I₁/3 H_iL H_kJ` and
//!   `T₂ = 2F_iJ F_kL + I₁ δ_ik δ_JL − δ_ik C_JL − F_iL F_kJ − B_ik δ_JL
//!   − 4/3 (G_iJ H_kL + H_iJ G_kL) + 8/9 I₂ H_iJ H_kL + ⅔ I₂ H_iL H_kJ`;
//! * `S = F⁻¹P`, and `dS/dE` from `∂P/∂F`.
//!
//! Parts: the isochoric terms and `μ/3 (ln J)²` are the shear part (bounded below on its own,
//! as the shear part integrated at every quadrature point must be), `λ/2 (ln J)²` the
//! volumetric part. `J ≤ 0` → [`MaterialError::Inverted`], as for neo-Hookean.

use super::neo_hookean::kinematics;
use super::{
    material_tangent_from_a, Lame, Law, Mat3, MaterialError, PointResponse, Tangent9, Voigt6,
};

/// Share `a = C10 / (C10 + C01)` of seed 003's liver moduli (C10 = 0.16 kPa, C01 = 0.14 kPa).
pub const MOONEY_RIVLIN_C10_SHARE: f64 = 0.16 / 0.30;

/// Zero-sized marker for the Mooney–Rivlin law.
pub(super) struct MooneyRivlin;

/// Everything the stress and tangent share at one `F`.
struct State {
    c10: f64,
    c01: f64,
    kappa: f64,
    ln_j: f64,
    /// `J^(−2/3)`.
    alpha: f64,
    i1: f64,
    i2: f64,
    c: Mat3,
    h: Mat3,
    /// `G = I₁F − FC`.
    g: Mat3,
}

impl State {
    /// Errors with `Inverted` on `J ≤ 0`.
    #[inline(always)]
    fn new(p: Lame, f: &Mat3) -> Result<Self, MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        let a = MOONEY_RIVLIN_C10_SHARE;
        let c = f.tr_mul(f);
        let i1 = c.trace();
        Ok(Self {
            c10: 0.5 * a * p.mu,
            c01: 0.5 * (1.0 - a) * p.mu,
            kappa: p.lambda + 2.0 / 3.0 * p.mu,
            ln_j,
            alpha: (-2.0 / 3.0 * ln_j).exp(),
            i1,
            i2: 0.5 * (i1 * i1 - c.norm_squared()),
            g: f * i1 - f * c,
            c,
            h,
        })
    }

    /// Strain-energy density, J/m³.
    fn energy(&self) -> f64 {
        let a2 = self.alpha * self.alpha;
        self.c10 * (self.alpha * self.i1 - 3.0)
            + self.c01 * (a2 * self.i2 - 3.0)
            + 0.5 * self.kappa * self.ln_j * self.ln_j
    }

    /// First Piola–Kirchhoff stress, Pa.
    fn pk1(&self, f: &Mat3) -> Mat3 {
        let a2 = self.alpha * self.alpha;
        (f - self.h * (self.i1 / 3.0)) * (2.0 * self.c10 * self.alpha)
            + (self.g - self.h * (2.0 / 3.0 * self.i2)) * (2.0 * self.c01 * a2)
            + self.h * (self.kappa * self.ln_j)
    }

    /// Second Piola–Kirchhoff stress, Pa:
    /// `S = F⁻¹ P = 2C10 α (I − I₁/3 C⁻¹) + 2C01 α² (I₁ I − C − ⅔ I₂ C⁻¹) + κ ln J C⁻¹`.
    fn pk2(&self) -> Mat3 {
        let ci = self.h.tr_mul(&self.h);
        let id = Mat3::identity();
        let a2 = self.alpha * self.alpha;
        (id - ci * (self.i1 / 3.0)) * (2.0 * self.c10 * self.alpha)
            + (id * self.i1 - self.c - ci * (2.0 / 3.0 * self.i2)) * (2.0 * self.c01 * a2)
            + ci * (self.kappa * self.ln_j)
    }

    /// `∂P/∂F`, Pa (module docs).
    fn tangent(&self, f: &Mat3) -> Tangent9 {
        let (h, c, g) = (&self.h, &self.c, &self.g);
        let b = f * f.transpose();
        let k1 = 2.0 * self.c10 * self.alpha;
        let k2 = 2.0 * self.c01 * self.alpha * self.alpha;
        let (i1, i2, kappa, ln_j) = (self.i1, self.i2, self.kappa, self.ln_j);
        Tangent9::from_fn(|r, s| {
            let (i, jj) = (r / 3, r % 3);
            let (k, ll) = (s / 3, s % 3);
            let hh = h[(i, jj)] * h[(k, ll)];
            let hx = h[(i, ll)] * h[(k, jj)];
            let mut v1 = -2.0 / 3.0 * (f[(i, jj)] * h[(k, ll)] + h[(i, jj)] * f[(k, ll)])
                + 2.0 / 9.0 * i1 * hh
                + i1 / 3.0 * hx;
            let mut v2 = 2.0 * f[(i, jj)] * f[(k, ll)]
                - f[(i, ll)] * f[(k, jj)]
                - 4.0 / 3.0 * (g[(i, jj)] * h[(k, ll)] + h[(i, jj)] * g[(k, ll)])
                + 8.0 / 9.0 * i2 * hh
                + 2.0 / 3.0 * i2 * hx;
            if i == k {
                v2 -= c[(jj, ll)];
                if jj == ll {
                    v1 += 1.0;
                    v2 += i1;
                }
            }
            if jj == ll {
                v2 -= b[(i, k)];
            }
            k1 * v1 + k2 * v2 + kappa * (hh - ln_j * hx)
        })
    }
}

impl Law for MooneyRivlin {
    fn energy(p: Lame, f: &Mat3) -> Result<f64, MaterialError> {
        Ok(State::new(p, f)?.energy())
    }

    fn pk1(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        Ok(State::new(p, f)?.pk1(f))
    }

    fn energy_pk1(p: Lame, f: &Mat3) -> Result<(f64, Mat3), MaterialError> {
        let st = State::new(p, f)?;
        Ok((st.energy(), st.pk1(f)))
    }

    fn response(p: Lame, f: &Mat3) -> Result<PointResponse, MaterialError> {
        let st = State::new(p, f)?;
        Ok(PointResponse {
            energy: st.energy(),
            pk1: st.pk1(f),
            tangent: st.tangent(f),
        })
    }

    fn pk2(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        Ok(State::new(p, f)?.pk2())
    }

    /// From the 9×9 tangent: `dS = F⁻¹(dP − dF S)` with `dF = F⁻ᵀ dE`.
    fn material_tangent(p: Lame, f: &Mat3) -> Result<Voigt6, MaterialError> {
        let st = State::new(p, f)?;
        Ok(material_tangent_from_a(
            &st.tangent(f),
            &st.pk2(),
            &st.h.transpose(),
        ))
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

    /// Pure dilation `F = sI` leaves the isochoric invariants at 3: `W = κ/2 (3 ln s)²` and
    /// `P = κ (3 ln s)/s I`, `κ = λ + 2μ/3`; the shear part alone is bounded below as `s → 0`.
    #[test]
    fn mooney_rivlin_dilation_closed_form() {
        let m = mat();
        let kappa = m.lambda + 2.0 / 3.0 * m.mu;
        for &sc in &[0.5, 0.9, 1.0, 1.2] {
            let f = Mat3::identity() * sc;
            let ln_j = 3.0 * f64::ln(sc);
            let w = m.energy(&f, Part::Full).unwrap();
            assert!(
                (w - 0.5 * kappa * ln_j * ln_j).abs() <= 1e-12 * kappa,
                "s {sc}"
            );
            let p = m.pk1(&f, Part::Full).unwrap();
            let expect = Mat3::identity() * (kappa * ln_j / sc);
            assert!((p - expect).amax() <= 1e-12 * kappa, "s {sc}");
        }
        for &sc in &[1e-1, 1e-2, 1e-4] {
            assert!(m.energy(&(Mat3::identity() * sc), Part::Shear).unwrap() >= 0.0);
        }
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
