//! Registering a [`Workload`] with one session and measuring it: [`FrameSample`] per frame,
//! [`Metrics`] over many.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;

use super::memory;
use super::workload::Workload;
use crate::evaluation::Summary;
use crate::scene::LoadedScene;
use crate::session::{FrameResult, Session, BEFORE_RECOVERY};

/// Why a frame counts as failed (or, for [`Cause::IcpCap`], as not converged).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Cause {
    /// A Newton solve diverged (residual growth, non-finite values, failed linear solve).
    Diverged,
    /// A Newton step would have inverted an element.
    Inverted,
    /// A Newton solve hit its iteration cap.
    NewtonCap,
    /// The frame was rejected (empty, no match, rigid or non-rigid stage error).
    Rejected,
    /// A non-finite number in the output (never expected).
    NonFinite,
    /// The non-rigid ICP used all its iterations without meeting its tolerance (the state is
    /// valid; not counted as a failure).
    IcpCap,
}

impl Cause {
    /// Every cause, in report order.
    pub const ALL: [Cause; 6] = [
        Cause::Diverged,
        Cause::Inverted,
        Cause::NewtonCap,
        Cause::Rejected,
        Cause::NonFinite,
        Cause::IcpCap,
    ];

    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Cause::Diverged => "diverged",
            Cause::Inverted => "inverted",
            Cause::NewtonCap => "newton-cap",
            Cause::Rejected => "rejected",
            Cause::NonFinite => "non-finite",
            Cause::IcpCap => "icp-cap",
        }
    }

    /// Whether a frame with this cause counts as failed.
    pub fn is_failure(self) -> bool {
        self != Cause::IcpCap
    }
}

/// What one frame's registration gave.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameSample {
    /// Distance between each registered and true structure point, mm.
    pub tre_mm: Vec<f64>,
    /// Wall time, ms.
    pub wall_ms: f64,
    /// Whether the frame started from the previous frame's state (a warm frame).
    pub warm: bool,
    /// Newton iterations.
    pub newton_iterations: usize,
    /// Non-rigid ICP iterations.
    pub icp_iterations: usize,
    /// Surface RMS of the last pairing, mm.
    pub surface_rms_mm: f64,
    /// The causes seen (a frame may have several).
    pub causes: Vec<Cause>,
    /// The frame's flags (e.g. `recovered:…`).
    pub flags: Vec<String>,
    /// Causes of a first attempt that a recovery then rescued (see
    /// [`crate::session::SessionSettings::recovery`]).
    pub recovered_causes: Vec<Cause>,
}

impl FrameSample {
    /// Whether the frame failed (a failure cause, see [`Cause::is_failure`]).
    pub fn failed(&self) -> bool {
        self.causes.iter().any(|c| c.is_failure())
    }
}

/// The causes of a frame's result: its error, and the Newton failures its warnings report
/// (`diverged: …`, `inverted: …`, `iteration-cap: …`), and `icp_not_converged`.
pub fn causes_of(r: &FrameResult) -> Vec<Cause> {
    let mut c = Vec::new();
    if r.error.is_some() {
        c.push(Cause::Rejected);
    }
    c.extend(r.warnings.iter().filter_map(|w| solver_cause(w)));
    if r.flags.iter().any(|f| f == "icp_not_converged") {
        c.push(Cause::IcpCap);
    }
    c.sort();
    c.dedup();
    c
}

/// The causes of the failed first attempt of a frame a recovery rescued (its warnings carry
/// the prefix [`BEFORE_RECOVERY`]).
pub fn recovered_causes_of(r: &FrameResult) -> Vec<Cause> {
    let mut c: Vec<Cause> = r
        .warnings
        .iter()
        .filter_map(|w| w.strip_prefix(BEFORE_RECOVERY).and_then(solver_cause))
        .collect();
    c.sort();
    c.dedup();
    c
}

/// The Newton failure a warning names (`diverged: …`, `inverted: …`, `iteration-cap: …`).
fn solver_cause(w: &str) -> Option<Cause> {
    Some(if w.starts_with("diverged") {
        Cause::Diverged
    } else if w.starts_with("inverted") {
        Cause::Inverted
    } else if w.starts_with("iteration-cap") {
        Cause::NewtonCap
    } else {
        return None;
    })
}

