//! The tool-indentation class as bench workloads and its metrics: node error over
//! the truth mesh's nodes (mean, p95), the error inside the indented region, and each frame's
//! error against no registration.

use crate::simulation::FromScene;
use nalgebra::{Point3, Rotation3, Unit, Vector3};
use serde::Serialize;

use super::run::{run_workload, FrameSample};
use super::workload::Workload;
use crate::charts::pareto::ChartPoint;
use crate::evaluation::percentile;
use crate::geometry::Camera;
use crate::registration::RigidTransform;
use crate::scene::{LoadedScene, RigidMode};
use crate::session::{Frame, Session};
use crate::synthetic::indentation::{
    indentation_sequence, IndentationCloudSpec, IndentationFrame, IndentationTruth,
};

/// Name of the structure holding every truth node in the indentation scene.
pub const NODES_STRUCTURE: &str = "nodes";

/// A frame is "worse than no registration" when its mean node error exceeds this times the
/// rest shape's (no frame may end more than 10 % worse than no registration).
pub const WORSE_THAN_NONE_FACTOR: f64 = 1.1;

/// The frames of an indentation sequence as a [`Workload`] in a scene whose unit is `scale`
/// metres; with `with_camera`, every frame carries the camera that saw it.
pub fn indentation_workload(
    truth: &IndentationTruth,
    frames: &[IndentationFrame],
    scale: f64,
    with_camera: bool,
) -> Workload {
    let to_scene = |p: &Point3<f64>| p / scale;
    Workload {
        name: format!("tool-indentation/{}/{}", truth.sequence, truth.law),
        frames: frames
            .iter()
            .enumerate()
            .map(|(k, f)| Frame {
                source: crate::synthetic::sequence::frame_file_name(k, frames.len()),
                points: f.cloud.iter().map(to_scene).collect(),
                camera: with_camera.then(|| Camera {
                    position: to_scene(&f.camera.position),
                    look_at: to_scene(&f.camera.look_at),
                    ..f.camera
                }),
            })
            .collect(),
        truth: frames
            .iter()
            .map(|f| {
                vec![(
                    NODES_STRUCTURE.to_string(),
                    f.truth_nodes.iter().map(to_scene).collect(),
                )]
            })
            .collect(),
        max_displacement_mm: Some(
            truth
                .displacements
                .iter()
                .flatten()
                .map(|u| u.norm())
                .fold(0.0, f64::max)
                * 1e3,
        ),
        truth_law: Some(truth.law.clone()),
    }
}

/// Per-frame node errors of an indentation run, mm.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IndentationFrameMetrics {
    /// Mean node error of the registration.
    pub mean_mm: f64,
    /// Mean node error inside the indented region.
    pub region_mean_mm: f64,
    /// Mean node error of the rest shape (no registration).
    pub none_mean_mm: f64,
    /// Mean node error of the rest shape inside the indented region.
    pub none_region_mean_mm: f64,
    /// Wall time, ms.
    pub wall_ms: f64,
    /// Whether the frame failed.
    pub failed: bool,
    /// Magnitude of the truth's tool force and of the registration's estimate, N.
    pub force_true_n: f64,
    /// See `force_true_n` (`None`: no estimate).
    pub force_estimate_n: Option<f64>,
    /// |estimate − truth| / |truth| of the force vector (`None`: no estimate).
    pub force_relative_error: Option<f64>,
    /// Distance from the estimate's centre to the truth's (the contact nodes' deformed
    /// positions weighted by their reactions), mm (`None`: no estimate).
    pub force_centre_error_mm: Option<f64>,
    /// The frame's pose uncertainty (`FrameResult::pose_uncertainty`), mm; `None` when the
    /// pose was given.
    pub pose_uncertainty_mm: Option<f64>,
    /// The frame's expected error (`FrameResult::expected_error`), mm.
    pub expected_error_mm: Option<f64>,
}

