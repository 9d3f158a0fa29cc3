//! Hyperelastic constitutive laws for liver tissue.
//!
//! Every law maps a deformation gradient `F = I + ∇u` (dimensionless) at a
//! material point to
//! * the strain-energy density `W(F)` in J/m³ (= Pa),
//! * the first Piola–Kirchhoff stress `P = ∂W/∂F` in Pa,
//! * the consistent tangent `∂P/∂F` (9×9, [`Tangent9`]) in Pa,
//! * the second Piola–Kirchhoff stress `S` and its material tangent `dS/dE`
//!   ([`Voigt6`]) in Pa.
//!
//! Laws (one file each): small-strain [`LawKind::Linear`] (`linear.rs`),
//! corotated linear [`LawKind::Corotated`] (`corotated.rs`),
//! St Venant–Kirchhoff [`LawKind::Svk`] (`svk.rs`, thesis eq. 2.8) and
//! compressible neo-Hookean [`LawKind::NeoHookean`] (`neo_hookean.rs`,
//! thesis eq. 2.9) and compressible Mooney–Rivlin [`LawKind::MooneyRivlin`]
//! (`mooney_rivlin.rs`, seed 003). [`Material`] dispatches on the law.
//!
//! Every energy is of the form `W = μ W_μ(F) + λ W_λ(F)`; [`Part`] selects the
//! μ-term, the λ-term, or both, so that the element can integrate the
//! volumetric term with a reduced rule (anti-locking).

mod corotated;
mod linear;
mod mooney_rivlin;
mod neo_hookean;
mod svk;

pub use mooney_rivlin::MOONEY_RIVLIN_C10_SHARE;

/// A 3×3 matrix of `f64` (deformation gradient, dimensionless; or a stress in Pa).
pub type Mat3 = nalgebra::Matrix3<f64>;

/// ∂P/∂F as a 9×9 matrix (Pa): entry `[(3*i + J), (3*k + L)] = ∂P_iJ / ∂F_kL`
/// (row-major flattening of the 3×3 index pairs). For a hyperelastic law it is
/// symmetric.
pub type Tangent9 = nalgebra::SMatrix<f64, 9, 9>;

/// Second-order 6×6 Voigt matrix for dS/dE (Pa), Voigt order
/// (11, 22, 33, 23, 13, 12) with engineering shear (factor 2 on the E shear
/// components), i.e. `S_voigt = Cvoigt * E_voigt_engineering` for linear laws.
/// Entry `[(a, b)] = ℂ_{I_a J_a K_b L_b}`.
pub type Voigt6 = nalgebra::SMatrix<f64, 6, 6>;

/// Failure of a constitutive evaluation.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum MaterialError {
    /// The material point is inverted or collapsed: `det F ≤ 0` for the
    /// neo-Hookean law (where `ln J` is undefined), or `F` is singular where an
    /// inverse of `F` is required (corotated `pk2`/`material_tangent`). `det`
    /// is `det F` (dimensionless).
    #[error("inverted material point: det F = {det:e}")]
    Inverted {
        /// `det F` at the failing point (dimensionless).
        det: f64,
    },
    /// The deformation gradient contains a NaN or an infinity.
    #[error("non-finite deformation gradient")]
    NonFinite,
}

/// Which terms of the strain-energy density are evaluated.
///
/// `Shear` holds every term multiplied by μ, `Volumetric` every term
/// multiplied by λ; `Shear + Volumetric == Full` (energy, stress and tangent,
/// up to floating-point rounding of one addition). The element integrates
/// `Volumetric` with a reduced (one-point) rule to avoid volumetric locking at
/// ν → 0.5 and `Shear` with the full 2×2×2 rule.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// μ-terms + λ-terms: the complete law.
    Full,
    /// Only the terms multiplied by μ (for neo-Hookean: `μ/2 (tr C − 3) − μ ln J`).
    Shear,
    /// Only the terms multiplied by λ (for neo-Hookean: `λ/2 (ln J)²`).
    Volumetric,
}

