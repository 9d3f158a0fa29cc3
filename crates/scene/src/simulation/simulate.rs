//! `livereg simulate`: forward static simulation of a scene.

use std::path::Path;
use std::time::Instant;

use super::model::{build_model, ModelError};
use crate::mechanics::{NewtonSolver, Outcome};
use crate::scene::{GridSummary, LoadedScene, ProbeResult, SimulateReport};

/// Errors of a simulation run (the solve itself never errors: its failures are in the report).
#[derive(Debug, thiserror::Error)]
pub enum SimulateError {
    /// The scene could not be turned into a model.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// Writing an output failed.
    #[error("{path}: {message}")]
    Output {
        /// The file or directory.
        path: String,
        /// Why.
        message: String,
    },
}

/// Builds the scene's model, solves it and returns the contract's report; writes the deformed
/// surface to `out_dir/deformed.obj` when given.
pub fn simulate_scene(
    loaded: &LoadedScene,
    out_dir: Option<&Path>,
) -> Result<SimulateReport, SimulateError> {
    let start = Instant::now();
    let (mut model, surface_report) = build_model(loaded)?;
    let mut solver = NewtonSolver::new(model.newton);
    let u0 = vec![0.0; model.problem.dofs()];
    let result = solver.solve(&mut model.problem, &[], &u0);
    let scale = model.length_scale;
    let probes = model
        .probes
        .rest
        .iter()
        .zip(model.probes.interpolate(&result.u))
        .map(|(x, d)| ProbeResult {
            point: (x.coords / scale).into(),
            displacement: (d / scale).into(),
        })
        .collect();
    let max_displacement = model
        .surface_embedding
        .interpolate(&result.u)
        .iter()
        .map(|d| d.norm() / scale)
        .fold(0.0, f64::max);
    if let Some(dir) = out_dir {
        let out_err = |path: &Path, e: &dyn std::fmt::Display| SimulateError::Output {
            path: path.display().to_string(),
            message: e.to_string(),
        };
        std::fs::create_dir_all(dir).map_err(|e| out_err(dir, &e))?;
        let path = dir.join("deformed.obj");
        crate::mesh::write_obj(&path, &model.deformed_surface(&result.u))
            .map_err(|e| out_err(&path, &e))?;
    }
    let stats = model.problem.grid.stats();
    let mut message = result.message.clone();
    if !surface_report.watertight {
        let note = format!("surface is not watertight: {}", surface_report);
        message = Some(match message {
            Some(m) => format!("{m}; {note}"),
            None => note,
        });
    }
    Ok(SimulateReport {
        converged: result.outcome == Outcome::Converged,
        newton_iterations: result.newton_iterations,
        load_steps: result.load_steps,
        wall_ms: start.elapsed().as_secs_f64() * 1e3,
        grid: GridSummary {
            nodes: stats.nodes,
            cells: stats.cells,
            cut_cells: stats.cut_cells,
        },
        probes,
        max_displacement,
        outcome: result.outcome.name().to_string(),
        message,
        bisections: result.bisections,
    })
}