/// What an indentation run gave, mm and ms.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IndentationMetrics {
    /// Workload name.
    pub workload: String,
    /// Mean and 95th percentile node error over every node of every frame.
    pub mean_mm: f64,
    /// See `mean_mm`.
    pub p95_mm: f64,
    /// The same for no registration (the rest shape).
    pub none_mean_mm: f64,
    /// See `none_mean_mm`.
    pub none_p95_mm: f64,
    /// Mean node error inside the indented region, registered and not.
    pub region_mean_mm: f64,
    /// See `region_mean_mm`.
    pub none_region_mean_mm: f64,
    /// Frames whose mean error exceeds [`WORSE_THAN_NONE_FACTOR`] × no registration's.
    pub frames_worse_than_none: usize,
    /// Failed frames.
    pub failed_frames: usize,
    /// Median over frames of the contact force's relative error |F̂ − F| / |F|, for the
    /// frames whose true force exceeds a quarter of the sequence's largest (`None`: no
    /// estimate).
    pub force_relative_error_median: Option<f64>,
    /// Median over the same frames of the distance between the estimated and the true force
    /// centres, mm.
    pub force_centre_error_median_mm: Option<f64>,
    /// The largest pose uncertainty over the frames (`FrameResult::pose_uncertainty`), mm;
    /// `None` when the pose was given.
    pub pose_uncertainty_max_mm: Option<f64>,
    /// Frames flagged `pose_uncertain`.
    pub pose_uncertain_frames: usize,
    /// The share of frames whose expected error is at least their true mean node error
    /// (`None`: no frame has an estimate).
    pub expected_error_bounded: Option<f64>,
    /// Median over frames of expected error / true mean node error.
    pub expected_error_ratio_median: Option<f64>,
    /// Median and 95th percentile wall time of the warm frames, ms.
    pub warm_ms_p50: f64,
    /// See `warm_ms_p50`.
    pub warm_ms_p95: f64,
    /// Per frame.
    pub frames: Vec<IndentationFrameMetrics>,
}

/// Grades `samples` (from [`super::run_workload`] on the workload of `truth` and `frames`,
/// whose only structure is [`NODES_STRUCTURE`]) against the truth and against no registration.
/// `offset` is the model → cloud transform of the clouds.
pub fn indentation_metrics(
    name: &str,
    truth: &IndentationTruth,
    frames: &[IndentationFrame],
    offset: &RigidTransform,
    samples: &[FrameSample],
) -> IndentationMetrics {
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let rotation = offset.rotation;
    let rest_nodes = offset.apply_all(&truth.nodes);
    let mut all = Vec::new();
    let mut none_all = Vec::new();
    let mut per_frame = Vec::new();
    for (k, (f, s)) in frames.iter().zip(samples).enumerate() {
        let region = truth.indented_region(k);
        // The truth's force in the clouds' frame: rotated like the clouds.
        let truth_force = rotation * truth.frames[k].force;
        let estimate = s.contact_force_n.map(Vector3::from);
        let truth_centre = offset.apply(&truth.frames[k].force_centre);
        let centre_error_mm = s
            .contact_centre_m
            .map(|c| (Point3::from(c) - truth_centre).norm() * 1e3);
        let none: Vec<f64> = f
            .truth_nodes
            .iter()
            .zip(&rest_nodes)
            .map(|(t, r)| (t - r).norm() * 1e3)
            .collect();
        let in_region = |v: &[f64]| -> Vec<f64> {
            v.iter()
                .zip(&region)
                .filter(|(_, &r)| r)
                .map(|(e, _)| *e)
                .collect()
        };
        per_frame.push(IndentationFrameMetrics {
            mean_mm: mean(&s.tre_mm),
            region_mean_mm: mean(&in_region(&s.tre_mm)),
            none_mean_mm: mean(&none),
            none_region_mean_mm: mean(&in_region(&none)),
            wall_ms: s.wall_ms,
            failed: s.failed(),
            force_true_n: truth_force.norm(),
            force_estimate_n: estimate.map(|e| e.norm()),
            force_relative_error: estimate
                .map(|e| (e - truth_force).norm() / truth_force.norm().max(1e-12)),
            force_centre_error_mm: centre_error_mm,
            pose_uncertainty_mm: s.pose_uncertainty_mm,
            expected_error_mm: s.expected_error_mm,
        });
        all.extend_from_slice(&s.tre_mm);
        none_all.extend(none);
    }
    let p95 = |mut v: Vec<f64>| {
        if v.is_empty() {
            return 0.0;
        }
        v.sort_by(f64::total_cmp);
        percentile(&v, 0.95)
    };
    let mut warm: Vec<f64> = samples
        .iter()
        .filter(|s| s.warm)
        .map(|s| s.wall_ms)
        .collect();
    warm.sort_by(f64::total_cmp);
    let q = |p: f64| {
        if warm.is_empty() {
            0.0
        } else {
            percentile(&warm, p)
        }
    };
    let region_mean = |pick: fn(&IndentationFrameMetrics) -> f64| {
        mean(&per_frame.iter().map(pick).collect::<Vec<_>>())
    };
    IndentationMetrics {
        workload: name.to_string(),
        mean_mm: mean(&all),
        p95_mm: p95(all),
        none_mean_mm: mean(&none_all),
        none_p95_mm: p95(none_all),
        region_mean_mm: region_mean(|f| f.region_mean_mm),
        none_region_mean_mm: region_mean(|f| f.none_region_mean_mm),
        frames_worse_than_none: per_frame
            .iter()
            .filter(|f| f.mean_mm > WORSE_THAN_NONE_FACTOR * f.none_mean_mm)
            .count(),
        failed_frames: per_frame.iter().filter(|f| f.failed).count(),
        force_relative_error_median: loaded_median(&per_frame, |f| f.force_relative_error),
        force_centre_error_median_mm: loaded_median(&per_frame, |f| f.force_centre_error_mm),
        pose_uncertainty_max_mm: per_frame
            .iter()
            .filter_map(|f| f.pose_uncertainty_mm)
            .reduce(f64::max),
        pose_uncertain_frames: samples
            .iter()
            .filter(|s| s.flags.contains(&crate::session::FrameFlag::PoseUncertain))
            .count(),
        warm_ms_p50: q(0.5),
        warm_ms_p95: q(0.95),
        expected_error_bounded: expected_error_bounded(&per_frame),
        expected_error_ratio_median: expected_error_ratio_median(&per_frame),
        frames: per_frame,
    }
}

