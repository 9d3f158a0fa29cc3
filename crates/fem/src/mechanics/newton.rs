//! Static Newton–Raphson with load stepping, a line search and increment bisection
//! (thesis eq. 2.28 and alg. 1; seed 003 §2.5).

use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::assembly::CellFailure;
use super::background_factorization::{BackgroundFactorizer, Factored};
use super::cell_kernel::Need;
use super::penalty::PenaltySprings;
use super::static_problem::StaticProblem;
use crate::linalg::{LinalgError, SolveStats, SolverKind, SparseSolver, SymmetricCsc};

/// Settings of the static solver.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NewtonSettings {
    /// Nominal number of equal load increments.
    pub load_steps: usize,
    /// Newton iterations allowed per increment.
    pub max_iterations: usize,
    /// Converged when ‖R‖ ≤ this × max(‖R₀‖, ‖s f_ext‖) (R₀: residual at the increment's start).
    pub residual_tolerance: f64,
    /// Converged when a full Newton step has ‖δu‖ ≤ this × ‖u‖.
    pub displacement_tolerance: f64,
    /// How many times in a row a failed increment may be halved before giving up.
    pub max_bisections: usize,
    /// Backtracking line search on the potential energy.
    pub line_search: bool,
    /// Linear solver.
    pub linear_solver: SolverKind,
    /// Assemble the positive semi-definite projected tangent
    /// ([`Need::ProjectedTangent`]) instead of the exact one: every step is a descent
    /// direction and the factorisation needs no diagonal shift; convergence is quadratic
    /// wherever nothing was clamped.
    pub projected_tangent: bool,
    /// [`NewtonSolver::improve`] (modified Newton, a kept factorisation) factorises in single
    /// precision and refines each solve in f64 to a relative residual of
    /// [`MIXED_PRECISION_TOLERANCE`] ([`SparseSolver::set_single_precision`]); full solves
    /// stay in f64.
    #[serde(default)]
    pub mixed_precision: bool,
    /// γ of the cut-cell step stabilisation
    /// ([`StaticProblem::add_cut_cell_stabilization`]; 0: off) of the factorisations [`NewtonSolver::improve`] keeps for several steps
    /// ([`NewtonSolver::with_factor_reuse`] > 1: registration's warm frames), whose steps
    /// would otherwise overshoot at the nodes of badly cut cells. Fresh factorisations are
    /// exact and get none; full solves never use it.
    #[serde(default)]
    pub step_stabilization: f64,
}

/// The message of a solve stopped by [`NewtonSolver::set_factorization_budget`].
const FACTORIZATION_BUDGET_SPENT: &str = "factorisation budget spent";

/// Relative residual to which solves with a single-precision factorisation are refined:
/// measured (`livereg bench`) to leave the registration's TRE unchanged, where 10⁻⁶ did not.
pub const MIXED_PRECISION_TOLERANCE: f64 = 1e-10;

impl Default for NewtonSettings {
    fn default() -> Self {
        Self {
            load_steps: 10,
            max_iterations: 30,
            residual_tolerance: 1e-8,
            displacement_tolerance: 1e-8,
            max_bisections: 6,
            line_search: true,
            linear_solver: SolverKind::Auto,
            projected_tangent: true,
            mixed_precision: false,
            step_stabilization: 0.0,
        }
    }
}

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Outcome {
    /// Full load reached and equilibrium found.
    Converged,
    /// An increment hit the iteration cap even after the allowed bisections.
    IterationCap,
    /// The residual grew without bound, became non-finite, or the linear solve failed.
    Diverged,
    /// A quadrature point inverted (J ≤ 0) and no smaller increment avoided it.
    Inverted,
}

impl Outcome {
    /// Name used in reports.
    pub fn name(self) -> &'static str {
        match self {
            Outcome::Converged => "converged",
            Outcome::IterationCap => "iteration-cap",
            Outcome::Diverged => "diverged",
            Outcome::Inverted => "inverted",
        }
    }
}

/// Result of a static solve. `u` is always a valid state: the converged solution, or the last
/// converged increment when the solve failed.
#[derive(Debug, Clone, PartialEq)]
pub struct SolveReport {
    /// How it ended.
    pub outcome: Outcome,
    /// Why it failed, when it did.
    pub message: Option<String>,
    /// Nodal displacements (m), 3 per node: the last good state.
    pub u: Vec<f64>,
    /// Load factor of `u` (1 when converged).
    pub load_reached: f64,
    /// Newton iterations over all increments (including failed ones).
    pub newton_iterations: usize,
    /// Converged increments.
    pub load_steps: usize,
    /// Increment halvings performed.
    pub bisections: usize,
    /// Final relative residual of the last converged increment.
    pub relative_residual: f64,
    /// Wall time, ms.
    pub wall_ms: f64,
    /// Every Newton iteration, in order (diagnostics).
    pub history: Vec<IterationRecord>,
}

