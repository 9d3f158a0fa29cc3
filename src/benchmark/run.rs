//! Registering a [`Workload`] with one session and measuring it: [`FrameSample`] per frame,
//! [`Metrics`] over many.

use crate::simulation::FromScene;
use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;

use super::memory;
use super::workload::Workload;
use crate::evaluation::{percentile, Summary};
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
    pub flags: Vec<crate::session::FrameFlag>,
    /// Causes of a first attempt that a recovery then rescued (see
    /// [`crate::session::SessionSettings::recovery`]).
    pub recovered_causes: Vec<Cause>,
    /// The contact force the registration estimated (N, cloud frame).
    pub contact_force_n: Option<[f64; 3]>,
    /// Where it acts (m, cloud frame).
    pub contact_centre_m: Option<[f64; 3]>,
    /// The frame's pose uncertainty (`FrameResult::pose_uncertainty`), mm.
    pub pose_uncertainty_mm: Option<f64>,
    /// The frame's expected error (`FrameResult::expected_error`), mm.
    pub expected_error_mm: Option<f64>,
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
    if r.flags
        .contains(&crate::session::FrameFlag::IcpNotConverged)
    {
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
    w.frames
        .iter()
        .zip(&w.truth)
        .map(|(frame, truth)| sample_of(&session.register(frame), truth, scale))
        .collect()
}

/// What one frame's result `r` gave against `truth` (each structure's name and true points,
/// scene units); `scale` is metres per scene unit. Output positions that are not finite count
/// as [`Cause::NonFinite`] (and infinite TRE).
pub fn sample_of(
    r: &FrameResult,
    truth: &[(String, Vec<nalgebra::Point3<f64>>)],
    scale: f64,
) -> FrameSample {
    let mut causes = causes_of(r);
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
        .all(crate::mesh::is_finite_point)
        && r.surface_rms.is_finite();
    if !finite {
        causes.push(Cause::NonFinite);
    }
    FrameSample {
        tre_mm,
        wall_ms: r.wall_ms,
        warm: r.warm,
        newton_iterations: r.newton_iterations,
        icp_iterations: r.icp_iterations,
        surface_rms_mm: r.surface_rms * scale * 1e3,
        causes,
        flags: r.flags.clone(),
        recovered_causes: recovered_causes_of(r),
        contact_force_n: r
            .contact_force
            .map(|c| [c.resultant.x, c.resultant.y, c.resultant.z]),
        contact_centre_m: r.contact_force.map(|c| (c.centre.coords * scale).into()),
        pose_uncertainty_mm: r.pose_uncertainty.map(|v| v * scale * 1e3),
        expected_error_mm: r.expected_error.map(|e| e.expected * scale * 1e3),
    }
}

/// The one-sided normal quantile (95 %) of [`Metrics::tre_upper_mm`].
pub const TRE_PREDICTION_Z: f64 = 1.645;

