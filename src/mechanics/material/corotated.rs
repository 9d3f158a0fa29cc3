//! Corotated linear elasticity (McAdams/Sifakis form), invertible.
//!
//! `F = R S` with `R` a proper rotation (`det R = +1`, also when `det F < 0`)
//! and `S = RᵀF` symmetric, obtained from the signed SVD
//! `F = U diag(σ) Vᵀ` (`U`, `V` proper rotations, `σ₁ ≥ σ₂ ≥ |σ₃|`, the sign of
//! `det F` carried by the smallest singular value `σ₃`), `R = U Vᵀ`,
//! `S = V diag(σ) Vᵀ`.
//!
//! * `W = μ ‖F − R‖² + λ/2 (tr S − 3)²` (J/m³)
//!   (= `μ Σ(σᵢ − 1)² + λ/2 (Σσᵢ − 3)²`),
//! * `P = 2μ(F − R) + λ (tr S − 3) R` (Pa),
//! * exact tangent (Pa): `dP = 2μ dF + λ tr(RᵀdF) R + c dR`,
//!   `c = λ(tr S − 3) − 2μ`, `dR = R[ω]ₓ`, `(tr S I − S) ω = axial(RᵀdF − dFᵀR)`.
//!   With `m_iJ = e_J × r_i` (`r_i` the i-th row of `R`, `axial` of the skew
//!   part of `Rᵀ e_i e_Jᵀ`) this is the symmetric matrix
//!   `A[(iJ),(kL)] = 2μ δ_ik δ_JL + λ R_iJ R_kL + c m_iJ · G⁻¹ m_kL`,
//!   `G = tr S I − S = V diag(σ₂+σ₃, σ₁+σ₃, σ₁+σ₂) Vᵀ`.
//!
//! **Degenerate F.** `R` is not differentiable where two signed singular
//! values sum to zero (`F` of rank ≤ 1, or `F` inverted with `σ₃ = −σ₂`); there
//! `G` is singular. The pair sums are floored at [`PAIR_SUM_FLOOR`], so the
//! tangent is exact wherever every pair sum is ≥ 1e-6 and stays finite (large,
//! regularised) closer to the singular set: no error, no NaN. Energy and `P`
//! are continuous everywhere and are never regularised.
//!
//! `pk2` (`S = F⁻¹P = V diag(2μ(1 − 1/σᵢ) + λ(tr S − 3)/σᵢ) Vᵀ`) and
//! `material_tangent` need `F⁻¹`: they return [`MaterialError::Inverted`]
//! when `|σ₃| ≤ 1e-12 σ₁` (numerically singular `F`). Inverted but regular `F`
//! is fine.

use super::{
    material_tangent_from_a, Lame, Law, Mat3, MaterialError, PointResponse, Tangent9, Voigt6,
};
use nalgebra::Vector3;

/// Zero-sized marker for the corotated law.
pub(super) struct Corotated;

/// Lower bound on the pair sums `σ_a + σ_b` (dimensionless) used when inverting
/// `tr S I − S` in the tangent (see module docs).
pub(super) const PAIR_SUM_FLOOR: f64 = 1e-6;

/// Relative size of the smallest singular value below which `F` counts as
/// singular for `pk2`/`material_tangent`.
const SINGULAR_REL_TOL: f64 = 1e-12;

/// Maximum number of cyclic Jacobi sweeps (convergence is quadratic; 3×3
/// matrices need ≤ 5 in practice).
const MAX_SWEEPS: usize = 16;

/// Signed SVD `F = U diag(σ) Vᵀ`, stored as `R = U Vᵀ`, `V` and `σ`.
struct SignedSvd {
    /// Proper rotation of the polar decomposition.
    r: Mat3,
    /// Right singular vectors (proper rotation), columns ordered like `sigma`.
    v: Mat3,
    /// Signed singular values, `σ₁ ≥ σ₂ ≥ |σ₃|`.
    sigma: Vector3<f64>,
}

/// One Jacobi rotation annihilating `a[(p,q)]` of the symmetric `a` (`r` is the
/// third index), accumulating it into `v`.
#[inline(always)]
fn jacobi_rotate(a: &mut Mat3, v: &mut Mat3, p: usize, q: usize, r: usize) {
    let apq = a[(p, q)];
    if apq == 0.0 {
        return;
    }
    let theta = (a[(q, q)] - a[(p, p)]) / (2.0 * apq);
    let t = if theta.abs() > 1e150 {
        0.5 / theta
    } else {
        theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
    };
    let c = 1.0 / (t * t + 1.0).sqrt();
    let s = t * c;
    a[(p, p)] -= t * apq;
    a[(q, q)] += t * apq;
    a[(p, q)] = 0.0;
    a[(q, p)] = 0.0;
    let (arp, arq) = (a[(r, p)], a[(r, q)]);
    let nrp = c * arp - s * arq;
    let nrq = s * arp + c * arq;
    a[(r, p)] = nrp;
    a[(p, r)] = nrp;
    a[(r, q)] = nrq;
    a[(q, r)] = nrq;
    for k in 0..3 {
        let (vkp, vkq) = (v[(k, p)], v[(k, q)]);
        v[(k, p)] = c * vkp - s * vkq;
        v[(k, q)] = s * vkp + c * vkq;
    }
}

