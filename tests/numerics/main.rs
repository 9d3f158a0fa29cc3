//! The numerics through the public API, one module per subject: patch tests, manufactured
//! solutions, the thesis's cylinder experiments, tangents against finite differences,
//! volumetric locking, the static solver's failure handling, and results independent of the
//! number of threads.
//!
//! One test binary of a few (`tests/*/main.rs`, helpers in `tests/common`); one subject alone:
//! `cargo test --test numerics patch_test::`.

#[path = "../common/mod.rs"]
mod common;

mod cylinder;
mod determinism;
mod ligament_hold;
mod manufactured_solutions;
mod newton_robustness;
mod patch_test;
mod tangent_consistency;
mod volumetric_locking;
