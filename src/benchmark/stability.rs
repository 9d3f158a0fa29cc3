//! The stability matrix: each registration method against one disturbance at a
//! time — cloud noise, outliers, visible fraction, deformation size, grid offset (cells cut
//! differently), Poisson's ratio and penalty stiffness — with the failure rate by cause, the
//! frames a recovery rescued, and the TRE of each cell. Nothing in it may panic or produce a
//! non-finite number; a panic is caught and reported as a crash of its cell.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::Instant;

use serde::Serialize;

use super::config::ModelConfig;
use super::run::{run_scene, Cause, Metrics};
use super::sweep::MachineInfo;
use super::workload::Workload;
use crate::grid::IntegrationMode;
use crate::mechanics::LawKind;
use crate::scene::LoadedScene;
use crate::synthetic::{solve_truth, ScenarioKind, SequenceSpec, SolvedTruth};

/// One disturbance the matrix varies (the others stay at the scenario's defaults). The
/// phantom's matrix varies [`Axis::ALL`] ([`Axis::values`]); the tool-indentation class's
/// ([`super::indentation_stability`]) varies [`Axis::INDENTATION`]
/// ([`Axis::indentation_values`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Axis {
    /// Gaussian noise of the cloud, mm (σ per axis).
    Noise,
    /// Share of the cloud that is outliers.
    Outliers,
    /// Share of the whole surface seen (1: everything the camera sees).
    Visible,
    /// Largest displacement of the liver surface, cm (the load is scaled to reach it).
    Deformation,
    /// Shift of the registration grid's origin, cell units, along each axis.
    GridOffset,
    /// Poisson's ratio of the registration model.
    Poisson,
    /// Factor on the penalty stiffness ramp.
    Penalty,
    /// Surface samples (inliers) per cloud, points (tool-indentation class).
    CloudSize,
    /// Constitutive law of the registration model: the value is an index into
    /// [`LawKind::ALL`] (tool-indentation class).
    Law,
}

impl Axis {
    /// Every axis of the phantom's matrix, in report order.
    pub const ALL: [Axis; 7] = [
        Axis::Noise,
        Axis::Outliers,
        Axis::Visible,
        Axis::Deformation,
        Axis::GridOffset,
        Axis::Poisson,
        Axis::Penalty,
    ];

    /// Every axis of the tool-indentation class's matrix, in report order.
    pub const INDENTATION: [Axis; 6] = [
        Axis::Noise,
        Axis::Visible,
        Axis::CloudSize,
        Axis::Outliers,
        Axis::Poisson,
        Axis::Law,
    ];