/// What [`NewtonSolver::improve`] achieved.
#[derive(Debug, Clone, PartialEq)]
pub struct ImproveReport {
    /// Newton iterations done.
    pub iterations: usize,
    /// Relative residual before the last step (or at convergence).
    pub relative_residual: f64,
    /// Whether equilibrium was reached.
    pub converged: bool,
    /// Steps whose tangent was indefinite and had to be shifted (Levenberg–Marquardt).
    pub shifted_steps: usize,
    /// Step lengths the line search accepted, in order.
    pub steps: Vec<f64>,
    /// A failure other than the iteration cap (inversion no step avoided, linear solve), with
    /// its message; the state is still the last valid one.
    pub failure: Option<(Outcome, String)>,
    /// Whether the solve stopped because a step needed a factorisation beyond the budget
    /// ([`NewtonSolver::set_factorization_budget`]); the state is the last iterate.
    pub budget_spent: bool,
}

/// One Newton iteration, for diagnostics.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct IterationRecord {
    /// Load factor of the increment being solved.
    pub load: f64,
    /// ‖R‖ / reference before the step.
    pub relative_residual: f64,
    /// Line-search step length taken.
    pub step: f64,
    /// Linear solver used (e.g. `"cholesky"`, or the indefinite fallback).
    pub linear_method: &'static str,
    /// Diagonal shift τ applied to an indefinite tangent (0 when none was needed).
    pub regularization: f64,
}

/// What one call of `NewtonSolver::iterate` runs at: the load factor, the caps and the
/// step stabilisation of its factorised tangents.
struct IterationRun {
    /// Load factor (1: full load).
    load: f64,
    /// Newton iterations allowed.
    max_iterations: usize,
    /// Steps one factorisation may serve (1: plain Newton).
    max_uses: usize,
    /// γ of the cut-cell step stabilisation added to factorised tangents (0 with one use).
    stabilization: f64,
}

/// The vectors one call of `NewtonSolver::iterate` works in (all of the problem's length,
/// N or m) and its residual scales (N).
struct IterationWork {
    /// The residual at the current state.
    r: Vec<f64>,
    /// The Newton direction.
    du: Vec<f64>,
    /// The line search's trial state.
    trial: Vec<f64>,
    /// The norm of the external load at this load factor.
    external_norm: f64,
    /// The residual norm relative residuals are measured against (set at the first
    /// iteration).
    reference: f64,
    /// The residual norm at which a state is exact to round-off (set at each assembly).
    round_off: f64,
}

impl IterationWork {
    fn new(n: usize, external_norm: f64) -> Self {
        Self {
            r: vec![0.0; n],
            du: vec![0.0; n],
            trial: vec![0.0; n],
            external_norm,
            reference: 0.0,
            round_off: 0.0,
        }
    }
}

/// Why one increment failed.
#[derive(Debug, Clone, PartialEq)]
struct StepFailure {
    outcome: Outcome,
    message: String,
}

impl From<CellFailure> for StepFailure {
    fn from(f: CellFailure) -> Self {
        StepFailure {
            outcome: Outcome::Inverted,
            message: format!("cell {}: {}", f.cell, f.error),
        }
    }
}

impl From<LinalgError> for StepFailure {
    fn from(e: LinalgError) -> Self {
        StepFailure {
            outcome: Outcome::Diverged,
            message: format!("linear solve failed: {e}"),
        }
    }
}

/// Newton–Raphson solver for a [`StaticProblem`], keeping its linear solver (and so the
/// symbolic factorisation) and work buffers across solves.
///
/// [`NewtonSolver::solve`] and [`NewtonSolver::improve`] take, besides the problem, spring
/// sets that act on the body for that call only (`extra`: a registration's data term;
/// [`StaticProblem::evaluate_with`]). The solver owns its factorisation state, including which
/// `extra` springs the factorisation in use was made with
/// ([`NewtonSolver::factorization_springs`]).
pub struct NewtonSolver {
    /// Settings.
    pub settings: NewtonSettings,
    linear: SparseSolver,
    tangent: Option<SymmetricCsc>,
    /// Grid (dims, node count) the linear solver's nested-dissection ordering was made for.
    ordered_for: Option<([usize; 3], usize)>,
    /// Most Newton steps one factorisation may serve in [`NewtonSolver::improve`] (1: a new
    /// factorisation every step, plain Newton).
    factor_reuse: usize,
    /// Steps served by the current factorisation (`None`: no usable factorisation).
    factor_age: Option<usize>,
    /// Factorisations done since the solver was made.
    factorizations: usize,
    /// Diagonal shift τ that last made an indefinite tangent factorisable (0: none needed);
    /// the next indefinite tangent starts its search one decade below it.
    last_shift: f64,
    /// Whether `linear` holds a factorisation of the current problem's pattern (stale or not).
    has_factor: bool,
    /// The `extra` springs whose stiffness the factorisation in `linear` includes.
    factored_with: Vec<PenaltySprings>,
    /// Steps a refactorisation may lag behind its request (0: refactorise in place).
    background_lag: usize,
    /// The helper thread that refactorises while steps go on with the old factorisation.
    background: Option<BackgroundFactorizer>,
    /// Newton steps made by [`NewtonSolver::improve`] since the solver was made (the clock of
    /// background refactorisation).
    improve_steps: usize,
    /// Helper-thread factorisations swapped in since the solver was made (also counted in
    /// `factorizations`; kept here so the counts never go back when a helper is replaced).
    helper_factorizations: usize,
    /// Fresh factorisations [`NewtonSolver::improve`] may still make (`None`: no limit).
    factorization_budget: Option<usize>,
    /// Whether the last call of [`NewtonSolver::improve`] stopped because the budget was spent.
    budget_stopped: bool,
}

