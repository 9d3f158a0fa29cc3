//! `livereg register SCENE --frames PATH [--out DIR]`: a sequence of clouds registered frame
//! after frame with warm start; one `results.jsonl` line per frame.

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::progress::bar;
use crate::evaluation::{percentile, JsonlWriter, ResultRecord};
use crate::mesh::read_points;
use crate::scene::{load_scene, LoadedScene};
use crate::session::{Frame, FrameError, FrameResult, Session};

/// Arguments of `register`.
#[derive(Debug, Clone)]
pub struct RegisterArgs {
    /// Scene file.
    pub scene: PathBuf,
    /// Directory of point files.
    pub frames: PathBuf,
    /// Output directory.
    pub out: PathBuf,
    /// Per-frame time budget override, ms.
    pub budget_ms: Option<f64>,
    /// Rigid stage only.
    pub rigid_only: bool,
}

/// What a `register` run did (printed as JSON on stdout).
#[derive(Debug, Clone, Serialize)]
pub struct RegisterSummary {
    /// Frames processed.
    pub frames: usize,
    /// Frames that failed (recorded with the last good state).
    pub failed: usize,
    /// Frames flagged by the time budget.
    pub over_budget: usize,
    /// Median wall time per frame, ms.
    pub p50_ms: f64,
    /// 95th percentile of the wall time per frame, ms.
    pub p95_ms: f64,
    /// The results file.
    pub results: PathBuf,
}

/// Point files of a frame directory (`.xyz .txt .csv .ply`), in lexical order of name.
pub fn frame_files(dir: &Path) -> Result<Vec<PathBuf>, String> {
    if dir
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
    {
        return Err(format!(
            "{}: reading frames from MCAP recordings is not supported by this build yet; give a directory of point files",
            dir.display()
        ));
    }
    let entries = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: cannot read the frame directory: {e}", dir.display()))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_file()
                && p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                    matches!(
                        e.to_ascii_lowercase().as_str(),
                        "xyz" | "txt" | "csv" | "ply"
                    )
                })
        })
        .collect();
    files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    if files.is_empty() {
        return Err(format!(
            "{}: no point files (.xyz .txt .csv .ply) in the frame directory",
            dir.display()
        ));
    }
    Ok(files)
}

/// Registers every file of `files` in order with `session`, writing each result to
/// `results` as soon as it is known; a file that cannot be read is a failed frame.
pub fn register_files(
    session: &mut Session,
    files: &[PathBuf],
    results: &Path,
    label: &str,
) -> Result<Vec<FrameResult>, String> {
    let mut writer = JsonlWriter::create(results).map_err(|e| e.to_string())?;
    let scale = session.model.length_scale;
    let pb = bar(files.len(), label);
    let mut out = Vec::with_capacity(files.len());
    for path in files {
        let source = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let r = match read_points(path) {
            Ok(points) => session.register(&Frame {
                source,
                points,
                camera: None,
            }),
            Err(e) => session.reject(&source, FrameError::Input(e.to_string())),
        };
        writer
            .write(&ResultRecord::from_frame(&r, scale))
            .map_err(|e| e.to_string())?;
        pb.set_message(format!("{:.0} ms", r.wall_ms));
        pb.inc(1);
        out.push(r);
    }
    pb.finish_and_clear();
    Ok(out)
}

/// Summary of a run's results.
pub fn summarize(results: &[FrameResult], path: &Path) -> RegisterSummary {
    let mut ms: Vec<f64> = results.iter().map(|r| r.wall_ms).collect();
    ms.sort_by(f64::total_cmp);
    let pct = |p| {
        if ms.is_empty() {
            0.0
        } else {
            percentile(&ms, p)
        }
    };
    RegisterSummary {
        frames: results.len(),
        failed: results.iter().filter(|r| r.error.is_some()).count(),
        over_budget: results
            .iter()
            .filter(|r| r.flags.iter().any(|f| f == "time_budget"))
            .count(),
        p50_ms: pct(0.5),
        p95_ms: pct(0.95),
        results: path.to_path_buf(),
    }
}

/// A session for `loaded` with the command's overrides.
pub fn session_for(
    loaded: &LoadedScene,
    budget_ms: Option<f64>,
    rigid_only: bool,
) -> Result<Session, String> {
    let mut session = Session::from_scene(loaded).map_err(|e| e.to_string())?;
    if let Some(b) = budget_ms {
        if !(b.is_finite() && b > 0.0) {
            return Err(format!("--budget-ms must be > 0, got {b}"));
        }
        session.settings.time_budget_ms = Some(b);
    }
    session.settings.non_rigid = !rigid_only;
    Ok(session)
}

/// Runs the command: prints the summary as JSON on stdout.
pub fn run(args: &RegisterArgs) -> Result<RegisterSummary, String> {
    let loaded = load_scene(&args.scene).map_err(|e| e.to_string())?;
    let files = frame_files(&args.frames)?;
    let mut session = session_for(&loaded, args.budget_ms, args.rigid_only)?;
    std::fs::create_dir_all(&args.out)
        .map_err(|e| format!("{}: cannot create: {e}", args.out.display()))?;
    let path = args.out.join("results.jsonl");
    let results = register_files(&mut session, &files, &path, "register")?;
    let summary = summarize(&results, &path);
    println!(
        "{}",
        serde_json::to_string(&summary).map_err(|e| e.to_string())?
    );
    if summary.failed == summary.frames {
        let first = results
            .iter()
            .find_map(|r| r.error.as_ref())
            .map(|e| e.to_string())
            .unwrap_or_default();
        return Err(format!(
            "no frame could be registered (first error: {first}); see {}",
            path.display()
        ));
    }
    Ok(summary)
}