    /// Name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Axis::Noise => "noise",
            Axis::Outliers => "outliers",
            Axis::Visible => "visible",
            Axis::Deformation => "deformation",
            Axis::GridOffset => "grid-offset",
            Axis::Poisson => "poisson",
            Axis::Penalty => "penalty",
            Axis::CloudSize => "cloud-size",
            Axis::Law => "law",
        }
    }

    /// The values of the phantom's full matrix, or (`reduced`) its two ends (empty for an axis
    /// that matrix does not vary).
    pub fn values(self, reduced: bool) -> Vec<f64> {
        let all: &[f64] = match self {
            Axis::Noise => &[0.0, 1.0, 2.0, 4.0],
            Axis::Outliers => &[0.0, 0.1, 0.3],
            Axis::Visible => &[0.1, 0.2, 0.4, 1.0],
            Axis::Deformation => &[1.0, 3.0, 6.0, 9.0],
            Axis::GridOffset => &[0.0, 0.25, 0.5, 0.75],
            Axis::Poisson => &[0.3, 0.45, 0.49, 0.499],
            Axis::Penalty => &[0.1, 1.0, 10.0, 100.0],
            Axis::CloudSize | Axis::Law => &[],
        };
        ends(all, reduced)
    }

    /// The values of the tool-indentation class's full matrix, or (`reduced`) its two ends
    /// (empty for an axis that matrix does not vary): noise 0–3 mm per axis, 5–25 % of the
    /// surface seen, 150–1,000 points, 0–30 % outliers, the model's ν 0.3–0.499 (the truth's is
    /// 0.49) and its law (linear, corotated, neo-Hookean — the default). The fixture's cloud
    /// defaults ([`crate::synthetic::indentation::IndentationCloudSpec::default`]: 1.5 mm,
    /// 15 %, 500 points, no outliers) are among the values.
    pub fn indentation_values(self, reduced: bool) -> Vec<f64> {
        let law = |l: LawKind| LawKind::ALL.iter().position(|&k| k == l).unwrap_or(0) as f64;
        let all: Vec<f64> = match self {
            Axis::Noise => vec![0.0, 0.5, 1.5, 3.0],
            Axis::Visible => vec![0.05, 0.1, 0.15, 0.25],
            Axis::CloudSize => vec![150.0, 300.0, 500.0, 1000.0],
            Axis::Outliers => vec![0.0, 0.1, 0.3],
            Axis::Poisson => vec![0.3, 0.45, 0.49, 0.499],
            Axis::Law => vec![
                law(LawKind::Linear),
                law(LawKind::Corotated),
                law(LawKind::NeoHookean),
            ],
            Axis::Deformation | Axis::GridOffset | Axis::Penalty => vec![],
        };
        ends(&all, reduced)
    }

    /// The law a value of [`Axis::Law`] stands for (`None`: not an index of
    /// [`LawKind::ALL`]).
    pub fn law_of(value: f64) -> Option<LawKind> {
        (value >= 0.0 && value.fract() == 0.0)
            .then(|| LawKind::ALL.get(value as usize).copied())
            .flatten()
    }

    /// A value as the table shows it.
    pub fn label(self, v: f64) -> String {
        match self {
            Axis::Noise => format!("{v} mm"),
            Axis::Outliers => format!("{:.0} %", 100.0 * v),
            Axis::Visible if v >= 1.0 => "all seen".into(),
            Axis::Visible => format!("{:.0} %", 100.0 * v),
            Axis::Deformation => format!("{v} cm"),
            Axis::GridOffset => format!("{v} h"),
            Axis::Poisson => format!("ν {v}"),
            Axis::Penalty => format!("k × {v}"),
            Axis::CloudSize => format!("{v} pts"),
            Axis::Law => Axis::law_of(v).map_or_else(
                || format!("law #{v}"),
                |l| super::config::law_name(l).to_string(),
            ),
        }
    }

    /// Whether the axis changes the data (a new synthetic sequence) rather than the model.
    pub fn changes_data(self) -> bool {
        matches!(
            self,
            Axis::Noise | Axis::Outliers | Axis::Visible | Axis::Deformation | Axis::CloudSize
        )
    }
}

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct StabilityOptions {
    /// The scenario whose sequence is disturbed.
    pub scenario: ScenarioKind,
    /// Frames per sequence.
    pub frames: usize,
    /// Only the two ends of each axis.
    pub reduced: bool,
    /// The methods (model configurations) compared.
    pub methods: Vec<ModelConfig>,
    /// Law of the synthetic truth (`None`: [`TruthModel`](crate::synthetic::TruthModel)'s default, neo-Hookean).
    pub truth_law: Option<LawKind>,
}

impl StabilityOptions {
    /// The matrix of the docs (`reduced = false`) or of CI (`reduced = true`): tool-push,
    /// weighted-cell, finite-cell and full-cell integration and weighted-cell with a
    /// coarse-to-fine start (cells ×2) (reduced: weighted- and full-cell), 4 frames
    /// (reduced: 2).
    pub fn standard(reduced: bool) -> Self {
        let method = |m: IntegrationMode| ModelConfig {
            name: m.name().into(),
            integration: Some(m),
            ..ModelConfig::default()
        };
        let mut methods = vec![method(IntegrationMode::WeightedCell)];
        if !reduced {
            methods.push(method(IntegrationMode::FiniteCell));
        }
        methods.push(method(IntegrationMode::FullCell));
        if !reduced {
            methods.push(ModelConfig {
                name: "weighted-cell, coarse start".into(),
                integration: Some(IntegrationMode::WeightedCell),
                coarse_to_fine: Some(2.0),
                ..ModelConfig::default()
            });
        }
        Self {
            scenario: ScenarioKind::ToolPush,
            frames: if reduced { 2 } else { 4 },
            reduced,
            methods,
            truth_law: None,
        }
    }
}