impl NewtonSolver {
    /// A solver with `settings`.
    pub fn new(settings: NewtonSettings) -> Self {
        Self {
            linear: SparseSolver::new(settings.linear_solver),
            settings,
            tangent: None,
            ordered_for: None,
            factor_reuse: 1,
            factor_age: None,
            factorizations: 0,
            last_shift: 0.0,
            has_factor: false,
            factored_with: Vec::new(),
            background_lag: 0,
            background: None,
            improve_steps: 0,
            helper_factorizations: 0,
            factorization_budget: None,
            budget_stopped: false,
        }
    }

    /// Lets one factorisation of the tangent serve up to `max_uses` steps of
    /// [`NewtonSolver::improve`], across calls (modified Newton): a step with a kept
    /// factorisation costs one residual evaluation and two triangular solves instead of a
    /// tangent assembly and a factorisation. The kept matrix is symmetric positive definite,
    /// so its step is still a descent direction of the energy and the line search still
    /// guarantees a decrease; a step the line search has to shorten below ½ drops the
    /// factorisation. `max_uses ≤ 1` restores plain Newton. [`NewtonSolver::solve`] always
    /// refactorises.
    pub fn with_factor_reuse(mut self, max_uses: usize) -> Self {
        self.set_factor_reuse(max_uses);
        self
    }

    /// [`NewtonSolver::with_factor_reuse`] on a solver in use (its ordering, symbolic analysis
    /// and current factorisation are kept).
    pub fn set_factor_reuse(&mut self, max_uses: usize) {
        self.factor_reuse = max_uses.max(1);
    }

    /// Forgets the kept factorisation (the next step refactorises), for example when the
    /// problem changed beyond what a stale tangent can follow.
    pub fn invalidate_factorization(&mut self) {
        self.factor_age = None;
        self.has_factor = false;
        if let Some(bg) = self.background.as_mut() {
            bg.cancel();
        }
    }

    /// Refactorisations in [`NewtonSolver::improve`] (modified Newton, `factor_reuse > 1`)
    /// run on a helper thread: when the kept factorisation has served its steps or a step was
    /// shortened, the tangent at the current state is factorised there while the steps go on
    /// with the old factorisation, and the new one is swapped in `lag` steps after it was
    /// asked for (waiting for it then if needed; results do not depend on thread timing).
    /// `lag = 0` refactorises in place. Without any factorisation yet, or after a step the
    /// old factorisation could not make at all, the solver refactorises in place.
    pub fn set_background_lag(&mut self, lag: usize) {
        if lag == 0 {
            self.background = None;
        } else if let Some(bg) = &self.background {
            if bg.lag() != lag {
                self.background = None;
            }
        }
        self.background_lag = lag;
    }

    /// Factorisations made by the helper thread (included in
    /// [`NewtonSolver::factorizations`]).
    pub fn background_factorizations(&self) -> usize {
        self.helper_factorizations
    }

    /// Whether the next step of [`NewtonSolver::improve`] would step with the kept
    /// factorisation (unless a background one is swapped in first, or its line search fails).
    pub fn reuses_factorization(&self) -> bool {
        self.factor_age.is_some_and(|a| a < self.factor_reuse)
            || (self.factor_reuse > 1 && self.has_factor && self.background_lag > 0)
    }

    /// Whether a background refactorisation has been asked for and not swapped in yet.
    pub fn background_pending(&self) -> bool {
        self.background.as_ref().is_some_and(|b| b.pending())
    }

    /// The `extra` springs (see [`NewtonSolver::improve`]) whose stiffness the kept
    /// factorisation includes, while the next step of [`NewtonSolver::improve`] would reuse
    /// it ([`NewtonSolver::reuses_factorization`]); `None` when that step refactorises. A
    /// caller may restrict its next springs to these: a spring the factorisation lacks, at a
    /// point the body barely holds, makes a modified-Newton step overshoot.
    pub fn factorization_springs(&self) -> Option<&[PenaltySprings]> {
        self.reuses_factorization()
            .then_some(self.factored_with.as_slice())
    }

