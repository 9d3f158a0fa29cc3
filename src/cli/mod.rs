//! The `livereg` command line (contract: "Binary"): one file per command.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod bench;
pub mod calibrate;
pub mod demo;
pub mod eval;
pub mod model;
pub mod progress;
pub mod register;
pub mod replay;
pub mod serve;
pub mod simulate;
pub mod vtk_series;

/// `--rerun FILE.rrd` and `--rerun-connect URL`: 3D logging to rerun (feature `rerun`).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RerunArgs {
    /// Write a rerun recording (.rrd) of the model, clouds, deformed surfaces, structures,
    /// correspondences and per-frame metrics. Needs a build with `--features rerun`.
    #[arg(long, value_name = "FILE.rrd")]
    pub rerun: Option<PathBuf>,
    /// Stream the same to a running rerun viewer (gRPC URL, e.g.
    /// `rerun+http://127.0.0.1:9876/proxy`) instead. Needs a build with `--features rerun`.
    #[arg(long, value_name = "URL", conflicts_with = "rerun")]
    pub rerun_connect: Option<String>,
}

/// The visualiser type of this build ([`crate::visualisation::Visualiser`] with the `rerun`
/// feature; an empty type without it).
#[cfg(feature = "rerun")]
pub type Visualiser = crate::visualisation::Visualiser;
/// The visualiser type of this build (none: built without the `rerun` feature).
#[cfg(not(feature = "rerun"))]
#[derive(Debug)]
pub enum Visualiser {}

impl RerunArgs {
    /// Whether rerun output was asked for.
    pub fn is_set(&self) -> bool {
        self.rerun.is_some() || self.rerun_connect.is_some()
    }

    /// The rerun stream asked for (`None` when neither flag is given).
    #[cfg(feature = "rerun")]
    pub fn stream(&self, app: &'static str) -> Result<Option<rerun::RecordingStream>, String> {
        crate::visualisation::open_stream(app, self.rerun.as_deref(), self.rerun_connect.as_deref())
    }

    /// Without the `rerun` feature: an error naming how to enable it when a flag is given.
    #[cfg(not(feature = "rerun"))]
    pub fn stream(&self, _app: &'static str) -> Result<Option<std::convert::Infallible>, String> {
        if self.is_set() {
            return Err(
                "--rerun / --rerun-connect need a build with rerun support: \
                 cargo build --release --features rerun (see README, \"Visualisation\")"
                    .into(),
            );
        }
        Ok(None)
    }

    /// A visualiser of `session`'s model (entities under `prefix`), when a flag is given.
    #[cfg(feature = "rerun")]
    pub fn visualiser(
        &self,
        session: &crate::session::Session,
        prefix: &str,
    ) -> Result<Option<Visualiser>, String> {
        Ok(self
            .stream("livereg")?
            .map(|s| Visualiser::new(s, prefix, session, None)))
    }

    /// Without the `rerun` feature: an error when a flag is given, else `None`.
    #[cfg(not(feature = "rerun"))]
    pub fn visualiser(
        &self,
        _session: &crate::session::Session,
        _prefix: &str,
    ) -> Result<Option<Visualiser>, String> {
        self.stream("livereg").map(|_| None)
    }
}

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
        /// A directory of point files (.xyz .txt .csv .ply .vtk .vtp), taken in lexical order of name,
        /// or an MCAP recording (its recorded frames).
        #[arg(long)]
        frames: PathBuf,
        /// Record the session (scene, model files, every frame and result) to this MCAP file.
        #[arg(long, value_name = "FILE.mcap")]
        record: Option<PathBuf>,
        /// 3D visualisation.
        #[command(flatten)]
        rerun: RerunArgs,
        /// Also write every frame's deformed liver and structures as VTK files (`.vtp`) with a
        /// ParaView time series (`.pvd`) per object into DIR (docs/vtk.md).
        #[arg(long, value_name = "DIR")]
        vtk: Option<PathBuf>,
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
    /// Speed against accuracy: a sweep of registration models (grid, integration, law, linear
    /// solver, penalty schedule) on the phantom's scenarios or your own frames and truth;
    /// writes bench.json and a chart (PNG, SVG) of TRE against ms per frame.
    Bench(bench::BenchArgs),
    /// Model no more than a scene needs: picks the cheapest registration model that meets a
    /// TRE target (or the most accurate within a latency budget) on synthetic deformations of
    /// the scene's own model, writes it into a scene file and checks it on fresh frames.
    Calibrate(calibrate::CalibrateArgs),
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
        /// 3D visualisation (with the truth's target errors).
        #[command(flatten)]
        rerun: RerunArgs,
        /// Also write every registered frame as VTK files with ParaView time series, one
        /// subdirectory of DIR per scenario (docs/vtk.md).
        #[arg(long, value_name = "DIR")]
        vtk: Option<PathBuf>,
    },
    /// The patient model straight from a segmentation labelmap (.nii, .nii.gz, .nrrd,
    /// .seg.nrrd): the organ's closed surface, tumours as meshes, vessels as points, and a scene
    /// file naming them (docs/segmentation.md).
    Model(model::ModelArgs),
    /// Re-runs a recorded session through this build and compares: the largest difference of
    /// surface vertices and structures (mm) per frame and overall; exits non-zero beyond the
    /// tolerance.
    Replay(replay::ReplayArgs),
    /// The registration server: HTTP + WebSocket and gRPC for AR displays (docs/server.md).
    /// Settings: --config FILE, then LIVEREG_* variables, then flags.
    Serve(serve::ServeArgs),
}

/// Runs the command line; errors are printed as one line on stderr with a non-zero exit code.
pub fn run(cli: Cli) -> ExitCode {
    let result: Result<(), String> = match cli.command {
        Command::Simulate { scene, out } => simulate::run(&scene, out.as_deref()),
        Command::Register {
            scene,
            frames,
            record,
            rerun,
            vtk,
            out,
            budget_ms,
            rigid_only,
        } => register::run(&register::RegisterArgs {
            scene,
            frames,
            out,
            budget_ms,
            rigid_only,
            record,
            rerun,
            vtk,
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
            rerun,
            vtk,
        } => demo::run_with(&out, frames, &scenarios, &rerun, vtk.as_deref()).map(|_| ()),
        Command::Bench(args) => bench::run(&args).map(|_| ()),
        Command::Calibrate(args) => calibrate::run(&args).map(|_| ()),
        Command::Replay(args) => replay::run(&args).map(|_| ()),
        Command::Model(args) => model::run(&args).map(|_| ()),
        Command::Serve(args) => serve::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("livereg: {}", message.replace('\n', " "));
            ExitCode::FAILURE
        }
    }
}
