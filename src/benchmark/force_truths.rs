//! The force-driven truths of `fixtures/liver_force` as a bench (`livereg bench
//! --force-truths`): a load on a small patch of surface vertices pushes a liver tens of
//! millimetres deep, solved with P2 tetrahedra on each liver's own tetrahedral mesh (an
//! independent discretisation), seen as noise-free 500-point clouds of 15 % of the surface.
//!
//! The cases are split once into a tuning set and a test set (`SPLIT.md` of the fixture,
//! read here: the split is the file's, not this code's). Defaults are chosen on the tuning
//! set; reports quote the test set.
//!
//! Per case: the mean node error (every truth node, surface and interior), the median of the
//! frames' 95th percentiles, no registration's error, the distance of the cloud's points near
//! the loaded patch to the registered surface (the dent: what the cloud shows there against
//! what the registration reached), the node error near the patch, the expected error's
//! calibration (the share of frames whose `expected_error` bounds the true mean node error,
//! and the median ratio), the contact force's error against the truth's applied load, and the
//! warm frames' wall time. With a moving camera ([`CameraMotion`]), the clouds and truths are
//! seen from a camera turning and moving over the sequence, registered with `rigid = "icp"`,
//! and the report counts `pose_uncertain` on frames that are far off and near. With cloud
//! noise ([`noisy_cloud`]) every cloud point is moved by seeded Gaussian noise; the dent
//! distance is then measured to the noisy points.
//! Lengths in millimetres (the fixture's unit), forces in newtons.

use crate::simulation::FromScene;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::{Point3, Rotation3, Unit, Vector3};
use serde::{Deserialize, Serialize};

use crate::evaluation::percentile;
use crate::evaluation::read_truth;
use crate::mesh::{read_obj, read_points};
use crate::random::{fnv1a, Rng};
use crate::registration::{
    RigidTransform, SurfaceDistances, SurfaceTopology, NOISE_IMPRINT, UNSEEN_SHARE,
    UNSEEN_SHARE_EXPLAINED,
};
use crate::scene::{load_scene, LoadedScene, PoseUpdate, RigidMode};
use crate::session::{Frame, Session};

/// The fixture's directory in this repository.
pub fn force_truths_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/liver_force")
}

/// Cloud points within this distance (mm) of the truth's loaded patch centre are the dent's.
pub const DENT_RADIUS_MM: f64 = 15.0;

/// Nodes within this distance (mm) of the patch centre at rest are "near the tool".
pub const NEAR_TOOL_MM: f64 = 10.0;

/// Frames whose true force is below this share of the sequence's largest are left out of the
/// force error (a relative error of a vanishing force says nothing).
pub const FORCE_FLOOR_SHARE: f64 = 0.25;

/// A frame this far off (mean node error, mm) must carry `pose_uncertain` under a moving
/// camera; one within [`POSE_NEAR_MM`] should not.
pub const POSE_FAR_MM: f64 = 5.0;

/// See [`POSE_FAR_MM`].
pub const POSE_NEAR_MM: f64 = 2.0;

/// Which cases of the split.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TruthSet {
    /// Cases defaults may be chosen on.
    Tuning,
    /// Cases only reported.
    Test,
    /// Both.
    All,
}

impl TruthSet {
    /// The set named `name` (`tuning`, `test`, `all`).
    pub fn from_name(name: &str) -> Result<Self, String> {
        match name {
            "tuning" => Ok(Self::Tuning),
            "test" => Ok(Self::Test),
            "all" => Ok(Self::All),
            other => Err(format!(
                "--set: unknown `{other}` (known: tuning, test, all)"
            )),
        }
    }

    /// The set's name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Tuning => "tuning",
            Self::Test => "test",
            Self::All => "all",
        }
    }
}

/// One truth of the fixture: a liver, a sequence and a law.
#[derive(Debug, Clone, PartialEq)]
pub struct ForceTruthCase {
    /// `<liver>/<sequence>_<law>`, as SPLIT.md names it.
    pub name: String,
    /// The set SPLIT.md puts it in ([`TruthSet::Tuning`] or [`TruthSet::Test`]).
    pub set: TruthSet,
    /// The case's directory (frames/, truth.jsonl, meta.json).
    pub dir: PathBuf,
    /// The liver's directory (liver.obj, nodes.xyz, fixed.xyz, `scene_<law>.toml`).
    pub liver_dir: PathBuf,
    /// The law (`linear`, `neo-hookean`): the scene the case is registered with.
    pub law: String,
}

