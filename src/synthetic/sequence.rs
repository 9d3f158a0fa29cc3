//! Synthetic intra-operative SEQUENCES with ground truth: a scene's liver deformed
//! over a number of frames by a surgical scenario, each frame seen as a partial, noisy point
//! cloud by the scene's virtual camera, with the true positions of the internal structures.
//!
//! * Scenarios ([`ScenarioKind`]): a pneumoperitoneum-like pressure on the anterior-superior
//!   (diaphragm-side) dome, the change of gravity when the patient is tilted, and a tool
//!   lifting the thin left lobe. The load grows with a smooth ramp ([`load_fraction`]) that
//!   reaches its full value at about 2/3 of the sequence and then holds, so that the last
//!   frames show a liver that has stopped moving.
//! * The ground truth is solved with a DIFFERENT discretisation and law than the scene's
//!   registration model ([`TruthModel`]: by default a 10 mm finite-cell grid with 2 octree
//!   levels and ν = 0.49, where the phantom's registration model uses 15 mm weighted cells and
//!   ν = 0.45), so that tests do not grade the model against itself. It also rests on an
//!   elastic bed under its posterior third (the organs behind it; the registration model
//!   has only the ligament box): held by the ligaments alone, the soft phantom swings almost
//!   rigidly, and a rigid registration would then leave nothing for the non-rigid stage.
//!   Frames are solved by continuation: each frame's Newton solve
//!   ([`NewtonSolver::improve`]) starts from the previous frame's equilibrium; a solve that
//!   does not converge is an error.
//! * The clouds ([`synthesize_cloud`]) use one [`CloudSpec`] with a per-frame seed
//!   ([`frame_seed`]); its `rigid_offset` is the constant model→camera transform.
//!
//! Frames: everything in a [`SyntheticSequence`] is in metres. "Camera frame" means the frame
//! of the clouds: the model frame moved by `model_to_camera` (not the optical frame centred
//! on the camera). [`write_sequence`] writes the clouds, the truth (`truth.jsonl`, the truth
//! format of contracts.md) and a description (`sequence.json`) in scene units.
//!
//! Regions of the scenarios are placed relative to the surface's bounding box in the
//! patient frame of the bundled phantom (x: patient right → left, y: posterior → anterior,
//! z: inferior → superior); see [`ScenarioLoad::for_surface`].

use crate::simulation::FromScene;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::time::Instant;

use nalgebra::{Point3, Rotation3, Unit, Vector3};
use serde::{Deserialize, Serialize};

use super::error::SynthError;
use super::point_cloud::{synthesize_cloud, CloudSpec};
use crate::evaluation::{RigidRecord, TruthRecord};
use crate::geometry::{Aabb, Camera, ViewError, DEFAULT_FOV_DEG};
use crate::grid::{EmbeddingError, IntegrationMode, WeightedCellGrid};
use crate::mechanics::loads::{body_forces, pressure_forces, traction_forces};
use crate::mechanics::{LawKind, NewtonSolver, PenaltySprings};
use crate::mesh::TriSurface;
use crate::registration::RigidTransform;
use crate::scene::{LoadedScene, MAX_SUBDIVISIONS};
use crate::simulation::{ModelError, SceneModel};

/// Standard gravity, m/s².
pub const STANDARD_GRAVITY: f64 = 9.81;

/// Default share of the sequence over which the load ramps up (then it holds).
pub const DEFAULT_RAMP_FRACTION: f64 = 2.0 / 3.0;

/// Edge of the tool's loaded patch, metres (3 cm).
pub const TOOL_PATCH_SIZE: f64 = 0.03;

/// Depth of the elastic bed of the truth ([`TruthModel::bed_stiffness`]) as a share of the
/// surface's posterior→anterior extent.
pub const BED_DEPTH_FRACTION: f64 = 0.35;

/// Default stiffness of the truth's elastic bed, N/m³: 4500 Pa / 1.5 cm, a layer of tissue as
/// soft as the liver and 1.5 cm thick.
pub const DEFAULT_BED_STIFFNESS: f64 = 3.0e5;

/// Relative residual at which a truth increment whose Newton iterations stall (at round-off,
/// above the scene's `residual_tolerance`) is still accepted as converged.
pub const TRUTH_STALL_TOLERANCE: f64 = 1e-6;

/// An intra-operative deformation scenario.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ScenarioKind {
    /// Insufflation-like dead pressure (Pa) on the anterior-superior (diaphragm-side) dome of
    /// the right lobe, pushing it inwards against the ligaments and the elastic bed.
    Pneumoperitoneum,
    /// The patient tilted from supine (gravity towards posterior, −y) into reverse
    /// Trendelenburg (head up) by an angle (degrees): the body force `ρ (g_new − g_old)` acts
    /// on the liver, which is at rest (stress-free) under `g_old`; the ligaments and the
    /// elastic bed hold.
    GravityPose,
    /// A tool lifting the thin left lobe: a dead traction (Pa, towards superior) on a 3 cm
    /// patch of its inferior face.
    ToolPush,
}

impl ScenarioKind {
    /// Every scenario.
    pub const ALL: [ScenarioKind; 3] = [
        ScenarioKind::Pneumoperitoneum,
        ScenarioKind::GravityPose,
        ScenarioKind::ToolPush,
    ];

