//! `livereg simulate SCENE [--out DIR]`.

use std::path::Path;

use crate::scene::load_scene;
use crate::simulation::simulate_scene;

/// Simulates the scene, prints the report's JSON on stdout; an unconverged solve is an error.
pub fn run(scene: &Path, out: Option<&Path>) -> Result<(), String> {
    let loaded = load_scene(scene).map_err(|e| e.to_string())?;
    let report = simulate_scene(&loaded, out).map_err(|e| e.to_string())?;
    println!("{}", report.to_json());
    if report.converged {
        Ok(())
    } else {
        Err(format!(
            "simulation did not converge ({}): {}",
            report.outcome,
            report.message.as_deref().unwrap_or("no detail")
        ))
    }
}
