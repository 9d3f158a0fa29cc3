//! Refactorisation of the tangent on a helper thread, for modified Newton.
//!
//! A warm registration frame reuses one factorisation of the tangent over several steps
//! (modified Newton); when it has served its steps, or a line search had to shorten a step,
//! a fresh one is due. Assembling and factorising the projected tangent costs as much as 5–7
//! modified-Newton steps on a 1,500-node grid, so instead of stopping for it the solver asks
//! this helper for it, goes on with the old factorisation, and swaps the new one in a fixed
//! number of steps later ([`BackgroundFactorizer::lag`]), waiting for it then if it is not
//! ready. The swap point depends only on the step count and the new factorisation only on
//! the state it was asked for, so results do not depend on thread timing: a replayed session
//! gives the same numbers.

use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;

use super::cell_kernel::Need;
use super::penalty::PenaltySprings;
use super::static_problem::StaticProblem;
use crate::linalg::{SolverKind, SparseSolver, SymmetricCsc};

/// A linear solver holding a factorisation and the matrix it factorised (solves refine
/// against it).
pub(crate) struct Factored {
    /// Solver with the numeric factorisation.
    pub linear: SparseSolver,
    /// The factorised matrix, N/m.
    pub matrix: SymmetricCsc,
}

/// A factorisation the helper made, and the extra spring sets (beyond the problem's own) whose
/// stiffness its tangent includes.
pub(crate) struct Made {
    /// The factorisation and its matrix.
    pub factored: Factored,
    /// The extra springs of the request (N/m), as given to [`BackgroundFactorizer::request`].
    pub extra: Vec<PenaltySprings>,
}

/// What the helper is asked to factorise: the projected tangent at `u` (m) and `load` with
/// the problem's own springs and these extra spring sets.
struct Job {
    u: Vec<f64>,
    load: f64,
    extra: Vec<PenaltySprings>,
    /// Buffers to factorise into (a solver with its symbolic analysis, and a matrix of the
    /// tangent's pattern), when the caller has spare ones.
    spare: Option<Factored>,
}

/// The helper's answer: the factorisation, or why there is none.
type Answer = Result<Made, String>;

/// A helper thread that assembles and factorises the projected tangent of one problem.
pub(crate) struct BackgroundFactorizer {
    jobs: Option<Sender<Job>>,
    answers: Receiver<Answer>,
    thread: Option<JoinHandle<()>>,
    /// Step count at which the pending job's factorisation is to be swapped in.
    due: Option<usize>,
    lag: usize,
    /// Spare buffers returned by the last swap.
    spare: Option<Factored>,
}

impl BackgroundFactorizer {
    /// Starts a helper with its own copy of `problem` (grid, material, loads and its own
    /// springs, as they are now: the helper does not see later changes to `problem`; the extra
    /// springs come with each request) and a `kind` solver ordered with `node_coords`; a requested
    /// factorisation is swapped in `lag` steps after the request; `single_precision` as in
    /// [`SparseSolver::set_single_precision`]; the tangents get the cut-cell step
    /// stabilisation of coefficient `stabilization`
    /// ([`StaticProblem::add_cut_cell_stabilization`]). `None` when the thread cannot be
    /// started (the caller then factorises itself).
    pub(crate) fn spawn(
        problem: &StaticProblem,
        kind: SolverKind,
        node_coords: Vec<[usize; 3]>,
        lag: usize,
        single_precision: Option<f64>,
        stabilization: f64,
    ) -> Option<Self> {
        let mut own = problem.clone();
        let (job_tx, job_rx) = channel::<Job>();
        let (ans_tx, ans_rx) = channel::<Answer>();
        let thread = std::thread::Builder::new()
            .name("livereg-factorize".into())
            .spawn(move || {
                while let Ok(job) = job_rx.recv() {
                    let Job {
                        u,
                        load,
                        extra,
                        spare,
                    } = job;
                    let Factored {
                        mut linear,
                        mut matrix,
                    } = spare.unwrap_or_else(|| Factored {
                        linear: SparseSolver::new(kind).with_node_coordinates(node_coords.clone()),
                        matrix: own.new_tangent(),
                    });
                    linear.set_single_precision(single_precision);
                    let answer = own
                        .evaluate_with(
                            &u,
                            load,
                            &extra,
                            Need::ProjectedTangent,
                            None,
                            Some(&mut matrix),
                        )
                        .map(|_| own.add_cut_cell_stabilization(stabilization, &mut matrix))
                        .map_err(|f| format!("cell {}: {}", f.cell, f.error))
                        .and_then(|_| {
                            linear
                                .factorize_if_positive_definite(&matrix)
                                .map_err(|e| e.to_string())
                        })
                        .and_then(|definite| {
                            if !definite {
                                Err("the projected tangent was not positive definite".into())
                            } else {
                                Ok(Made {
                                    factored: Factored { linear, matrix },
                                    extra,
                                })
                            }
                        });
                    if ans_tx.send(answer).is_err() {
                        break;
                    }
                }
            })
            .ok()?;
        Some(Self {
            jobs: Some(job_tx),
            answers: ans_rx,
            thread: Some(thread),
            due: None,
            lag: lag.max(1),
            spare: None,
        })
    }

    /// Steps between a request and the swap of its factorisation.
    pub(crate) fn lag(&self) -> usize {
        self.lag
    }

    /// Whether a requested factorisation has not been swapped in yet.
    pub(crate) fn pending(&self) -> bool {
        self.due.is_some()
    }

    /// Asks for the projected tangent at `u` (m), `load` with the problem's own springs and
    /// the `extra` spring sets (N/m) to be factorised, to be swapped in at step `step + lag`.
    /// Ignored while another request is pending. `false` when the helper has gone (the caller
    /// factorises itself).
    pub(crate) fn request(
        &mut self,
        u: &[f64],
        load: f64,
        extra: &[PenaltySprings],
        step: usize,
    ) -> bool {
        if self.due.is_some() {
            return true;
        }
        let Some(tx) = &self.jobs else {
            return false;
        };
        let job = Job {
            u: u.to_vec(),
            load,
            extra: extra.to_vec(),
            spare: self.spare.take(),
        };
        if tx.send(job).is_err() {
            self.jobs = None;
            return false;
        }
        self.due = Some(step + self.lag);
        true
    }

    /// At step `step`: the requested factorisation when it is due (waiting for it if the
    /// helper is still at work), with the extra springs it was asked with; `None` before.
    /// `Some(Err)` when the helper failed or is gone.
    pub(crate) fn take_due(&mut self, step: usize) -> Option<Result<Made, String>> {
        if self.due.is_none_or(|d| step < d) {
            return None;
        }
        self.due = None;
        Some(match self.answers.recv() {
            Ok(answer) => answer,
            Err(_) => {
                self.jobs = None;
                Err("the factorisation thread ended".into())
            }
        })
    }

    /// Drops a pending request (its answer is awaited and discarded, so the next one is
    /// not confused with it).
    pub(crate) fn cancel(&mut self) {
        if self.due.take().is_some() {
            if let Ok(Ok(made)) = self.answers.recv() {
                self.spare = Some(made.factored);
            }
        }
    }

    /// Keeps `f` (a factorisation no longer in use) as buffers for the next request.
    pub(crate) fn give_back(&mut self, f: Factored) {
        self.spare = Some(f);
    }
}

impl Drop for BackgroundFactorizer {
    fn drop(&mut self) {
        // Closing the job channel ends the helper after its current job.
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