/// The cases of `set` listed in `root/SPLIT.md` (lines `- <liver>/<sequence>_<law>` under a
/// heading starting with `Tuning` or `Test`), in the file's order. An error names the file
/// and line of a case whose directory is missing.
pub fn force_truth_cases(root: &Path, set: TruthSet) -> Result<Vec<ForceTruthCase>, String> {
    let split = root.join("SPLIT.md");
    let text = std::fs::read_to_string(&split).map_err(|e| format!("{}: {e}", split.display()))?;
    let mut current = None;
    let mut out = Vec::new();
    for (line_no, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.starts_with("Tuning") {
            current = Some(TruthSet::Tuning);
        } else if line.starts_with("Test") {
            current = Some(TruthSet::Test);
        }
        let (Some(which), Some(name)) = (current, line.strip_prefix("- ")) else {
            continue;
        };
        let name = name.trim();
        let (liver, case) = name.split_once('/').ok_or_else(|| {
            format!(
                "{}:{}: `{name}` is not <liver>/<sequence>_<law>",
                split.display(),
                line_no + 1
            )
        })?;
        let law = case
            .split_once('_')
            .map(|(_, l)| l.to_string())
            .ok_or_else(|| {
                format!(
                    "{}:{}: `{case}` has no _<law>",
                    split.display(),
                    line_no + 1
                )
            })?;
        let dir = root.join(liver).join(case);
        if !dir.join("truth.jsonl").is_file() {
            return Err(format!(
                "{}:{}: {} has no truth.jsonl",
                split.display(),
                line_no + 1,
                dir.display()
            ));
        }
        if set == TruthSet::All || set == which {
            out.push(ForceTruthCase {
                name: name.to_string(),
                set: which,
                dir,
                liver_dir: root.join(liver),
                law,
            });
        }
    }
    if out.is_empty() {
        return Err(format!("{}: no {} case", split.display(), set.name()));
    }
    Ok(out)
}

/// A camera that turns by up to `degrees` about a fixed tilted axis through the rest nodes'
/// centroid and moves by up to `mm`, both growing linearly from the first frame (none) to
/// the last (all); frame `k`'s cloud and truth are seen from it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CameraMotion {
    /// Largest turn, degrees.
    pub degrees: f64,
    /// Largest shift, mm.
    pub mm: f64,
}

impl CameraMotion {
    /// `DEG,MM` as `--moving-camera` takes it.
    pub fn parse(text: &str) -> Result<Self, String> {
        let bad = || format!("--moving-camera: `{text}` is not DEG,MM (e.g. 10,20)");
        let (d, m) = text.split_once(',').ok_or_else(bad)?;
        let degrees: f64 = d.trim().parse().map_err(|_| bad())?;
        let mm: f64 = m.trim().parse().map_err(|_| bad())?;
        if !(degrees.is_finite() && mm.is_finite() && degrees.abs() <= 180.0) {
            return Err(bad());
        }
        Ok(Self { degrees, mm })
    }

    /// The camera's motion at frame `k` of `n`: a turn about the fixed axis through `centre`
    /// (mm), then the shift; the identity at frame 0. Points and forces seen from it are
    /// `apply` and `apply_vector` of it.
    pub fn at(&self, k: usize, n: usize, centre: &Point3<f64>) -> RigidTransform {
        let t = k as f64 / n.saturating_sub(1).max(1) as f64;
        let axis = Unit::new_normalize(Vector3::new(0.3, 0.5, 0.8));
        let rotation = Rotation3::from_axis_angle(&axis, self.degrees.to_radians() * t);
        let shift = Vector3::new(1.0, -0.5, 0.3).normalize() * self.mm * t;
        RigidTransform::new(rotation, centre.coords - rotation * centre.coords + shift)
    }
}

/// How the cases are registered: the scene of the case's law, changed only as given.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ForceTruthOptions {
    /// Cell size (mm) instead of the derived one.
    pub cell_size: Option<f64>,
    /// A moving camera ([`CameraMotion`]); the scene then registers with `rigid = "icp"`.
    pub moving_camera: Option<CameraMotion>,
    /// `registration.pose` with a moving camera (default: the scene's).
    pub pose: Option<PoseUpdate>,
    /// At most this many frames of each case.
    pub max_frames: Option<usize>,
    /// Gaussian noise added to every cloud point, mm per axis (1σ; [`noisy_cloud`]): a
    /// camera's depth noise on the noise-free clouds.
    pub cloud_noise: Option<f64>,
}

/// `points` (mm) with isotropic Gaussian noise of `sigma` mm per axis, drawn from a generator
/// seeded by the case's name and the frame index `k` (the same noise on every run and
/// machine, different on every frame).
pub fn noisy_cloud(points: &[Point3<f64>], sigma: f64, case: &str, k: usize) -> Vec<Point3<f64>> {
    let mut rng = Rng::new(fnv1a(case.bytes().chain((k as u64).to_le_bytes())));
    points
        .iter()
        .map(|p| p + rng.gaussian_vector(sigma))
        .collect()
}

