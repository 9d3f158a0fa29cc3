//! `livereg register SCENE --frames PATH [--out DIR] [--record FILE.mcap]`: a sequence of
//! clouds (a directory of point files, or the `/frames` of an MCAP recording) registered frame
//! after frame with warm start; one `results.jsonl` line per frame, and optionally a recording.

use crate::simulation::FromScene;
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::progress::bar;
use super::vtk_series::VtkSeriesWriter;
use super::RerunArgs;
use crate::evaluation::{percentile, JsonlWriter, ResultRecord};
use crate::mesh::read_points;
use crate::recording::{now_ns, FrameMessage, Recorder, Recording, RecordingMeta, SceneFiles};
use crate::scene::{load_scene, LoadedScene};
use crate::session::{Frame, FrameError, FrameResult, Session};

/// Arguments of `register`.
#[derive(Debug, Clone)]
pub struct RegisterArgs {
    /// Scene file.
    pub scene: PathBuf,
    /// Directory of point files, or an MCAP recording.
    pub frames: PathBuf,
    /// Output directory.
    pub out: PathBuf,
    /// Per-frame time budget override, ms.
    pub budget_ms: Option<f64>,
    /// Rigid stage only.
    pub rigid_only: bool,
    /// Record the session to this MCAP file.
    pub record: Option<PathBuf>,
    /// Log to rerun (needs the `rerun` feature).
    pub rerun: RerunArgs,
    /// Write each frame as VTK files with ParaView time series into this directory.
    pub vtk: Option<PathBuf>,
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
    /// What `--record` wrote (frames, results, bytes, ms spent recording).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub recording: Option<crate::recording::RecorderStats>,
}

/// One frame to register: a point file, or a frame of a recording.
#[derive(Debug, Clone)]
pub enum FrameInput {
    /// A point file (read when its turn comes; unreadable → a failed frame).
    File(PathBuf),
    /// A recorded frame (its points and camera, or the reason it could not be read).
    Recorded(Box<FrameMessage>),
}

impl FrameInput {
    /// The frame: the file's points, or the recorded frame; otherwise its source name and
    /// why it could not be read.
    pub fn read(&self) -> Result<Frame, (String, String)> {
        match self {
            FrameInput::File(path) => {
                let source = path
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                read_points(path)
                    .map(|points| Frame {
                        source: source.clone(),
                        points,
                        camera: None,
                    })
                    .map_err(|e| (source, e.to_string()))
            }
            FrameInput::Recorded(m) => m
                .to_frame()
                .ok_or_else(|| (m.source.clone(), m.input_error.clone().unwrap_or_default())),
        }
    }
}

pub use crate::session::{frame_files, FrameFiles, FrameObserver};

/// Whether `path` is an MCAP file (by extension, or by its magic bytes for another file).
pub fn is_mcap(path: &Path) -> bool {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
    {
        return true;
    }
    path.is_file()
        && std::fs::File::open(path)
            .and_then(|mut f| {
                let mut magic = [0u8; 8];
                std::io::Read::read_exact(&mut f, &mut magic).map(|()| magic)
            })
            .is_ok_and(|m| m == mcap::MAGIC)
}

/// The frames of `path`: a directory's point files in lexical order, or every recorded frame
/// of an MCAP recording (an unfinished recording gives the frames it holds, with a note on
/// stderr).
pub fn frame_inputs(path: &Path) -> Result<Vec<FrameInput>, String> {
    if is_mcap(path) {
        let rec = Recording::open(path).map_err(|e| e.to_string())?;
        if !rec.finished {
            eprintln!("livereg: {}", rec.describe());
        }
        if rec.frames.is_empty() {
            return Err(format!("{}: the recording holds no frames", path.display()));
        }
        return Ok(rec
            .frames
            .into_iter()
            .map(|m| FrameInput::Recorded(Box::new(m)))
            .collect());
    }
    if path.is_file() {
        return Err(format!(
            "{}: --frames takes a directory of point files or an MCAP recording (.mcap)",
            path.display()
        ));
    }
    let found = frame_files(path)?;
    if let Some(note) = found.skipped_note(path) {
        eprintln!("livereg: {note}");
    }
    Ok(found.frames.into_iter().map(FrameInput::File).collect())
}

