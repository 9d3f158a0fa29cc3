//! Computes the reference solution of the thesis's cylinder bending (a much finer finite-cell
//! solve) and writes `fixtures/reference/cylinder_bending.json`, which `tests/numerics/cylinder.rs`
//! compares coarse weighted-cell and finite-cell solves against.
//!
//! Run: `cargo run --release --example cylinder_reference -- [CELL_SIZE_M] [LEVELS]`
//! (defaults 0.00625 m and 3 levels: 16 cells across the diameter).

use std::time::Instant;

use livereg::grid::IntegrationMode;
use livereg::scenarios::CylinderBending;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let cell_size: f64 = args
        .get(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(0.00625);
    let levels: u32 = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(3);
    let start = Instant::now();
    let r = CylinderBending {
        cell_size,
        levels,
        mode: IntegrationMode::FiniteCell,
    }
    .solve();
    let wall_s = start.elapsed().as_secs_f64();
    eprintln!(
        "{:?} after {} Newton iterations, {} nodes, {wall_s:.1} s",
        r.report.outcome, r.report.newton_iterations, r.nodes
    );
    let json = serde_json::json!({
        "description": "Thesis §4.6 cylinder bending (neo-Hookean, E = 5000 Pa, nu = 0.3, radius 5 cm, length 60 cm, base held, 30 Pa downward end traction): displacements (m) of CylinderBending::samples() from a much finer finite-cell solve",
        "command": format!("cargo run --release --example cylinder_reference -- {cell_size} {levels}"),
        "cell_size": cell_size,
        "levels": levels,
        "mode": "finite-cell",
        "outcome": r.report.outcome.name(),
        "nodes": r.nodes,
        "newton_iterations": r.report.newton_iterations,
        "wall_s": wall_s,
        "samples": r.samples.iter().map(|p| [p.x, p.y, p.z]).collect::<Vec<_>>(),
        "displacements": r.displacements.iter().map(|d| [d.x, d.y, d.z]).collect::<Vec<_>>(),
    });
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/reference");
    std::fs::create_dir_all(&dir)?;
    std::fs::write(
        dir.join("cylinder_bending.json"),
        serde_json::to_string_pretty(&json)? + "\n",
    )?;
    Ok(())
}