/// Eigen-decomposition of a symmetric 3×3 matrix by cyclic Jacobi:
/// returns eigenvalues sorted descending and the matching eigenvectors as the
/// columns of a proper rotation.
#[inline(always)]
fn sym_eigen_desc(mut a: Mat3) -> (Vector3<f64>, Mat3) {
    let mut v = Mat3::identity();
    let diag2 = a[(0, 0)] * a[(0, 0)] + a[(1, 1)] * a[(1, 1)] + a[(2, 2)] * a[(2, 2)];
    // off-diagonal mass below ~(1e-18 ‖A‖)² is at the rounding level
    let tol = 1e-36 * diag2;
    for _ in 0..MAX_SWEEPS {
        let off = a[(0, 1)] * a[(0, 1)] + a[(0, 2)] * a[(0, 2)] + a[(1, 2)] * a[(1, 2)];
        if off <= tol {
            break;
        }
        jacobi_rotate(&mut a, &mut v, 0, 1, 2);
        jacobi_rotate(&mut a, &mut v, 0, 2, 1);
        jacobi_rotate(&mut a, &mut v, 1, 2, 0);
    }
    let mut w = Vector3::new(a[(0, 0)], a[(1, 1)], a[(2, 2)]);
    // sort descending (3-element network), permuting columns of v
    let mut swap = |w: &mut Vector3<f64>, i: usize, j: usize| {
        if w[i] < w[j] {
            w.swap_rows(i, j);
            v.swap_columns(i, j);
        }
    };
    swap(&mut w, 0, 1);
    swap(&mut w, 1, 2);
    swap(&mut w, 0, 1);
    if v.determinant() < 0.0 {
        v.set_column(2, &-v.column(2));
    }
    (w, v)
}

/// A unit vector orthogonal to the unit vector `u`.
#[inline(never)]
fn any_orthogonal(u: &Vector3<f64>) -> Vector3<f64> {
    let m = u.iamin();
    let mut e = Vector3::zeros();
    e[m] = 1.0;
    (e - u * u[m]).normalize()
}

/// Signed SVD of `F` via Jacobi on `FᵀF` and a Gram–Schmidt QR of `F V`.
#[inline(always)]
fn signed_svd(f: &Mat3) -> SignedSvd {
    let (_, v) = sym_eigen_desc(f.tr_mul(f));
    let b = f * v;
    let b0: Vector3<f64> = b.column(0).into_owned();
    let b1: Vector3<f64> = b.column(1).into_owned();
    let b2: Vector3<f64> = b.column(2).into_owned();
    let s0 = b0.norm();
    let u0 = if s0 > 1e-300 {
        b0 / s0
    } else {
        Vector3::x()
    };
    let w = b1 - u0 * u0.dot(&b1);
    let wn = w.norm();
    let u1 = if wn > 1e-300 {
        w / wn
    } else {
        any_orthogonal(&u0)
    };
    let u2 = u0.cross(&u1);
    let sigma = Vector3::new(s0, u1.dot(&b1), u2.dot(&b2));
    let u = Mat3::from_columns(&[u0, u1, u2]);
    SignedSvd {
        r: u * v.transpose(),
        v,
        sigma,
    }
}

#[inline(always)]
fn energy_of(p: Lame, sigma: &Vector3<f64>) -> f64 {
    let d = sigma - Vector3::repeat(1.0);
    let t = d.sum();
    p.mu * d.norm_squared() + 0.5 * p.lambda * t * t
}

/// `F⁻¹ = V diag(1/σ) Uᵀ = V diag(1/σ) Vᵀ Rᵀ`, or `Inverted` if `F` is singular.
fn checked_inverse_parts(f: &Mat3, svd: &SignedSvd) -> Result<Vector3<f64>, MaterialError> {
    let s = &svd.sigma;
    if !(s[2].abs() > SINGULAR_REL_TOL * s[0]) {
        return Err(MaterialError::Inverted {
            det: f.determinant(),
        });
    }
    Ok(Vector3::new(1.0 / s[0], 1.0 / s[1], 1.0 / s[2]))
}