/// Everything the element needs at one quadrature point, from one evaluation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointResponse {
    /// Strain-energy density `W(F)` in J/m³.
    pub energy: f64,
    /// First Piola–Kirchhoff stress `P = ∂W/∂F` in Pa.
    pub pk1: Mat3,
    /// Consistent tangent `∂P/∂F` in Pa, layout of [`Tangent9`].
    pub tangent: Tangent9,
}

/// Constitutive law selector. Serde names: `"linear"`, `"corotated"`, `"svk"`,
/// `"neo-hookean"`, `"mooney-rivlin"`.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Deserialize, serde::Serialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum LawKind {
    /// Small-strain linear elasticity, `W = μ ε:ε + λ/2 (tr ε)²`, `ε = sym(F) − I`;
    /// `P = σ = 2με + λ tr(ε) I`. Not rotation invariant.
    Linear,
    /// Corotated linear elasticity (McAdams/Sifakis form),
    /// `W = μ ‖F − R‖² + λ/2 (tr(RᵀF − I))²` with `F = R S` the polar
    /// decomposition (`det R = +1`, defined for inverted `F`).
    Corotated,
    /// St Venant–Kirchhoff (thesis eq. 2.8), `W = λ/2 (tr E)² + μ tr(E²)`,
    /// `E = ½(FᵀF − I)`. Defined for every `F`.
    Svk,
    /// Compressible neo-Hookean (thesis eq. 2.9),
    /// `W = μ/2 (tr C − 3) − μ ln J + λ/2 (ln J)²`. Requires `J = det F > 0`. The default.
    #[default]
    NeoHookean,
    /// Compressible Mooney–Rivlin (seed 003) with seed 003's liver ratio C10 : C01 =
    /// 0.16 : 0.14 ([`MOONEY_RIVLIN_C10_SHARE`]), scaled to the material's μ and λ:
    /// `W = C10 (Ī₁ − 3) + C01 (Ī₂ − 3) + κ/2 (ln J)²` (isochoric invariants),
    /// `2(C10 + C01) = μ`, `κ = λ + 2μ/3` (linear elasticity with μ, λ at small strain).
    /// Requires `J > 0`. See `mooney_rivlin.rs`.
    MooneyRivlin,
}

impl LawKind {
    /// Every law, in the order of their serde names' list.
    pub const ALL: [LawKind; 5] = [
        LawKind::Linear,
        LawKind::Corotated,
        LawKind::Svk,
        LawKind::NeoHookean,
        LawKind::MooneyRivlin,
    ];
}

/// Lamé parameters actually used by a law for a given [`Part`] (Pa).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Lame {
    mu: f64,
    lambda: f64,
}

/// Internal interface implemented by one zero-sized type per law.
///
/// The dispatcher in [`Material`] has already rejected non-finite `F` and
/// selected the [`Part`] by zeroing μ or λ in [`Lame`], so implementations
/// only see finite `F` and plain Lamé parameters (every law is linear in
/// (μ, λ)).
trait Law {
    /// Strain-energy density (J/m³).
    fn energy(p: Lame, f: &Mat3) -> Result<f64, MaterialError>;
    /// First Piola–Kirchhoff stress (Pa).
    fn pk1(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError>;
    /// Energy density (J/m³) and P (Pa) in one pass.
    fn energy_pk1(p: Lame, f: &Mat3) -> Result<(f64, Mat3), MaterialError>;
    /// Energy, P and ∂P/∂F in one pass.
    fn response(p: Lame, f: &Mat3) -> Result<PointResponse, MaterialError>;
    /// As `response`, with a positive semi-definite tangent where the exact one is
    /// indefinite (by default: the exact tangent).
    fn response_projected(p: Lame, f: &Mat3) -> Result<PointResponse, MaterialError> {
        Self::response(p, f)
    }
    /// Second Piola–Kirchhoff stress (Pa).
    fn pk2(p: Lame, f: &Mat3) -> Result<Mat3, MaterialError>;
    /// Material tangent dS/dE in Voigt form (Pa).
    fn material_tangent(p: Lame, f: &Mat3) -> Result<Voigt6, MaterialError>;
}

/// A homogeneous material: a constitutive law and its Lamé parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Constitutive law.
    pub law: LawKind,
    /// Shear modulus μ (second Lamé parameter) in Pa.
    pub mu: f64,
    /// First Lamé parameter λ in Pa.
    pub lambda: f64,
}