/// `--noise MM`: a finite, non-negative noise (mm per axis).
pub fn parse_cloud_noise(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!(
            "--noise: `{text}` is not a noise in mm (a finite number >= 0, e.g. 1.0)"
        )),
    }
}

/// One frame's grades.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ForceTruthFrame {
    /// Mean node error, mm.
    pub mean_mm: f64,
    /// 95th percentile of the node error, mm.
    pub p95_mm: f64,
    /// Mean node error of no registration (the rest shape, seen from the frame's camera), mm.
    pub none_mm: f64,
    /// Mean distance of the cloud's points within [`DENT_RADIUS_MM`] of the truth's patch
    /// centre to the registered surface, mm (`None`: no such point).
    pub dent_mm: Option<f64>,
    /// Mean node error within [`NEAR_TOOL_MM`] of the patch centre at rest, mm.
    pub near_tool_mm: f64,
    /// How far the registered pose puts the rest nodes from where the frame's true camera
    /// sees them (root mean square), mm: the pose's share of the error.
    pub pose_error_mm: f64,
    /// How far the truth's own deformation moves the seen part of the surface as a rigid body
    /// (`registration::rigid_share_of_deformation` of the surface vertices the
    /// cloud lies on, rest → truth, still camera), mm: the camera motion this frame's
    /// deformation looks like from the cloud alone.
    pub seen_rigid_motion_mm: f64,
    /// The frame's `expected_error`, mm (`None` when it has none).
    pub expected_error_mm: Option<f64>,
    /// Its parts, mm: pose, unseen deformation, residual beyond the noise, noise
    /// (`registration::ErrorEstimate`; `None` when it has none): what a calibration of the
    /// estimate's constants recomputes from.
    pub expected_error_parts_mm: Option<[f64; 4]>,
    /// The truth's applied force, N.
    pub force_true_n: f64,
    /// The truth's applied force as a vector in the camera's frame (the cloud's), N.
    pub force_true_vector_n: [f64; 3],
    /// The estimated contact force's magnitude, N (`None`: no estimate).
    pub force_estimate_n: Option<f64>,
    /// The estimated contact force as a vector in the camera's frame, N (`None`: no estimate).
    pub force_estimate_vector_n: Option<[f64; 3]>,
    /// |estimate − truth| / |truth| (`None`: no estimate).
    pub force_relative_error: Option<f64>,
    /// The force estimate's own expected error, N (`contact_force.expected_error_n`).
    pub force_expected_error_n: Option<f64>,
    /// Wall time, ms.
    pub wall_ms: f64,
    /// Whether the frame started from the previous frame's state.
    pub warm: bool,
    /// The frame's flags.
    pub flags: Vec<crate::session::FrameFlag>,
}

/// One case's grades (module docs).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ForceTruthMetrics {
    /// `<liver>/<sequence>_<law>`.
    pub case: String,
    /// Its set.
    pub set: TruthSet,
    /// Cell size the model was built with, mm.
    pub cell_size_mm: f64,
    /// The camera's motion, when moving.
    pub moving_camera: Option<CameraMotion>,
    /// The noise added to the clouds, mm per axis (`None`: the fixture's noise-free clouds).
    pub cloud_noise_mm: Option<f64>,
    /// The expected error's constants its frames' parts were made with: `UNSEEN_SHARE`,
    /// `UNSEEN_SHARE_EXPLAINED`, `NOISE_IMPRINT` (`registration::error_estimate`), which a
    /// calibration rescales (`fixtures/liver_force/calibrate_estimate.py`).
    pub expected_error_constants: [f64; 3],
    /// Mean over frames of the mean node error, mm.
    pub mean_mm: f64,
    /// Median over frames of the frame's 95th percentile node error, mm.
    pub p95_mm: f64,
    /// No registration's mean node error, mm.
    pub none_mm: f64,
    /// Mean over frames of the dent distance, mm.
    pub dent_mean_mm: f64,
    /// Largest frame dent distance, mm.
    pub dent_max_mm: f64,
    /// Mean over frames of the node error near the tool, mm.
    pub near_tool_mm: f64,
    /// Mean over frames of the pose error ([`ForceTruthFrame::pose_error_mm`]), mm.
    pub pose_error_mm: f64,
    /// Largest frame pose error, mm.
    pub pose_error_max_mm: f64,
    /// Largest frame [`ForceTruthFrame::seen_rigid_motion_mm`], mm.
    pub seen_rigid_motion_max_mm: f64,
    /// Share of frames whose expected error is at least the true mean node error.
    pub expected_error_bounded: Option<f64>,
    /// Median over frames of expected error / true mean node error.
    pub expected_error_ratio_median: Option<f64>,
    /// Median relative force error over the frames whose true force is at least
    /// [`FORCE_FLOOR_SHARE`] of the largest and which have an estimate.
    pub force_error_median: Option<f64>,
    /// Largest relative force error over the same frames: a median hides the frame whose
    /// force is off by orders of magnitude.
    pub force_error_max: Option<f64>,
    /// Share of those frames with an estimate.
    pub force_estimated_share: f64,
    /// Share of those frames with an estimate whose error is at most its expected error.
    pub force_bounded: Option<f64>,
    /// Share of frames over [`POSE_FAR_MM`] that carry `pose_uncertain` (`None`: no such
    /// frame).
    pub pose_uncertain_when_far: Option<f64>,
    /// Share of frames within [`POSE_NEAR_MM`] that carry `pose_uncertain`.
    pub pose_uncertain_when_near: Option<f64>,
    /// Median and 95th percentile wall time of the warm frames, ms.
    pub warm_ms_p50: f64,
    /// See `warm_ms_p50`.
    pub warm_ms_p95: f64,
    /// Per frame.
    pub frames: Vec<ForceTruthFrame>,
}

