//! Compressible neo-Hookean hyperelasticity (thesis eq. 2.9).
//!
//! `W = μ/2 (tr C − 3) − μ ln J + λ/2 (ln J)²` (J/m³), `C = FᵀF`, `J = det F`.
//! * S-form: `S = μ(I − C⁻¹) + λ ln J C⁻¹`,
//!   `ℂ = λ C⁻¹⊗C⁻¹ + 2(μ − λ ln J) C⁻¹⊙C⁻¹` (Pa).
//! * F-form used on the hot path (identical, cheaper): with `H = F⁻ᵀ`,
//!   `P = μ F + (λ ln J − μ) H` and
//!   `∂P_iJ/∂F_kL = μ δ_ik δ_JL + (μ − λ ln J) H_iL H_kJ + λ H_iJ H_kL` (Pa).
//!
//! Shear part: `μ/2 (tr C − 3) − μ ln J`; volumetric part: `λ/2 (ln J)²`.
//! `J ≤ 0` (or `J` so small that `F⁻¹` overflows) → [`MaterialError::Inverted`].

use super::{Lame, Law, Mat3, MaterialError, PointResponse, Tangent9, Voigt6, VOIGT};

/// Zero-sized marker for the neo-Hookean law.
pub(super) struct NeoHookean;

/// `J = det F`, `ln J` and `H = F⁻ᵀ = cof(F)/J`; errors on `J ≤ 0`.
#[inline(always)]
pub(super) fn kinematics(f: &Mat3) -> Result<(f64, Mat3), MaterialError> {
    let (f00, f01, f02) = (f[(0, 0)], f[(0, 1)], f[(0, 2)]);
    let (f10, f11, f12) = (f[(1, 0)], f[(1, 1)], f[(1, 2)]);
    let (f20, f21, f22) = (f[(2, 0)], f[(2, 1)], f[(2, 2)]);
    let c00 = f11 * f22 - f12 * f21;
    let c01 = f12 * f20 - f10 * f22;
    let c02 = f10 * f21 - f11 * f20;
    let j = f00 * c00 + f01 * c01 + f02 * c02;
    if j.is_nan() || j <= 0.0 {
        return Err(MaterialError::Inverted { det: j });
    }
    let inv_j = 1.0 / j;
    let h = Mat3::new(
        c00 * inv_j,
        c01 * inv_j,
        c02 * inv_j,
        (f02 * f21 - f01 * f22) * inv_j,
        (f00 * f22 - f02 * f20) * inv_j,
        (f01 * f20 - f00 * f21) * inv_j,
        (f01 * f12 - f02 * f11) * inv_j,
        (f02 * f10 - f00 * f12) * inv_j,
        (f00 * f11 - f01 * f10) * inv_j,
    );
    // J > 0 but so small (or F so large) that F⁻ᵀ is not representable.
    if h.iter().fold(0.0, |a, &x| a + x * 0.0) != 0.0 {
        return Err(MaterialError::Inverted { det: j });
    }
    Ok((j.ln(), h))
}

#[inline(always)]
fn energy_of(p: Lame, f: &Mat3, ln_j: f64) -> f64 {
    0.5 * p.mu * (f.norm_squared() - 3.0) - p.mu * ln_j + 0.5 * p.lambda * ln_j * ln_j
}

impl Law for NeoHookean {
    fn energy(p: Lame, f: &Mat3) -> Result<f64, MaterialError> {
        // same admissibility test as `pk1`/`response` (a line search calling
        // `energy` must fail exactly where the Newton step would)
        let (ln_j, _) = kinematics(f)?;
        Ok(energy_of(p, f, ln_j))
    }

    fn pk1(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        Ok(f * p.mu + h * (p.lambda * ln_j - p.mu))
    }

