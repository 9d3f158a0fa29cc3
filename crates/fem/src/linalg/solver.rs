//! Solver front-end: sparse Cholesky / Bunch–Kaufman (faer) and Jacobi CG.

use std::time::Instant;

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::lblt::factor::LbltParams;
use faer::linalg::cholesky::llt::factor::LltParams;
use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, IntranodeLbltRef, LltRef,
    SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::traits::ComplexField;
use faer::{Conj, MatMut, Par, Side, Spec};
use serde::{Deserialize, Serialize};

use super::cg::{self, CgWork, FullOperator};
use super::nested_dissection::{expand_node_permutation, inverse_permutation, nested_dissection};
use super::{LinalgError, SymmetricCsc};

/// Largest dimension (degrees of freedom) for which [`SolverKind::Auto`]
/// uses the direct sparse Cholesky factorisation; larger systems use Jacobi
/// conjugate gradients.
///
/// Chosen by measurement on 3-dof linear-elasticity matrices of `m³`-node
/// grids (27-point stencil, four corners fixed, see [`super::testing`]),
/// comparing what one Newton iteration pays: numeric factorisation + solve
/// (symbolic analysis reused) against Jacobi CG to `‖r‖/‖b‖ ≤ 1e-10`.
/// Single-thread CPU time on the 2-core development machine:
///
/// | dofs   | direct  | CG (iterations) |
/// |-------:|--------:|----------------:|
/// |  3 000 |  0.008 s | 0.024 s (198) |
/// |  8 232 |  0.062 s | 0.107 s (291) |
/// | 12 288 |  0.18 s  | 0.19 s (342)  |
/// | 24 000 |  0.71 s  | 0.51 s (433)  |
/// | 41 472 |  2.0 s   | 1.2 s (529)   |
/// | 65 856 |  5.9 s   | 3.6 s (623)   |
/// | 98 304 | 13.8 s   | 8.2 s (721)   |
///
/// The pure-speed crossover is at about 12 000 dofs, but up to about
/// 100 000 dofs the direct solver costs at most ≈ 1.7× CG, needs at most
/// ≈ 1.5 GB for the factor, and is far more robust: it handles indefinite
/// tangents (Bunch–Kaufman fallback) and cut cells with tiny inside volume,
/// where Jacobi CG stalls (e.g. 1e-6 volume fraction: CG not converged after
/// 20 000 iterations, direct solve in < 0.1 s). Beyond this size the factor's
/// time (∝ n²) and memory (∝ n^{4/3}) outgrow CG's.
pub const AUTO_DIRECT_MAX_DOFS: usize = 100_000;

/// Which linear solver [`SparseSolver`] uses.
///
/// Serialised in kebab-case: `"auto"`, `"cholesky"`, `"ldlt"`, `"jacobi-cg"`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SolverKind {
    /// [`SolverKind::Cholesky`] up to [`AUTO_DIRECT_MAX_DOFS`] unknowns,
    /// [`SolverKind::JacobiCg`] beyond.
    #[default]
    Auto,
    /// Sparse supernodal Cholesky `LLᵀ` (AMD ordering, or nested dissection
    /// given [`SparseSolver::with_node_coordinates`]); if the matrix turns out
    /// not to be positive definite, automatically refactorised with the
    /// intranodal Bunch–Kaufman `LBLᵀ` on the same symbolic structure.
    Cholesky,
    /// Directly the indefinite-capable intranodal Bunch–Kaufman `LBLᵀ`
    /// factorisation (symmetric pivoting inside each supernode).
    Ldlt,
    /// Conjugate gradient preconditioned by the diagonal (Jacobi), `x₀ = 0`.
    JacobiCg,
}

/// Statistics of one [`SparseSolver::solve`] call.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveStats {
    /// Method actually used: `"cholesky"`, `"ldlt-bunch-kaufman"`,
    /// `"cholesky-fallback-ldlt-bunch-kaufman"` (Cholesky requested but the
    /// matrix was not positive definite) or `"jacobi-cg"`.
    pub method: &'static str,
    /// Conjugate-gradient iterations (0 for direct methods).
    pub iterations: usize,
    /// Iterative-refinement steps applied after a direct solve (0 for CG, and
    /// for direct solves that were accurate at once, i.e. relative residual
    /// ≤ 1e-12).
    pub refinement_steps: usize,
    /// Achieved relative residual `‖b − Kx‖₂ / ‖b‖₂` (0 when `b = 0`),
    /// computed with the true residual.
    pub relative_residual: f64,
    /// Wall time of the last [`SparseSolver::factorize`] (milliseconds),
    /// including a symbolic analysis if one was needed.
    pub factor_ms: f64,
    /// Wall time of this solve (milliseconds).
    pub solve_ms: f64,
}

/// Method names reported in [`SolveStats::method`].
const M_CHOLESKY: &str = "cholesky";
const M_CHOLESKY_F32: &str = "cholesky-f32";
const M_LBLT: &str = "ldlt-bunch-kaufman";
const M_FALLBACK: &str = "cholesky-fallback-ldlt-bunch-kaufman";
const M_CG: &str = "jacobi-cg";