/// The truth's per-frame applied load (meta.json `force_vector_N`), N.
#[derive(Debug, Deserialize)]
struct CaseMeta {
    patch_centre_vertex: usize,
    #[serde(rename = "force_vector_N")]
    force_vector_n: Vec<[f64; 3]>,
}

/// The scene `case` is registered with: its liver's `scene_<law>.toml`, changed by `options`.
pub fn force_truth_scene(
    case: &ForceTruthCase,
    options: &ForceTruthOptions,
) -> Result<LoadedScene, String> {
    let path = case.liver_dir.join(format!("scene_{}.toml", case.law));
    let mut scene = load_scene(&path).map_err(|e| e.to_string())?;
    if let Some(h) = options.cell_size {
        if !(h.is_finite() && h > 0.0) {
            return Err(format!("--cell-size must be > 0, got {h}"));
        }
        scene.scene.grid.cell_size = h;
    }
    if options.moving_camera.is_some() {
        let r = scene
            .scene
            .registration
            .get_or_insert_with(Default::default);
        r.rigid = RigidMode::Icp;
        if let Some(p) = options.pose {
            r.pose = p;
        }
    }
    Ok(scene)
}

/// Registers `case` with a fresh session of [`force_truth_scene`] and grades every frame.
pub fn run_force_truth(
    case: &ForceTruthCase,
    options: &ForceTruthOptions,
) -> Result<ForceTruthMetrics, String> {
    let at = |p: &Path, e: &dyn std::fmt::Display| format!("{}: {e}", p.display());
    let scene = force_truth_scene(case, options)?;
    if scene.length_scale() != 1e-3 {
        return Err(format!(
            "{}: the force truths are in millimetres",
            scene.path.display()
        ));
    }
    let surface_path = case.liver_dir.join("liver.obj");
    let surface = read_obj(&surface_path).map_err(|e| at(&surface_path, &e))?;
    let nodes_path = case.liver_dir.join("nodes.xyz");
    let rest = read_points(&nodes_path).map_err(|e| at(&nodes_path, &e))?;
    let meta_path = case.dir.join("meta.json");
    let meta: CaseMeta =
        serde_json::from_str(&std::fs::read_to_string(&meta_path).map_err(|e| at(&meta_path, &e))?)
            .map_err(|e| at(&meta_path, &e))?;
    let truth_path = case.dir.join("truth.jsonl");
    let truth = read_truth(&truth_path).map_err(|e| e.to_string())?;
    let frame_files = crate::session::frame_files(&case.dir.join("frames"))?.frames;
    let mut n = truth.len().min(frame_files.len());
    if let Some(m) = options.max_frames {
        n = n.min(m);
    }
    if n == 0 || meta.force_vector_n.len() < n || meta.patch_centre_vertex >= rest.len() {
        return Err(format!(
            "{}: {} truth frames, {} clouds, {} forces, patch centre {} of {} nodes",
            case.dir.display(),
            truth.len(),
            frame_files.len(),
            meta.force_vector_n.len(),
            meta.patch_centre_vertex,
            rest.len()
        ));
    }
    let vertices = surface.vertices.len();
    let topology = Arc::new(SurfaceTopology::new(vertices, &surface.triangles));
    let centroid =
        Point3::from(rest.iter().map(|p| p.coords).sum::<Vector3<f64>>() / rest.len() as f64);
    let centre = meta.patch_centre_vertex;
    let near_tool: Vec<bool> = rest
        .iter()
        .map(|p| (p - rest[centre]).norm() < NEAR_TOOL_MM)
        .collect();
    let largest_force = meta.force_vector_n[..n]
        .iter()
        .map(|f| Vector3::from(*f).norm())
        .fold(0.0, f64::max);
    let mut session = Session::from_scene(&scene).map_err(|e| e.to_string())?;
    let mut frames = Vec::with_capacity(n);
    for (k, cloud_path) in frame_files.iter().enumerate().take(n) {
        let camera = options
            .moving_camera
            .map_or_else(RigidTransform::identity, |m| m.at(k, n, &centroid));
        let raw_cloud = read_points(cloud_path).map_err(|e| at(cloud_path, &e))?;
        let frame = Frame {
            source: cloud_path
                .file_name()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            points: match (camera.apply_all(&raw_cloud), options.cloud_noise) {
                (seen, Some(sigma)) if sigma > 0.0 => noisy_cloud(&seen, sigma, &case.name, k),
                (seen, _) => seen,
            },
            camera: None,
        };
        let unmoved_nodes: Vec<Point3<f64>> = truth
            .iter()
            .find(|t| t.frame == k)
            .and_then(|t| t.structures.get("nodes"))
            .map(|pts| pts.iter().map(|p| Point3::from(*p)).collect())
            .ok_or_else(|| format!("{}: frame {k} has no `nodes`", truth_path.display()))?;
        let true_nodes = camera.apply_all(&unmoved_nodes);
        if true_nodes.len() != rest.len() || vertices > rest.len() {
            return Err(format!(
                "{}: frame {k}: {} true nodes, {} rest nodes, {vertices} surface vertices",
                truth_path.display(),
                true_nodes.len(),
                rest.len()
            ));
        }
        let r = session.register(&frame);
        let registered = r
            .structures
            .iter()
            .find(|(name, _)| name == "nodes")
            .map_or(&[][..], |(_, pts)| pts.as_slice());
        frames.push(grade_frame(&FrameToGrade {
            registered,
            truth: &true_nodes,
            rest_seen: &camera.apply_all(&rest),
            rest: &rest,
            seen_rigid_motion_mm: seen_rigid_motion(
                &rest[..vertices.min(rest.len())],
                &unmoved_nodes[..vertices.min(unmoved_nodes.len())],
                &raw_cloud,
            ),
            cloud: &frame.points,
            topology: &topology,
            surface_vertices: vertices,
            patch_centre: centre,
            near_tool: &near_tool,
            force: camera.apply_vector(&Vector3::from(meta.force_vector_n[k])),
            result: &r,
        }));
    }
    Ok(summarise(case, &scene, options, largest_force, frames))
}

