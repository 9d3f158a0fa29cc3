//! `livereg replay FILE.mcap`: re-runs a recorded session's frames through this build and
//! compares the results with the recorded ones: per frame and overall, the largest distance
//! between replayed and recorded surface vertices and structure points (mm). Exits non-zero
//! beyond `--tolerance`. `--set KEY=VALUE` (on the recorded scene) or `--scene FILE` replays
//! against a deliberately changed scene.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use nalgebra::Point3;
use serde::Serialize;

use super::progress::bar;
use super::register::session_for;
#[cfg(feature = "rerun")]
use super::register::FrameObserver;
use super::RerunArgs;
use crate::evaluation::{JsonlWriter, ResultRecord};
use crate::recording::{FrameMessage, Recording, ResultMessage};
use crate::scene::{load_scene, LoadedScene};
use crate::session::{Frame, FrameError, FrameResult, Session};

/// How fast frames are fed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Speed {
    /// At the pace they were received (by their recorded timestamps).
    Realtime,
    /// As fast as they register.
    Max,
}

/// Arguments of `replay`.
#[derive(Debug, Clone, clap::Args)]
pub struct ReplayArgs {
    /// The recording (`register --record`, `demo`, or a served session).
    pub file: PathBuf,
    /// Frame pacing.
    #[arg(long, value_enum, default_value = "max")]
    pub speed: Speed,
    /// Largest accepted difference from the recorded results, mm (surface vertices and
    /// structure points).
    #[arg(long, default_value_t = 1e-6, value_name = "MM")]
    pub tolerance: f64,
    /// Directory for the replay's `results.jsonl` and `replay.json` (report).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Change a key of the recorded scene before replaying (repeatable), e.g.
    /// `--set registration.alpha=0.5`; the value is read as TOML (else as a string).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Replay against this scene instead of the recorded one (same surface expected).
    #[arg(long, value_name = "SCENE", conflicts_with = "set")]
    pub scene: Option<PathBuf>,
    /// Print the report as one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// 3D visualisation of the replayed frames.
    #[command(flatten)]
    pub rerun: RerunArgs,
    /// Also write every replayed frame as VTK files with a ParaView time series per object
    /// into DIR (docs/vtk.md).
    #[arg(long, value_name = "DIR")]
    pub vtk: Option<PathBuf>,
}

/// The comparison of one frame.
#[derive(Debug, Clone, Serialize)]
pub struct FrameDiff {
    /// Frame index.
    pub frame: usize,
    /// The frame's source.
    pub source: String,
    /// Largest distance between replayed and recorded surface vertices, mm (`None`: not
    /// comparable, e.g. a different vertex count).
    pub surface_mm: Option<f64>,
    /// Largest distance between replayed and recorded structure points, mm (`None`: not
    /// comparable).
    pub structures_mm: Option<f64>,
    /// Whether the frame failed in one run and not in the other.
    pub status_changed: bool,
    /// Whether the recorded result was cut short by the recording's time budget (flag
    /// `time_budget`): where the budget stopped it depends on the recording machine's speed,
    /// so a difference on this frame is timing, not a change of the method.
    pub recorded_time_budget: bool,
    /// Recorded wall time, ms.
    pub recorded_ms: f64,
    /// Replayed wall time, ms.
    pub replay_ms: f64,
}

impl FrameDiff {
    /// The frame's largest difference, mm (infinite when not comparable or the status
    /// changed).
    pub fn max_mm(&self) -> f64 {
        if self.status_changed {
            return f64::INFINITY;
        }
        match (self.surface_mm, self.structures_mm) {
            (Some(a), Some(b)) => a.max(b),
            _ => f64::INFINITY,
        }
    }
}

/// The replay's report (printed, and written to `replay.json` with `--out`).
#[derive(Debug, Clone, Serialize)]
pub struct ReplayReport {
    /// The recording.
    pub file: PathBuf,
    /// Whether the recording was finished (else: cut short, replayed as far as it goes).
    pub finished: bool,
    /// Frames replayed (recorded frames that have a recorded result).
    pub frames: usize,
    /// Largest surface difference over all frames, mm (`None`: some frame not comparable).
    pub max_surface_mm: Option<f64>,
    /// Largest structure difference over all frames, mm (`None`: some frame not comparable).
    pub max_structures_mm: Option<f64>,
    /// Frames whose failed/succeeded status changed.
    pub status_changes: usize,
    /// Recorded frames cut short by the recording's time budget (their results depend on
    /// timing; see [`FrameDiff::recorded_time_budget`]).
    pub time_budget_frames: usize,
    /// The tolerance, mm.
    pub tolerance_mm: f64,
    /// Whether every frame is within the tolerance.
    pub within_tolerance: bool,
    /// Whether every compared coordinate is bitwise identical.
    pub identical: bool,
    /// Sum of the recorded wall times, ms.
    pub recorded_ms: f64,
    /// Wall time of the replay's registrations, ms.
    pub replay_ms: f64,
    /// Per frame.
    pub per_frame: Vec<FrameDiff>,
}