/// Registers every frame of `w` in order with `session` and measures each against the
/// truth; `scale` is metres per scene unit. Output positions that are not finite count as
/// [`Cause::NonFinite`] (and infinite TRE).
pub fn run_workload(session: &mut Session, w: &Workload, scale: f64) -> Vec<FrameSample> {
    let mut out = Vec::with_capacity(w.frames.len());
    for (frame, truth) in w.frames.iter().zip(&w.truth) {
        let r = session.register(frame);
        let mut causes = causes_of(&r);
        let mut tre_mm = Vec::new();
        for (name, pts) in &r.structures {
            let Some((_, t)) = truth.iter().find(|(n, _)| n == name) else {
                continue;
            };
            for (p, q) in pts.iter().zip(t) {
                let d = (p - q).norm() * scale * 1e3;
                tre_mm.push(if d.is_finite() { d } else { f64::INFINITY });
            }
        }
        let finite = r
            .structures
            .iter()
            .flat_map(|(_, p)| p)
            .chain(&r.surface)
            .all(|p| p.coords.iter().all(|c| c.is_finite()))
            && r.surface_rms.is_finite();
        if !finite {
            causes.push(Cause::NonFinite);
        }
        out.push(FrameSample {
            tre_mm,
            wall_ms: r.wall_ms,
            warm: r.warm,
            newton_iterations: r.newton_iterations,
            icp_iterations: r.icp_iterations,
            surface_rms_mm: r.surface_rms * scale * 1e3,
            causes,
            flags: r.flags.clone(),
            recovered_causes: recovered_causes_of(&r),
        });
    }
    out
}

/// The numbers of one configuration over its frames. Lengths in mm, times in ms.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Metrics {
    /// Frames registered.
    pub frames: usize,
    /// Mean, 95th percentile and largest target registration error over every structure
    /// point of every frame, mm.
    pub tre_mean_mm: f64,
    /// See `tre_mean_mm`.
    pub tre_p95_mm: f64,
    /// See `tre_mean_mm`.
    pub tre_max_mm: f64,
    /// Mean surface RMS of the frames' last pairing, mm.
    pub surface_rms_mm: f64,
    /// Median, 95th percentile and mean wall time per frame, ms.
    pub ms_p50: f64,
    /// See `ms_p50`.
    pub ms_p95: f64,
    /// See `ms_p50`.
    pub ms_mean: f64,
    /// Median and 95th percentile wall time of the warm frames (those starting from the
    /// previous frame's state: what a running session costs), ms; 0 without warm frames.
    pub warm_ms_p50: f64,
    /// See `warm_ms_p50`.
    pub warm_ms_p95: f64,
    /// Mean Newton iterations per frame.
    pub newton_per_frame: f64,
    /// Mean non-rigid ICP iterations per frame.
    pub icp_per_frame: f64,
    /// Frames that failed (any failure cause).
    pub failed_frames: usize,
    /// Share of frames that failed, in [0, 1].
    pub failure_rate: f64,
    /// Frames per cause (a frame may count under several).
    pub causes: BTreeMap<Cause, usize>,
    /// Frames a recovery rescued (flag `recovered:…`).
    pub recovered_frames: usize,
    /// Frames per cause of the first attempts that a recovery rescued.
    pub recovered_causes: BTreeMap<Cause, usize>,
    /// Peak resident memory of the process while the configuration ran, MiB (`None` where
    /// not measurable).
    pub peak_rss_mib: Option<f64>,
    /// Time to build the model (grid, weights, embedding), ms.
    pub build_ms: f64,
    /// Active grid nodes, cells and cut cells of the model.
    pub nodes: usize,
    /// See `nodes`.
    pub cells: usize,
    /// See `nodes`.
    pub cut_cells: usize,
}