/// Voigt index → tensor index pair, order (11, 22, 33, 23, 13, 12).
const VOIGT: [(usize, usize); 6] = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)];

impl Material {
    /// Whether the law is small-strain linear elasticity ([`LawKind::Linear`]): forces
    /// linear in the displacements.
    pub fn is_linear(&self) -> bool {
        self.law == LawKind::Linear
    }

    /// Builds a material from Young's modulus `young` (Pa) and Poisson's ratio
    /// `poisson` (dimensionless): `μ = E/(2(1+ν))`, `λ = Eν/((1+ν)(1−2ν))`, both
    /// in Pa.
    ///
    /// Errors (with a message naming the offending value) unless `E` is finite
    /// and `> 0` and `−1 < ν < 0.5` (NaN is rejected).
    pub fn from_young_poisson(law: LawKind, young: f64, poisson: f64) -> Result<Self, String> {
        if !(young.is_finite() && young > 0.0) {
            return Err(format!(
                "invalid Young's modulus E = {young} Pa: must be finite and > 0"
            ));
        }
        if !(poisson > -1.0 && poisson < 0.5) {
            return Err(format!(
                "invalid Poisson's ratio ν = {poisson}: must satisfy -1 < ν < 0.5"
            ));
        }
        let mu = young / (2.0 * (1.0 + poisson));
        let lambda = young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson));
        Ok(Self { law, mu, lambda })
    }

    /// Young's modulus `E = μ(3λ + 2μ)/(λ + μ)`, Pa: the inverse of
    /// [`Material::from_young_poisson`].
    pub fn young_modulus(&self) -> f64 {
        self.mu * (3.0 * self.lambda + 2.0 * self.mu) / (self.lambda + self.mu)
    }

    /// Poisson's ratio `ν = λ / (2(λ + μ))`, dimensionless: the inverse of
    /// [`Material::from_young_poisson`].
    pub fn poisson_ratio(&self) -> f64 {
        self.lambda / (2.0 * (self.lambda + self.mu))
    }

    /// P-wave modulus `λ + 2μ` in Pa (stiffness scale used to scale penalties).
    pub fn wave_speed_modulus(&self) -> f64 {
        self.lambda + 2.0 * self.mu
    }

    /// Lamé parameters restricted to `part`.
    #[inline(always)]
    fn lame(&self, part: Part) -> Lame {
        match part {
            Part::Full => Lame {
                mu: self.mu,
                lambda: self.lambda,
            },
            Part::Shear => Lame {
                mu: self.mu,
                lambda: 0.0,
            },
            Part::Volumetric => Lame {
                mu: 0.0,
                lambda: self.lambda,
            },
        }
    }

    /// Strain-energy density `W(F)` (or its `part`) in J/m³.
    ///
    /// SVK: thesis eq. 2.8; neo-Hookean: thesis eq. 2.9. Errors: `NonFinite`
    /// for NaN/∞ in `F`; `Inverted` for neo-Hookean with `det F ≤ 0`.
    pub fn energy(&self, f: &Mat3, part: Part) -> Result<f64, MaterialError> {
        check_finite(f)?;
        let p = self.lame(part);
        match self.law {
            LawKind::Linear => linear::Linear::energy(p, f),
            LawKind::Corotated => corotated::Corotated::energy(p, f),
            LawKind::Svk => svk::Svk::energy(p, f),
            LawKind::NeoHookean => neo_hookean::NeoHookean::energy(p, f),
            LawKind::MooneyRivlin => mooney_rivlin::MooneyRivlin::energy(p, f),
        }
    }

    /// First Piola–Kirchhoff stress `P = ∂W/∂F` (or of its `part`) in Pa.
    ///
    /// For [`LawKind::Linear`] this is the small-strain Cauchy stress σ.
    /// Errors as [`Material::energy`].
    pub fn pk1(&self, f: &Mat3, part: Part) -> Result<Mat3, MaterialError> {
        check_finite(f)?;
        let p = self.lame(part);
        match self.law {
            LawKind::Linear => linear::Linear::pk1(p, f),
            LawKind::Corotated => corotated::Corotated::pk1(p, f),
            LawKind::Svk => svk::Svk::pk1(p, f),
            LawKind::NeoHookean => neo_hookean::NeoHookean::pk1(p, f),
            LawKind::MooneyRivlin => mooney_rivlin::MooneyRivlin::pk1(p, f),
        }
    }

    /// Energy density (J/m³) and `P = ∂W/∂F` (Pa) in one pass, sharing the
    /// kinematics (for corotated: one polar decomposition instead of two).
    /// Same values and errors as [`Material::energy`] and [`Material::pk1`].
    pub fn energy_pk1(&self, f: &Mat3, part: Part) -> Result<(f64, Mat3), MaterialError> {
        check_finite(f)?;
        let p = self.lame(part);
        match self.law {
            LawKind::Linear => linear::Linear::energy_pk1(p, f),
            LawKind::Corotated => corotated::Corotated::energy_pk1(p, f),
            LawKind::Svk => svk::Svk::energy_pk1(p, f),
            LawKind::NeoHookean => neo_hookean::NeoHookean::energy_pk1(p, f),
            LawKind::MooneyRivlin => mooney_rivlin::MooneyRivlin::energy_pk1(p, f),
        }
    }

    /// Energy density (J/m³), `P` (Pa) and the consistent tangent `∂P/∂F` (Pa)
    /// in one pass — the per-quadrature-point hot path (stack only, no heap).
    ///
    /// The corotated tangent is exact (includes ∂R/∂F); where it does not
    /// exist (two signed singular values summing to ≈ 0, e.g. a collapsed or
    /// half-inverted `F`) it is regularised, see `corotated.rs`. Errors as
    /// [`Material::energy`].
    #[inline]
    pub fn response(&self, f: &Mat3, part: Part) -> Result<PointResponse, MaterialError> {
        check_finite(f)?;
        let p = self.lame(part);
        match self.law {
            LawKind::Linear => linear::Linear::response(p, f),
            LawKind::Corotated => corotated::Corotated::response(p, f),
            LawKind::Svk => svk::Svk::response(p, f),
            LawKind::NeoHookean => neo_hookean::NeoHookean::response(p, f),
            LawKind::MooneyRivlin => mooney_rivlin::MooneyRivlin::response(p, f),
        }
    }

    /// [`Material::response`] with the tangent made positive semi-definite where the exact
    /// one is not, for Newton steps that must be descent directions and sparse Cholesky
    /// factorisations that must not fail. Corotated: the twist modes' negative eigenvalues
    /// (compressed points) are clamped to 0 (see `corotated.rs`); the tangent is exact
    /// wherever none is negative. Other laws: the exact tangent. Energy and `P` are
    /// unchanged.
    #[inline]
    pub fn response_projected(&self, f: &Mat3, part: Part) -> Result<PointResponse, MaterialError> {
        check_finite(f)?;
        let p = self.lame(part);
        match self.law {
            LawKind::Corotated => corotated::Corotated::response_projected(p, f),
            _ => self.response(f, part),
        }
    }

    /// Second Piola–Kirchhoff stress `S` (Pa), symmetric.
    ///
    /// SVK: `S = λ tr(E) I + 2μE` (eq. 2.8); neo-Hookean:
    /// `S = μ(I − C⁻¹) + λ ln J C⁻¹` (eq. 2.9); corotated: `S = F⁻¹P`
    /// (`Inverted` error if `F` is numerically singular; inverted but regular
    /// `F` is fine); linear: small-strain theory does not distinguish stress
    /// measures, so this returns σ (same as [`Material::pk1`]).
    pub fn pk2(&self, f: &Mat3, part: Part) -> Result<Mat3, MaterialError> {
        check_finite(f)?;
        let p = self.lame(part);
        match self.law {
            LawKind::Linear => linear::Linear::pk2(p, f),
            LawKind::Corotated => corotated::Corotated::pk2(p, f),
            LawKind::Svk => svk::Svk::pk2(p, f),
            LawKind::NeoHookean => neo_hookean::NeoHookean::pk2(p, f),
            LawKind::MooneyRivlin => mooney_rivlin::MooneyRivlin::pk2(p, f),
        }
    }

    /// Material tangent `ℂ = dS/dE` (Pa) as a [`Voigt6`] (engineering shear).
    ///
    /// Linear and SVK: the constant isotropic tensor `λ I⊗I + 2μ 𝕀`
    /// (for linear this is dσ/dε). Neo-Hookean:
    /// `λ C⁻¹⊗C⁻¹ + 2(μ − λ ln J) C⁻¹⊙C⁻¹` (eq. 2.9). Corotated: obtained from
    /// the exact 9×9 tangent via `dS = F⁻¹(dP − dF S)` with `dF = F⁻ᵀ dE`;
    /// requires invertible `F` (`Inverted` error if `F` is numerically
    /// singular).
    pub fn material_tangent(&self, f: &Mat3, part: Part) -> Result<Voigt6, MaterialError> {
        check_finite(f)?;
        let p = self.lame(part);
        match self.law {
            LawKind::Linear => linear::Linear::material_tangent(p, f),
            LawKind::Corotated => corotated::Corotated::material_tangent(p, f),
            LawKind::Svk => svk::Svk::material_tangent(p, f),
            LawKind::NeoHookean => neo_hookean::NeoHookean::material_tangent(p, f),
            LawKind::MooneyRivlin => mooney_rivlin::MooneyRivlin::material_tangent(p, f),
        }
    }
}