/// Runs the command: prints the report; an error (non-zero exit) beyond the tolerance.
pub fn run(args: &ReplayArgs) -> Result<ReplayReport, String> {
    if !(args.tolerance.is_finite() && args.tolerance >= 0.0) {
        return Err(format!(
            "--tolerance must be >= 0 mm, got {}",
            args.tolerance
        ));
    }
    let rec = open_recording(&args.file)?;
    let (mut session, loaded) = replay_session(args, &rec)?;
    let scale = loaded.length_scale();
    let mut outputs = FrameOutputs::create(args, &session)?;
    let (per_frame, replay_ms) = replay_frames(args, &rec, &mut session, &mut outputs, scale)?;
    let report = report_of(args, &rec, per_frame, replay_ms);
    publish(args, &report)?;
    if !report.within_tolerance {
        return Err(beyond_tolerance(args, &report, rec.session.budget_ms));
    }
    Ok(report)
}

/// The recording in `file`, with a note on stderr when it was cut short; an error when it
/// has no frame with a recorded result.
fn open_recording(file: &Path) -> Result<Recording, String> {
    let rec = Recording::open(file).map_err(|e| e.to_string())?;
    if !rec.finished {
        eprintln!("livereg: {}", rec.describe());
    }
    if rec.complete_frames() == 0 {
        return Err(format!(
            "{}: no frame with a recorded result to replay",
            file.display()
        ));
    }
    Ok(rec)
}

/// The session to replay with, set up as the recorded one (time budget, rigid only), and its
/// scene (see [`scene_for`]; a recorded scene is rebuilt in a temporary directory, removed
/// once the session is built). Notes on stderr when the recording ran with a time budget.
fn replay_session(args: &ReplayArgs, rec: &Recording) -> Result<(Session, LoadedScene), String> {
    let tmp = std::env::temp_dir().join(format!(
        "livereg-replay-{}-{}",
        std::process::id(),
        crate::recording::now_ns()
    ));
    let loaded = scene_for(args, rec, &tmp);
    let budget = rec.session.budget_ms;
    if budget.is_some() {
        eprintln!(
            "livereg: the recording ran with a {:.0} ms time budget: its results depend on timing",
            budget.unwrap_or_default()
        );
    }
    // The session reads the scene's files while it is built; the temporary copy goes after.
    let session = loaded.and_then(|l| Ok((session_for(&l, budget, rec.session.rigid_only)?, l)));
    let _ = std::fs::remove_dir_all(&tmp);
    session
}

/// Where each replayed frame goes besides the comparison: `--out`'s `results.jsonl`, the
/// rerun visualiser and the VTK series, each when asked for.
struct FrameOutputs {
    /// `results.jsonl` in `--out`.
    writer: Option<JsonlWriter>,
    /// The rerun visualiser (never present without the `rerun` feature).
    #[cfg_attr(not(feature = "rerun"), allow(dead_code))]
    visualiser: Option<super::Visualiser>,
    /// The VTK series in `--vtk`.
    vtk: Option<super::vtk_series::VtkSeriesWriter>,
}

impl FrameOutputs {
    /// Creates the outputs `args` asks for (the `--out` directory included) for `session`.
    fn create(args: &ReplayArgs, session: &Session) -> Result<Self, String> {
        let writer = match &args.out {
            Some(dir) => {
                std::fs::create_dir_all(dir)
                    .map_err(|e| format!("{}: cannot create: {e}", dir.display()))?;
                Some(JsonlWriter::create(dir.join("results.jsonl")).map_err(|e| e.to_string())?)
            }
            None => None,
        };
        let visualiser = args.rerun.visualiser(session, "replay")?;
        let vtk = match &args.vtk {
            Some(dir) => Some(super::vtk_series::VtkSeriesWriter::create(dir, session)?),
            None => None,
        };
        Ok(FrameOutputs {
            writer,
            visualiser,
            vtk,
        })
    }

    /// Hands replayed frame `k` (`fm` as recorded, `frame` as registered, `r` its result)
    /// to the visualiser, the VTK series and `results.jsonl` (`scale`: metres per scene
    /// unit).
    #[cfg_attr(not(feature = "rerun"), allow(unused_variables))]
    fn frame_done(
        &mut self,
        k: usize,
        fm: &FrameMessage,
        frame: Option<&Frame>,
        r: &FrameResult,
        scale: f64,
    ) -> Result<(), String> {
        #[cfg(feature = "rerun")]
        if let Some(v) = self.visualiser.as_mut() {
            v.frame_done(k, frame, fm.timestamp_ns, r)?;
        }
        if let Some(v) = self.vtk.as_mut() {
            v.write_frame(k, r)?;
        }
        if let Some(w) = self.writer.as_mut() {
            w.write(&ResultRecord::from_frame(r, scale))
                .map_err(|e| e.to_string())?;
        }
        Ok(())
    }
}