    /// Limits the fresh factorisations [`NewtonSolver::improve`] may make from now on to
    /// `budget` (`None`: no limit). A step that would need one more stops the solve at its
    /// last iterate, as the iteration cap does ([`ImproveReport::budget_spent`]): a bound on a
    /// solve's time where its iteration cap alone is not one, since every iteration may
    /// refactorise.
    pub fn set_factorization_budget(&mut self, budget: Option<usize>) {
        self.factorization_budget = budget;
    }

    /// Factorisations of the tangent done so far (each costs far more than a step),
    /// including the helper thread's.
    pub fn factorizations(&self) -> usize {
        self.factorizations
    }

    /// Solves from the state `u0` (m; load factor 0 is assumed to hold there) up to full load,
    /// with the spring sets `extra` (N/m) acting on the body besides its own
    /// ([`StaticProblem::evaluate_with`]; `&[]`: none).
    pub fn solve(
        &mut self,
        problem: &mut StaticProblem,
        extra: &[PenaltySprings],
        u0: &[f64],
    ) -> SolveReport {
        let start = Instant::now();
        self.prepare_for(problem);
        self.linear.set_single_precision(None);
        let s = self.settings;
        let nominal = 1.0 / s.load_steps.max(1) as f64;
        let mut u = u0.to_vec();
        let mut load = 0.0;
        let mut step = nominal;
        let mut consecutive = 0;
        let mut report = SolveReport {
            outcome: Outcome::Converged,
            message: None,
            u: Vec::new(),
            load_reached: 0.0,
            newton_iterations: 0,
            load_steps: 0,
            bisections: 0,
            relative_residual: 0.0,
            wall_ms: 0.0,
            history: Vec::new(),
        };
        // The previous converged state, for the secant predictor of the next increment.
        let mut previous: Option<(Vec<f64>, f64)> = None;
        while load < 1.0 - 1e-12 {
            let target = (load + step).min(1.0);
            let mut trial = self.predict(problem, extra, &u, load, previous.as_ref(), target);
            match self.increment(
                problem,
                extra,
                &mut trial,
                target,
                &mut report.newton_iterations,
                &mut report.history,
            ) {
                Ok(rel) => {
                    previous = Some((std::mem::replace(&mut u, trial), load));
                    load = target;
                    report.load_steps += 1;
                    report.relative_residual = rel;
                    consecutive = 0;
                    step = (step * 2.0).min(nominal);
                }
                Err(fail) => {
                    if consecutive >= s.max_bisections {
                        report.outcome = fail.outcome;
                        report.message = Some(format!(
                            "increment to load factor {target:.4} failed after {consecutive} bisections: {}",
                            fail.message
                        ));
                        break;
                    }
                    consecutive += 1;
                    report.bisections += 1;
                    step *= 0.5;
                }
            }
        }
        report.u = u;
        report.load_reached = load;
        report.wall_ms = start.elapsed().as_secs_f64() * 1e3;
        report
    }

    /// Improves the state `u` (m, updated in place) of a problem at full load by at most
    /// `max_iterations` Newton iterations with line search, stopping early when converged:
    /// what each iteration of non-rigid ICP needs (a few iterations, not full equilibrium).
    /// `extra`: spring sets (N/m) acting on the body for this call besides its own
    /// ([`StaticProblem::evaluate_with`]; a registration's data term). A kept factorisation
    /// may have been made with earlier `extra` springs
    /// ([`NewtonSolver::factorization_springs`]): the steps then follow the new springs'
    /// forces with the old springs' stiffness, and the line search guarantees the decrease.
    /// The state stays valid whatever happens; the report says how far it got.
    pub fn improve(
        &mut self,
        problem: &mut StaticProblem,
        extra: &[PenaltySprings],
        u: &mut [f64],
        max_iterations: usize,
    ) -> ImproveReport {
        self.prepare_for(problem);
        self.linear.set_single_precision(self.single_precision());
        self.budget_stopped = false;
        let mut iterations = 0;
        let mut history = Vec::new();
        let result = self.iterate(
            problem,
            extra,
            u,
            1.0,
            max_iterations,
            &mut iterations,
            &mut history,
            self.factor_reuse,
        );
        let last = history.last().map_or(0.0, |h| h.relative_residual);
        let shifted_steps = history.iter().filter(|h| h.regularization > 0.0).count();
        let steps = history.iter().map(|h| h.step).collect();
        match result {
            Ok(rel) => ImproveReport {
                iterations,
                relative_residual: rel,
                converged: true,
                failure: None,
                shifted_steps,
                steps,
                budget_spent: false,
            },
            Err(f) => ImproveReport {
                iterations,
                relative_residual: last,
                converged: false,
                budget_spent: self.budget_stopped,
                failure: (f.outcome != Outcome::IterationCap).then_some((f.outcome, f.message)),
                shifted_steps,
                steps,
            },
        }
    }

