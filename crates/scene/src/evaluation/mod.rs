//! Outputs for evaluation: the `results.jsonl` and truth line formats, and target
//! registration error (TRE) per frame, per structure and in summary.

pub(crate) mod error;
pub(crate) mod jsonl;
pub(crate) mod records;
pub(crate) mod tre;

pub use error::EvalError;
pub use jsonl::{read_jsonl, read_results, read_truth, JsonlWriter};
pub use records::{
    present_or_null, ContactForceRecord, DiagnosticsRecord, ErrorPartsRecord, ResultRecord,
    RigidRecord, TruthRecord,
};
pub use tre::{evaluate, percentile, EvalReport, FrameReport, StructureFrameTre, Summary};

#[cfg(test)]
mod tests;
