//! Corotated linear elasticity (McAdams/Sifakis form), invertible.
//!
//! `F = R S` with `R` a proper rotation (`det R = +1`, also when `det F < 0`)
//! and `S = RᵀF` symmetric; in terms of the signed SVD
//! `F = U diag(σ) Vᵀ` (`U`, `V` proper rotations, `σ₁ ≥ σ₂ ≥ |σ₃|`, the sign of
//! `det F` carried by the smallest singular value `σ₃`), `R = U Vᵀ` and
//! `S = V diag(σ) Vᵀ`.
//!
//! * `W = μ ‖F − R‖² + λ/2 (tr S − 3)²` (J/m³)
//!   (= `μ Σ(σᵢ − 1)² + λ/2 (Σσᵢ − 3)²`); shear part `μ ‖F − R‖²`,
//!   volumetric part `λ/2 (tr S − 3)²`,
//! * `P = 2μ(F − R) + λ (tr S − 3) R` (Pa),
//! * exact tangent (Pa): `dP = 2μ dF + λ tr(RᵀdF) R + c dR`,
//!   `c = λ(tr S − 3) − 2μ`, `dR = R[ω]ₓ`, `(tr S I − S) ω = axial(RᵀdF − dFᵀR)`.
//!   With `m_iJ = e_J × r_i` (`r_i` the i-th row of `R`; `m_iJ` is the axial
//!   vector of `RᵀE_iJ − E_iJᵀR` for the unit matrix `E_iJ`) this is the
//!   symmetric matrix
//!   `A[(iJ),(kL)] = 2μ δ_ik δ_JL + λ R_iJ R_kL + c m_iJ · G⁻¹ m_kL`,
//!   `G = tr S I − S = V diag(σ₂+σ₃, σ₁+σ₃, σ₁+σ₂) Vᵀ`.
//!
//! **Computation.** For `det F > 0` (the normal case) `R` comes from a scaled
//! Newton polar iteration (≈5 iterations, no eigen-solve) and `G⁻¹` from its
//! cofactor matrix. For `det F ≤ 0`, or when `G` is close to singular, `R`
//! and `G` come from a signed SVD (cyclic Jacobi on `FᵀF` + Gram–Schmidt QR of
//! `F V`). Both paths agree to rounding where both apply (tested).
//!
//! **Degenerate F.** `R` is not differentiable (and not unique) where two
//! signed singular values sum to zero (`F` of rank ≤ 1, or `F` inverted with
//! `σ₃ = −σ₂`); there `G` is singular and `P` may jump (the energy stays
//! continuous). The eigenvalues of `G` are floored at [`PAIR_SUM_FLOOR`]
//! (1e-6), so the tangent is exact wherever every pair sum is ≥ 1e-6 and stays
//! finite (large, regularised) closer to the singular set: no error, no NaN.
//! Energy and `P` are never regularised.
//!
//! **Projected tangent.** The twist modes `T_a = R [v_a]ₓ / √2` (`v_a` the
//! eigenvectors of `G`, eigenvalues `g_a`) are eigenvectors of `A` with
//! eigenvalues `e_a = 2μ + 2c / g_a`. Under compression (`c < 0`, pair sums
//! `g_a < 2`) they turn negative and `A` is indefinite: the Newton step of the
//! assembled tangent then need not be a descent direction, and the sparse
//! Cholesky factorisation fails. [`Law::response_projected`] clamps them,
//! `A⁺ = A − Σ_{e_a<0} e_a T_a T_aᵀ` (a positive semi-definite tangent, the
//! "definiteness fix" of Teran et al. 2005 / McAdams et al. 2011); it is the
//! exact tangent wherever no `e_a` is negative.
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
const PAIR_SUM_FLOOR: f64 = 1e-6;

/// Relative size of the smallest singular value below which `F` counts as
/// singular for `pk2`/`material_tangent`.
const SINGULAR_REL_TOL: f64 = 1e-12;

/// Maximum number of Newton polar iterations before falling back to the SVD
/// (scaled Newton needs ≤ 10 even for condition numbers ~1e16).
const NEWTON_MAX_ITERS: usize = 30;

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