/// One cell of the matrix: a method under one disturbance.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StabilityCell {
    /// The axis.
    pub axis: Axis,
    /// The value on it.
    pub value: f64,
    /// The value as shown.
    pub label: String,
    /// The method.
    pub method: String,
    /// Largest true surface displacement of the cell's sequence, mm.
    pub max_displacement_mm: Option<f64>,
    /// The non-rigid registration's numbers (`None` with `error`).
    pub metrics: Option<Metrics>,
    /// Mean TRE after rigid registration only, mm (same frames).
    pub tre_rigid_mm: Option<f64>,
    /// Why the cell has no numbers: the truth could not be simulated, the model could not be
    /// built, or (never expected) a panic.
    pub error: Option<String>,
    /// Whether the cell panicked (caught).
    pub crashed: bool,
}

/// The whole matrix.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StabilityReport {
    /// Where it ran.
    pub machine: MachineInfo,
    /// Scenario.
    pub scenario: String,
    /// Frames per sequence.
    pub frames: usize,
    /// Constitutive law of the synthetic truth (scene-file name).
    pub truth_law: String,
    /// Whether this is the reduced (CI) matrix.
    pub reduced: bool,
    /// The cells, axis by axis, value by value, method by method.
    pub cells: Vec<StabilityCell>,
    /// Cells that panicked.
    pub crashes: usize,
    /// Frames with a non-finite output, over all cells.
    pub non_finite_frames: usize,
    /// Wall time, s.
    pub wall_s: f64,
}

impl StabilityReport {
    /// The matrix as a Markdown table: one row per axis value, one column per method, each
    /// entry `TRE mm · failed % (causes) · recovered`.
    pub fn markdown(&self) -> String {
        let mut methods: Vec<&str> = Vec::new();
        for c in &self.cells {
            if !methods.contains(&c.method.as_str()) {
                methods.push(&c.method);
            }
        }
        let mut s = format!(
            "| axis | value | max disp | rigid TRE | {} |\n",
            methods.join(" | ")
        );
        s.push_str(&format!(
            "|---|---|---|---|{}\n",
            "---|".repeat(methods.len())
        ));
        let mut k = 0;
        while k < self.cells.len() {
            let first = &self.cells[k];
            let row: Vec<&StabilityCell> = self.cells[k..]
                .iter()
                .take_while(|c| c.axis == first.axis && c.value == first.value)
                .collect();
            k += row.len();
            let rigid = row.iter().find_map(|c| c.tre_rigid_mm);
            s.push_str(&format!(
                "| {} | {} | {} | {} |",
                first.axis.name(),
                first.label,
                first
                    .max_displacement_mm
                    .map_or("–".into(), |d| format!("{d:.0} mm")),
                rigid.map_or("–".into(), |t| format!("{t:.2} mm")),
            ));
            for m in &methods {
                let entry = match row.iter().find(|c| c.method == *m) {
                    None => "–".to_string(),
                    Some(c) => cell_text(c),
                };
                s.push_str(&format!(" {entry} |"));
            }
            s.push('\n');
        }
        s
    }
}

/// One table entry: TRE, failures by cause, recoveries.
fn cell_text(c: &StabilityCell) -> String {
    let Some(m) = &c.metrics else {
        return format!(
            "{}: {}",
            if c.crashed { "CRASH" } else { "n/a" },
            c.error.as_deref().unwrap_or("?").replace('|', "/")
        );
    };
    let mut t = format!("{:.2} mm", m.tre_mean_mm);
    let failures: Vec<String> = m
        .causes
        .iter()
        .filter(|(c, _)| c.is_failure())
        .map(|(c, n)| format!("{} {n}", c.name()))
        .collect();
    t.push_str(&format!(" · fail {:.0} %", 100.0 * m.failure_rate));
    if !failures.is_empty() {
        t.push_str(&format!(" ({})", failures.join(", ")));
    }
    if m.recovered_frames > 0 {
        let rescued: Vec<String> = m
            .recovered_causes
            .iter()
            .map(|(c, n)| format!("{} {n}", c.name()))
            .collect();
        t.push_str(&format!(
            " · recovered {} ({})",
            m.recovered_frames,
            rescued.join(", ")
        ));
    }
    if let Some(n) = m.causes.get(&Cause::IcpCap) {
        t.push_str(&format!(" · icp-cap {n}"));
    }
    t
}