/// What [`grade_frame`] compares (mm, the frame's camera).
struct FrameToGrade<'a> {
    registered: &'a [Point3<f64>],
    truth: &'a [Point3<f64>],
    rest_seen: &'a [Point3<f64>],
    rest: &'a [Point3<f64>],
    seen_rigid_motion_mm: f64,
    cloud: &'a [Point3<f64>],
    topology: &'a Arc<SurfaceTopology>,
    surface_vertices: usize,
    patch_centre: usize,
    near_tool: &'a [bool],
    force: Vector3<f64>,
    result: &'a crate::session::FrameResult,
}

/// [`ForceTruthFrame::seen_rigid_motion_mm`]: the rigid motion (trimmed to the best-fitting
/// three quarters) of the surface vertices nearest the cloud's points, from `rest` to
/// `truth` (both the surface vertices only, mm), RMS over the surface; 0 when undetermined.
fn seen_rigid_motion(rest: &[Point3<f64>], truth: &[Point3<f64>], cloud: &[Point3<f64>]) -> f64 {
    let Some(index) = crate::registration::IndexedPoints::new(truth.to_vec()) else {
        return 0.0;
    };
    let mut seen: Vec<usize> = cloud.iter().map(|c| index.nearest(c).0).collect();
    seen.sort_unstable();
    seen.dedup();
    crate::registration::rigid_share_of_deformation(rest, truth, &seen, 0.75).unwrap_or(0.0)
}

