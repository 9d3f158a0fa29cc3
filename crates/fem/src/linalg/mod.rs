//! Sparse symmetric linear algebra for the Newton–Raphson solver.
//!
//! Every Newton iteration of the nonlinear finite-element model solves
//! `K δu = r`, where `K` is the (symmetric) tangent stiffness matrix with
//! three degrees of freedom per node and a sparsity pattern that is fixed per
//! grid. This module provides:
//!
//! * [`SymmetricCsc`]: the lower triangle of `K` in compressed sparse column
//!   form, with a pattern fingerprint ([`SymmetricCsc::pattern_id`]) so that
//!   the symbolic analysis of a direct solver can be reused across Newton
//!   iterations;
//! * [`SparseSolver`]: a solver front-end that factorises (sparse supernodal
//!   Cholesky `LLᵀ`, falling back to an intranodal Bunch–Kaufman `LBLᵀ` for
//!   indefinite matrices) or runs a Jacobi-preconditioned conjugate gradient,
//!   selected by [`SolverKind`];
//! * [`nested_dissection()`]: a geometric nested-dissection fill-reducing
//!   ordering for grid nodes, used by the direct solvers when given node
//!   coordinates ([`SparseSolver::with_node_coordinates`]);
//! * [`testing`]: a small generator of linear-elasticity grid matrices used by
//!   the tests and the benchmarks.
//!
//! All results are independent of the number of rayon threads up to rounding
//! (the conjugate gradient is even bitwise reproducible: its reductions use a
//! fixed, thread-count independent blocking).

#![warn(missing_docs)]

mod cg;
mod csc;
mod nested_dissection;
mod solver;
pub mod testing;

#[cfg(test)]
mod tests;

pub use csc::SymmetricCsc;
pub use nested_dissection::{
    expand_node_permutation, inverse_permutation, nested_dissection,
    nested_dissection_with_leaf_size, ND_LEAF_NODES,
};
pub use solver::{
    predicted_factor_len, SolveStats, SolverKind, SparseSolver, AUTO_DIRECT_MAX_DOFS,
};

/// Errors reported by the sparse linear algebra layer.
#[derive(thiserror::Error, Debug, Clone, PartialEq)]
pub enum LinalgError {
    /// The matrix is not positive definite: a Cholesky pivot (when no
    /// indefinite fallback is possible), a negative diagonal entry for the
    /// Jacobi preconditioner, or a conjugate-gradient curvature `pᵀKp ≤ 0`.
    #[error("matrix is not positive definite")]
    NotPositiveDefinite,
    /// The matrix is (numerically exactly) singular: a zero pivot in the
    /// factorisation or a zero diagonal entry for the Jacobi preconditioner.
    #[error("matrix is singular")]
    Singular,
    /// The iterative solver hit its iteration cap before reaching the
    /// requested relative residual `‖b − Kx‖ / ‖b‖`.
    #[error("iterative solver did not converge after {iterations} iterations (relative residual {relative_residual:e})")]
    NotConverged {
        /// Number of iterations performed.
        iterations: usize,
        /// Achieved relative residual `‖b − Kx‖₂ / ‖b‖₂`.
        relative_residual: f64,
    },
    /// A NaN or infinity appeared in the input matrix, the right-hand side or
    /// the computed solution.
    #[error("non-finite value (NaN or infinity) in matrix, right-hand side or solution")]
    NonFinite,
    /// The sparsity pattern violates the [`SymmetricCsc`] invariants, or a
    /// matrix/vector has a dimension or pattern inconsistent with the solver
    /// state. The message says which.
    #[error("invalid sparse pattern: {0}")]
    InvalidPattern(String),
    /// `solve` was called before a successful `factorize`.
    #[error("solve called before a successful factorize")]
    NotFactorized,
    /// An error reported by faer (allocation failure, index overflow).
    #[error("faer error: {0}")]
    Faer(String),
}