    /// Name used in files and on the command line: `"pneumoperitoneum"`, `"gravity-pose"`,
    /// `"tool-push"`.
    pub fn name(self) -> &'static str {
        match self {
            ScenarioKind::Pneumoperitoneum => "pneumoperitoneum",
            ScenarioKind::GravityPose => "gravity-pose",
            ScenarioKind::ToolPush => "tool-push",
        }
    }

    /// The scenario called `name` (see [`ScenarioKind::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }

    /// The scenarios called `names`, or every scenario when `names` is empty; an unknown name
    /// is an error that lists the known ones.
    pub fn parse_list(names: &[String]) -> Result<Vec<Self>, String> {
        if names.is_empty() {
            return Ok(Self::ALL.to_vec());
        }
        names
            .iter()
            .map(|n| {
                Self::from_name(n).ok_or_else(|| {
                    format!(
                        "unknown scenario '{n}' (known: {})",
                        Self::ALL.map(|k| k.name()).join(", ")
                    )
                })
            })
            .collect()
    }

    /// Unit of [`SequenceSpec::magnitude`] for this scenario: `"Pa"` (pressure, traction) or
    /// `"deg"` (tilt angle).
    pub fn magnitude_unit(self) -> &'static str {
        match self {
            ScenarioKind::GravityPose => "deg",
            _ => "Pa",
        }
    }

    /// The full-load magnitude tuned on the bundled phantom (E = 4500 Pa, held by its
    /// ligament box and the truth's elastic bed) so that the largest surface displacement of
    /// the default truth at full load is 1.5–3.5 cm: 200 Pa of pressure (→ 24.7 mm), a 25°
    /// tilt (→ about 30 mm), 400 Pa of tool traction (→ 31.7 mm).
    pub fn default_magnitude(self) -> f64 {
        match self {
            ScenarioKind::Pneumoperitoneum => 200.0,
            ScenarioKind::GravityPose => 25.0,
            ScenarioKind::ToolPush => 400.0,
        }
    }
}

impl std::fmt::Display for ScenarioKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// How the ground truth is discretised: the scene's model with its grid and material replaced
/// by these (fixed regions, structures and the rest of the scene are kept; the scene's own
/// loads are replaced by the scenario's).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TruthModel {
    /// Edge of a grid cell, metres (default 0.010).
    pub cell_size: f64,
    /// Octree levels on cut cells (default 2), at most [`MAX_SUBDIVISIONS`].
    pub subdivisions: u32,
    /// Integration of cut cells (default finite-cell).
    pub integration: IntegrationMode,
    /// Constitutive law (default neo-Hookean).
    pub law: LawKind,
    /// Poisson's ratio (default 0.49).
    pub poisson_ratio: f64,
    /// Young's modulus, Pa; `None` (default): the scene's.
    pub young_modulus: Option<f64>,
    /// Stiffness of an elastic bed under the posterior part of the surface (the part with
    /// `y ≤ lo.y + `[`BED_DEPTH_FRACTION`]` · e.y` of its bounding box), N/m³ (pascals per
    /// metre of displacement, in every direction): the organs the liver rests on in a supine
    /// patient (diaphragm, retroperitoneum), which the registration model does not have.
    /// Without it the phantom, held only by its ligament box, swings almost rigidly under any
    /// load. Default [`DEFAULT_BED_STIFFNESS`]; 0: no bed.
    pub bed_stiffness: f64,
    /// Fictitious-domain weight α of the truth's cut cells (default 1e-4, the finite cell
    /// method's usual small value): fixed here, so that the ground truth does not move when
    /// the registration model's `grid.min_fraction` default does.
    pub min_fraction: f64,
}

impl Default for TruthModel {
    fn default() -> Self {
        Self {
            cell_size: 0.010,
            subdivisions: 2,
            integration: IntegrationMode::FiniteCell,
            law: LawKind::NeoHookean,
            poisson_ratio: 0.49,
            young_modulus: None,
            bed_stiffness: DEFAULT_BED_STIFFNESS,
            min_fraction: 1e-4,
        }
    }
}

impl TruthModel {
    /// Whether this truth would be discretised exactly like `scene`'s own model (same cell
    /// size, subdivisions, integration, fictitious weight, law, ν and E, and no elastic bed):
    /// then a registration
    /// would be graded against itself.
    pub fn same_as_scene(&self, scene: &LoadedScene) -> bool {
        let s = &scene.scene;
        let h = s.grid.cell_size * scene.length_scale();
        (h - self.cell_size).abs() <= 1e-12 * h.max(self.cell_size)
            && s.grid.subdivisions == self.subdivisions
            && s.grid.integration == self.integration
            && s.grid.min_fraction == self.min_fraction
            && s.material.law == self.law
            && s.material.poisson_ratio == self.poisson_ratio
            && self
                .young_modulus
                .is_none_or(|e| e == s.material.young_modulus)
            && self.bed_stiffness == 0.0
    }

    /// `scene` with its grid and material replaced by this truth model's, and its elastic
    /// supports (`[[boundary.support]]`, the registration model's guess of what the liver
    /// rests on) removed: the truth's own bed ([`TruthModel::bed_stiffness`]) stands for the
    /// real anatomy, so the registration's guess is graded, not copied.
    pub fn apply_to(&self, scene: &LoadedScene) -> LoadedScene {
        let mut out = scene.clone();
        let s = &mut out.scene;
        s.boundary.support.clear();
        s.grid.cell_size = self.cell_size / scene.length_scale();
        s.grid.subdivisions = self.subdivisions;
        s.grid.integration = self.integration;
        s.grid.min_fraction = self.min_fraction;
        s.material.law = self.law;
        s.material.poisson_ratio = self.poisson_ratio;
        if let Some(e) = self.young_modulus {
            s.material.young_modulus = e;
        }
        out
    }
}

