//! `livereg eval --results FILE --truth FILE`: target registration error.

use std::path::Path;

use crate::evaluation::{evaluate, read_results, read_truth};

/// Evaluates and prints the table (or the JSON report with `json`).
pub fn run(results: &Path, truth: &Path, json: bool) -> Result<(), String> {
    let r = read_results(results).map_err(|e| e.to_string())?;
    let t = read_truth(truth).map_err(|e| e.to_string())?;
    let report = evaluate(&r, &t)
        .map_err(|e| format!("{} against {}: {e}", results.display(), truth.display()))?;
    if json {
        println!(
            "{}",
            serde_json::to_string(&report).map_err(|e| e.to_string())?
        );
    } else {
        print!("{}", report.to_table());
    }
    Ok(())
}
