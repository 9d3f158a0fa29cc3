//! [`run_sweep`]: every configuration on every workload, the Pareto front of TRE against
//! time per frame, and the [`BenchReport`] that `livereg bench` writes.

use std::time::Instant;

use serde::Serialize;

use super::config::{ModelConfig, ResolvedConfig};
use super::run::{merge_repeats, run_scene, FrameSample, Metrics, SceneRun};
use super::workload::Workload;
use crate::charts::pareto::{pareto_front, ChartPoint};
use crate::scene::LoadedScene;

/// One workload's share of a configuration's numbers.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WorkloadMetrics {
    /// Workload name.
    pub workload: String,
    /// Its numbers.
    pub metrics: Metrics,
}

/// One configuration's result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ConfigReport {
    /// Configuration name.
    pub name: String,
    /// Whether it is the scene's own model.
    pub default: bool,
    /// The model it resolved to (`None` if it could not be applied).
    pub config: Option<ResolvedConfig>,
    /// Numbers over all workloads (`None` if the model could not be built).
    pub metrics: Option<Metrics>,
    /// Numbers per workload.
    pub per_workload: Vec<WorkloadMetrics>,
    /// Whether it lies on the Pareto front of mean TRE against median ms per frame.
    pub pareto: bool,
    /// Why it has no numbers.
    pub error: Option<String>,
}

/// A workload as the report describes it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WorkloadInfo {
    /// Name.
    pub name: String,
    /// Frames.
    pub frames: usize,
    /// Largest true displacement, mm, when known.
    pub max_displacement_mm: Option<f64>,
    /// Law of the synthetic truth, when known.
    pub truth_law: Option<String>,
}

/// The machine the numbers were measured on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MachineInfo {
    /// Logical cores available to the process.
    pub cores: usize,
    /// Operating system and architecture.
    pub os: String,
    /// Build profile of the binary (`release` or `debug`): debug numbers are not speeds.
    pub profile: String,
}

impl MachineInfo {
    /// This machine and build.
    pub fn current() -> Self {
        Self {
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            os: format!("{} {}", std::env::consts::OS, std::env::consts::ARCH),
            profile: if cfg!(debug_assertions) {
                "debug"
            } else {
                "release"
            }
            .into(),
        }
    }
}

/// What `livereg bench` writes to `bench.json`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchReport {
    /// livereg version.
    pub version: String,
    /// Where it ran.
    pub machine: MachineInfo,
    /// The scene the configurations were applied to.
    pub scene: String,
    /// Whether this was the `--quick` sweep.
    pub quick: bool,
    /// Timing passes: every configuration ran this many times, pass after pass over all
    /// configurations, and each frame's time is its median over the passes (TRE and
    /// iteration counts are the first pass's; see [`merge_repeats`]).
    pub repeats: usize,
    /// The workloads every configuration ran.
    pub workloads: Vec<WorkloadInfo>,
    /// Rigid registration only, for reference (`None` when not run).
    pub rigid_only: Option<Metrics>,
    /// One entry per configuration, in sweep order.
    pub configs: Vec<ConfigReport>,
    /// Whether the default configuration is on the Pareto front.
    pub default_on_front: bool,
    /// Wall time of the sweep, s.
    pub wall_s: f64,
}

impl BenchReport {
    /// The chart's points: (median ms per frame, mean TRE) per configuration with numbers.
    pub fn chart_points(&self) -> Vec<ChartPoint> {
        self.configs
            .iter()
            .filter_map(|c| {
                c.metrics.as_ref().map(|m| ChartPoint {
                    label: c.name.clone(),
                    ms_per_frame: m.ms_p50,
                    tre_mm: m.tre_mean_mm,
                    is_default: c.default,
                })
            })
            .collect()
    }

    /// A text table of the configurations (mm, ms), Pareto members starred.
    pub fn table(&self) -> String {
        let mut s = format!(
            "{:<16} {:>7} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>7} {:>7} {:>6} {:>6}\n",
            "config",
            "nodes",
            "TRE mm",
            "p95 mm",
            "max mm",
            "ms p50",
            "ms p95",
            "warm p50",
            "warm p95",
            "newton",
            "MiB",
            "fail",
            "front"
        );
        let row = |name: &str, m: &Metrics, front: &str| {
            format!(
                "{:<16} {:>7} {:>8.2} {:>8.2} {:>8.2} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>7.1} {:>7} {:>6} {:>6}\n",
                name,
                m.nodes,
                m.tre_mean_mm,
                m.tre_p95_mm,
                m.tre_max_mm,
                m.ms_p50,
                m.ms_p95,
                m.warm_ms_p50,
                m.warm_ms_p95,
                m.newton_per_frame,
                m.peak_rss_mib.map_or("-".into(), |v| format!("{v:.0}")),
                m.failed_frames,
                front
            )
        };
        if let Some(m) = &self.rigid_only {
            s.push_str(&row("(rigid only)", m, ""));
        }
        for c in &self.configs {
            match &c.metrics {
                Some(m) => s.push_str(&row(&c.name, m, if c.pareto { "*" } else { "" })),
                None => s.push_str(&format!(
                    "{:<16} error: {}\n",
                    c.name,
                    c.error.as_deref().unwrap_or("?")
                )),
            }
        }
        s
    }
}

