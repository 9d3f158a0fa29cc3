//! Outputs for evaluation: the `results.jsonl` and truth line formats, and target
//! registration error (TRE) per frame, per structure and in summary.

pub mod records;

pub use records::{DiagnosticsRecord, ResultRecord, RigidRecord, TruthRecord};