/// Sample standard deviation of `v` over `√len` (0 with fewer than 2 values).
fn standard_error(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return 0.0;
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (var / n).sqrt()
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
    /// Standard error of `tre_mean_mm` over frames, mm: the sample standard deviation of the
    /// frames' own mean TREs over √frames (0 with fewer than 2 frames). Frames of one
    /// sequence are correlated and their loads differ, so this is a scale of how far another
    /// draw of frames may land, not an exact confidence interval.
    pub tre_standard_error_mm: f64,
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
    /// Mean wall time of the warm frames, ms (0 without warm frames): a running session's
    /// cost per frame, its throughput's inverse.
    pub warm_ms_mean: f64,
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
            tre_standard_error_mm: standard_error(
                &samples
                    .iter()
                    .filter(|s| !s.tre_mm.is_empty())
                    .map(|s| s.tre_mm.iter().sum::<f64>() / s.tre_mm.len() as f64)
                    .collect::<Vec<_>>(),
            ),
            surface_rms_mm: samples.iter().map(|s| s.surface_rms_mm).sum::<f64>() / n,
            ms_p50: ms.median,
            ms_p95: ms.p95,
            ms_mean: ms.mean,
            warm_ms_p50: warm_ms.median,
            warm_ms_p95: warm_ms.p95,
            warm_ms_mean: warm_ms.mean,
            newton_per_frame: samples.iter().map(|s| s.newton_iterations).sum::<usize>() as f64 / n,
            icp_per_frame: samples.iter().map(|s| s.icp_iterations).sum::<usize>() as f64 / n,
            failed_frames: failed,
            failure_rate: failed as f64 / n,
            causes,
            recovered_frames: samples
                .iter()
                .filter(|s| {
                    s.flags
                        .iter()
                        .any(|f| matches!(f, crate::session::FrameFlag::Recovered(_)))
                })
                .count(),
            recovered_causes,
            peak_rss_mib: build.peak_rss_mib,
            build_ms: build.build_ms,
            nodes: build.nodes,
            cells: build.cells,
            cut_cells: build.cut_cells,
        }
    }

    /// Upper prediction of the mean TRE on other frames of the same kind, mm:
    /// `tre_mean_mm + z · tre_standard_error_mm` with `z` = [`TRE_PREDICTION_Z`].
    pub fn tre_upper_mm(&self) -> f64 {
        self.tre_mean_mm + TRE_PREDICTION_Z * self.tre_standard_error_mm
    }

    /// Whether every number is finite (what CI checks of `bench --quick`).
    pub fn all_finite(&self) -> bool {
        [
            self.tre_mean_mm,
            self.tre_p95_mm,
            self.tre_max_mm,
            self.tre_standard_error_mm,
            self.surface_rms_mm,
            self.ms_p50,
            self.ms_p95,
            self.ms_mean,
            self.warm_ms_p50,
            self.warm_ms_p95,
            self.warm_ms_mean,
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

/// One run of a scene over its workloads: the samples per workload and the build info (see
/// [`run_scene`]).
pub type SceneRun = (Vec<Vec<FrameSample>>, BuildInfo);

/// Merges repeated runs of the same configuration on the same workloads into one: the first
/// run's samples (TRE and iteration counts; the runs compute the same registrations, equal up
/// to rounding) with each frame's wall time replaced by its median over the runs, the median
/// build time and the largest peak memory. Timing noise (other processes, frequency changes,
/// the machine drifting ±10–20 % between hours) then moves a configuration's times much less
/// than one run does, and interleaving the runs over configurations spreads drift over all of
/// them. The first error of any run is returned, as is an error when the runs registered
/// different numbers of frames. `runs` must not be empty.
pub fn merge_repeats(runs: Vec<Result<SceneRun, String>>) -> Result<SceneRun, String> {
    let mut runs = runs
        .into_iter()
        .collect::<Result<Vec<SceneRun>, String>>()?;
    if runs.is_empty() {
        return Err("no run to merge".into());
    }
    // The project's quantile (`evaluation::percentile`): the mean of the middle two when even.
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        percentile(&v, 0.5)
    };
    let shape = |r: &SceneRun| r.0.iter().map(Vec::len).collect::<Vec<_>>();
    let first_shape = shape(&runs[0]);
    if let Some(k) = runs.iter().position(|r| shape(r) != first_shape) {
        return Err(format!(
            "repeat {k} registered {:?} frames per workload, the first {first_shape:?}",
            shape(&runs[k])
        ));
    }
    let build_ms = median(runs.iter().map(|r| r.1.build_ms).collect());
    let peak = runs
        .iter()
        .filter_map(|r| r.1.peak_rss_mib)
        .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))));
    let (first, rest) = runs.split_first_mut().expect("not empty");
    for (w, frames) in first.0.iter_mut().enumerate() {
        for (f, s) in frames.iter_mut().enumerate() {
            let walls = std::iter::once(s.wall_ms).chain(rest.iter().map(|r| r.0[w][f].wall_ms));
            s.wall_ms = median(walls.collect());
        }
    }
    let (samples, mut build) = runs.swap_remove(0);
    build.build_ms = build_ms;
    build.peak_rss_mib = peak;
    Ok((samples, build))
}