/// The share of `frames` with an expected error whose estimate is at least their mean node
/// error.
fn expected_error_bounded(frames: &[IndentationFrameMetrics]) -> Option<f64> {
    let with: Vec<&IndentationFrameMetrics> = frames
        .iter()
        .filter(|f| f.expected_error_mm.is_some())
        .collect();
    (!with.is_empty()).then(|| {
        with.iter()
            .filter(|f| f.expected_error_mm.is_some_and(|e| e >= f.mean_mm))
            .count() as f64
            / with.len() as f64
    })
}

/// The median over `frames` of expected error / mean node error.
fn expected_error_ratio_median(frames: &[IndentationFrameMetrics]) -> Option<f64> {
    let mut r: Vec<f64> = frames
        .iter()
        .filter_map(|f| f.expected_error_mm.map(|e| e / f.mean_mm.max(1e-9)))
        .collect();
    if r.is_empty() {
        return None;
    }
    r.sort_by(f64::total_cmp);
    Some(percentile(&r, 0.5))
}

/// Median of `pick` over the frames whose true force exceeds a quarter of the sequence's
/// largest (the loaded frames; `None` when none has a value).
fn loaded_median(
    frames: &[IndentationFrameMetrics],
    pick: fn(&IndentationFrameMetrics) -> Option<f64>,
) -> Option<f64> {
    let largest = frames.iter().map(|f| f.force_true_n).fold(0.0, f64::max);
    let mut v: Vec<f64> = frames
        .iter()
        .filter(|f| f.force_true_n > 0.25 * largest)
        .filter_map(pick)
        .collect();
    v.sort_by(f64::total_cmp);
    (!v.is_empty()).then(|| percentile(&v, 0.5))
}

/// How the clouds of an indentation case reach the registration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum IndentationVariant {
    /// Clouds in the model's frame (`rigid = "none"`), no camera pose known: the third-party
    /// benchmark's conditions.
    NoCamera,
    /// Clouds in the model's frame, each frame with the camera that saw it.
    Camera,
    /// Clouds moved by an unknown rigid offset (6°, 1.5 cm), `rigid = "icp"`, no camera.
    RigidIcp,
}