/// Runs the matrix on `scene` (which must have a camera, like the phantom). `progress` is
/// called with a description of each cell before it runs.
pub fn run_matrix(
    scene: &LoadedScene,
    options: &StabilityOptions,
    progress: &mut dyn FnMut(&str),
) -> StabilityReport {
    let start = Instant::now();
    let matrix = Matrix::new(scene, options);
    let mut cells = Vec::new();
    for axis in Axis::ALL {
        for value in axis.values(options.reduced) {
            let data = matrix.workload(axis, value);
            let rigid = matrix.rigid_tre(&data);
            for method in &options.methods {
                progress(&format!(
                    "{} {} {}",
                    axis.name(),
                    axis.label(value),
                    method.name
                ));
                cells.push(matrix.cell(axis, value, method, &data, rigid));
            }
        }
    }
    matrix.report(options, cells, start)
}

/// What every cell of the matrix shares: the scene, its length scale, and the default
/// sequence the data axes disturb.
struct Matrix<'a> {
    /// The scene registered.
    scene: &'a LoadedScene,
    /// Metres per scene unit.
    scale: f64,
    /// The scenario's default sequence, with the options' frames and truth law.
    base_spec: SequenceSpec,
    /// The default sequence's truth, which the cloud axes (noise, outliers, visible) share:
    /// they change what the camera sees, not the liver.
    base_truth: Result<SolvedTruth, String>,
    /// The default sequence's workload (or why it could not be simulated).
    base: Result<Workload, String>,
    /// The default sequence's largest surface displacement, mm (`None`: not simulated, or
    /// no motion).
    base_disp: Option<f64>,
}

impl<'a> Matrix<'a> {
    /// Simulates the default sequence of `options` on `scene`.
    fn new(scene: &'a LoadedScene, options: &StabilityOptions) -> Self {
        let scale = scene.length_scale();
        let mut base_spec = SequenceSpec::phantom_default(options.scenario);
        base_spec.frames = options.frames.max(1);
        if let Some(law) = options.truth_law {
            base_spec.truth.law = law;
        }
        let base_truth = solve(scene, &base_spec);
        let base = with_clouds(&base_truth, &base_spec, scale);
        let base_disp = base
            .as_ref()
            .ok()
            .and_then(|w| w.max_displacement_mm)
            .filter(|d| *d > 0.0);
        Matrix {
            scene,
            scale,
            base_spec,
            base_truth,
            base,
            base_disp,
        }
    }

    /// The data of the cells at `value` on `axis`: a new sequence for an axis that changes
    /// the data (noise in mm, outlier and visible fractions, deformation in cm), else the
    /// default one.
    fn workload(&self, axis: Axis, value: f64) -> Result<Workload, String> {
        if !axis.changes_data() {
            return self.base.clone();
        }
        let mut spec = self.base_spec.clone();
        match axis {
            Axis::Noise => spec.cloud.noise_sigma = value * 1e-3,
            Axis::Outliers => spec.cloud.outlier_fraction = value,
            Axis::Visible => spec.cloud.visible_fraction = (value < 1.0).then_some(value),
            _ => {
                // Deformation: scale the load by the wanted over the default
                // displacement (the response is not linear: the table shows what
                // was reached).
                if let Some(d) = self.base_disp {
                    spec.magnitude *= value * 10.0 / d;
                }
            }
        }
        match axis {
            Axis::Deformation if self.base_disp.is_none() => {
                Err("the default sequence could not be simulated".into())
            }
            Axis::Deformation => with_clouds(&solve(self.scene, &spec), &spec, self.scale),
            _ => with_clouds(&self.base_truth, &spec, self.scale),
        }
    }

    /// Mean TRE after rigid registration only of `data`, mm (`None`: no data, the
    /// registration failed, or it panicked).
    fn rigid_tre(&self, data: &Result<Workload, String>) -> Option<f64> {
        data.as_ref().ok().and_then(|w| {
            catch_unwind(AssertUnwindSafe(|| {
                run_scene(self.scene, std::slice::from_ref(w), true).ok()
            }))
            .ok()
            .flatten()
            .map(|(s, b)| Metrics::of(&s.concat(), &b).tre_mean_mm)
        })
    }