/// Rejects deformation gradients containing NaN or ±∞.
#[inline(always)]
fn check_finite(f: &Mat3) -> Result<(), MaterialError> {
    // x·0 is 0 for finite x and NaN for NaN/±∞: one branch for all nine entries.
    let s: f64 = f.iter().fold(0.0, |a, &x| a + x * 0.0);
    if s == 0.0 {
        Ok(())
    } else {
        Err(MaterialError::NonFinite)
    }
}

/// Constant isotropic elasticity tensor `λ I⊗I + 2μ 𝕀ˢʸᵐ` in Voigt form
/// (engineering shear), Pa.
fn isotropic_voigt(p: Lame) -> Voigt6 {
    let mut c = Voigt6::zeros();
    for a in 0..3 {
        for b in 0..3 {
            c[(a, b)] = p.lambda;
        }
        c[(a, a)] += 2.0 * p.mu;
        c[(a + 3, a + 3)] = p.mu;
    }
    c
}

/// Generic `dS/dE` from a 9×9 tangent `A = ∂P/∂F`, the stress `S` and an
/// invertible `F` with inverse `f_inv`: for each Voigt direction, `dE` unit
/// (engineering), `dF = F⁻ᵀ dE` (so `dC = 2 dE`), `dS = F⁻¹(A:dF − dF S)`.
fn material_tangent_from_a(a: &Tangent9, s: &Mat3, f_inv: &Mat3) -> Voigt6 {
    let f_inv_t = f_inv.transpose();
    let mut out = Voigt6::zeros();
    for (b, &(k, l)) in VOIGT.iter().enumerate() {
        let mut de = Mat3::zeros();
        if k == l {
            de[(k, l)] = 1.0;
        } else {
            de[(k, l)] = 0.5;
            de[(l, k)] = 0.5;
        }
        let df = f_inv_t * de;
        let mut dp = Mat3::zeros();
        for i in 0..3 {
            for j in 0..3 {
                let mut acc = 0.0;
                for kk in 0..3 {
                    for ll in 0..3 {
                        acc += a[(3 * i + j, 3 * kk + ll)] * df[(kk, ll)];
                    }
                }
                dp[(i, j)] = acc;
            }
        }
        let ds = f_inv * (dp - df * s);
        for (r, &(i, j)) in VOIGT.iter().enumerate() {
            out[(r, b)] = 0.5 * (ds[(i, j)] + ds[(j, i)]);
        }
    }
    out
}

#[cfg(test)]
mod tests;