/// What sequence to synthesize.
#[derive(Debug, Clone, PartialEq)]
pub struct SequenceSpec {
    /// The scenario.
    pub kind: ScenarioKind,
    /// Number of frames (≥ 1).
    pub frames: usize,
    /// Full-load magnitude: pressure in Pa (pneumoperitoneum), tilt angle in degrees
    /// (gravity-pose), traction in Pa (tool-push). See [`ScenarioKind::default_magnitude`].
    pub magnitude: f64,
    /// Share of the frames over which the load ramps up, in `(0, 1]` (default 2/3); see
    /// [`load_fraction`].
    pub ramp_fraction: f64,
    /// The clouds: density, noise (m), outliers, visible fraction, the constant model→camera
    /// `rigid_offset` (m) and the base `seed` (frame `k` uses [`frame_seed`]`(seed, k)`).
    pub cloud: CloudSpec,
    /// Discretisation of the ground truth.
    pub truth: TruthModel,
}

impl SequenceSpec {
    /// The defaults for the bundled phantom: 10 frames, the scenario's default magnitude, a
    /// ramp over 2/3 of the frames, 3 samples/cm², 1 mm noise, 10 % outliers, 30 % of the
    /// surface visible, a model→camera offset of about 10° and 2 cm (different per scenario),
    /// and the default [`TruthModel`].
    pub fn phantom_default(kind: ScenarioKind) -> Self {
        let (axis, angle_deg, t, seed): (Vector3<f64>, f64, Vector3<f64>, u64) = match kind {
            ScenarioKind::Pneumoperitoneum => {
                (Vector3::z(), 10.0, Vector3::new(0.02, -0.01, 0.005), 101)
            }
            ScenarioKind::GravityPose => (
                Vector3::new(1.0, 0.0, 1.0),
                -9.0,
                Vector3::new(-0.012, 0.015, -0.008),
                202,
            ),
            ScenarioKind::ToolPush => (
                Vector3::new(0.3, 1.0, 0.2),
                11.0,
                Vector3::new(0.005, 0.012, 0.017),
                303,
            ),
        };
        let rotation =
            Rotation3::from_axis_angle(&Unit::new_normalize(axis), angle_deg.to_radians());
        Self {
            kind,
            frames: 10,
            magnitude: kind.default_magnitude(),
            ramp_fraction: DEFAULT_RAMP_FRACTION,
            cloud: CloudSpec {
                density_per_cm2: 3.0,
                noise_sigma: 1e-3,
                outlier_fraction: 0.1,
                visible_fraction: Some(0.3),
                rigid_offset: Some((rotation, t)),
                seed,
            },
            truth: TruthModel::default(),
        }
    }

    /// Checks every parameter's range.
    pub fn validate(&self) -> Result<(), SequenceError> {
        let bad = |m: String| Err(SequenceError::InvalidSpec(m));
        if self.frames == 0 {
            return bad("frames must be at least 1".into());
        }
        if !self.magnitude.is_finite() {
            return bad(format!("magnitude {} is not finite", self.magnitude));
        }
        if self.kind == ScenarioKind::GravityPose && self.magnitude.abs() > 180.0 {
            return bad(format!(
                "tilt angle {} degrees is outside [-180, 180]",
                self.magnitude
            ));
        }
        if !(self.ramp_fraction > 0.0 && self.ramp_fraction <= 1.0) {
            return bad(format!(
                "ramp_fraction {} is outside (0, 1]",
                self.ramp_fraction
            ));
        }
        let t = &self.truth;
        if !(t.cell_size.is_finite() && t.cell_size > 0.0) {
            return bad(format!(
                "truth cell_size {} m must be finite and > 0",
                t.cell_size
            ));
        }
        if t.subdivisions > MAX_SUBDIVISIONS {
            return bad(format!(
                "truth subdivisions {} exceed {MAX_SUBDIVISIONS}",
                t.subdivisions
            ));
        }
        if !(t.poisson_ratio > -1.0 && t.poisson_ratio < 0.5) {
            return bad(format!(
                "truth poisson_ratio {} is outside (-1, 0.5)",
                t.poisson_ratio
            ));
        }
        if let Some(e) = t.young_modulus {
            if !(e.is_finite() && e > 0.0) {
                return bad(format!("truth young_modulus {e} Pa must be finite and > 0"));
            }
        }
        if !(t.bed_stiffness.is_finite() && t.bed_stiffness >= 0.0) {
            return bad(format!(
                "truth bed_stiffness {} N/m³ must be finite and >= 0",
                t.bed_stiffness
            ));
        }
        self.cloud
            .validate()
            .map_err(|e| SequenceError::InvalidSpec(format!("cloud: {e}")))
    }

    /// The model→camera transform (the cloud spec's `rigid_offset`, identity when unset).
    pub fn model_to_camera(&self) -> RigidTransform {
        self.cloud
            .rigid_offset
            .map_or_else(RigidTransform::identity, |(r, t)| RigidTransform::new(r, t))
    }
}

