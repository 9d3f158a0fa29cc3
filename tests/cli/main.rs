//! The `livereg` binary as users and scripts run it, one module per subject: malformed input,
//! `register` and `eval`, recordings and `replay`, `bench` (the sweep, calibration, the
//! stability matrices, indentation and force truths), and VTK files read and written beside
//! the `vtk` Python package.
//!
//! One test binary of a few (`tests/*/main.rs`, helpers in `tests/common` and
//! `recording_case.rs`); one subject alone: `cargo test --test cli register_cli::`.

#[path = "../common/mod.rs"]
mod common;
mod recording_case;

mod bench_cli;
mod bench_indentation_cli;
mod cli;
mod recording_cli;
mod register_cli;
mod replay_cli;
mod vtk_files;