    /// One cell: `method` at `value` on `axis` registering `data` (`rigid`: the rigid-only
    /// TRE of the same data, mm). A panic is caught and reported as a crash.
    fn cell(
        &self,
        axis: Axis,
        value: f64,
        method: &ModelConfig,
        data: &Result<Workload, String>,
        rigid: Option<f64>,
    ) -> StabilityCell {
        let config = method_config(method, axis, value);
        let mut cell = StabilityCell {
            axis,
            value,
            label: axis.label(value),
            method: method.name.clone(),
            max_displacement_mm: data.as_ref().ok().and_then(|w| w.max_displacement_mm),
            metrics: None,
            tre_rigid_mm: rigid,
            error: None,
            crashed: false,
        };
        match data {
            Err(e) => cell.error = Some(e.clone()),
            Ok(w) => {
                let run = catch_unwind(AssertUnwindSafe(|| {
                    let applied = config.apply(self.scene)?;
                    run_scene(&applied, std::slice::from_ref(w), false)
                }));
                match run {
                    Err(p) => {
                        cell.crashed = true;
                        cell.error = Some(format!("panic: {}", panic_text(&p)));
                    }
                    Ok(Err(e)) => cell.error = Some(e),
                    Ok(Ok((s, b))) => cell.metrics = Some(Metrics::of(&s.concat(), &b)),
                }
            }
        }
        cell
    }

    /// The report of `cells`, with the crash and non-finite frame counts and the wall time
    /// since `start` (s).
    fn report(
        &self,
        options: &StabilityOptions,
        cells: Vec<StabilityCell>,
        start: Instant,
    ) -> StabilityReport {
        StabilityReport {
            machine: MachineInfo::current(),
            scenario: options.scenario.name().into(),
            frames: self.base_spec.frames,
            truth_law: super::config::law_name(self.base_spec.truth.law).into(),
            reduced: options.reduced,
            crashes: cells.iter().filter(|c| c.crashed).count(),
            non_finite_frames: cells
                .iter()
                .filter_map(|c| c.metrics.as_ref())
                .map(|m| m.causes.get(&Cause::NonFinite).copied().unwrap_or(0))
                .sum(),
            cells,
            wall_s: start.elapsed().as_secs_f64(),
        }
    }
}

/// The truth of `spec` solved on `scene`; a panic while solving becomes an error.
fn solve(scene: &LoadedScene, spec: &SequenceSpec) -> Result<SolvedTruth, String> {
    catch_unwind(AssertUnwindSafe(|| solve_truth(scene, spec)))
        .map_err(|p| format!("panic while simulating the truth: {}", panic_text(&p)))?
        .map_err(|e| format!("truth: {e}"))
}

/// The workload of `truth` seen with `spec`'s clouds (`scale`: metres per scene unit); a
/// panic while synthesizing becomes an error.
fn with_clouds(
    truth: &Result<SolvedTruth, String>,
    spec: &SequenceSpec,
    scale: f64,
) -> Result<Workload, String> {
    let truth = truth.as_ref().map_err(|e| e.clone())?;
    catch_unwind(AssertUnwindSafe(|| truth.sequence(&spec.cloud)))
        .map_err(|p| format!("panic while synthesizing the clouds: {}", panic_text(&p)))?
        .map(|s| Workload::from_sequence(&s, scale))
        .map_err(|e| format!("truth: {e}"))
}

/// `method` with the model axis `axis` set to `value` (grid offset in cells, Poisson's
/// ratio, penalty factor); unchanged for an axis that changes the data.
fn method_config(method: &ModelConfig, axis: Axis, value: f64) -> ModelConfig {
    match axis {
        Axis::GridOffset => ModelConfig {
            origin_offset: Some([value; 3]),
            ..method.clone()
        },
        Axis::Poisson => ModelConfig {
            poisson_ratio: Some(value),
            ..method.clone()
        },
        Axis::Penalty => ModelConfig {
            penalty_factor: Some(value),
            ..method.clone()
        },
        _ => method.clone(),
    }
}

/// `all`, or (`reduced`) its first and last values.
fn ends(all: &[f64], reduced: bool) -> Vec<f64> {
    match all {
        [first, .., last] if reduced => vec![*first, *last],
        _ => all.to_vec(),
    }
}

/// The message of a caught panic.
pub(crate) fn panic_text(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".into())
}