/// Cofactor matrix `cof(X) = det(X) X⁻ᵀ` and `det X`.
#[inline(always)]
fn cofactor_det(x: &Mat3) -> (Mat3, f64) {
    let (x00, x01, x02) = (x[(0, 0)], x[(0, 1)], x[(0, 2)]);
    let (x10, x11, x12) = (x[(1, 0)], x[(1, 1)], x[(1, 2)]);
    let (x20, x21, x22) = (x[(2, 0)], x[(2, 1)], x[(2, 2)]);
    let c00 = x11 * x22 - x12 * x21;
    let c01 = x12 * x20 - x10 * x22;
    let c02 = x10 * x21 - x11 * x20;
    let det = x00 * c00 + x01 * c01 + x02 * c02;
    let cof = Mat3::new(
        c00,
        c01,
        c02,
        x02 * x21 - x01 * x22,
        x00 * x22 - x02 * x20,
        x01 * x20 - x00 * x21,
        x01 * x12 - x02 * x11,
        x02 * x10 - x00 * x12,
        x00 * x11 - x01 * x10,
    );
    (cof, det)
}

/// Orthogonal polar factor of `F` by the scaled Newton iteration
/// `X ← ½(γX + γ⁻¹X⁻ᵀ)`, `γ = (‖X⁻¹‖/‖X‖)^½` (Higham), for `det F > 0` only
/// (then the polar factor is the proper rotation `R`). Iterates until the
/// update is ≤ 3e-9, after which the quadratic convergence puts the iterate
/// at rounding level. `None` if `det F ≤ 0` or no convergence (the caller
/// falls back to the signed SVD).
#[inline(always)]
fn polar_newton(f: &Mat3) -> Option<Mat3> {
    let mut x = *f;
    let mut scaled = true;
    for _ in 0..NEWTON_MAX_ITERS {
        let (cof, det) = cofactor_det(&x);
        if det.is_nan() || det <= 0.0 {
            return None;
        }
        let inv_det = 1.0 / det;
        let xn = if scaled {
            let g = (cof.norm_squared() * inv_det * inv_det / x.norm_squared())
                .sqrt()
                .sqrt();
            (x * g + cof * (inv_det / g)) * 0.5
        } else {
            (x + cof * inv_det) * 0.5
        };
        let step2 = (xn - x).norm_squared();
        x = xn;
        if step2 <= 1e-17 {
            return Some(x);
        }
        // near convergence the optimal γ → 1: stop scaling (Higham)
        scaled = step2 > 1e-4;
    }
    None
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
    let u0 = if s0 > 1e-300 { b0 / s0 } else { Vector3::x() };
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

/// Proper rotation `R` of the polar decomposition (fast path: Newton for
/// `det F > 0`; otherwise the signed SVD).
#[inline(always)]
fn rotation(f: &Mat3) -> Mat3 {
    match polar_newton(f) {
        Some(r) => r,
        None => signed_svd(f).r,
    }
}

/// `R` and `G⁻¹ = (tr S I − S)⁻¹`, `S = RᵀF`, with every eigenvalue of `G`
/// (pair sum of signed singular values) floored at [`PAIR_SUM_FLOOR`].
///
/// Fast path: Newton `R` and a cofactor inverse of `G`, taken when
/// `4 det G / (tr G)² ≥ PAIR_SUM_FLOOR`, which guarantees
/// `λ_min(G) ≥ PAIR_SUM_FLOOR` (no flooring needed). Otherwise the signed SVD
/// gives `G⁻¹ = V diag(1/max(σ_b + σ_c, floor)) Vᵀ`.
#[inline(always)]
fn rotation_and_g_inv(f: &Mat3) -> (Mat3, Mat3) {
    if let Some(r) = polar_newton(f) {
        let s = r.tr_mul(f);
        let tr = s.trace();
        // G = tr S I − sym(S)
        let mut g = (s + s.transpose()) * -0.5;
        g[(0, 0)] += tr;
        g[(1, 1)] += tr;
        g[(2, 2)] += tr;
        let (cof, det) = cofactor_det(&g);
        let tr_g = 2.0 * tr;
        if 4.0 * det >= PAIR_SUM_FLOOR * tr_g * tr_g {
            // G symmetric → cof(G) symmetric, G⁻¹ = cof(G)/det G
            return (r, cof * (1.0 / det));
        }
    }
    rotation_and_g_inv_svd(f)
}

/// Slow path of [`rotation_and_g_inv`]: everything from the signed SVD,
/// `G⁻¹ = V diag(1/max(σ_b + σ_c, PAIR_SUM_FLOOR)) Vᵀ`.
#[inline(never)]
fn rotation_and_g_inv_svd(f: &Mat3) -> (Mat3, Mat3) {
    let SignedSvd { r, v, sigma } = signed_svd(f);
    let d = Vector3::new(
        1.0 / (sigma[1] + sigma[2]).max(PAIR_SUM_FLOOR),
        1.0 / (sigma[0] + sigma[2]).max(PAIR_SUM_FLOOR),
        1.0 / (sigma[0] + sigma[1]).max(PAIR_SUM_FLOOR),
    );
    (r, in_basis(&v, &d))
}

/// Energy (J/m³) and `P` (Pa) from `R`.
#[inline(always)]
fn energy_and_pk1(p: Lame, f: &Mat3, r: &Mat3) -> (f64, Mat3, f64) {
    let t = r.dot(f) - 3.0; // tr(RᵀF) − 3
    let d = f - r;
    let energy = p.mu * d.norm_squared() + 0.5 * p.lambda * t * t;
    (energy, d * (2.0 * p.mu) + r * (p.lambda * t), t)
}

/// Cross product of plain arrays.
#[inline(always)]
fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `1/σ` (for `F⁻¹ = V diag(1/σ) Vᵀ Rᵀ`), or `Inverted` if `F` is singular.
fn checked_inverse_parts(f: &Mat3, svd: &SignedSvd) -> Result<Vector3<f64>, MaterialError> {
    let s = &svd.sigma;
    if s[2].is_nan() || s[2].abs() <= SINGULAR_REL_TOL * s[0] {
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

/// `A⁺ = A − Σ_{e_a<0} e_a T_a T_aᵀ` for the twist modes of `F` (see the module docs):
/// subtracts the negative part of `c m G⁻¹ mᵀ + 2μ 𝕀` on the rotation subspace from
/// `tangent`. `c = λ(tr S − 3) − 2μ`. Nothing to do when `c ≥ 0` (every `e_a ≥ 2μ`).
fn clamp_twist_modes(p: Lame, f: &Mat3, r: &Mat3, c: f64, tangent: &mut Tangent9) {
    if c >= 0.0 {
        return;
    }
    // G = tr S I − sym(S), S = RᵀF; its eigenvectors are the twist axes.
    let s = r.tr_mul(f);
    let tr = s.trace();
    let mut g = (s + s.transpose()) * -0.5;
    for i in 0..3 {
        g[(i, i)] += tr;
    }
    let (ga, v) = sym_eigen_desc(g);
    for a in 0..3 {
        let e = 2.0 * p.mu + 2.0 * c / ga[a].max(PAIR_SUM_FLOOR);
        if e >= 0.0 {
            continue;
        }
        let axis: Vector3<f64> = v.column(a).into_owned();
        let t = r * axis.cross_matrix() * std::f64::consts::FRAC_1_SQRT_2;
        // Row-major flattening, as in Tangent9: index 3i + J.
        let mut flat = [0.0f64; 9];
        for i in 0..3 {
            for j in 0..3 {
                flat[3 * i + j] = t[(i, j)];
            }
        }
        for (row, &x) in flat.iter().enumerate() {
            for (col, &y) in flat.iter().enumerate() {
                tangent[(row, col)] -= e * x * y;
            }
        }
    }
}

/// Energy, `P` and the exact tangent (see the module docs), with the twist modes clamped
/// when `projected`.
#[inline(always)]
fn response_with(p: Lame, f: &Mat3, projected: bool) -> PointResponse {
    let (r, g_inv) = rotation_and_g_inv(f);
    let (energy, pk1, t) = energy_and_pk1(p, f, &r);
    let c = p.lambda * t - 2.0 * p.mu;
    // A[(3i+J),(3k+L)] = 2μ δ_ik δ_JL + λ R_iJ R_kL + c m_iJ · G⁻¹ m_kL with
    // m_iJ = e_J × r_i (r_i the i-th row of R). Writing M_i = [r_i]ₓ (its
    // rows are the m_iJ), block (i, k) of the last term is c M_i G⁻¹ M_kᵀ,
    // whose row J is r_k × (row J of P_i), where
    // P_i = c [r_i]ₓ G⁻¹ = [r_i × cg_0 | r_i × cg_1 | r_i × cg_2]
    // and cg_a are the columns of c G⁻¹.
    let ra: [[f64; 3]; 3] = r.transpose().into(); // ra[i] = r_i
    let cg: [[f64; 3]; 3] = (g_inv * c).into(); // cg[a] = column a
    let mut pt = [[[0.0f64; 3]; 3]; 3]; // pt[i][a] = column a of P_i
    for i in 0..3 {
        for a in 0..3 {
            pt[i][a] = cross(&ra[i], &cg[a]);
        }
    }
    let (mu2, la) = (2.0 * p.mu, p.lambda);
    // column-major storage: cols[3k+L][3i+J]
    let mut cols = [[0.0f64; 9]; 9];
    for i in 0..3 {
        for j in 0..3 {
            let prow = [pt[i][0][j], pt[i][1][j], pt[i][2][j]];
            let lr = la * ra[i][j];
            for k in 0..3 {
                let x = cross(&ra[k], &prow);
                for l in 0..3 {
                    cols[3 * k + l][3 * i + j] = x[l] + lr * ra[k][l];
                }
            }
            cols[3 * i + j][3 * i + j] += mu2;
        }
    }
    let mut tangent = Tangent9::from_data(nalgebra::ArrayStorage(cols));
    if projected {
        clamp_twist_modes(p, f, &r, c, &mut tangent);
    }
    PointResponse {
        energy,
        pk1,
        tangent,
    }
}

impl Law for Corotated {
    fn energy(p: Lame, f: &Mat3) -> Result<f64, MaterialError> {
        Ok(energy_and_pk1(p, f, &rotation(f)).0)
    }

    fn pk1(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError> {
        Ok(energy_and_pk1(p, f, &rotation(f)).1)
    }

    fn energy_pk1(p: Lame, f: &Mat3) -> Result<(f64, Mat3), MaterialError> {
        let (w, pk1, _) = energy_and_pk1(p, f, &rotation(f));
        Ok((w, pk1))
    }

    #[inline]
    fn response(p: Lame, f: &Mat3) -> Result<PointResponse, MaterialError> {
        Ok(response_with(p, f, false))
    }

    #[inline]
    fn response_projected(p: Lame, f: &Mat3) -> Result<PointResponse, MaterialError> {
        Ok(response_with(p, f, true))
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
        *nalgebra::Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle).matrix()
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
            for (computed, expected) in svd.sigma.iter().zip(&sorted) {
                assert!((computed.abs() - expected).abs() < 1e-12);
            }
            assert!(svd.sigma[0] >= svd.sigma[1] && svd.sigma[1] >= svd.sigma[2].abs() - 1e-14);
            let det = d[0] * d[1] * d[2];
            if det != 0.0 {
                assert_eq!(svd.sigma[2] < 0.0, det < 0.0);
            }
        }
    }

    /// The fast path (Newton polar + cofactor inverse of G) and the SVD path
    /// agree wherever both apply (det F > 0), including ill-conditioned F.
    #[test]
    fn corotated_newton_path_matches_svd_path() {
        let q1 = rot(Vector3::new(1.0, -2.0, 0.5), 0.9);
        let q2 = rot(Vector3::new(0.2, 1.0, 3.0), -2.0);
        for d in [
            Vector3::new(1.0, 1.0, 1.0),
            Vector3::new(1.8, 0.8, 0.72),
            Vector3::new(0.5, 1.2, 1.1),
            Vector3::new(3.0, 0.2, 0.05),
            Vector3::new(1.0, 1e-3, 1e-4),
            Vector3::new(1.0, 1.0 + 1e-9, 1.0 - 1e-9),
        ] {
            let f = q1 * Mat3::from_diagonal(&d) * q2;
            let r_newton = polar_newton(&f).expect("det F > 0 converges");
            let (r_fast, g_fast) = rotation_and_g_inv(&f);
            let (r_svd, g_svd) = rotation_and_g_inv_svd(&f);
            // the SVD path works on FᵀF, so its error grows faster than
            // Newton's with the condition number of F
            let tol = 1e-15 * (d.max() / d.min()).max(10.0).powf(1.5);
            assert!((r_newton - r_svd).amax() <= tol, "{d:?}");
            assert!((r_fast - r_svd).amax() <= tol, "{d:?}");
            assert!((g_fast - g_svd).amax() <= 1e-12 * g_svd.amax(), "{d:?}");
        }
        // inverted F: Newton declines, the SVD path is used
        let f = q1 * Mat3::from_diagonal(&Vector3::new(1.2, 0.9, -0.4)) * q2;
        assert!(polar_newton(&f).is_none());
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

    /// Closed forms: F = diag(1.4, 1, 1) → R = I, P11 = (2μ + λ)·0.4,
    /// P22 = λ·0.4; inverted F = diag(2, 1.5, −0.5) → signed σ = (2, 1.5, −0.5),
    /// R = I (proper), W = μ Σ(σᵢ − 1)² + λ/2 (Σσᵢ − 3)² = μ·3.5.
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
        let f = Mat3::from_diagonal(&Vector3::new(2.0, 1.5, -0.5));
        let svd = signed_svd(&f);
        assert!((svd.r - Mat3::identity()).amax() < 1e-14);
        let w = m.energy(&f, Part::Full).unwrap();
        let expect = 2.0 * (1.0 + 0.25 + 2.25) + 1.5 * 0.0;
        assert!((w - expect).abs() < 1e-12, "{w} vs {expect}");
    }

    /// The projected tangent equals the exact one with its negative eigenvalues set to zero,
    /// computed independently by a full 9×9 symmetric eigen-decomposition; and it is the
    /// exact tangent where the exact one has no negative eigenvalue.
    #[test]
    fn corotated_projected_tangent_is_the_clamped_exact_tangent() {
        let m = Material::from_young_poisson(LawKind::Corotated, 4500.0, 0.49).unwrap();
        let q1 = rot(Vector3::new(1.0, 2.0, 3.0), 0.7);
        let q2 = rot(Vector3::new(-2.0, 0.5, 1.0), 1.9);
        let cases = [
            (Vector3::new(0.9, 0.85, 0.95), true), // compressed: twist modes negative
            (Vector3::new(1.1, 0.7, 0.98), true),  // mixed
            (Vector3::new(1.0, 1.0, -0.2), true),  // inverted
            (Vector3::new(1.2, 1.15, 1.1), false), // stretched: nothing to clamp
        ];
        for (d, expect_clamp) in cases {
            let f = q1 * Mat3::from_diagonal(&d) * q2;
            for part in [Part::Full, Part::Shear, Part::Volumetric] {
                let exact = m.response(&f, part).unwrap().tangent;
                let projected = m.response_projected(&f, part).unwrap().tangent;
                let eig = nalgebra::SymmetricEigen::new(exact);
                let clamped = eig.eigenvectors
                    * Tangent9::from_diagonal(&eig.eigenvalues.map(|e| e.max(0.0)))
                    * eig.eigenvectors.transpose();
                let scale = exact.norm().max(m.mu);
                let err = (projected - clamped).norm() / scale;
                assert!(err < 1e-9, "{d:?} {part:?}: projected vs clamped {err:e}");
                let min = nalgebra::SymmetricEigen::new(projected).eigenvalues.min();
                assert!(
                    min >= -1e-9 * scale,
                    "{d:?} {part:?}: min eigenvalue {min:e}"
                );
                let changed = (projected - exact).norm() / scale > 1e-12;
                if part == Part::Full {
                    assert_eq!(
                        changed, expect_clamp,
                        "{d:?}: clamping expected {expect_clamp}"
                    );
                }
                if !expect_clamp {
                    assert!(!changed, "{d:?} {part:?}: stretched tangent changed");
                }
            }
        }
    }
}