/// One frame's grades; a registration with no (or non-finite) nodes counts as infinitely off.
fn grade_frame(g: &FrameToGrade<'_>) -> ForceTruthFrame {
    let distance = |a: &[Point3<f64>]| -> Vec<f64> {
        if a.len() != g.truth.len() {
            return vec![f64::INFINITY; g.truth.len()];
        }
        a.iter()
            .zip(g.truth)
            .map(|(p, q)| {
                let d = (p - q).norm();
                if d.is_finite() {
                    d
                } else {
                    f64::INFINITY
                }
            })
            .collect()
    };
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let error = distance(g.registered);
    let mut sorted = error.clone();
    sorted.sort_by(f64::total_cmp);
    let near: Vec<f64> = error
        .iter()
        .zip(g.near_tool)
        .filter(|(_, &n)| n)
        .map(|(e, _)| *e)
        .collect();
    let dent_points: Vec<Point3<f64>> = g
        .cloud
        .iter()
        .filter(|p| (*p - g.truth[g.patch_centre]).norm() < DENT_RADIUS_MM)
        .copied()
        .collect();
    let dent_mm = (!dent_points.is_empty() && g.registered.len() == g.truth.len())
        .then(|| {
            SurfaceDistances::new(
                g.registered[..g.surface_vertices].to_vec(),
                Arc::clone(g.topology),
            )
            .map(|s| {
                mean(
                    &s.signed_distances(&dent_points)
                        .iter()
                        .map(|d| d.abs())
                        .collect::<Vec<_>>(),
                )
            })
        })
        .flatten();
    let force = g
        .result
        .contact_force
        .as_ref()
        .filter(|c| c.resultant.iter().all(|v| v.is_finite()));
    let estimate = force.map(|c| c.resultant);
    let pose = &g.result.model_to_cloud;
    let pose_error_mm = (g
        .rest
        .iter()
        .zip(g.rest_seen)
        .map(|(p, seen)| (pose.apply(&(p * 1e-3)) * 1e3 - seen).norm_squared())
        .sum::<f64>()
        / g.rest.len().max(1) as f64)
        .sqrt();
    ForceTruthFrame {
        mean_mm: mean(&error),
        pose_error_mm,
        seen_rigid_motion_mm: g.seen_rigid_motion_mm,
        p95_mm: percentile(&sorted, 0.95),
        none_mm: mean(&distance(g.rest_seen)),
        dent_mm,
        near_tool_mm: mean(&near),
        expected_error_mm: g.result.expected_error.map(|e| e.expected),
        expected_error_parts_mm: g
            .result
            .expected_error
            .map(|e| [e.pose, e.unseen, e.residual, e.noise]),
        force_true_n: g.force.norm(),
        force_true_vector_n: g.force.into(),
        force_estimate_n: estimate.map(|f| f.norm()),
        force_estimate_vector_n: estimate.map(|f| f.into()),
        force_relative_error: estimate.map(|f| (f - g.force).norm() / g.force.norm().max(1e-12)),
        force_expected_error_n: force.map(|c| c.expected_error),
        wall_ms: g.result.wall_ms,
        warm: g.result.warm,
        flags: g.result.flags.clone(),
    }
}