/// Replays every recorded frame that has a recorded result through `session` (at the
/// recorded pace with `--speed realtime`), hands each to `outputs` and compares it with the
/// recorded result (`scale`: metres per scene unit): the comparisons (mm) and the sum of the
/// replayed wall times (ms).
fn replay_frames(
    args: &ReplayArgs,
    rec: &Recording,
    session: &mut Session,
    outputs: &mut FrameOutputs,
    scale: f64,
) -> Result<(Vec<FrameDiff>, f64), String> {
    let mm = scale * 1e3;
    let n = rec.complete_frames();
    let pb = bar(n, "replay");
    let start = Instant::now();
    let t0 = rec.frames[0].timestamp_ns;
    let mut per_frame = Vec::with_capacity(n);
    let mut replay_ms = 0.0;
    for (k, (fm, recorded)) in rec.frames.iter().zip(&rec.results).enumerate() {
        if args.speed == Speed::Realtime {
            let due = Duration::from_nanos(fm.timestamp_ns.saturating_sub(t0));
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        let frame = fm.to_frame();
        let r = register_recorded(session, fm, frame.as_ref());
        replay_ms += r.wall_ms;
        outputs.frame_done(k, fm, frame.as_ref(), &r, scale)?;
        let d = compare(&r, recorded, mm);
        pb.set_message(format!("Δ {:.2e} mm", d.max_mm()));
        pb.inc(1);
        per_frame.push(d);
    }
    pb.finish_and_clear();
    Ok((per_frame, replay_ms))
}

/// The result of a recorded frame: `frame` registered by `session`, or (no frame: its input
/// could not be read) rejected with the recorded input error.
fn register_recorded(
    session: &mut Session,
    fm: &FrameMessage,
    frame: Option<&Frame>,
) -> FrameResult {
    match frame {
        Some(f) => session.register(f),
        None => session.reject(
            &fm.source,
            FrameError::Input(fm.input_error.clone().unwrap_or_default()),
        ),
    }
}

/// The largest difference over `per_frame`, mm (infinite when a frame is not comparable).
fn worst_mm(per_frame: &[FrameDiff]) -> f64 {
    per_frame.iter().map(FrameDiff::max_mm).fold(0.0, f64::max)
}

/// The report of the comparisons `per_frame` (mm) and the replay's wall time `replay_ms`.
fn report_of(
    args: &ReplayArgs,
    rec: &Recording,
    per_frame: Vec<FrameDiff>,
    replay_ms: f64,
) -> ReplayReport {
    let fold = |f: fn(&FrameDiff) -> Option<f64>| {
        per_frame
            .iter()
            .map(f)
            .try_fold(0.0f64, |m, v| v.map(|v| m.max(v)))
    };
    let max_surface_mm = fold(|d| d.surface_mm);
    let max_structures_mm = fold(|d| d.structures_mm);
    let status_changes = per_frame.iter().filter(|d| d.status_changed).count();
    let time_budget_frames = per_frame.iter().filter(|d| d.recorded_time_budget).count();
    let worst = worst_mm(&per_frame);
    ReplayReport {
        file: args.file.clone(),
        finished: rec.finished,
        frames: rec.complete_frames(),
        max_surface_mm,
        max_structures_mm,
        status_changes,
        time_budget_frames,
        tolerance_mm: args.tolerance,
        within_tolerance: worst <= args.tolerance,
        identical: worst == 0.0,
        recorded_ms: rec.results.iter().map(|r| r.record.wall_ms).sum(),
        replay_ms,
        per_frame,
    }
}

/// Writes the report to `--out`'s `replay.json` (when given) and prints it: one JSON object
/// with `--json`, else the table.
fn publish(args: &ReplayArgs, report: &ReplayReport) -> Result<(), String> {
    if let Some(dir) = &args.out {
        let p = dir.join("replay.json");
        let text = serde_json::to_string_pretty(report).map_err(|e| e.to_string())?;
        std::fs::write(&p, text).map_err(|e| format!("{}: {e}", p.display()))?;
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string(report).map_err(|e| e.to_string())?
        );
    } else {
        print!("{}", table(report));
    }
    Ok(())
}