/// `V diag(d) Vᵀ`.
#[inline(always)]
fn in_basis(v: &Mat3, d: &Vector3<f64>) -> Mat3 {
    v * Mat3::from_diagonal(d) * v.transpose()
}

impl Law for Corotated {
    fn energy(p: Lame, f: &Mat3) -> Result<f64, MaterialError> {
        Ok(energy_of(p, &signed_svd(f).sigma))
    }

    fn pk1(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        let svd = signed_svd(f);
        let t = svd.sigma.sum() - 3.0;
        Ok((f - svd.r) * (2.0 * p.mu) + svd.r * (p.lambda * t))
    }

    #[inline]
    fn response(p: Lame, f: &Mat3) -> Result<PointResponse, MaterialError> {
        let SignedSvd { r, v, sigma } = signed_svd(f);
        let t = sigma.sum() - 3.0;
        let energy = energy_of(p, &sigma);
        let pk1 = (f - r) * (2.0 * p.mu) + r * (p.lambda * t);
        let c = p.lambda * t - 2.0 * p.mu;
        // G⁻¹ in the V basis: 1/(σ_b + σ_c), floored (see module docs);
        // fold c in: coefficient of each rank-one term.
        let w = Vector3::new(
            c / (sigma[1] + sigma[2]).max(PAIR_SUM_FLOOR),
            c / (sigma[0] + sigma[2]).max(PAIR_SUM_FLOOR),
            c / (sigma[0] + sigma[1]).max(PAIR_SUM_FLOOR),
        );
        // N[(3i+J), a] = (m_iJ · v_a) = (r_i × v_a)_J
        let mut n = [[0.0f64; 3]; 9];
        for i in 0..3 {
            let ri = Vector3::new(r[(i, 0)], r[(i, 1)], r[(i, 2)]);
            for a in 0..3 {
                let x = ri.cross(&v.column(a).into_owned());
                n[3 * i][a] = x[0];
                n[3 * i + 1][a] = x[1];
                n[3 * i + 2][a] = x[2];
            }
        }
        let (mu2, la) = (2.0 * p.mu, p.lambda);
        let tangent = Tangent9::from_fn(|row, col| {
            let (nr, nc) = (&n[row], &n[col]);
            let mut val = la * r[(row / 3, row % 3)] * r[(col / 3, col % 3)]
                + w[0] * nr[0] * nc[0]
                + w[1] * nr[1] * nc[1]
                + w[2] * nr[2] * nc[2];
            if row == col {
                val += mu2;
            }
            val
        });
        Ok(PointResponse {
            energy,
            pk1,
            tangent,
        })
    }

    /// `S = F⁻¹P = V diag(2μ(1 − 1/σᵢ) + λ(tr S − 3)/σᵢ) Vᵀ`.
    fn pk2(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        let svd = signed_svd(f);
        let inv = checked_inverse_parts(f, &svd)?;
        let t = svd.sigma.sum() - 3.0;
        let d = inv.map(|is| 2.0 * p.mu * (1.0 - is) + p.lambda * t * is);
        Ok(in_basis(&svd.v, &d))
    }

    /// From the exact 9×9 tangent, `dS = F⁻¹(A:dF − dF S)`, `dF = F⁻ᵀ dE`.
    fn material_tangent(p: Lame, f: &Mat3) -> Result<Voigt6, MaterialError> {
        let svd = signed_svd(f);
        let inv = checked_inverse_parts(f, &svd)?;
        let f_inv = in_basis(&svd.v, &inv) * svd.r.transpose();
        let s = Self::pk2(p, f)?;
        let a = Self::response(p, f)?.tangent;
        Ok(material_tangent_from_a(&a, &s, &f_inv))
    }
}

#[cfg(test)]
mod tests {
    use super::super::{LawKind, Material, Part};
    use super::*;