/// The case's grades from its frames'.
fn summarise(
    case: &ForceTruthCase,
    scene: &LoadedScene,
    options: &ForceTruthOptions,
    largest_force: f64,
    frames: Vec<ForceTruthFrame>,
) -> ForceTruthMetrics {
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let median = |mut v: Vec<f64>| -> Option<f64> {
        v.retain(|x| !x.is_nan());
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        Some(percentile(&v, 0.5))
    };
    let dents: Vec<f64> = frames.iter().filter_map(|f| f.dent_mm).collect();
    let expected: Vec<(f64, f64)> = frames
        .iter()
        .filter_map(|f| f.expected_error_mm.map(|e| (e, f.mean_mm)))
        .collect();
    let loaded: Vec<&ForceTruthFrame> = frames
        .iter()
        .filter(|f| f.force_true_n >= FORCE_FLOOR_SHARE * largest_force && f.force_true_n > 0.0)
        .collect();
    let force_errors: Vec<f64> = loaded
        .iter()
        .filter_map(|f| f.force_relative_error)
        .collect();
    let pose_share = |pick: &dyn Fn(f64) -> bool| -> Option<f64> {
        let picked: Vec<&ForceTruthFrame> = frames.iter().filter(|f| pick(f.mean_mm)).collect();
        (!picked.is_empty()).then(|| {
            picked
                .iter()
                .filter(|f| f.flags.contains(&crate::session::FrameFlag::PoseUncertain))
                .count() as f64
                / picked.len() as f64
        })
    };
    let mut warm: Vec<f64> = frames
        .iter()
        .filter(|f| f.warm)
        .map(|f| f.wall_ms)
        .collect();
    warm.sort_by(f64::total_cmp);
    let warm_at = |p: f64| {
        if warm.is_empty() {
            0.0
        } else {
            percentile(&warm, p)
        }
    };
    ForceTruthMetrics {
        case: case.name.clone(),
        set: case.set,
        cell_size_mm: scene.scene.grid.cell_size,
        moving_camera: options.moving_camera,
        cloud_noise_mm: options.cloud_noise,
        expected_error_constants: [UNSEEN_SHARE, UNSEEN_SHARE_EXPLAINED, NOISE_IMPRINT],
        mean_mm: mean(&frames.iter().map(|f| f.mean_mm).collect::<Vec<_>>()),
        p95_mm: median(frames.iter().map(|f| f.p95_mm).collect()).unwrap_or(f64::NAN),
        none_mm: mean(&frames.iter().map(|f| f.none_mm).collect::<Vec<_>>()),
        dent_mean_mm: mean(&dents),
        dent_max_mm: dents.iter().copied().fold(0.0, f64::max),
        near_tool_mm: mean(&frames.iter().map(|f| f.near_tool_mm).collect::<Vec<_>>()),
        pose_error_mm: mean(&frames.iter().map(|f| f.pose_error_mm).collect::<Vec<_>>()),
        pose_error_max_mm: frames.iter().map(|f| f.pose_error_mm).fold(0.0, f64::max),
        seen_rigid_motion_max_mm: frames
            .iter()
            .map(|f| f.seen_rigid_motion_mm)
            .fold(0.0, f64::max),
        expected_error_bounded: (!expected.is_empty()).then(|| {
            expected.iter().filter(|(e, t)| e >= t).count() as f64 / expected.len() as f64
        }),
        expected_error_ratio_median: median(
            expected.iter().map(|(e, t)| e / t.max(1e-9)).collect(),
        ),
        force_error_median: median(force_errors.clone()),
        force_error_max: force_errors.iter().copied().reduce(f64::max),
        force_estimated_share: force_errors.len() as f64 / loaded.len().max(1) as f64,
        force_bounded: {
            let pairs: Vec<bool> = loaded
                .iter()
                .filter_map(|f| {
                    let error = f.force_relative_error? * f.force_true_n;
                    Some(error <= f.force_expected_error_n?)
                })
                .collect();
            (!pairs.is_empty())
                .then(|| pairs.iter().filter(|b| **b).count() as f64 / pairs.len() as f64)
        },
        pose_uncertain_when_far: pose_share(&|m| m > POSE_FAR_MM),
        pose_uncertain_when_near: pose_share(&|m| m <= POSE_NEAR_MM),
        warm_ms_p50: warm_at(0.5),
        warm_ms_p95: warm_at(0.95),
        frames,
    }
}