/// The error of a replay beyond the tolerance: the largest difference (mm) and its frame,
/// and — when that frame was cut short by the recording's time budget `budget` (ms) — why
/// it may differ.
fn beyond_tolerance(args: &ReplayArgs, report: &ReplayReport, budget: Option<f64>) -> String {
    let worst = worst_mm(&report.per_frame);
    let worst_frame = report
        .per_frame
        .iter()
        .max_by(|a, b| a.max_mm().total_cmp(&b.max_mm()));
    let at = worst_frame.map(|d| d.frame).unwrap_or_default();
    let why = match (worst_frame, budget) {
        (Some(d), Some(b)) if d.recorded_time_budget => format!(
            "; the recorded frame {at} was cut short by the recording's {b:.0} ms time budget, so its result depends on the recording machine's speed"
        ),
        _ => String::new(),
    };
    format!(
        "the replay differs from the recording beyond the tolerance: largest difference {} (frame {at}), tolerance {:e} mm{why}",
        fmt_mm(Some(worst).filter(|w| w.is_finite())),
        args.tolerance
    )
}

/// The scene to replay against: `--scene`, or the recorded one (with `--set` changes)
/// rebuilt in `tmp`.
fn scene_for(args: &ReplayArgs, rec: &Recording, tmp: &Path) -> Result<LoadedScene, String> {
    if let Some(s) = &args.scene {
        return load_scene(s).map_err(|e| e.to_string());
    }
    let files = rec.scene_files().map_err(|e| e.to_string())?;
    files
        .materialize(tmp, &args.set)
        .map_err(|e| format!("{}: {e}", args.file.display()))
}

/// Largest distance between two point lists given flat or as points, in scene units;
/// `None` when their lengths differ.
fn max_distance(a: &[Point3<f64>], b: impl ExactSizeIterator<Item = [f64; 3]>) -> Option<f64> {
    if a.len() != b.len() {
        return None;
    }
    Some(
        a.iter()
            .zip(b)
            .map(|(p, q)| (p - Point3::from(q)).norm())
            .fold(0.0, f64::max),
    )
}

/// The comparison of a replayed result with the recorded one (`mm`: mm per scene unit).
pub fn compare(r: &FrameResult, recorded: &ResultMessage, mm: f64) -> FrameDiff {
    let surface = max_distance(
        &r.surface,
        recorded.surface.chunks_exact(3).map(|c| [c[0], c[1], c[2]]),
    );
    let mut structures = Some(0.0f64);
    if r.structures.len() != recorded.record.structures.len() {
        structures = None;
    }
    for (name, pts) in &r.structures {
        let d = recorded
            .record
            .structures
            .get(name)
            .and_then(|old| max_distance(pts, old.iter().copied()));
        structures = match (structures, d) {
            (Some(a), Some(b)) => Some(a.max(b)),
            _ => None,
        };
    }
    FrameDiff {
        frame: r.frame,
        source: r.source.clone(),
        surface_mm: surface.map(|d| d * mm),
        structures_mm: structures.map(|d| d * mm),
        status_changed: r.error.is_some() != recorded.record.diagnostics.error.is_some(),
        recorded_time_budget: recorded
            .record
            .diagnostics
            .flags
            .iter()
            .any(|f| f == "time_budget"),
        recorded_ms: recorded.record.wall_ms,
        replay_ms: r.wall_ms,
    }
}

fn fmt_mm(v: Option<f64>) -> String {
    match v {
        Some(0.0) => "0 mm".into(),
        Some(v) => format!("{v:.3e} mm"),
        None => "not comparable".into(),
    }
}

/// The report as a table: one row per frame, then the overall line.
pub fn table(r: &ReplayReport) -> String {
    let mut s = format!(
        "{:>5} {:<20} {:>16} {:>16} {:>8} {:>11} {:>9}\n",
        "frame", "source", "surface Δ", "structures Δ", "status", "recorded ms", "replay ms"
    );
    for d in &r.per_frame {
        s.push_str(&format!(
            "{:>5} {:<20} {:>16} {:>16} {:>8} {:>11.1} {:>9.1}\n",
            d.frame,
            d.source,
            fmt_mm(d.surface_mm),
            fmt_mm(d.structures_mm),
            if d.status_changed {
                "CHANGED"
            } else if d.recorded_time_budget {
                "budget"
            } else {
                "same"
            },
            d.recorded_ms,
            d.replay_ms
        ));
    }
    s.push_str(&format!(
        "overall: {} frames, largest surface Δ {}, structures Δ {}, {} status changes, {} cut by the recorded time budget; tolerance {:e} mm: {}\n",
        r.frames,
        fmt_mm(r.max_surface_mm),
        fmt_mm(r.max_structures_mm),
        r.status_changes,
        r.time_budget_frames,
        r.tolerance_mm,
        if r.identical {
            "identical"
        } else if r.within_tolerance {
            "within tolerance"
        } else {
            "BEYOND TOLERANCE"
        }
    ));
    s
}