    fn energy_pk1(p: Lame, f: &Mat3) -> Result<(f64, Mat3), MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        Ok((
            energy_of(p, f, ln_j),
            f * p.mu + h * (p.lambda * ln_j - p.mu),
        ))
    }

    #[inline]
    fn response(p: Lame, f: &Mat3) -> Result<PointResponse, MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        let energy = energy_of(p, f, ln_j);
        let pk1 = f * p.mu + h * (p.lambda * ln_j - p.mu);
        let (mu, la) = (p.mu, p.lambda);
        let g = mu - la * ln_j;
        // A[(3i+J),(3k+L)] = (μ − λ ln J) H_iL H_kJ + λ H_iJ H_kL + μ δ_ik δ_JL;
        // `cols[3k+L][3i+J]` is the column-major storage of A.
        let ha: [[f64; 3]; 3] = h.transpose().into(); // ha[i][J] = H_iJ
        let mut cols = [[0.0f64; 9]; 9];
        for k in 0..3 {
            for l in 0..3 {
                let col = &mut cols[3 * k + l];
                let lhkl = la * ha[k][l];
                for i in 0..3 {
                    let ghil = g * ha[i][l];
                    for j in 0..3 {
                        col[3 * i + j] = ghil * ha[k][j] + lhkl * ha[i][j];
                    }
                }
                col[3 * k + l] += mu;
            }
        }
        let tangent = Tangent9::from_data(nalgebra::ArrayStorage(cols));
        Ok(PointResponse {
            energy,
            pk1,
            tangent,
        })
    }

    /// `S = μ(I − C⁻¹) + λ ln J C⁻¹`, `C⁻¹ = HᵀH`.
    fn pk2(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        let c_inv = h.tr_mul(&h);
        Ok(Mat3::identity() * p.mu + c_inv * (p.lambda * ln_j - p.mu))
    }

    /// `ℂ_IJKL = λ C⁻¹_IJ C⁻¹_KL + (μ − λ ln J)(C⁻¹_IK C⁻¹_JL + C⁻¹_IL C⁻¹_JK)`.
    fn material_tangent(p: Lame, f: &Mat3) -> Result<Voigt6, MaterialError> {
        let (ln_j, h) = kinematics(f)?;
        let ci = h.tr_mul(&h);
        let g = p.mu - p.lambda * ln_j;
        Ok(Voigt6::from_fn(|a, b| {
            let (i, j) = VOIGT[a];
            let (k, l) = VOIGT[b];
            p.lambda * ci[(i, j)] * ci[(k, l)]
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
        Material::from_young_poisson(LawKind::NeoHookean, 4500.0, 0.45).unwrap()
    }

    /// det F ≤ 0 → `Inverted` carrying det F, for every entry point and part.
    #[test]
    fn neo_hookean_rejects_inverted_and_singular() {
        let m = mat();
        let cases = [
            (Mat3::from_diagonal(&Vector3::new(1.0, 1.0, -0.5)), -0.5),
            (Mat3::from_diagonal(&Vector3::new(1.2, 0.7, 0.0)), 0.0),
            (-Mat3::identity(), -1.0),
            (
                Mat3::new(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0),
                -3.0,
            ),
        ];
        for (f, det) in cases {
            for part in [Part::Full, Part::Shear, Part::Volumetric] {
                let check = |e: MaterialError| match e {
                    MaterialError::Inverted { det: d } => {
                        assert!((d - det).abs() < 1e-12, "det {d} vs {det}")
                    }
                    other => panic!("expected Inverted, got {other:?}"),
                };
                check(m.energy(&f, part).unwrap_err());
                check(m.pk1(&f, part).unwrap_err());
                check(m.energy_pk1(&f, part).unwrap_err());
                check(m.response(&f, part).unwrap_err());
                check(m.pk2(&f, part).unwrap_err());
                check(m.material_tangent(&f, part).unwrap_err());
            }
        }
        // J > 0 but F⁻¹ not representable: still an error, never NaN/∞.
        let f = Mat3::from_diagonal(&Vector3::new(1e-200, 1e-200, 1.0));
        assert!(matches!(
            m.response(&f, Part::Full),
            Err(MaterialError::Inverted { .. })
        ));
        assert!(matches!(
            m.energy(&f, Part::Full),
            Err(MaterialError::Inverted { .. })
        ));
        let msg = m
            .pk1(&-Mat3::identity(), Part::Full)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("-1e0"), "{msg}");
    }

    /// Uniaxial stress: F = diag(λ1, λ2, λ2) with λ2 solving P22 = 0 by
    /// bisection; P11 must equal μ(λ1 − 1/λ1) + λ ln(J)/λ1, J = λ1 λ2².
    #[test]
    fn neo_hookean_uniaxial_closed_form() {
        let m = mat();
        for &l1 in &[0.6, 0.9, 1.05, 1.5, 2.0] {
            let p22 = |l2: f64| {
                let f = Mat3::from_diagonal(&Vector3::new(l1, l2, l2));
                m.pk1(&f, Part::Full).unwrap()[(1, 1)]
            };
            let (mut lo, mut hi) = (1e-3, 10.0);
            assert!(p22(lo) < 0.0 && p22(hi) > 0.0);
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if p22(mid) > 0.0 {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            let l2 = 0.5 * (lo + hi);
            let f = Mat3::from_diagonal(&Vector3::new(l1, l2, l2));
            let p = m.pk1(&f, Part::Full).unwrap();
            let j: f64 = l1 * l2 * l2;
            let closed = m.mu * (l1 - 1.0 / l1) + m.lambda * j.ln() / l1;
            assert!(
                (p[(0, 0)] - closed).abs() <= 1e-10 * closed.abs(),
                "λ1={l1}: P11={} closed={closed}",
                p[(0, 0)]
            );
            let scale = m.wave_speed_modulus();
            assert!(p[(1, 1)].abs() < 1e-9 * scale && p[(2, 2)].abs() < 1e-9 * scale);
            // Lateral contraction direction is right and nearly incompressible.
            assert!((l1 > 1.0) == (l2 < 1.0));
            assert!((j - 1.0).abs() < (l1 - 1.0_f64).abs());
        }
    }

    /// S-form and F-form agree: P = F S and A reconstructed from ℂ.
    #[test]
    fn neo_hookean_s_form_matches_f_form() {
        let m = mat();
        let f = Mat3::new(1.3, 0.2, -0.1, 0.05, 0.8, 0.3, -0.2, 0.1, 1.1);
        let p = m.pk1(&f, Part::Full).unwrap();
        let s = m.pk2(&f, Part::Full).unwrap();
        assert!((p - f * s).amax() <= 1e-12 * p.amax());
        // A_iJkL = δ_ik S_JL + F_iI ℂ_IJKL F_kK
        let cv = m.material_tangent(&f, Part::Full).unwrap();
        // every VOIGT pair is stored as (min, max)
        let voigt_of = |i: usize, j: usize| {
            VOIGT
                .iter()
                .position(|&p| p == (i.min(j), i.max(j)))
                .unwrap()
        };
        let c4 = |i: usize, j: usize, k: usize, l: usize| cv[(voigt_of(i, j), voigt_of(k, l))];
        let a = m.response(&f, Part::Full).unwrap().tangent;
        let mut err: f64 = 0.0;
        for i in 0..3 {
            for jj in 0..3 {
                for k in 0..3 {
                    for ll in 0..3 {
                        let mut v = if i == k { s[(jj, ll)] } else { 0.0 };
                        for ii in 0..3 {
                            for kk in 0..3 {
                                v += f[(i, ii)] * c4(ii, jj, kk, ll) * f[(k, kk)];
                            }
                        }
                        err = err.max((v - a[(3 * i + jj, 3 * k + ll)]).abs());
                    }
                }
            }
        }
        assert!(err <= 1e-11 * a.amax(), "err {err}");
    }
}
