//! Mechanics: hexahedral element kernels (the trilinear shape functions are the grid's,
//! [`crate::grid::hex8`]), hyperelastic materials, assembly, loads, penalty springs and the
//! static Newton solver (thesis ch. 2 and §4.6–4.7).

pub(crate) mod assembly;
pub(crate) mod background_factorization;
pub(crate) mod cell_kernel;
pub(crate) mod cut_cell_stabilization;
pub mod loads;
pub mod material;
pub(crate) mod newton;
pub(crate) mod penalty;
pub(crate) mod static_problem;
#[cfg(any(test, feature = "test-fixtures"))]
pub mod test_fixtures;

pub use assembly::{Assembler, CellFailure};
pub use cell_kernel::{Need, VolumetricIntegration};
pub use material::{LawKind, Material, MaterialError, Part};
pub use newton::{
    ImproveReport, IterationRecord, NewtonSettings, NewtonSolver, Outcome, SolveReport,
    MIXED_PRECISION_TOLERANCE,
};
pub use penalty::PenaltySprings;
pub use static_problem::{Evaluation, StaticProblem};