/// The report as a Markdown table: one row per case, then one per set over its frames.
pub fn force_truths_table(rows: &[ForceTruthMetrics]) -> String {
    let opt = |v: Option<f64>, pct: bool| match v {
        Some(x) if pct => format!("{:.0} %", 100.0 * x),
        Some(x) => format!("{x:.2}"),
        None => "—".to_string(),
    };
    let mut s = String::from(
        "| case | set | none | mean | p95 | dent mean / max | near tool | bounded | est./true | force error median / max | force bounded | pose error mean / max | seen rigid motion max | pose_uncertain far / near | warm p50 / p95 ms |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {:.2} | {:.2} | {:.2} | {:.2} / {:.2} | {:.2} | {} | {} | {} / {} | {} | {:.2} / {:.2} | {:.1} | {} / {} | {:.0} / {:.0} |\n",
            r.case,
            r.set.name(),
            r.none_mm,
            r.mean_mm,
            r.p95_mm,
            r.dent_mean_mm,
            r.dent_max_mm,
            r.near_tool_mm,
            opt(r.expected_error_bounded, true),
            opt(r.expected_error_ratio_median, false),
            opt(r.force_error_median, true),
            opt(r.force_error_max, true),
            opt(r.force_bounded, true),
            r.pose_error_mm,
            r.pose_error_max_mm,
            r.seen_rigid_motion_max_mm,
            opt(r.pose_uncertain_when_far, true),
            opt(r.pose_uncertain_when_near, true),
            r.warm_ms_p50,
            r.warm_ms_p95,
        ));
    }
    for set in [TruthSet::Tuning, TruthSet::Test] {
        let frames: Vec<&ForceTruthFrame> = rows
            .iter()
            .filter(|r| r.set == set)
            .flat_map(|r| &r.frames)
            .collect();
        if frames.is_empty() {
            continue;
        }
        let n = frames.len() as f64;
        let mean =
            |f: &dyn Fn(&ForceTruthFrame) -> f64| frames.iter().map(|x| f(x)).sum::<f64>() / n;
        let bounded: Vec<bool> = frames
            .iter()
            .filter_map(|f| f.expected_error_mm.map(|e| e >= f.mean_mm))
            .collect();
        s.push_str(&format!(
            "| all {} ({} frames) | {} | {:.2} | {:.2} | | | {:.2} | {} | | | | {:.2} | | | |\n",
            set.name(),
            frames.len(),
            set.name(),
            mean(&|f| f.none_mm),
            mean(&|f| f.mean_mm),
            mean(&|f| f.near_tool_mm),
            opt(
                (!bounded.is_empty())
                    .then(|| bounded.iter().filter(|b| **b).count() as f64 / bounded.len() as f64),
                true
            ),
            mean(&|f| f.pose_error_mm),
        ));
    }
    if let Some(sigma) = rows.iter().find_map(|r| r.cloud_noise_mm) {
        s.push_str(&format!(
            "\nClouds with {sigma} mm Gaussian noise per axis added (`--noise`); the dent \
             distance is to the noisy points.\n"
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The split is SPLIT.md's: sixteen tuning cases on four livers, eight test cases on the
    /// two others, no liver in both.
    #[test]
    fn the_split_is_read_from_the_fixture() {
        let root = force_truths_dir();
        let tuning = force_truth_cases(&root, TruthSet::Tuning).unwrap();
        let test = force_truth_cases(&root, TruthSet::Test).unwrap();
        let all = force_truth_cases(&root, TruthSet::All).unwrap();
        assert_eq!(tuning.len(), 16);
        assert_eq!(test.len(), 8);
        assert_eq!(all.len(), 24);
        let livers = |cases: &[ForceTruthCase]| -> Vec<String> {
            let set: std::collections::BTreeSet<&str> = cases
                .iter()
                .map(|c| c.name.split_once('/').unwrap().0)
                .collect();
            set.into_iter().map(str::to_string).collect()
        };
        assert_eq!(
            livers(&tuning),
            [
                "bent-liver",
                "indentation-liver",
                "random-liver-1",
                "random-liver-2"
            ]
        );
        assert_eq!(livers(&test), ["phantom-liver", "varied-liver"]);
        assert!(all
            .iter()
            .all(|c| ["linear", "neo-hookean"].contains(&c.law.as_str())));
    }

    /// The camera's motion is rigid (distances kept) and grows from none to the whole turn and
    /// shift.
    #[test]
    fn the_camera_motion_is_rigid_and_grows_to_its_end() {
        let m = CameraMotion::parse("10,20").unwrap();
        let c = Point3::new(1.0, 2.0, 3.0);
        let (a, b) = (Point3::new(40.0, -5.0, 7.0), Point3::new(-3.0, 22.0, 9.0));
        assert_eq!(m.at(0, 5, &c).apply(&a), a);
        let last = m.at(4, 5, &c);
        let distance = (last.apply(&a) - last.apply(&b)).norm();
        assert!((distance - (a - b).norm()).abs() < 1e-12);
        assert!(((last.apply(&c) - c).norm() - 20.0).abs() < 1e-12);
        let angle = last.rotation_angle().to_degrees();
        assert!((angle - 10.0).abs() < 1e-9, "{angle}");
        assert!(CameraMotion::parse("10").is_err());
        assert!(CameraMotion::parse("x,2").is_err());
    }

    /// The added noise has the asked deviation per axis and no bias (20,000 draws: the sample
    /// deviation within 2 % of σ, the mean within 4 standard errors of 0), is the same on
    /// every run of a case and frame and differs between frames; a bad `--noise` names it.
    #[test]
    fn the_cloud_noise_is_seeded_gaussian_of_the_asked_deviation() {
        let points = vec![Point3::new(10.0, -20.0, 30.0); 20_000];
        let sigma = 1.5;
        let noisy = noisy_cloud(&points, sigma, "phantom-liver/press_linear", 3);
        let d: Vec<f64> = noisy
            .iter()
            .zip(&points)
            .flat_map(|(q, p)| (q - p).iter().copied().collect::<Vec<_>>())
            .collect();
        let n = d.len() as f64;
        let mean = d.iter().sum::<f64>() / n;
        let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        assert!(
            (sd / sigma - 1.0).abs() < 0.02,
            "deviation {sd} against {sigma}"
        );
        assert!(mean.abs() < 4.0 * sigma / n.sqrt(), "mean {mean}");
        assert_eq!(
            noisy,
            noisy_cloud(&points, sigma, "phantom-liver/press_linear", 3)
        );
        assert_ne!(
            noisy,
            noisy_cloud(&points, sigma, "phantom-liver/press_linear", 4)
        );
        assert_ne!(
            noisy,
            noisy_cloud(&points, sigma, "varied-liver/press_linear", 3)
        );
        assert_eq!(parse_cloud_noise(" 0.5 "), Ok(0.5));
        for bad in ["-1", "nan", "inf", "one"] {
            let e = parse_cloud_noise(bad).unwrap_err();
            assert!(e.contains("--noise") && e.contains(bad), "{e}");
        }
    }
}