/// Registers every file of `files` in order with `session`, writing each result to
/// `results` as soon as it is known; a file that cannot be read is a failed frame.
pub fn register_files(
    session: &mut Session,
    files: &[PathBuf],
    results: &Path,
    label: &str,
) -> Result<Vec<FrameResult>, String> {
    let inputs: Vec<FrameInput> = files.iter().cloned().map(FrameInput::File).collect();
    register_inputs(session, &inputs, results, label, &mut [])
}

/// Registers `inputs` in order with `session`; each result goes to every observer (a
/// recorder first: a frame is in the recording before its `results.jsonl` line exists), then
/// to `results` as soon as it is known. An input that cannot be read is a failed frame.
pub fn register_inputs(
    session: &mut Session,
    inputs: &[FrameInput],
    results: &Path,
    label: &str,
    observers: &mut [&mut dyn FrameObserver],
) -> Result<Vec<FrameResult>, String> {
    let mut writer = JsonlWriter::create(results).map_err(|e| e.to_string())?;
    let scale = session.model.length_scale;
    let pb = bar(inputs.len(), label);
    let mut out = Vec::with_capacity(inputs.len());
    for (index, input) in inputs.iter().enumerate() {
        let received = now_ns();
        let frame = input.read();
        let r = match &frame {
            Ok(f) => session.register(f),
            Err((source, e)) => session.reject(source, FrameError::Input(e.clone())),
        };
        for o in observers.iter_mut() {
            o.frame_done(index, frame.as_ref().ok(), received, &r)?;
        }
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
            .filter(|r| r.flags.contains(&crate::session::FrameFlag::TimeBudget))
            .count(),
        p50_ms: pct(0.5),
        p95_ms: pct(0.95),
        results: path.to_path_buf(),
        recording: None,
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

/// A recorder for a run of `command` on `loaded` into `path`.
pub fn recorder_for(
    path: &Path,
    loaded: &LoadedScene,
    command: &str,
    budget_ms: Option<f64>,
    rigid_only: bool,
) -> Result<Recorder, String> {
    let scene = SceneFiles::from_loaded(loaded).map_err(|e| e.to_string())?;
    let meta = RecordingMeta {
        command: command.into(),
        budget_ms,
        rigid_only,
        ..Default::default()
    };
    Recorder::create(
        path,
        &scene,
        &meta,
        loaded.length_scale(),
        loaded.scene.units.as_str(),
    )
    .map_err(|e| e.to_string())
}

/// Runs the command: prints the summary as JSON on stdout.
pub fn run(args: &RegisterArgs) -> Result<RegisterSummary, String> {
    let loaded = load_scene(&args.scene).map_err(|e| e.to_string())?;
    let inputs = frame_inputs(&args.frames)?;
    let mut session = session_for(&loaded, args.budget_ms, args.rigid_only)?;
    std::fs::create_dir_all(&args.out)
        .map_err(|e| format!("{}: cannot create: {e}", args.out.display()))?;
    let path = args.out.join("results.jsonl");
    let mut recorder = match &args.record {
        Some(p) => Some(recorder_for(
            p,
            &loaded,
            "register",
            args.budget_ms,
            args.rigid_only,
        )?),
        None => None,
    };
    #[allow(unused_mut, unused_variables)]
    let mut visualiser = args.rerun.visualiser(&session, "")?;
    let mut vtk = match &args.vtk {
        Some(dir) => Some(VtkSeriesWriter::create(dir, &session)?),
        None => None,
    };
    let results = {
        let mut observers: Vec<&mut dyn FrameObserver> = Vec::new();
        if let Some(r) = recorder.as_mut() {
            observers.push(r);
        }
        if let Some(v) = vtk.as_mut() {
            observers.push(v);
        }
        #[cfg(feature = "rerun")]
        if let Some(v) = visualiser.as_mut() {
            observers.push(v);
        }
        register_inputs(&mut session, &inputs, &path, "register", &mut observers)?
    };
    let stats = match recorder {
        Some(r) => Some(r.finish().map_err(|e| e.to_string())?),
        None => None,
    };
    let mut summary = summarize(&results, &path);
    summary.recording = stats;
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
