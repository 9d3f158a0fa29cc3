//! Mechanics: hexahedral element kernels (the trilinear shape functions are the grid's,
//! [`crate::grid::hex8`]), hyperelastic materials, assembly, loads, penalty springs and the
//! static Newton solver (thesis ch. 2 and §4.6–4.7).

pub mod assembly;
pub mod background_factorization;
pub mod cell_kernel;
pub mod cut_cell_stabilization;
pub mod loads;
pub mod material;
pub mod newton;
pub mod penalty;
pub mod static_problem;
#[cfg(any(test, feature = "test-fixtures"))]
pub mod test_fixtures;

pub use assembly::Assembler;
pub use cell_kernel::{Need, VolumetricIntegration};
pub use material::{LawKind, Material, MaterialError, Part};
pub use newton::{
    ImproveReport, IterationRecord, NewtonSettings, NewtonSolver, Outcome, SolveReport,
};
pub use penalty::PenaltySprings;
pub use static_problem::StaticProblem;