/// Runs every configuration of `configs` on `scene` over every workload (each workload from
/// a reset session), plus the rigid-only baseline when `rigid_baseline`, `repeats` times (at
/// least once; pass after pass over all configurations, times merged by [`merge_repeats`]),
/// and marks the Pareto front. `progress` is called with each configuration's name before
/// each of its runs. A configuration that cannot be applied or built is reported with its
/// error; the sweep goes on.
pub fn run_sweep(
    scene: &LoadedScene,
    configs: &[ModelConfig],
    workloads: &[Workload],
    rigid_baseline: bool,
    quick: bool,
    repeats: usize,
    progress: &mut dyn FnMut(&str),
) -> BenchReport {
    let start = Instant::now();
    let repeats = repeats.max(1);
    let mut rigid_runs = Vec::new();
    // Per configuration: the model it resolved to, and its runs.
    type Runs = (Option<ResolvedConfig>, Vec<Result<SceneRun, String>>);
    let mut runs: Vec<Runs> = configs.iter().map(|_| (None, Vec::new())).collect();
    for _ in 0..repeats {
        if rigid_baseline {
            progress("rigid only");
            rigid_runs.push(run_scene(scene, workloads, true));
        }
        for (c, (resolved, passes)) in configs.iter().zip(&mut runs) {
            progress(&c.name);
            let (r, run) = run_config_once(scene, c, workloads);
            *resolved = r;
            passes.push(run);
        }
    }
    // No baseline run (or a failed one) merges to an error: no rigid-only row.
    let rigid_only = merge_repeats(rigid_runs)
        .ok()
        .map(|(s, b)| Metrics::of(&s.concat(), &b));
    let reports = configs
        .iter()
        .zip(runs)
        .map(|(c, (resolved, passes))| report_of(c, workloads, resolved, merge_repeats(passes)))
        .collect();
    let mut report = BenchReport {
        version: env!("CARGO_PKG_VERSION").into(),
        machine: MachineInfo::current(),
        scene: scene.path.display().to_string(),
        quick,
        repeats,
        workloads: workloads
            .iter()
            .map(|w| WorkloadInfo {
                name: w.name.clone(),
                frames: w.frames.len(),
                max_displacement_mm: w.max_displacement_mm,
                truth_law: w.truth_law.clone(),
            })
            .collect(),
        rigid_only,
        configs: reports,
        default_on_front: false,
        wall_s: 0.0,
    };
    mark_front(&mut report);
    report.wall_s = start.elapsed().as_secs_f64();
    report
}

/// Runs one configuration once (see [`run_sweep`]).
pub fn run_config(scene: &LoadedScene, c: &ModelConfig, workloads: &[Workload]) -> ConfigReport {
    let (resolved, run) = run_config_once(scene, c, workloads);
    report_of(c, workloads, resolved, run)
}

/// Applies `c` to `scene` and runs it once: the model it resolved to (`None` when it could
/// not be applied) and the run.
fn run_config_once(
    scene: &LoadedScene,
    c: &ModelConfig,
    workloads: &[Workload],
) -> (Option<ResolvedConfig>, Result<SceneRun, String>) {
    match c.apply(scene) {
        Err(e) => (None, Err(e)),
        Ok(applied) => (
            Some(c.resolved(&applied)),
            run_scene(&applied, workloads, false),
        ),
    }
}

/// The report of configuration `c` from its (merged) run.
fn report_of(
    c: &ModelConfig,
    workloads: &[Workload],
    resolved: Option<ResolvedConfig>,
    run: Result<SceneRun, String>,
) -> ConfigReport {
    match run {
        Err(e) => ConfigReport {
            name: c.name.clone(),
            default: c.is_default(),
            config: resolved,
            metrics: None,
            per_workload: Vec::new(),
            pareto: false,
            error: Some(e),
        },
        Ok((samples, build)) => ConfigReport {
            name: c.name.clone(),
            default: c.is_default(),
            config: resolved,
            metrics: Some(Metrics::of(&samples.concat(), &build)),
            per_workload: workloads
                .iter()
                .zip(&samples)
                .map(|(w, s): (&Workload, &Vec<FrameSample>)| WorkloadMetrics {
                    workload: w.name.clone(),
                    metrics: Metrics::of(s, &build),
                })
                .collect(),
            pareto: false,
            error: None,
        },
    }
}

/// Sets `pareto` on the configurations of the front and `default_on_front`.
fn mark_front(report: &mut BenchReport) {
    let with: Vec<usize> = (0..report.configs.len())
        .filter(|&i| report.configs[i].metrics.is_some())
        .collect();
    let points = report.chart_points();
    for k in pareto_front(&points) {
        report.configs[with[k]].pareto = true;
    }
    report.default_on_front = report.configs.iter().any(|c| c.default && c.pareto);
}