impl IndentationVariant {
    /// Every variant.
    pub const ALL: [IndentationVariant; 3] = [
        IndentationVariant::NoCamera,
        IndentationVariant::Camera,
        IndentationVariant::RigidIcp,
    ];

    /// Name in reports and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            IndentationVariant::NoCamera => "no-camera",
            IndentationVariant::Camera => "camera",
            IndentationVariant::RigidIcp => "rigid-icp",
        }
    }

    /// The variant called `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|v| v.name() == name)
    }

    /// The model → camera offset of the clouds.
    pub fn offset(self) -> Option<RigidTransform> {
        match self {
            IndentationVariant::RigidIcp => Some(RigidTransform::new(
                Rotation3::from_axis_angle(
                    &Unit::new_normalize(Vector3::new(0.4, 1.0, 0.3)),
                    6f64.to_radians(),
                ),
                Vector3::new(0.012, -0.008, 0.006),
            )),
            _ => None,
        }
    }
}

/// One indentation case: a truth, its clouds and how they are registered.
#[derive(Debug, Clone)]
pub struct IndentationCase {
    /// The truth.
    pub truth: IndentationTruth,
    /// The clouds (camera frame) with the true nodes.
    pub frames: Vec<IndentationFrame>,
    /// How they are registered.
    pub variant: IndentationVariant,
}

impl IndentationCase {
    /// Name: `sequence/law/variant`.
    pub fn name(&self) -> String {
        format!(
            "{}/{}/{}",
            self.truth.sequence,
            self.truth.law,
            self.variant.name()
        )
    }
}

/// The cases of the fixture in `dir`: every sequence × law × variant given, with at most
/// `frames` frames each (`None`: all), clouds from [`IndentationCloudSpec::default`].
pub fn indentation_cases(
    dir: &std::path::Path,
    sequences: &[&str],
    laws: &[&str],
    variants: &[IndentationVariant],
    frames: Option<usize>,
) -> Result<Vec<IndentationCase>, String> {
    let mut out = Vec::new();
    for seq in sequences {
        for law in laws {
            let mut truth = IndentationTruth::load(dir, seq, law).map_err(|e| e.to_string())?;
            if let Some(n) = frames {
                truth.truncate(n);
            }
            for &variant in variants {
                let spec = IndentationCloudSpec {
                    rigid_offset: variant.offset(),
                    ..IndentationCloudSpec::default()
                };
                let clouds =
                    indentation_sequence(&truth, &spec).map_err(|e| format!("{seq}/{law}: {e}"))?;
                out.push(IndentationCase {
                    truth: truth.clone(),
                    frames: clouds,
                    variant,
                });
            }
        }
    }
    Ok(out)
}

/// The scene a case is registered with: `scene` with `rigid = "icp"` for
/// [`IndentationVariant::RigidIcp`], `"none"` otherwise.
pub fn scene_for(scene: &LoadedScene, variant: IndentationVariant) -> LoadedScene {
    let mut s = scene.clone();
    let r = s.scene.registration.get_or_insert_with(Default::default);
    r.rigid = match variant {
        IndentationVariant::RigidIcp => RigidMode::Icp,
        _ => RigidMode::Identity,
    };
    s
}