    /// The refinement tolerance of single-precision factorisations in [`NewtonSolver::improve`]
    /// (`None`: f64), from [`NewtonSettings::mixed_precision`].
    fn single_precision(&self) -> Option<f64> {
        self.settings
            .mixed_precision
            .then_some(MIXED_PRECISION_TOLERANCE)
    }

    /// Gives the linear solver the grid's node coordinates (a nested-dissection ordering,
    /// computed once per grid) and drops buffers of another grid.
    fn prepare_for(&mut self, problem: &StaticProblem) {
        let key = (problem.grid.grid.dims, problem.grid.node_count());
        if self.ordered_for != Some(key) {
            self.linear = SparseSolver::new(self.settings.linear_solver)
                .with_node_coordinates(problem.grid.node_coords.clone());
            self.tangent = None;
            self.factor_age = None;
            self.has_factor = false;
            self.background = None;
            self.ordered_for = Some(key);
        }
    }

    /// Starting state of the increment to `target`: the secant extrapolation
    /// `u + (target − load)/(load − load_prev) · (u − u_prev)` of the last two converged states,
    /// when it is a valid state with lower potential than `u` at the new load; `u` otherwise.
    fn predict(
        &self,
        problem: &mut StaticProblem,
        extra: &[PenaltySprings],
        u: &[f64],
        load: f64,
        previous: Option<&(Vec<f64>, f64)>,
        target: f64,
    ) -> Vec<f64> {
        let Some((u_prev, load_prev)) = previous else {
            return u.to_vec();
        };
        let ratio = (target - load) / (load - load_prev);
        if !(ratio.is_finite() && ratio > 0.0) {
            return u.to_vec();
        }
        let guess: Vec<f64> = u
            .iter()
            .zip(u_prev)
            .map(|(a, b)| a + ratio * (a - b))
            .collect();
        let energy = |v: &[f64], p: &mut StaticProblem| {
            p.evaluate_with(v, target, extra, Need::Energy, None, None)
                .map(|e| e.potential)
        };
        match (energy(&guess, problem), energy(u, problem)) {
            (Ok(g), Ok(c)) if g.is_finite() && g < c => guess,
            _ => u.to_vec(),
        }
    }

    /// Newton iterations at load factor `load` starting from `u`; on success `u` holds the
    /// equilibrium and the final relative residual is returned.
    fn increment(
        &mut self,
        problem: &mut StaticProblem,
        extra: &[PenaltySprings],
        u: &mut [f64],
        load: f64,
        iterations: &mut usize,
        history: &mut Vec<IterationRecord>,
    ) -> Result<f64, StepFailure> {
        let cap = self.settings.max_iterations;
        self.factor_age = None;
        self.iterate(problem, extra, u, load, cap, iterations, history, 1)
    }

    /// At most `max_iterations` Newton iterations at load factor `load` from `u` (updated in
    /// place; every accepted step keeps it valid). `Ok(relative residual)` when converged.
    /// A factorisation serves at most `max_uses` steps (1: plain Newton); with more than one
    /// the factorised tangents get the cut-cell step stabilisation (a fresh factorisation
    /// used once is exact and needs none).
    ///
    /// Each iteration goes through named stages: [`NewtonSolver::residual_for_step`] (the
    /// residual, and the tangent unless a kept factorisation serves), the convergence tests,
    /// [`NewtonSolver::factorize_for_step`], [`NewtonSolver::newton_direction`],
    /// [`NewtonSolver::step_length`] (the line search) and [`NewtonSolver::take_step`].
    #[allow(clippy::too_many_arguments)]
    fn iterate(
        &mut self,
        problem: &mut StaticProblem,
        extra: &[PenaltySprings],
        u: &mut [f64],
        load: f64,
        max_iterations: usize,
        iterations: &mut usize,
        history: &mut Vec<IterationRecord>,
        max_uses: usize,
    ) -> Result<f64, StepFailure> {
        let mut k = self.tangent.take().unwrap_or_else(|| problem.new_tangent());
        let mut work = IterationWork::new(problem.dofs(), load * norm(&problem.external));
        let run = IterationRun {
            load,
            max_iterations,
            max_uses,
            stabilization: if max_uses > 1 {
                self.settings.step_stabilization
            } else {
                0.0
            },
        };
        let result = self.iterate_in(
            problem, extra, u, &run, &mut k, &mut work, iterations, history,
        );
        // The tangent's buffers (or the kept factorisation's matrix) serve the next call.
        self.tangent = Some(k);
        result
    }

