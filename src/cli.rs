//! The `livereg` command line (contract: "Binary").

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use crate::scene::load_scene;
use crate::simulation::simulate_scene;

/// Biomechanical registration of a deforming liver for surgical augmented reality.
#[derive(Debug, Parser)]
#[command(name = "livereg", version, about, long_about = None)]
pub struct Cli {
    /// The command to run.
    #[command(subcommand)]
    pub command: Command,
}

/// The commands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Forward static simulation of a scene: prints one JSON object (converged, iterations,
    /// grid size, probe displacements, max displacement) on stdout.
    Simulate {
        /// The scene file (TOML, or JSON with the same structure).
        scene: PathBuf,
        /// Directory to write the deformed surface to (`deformed.obj`, scene units).
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

/// Runs the command line; errors are printed as one line on stderr with a non-zero exit code.
pub fn run(cli: Cli) -> ExitCode {
    let result: Result<(), String> = match cli.command {
        Command::Simulate { scene, out } => (|| {
            let loaded = load_scene(&scene).map_err(|e| e.to_string())?;
            let report = simulate_scene(&loaded, out.as_deref()).map_err(|e| e.to_string())?;
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
        })(),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("livereg: {}", message.replace('\n', " "));
            ExitCode::FAILURE
        }
    }
}