/// Registers every case with a fresh session of `scene` (adapted by [`scene_for`]) and grades
/// it; `progress` is called with each case's name.
pub fn run_indentation(
    scene: &LoadedScene,
    cases: &[IndentationCase],
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<IndentationMetrics>, String> {
    let scale = scene.length_scale();
    let mut out = Vec::new();
    for case in cases {
        progress(&case.name());
        let applied = scene_for(scene, case.variant);
        let mut session = Session::from_scene(&applied).map_err(|e| e.to_string())?;
        out.push(run_case(&mut session, case, scale)?.0);
    }
    Ok(out)
}

/// One configuration's point on the speed-versus-accuracy chart of the indentation class:
/// the mean over `metrics`' cases of their mean node error (mm; the node error is a TRE over
/// every node of the truth mesh), against the median of their warm-frame p50 times (ms).
pub fn indentation_chart_point(
    name: &str,
    is_default: bool,
    metrics: &[IndentationMetrics],
) -> ChartPoint {
    let n = metrics.len().max(1) as f64;
    let mut ms: Vec<f64> = metrics.iter().map(|m| m.warm_ms_p50).collect();
    ms.sort_by(f64::total_cmp);
    ChartPoint {
        label: name.to_string(),
        ms_per_frame: ms.get(ms.len() / 2).copied().unwrap_or(f64::NAN),
        tre_mm: metrics.iter().map(|m| m.mean_mm).sum::<f64>() / n,
        is_default,
    }
}

/// Registers `case` with `session` (a fresh session of the scene from [`scene_for`] for the
/// case's variant, whose unit is `scale` metres) and grades it: the metrics and each frame's
/// sample (node errors, mm; wall time, ms).
pub fn run_case(
    session: &mut Session,
    case: &IndentationCase,
    scale: f64,
) -> Result<(IndentationMetrics, Vec<FrameSample>), String> {
    let workload = indentation_workload(
        &case.truth,
        &case.frames,
        scale,
        case.variant == IndentationVariant::Camera,
    );
    let structures = session.model.structure_sizes();
    workload.check_against(&structures)?;
    let samples = run_workload(session, &workload, scale);
    let metrics = indentation_metrics(
        &case.name(),
        &case.truth,
        &case.frames,
        &case
            .variant
            .offset()
            .unwrap_or_else(RigidTransform::identity),
        &samples,
    );
    Ok((metrics, samples))
}

/// A table of indentation metrics (mm, ms).
pub fn indentation_table(rows: &[IndentationMetrics]) -> String {
    let mut s = String::from(
        "| case | none mean / p95 | mean | p95 | region none / reg. | worse than none | failed | force error / centre (median) | warm p50 / p95 ms |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for m in rows {
        s.push_str(&format!(
            "| {} | {:.2} / {:.2} | {:.2} | {:.2} | {:.2} / {:.2} | {} | {} | {} / {} | {:.1} / {:.1} |\n",
            m.workload,
            m.none_mean_mm,
            m.none_p95_mm,
            m.mean_mm,
            m.p95_mm,
            m.none_region_mean_mm,
            m.region_mean_mm,
            m.frames_worse_than_none,
            m.failed_frames,
            m.force_relative_error_median
                .map_or("–".to_string(), |e| format!("{:.0} %", 100.0 * e)),
            m.force_centre_error_median_mm
                .map_or("–".to_string(), |e| format!("{e:.1} mm")),
            m.warm_ms_p50,
            m.warm_ms_p95
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn metrics(mean_mm: f64, warm_ms_p50: f64) -> IndentationMetrics {
        IndentationMetrics {
            workload: "x".into(),
            mean_mm,
            p95_mm: 0.0,
            none_mean_mm: 0.0,
            none_p95_mm: 0.0,
            region_mean_mm: 0.0,
            none_region_mean_mm: 0.0,
            pose_uncertainty_max_mm: None,
            pose_uncertain_frames: 0,
            frames_worse_than_none: 0,
            failed_frames: 0,
            force_relative_error_median: None,
            force_centre_error_median_mm: None,
            warm_ms_p50,
            warm_ms_p95: 0.0,
            expected_error_bounded: None,
            expected_error_ratio_median: None,
            frames: Vec::new(),
        }
    }

    #[test]
    fn a_chart_point_is_the_mean_error_at_the_median_time_of_the_cases() {
        let p = indentation_chart_point(
            "cell x2",
            false,
            &[metrics(1.0, 30.0), metrics(0.5, 10.0), metrics(1.5, 20.0)],
        );
        assert_eq!(p.label, "cell x2");
        assert!(!p.is_default);
        assert!((p.tre_mm - 1.0).abs() < 1e-12);
        assert_eq!(p.ms_per_frame, 20.0);
        // No case: no point to draw (non-finite coordinates are left off the chart).
        let empty = indentation_chart_point("none", true, &[]);
        assert!(empty.ms_per_frame.is_nan());
    }
}