    /// The loop of [`NewtonSolver::iterate`] with its buffers: `k` the tangent (or, while a
    /// kept factorisation serves, the matrix it factorised).
    #[allow(clippy::too_many_arguments)]
    fn iterate_in(
        &mut self,
        problem: &mut StaticProblem,
        extra: &[PenaltySprings],
        u: &mut [f64],
        run: &IterationRun,
        k: &mut SymmetricCsc,
        work: &mut IterationWork,
        iterations: &mut usize,
        history: &mut Vec<IterationRecord>,
    ) -> Result<f64, StepFailure> {
        let s = self.settings;
        for it in 0..run.max_iterations {
            let (potential, reuse) = self.residual_for_step(problem, extra, u, run, k, work)?;
            let rn = norm(&work.r);
            if !rn.is_finite() || !potential.is_finite() {
                return Err(StepFailure {
                    outcome: Outcome::Diverged,
                    message: "non-finite residual".into(),
                });
            }
            if it == 0 {
                work.reference = rn.max(work.external_norm).max(f64::MIN_POSITIVE);
            }
            let rel = rn / work.reference;
            // A state already exact to round-off (e.g. a noise-free cloud of the rest
            // shape: every data spring's gap is 1e-17 m) is converged, whatever its
            // relative residual: no step can lower a residual made of round-off, and the
            // line search would call that divergence.
            if rel <= s.residual_tolerance || rn <= work.round_off {
                return Ok(rel);
            }
            if rel > 1e8 {
                return Err(StepFailure {
                    outcome: Outcome::Diverged,
                    message: format!("residual grew to {rel:.3e} times its initial value"),
                });
            }
            let regularization = if reuse {
                *iterations += 1;
                0.0
            } else {
                match &mut self.factorization_budget {
                    Some(0) => {
                        self.budget_stopped = true;
                        return Err(StepFailure {
                            outcome: Outcome::IterationCap,
                            message: FACTORIZATION_BUDGET_SPENT.into(),
                        });
                    }
                    Some(left) => *left -= 1,
                    None => {}
                }
                *iterations += 1;
                self.factorize_for_step(k, extra)?
            };
            let stats = self.newton_direction(k, work)?;
            let Some(alpha) =
                self.step_length(problem, extra, u, run, reuse, potential, rn, work)?
            else {
                // The kept factorisation was too stale for any step: retry with a fresh one.
                continue;
            };
            history.push(IterationRecord {
                load: run.load,
                relative_residual: rel,
                step: alpha,
                linear_method: stats.method,
                regularization,
            });
            if self.take_step(u, alpha, run, work) {
                // Converged in displacement; report the residual of the new state.
                problem.evaluate_with(u, run.load, extra, Need::Force, Some(&mut work.r), None)?;
                return Ok(norm(&work.r) / work.reference);
            }
        }
        Err(StepFailure {
            outcome: Outcome::IterationCap,
            message: format!("no convergence in {} Newton iterations", run.max_iterations),
        })
    }

    /// The residual at `u` into `work.r` and the potential energy (J), and whether the step
    /// reuses the kept factorisation (`k` stays the matrix it factorised, which the direct
    /// solver refines against, so only the residual is evaluated). Otherwise the tangent is
    /// assembled into `k` with the cut-cell stabilisation of `run`, and the round-off
    /// residual is updated: the tangent's largest diagonal entry (N/m) times
    /// [`ROUND_OFF_DISPLACEMENT`], the residual (N) at which the state is exact to round-off.
    /// With several uses per factorisation, the helper thread's factorisation is swapped in
    /// when due, or asked for when the kept one has served its steps.
    fn residual_for_step(
        &mut self,
        problem: &mut StaticProblem,
        extra: &[PenaltySprings],
        u: &[f64],
        run: &IterationRun,
        k: &mut SymmetricCsc,
        work: &mut IterationWork,
    ) -> Result<(f64, bool), StepFailure> {
        if run.max_uses > 1 {
            self.swap_in_background_factor(k);
        }
        let mut reuse = self.factor_age.is_some_and(|a| a < run.max_uses);
        if !reuse
            && run.max_uses > 1
            && self.has_factor
            && self.request_background(problem, extra, u, run.load)
        {
            // The old factorisation serves until the new one is due.
            reuse = true;
        }
        if reuse {
            let e =
                problem.evaluate_with(u, run.load, extra, Need::Force, Some(&mut work.r), None)?;
            return Ok((e.potential, true));
        }
        let need = if self.settings.projected_tangent {
            Need::ProjectedTangent
        } else {
            Need::Tangent
        };
        let e = problem.evaluate_with(u, run.load, extra, need, Some(&mut work.r), Some(k))?;
        problem.add_cut_cell_stabilization(run.stabilization, k);
        work.round_off =
            ROUND_OFF_DISPLACEMENT * k.diagonal().iter().fold(0.0f64, |m, d| m.max(d.abs()));
        Ok((e.potential, false))
    }