/// Relative residual above which a direct solve is iteratively refined.
const REFINE_TOL: f64 = 1e-12;
/// Maximum number of iterative refinement steps after a direct solve.
const MAX_REFINE: usize = 3;
/// The same after a solve with a single-precision factor.
const MAX_REFINE_F32: usize = 6;

/// Pattern identity: fingerprint, dimension, number of stored entries.
type PatternKey = (u64, usize, usize);

fn pattern_key(k: &SymmetricCsc) -> PatternKey {
    (k.pattern_id(), k.n, k.row_idx.len())
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum DirectFactor {
    Llt,
    /// `L` of the diagonally scaled matrix `D K D` (`D = diag(K)^-1/2`) in f32.
    LltF32,
    Lblt,
}

/// Cached symbolic analysis plus numeric factor of the direct solver.
struct Direct {
    key: PatternKey,
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<f64>,
    /// Single-precision factor values and the diagonal scaling `D` (f64) it was made with.
    l_values_f32: Vec<f32>,
    scaled_f32: Vec<f32>,
    scale: Vec<f64>,
    rhs_f32: Vec<f32>,
    subdiag: Vec<f64>,
    perm_fwd: Vec<usize>,
    perm_inv: Vec<usize>,
    mem: MemBuffer,
    factor: Option<DirectFactor>,
    nested_dissection: bool,
}

/// Cached operator structure and preconditioner of the CG solver.
struct Cg {
    key: PatternKey,
    op: FullOperator,
    inv_diag: Vec<f64>,
    work: CgWork,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Active {
    Direct,
    Cg,
}

/// Solves `K x = b` for a sequence of symmetric matrices sharing one sparsity
/// pattern (the Newton tangent matrices of one grid).
///
/// The pattern-dependent analysis (fill-reducing ordering, elimination tree
/// and supernodes for the direct solvers; the full row-wise operator structure
/// for CG) is computed on the first [`SparseSolver::factorize`] and reused as
/// long as [`SymmetricCsc::pattern_id`] (and `n`, `nnz`) are unchanged;
/// [`SparseSolver::symbolic_analyses`] counts how often it was computed.
///
/// Parallelism: faer's kernels and the CG kernels run on the current rayon
/// thread pool; results do not depend on the number of threads beyond
/// rounding (CG: bitwise identical).
pub struct SparseSolver {
    kind: SolverKind,
    rel_tol: f64,
    max_iter: Option<usize>,
    direct: Option<Direct>,
    cg: Option<Cg>,
    active: Option<Active>,
    analyses: usize,
    factor_ms: f64,
    factorized_key: Option<PatternKey>,
    node_coords: Option<Vec<[usize; 3]>>,
    single_precision: Option<f64>,
}

impl std::fmt::Debug for SparseSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SparseSolver")
            .field("kind", &self.kind)
            .field("rel_tol", &self.rel_tol)
            .field("max_iter", &self.max_iter)
            .field("active", &self.active)
            .field("symbolic_analyses", &self.analyses)
            .field("factor_ms", &self.factor_ms)
            .field("node_coordinates", &self.node_coords.as_ref().map(Vec::len))
            .finish_non_exhaustive()
    }
}

impl Default for SparseSolver {
    fn default() -> Self {
        Self::new(SolverKind::Auto)
    }
}

/// Parallelism of the factorisation and triangular solves: sequential. faer parallelises only
/// inside each supernode's dense kernels, and on these grid matrices that costs more than it
/// gains on this 2-core machine (criterion, `benches/newton_iteration.rs`, liver-like ellipsoid
/// with nested dissection: factorisation 17.4 → 6.5 ms at 937 nodes and 270 → 213 ms at
/// 6,576 nodes going from 2 threads to 1). Assembly stays parallel.
fn par() -> Par {
    Par::Seq
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

fn faer_view(k: &SymmetricCsc) -> SparseColMatRef<'_, usize, f64> {
    faer_view_with(k, &k.values)
}

/// faer's view of `k`'s pattern holding `values` (one per stored entry of `k`, in its order).
fn faer_view_with<'a, T>(k: &'a SymmetricCsc, values: &'a [T]) -> SparseColMatRef<'a, usize, T> {
    let sym = SymbolicSparseColMatRef::new_checked(k.n, k.n, &k.col_ptr, None, &k.row_idx);
    SparseColMatRef::new(sym, values)
}

impl SparseSolver {
    /// Default relative tolerance `‖b − Kx‖ / ‖b‖` of the conjugate gradient.
    pub const DEFAULT_CG_REL_TOL: f64 = 1e-10;
    /// Upper bound of the default CG iteration cap (`min(5 n, 20 000)`).
    pub const DEFAULT_CG_MAX_ITER_CAP: usize = 20_000;

    /// Creates a solver of the given kind with default CG settings
    /// (`rel_tol = 1e-10`, `max_iter = min(5 n, 20 000)`).
    pub fn new(kind: SolverKind) -> Self {
        Self {
            kind,
            rel_tol: Self::DEFAULT_CG_REL_TOL,
            max_iter: None,
            direct: None,
            cg: None,
            active: None,
            analyses: 0,
            factor_ms: 0.0,
            factorized_key: None,
            node_coords: None,
            single_precision: None,
        }
    }