impl Metrics {
    /// Summarises `samples` (no sample: zero frames, NaN-free zeros and infinite TRE are
    /// never produced: an empty set gives zeros).
    pub fn of(samples: &[FrameSample], build: &BuildInfo) -> Self {
        let stats = |v: Vec<f64>| {
            Summary::of(&v).unwrap_or(Summary {
                count: 0,
                mean: 0.0,
                median: 0.0,
                p95: 0.0,
                max: 0.0,
            })
        };
        let tre = stats(samples.iter().flat_map(|s| s.tre_mm.clone()).collect());
        let ms = stats(samples.iter().map(|s| s.wall_ms).collect());
        let warm_ms = stats(
            samples
                .iter()
                .filter(|s| s.warm)
                .map(|s| s.wall_ms)
                .collect(),
        );
        let n = samples.len().max(1) as f64;
        let count = |causes: &mut dyn Iterator<Item = &Cause>| {
            let mut out = BTreeMap::new();
            for c in causes {
                *out.entry(*c).or_insert(0) += 1;
            }
            out
        };
        let causes = count(&mut samples.iter().flat_map(|s| &s.causes));
        let recovered_causes = count(&mut samples.iter().flat_map(|s| &s.recovered_causes));
        let failed = samples.iter().filter(|s| s.failed()).count();
        Self {
            frames: samples.len(),
            tre_mean_mm: tre.mean,
            tre_p95_mm: tre.p95,
            tre_max_mm: tre.max,
            surface_rms_mm: samples.iter().map(|s| s.surface_rms_mm).sum::<f64>() / n,
            ms_p50: ms.median,
            ms_p95: ms.p95,
            ms_mean: ms.mean,
            warm_ms_p50: warm_ms.median,
            warm_ms_p95: warm_ms.p95,
            newton_per_frame: samples.iter().map(|s| s.newton_iterations).sum::<usize>() as f64 / n,
            icp_per_frame: samples.iter().map(|s| s.icp_iterations).sum::<usize>() as f64 / n,
            failed_frames: failed,
            failure_rate: failed as f64 / n,
            causes,
            recovered_frames: samples
                .iter()
                .filter(|s| s.flags.iter().any(|f| f.starts_with("recovered:")))
                .count(),
            recovered_causes,
            peak_rss_mib: build.peak_rss_mib,
            build_ms: build.build_ms,
            nodes: build.nodes,
            cells: build.cells,
            cut_cells: build.cut_cells,
        }
    }

    /// Whether every number is finite (what CI checks of `bench --quick`).
    pub fn all_finite(&self) -> bool {
        [
            self.tre_mean_mm,
            self.tre_p95_mm,
            self.tre_max_mm,
            self.surface_rms_mm,
            self.ms_p50,
            self.ms_p95,
            self.ms_mean,
            self.warm_ms_p50,
            self.warm_ms_p95,
            self.newton_per_frame,
            self.icp_per_frame,
            self.failure_rate,
            self.build_ms,
        ]
        .iter()
        .chain(self.peak_rss_mib.iter())
        .all(|v| v.is_finite())
    }
}

/// The model a configuration built: its size and cost.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BuildInfo {
    /// Time to build the session's model, ms.
    pub build_ms: f64,
    /// Active nodes, cells and cut cells.
    pub nodes: usize,
    /// See `nodes`.
    pub cells: usize,
    /// See `nodes`.
    pub cut_cells: usize,
    /// Peak resident memory while it ran, MiB.
    pub peak_rss_mib: Option<f64>,
}

/// Builds a session for `scene` (rigid only when `rigid_only`) and registers each workload
/// with a fresh start (reset between workloads); returns the samples per workload and the
/// build info, with the peak memory of the whole run.
pub fn run_scene(
    scene: &LoadedScene,
    workloads: &[Workload],
    rigid_only: bool,
) -> Result<(Vec<Vec<FrameSample>>, BuildInfo), String> {
    memory::reset_peak();
    let t = Instant::now();
    let mut session = Session::from_scene(scene).map_err(|e| e.to_string())?;
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    session.settings.non_rigid = !rigid_only;
    let structures: Vec<(String, usize)> = session
        .model
        .structures
        .iter()
        .map(|s| (s.name.clone(), s.embedding.rest.len()))
        .collect();
    let stats = session.model.problem.grid.stats();
    let scale = scene.length_scale();
    let mut all = Vec::with_capacity(workloads.len());
    for w in workloads {
        w.check_against(&structures)?;
        session.reset();
        all.push(run_workload(&mut session, w, scale));
    }
    Ok((
        all,
        BuildInfo {
            build_ms,
            nodes: stats.nodes,
            cells: stats.cells,
            cut_cells: stats.cut_cells,
            peak_rss_mib: memory::peak_rss_mib(),
        },
    ))
}