    /// Factorises the freshly assembled tangent `k` (with the `extra` springs it includes)
    /// and makes it the kept factorisation; returns the diagonal shift τ it needed
    /// ([`NewtonSolver::factorize_descent`]).
    fn factorize_for_step(
        &mut self,
        k: &mut SymmetricCsc,
        extra: &[PenaltySprings],
    ) -> Result<f64, StepFailure> {
        self.factor_age = None;
        let tau = self.factorize_descent(k)?;
        self.factor_age = Some(0);
        self.has_factor = true;
        self.factored_with.clear();
        self.factored_with.extend_from_slice(extra);
        Ok(tau)
    }

    /// The Newton direction `work.du = −K⁻¹ R` (m) through the factorisation of `k`.
    fn newton_direction(
        &mut self,
        k: &SymmetricCsc,
        work: &mut IterationWork,
    ) -> Result<SolveStats, StepFailure> {
        for v in work.r.iter_mut() {
            *v = -*v;
        }
        let stats = self.linear.solve(k, &work.r, &mut work.du)?;
        for v in work.r.iter_mut() {
            *v = -*v;
        }
        Ok(stats)
    }

    /// The step length along `work.du` ([`NewtonSolver::line_search`], or 1 without one).
    /// `None` when a kept factorisation's direction admits no step: the factorisation is
    /// dropped (and a pending helper request cancelled) so that the next try refactorises.
    #[allow(clippy::too_many_arguments)]
    fn step_length(
        &mut self,
        problem: &mut StaticProblem,
        extra: &[PenaltySprings],
        u: &[f64],
        run: &IterationRun,
        reuse: bool,
        potential: f64,
        residual_norm: f64,
        work: &mut IterationWork,
    ) -> Result<Option<f64>, StepFailure> {
        if !self.settings.line_search {
            return Ok(Some(1.0));
        }
        // Modified Newton evaluates the residual at the accepted state next: assemble the
        // force already in the line search, so the problem's body cache serves it.
        let with_force = run.max_uses > 1;
        match self.line_search(
            problem,
            extra,
            u,
            &work.du,
            &work.r,
            potential,
            residual_norm,
            run.load,
            with_force,
            &mut work.trial,
        ) {
            Ok(a) => Ok(Some(a)),
            Err(_) if reuse => {
                self.factor_age = None;
                self.has_factor = false;
                if let Some(bg) = self.background.as_mut() {
                    bg.cancel();
                }
                Ok(None)
            }
            Err(f) => Err(f),
        }
    }

    /// Moves `u` by `alpha` times the direction `work.du` and ages the kept factorisation (a
    /// step shortened below ½ drops it). `true` when a full step was smaller than the
    /// displacement tolerance: converged in displacement.
    fn take_step(
        &mut self,
        u: &mut [f64],
        alpha: f64,
        run: &IterationRun,
        work: &IterationWork,
    ) -> bool {
        self.factor_age = match self.factor_age {
            Some(a) if alpha >= 0.5 => Some(a + 1),
            _ => None,
        };
        if run.max_uses > 1 {
            self.improve_steps += 1;
        }
        // The same sums as the line search's trial, so the body cache matches bit for bit.
        for (ui, di) in u.iter_mut().zip(&work.du) {
            *ui += alpha * di;
        }
        let dn = alpha * norm(&work.du);
        alpha == 1.0 && dn <= self.settings.displacement_tolerance * norm(u)
    }

    /// Swaps in the helper's factorisation when it is due at this step (`k` becomes the matrix
    /// it factorised); a failed one leaves no usable factorisation, so the step refactorises.
    fn swap_in_background_factor(&mut self, k: &mut SymmetricCsc) {
        let Some(bg) = self.background.as_mut() else {
            return;
        };
        match bg.take_due(self.improve_steps) {
            Some(Ok(made)) => {
                let f = made.factored;
                let old = Factored {
                    linear: std::mem::replace(&mut self.linear, f.linear),
                    matrix: std::mem::replace(k, f.matrix),
                };
                self.factored_with = made.extra;
                bg.give_back(old);
                self.factorizations += 1;
                self.helper_factorizations += 1;
                self.factor_age = Some(0);
                self.has_factor = true;
            }
            Some(Err(_)) => {
                self.factor_age = None;
                self.has_factor = false;
            }
            None => {}
        }
    }

    /// Asks the helper (started on first use) to refactorise at `u` with the `extra` springs;
    /// `false` when background refactorisation is off or unavailable.
    fn request_background(
        &mut self,
        problem: &StaticProblem,
        extra: &[PenaltySprings],
        u: &[f64],
        load: f64,
    ) -> bool {
        if self.background_lag == 0 {
            return false;
        }
        if self.background.is_none() {
            self.background = BackgroundFactorizer::spawn(
                problem,
                self.settings.linear_solver,
                problem.grid.node_coords.clone(),
                self.background_lag,
                self.single_precision(),
                self.settings.step_stabilization,
            );
        }
        let step = self.improve_steps;
        match self.background.as_mut() {
            Some(bg) => bg.request(u, load, extra, step),
            None => false,
        }
    }