    fn rot(axis: Vector3<f64>, angle: f64) -> Mat3 {
        *nalgebra::Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle)
            .matrix()
    }

    /// The signed SVD reproduces F, R is a proper rotation, S = RᵀF is
    /// symmetric, and the sign of det F sits on the smallest singular value.
    #[test]
    fn corotated_signed_svd_reconstructs() {
        let q1 = rot(Vector3::new(1.0, 2.0, 3.0), 1.1);
        let q2 = rot(Vector3::new(-2.0, 0.5, 1.0), 2.3);
        let diags = [
            Vector3::new(1.8, 0.9, 0.5),
            Vector3::new(1.0, 1.0, 1.0),
            Vector3::new(1.2, 1.2, 0.7),
            Vector3::new(2.0, 0.6, -0.3),
            Vector3::new(0.4, 1.5, -1.1),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 1.0, -1.0),
        ];
        for d in diags {
            let f = q1 * Mat3::from_diagonal(&d) * q2;
            let svd = signed_svd(&f);
            let u = svd.r * svd.v;
            let rec = u * Mat3::from_diagonal(&svd.sigma) * svd.v.transpose();
            assert!((rec - f).amax() < 1e-13, "{d:?}");
            assert!((svd.r.tr_mul(&svd.r) - Mat3::identity()).amax() < 1e-13);
            assert!((svd.r.determinant() - 1.0).abs() < 1e-13);
            let s = svd.r.tr_mul(&f);
            assert!((s - s.transpose()).amax() < 1e-13);
            let mut sorted: Vec<f64> = d.iter().map(|x| x.abs()).collect();
            sorted.sort_by(|a, b| b.partial_cmp(a).unwrap());
            for k in 0..3 {
                assert!((svd.sigma[k].abs() - sorted[k]).abs() < 1e-12);
            }
            assert!(svd.sigma[0] >= svd.sigma[1] && svd.sigma[1] >= svd.sigma[2].abs() - 1e-14);
            let det = d[0] * d[1] * d[2];
            if det != 0.0 {
                assert_eq!(svd.sigma[2] < 0.0, det < 0.0);
            }
        }
    }

    /// Degenerate F (collapsed, rank 1, half-inverted σ₃ = −σ₂) gives a
    /// finite response (regularised tangent) and no error; pk2 of a singular F
    /// is an `Inverted` error.
    #[test]
    fn corotated_degenerate_is_finite() {
        let m = Material::from_young_poisson(LawKind::Corotated, 4500.0, 0.45).unwrap();
        let q = rot(Vector3::new(0.3, -1.0, 0.2), 0.7);
        for d in [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.3, 0.0, 0.0),
            Vector3::new(1.0, 1.0, -1.0),
            Vector3::new(1.5, 0.8, -0.8),
            Vector3::new(-1.0, -1.0, -1.0),
        ] {
            let f = q * Mat3::from_diagonal(&d);
            for part in [Part::Full, Part::Shear, Part::Volumetric] {
                let r = m.response(&f, part).unwrap();
                assert!(r.energy.is_finite());
                assert!(r.pk1.iter().all(|x| x.is_finite()));
                assert!(r.tangent.iter().all(|x| x.is_finite()));
                assert!((r.tangent - r.tangent.transpose()).amax() <= 1e-9 * r.tangent.amax());
            }
        }
        let f = q * Mat3::from_diagonal(&Vector3::new(1.0, 0.5, 0.0));
        assert!(matches!(
            m.pk2(&f, Part::Full),
            Err(MaterialError::Inverted { .. })
        ));
        assert!(matches!(
            m.material_tangent(&f, Part::Full),
            Err(MaterialError::Inverted { .. })
        ));
        // inverted but regular: pk2 fine and F S = P
        let f = q * Mat3::from_diagonal(&Vector3::new(1.2, 0.9, -0.4));
        let s = m.pk2(&f, Part::Full).unwrap();
        let p = m.pk1(&f, Part::Full).unwrap();
        assert!((f * s - p).amax() <= 1e-12 * p.amax());
    }

    /// Closed form: F = diag(s, 1, 1), s > 0 → R = I,
    /// P11 = 2μ(s−1) + λ(s−1), P22 = λ(s−1);
    /// inverted F = diag(1, 1, −s) → σ = (1, 1, −s), R = diag(1, 1, −1)… 
    /// only up to the choice among equal singular values, so use distinct ones.
    #[test]
    fn corotated_closed_form_and_inversion() {
        let m = Material {
            law: LawKind::Corotated,
            mu: 2.0,
            lambda: 3.0,
        };
        let f = Mat3::from_diagonal(&Vector3::new(1.4, 1.0, 1.0));
        let p = m.pk1(&f, Part::Full).unwrap();
        assert!((p[(0, 0)] - (4.0 * 0.4 + 3.0 * 0.4)).abs() < 1e-13);
        assert!((p[(1, 1)] - 3.0 * 0.4).abs() < 1e-13);
        // F = diag(2, 1.5, −0.5): smallest singular value flipped,
        // R = diag(1, 1, −1), S = diag(2, 1.5, 0.5)… with sign fix σ₃ = −0.5:
        // R = diag(1,1,1)·?  The signed SVD gives σ = (2, 1.5, −0.5), R = I.
        let f = Mat3::from_diagonal(&Vector3::new(2.0, 1.5, -0.5));
        let svd = signed_svd(&f);
        assert!((svd.r - Mat3::identity()).amax() < 1e-14);
        let w = m.energy(&f, Part::Full).unwrap();
        let expect = 2.0 * (1.0 + 0.25 + 2.25) + 1.5 * 0.0;
        assert!((w - expect).abs() < 1e-12, "{w} vs {expect}");
    }
}
