//! The `livereg` command line (contract: "Binary"): one file per command.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod demo;
pub mod eval;
pub mod progress;
pub mod register;
pub mod simulate;

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
    /// Registers a sequence of point clouds to the scene's model, frame after frame with warm
    /// start; writes DIR/results.jsonl (one line per frame, scene units, cloud frame).
    Register {
        /// The scene file.
        scene: PathBuf,
        /// A directory of point files (.xyz .txt .csv .ply), taken in lexical order of name.
        #[arg(long)]
        frames: PathBuf,
        /// Output directory (created); default `./register-out`.
        #[arg(long, default_value = "register-out")]
        out: PathBuf,
        /// Per-frame time budget, ms (overrides the scene's `registration.time_budget_ms`).
        #[arg(long)]
        budget_ms: Option<f64>,
        /// Rigid registration only (the baseline), no biomechanical stage.
        #[arg(long)]
        rigid_only: bool,
    },
    /// Target registration error of a results.jsonl against a truth file: per frame, per
    /// structure, and a summary (mean, median, p95, max), in the files' units.
    Eval {
        /// The results (`livereg register` output).
        #[arg(long)]
        results: PathBuf,
        /// The truth (`frame` and `structures` per line).
        #[arg(long)]
        truth: PathBuf,
        /// Print the full report as one JSON object instead of the table.
        #[arg(long)]
        json: bool,
    },
    /// End to end on the bundled liver phantom: simulates intra-operative sequences
    /// (pneumoperitoneum, gravity in a new pose, a tool push), registers them, prints TRE
    /// without registration, after rigid and after non-rigid, and ms per frame.
    Demo {
        /// Where the artefacts go (phantom, frames, truth, results, summary).
        #[arg(long, default_value = "demo-out")]
        out: PathBuf,
        /// Frames per scenario.
        #[arg(long, default_value_t = 10)]
        frames: usize,
        /// Only these scenarios (comma-separated: pneumoperitoneum, gravity-pose, tool-push).
        #[arg(long, value_delimiter = ',')]
        scenarios: Vec<String>,
    },
}

/// Runs the command line; errors are printed as one line on stderr with a non-zero exit code.
pub fn run(cli: Cli) -> ExitCode {
    let result: Result<(), String> = match cli.command {
        Command::Simulate { scene, out } => simulate::run(&scene, out.as_deref()),
        Command::Register {
            scene,
            frames,
            out,
            budget_ms,
            rigid_only,
        } => register::run(&register::RegisterArgs {
            scene,
            frames,
            out,
            budget_ms,
            rigid_only,
        })
        .map(|_| ()),
        Command::Eval {
            results,
            truth,
            json,
        } => eval::run(&results, &truth, json),
        Command::Demo {
            out,
            frames,
            scenarios,
        } => demo::run(&out, frames, &scenarios).map(|_| ()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("livereg: {}", message.replace('\n', " "));
            ExitCode::FAILURE
        }
    }
}