    /// Hint for the direct solvers' fill-reducing ordering: `coords[node]`
    /// are the integer grid coordinates `[i, j, k]` of the nodes, whose
    /// degrees of freedom are `3 node, 3 node + 1, 3 node + 2`, and two nodes
    /// are coupled only if `|Δi|, |Δj|, |Δk| ≤ 1` (hexahedra of a regular
    /// grid).
    ///
    /// For matrices with `n = 3 coords.len()`, the symbolic analysis then
    /// orders by geometric nested dissection
    /// ([`nested_dissection`](super::nested_dissection())) instead of AMD;
    /// for other dimensions the hint is ignored (AMD). A cached symbolic
    /// analysis is discarded, so the next [`SparseSolver::factorize`]
    /// analyses anew.
    pub fn with_node_coordinates(mut self, coords: Vec<[usize; 3]>) -> Self {
        self.node_coords = Some(coords);
        self.direct = None;
        self.active = None;
        self.factorized_key = None;
        self
    }

    /// Fill-reducing ordering of the current direct symbolic analysis:
    /// `Some("nested-dissection")` or `Some("amd")`, `None` if there is none.
    pub fn fill_reducing_ordering(&self) -> Option<&'static str> {
        self.direct.as_ref().map(|d| {
            if d.nested_dissection {
                "nested-dissection"
            } else {
                "amd"
            }
        })
    }

    /// Sets the conjugate-gradient stopping rule: relative residual
    /// `‖b − Kx‖₂ / ‖b‖₂ ≤ rel_tol`, at most `max_iter` iterations (clamped to
    /// at least 1).
    pub fn with_cg_settings(mut self, rel_tol: f64, max_iter: usize) -> Self {
        self.rel_tol = rel_tol;
        self.max_iter = Some(max_iter.max(1));
        self
    }

    /// The configured kind (possibly [`SolverKind::Auto`]).
    pub fn kind(&self) -> SolverKind {
        self.kind
    }

    /// What the configured kind resolves to for an `n × n` system
    /// ([`SolverKind::Auto`] becomes [`SolverKind::Cholesky`] for
    /// `n ≤ AUTO_DIRECT_MAX_DOFS`, else [`SolverKind::JacobiCg`]; other
    /// kinds are returned unchanged).
    pub fn chosen_method(&self, n: usize) -> SolverKind {
        match self.kind {
            SolverKind::Auto if n <= AUTO_DIRECT_MAX_DOFS => SolverKind::Cholesky,
            SolverKind::Auto => SolverKind::JacobiCg,
            k => k,
        }
    }

    /// Number of pattern analyses (symbolic factorisations, or CG operator
    /// structures) computed so far. Stays constant across `factorize` calls
    /// on matrices with an unchanged pattern.
    pub fn symbolic_analyses(&self) -> usize {
        self.analyses
    }

    /// Whether the current factorisation is a direct one (a sparse Cholesky or `LBLᵀ` factor),
    /// not the conjugate gradient's preconditioner.
    pub fn is_direct(&self) -> bool {
        self.active == Some(Active::Direct)
    }

    /// Method name of the current factorisation (same strings as
    /// [`SolveStats::method`]), or `None` if nothing is factorised.
    pub fn factorized_method(&self) -> Option<&'static str> {
        match self.active? {
            Active::Cg => Some(M_CG),
            Active::Direct => {
                let d = self.direct.as_ref()?;
                match (d.factor?, self.chosen_kind_for_direct()) {
                    (DirectFactor::Llt, _) => Some(M_CHOLESKY),
                    (DirectFactor::LltF32, _) => Some(M_CHOLESKY_F32),
                    (DirectFactor::Lblt, SolverKind::Ldlt) => Some(M_LBLT),
                    (DirectFactor::Lblt, _) => Some(M_FALLBACK),
                }
            }
        }
    }

    /// Mixed precision for the Cholesky factorisation: with `Some(tol)` the next
    /// factorisations of a positive definite matrix are computed in single precision (f32) on
    /// the diagonally scaled matrix `D K D`, `D = diag(K)^-1/2` — about 30 % less time and half
    /// the memory traffic of the triangular solves — and every solve is refined in f64 against
    /// `K` until its relative residual is at most `tol` (at most 6 refinement steps). For
    /// Newton steps with a kept, already approximate factorisation, where a relative residual
    /// of 10⁻⁶ is as good as 10⁻¹⁵. A matrix whose single-precision factorisation fails (not
    /// positive definite in f32) is factorised in f64 as before. `None` (the default): f64.
    pub fn set_single_precision(&mut self, tol: Option<f64>) {
        self.single_precision = tol.filter(|t| t.is_finite() && *t > 0.0);
    }

    fn chosen_kind_for_direct(&self) -> SolverKind {
        match self.kind {
            SolverKind::Ldlt => SolverKind::Ldlt,
            _ => SolverKind::Cholesky,
        }
    }

    /// Whether the last factorisation asked for Cholesky but found the matrix indefinite and
    /// fell back to the Bunch–Kaufman LBLᵀ factorisation.
    pub fn fell_back_to_indefinite(&self) -> bool {
        self.factorized_method() == Some(M_FALLBACK)
    }

    /// Number of stored values of the current direct factor (0 if none), a
    /// measure of its memory use (8 bytes each).
    pub fn factor_nnz(&self) -> usize {
        self.direct.as_ref().map_or(0, |d| d.l_values.len())
    }

    /// Factorises `k` (direct kinds) or prepares the Jacobi preconditioner
    /// (CG). The pattern analysis is computed on the first call and reused
    /// while `k.pattern_id()`, `k.n` and the number of entries are unchanged.
    ///
    /// Errors: [`LinalgError::InvalidPattern`] (pattern invariants violated),
    /// [`LinalgError::NonFinite`] (NaN/∞ in `k`), [`LinalgError::Singular`]
    /// (zero pivot / zero diagonal for CG), [`LinalgError::NotPositiveDefinite`]
    /// (CG only: negative diagonal), [`LinalgError::Faer`] (allocation). After
    /// an error nothing is factorised and `solve` returns
    /// [`LinalgError::NotFactorized`].
    pub fn factorize(&mut self, k: &SymmetricCsc) -> Result<(), LinalgError> {
        self.factorize_with(k, true).map(|_| ())
    }

    /// [`SparseSolver::factorize`] for a caller that makes an indefinite matrix definite
    /// itself (a diagonal shift) rather than use the Bunch–Kaufman factorisation: where
    /// Cholesky is the chosen method and the matrix is not positive definite, nothing is
    /// factorised and `Ok(false)` is returned, without the `LBLᵀ` factorisation
    /// [`SparseSolver::factorize`] would make and the caller would throw away. `Ok(true)`
    /// when a factorisation is in place (every other method behaves as
    /// [`SparseSolver::factorize`] does, with `Ok(true)`).
    pub fn factorize_if_positive_definite(
        &mut self,
        k: &SymmetricCsc,
    ) -> Result<bool, LinalgError> {
        self.factorize_with(k, false)
    }

    /// [`SparseSolver::factorize`], falling back to `LBLᵀ` on an indefinite matrix when
    /// `indefinite_fallback`, else leaving nothing factorised (`Ok(false)`).
    fn factorize_with(
        &mut self,
        k: &SymmetricCsc,
        indefinite_fallback: bool,
    ) -> Result<bool, LinalgError> {
        let t0 = Instant::now();
        self.active = None;
        self.factorized_key = None;
        if k.values.len() != k.row_idx.len() || k.col_ptr.len() != k.n + 1 {
            k.validate()?;
        }
        if !k.values.iter().all(|v| v.is_finite()) {
            return Err(LinalgError::NonFinite);
        }
        let key = pattern_key(k);
        let result = match self.chosen_method(k.n) {
            SolverKind::JacobiCg => self.prepare_cg(k, key).map(|_| Some(Active::Cg)),
            _ => self
                .factorize_direct(k, key, indefinite_fallback)
                .map(|done| done.then_some(Active::Direct)),
        };
        self.factor_ms = ms_since(t0);
        let Some(active) = result? else {
            return Ok(false);
        };
        self.active = Some(active);
        self.factorized_key = Some(key);
        Ok(true)
    }

    fn prepare_cg(&mut self, k: &SymmetricCsc, key: PatternKey) -> Result<(), LinalgError> {
        if self.cg.as_ref().is_none_or(|c| c.key != key) {
            self.cg = None;
            k.validate()?;
            let op = FullOperator::new(k)?;
            self.analyses += 1;
            self.cg = Some(Cg {
                key,
                op,
                inv_diag: Vec::new(),
                work: CgWork::default(),
            });
        }
        let cg = self.cg.as_mut().ok_or(LinalgError::NotFactorized)?;
        cg.inv_diag.clear();
        cg.inv_diag.reserve(k.n);
        for d in k.diagonal() {
            if d == 0.0 {
                return Err(LinalgError::Singular);
            }
            if d < 0.0 {
                return Err(LinalgError::NotPositiveDefinite);
            }
            cg.inv_diag.push(1.0 / d);
        }
        Ok(())
    }

    fn analyse_direct(&mut self, k: &SymmetricCsc, key: PatternKey) -> Result<(), LinalgError> {
        self.direct = None;
        let (symbolic, nested) = symbolic_cholesky(k, self.node_coords.as_deref())?;
        let n = k.n;
        self.analyses += 1;
        let mut l_values = Vec::new();
        l_values
            .try_reserve_exact(symbolic.len_val())
            .map_err(|_| LinalgError::Faer("out of memory for the factor".into()))?;
        l_values.resize(symbolic.len_val(), 0.0);
        let mem = MemBuffer::try_new(StackReq::EMPTY)
            .map_err(|_| LinalgError::Faer("out of memory for scratch".into()))?;
        self.direct = Some(Direct {
            key,
            symbolic,
            l_values,
            l_values_f32: Vec::new(),
            scaled_f32: Vec::new(),
            scale: Vec::new(),
            rhs_f32: Vec::new(),
            subdiag: vec![0.0; n],
            perm_fwd: vec![0; n],
            perm_inv: vec![0; n],
            mem,
            factor: None,
            nested_dissection: nested,
        });
        Ok(())
    }

    /// The direct factorisation of `k`: `Ok(false)` (nothing factorised) when Cholesky found
    /// it indefinite and `indefinite_fallback` is off.
    fn factorize_direct(
        &mut self,
        k: &SymmetricCsc,
        key: PatternKey,
        indefinite_fallback: bool,
    ) -> Result<bool, LinalgError> {
        if self.direct.as_ref().is_none_or(|d| d.key != key) {
            self.analyse_direct(k, key)?;
        }
        let want_llt = self.chosen_method(k.n) == SolverKind::Cholesky;
        let d = self.direct.as_mut().ok_or(LinalgError::NotFactorized)?;
        d.factor = None;
        let par = par();
        // Scratch sized for LLᵀ, LBLᵀ and a one-column solve at this
        // parallelism; grown if needed.
        let req = d
            .symbolic
            .factorize_numeric_llt_scratch::<f64>(par, Spec::<LltParams, f64>::default())
            .or(d.symbolic.factorize_numeric_intranode_lblt_scratch::<f64>(
                par,
                Spec::<LbltParams, f64>::default(),
            ))
            .or(d.symbolic.solve_in_place_scratch::<f64>(1, par));
        grow_scratch(&mut d.mem, req)?;
        if want_llt && self.single_precision.is_some() && d.factorize_f32(k, par)? {
            d.factor = Some(DirectFactor::LltF32);
            return Ok(true);
        }
        let a = faer_view(k);
        if want_llt {
            let ok = llt_numeric(&d.symbolic, &mut d.l_values, a, &mut d.mem, par);
            if ok && d.l_values.iter().all(|v| v.is_finite()) {
                d.factor = Some(DirectFactor::Llt);
                return Ok(true);
            }
            if !indefinite_fallback {
                return Ok(false);
            }
        }
        d.symbolic.factorize_numeric_intranode_lblt::<f64>(
            &mut d.l_values,
            &mut d.subdiag,
            &mut d.perm_fwd,
            &mut d.perm_inv,
            a,
            Side::Lower,
            par,
            MemStack::new(&mut d.mem),
            Default::default(),
        );
        check_lblt_pivots(&d.symbolic, &d.l_values, &d.subdiag)?;
        d.factor = Some(DirectFactor::Lblt);
        Ok(true)
    }

    /// Solves `K x = b` with the last factorised matrix; `x` is overwritten
    /// (for CG the initial guess is `x = 0`).
    ///
    /// `k` must be the matrix passed to the last successful
    /// [`SparseSolver::factorize`] (or at least have the same pattern): CG
    /// uses it for its products; direct solvers use it for the residual and
    /// up to 3 steps of iterative refinement when the relative residual
    /// exceeds `1e-12`.
    ///
    /// `b = 0` gives `x = 0` immediately. The returned `x` is always finite:
    /// on any error it holds a finite vector (CG: the last iterate, which the
    /// caller may use after [`LinalgError::NotConverged`]; otherwise zero).
    pub fn solve(
        &mut self,
        k: &SymmetricCsc,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, LinalgError> {
        let t0 = Instant::now();
        let active = self.active.ok_or(LinalgError::NotFactorized)?;
        self.check_factorised_pattern(k, "solve")?;
        if b.len() != k.n || x.len() != k.n {
            return Err(LinalgError::InvalidPattern(format!(
                "solve: b has length {} and x has length {}, expected {}",
                b.len(),
                x.len(),
                k.n
            )));
        }
        let method = self.factorized_method().unwrap_or(M_CG);
        if !b.iter().all(|v| v.is_finite()) {
            x.fill(0.0);
            return Err(LinalgError::NonFinite);
        }
        if b.iter().all(|&v| v == 0.0) {
            x.fill(0.0);
            return Ok(SolveStats {
                method,
                iterations: 0,
                refinement_steps: 0,
                relative_residual: 0.0,
                factor_ms: self.factor_ms,
                solve_ms: ms_since(t0),
            });
        }
        let (iterations, refinement_steps, relative_residual) = match active {
            Active::Cg => {
                let (it, rel) = self.solve_cg(k, b, x)?;
                (it, 0, rel)
            }
            Active::Direct => {
                let (steps, rel) = self.solve_direct(k, b, x)?;
                (0, steps, rel)
            }
        };
        Ok(SolveStats {
            method,
            iterations,
            refinement_steps,
            relative_residual,
            factor_ms: self.factor_ms,
            solve_ms: ms_since(t0),
        })
    }

    /// Solves `K X = B` for `columns` right-hand sides stored column after column in `b`
    /// (`n × columns`, column-major); `x` (the same shape) is overwritten. The same contract
    /// as [`SparseSolver::solve`] per column; a direct factorisation serves all columns in one
    /// pass over the factor (on these grid sizes, whose factors stay in cache, that saves only
    /// a few per cent: `benches/linear_solvers.rs`, `three-rhs`), then each column is refined
    /// on its own. CG solves the columns one after the other. The statistics are the worst
    /// column's residual and the summed iterations and refinement steps.
    pub fn solve_columns(
        &mut self,
        k: &SymmetricCsc,
        b: &[f64],
        x: &mut [f64],
        columns: usize,
    ) -> Result<SolveStats, LinalgError> {
        let t0 = Instant::now();
        let n = k.n;
        if b.len() != n * columns || x.len() != n * columns {
            return Err(LinalgError::InvalidPattern(format!(
                "solve_columns: b has length {} and x has length {}, expected {} × {columns}",
                b.len(),
                x.len(),
                n
            )));
        }
        let direct = self.active == Some(Active::Direct) && columns > 1;
        if !direct || !b.iter().all(|v| v.is_finite()) {
            let mut total = SolveStats {
                method: self.factorized_method().unwrap_or(M_CG),
                iterations: 0,
                refinement_steps: 0,
                relative_residual: 0.0,
                factor_ms: self.factor_ms,
                solve_ms: 0.0,
            };
            for (bj, xj) in b.chunks(n.max(1)).zip(x.chunks_mut(n.max(1))) {
                let s = self.solve(k, bj, xj)?;
                total.iterations += s.iterations;
                total.refinement_steps += s.refinement_steps;
                total.relative_residual = total.relative_residual.max(s.relative_residual);
            }
            total.solve_ms = ms_since(t0);
            return Ok(total);
        }
        self.check_factorised_pattern(k, "solve_columns")?;
        let method = self.factorized_method().unwrap_or(M_CG);
        let single_precision = self.single_precision;
        let d = self.direct.as_mut().ok_or(LinalgError::NotFactorized)?;
        x.copy_from_slice(b);
        d.apply_inverse(x, columns, par())?;
        let mut stats = SolveStats {
            method,
            iterations: 0,
            refinement_steps: 0,
            relative_residual: 0.0,
            factor_ms: self.factor_ms,
            solve_ms: 0.0,
        };
        for (bj, xj) in b.chunks(n).zip(x.chunks_mut(n)) {
            if bj.iter().all(|&v| v == 0.0) {
                xj.fill(0.0);
                continue;
            }
            let (steps, rel) = d.refine(k, bj, xj, single_precision)?;
            stats.refinement_steps += steps;
            stats.relative_residual = stats.relative_residual.max(rel);
        }
        stats.solve_ms = ms_since(t0);
        Ok(stats)
    }

    /// `Ok` when `k` has the dimension and number of stored entries of the last factorised
    /// matrix; the error names `caller`.
    fn check_factorised_pattern(&self, k: &SymmetricCsc, caller: &str) -> Result<(), LinalgError> {
        let key = self.factorized_key.ok_or(LinalgError::NotFactorized)?;
        if k.n != key.1 || k.row_idx.len() != key.2 || k.values.len() != key.2 {
            return Err(LinalgError::InvalidPattern(format!(
                "{caller}: matrix (n = {}, nnz = {}) differs from the factorised one (n = {}, nnz = {})",
                k.n,
                k.row_idx.len(),
                key.1,
                key.2
            )));
        }
        Ok(())
    }

    fn solve_cg(
        &mut self,
        k: &SymmetricCsc,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<(usize, f64), LinalgError> {
        let n = k.n;
        let max_iter = self
            .max_iter
            .unwrap_or_else(|| (5 * n).clamp(1, Self::DEFAULT_CG_MAX_ITER_CAP));
        let rel_tol = self.rel_tol;
        let cg = self.cg.as_mut().ok_or(LinalgError::NotFactorized)?;
        cg.op.gather(k);
        let out = cg::pcg(&cg.op, &cg.inv_diag, b, x, rel_tol, max_iter, &mut cg.work);
        if !x.iter().all(|v| v.is_finite()) {
            x.fill(0.0);
            return Err(LinalgError::NonFinite);
        }
        out.result?;
        Ok((out.iterations, out.relative_residual))
    }

    fn solve_direct(
        &mut self,
        k: &SymmetricCsc,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<(usize, f64), LinalgError> {
        let single_precision = self.single_precision;
        let d = self.direct.as_mut().ok_or(LinalgError::NotFactorized)?;
        x.copy_from_slice(b);
        d.apply_inverse(x, 1, par())?;
        d.refine(k, b, x, single_precision)
    }
}

impl Direct {
    /// Iteratively refines `x` (already `K⁻¹ b` through the factor) against `k` while the
    /// relative residual exceeds the tolerance of the factor's precision; returns the steps
    /// taken and the final relative residual. A non-finite `x` is zeroed and reported.
    fn refine(
        &mut self,
        k: &SymmetricCsc,
        b: &[f64],
        x: &mut [f64],
        single_precision: Option<f64>,
    ) -> Result<(usize, f64), LinalgError> {
        let n = k.n;
        let par = par();
        if !x.iter().all(|v| v.is_finite()) {
            x.fill(0.0);
            return Err(LinalgError::NonFinite);
        }
        let bnorm = cg::norm(b);
        let mut r = vec![0.0; n];
        let residual = |x: &[f64], r: &mut [f64]| {
            k.mul_vec(x, r);
            for (ri, bi) in r.iter_mut().zip(b) {
                *ri = bi - *ri;
            }
            cg::norm(r) / bnorm
        };
        let mut rel = residual(x, &mut r);
        let mut steps = 0;
        let mut trial = vec![0.0; n];
        let (tol, max_steps) = match (self.factor, single_precision) {
            (Some(DirectFactor::LltF32), Some(t)) => (t, MAX_REFINE_F32),
            _ => (REFINE_TOL, MAX_REFINE),
        };
        while rel > tol && steps < max_steps && rel.is_finite() {
            steps += 1;
            // r ← K⁻¹ r; trial = x + r.
            self.apply_inverse(&mut r, 1, par)?;
            for ((t, xi), di) in trial.iter_mut().zip(x.iter()).zip(&r) {
                *t = xi + di;
            }
            let rel_new = residual(&trial, &mut r);
            if rel_new.is_nan() || rel_new >= rel {
                break;
            }
            x.copy_from_slice(&trial);
            rel = rel_new;
        }
        if !rel.is_finite() {
            x.fill(0.0);
            return Err(LinalgError::NonFinite);
        }
        Ok((steps, rel))
    }

    /// Factorises `D K D` (`D = diag(K)^-1/2`) in single precision; `Ok(false)` when `K` has a
    /// non-positive diagonal or the factorisation fails or is not finite (then the caller
    /// factorises in f64).
    fn factorize_f32(&mut self, k: &SymmetricCsc, par: Par) -> Result<bool, LinalgError> {
        let n = k.n;
        self.scale.clear();
        for d in k.diagonal() {
            if d.is_nan() || d <= 0.0 {
                return Ok(false);
            }
            self.scale.push(1.0 / d.sqrt());
        }
        self.scaled_f32.clear();
        for j in 0..n {
            for q in k.col_ptr[j]..k.col_ptr[j + 1] {
                let v = k.values[q] * self.scale[j] * self.scale[k.row_idx[q]];
                self.scaled_f32.push(v as f32);
            }
        }
        let req = self
            .symbolic
            .factorize_numeric_llt_scratch::<f32>(par, Spec::<LltParams, f32>::default())
            .or(self.symbolic.solve_in_place_scratch::<f32>(1, par));
        grow_scratch(&mut self.mem, req)?;
        self.l_values_f32.resize(self.symbolic.len_val(), 0.0);
        let a = faer_view_with(k, &self.scaled_f32);
        let ok = llt_numeric(
            &self.symbolic,
            &mut self.l_values_f32,
            a,
            &mut self.mem,
            par,
        );
        Ok(ok && self.l_values_f32.iter().all(|v| v.is_finite()))
    }

    /// Overwrites the `columns` right-hand sides stored column after column in `rhs` with
    /// `K⁻¹` of them (the current factor), in one pass over the factor.
    fn apply_inverse(
        &mut self,
        rhs: &mut [f64],
        columns: usize,
        par: Par,
    ) -> Result<(), LinalgError> {
        let n = rhs.len() / columns.max(1);
        if columns > 1 {
            let req = if self.factor == Some(DirectFactor::LltF32) {
                self.symbolic.solve_in_place_scratch::<f32>(columns, par)
            } else {
                self.symbolic.solve_in_place_scratch::<f64>(columns, par)
            };
            grow_scratch(&mut self.mem, req)?;
        }
        match self.factor {
            Some(DirectFactor::LltF32) => {
                // K⁻¹ = D (D K D)⁻¹ D.
                self.rhs_f32.clear();
                self.rhs_f32.extend(
                    rhs.iter()
                        .zip(self.scale.iter().cycle())
                        .map(|(r, d)| (r * d) as f32),
                );
                llt_solve_in_place(
                    &self.symbolic,
                    &self.l_values_f32,
                    &mut self.rhs_f32,
                    columns,
                    &mut self.mem,
                    par,
                );
                for ((r, y), d) in rhs
                    .iter_mut()
                    .zip(&self.rhs_f32)
                    .zip(self.scale.iter().cycle())
                {
                    *r = f64::from(*y) * d;
                }
            }
            Some(DirectFactor::Llt) => llt_solve_in_place(
                &self.symbolic,
                &self.l_values,
                rhs,
                columns,
                &mut self.mem,
                par,
            ),
            Some(DirectFactor::Lblt) => {
                let perm = PermRef::new_checked(&self.perm_fwd, &self.perm_inv, n);
                let rhs = MatMut::from_column_major_slice_mut(rhs, n, columns);
                IntranodeLbltRef::new(&self.symbolic, &self.l_values, &self.subdiag, perm)
                    .solve_in_place_with_conj(Conj::No, rhs, par, MemStack::new(&mut self.mem))
            }
            None => {}
        }
        Ok(())
    }
}

/// Numeric supernodal Cholesky `LLᵀ` of `a` (its lower triangle; the pattern `symbolic` was
/// analysed from) in the precision `T` of its values, into `l_values` (sized to
/// `symbolic.len_val()`); `mem` holds the scratch. `false` when faer finds a non-positive pivot;
/// the caller checks the values' finiteness. The one factorisation of both precisions.
fn llt_numeric<T: ComplexField>(
    symbolic: &SymbolicCholesky<usize>,
    l_values: &mut [T],
    a: SparseColMatRef<'_, usize, T>,
    mem: &mut MemBuffer,
    par: Par,
) -> bool {
    symbolic
        .factorize_numeric_llt::<T>(
            l_values,
            a,
            Side::Lower,
            Default::default(),
            par,
            MemStack::new(mem),
            Default::default(),
        )
        .is_ok()
}

/// Overwrites the `columns` right-hand sides stored column after column in `rhs` with
/// `(L Lᵀ)⁻¹` of them, `L` the factor values `l_values` of `symbolic`, in precision `T`; `mem`
/// must hold the solve's scratch. The one triangular solve of both precisions.
fn llt_solve_in_place<T: ComplexField>(
    symbolic: &SymbolicCholesky<usize>,
    l_values: &[T],
    rhs: &mut [T],
    columns: usize,
    mem: &mut MemBuffer,
    par: Par,
) {
    let n = rhs.len() / columns.max(1);
    let rhs = MatMut::from_column_major_slice_mut(rhs, n, columns);
    LltRef::new(symbolic, l_values).solve_in_place_with_conj(
        Conj::No,
        rhs,
        par,
        MemStack::new(mem),
    );
}

/// Symbolic supernodal Cholesky analysis of `k`'s pattern, ordered by geometric nested
/// dissection when `node_coords` matches the matrix (3 dofs per node), else by AMD; also
/// whether nested dissection was used.
fn symbolic_cholesky(
    k: &SymmetricCsc,
    node_coords: Option<&[[usize; 3]]>,
) -> Result<(SymbolicCholesky<usize>, bool), LinalgError> {
    k.validate()?;
    let a = faer_view(k);
    let params = CholeskySymbolicParams {
        // Always supernodal: the intranodal Bunch–Kaufman fallback only
        // pivots in the supernodal code path (the simplicial LDLᵀ has no
        // pivoting), and 3-dof elasticity patterns favour supernodes.
        supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
        ..Default::default()
    };
    let n = k.n;
    // Geometric nested dissection if node coordinates match the matrix.
    // faer's `Custom(PermRef)` takes `fwd[new] = old`, `inv[old] = new`.
    let nd_perm = node_coords
        .filter(|c| !c.is_empty() && 3 * c.len() == n)
        .map(|c| {
            let fwd = expand_node_permutation(&nested_dissection(c), 3);
            let inv = inverse_permutation(&fwd);
            (fwd, inv)
        });
    let ordering = match &nd_perm {
        Some((fwd, inv)) => SymmetricOrdering::Custom(PermRef::new_checked(fwd, inv, n)),
        None => SymmetricOrdering::Amd,
    };
    let symbolic = factorize_symbolic_cholesky(a.symbolic(), Side::Lower, ordering, params)
        .map_err(|e| LinalgError::Faer(format!("symbolic analysis: {e:?}")))?;
    Ok((symbolic, nd_perm.is_some()))
}

/// Number of values the direct factor `L` of a matrix with `k`'s pattern will store (8 bytes
/// each in f64), from the same symbolic analysis [`SparseSolver::factorize`] makes with the
/// node-coordinate hint `node_coords` (see [`SparseSolver::with_node_coordinates`]); 0 when
/// `kind` resolves to the conjugate gradient for this size (which stores no factor). Only the
/// pattern of `k` is read; no values are allocated. Used to estimate a model's memory before
/// its first frame.
pub fn predicted_factor_len(
    k: &SymmetricCsc,
    node_coords: Option<&[[usize; 3]]>,
    kind: SolverKind,
) -> Result<usize, LinalgError> {
    if SparseSolver::new(kind).chosen_method(k.n) == SolverKind::JacobiCg {
        return Ok(0);
    }
    Ok(symbolic_cholesky(k, node_coords)?.0.len_val())
}

/// Makes `mem` at least as large as `req` (kept across factorisations; only grows).
fn grow_scratch(mem: &mut MemBuffer, req: StackReq) -> Result<(), LinalgError> {
    if req.unaligned_bytes_required() > mem.len() {
        *mem = MemBuffer::try_new(req)
            .map_err(|_| LinalgError::Faer("out of memory for scratch".into()))?;
    }
    Ok(())
}

/// Checks the block-diagonal factor `B` of an intranodal `LBLᵀ`: every 1×1
/// pivot and every 2×2 pivot block must be finite and nonsingular, and all
/// factor values finite. Returns [`LinalgError::Singular`] otherwise.
fn check_lblt_pivots(
    symbolic: &SymbolicCholesky<usize>,
    l_values: &[f64],
    subdiag: &[f64],
) -> Result<(), LinalgError> {
    if !l_values.iter().all(|v| v.is_finite()) || !subdiag.iter().all(|v| v.is_finite()) {
        return Err(LinalgError::Singular);
    }
    let SymbolicCholeskyRaw::Supernodal(sn) = symbolic.raw() else {
        // Not produced by `analyse_direct` (always supernodal).
        return Ok(());
    };
    let begin = sn.supernode_begin();
    let end = sn.supernode_end();
    let val_ptr = sn.col_ptr_for_val();
    for s in 0..sn.n_supernodes() {
        let ncols = end[s] - begin[s];
        let nrows = sn.supernode(s).pattern().len() + ncols;
        let base = val_ptr[s];
        let diag = |j: usize| l_values[base + j * nrows + j];
        let sub = &subdiag[begin[s]..end[s]];
        let mut j = 0;
        while j < ncols {
            if sub[j] == 0.0 {
                if diag(j) == 0.0 {
                    return Err(LinalgError::Singular);
                }
                j += 1;
            } else {
                let det = diag(j) * diag(j + 1) - sub[j] * sub[j];
                if det == 0.0 || !det.is_finite() {
                    return Err(LinalgError::Singular);
                }
                j += 2;
            }
        }
    }
    Ok(())
}