/// Builds a session for `scene` (rigid only when `rigid_only`) and registers each workload
/// with a fresh start (reset between workloads); returns the samples per workload and the
/// build info, with the peak memory of the whole run.
pub fn run_scene(
    scene: &LoadedScene,
    workloads: &[Workload],
    rigid_only: bool,
) -> Result<SceneRun, String> {
    memory::reset_peak();
    let t = Instant::now();
    let mut session = Session::from_scene(scene).map_err(|e| e.to_string())?;
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    session.settings.non_rigid = !rigid_only;
    let structures = session.model.structure_sizes();
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

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(tre: f64, wall_ms: f64) -> FrameSample {
        FrameSample {
            tre_mm: vec![tre],
            wall_ms,
            warm: true,
            newton_iterations: 2,
            icp_iterations: 3,
            surface_rms_mm: 1.0,
            causes: Vec::new(),
            flags: Vec::new(),
            recovered_causes: Vec::new(),
            contact_force_n: None,
            contact_centre_m: None,
            pose_uncertainty_mm: None,
            expected_error_mm: None,
        }
    }

    /// The standard error is over frames (each frame's own mean TRE), by the textbook
    /// formula: frames 1, 2, 3, 4 mm → sd √(5/3), SE √(5/3)/2; one frame → 0.
    #[test]
    fn tre_standard_error_is_over_frame_means() {
        let b = BuildInfo::default();
        let m = Metrics::of(
            &[
                sample(1.0, 1.0),
                sample(2.0, 1.0),
                FrameSample {
                    tre_mm: vec![2.0, 4.0],
                    ..sample(0.0, 1.0)
                },
                sample(4.0, 1.0),
            ],
            &b,
        );
        let expect = (5.0f64 / 3.0).sqrt() / 2.0;
        assert!((m.tre_standard_error_mm - expect).abs() < 1e-12, "{m:?}");
        assert!((m.tre_upper_mm() - (m.tre_mean_mm + TRE_PREDICTION_Z * expect)).abs() < 1e-12);
        assert_eq!(
            Metrics::of(&[sample(3.0, 1.0)], &b).tre_standard_error_mm,
            0.0
        );
    }

    fn run(walls: &[&[f64]], build_ms: f64, peak: Option<f64>) -> Result<SceneRun, String> {
        Ok((
            walls
                .iter()
                .map(|w| w.iter().map(|&t| sample(1.5, t)).collect())
                .collect(),
            BuildInfo {
                build_ms,
                nodes: 10,
                cells: 4,
                cut_cells: 2,
                peak_rss_mib: peak,
            },
        ))
    }

    #[test]
    fn repeats_merge_to_per_frame_medians() {
        let merged = merge_repeats(vec![
            run(&[&[3.0, 10.0], &[5.0]], 7.0, Some(100.0)),
            run(&[&[1.0, 30.0], &[6.0]], 9.0, Some(120.0)),
            run(&[&[2.0, 20.0], &[4.0]], 8.0, None),
        ])
        .unwrap();
        let walls: Vec<Vec<f64>> = merged
            .0
            .iter()
            .map(|w| w.iter().map(|s| s.wall_ms).collect())
            .collect();
        assert_eq!(walls, vec![vec![2.0, 20.0], vec![5.0]]);
        assert_eq!(merged.0[0][0].tre_mm, vec![1.5]);
        assert_eq!(merged.1.build_ms, 8.0);
        assert_eq!(merged.1.peak_rss_mib, Some(120.0));
        // An even count takes the mean of the middle two.
        let two =
            merge_repeats(vec![run(&[&[1.0]], 1.0, None), run(&[&[4.0]], 3.0, None)]).unwrap();
        assert_eq!(two.0[0][0].wall_ms, 2.5);
        assert_eq!(two.1.build_ms, 2.0);
    }

    #[test]
    fn a_failed_or_different_repeat_is_an_error() {
        let err = merge_repeats(vec![
            run(&[&[1.0]], 1.0, None),
            Err("model: no active cell".into()),
        ])
        .unwrap_err();
        assert!(err.contains("no active cell"), "{err}");
        let err = merge_repeats(vec![
            run(&[&[1.0]], 1.0, None),
            run(&[&[1.0, 2.0]], 1.0, None),
        ])
        .unwrap_err();
        assert!(err.contains("repeat 1"), "{err}");
        assert!(merge_repeats(Vec::new()).is_err());
    }
}