    /// Factorises the tangent. Far from equilibrium the tangent can be indefinite, and its
    /// Newton step then need not lower the energy; unless the LDLᵀ solver was asked for
    /// explicitly, the diagonal is then raised to `(1 + τ) K_ii` with τ = 10⁻³, 10⁻², … 10³
    /// (Levenberg–Marquardt) until the Cholesky factorisation succeeds, which makes the step a
    /// descent direction. Near equilibrium the tangent is positive definite and the iteration is
    /// plain Newton, with its quadratic convergence. Returns the shift τ used (0 when none).
    ///
    /// Every attempt but the last asks for Cholesky alone
    /// ([`SparseSolver::factorize_if_positive_definite`]): the Bunch–Kaufman factorisation of
    /// a matrix about to be shifted would be thrown away. An LDLᵀ solver asked for explicitly
    /// factorises any matrix there, unshifted.
    fn factorize_descent(&mut self, k: &mut SymmetricCsc) -> Result<f64, LinalgError> {
        self.factorizations += 1;
        if self.linear.factorize_if_positive_definite(k)? {
            self.last_shift /= 10.0;
            return Ok(0.0);
        }
        let diag: Vec<usize> = (0..k.n)
            .map(|i| k.position(i, i).expect("diagonal stored"))
            .collect();
        let original: Vec<f64> = diag.iter().map(|&p| k.values[p]).collect();
        // Start one decade below the shift that worked last time (neighbouring states of one
        // solve tend to need similar shifts): fewer refactorisations.
        let mut tau = (self.last_shift / 10.0).clamp(1e-3, 1e2);
        const SHIFTS: usize = 7;
        for attempt in 1..=SHIFTS {
            for (&p, &d) in diag.iter().zip(&original) {
                k.values[p] = d + tau * d.abs();
            }
            self.factorizations += 1;
            let definite = if attempt < SHIFTS {
                self.linear.factorize_if_positive_definite(k)?
            } else {
                self.linear.factorize(k)?;
                !self.linear.fell_back_to_indefinite()
            };
            if definite {
                self.last_shift = tau;
                return Ok(tau);
            }
            tau *= 10.0;
        }
        // Still indefinite: keep the LBLᵀ factorisation of the last shifted matrix.
        Ok(tau / 10.0)
    }

    /// Backtracking on the potential energy (Armijo), falling back to the residual norm when
    /// the step is not a descent direction (indefinite tangent). Returns the step length.
    /// With `with_force` the trial states' residuals are assembled too (a little dearer than
    /// the energy alone), which leaves the accepted state's cell forces in the problem's cache.
    #[allow(clippy::too_many_arguments)]
    fn line_search(
        &self,
        problem: &mut StaticProblem,
        extra: &[PenaltySprings],
        u: &[f64],
        du: &[f64],
        r: &[f64],
        potential: f64,
        r_norm: f64,
        load: f64,
        with_force: bool,
        trial: &mut [f64],
    ) -> Result<f64, StepFailure> {
        let slope: f64 = r.iter().zip(du).map(|(a, b)| a * b).sum();
        let descent = slope < 0.0;
        let mut alpha = 1.0;
        let mut last_failure: Option<StepFailure> = None;
        let mut scratch = vec![0.0; if descent && !with_force { 0 } else { r.len() }];
        let energy_need = if with_force {
            Need::Force
        } else {
            Need::Energy
        };
        for _ in 0..12 {
            for ((t, ui), di) in trial.iter_mut().zip(u).zip(du) {
                *t = ui + alpha * di;
            }
            let accepted = if descent {
                let residual = with_force.then_some(&mut scratch[..]);
                match problem.evaluate_with(trial, load, extra, energy_need, residual, None) {
                    Ok(e) => {
                        let tol = 1e-12 * (potential.abs() + 1e-300);
                        e.potential.is_finite()
                            && e.potential <= potential + 1e-4 * alpha * slope + tol
                    }
                    Err(f) => {
                        last_failure = Some(f.into());
                        false
                    }
                }
            } else {
                match problem.evaluate_with(
                    trial,
                    load,
                    extra,
                    Need::Force,
                    Some(&mut scratch),
                    None,
                ) {
                    Ok(_) => norm(&scratch) < r_norm,
                    Err(f) => {
                        last_failure = Some(f.into());
                        false
                    }
                }
            };
            if accepted {
                return Ok(alpha);
            }
            alpha *= 0.5;
        }
        Err(last_failure.unwrap_or(StepFailure {
            outcome: Outcome::Diverged,
            message: "line search found no decrease".into(),
        }))
    }
}

/// A residual (N) below this displacement (m) times the tangent's largest stiffness (N/m)
/// is round-off: the state is exact to within a picometre, far below any registration's
/// accuracy, and Newton's method cannot improve it.
pub(crate) const ROUND_OFF_DISPLACEMENT: f64 = 1e-12;

/// Euclidean norm.
pub(crate) fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}