/// Errors synthesizing a sequence.
#[derive(Debug, thiserror::Error)]
pub enum SequenceError {
    /// A [`SequenceSpec`] parameter is out of its range.
    #[error("invalid sequence specification: {0}")]
    InvalidSpec(String),
    /// The scene names no camera, which the clouds need.
    #[error("{0}: the scene has no [registration] camera; a synthetic sequence needs one")]
    NoCamera(String),
    /// The camera of the scene is unusable.
    #[error("camera: {0}")]
    Camera(#[from] ViewError),
    /// The truth model could not be built from the scene.
    #[error("truth model: {0}")]
    Model(#[from] ModelError),
    /// A load region could not be embedded in the truth grid.
    #[error("{what}: {source}")]
    Embedding {
        /// Which load.
        what: String,
        /// Why.
        source: EmbeddingError,
    },
    /// The scenario's region holds no part of the surface.
    #[error("{0}")]
    EmptyRegion(String),
    /// A frame's ground truth did not converge (never used silently).
    #[error("ground truth of frame {frame} (load fraction {load:.4}) failed: {message}")]
    TruthSolve {
        /// Frame index.
        frame: usize,
        /// Load fraction of the frame.
        load: f64,
        /// Why.
        message: String,
    },
    /// A frame's cloud could not be synthesized.
    #[error("cloud of frame {frame}: {source}")]
    Cloud {
        /// Frame index.
        frame: usize,
        /// Why.
        source: SynthError,
    },
}

/// Load fraction in `[0, 1]` of frame `frame` (from 0) of a `frames`-frame sequence whose
/// load ramps over `ramp_fraction` of the frames: with `n = clamp(round(ramp_fraction ·
/// frames), 1, frames)` and `t = min((frame + 1) / n, 1)`, the smooth step `3t² − 2t³`. It
/// reaches 1 at frame `n − 1` and holds there for the remaining frames; frame 0 already
/// carries a little load.
pub fn load_fraction(frame: usize, frames: usize, ramp_fraction: f64) -> f64 {
    let n = ((ramp_fraction * frames as f64).round() as usize).clamp(1, frames.max(1));
    let t = ((frame + 1) as f64 / n as f64).min(1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Seed of frame `frame`'s cloud from the spec's base `seed` (a different, deterministic
/// stream per frame).
pub fn frame_seed(seed: u64, frame: usize) -> u64 {
    seed ^ (frame as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

/// The full load of a scenario, resolved on a surface (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ScenarioLoad {
    /// Dead pressure `pressure` (Pa) on the surface inside `region` (metres).
    Pressure {
        /// Loaded part of the surface.
        region: Aabb,
        /// Pa; positive pushes inwards.
        pressure: f64,
    },
    /// Body force `density · delta_g` (N/m³) over the whole body.
    BodyForce {
        /// kg/m³.
        density: f64,
        /// Change of gravity `g_new − g_old`, m/s².
        delta_g: Vector3<f64>,
    },
    /// Dead traction (Pa) on the surface inside `region` (metres).
    Traction {
        /// Loaded part of the surface.
        region: Aabb,
        /// Force per unit rest area, Pa.
        traction: Vector3<f64>,
    },
}

impl ScenarioLoad {
    /// The full load of scenario `kind` with `magnitude` (Pa or degrees) on `surface` (metres,
    /// patient frame: x right → left, y posterior → anterior, z inferior → superior) of
    /// material density `density` (kg/m³). With `lo`, `e` the surface's bounding-box corner
    /// and extent:
    /// * pneumoperitoneum: `magnitude` Pa on the surface with `y ≥ lo.y + 0.5 e.y`,
    ///   `z ≥ lo.z + 0.5 e.z` and `x ≤ lo.x + 0.6 e.x` (the anterior-superior dome of the
    ///   right lobe, diaphragm side);
    /// * gravity-pose: `g_old = (0, −9.81, 0)` (supine), `g_new` = `g_old` turned about +x by
    ///   `magnitude` degrees (head up: gravity gains a component towards inferior), body force
    ///   `ρ (g_new − g_old)`;
    /// * tool-push: `magnitude` Pa towards +z (superior) on a 3 cm box (1 cm tall) centred on
    ///   the surface vertex nearest to `(lo.x + 0.8 e.x, lo.y + 0.75 e.y, lo.z)` — the
    ///   inferior face of the thin left lobe, near its anterior edge.
    pub fn for_surface(
        kind: ScenarioKind,
        magnitude: f64,
        surface: &TriSurface,
        density: f64,
    ) -> Self {
        let (lo, hi) = surface
            .bounding_box()
            .unwrap_or((Point3::origin(), Point3::origin()));
        let e = hi - lo;
        let big = 1.0 + e.norm();
        match kind {
            ScenarioKind::Pneumoperitoneum => ScenarioLoad::Pressure {
                region: Aabb::new(
                    Point3::new(lo.x - big, lo.y + 0.5 * e.y, lo.z + 0.5 * e.z),
                    Point3::new(lo.x + 0.6 * e.x, hi.y + big, hi.z + big),
                ),
                pressure: magnitude,
            },
            ScenarioKind::GravityPose => {
                let g_old = Vector3::new(0.0, -STANDARD_GRAVITY, 0.0);
                let turn = Rotation3::from_axis_angle(&Vector3::x_axis(), magnitude.to_radians());
                ScenarioLoad::BodyForce {
                    density,
                    delta_g: turn * g_old - g_old,
                }
            }
            ScenarioKind::ToolPush => {
                let aim = Point3::new(lo.x + 0.8 * e.x, lo.y + 0.75 * e.y, lo.z);
                let centre = surface
                    .vertices
                    .iter()
                    .min_by(|a, b| (*a - aim).norm().total_cmp(&(*b - aim).norm()))
                    .copied()
                    .unwrap_or(aim);
                let half = Vector3::new(
                    0.5 * TOOL_PATCH_SIZE,
                    0.5 * TOOL_PATCH_SIZE,
                    0.5 * TOOL_PATCH_SIZE / 3.0,
                );
                ScenarioLoad::Traction {
                    region: Aabb::new(centre - half, centre + half),
                    traction: Vector3::new(0.0, 0.0, magnitude),
                }
            }
        }
    }

    /// Grid forces (N, 3 per node) of this load on `grid` with the surface `surface`
    /// (metres), through the embedding (surface loads) or the grid's quadrature (body force).
    /// Errors when a surface region holds no part of the surface.
    pub fn forces(
        &self,
        grid: &WeightedCellGrid,
        surface: &TriSurface,
    ) -> Result<Vec<f64>, SequenceError> {
        let mut f = vec![0.0; 3 * grid.node_count()];
        let emb = |what: &str| {
            let what = what.to_string();
            move |source| SequenceError::Embedding { what, source }
        };
        let loaded = match self {
            ScenarioLoad::Pressure { region, pressure } => {
                pressure_forces(grid, surface, Some(region), *pressure, &mut f)
                    .map_err(emb("pressure region"))?
            }
            ScenarioLoad::Traction { region, traction } => {
                traction_forces(grid, surface, region, *traction, &mut f)
                    .map_err(emb("tool patch"))?
            }
            ScenarioLoad::BodyForce { density, delta_g } => {
                let b = delta_g * *density;
                body_forces(grid, |_| b, &mut f);
                1
            }
        };
        if loaded == 0 {
            return Err(SequenceError::EmptyRegion(format!(
                "the load region {self:?} holds no part of the surface"
            )));
        }
        Ok(f)
    }

    /// Description for `sequence.json`, lengths divided by `length_scale` (scene units).
    fn to_json(self, length_scale: f64) -> serde_json::Value {
        let b = |r: &Aabb| {
            let s = |p: &Point3<f64>| [p.x / length_scale, p.y / length_scale, p.z / length_scale];
            [s(&r.min), s(&r.max)]
        };
        match self {
            ScenarioLoad::Pressure { region, pressure } => serde_json::json!({
                "type": "pressure", "region": b(&region), "pressure_pa": pressure,
            }),
            ScenarioLoad::BodyForce { density, delta_g } => serde_json::json!({
                "type": "body-force", "density": density,
                "delta_g": [delta_g.x, delta_g.y, delta_g.z],
            }),
            ScenarioLoad::Traction { region, traction } => serde_json::json!({
                "type": "traction", "region": b(&region),
                "traction_pa": [traction.x, traction.y, traction.z],
            }),
        }
    }
}

/// One frame of a synthetic sequence. Lengths in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticFrame {
    /// Load fraction of the frame ([`load_fraction`]).
    pub load_fraction: f64,
    /// The cloud, camera frame, shuffled (inliers and outliers mixed).
    pub cloud: Vec<Point3<f64>>,
    /// Whether each cloud point is an outlier (parallel to `cloud`).
    pub is_outlier: Vec<bool>,
    /// Number of outliers in the cloud.
    pub outliers: usize,
    /// True positions of every structure of the scene, in scene order and point order (a mesh
    /// structure: its vertices), camera frame.
    pub truth_structures: Vec<(String, Vec<Point3<f64>>)>,
    /// True positions of the surface vertices (triangles: [`SyntheticSequence::triangles`]),
    /// camera frame.
    pub truth_surface: Vec<Point3<f64>>,
    /// Largest displacement of a surface vertex from its rest position, metres.
    pub max_displacement: f64,
    /// Newton iterations the frame's truth took (0 when the load did not change).
    pub newton_iterations: usize,
    /// Wall time of the frame's truth solve, ms.
    pub solve_ms: f64,
}

impl SyntheticFrame {
    /// The cloud's inliers (noisy surface samples), camera frame, in cloud order.
    pub fn inliers(&self) -> Vec<Point3<f64>> {
        super::point_cloud::inliers_of(&self.cloud, &self.is_outlier)
    }
}

/// A synthetic sequence: frames with clouds and ground truth. Lengths in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticSequence {
    /// The scenario.
    pub kind: ScenarioKind,
    /// The specification it was made from.
    pub spec: SequenceSpec,
    /// The resolved full load (model frame, metres).
    pub load: ScenarioLoad,
    /// The frames, in order.
    pub frames: Vec<SyntheticFrame>,
    /// The camera in the camera (cloud) frame: the scene's camera moved by `model_to_camera`.
    pub camera: Camera,
    /// The constant rigid transform from the model frame to the camera (cloud) frame.
    pub model_to_camera: RigidTransform,
    /// Triangles of the surface (indices into `rest_surface` and each frame's
    /// `truth_surface`).
    pub triangles: Vec<[usize; 3]>,
    /// The undeformed surface vertices, model frame.
    pub rest_surface: Vec<Point3<f64>>,
    /// The undeformed structures, model frame, in scene order.
    pub rest_structures: Vec<(String, Vec<Point3<f64>>)>,
    /// Active nodes of the truth grid.
    pub truth_nodes: usize,
    /// Active cells of the truth grid.
    pub truth_cells: usize,
    /// Wall time of building the truth model and solving every frame, ms.
    pub truth_ms: f64,
}

impl SyntheticSequence {
    /// Frame `k`'s true surface as a triangle surface (camera frame, metres).
    pub fn truth_surface(&self, k: usize) -> TriSurface {
        TriSurface::new(self.frames[k].truth_surface.clone(), self.triangles.clone())
    }

    /// The rest surface moved into the camera frame (what a perfect rigid registration with
    /// no deformation would predict), metres.
    pub fn rest_surface_in_camera(&self) -> TriSurface {
        TriSurface::new(
            self.model_to_camera.apply_all(&self.rest_surface),
            self.triangles.clone(),
        )
    }
}

/// The part of `surface` (metres, patient frame) under the truth's elastic bed: `y ≤ lo.y +`
/// [`BED_DEPTH_FRACTION`]` · e.y` with `lo`, `e` the bounding box's corner and extent.
pub fn bed_region(surface: &TriSurface) -> Aabb {
    let (lo, hi) = surface
        .bounding_box()
        .unwrap_or((Point3::origin(), Point3::origin()));
    let e = hi - lo;
    let big = 1.0 + e.norm();
    Aabb::new(
        Point3::new(lo.x - big, lo.y - big, lo.z - big),
        Point3::new(hi.x + big, lo.y + BED_DEPTH_FRACTION * e.y, hi.z + big),
    )
}

/// Adds to `model` the elastic bed of [`TruthModel::bed_stiffness`]: springs of `stiffness`
/// N/m³ per unit rest area holding the surface inside [`bed_region`] at rest.
pub fn add_elastic_bed(model: &mut SceneModel, stiffness: f64) -> Result<(), SequenceError> {
    let region = bed_region(&model.surface);
    let bed = PenaltySprings::fixed_surface_region(
        &model.problem.grid,
        &model.surface,
        &region,
        stiffness,
    )
    .map_err(|source| SequenceError::Embedding {
        what: "elastic bed".into(),
        source,
    })?
    .ok_or_else(|| SequenceError::EmptyRegion("the elastic bed holds no surface".into()))?;
    model.problem.springs.push(bed);
    Ok(())
}

/// The scene's camera (`[registration] camera`), in metres, model frame.
pub fn scene_camera(scene: &LoadedScene) -> Result<Camera, SequenceError> {
    let cam = scene
        .scene
        .registration
        .as_ref()
        .and_then(|r| r.camera.as_ref())
        .ok_or_else(|| SequenceError::NoCamera(scene.path.display().to_string()))?;
    let s = scene.length_scale();
    let p = |v: [f64; 3]| Point3::new(v[0], v[1], v[2]) * s;
    Ok(match cam.up {
        Some(up) => Camera::new(
            p(cam.position),
            p(cam.look_at),
            Vector3::from(up),
            DEFAULT_FOV_DEG,
        )?,
        None => Camera::looking_at(p(cam.position), p(cam.look_at))?,
    })
}

/// Solves the truth from the equilibrium `u` at load fraction `from` to `to` (loads
/// `s · f_full`) by Newton continuation: one [`NewtonSolver::improve`] per increment, starting
/// with the whole step, halving a failed increment (from the last converged state) at most
/// `max_bisections` times in a row and doubling again after a success. An increment converges
/// when `improve` does, or when its iterations stall without failure below
/// [`TRUTH_STALL_TOLERANCE`] (round-off). Returns the Newton iterations, or why it failed.
fn continue_load(
    solver: &mut NewtonSolver,
    model: &mut SceneModel,
    f_full: &[f64],
    u: &mut Vec<f64>,
    from: f64,
    to: f64,
) -> Result<usize, String> {
    let settings = solver.settings;
    let full = to - from;
    let mut step = full;
    let mut current = from;
    let mut iterations = 0;
    let mut consecutive = 0;
    while (to - current).abs() > 1e-14 {
        let target = if (to - current).abs() <= step.abs() {
            to
        } else {
            current + step
        };
        model.problem.external = f_full.iter().map(|f| f * target).collect();
        let mut trial = u.clone();
        let r = solver.improve(&mut model.problem, &[], &mut trial, settings.max_iterations);
        iterations += r.iterations;
        let stalled_at_roundoff =
            r.failure.is_none() && r.relative_residual <= TRUTH_STALL_TOLERANCE;
        if r.converged || stalled_at_roundoff {
            *u = trial;
            current = target;
            consecutive = 0;
            step = if step.abs() * 2.0 >= full.abs() {
                full
            } else {
                step * 2.0
            };
        } else {
            if consecutive >= settings.max_bisections {
                let why = r.failure.map_or_else(
                    || format!("no convergence in {} Newton iterations", r.iterations),
                    |(o, m)| format!("{}: {m}", o.name()),
                );
                return Err(format!(
                    "increment to load fraction {target:.4} failed after {consecutive} \
                     bisections: {why} (relative residual {:.3e})",
                    r.relative_residual
                ));
            }
            consecutive += 1;
            step *= 0.5;
        }
    }
    Ok(iterations)
}

/// Synthesizes the sequence `spec` for `scene` (for example the bundled phantom written by
/// [`crate::phantom::write_phantom`]): solves the truth ([`solve_truth`]), then synthesizes
/// each frame's cloud with the spec's cloud settings ([`SolvedTruth::sequence`]).
/// Deterministic for a spec.
///
/// Errors: invalid spec, no camera in the scene, a scene that cannot be built with the truth
/// discretisation, an empty load region, a truth solve that does not converge, or a cloud
/// that cannot be synthesized (e.g. nothing visible).
pub fn generate_sequence(
    scene: &LoadedScene,
    spec: &SequenceSpec,
) -> Result<SyntheticSequence, SequenceError> {
    solve_truth(scene, spec)?.sequence(&spec.cloud)
}

/// One frame of a solved truth, before any cloud: model frame, metres.
#[derive(Debug, Clone)]
struct TruthFrame {
    /// Load fraction ([`load_fraction`]).
    load_fraction: f64,
    /// The deformed surface (model frame).
    surface: TriSurface,
    /// The deformed structures, in scene order (model frame).
    structures: Vec<(String, Vec<Point3<f64>>)>,
    /// Largest displacement of a surface vertex, m.
    max_displacement: f64,
    /// Newton iterations of the frame's solve.
    newton_iterations: usize,
    /// Wall time of the frame's solve, ms.
    solve_ms: f64,
}

/// The truth of a sequence, solved once: every frame's deformed surface and structures in the
/// model frame, before the camera sees them. [`SolvedTruth::sequence`] synthesizes the clouds
/// of any [`CloudSpec`] from it, so that sequences differing only in their clouds (noise,
/// outliers, the visible share, the camera offset, the seed) share one truth solve.
#[derive(Debug, Clone)]
pub struct SolvedTruth {
    /// The specification the truth was solved for; [`SolvedTruth::sequence`] replaces its
    /// `cloud`, which the truth does not use.
    spec: SequenceSpec,
    /// The scene's camera, model frame.
    camera: Camera,
    /// The resolved full load (model frame, metres).
    load: ScenarioLoad,
    /// The solved frames.
    frames: Vec<TruthFrame>,
    /// Triangles of the surface.
    triangles: Vec<[usize; 3]>,
    /// The undeformed surface vertices, model frame.
    rest_surface: Vec<Point3<f64>>,
    /// The undeformed structures, model frame, in scene order.
    rest_structures: Vec<(String, Vec<Point3<f64>>)>,
    /// Active nodes of the truth grid.
    truth_nodes: usize,
    /// Active cells of the truth grid.
    truth_cells: usize,
    /// Wall time of building the truth model and solving every frame, ms.
    truth_ms: f64,
}

/// Solves the truth of `spec` on `scene`: builds the truth model ([`TruthModel::apply_to`]),
/// resolves the scenario's load on its surface ([`ScenarioLoad::for_surface`]) and solves the
/// frames by continuation (each from the previous frame's equilibrium; a frame whose load
/// fraction equals the previous one keeps its state exactly).
///
/// Errors: invalid spec, no camera in the scene, a scene that cannot be built with the truth
/// discretisation, an empty load region, or a truth solve that does not converge.
pub fn solve_truth(scene: &LoadedScene, spec: &SequenceSpec) -> Result<SolvedTruth, SequenceError> {
    spec.validate()?;
    let camera = scene_camera(scene)?;
    let start = Instant::now();
    let truth_scene = spec.truth.apply_to(scene);
    let mut model = SceneModel::from_scene(&truth_scene)?;
    let density = truth_scene.scene.material.density;
    let load = ScenarioLoad::for_surface(spec.kind, spec.magnitude, &model.surface, density);
    let f_full = load.forces(&model.problem.grid, &model.surface)?;
    if spec.truth.bed_stiffness > 0.0 {
        add_elastic_bed(&mut model, spec.truth.bed_stiffness)?;
    }
    let mut solver = NewtonSolver::new(model.newton);

    let mut u = vec![0.0; model.problem.dofs()];
    let mut previous = 0.0;
    let mut frames = Vec::with_capacity(spec.frames);
    for k in 0..spec.frames {
        let s = load_fraction(k, spec.frames, spec.ramp_fraction);
        let t = Instant::now();
        let newton_iterations = if s == previous {
            0
        } else {
            continue_load(&mut solver, &mut model, &f_full, &mut u, previous, s).map_err(
                |message| SequenceError::TruthSolve {
                    frame: k,
                    load: s,
                    message,
                },
            )?
        };
        let solve_ms = t.elapsed().as_secs_f64() * 1e3;
        previous = s;
        let surface_now = model.surface_embedding.positions(&u);
        let max_displacement = model
            .surface_embedding
            .interpolate(&u)
            .iter()
            .map(|d| d.norm())
            .fold(0.0, f64::max);
        frames.push(TruthFrame {
            load_fraction: s,
            surface: TriSurface::new(surface_now, model.surface.triangles.clone()),
            structures: model
                .structures
                .iter()
                .map(|st| (st.name.clone(), st.embedding.positions(&u)))
                .collect(),
            max_displacement,
            newton_iterations,
            solve_ms,
        });
    }
    Ok(SolvedTruth {
        spec: spec.clone(),
        camera,
        load,
        frames,
        triangles: model.surface.triangles.clone(),
        rest_surface: model.surface.vertices.clone(),
        rest_structures: model
            .structures
            .iter()
            .map(|st| (st.name.clone(), st.embedding.rest.clone()))
            .collect(),
        truth_nodes: model.problem.grid.node_count(),
        truth_cells: model.problem.grid.cells.len(),
        truth_ms: start.elapsed().as_secs_f64() * 1e3,
    })
}

impl SolvedTruth {
    /// The sequence of this truth seen with the clouds of `cloud`: for each frame the cloud
    /// the scene's camera sees of the true surface, with the frame's seed
    /// ([`frame_seed`]`(cloud.seed, k)`) and the cloud's rigid offset; the truth moved into
    /// the camera frame. The same as [`generate_sequence`] of the spec with `cloud`.
    ///
    /// Errors: `cloud` out of range, or a cloud that cannot be synthesized (e.g. nothing
    /// visible).
    pub fn sequence(&self, cloud: &CloudSpec) -> Result<SyntheticSequence, SequenceError> {
        let spec = SequenceSpec {
            cloud: *cloud,
            ..self.spec.clone()
        };
        spec.validate()?;
        let to_camera = spec.model_to_camera();
        let camera_in_camera_frame = Camera::new(
            to_camera.apply(&self.camera.position),
            to_camera.apply(&self.camera.look_at),
            to_camera.apply_vector(&self.camera.up),
            self.camera.fov_deg,
        )?;
        let mut frames = Vec::with_capacity(self.frames.len());
        for (k, truth) in self.frames.iter().enumerate() {
            let cloud_spec = CloudSpec {
                seed: frame_seed(spec.cloud.seed, k),
                ..spec.cloud
            };
            let cloud = synthesize_cloud(&truth.surface, &self.camera, &cloud_spec)
                .map_err(|source| SequenceError::Cloud { frame: k, source })?;
            frames.push(SyntheticFrame {
                load_fraction: truth.load_fraction,
                outliers: cloud.outlier_count(),
                cloud: cloud.points,
                is_outlier: cloud.is_outlier,
                truth_structures: truth
                    .structures
                    .iter()
                    .map(|(name, p)| (name.clone(), to_camera.apply_all(p)))
                    .collect(),
                truth_surface: to_camera.apply_all(&truth.surface.vertices),
                max_displacement: truth.max_displacement,
                newton_iterations: truth.newton_iterations,
                solve_ms: truth.solve_ms,
            });
        }
        Ok(SyntheticSequence {
            kind: spec.kind,
            load: self.load,
            spec,
            frames,
            camera: camera_in_camera_frame,
            model_to_camera: to_camera,
            triangles: self.triangles.clone(),
            rest_surface: self.rest_surface.clone(),
            rest_structures: self.rest_structures.clone(),
            truth_nodes: self.truth_nodes,
            truth_cells: self.truth_cells,
            truth_ms: self.truth_ms,
        })
    }
}

/// Directory (inside the output directory) holding the frames' clouds.
pub const FRAMES_DIR: &str = "frames";
/// Truth file written by [`write_sequence`].
pub const TRUTH_FILE: &str = "truth.jsonl";
/// Description file written by [`write_sequence`].
pub const SEQUENCE_FILE: &str = "sequence.json";

/// Name of frame `k`'s cloud file among `frames` frames: `frame_000.xyz`, … (at least three
/// digits, more when needed, so that lexical order is frame order).
pub fn frame_file_name(k: usize, frames: usize) -> String {
    let width = frames.saturating_sub(1).to_string().len().max(3);
    format!("frame_{k:0width$}.xyz")
}

/// `[x, y, z] / scale`.
fn scaled(p: &Point3<f64>, scale: f64) -> [f64; 3] {
    [p.x / scale, p.y / scale, p.z / scale]
}

/// Writes `seq` into `dir` (created if missing), every length divided by `length_scale`
/// (metres per scene unit, e.g. 0.001 for a scene in millimetres):
/// * `frames/frame_000.xyz`, …: each frame's cloud, one `x y z` line per point (shortest
///   round-trip formatting; readable by [`crate::mesh::read_points`]);
/// * `truth.jsonl`: one [`TruthRecord`] per frame — every structure's true points in the
///   camera frame, in point order;
/// * `sequence.json`: scenario, frame count, spec numbers (noise in scene units), the resolved
///   load, the truth model, the camera pose in the camera frame, `model_to_camera` (translation
///   in scene units) and, per frame, its file, load fraction, point and outlier counts and
///   maximal displacement (scene units).
pub fn write_sequence(
    seq: &SyntheticSequence,
    dir: &Path,
    length_scale: f64,
) -> std::io::Result<()> {
    if !(length_scale.is_finite() && length_scale > 0.0) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("length_scale {length_scale} must be finite and > 0"),
        ));
    }
    let frames_dir = dir.join(FRAMES_DIR);
    std::fs::create_dir_all(&frames_dir)?;
    let n = seq.frames.len();
    let mut truth = String::new();
    let mut frame_info = Vec::with_capacity(n);
    for (k, frame) in seq.frames.iter().enumerate() {
        let name = frame_file_name(k, n);
        let mut text = String::with_capacity(48 * frame.cloud.len());
        for p in &frame.cloud {
            let [x, y, z] = scaled(p, length_scale);
            // Writing to a String cannot fail.
            let _ = writeln!(text, "{x} {y} {z}");
        }
        write_file(&frames_dir.join(&name), text.as_bytes())?;
        let record = TruthRecord {
            frame: k,
            structures: frame
                .truth_structures
                .iter()
                .map(|(name, pts)| {
                    (
                        name.clone(),
                        pts.iter().map(|p| scaled(p, length_scale)).collect(),
                    )
                })
                .collect(),
        };
        truth.push_str(&serde_json::to_string(&record).map_err(std::io::Error::other)?);
        truth.push('\n');
        frame_info.push(serde_json::json!({
            "frame": k,
            "file": format!("{FRAMES_DIR}/{name}"),
            "load_fraction": frame.load_fraction,
            "points": frame.cloud.len(),
            "outliers": frame.outliers,
            "max_displacement": frame.max_displacement / length_scale,
            "newton_iterations": frame.newton_iterations,
        }));
    }
    write_file(&dir.join(TRUTH_FILE), truth.as_bytes())?;

    let spec = &seq.spec;
    let rigid = RigidRecord::from_transform(&seq.model_to_camera, length_scale);
    let cam = &seq.camera;
    let t = &spec.truth;
    let info = serde_json::json!({
        "kind": seq.kind.name(),
        "frames": n,
        "length_scale": length_scale,
        "magnitude": spec.magnitude,
        "magnitude_unit": seq.kind.magnitude_unit(),
        "ramp_fraction": spec.ramp_fraction,
        "load": seq.load.to_json(length_scale),
        "cloud": {
            "density_per_cm2": spec.cloud.density_per_cm2,
            "noise_sigma": spec.cloud.noise_sigma / length_scale,
            "outlier_fraction": spec.cloud.outlier_fraction,
            "visible_fraction": spec.cloud.visible_fraction,
            "seed": spec.cloud.seed,
        },
        "truth_model": {
            "cell_size": t.cell_size / length_scale,
            "subdivisions": t.subdivisions,
            "integration": t.integration.name(),
            "law": t.law,
            "poisson_ratio": t.poisson_ratio,
            "young_modulus": t.young_modulus,
            "nodes": seq.truth_nodes,
            "cells": seq.truth_cells,
        },
        "camera": {
            "position": scaled(&cam.position, length_scale),
            "look_at": scaled(&cam.look_at, length_scale),
            "up": [cam.up.x, cam.up.y, cam.up.z],
            "fov_deg": cam.fov_deg,
        },
        "model_to_camera": rigid,
        "frame_info": frame_info,
    });
    let text = serde_json::to_string_pretty(&info).map_err(std::io::Error::other)?;
    write_file(&dir.join(SEQUENCE_FILE), text.as_bytes())
}

/// Writes `bytes` to `path`.
fn write_file(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    out.write_all(bytes)?;
    out.flush()
}

#[cfg(test)]
#[path = "sequence_tests.rs"]
mod tests;
