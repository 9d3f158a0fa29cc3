//! The scene file's data model: plain serde types mirroring the contract's keys.
//!
//! Every struct denies unknown keys, so a misspelt key is an error that names it. Defaults are
//! applied by serde when a key is absent; value constraints are checked afterwards by
//! [`crate::scene::load_scene`] (see `validate.rs`), not here.
//!
//! Units: every *length* (box corners, inline points, probe points, `cell_size`, the camera, and
//! the coordinates inside the files the scene names) is in *scene units* (see [`Units`]).
//! Material constants, tractions, gravity and spring stiffnesses are always SI.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

pub use crate::grid::IntegrationMode;
pub use crate::linalg::SolverKind;
pub use crate::mechanics::{LawKind, VolumetricIntegration};
// The registration's own choices, which `[registration]` names.
pub use livereg_registration::registration::DataTerm;
pub use livereg_registration::session::{PoseUpdate, RigidMode};

/// A point or vector `[x, y, z]`.
pub type Vec3 = [f64; 3];

/// The unit of every length in the scene and in the files it names (`units = "m" | "cm" | "mm"`).
///
/// Lengths are *not* rescaled when a scene is loaded; results are written in the same unit.
/// Use [`Units::to_metres`] (or [`crate::scene::LoadedScene::length_scale`]) to convert to SI
/// when combining lengths with the SI material constants and loads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Deserialize, Serialize)]
pub enum Units {
    /// Metres (`"m"`, the default).
    #[default]
    #[serde(rename = "m")]
    Metres,
    /// Centimetres (`"cm"`).
    #[serde(rename = "cm")]
    Centimetres,
    /// Millimetres (`"mm"`).
    #[serde(rename = "mm")]
    Millimetres,
}

impl Units {
    /// Metres per scene unit: 1 for `"m"`, 0.01 for `"cm"`, 0.001 for `"mm"`.
    ///
    /// A length `l` read from the scene is `l * to_metres()` metres.
    pub fn to_metres(self) -> f64 {
        match self {
            Units::Metres => 1.0,
            Units::Centimetres => 0.01,
            Units::Millimetres => 0.001,
        }
    }

    /// The spelling used in the scene file (`"m"`, `"cm"` or `"mm"`).
    pub fn as_str(self) -> &'static str {
        match self {
            Units::Metres => "m",
            Units::Centimetres => "cm",
            Units::Millimetres => "mm",
        }
    }
}

/// An axis-aligned box `[[xmin, ymin, zmin], [xmax, ymax, zmax]]`, in scene units.
///
/// In a file it is written as the two corners; `min <= max` on every axis is checked when the
/// scene is loaded. Bounds are inclusive (see [`BoxRegion::contains`]).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(from = "[Vec3; 2]", into = "[Vec3; 2]")]
pub struct BoxRegion {
    /// Lower corner (scene units).
    pub min: Vec3,
    /// Upper corner (scene units).
    pub max: Vec3,
}

impl BoxRegion {
    /// True when `p` (scene units) lies inside the box or on its boundary.
    pub fn contains(&self, p: Vec3) -> bool {
        (0..3).all(|k| self.min[k] <= p[k] && p[k] <= self.max[k])
    }
}

impl From<[Vec3; 2]> for BoxRegion {
    fn from(c: [Vec3; 2]) -> Self {
        BoxRegion {
            min: c[0],
            max: c[1],
        }
    }
}

impl From<BoxRegion> for [Vec3; 2] {
    fn from(b: BoxRegion) -> Self {
        [b.min, b.max]
    }
}

/// A set of points given either as a point file or inline.
///
/// `points = "fixed.xyz"` (a path, relative to the scene file until loaded, absolute after
/// [`crate::scene::load_scene`]) or `points = [[x, y, z], ...]` (scene units).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(
    untagged,
    expecting = "invalid points: expected a point file path (a string) or an inline list of points [[x, y, z], ...]"
)]
pub enum PointSource {
    /// Inline points, in scene units.
    Inline(Vec<Vec3>),
    /// A point file (text `.xyz` `.txt` `.csv`, or `.ply`) whose coordinates are in scene units.
    File(PathBuf),
}

/// The whole scene file.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Unit of every length in the scene and its files (default `"m"`).
    #[serde(default)]
    pub units: Units,
    /// The pre-operative model: surface and internal structures (required).
    pub model: ModelSpec,
    /// The immersed-boundary grid (optional: every key has a default; the cell size is
    /// derived from the surface when omitted).
    #[serde(default)]
    pub grid: GridSpec,
    /// The hyperelastic material (required: `young_modulus` and `poisson_ratio`).
    pub material: MaterialSpec,
    /// Dirichlet conditions (default: nothing fixed).
    #[serde(default)]
    pub boundary: BoundarySpec,
    /// External loads (default: none).
    #[serde(default)]
    pub load: LoadSpec,
    /// Nonlinear solver settings (default: all defaults).
    #[serde(default)]
    pub solver: SolverSpec,
    /// `[[probe]]`: points whose displacement `livereg simulate` reports (default: none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub probe: Vec<ProbeSpec>,
    /// Registration settings (`[registration]`, optional; `None` when the table is absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub registration: Option<RegistrationSpec>,
}

impl Scene {
    /// Every file the scene names, with the dotted key naming it (`model.surface`,
    /// `model.structures[1].mesh`, `boundary.fixed[0].points`, …), paths as they stand
    /// (relative as written, absolute once loaded). The one list of a scene's files: what a
    /// recording stores and what an upload must bring.
    pub fn file_keys(&self) -> Vec<(String, PathBuf)> {
        let mut out = Vec::new();
        if !self.model.surface.as_os_str().is_empty() {
            out.push(("model.surface".to_string(), self.model.surface.clone()));
        }
        if let Some(p) = &self.model.segmentation {
            out.push(("model.segmentation".to_string(), p.clone()));
        }
        for (i, st) in self.model.structures.iter().enumerate() {
            if let Some(p) = &st.points {
                out.push((format!("model.structures[{i}].points"), p.clone()));
            }
            if let Some(p) = &st.mesh {
                out.push((format!("model.structures[{i}].mesh"), p.clone()));
            }
        }
        for (i, f) in self.boundary.fixed.iter().enumerate() {
            if let Some(PointSource::File(p)) = &f.points {
                out.push((format!("boundary.fixed[{i}].points"), p.clone()));
            }
        }
        for (i, p) in self.probe.iter().enumerate() {
            if let PointSource::File(f) = &p.points {
                out.push((format!("probe[{i}].points"), f.clone()));
            }
        }
        out
    }
}

/// `[model]`: the pre-operative model.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSpec {
    /// Closed triangle surface (`.obj .stl .ply .off .vtk .vtp`, or the triangles of a Gmsh 2.2
    /// `.msh`), coordinates in scene units. Required unless `segmentation` is given; then it
    /// is the surface derived on load.
    #[serde(default, skip_serializing_if = "path_is_empty")]
    pub surface: PathBuf,
    /// A segmentation labelmap (`.nii`, `.nii.gz`, `.nrrd`, `.seg.nrrd`; LPS millimetres) the
    /// surface is derived from on load, instead of `surface` (docs/segmentation.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub segmentation: Option<PathBuf>,
    /// The organ's label(s) in `segmentation`: a value, a segment name, or a list of them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<Labels>,
    /// Triangles of the surface derived from `segmentation` (default 20 000).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_triangles: Option<usize>,
    /// `[[model.structures]]`: internal structures carried along by the deformation.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub structures: Vec<StructureSpec>,
}

/// One `[[model.structures]]` entry: a named set of internal points or a small mesh.
///
/// Exactly one of `points` and `mesh` must be given (checked on load).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StructureSpec {
    /// Unique, non-empty name; the key of this structure in `register`'s `results.jsonl`.
    pub name: String,
    /// A point file (scene units); the output keeps the order of its points.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points: Option<PathBuf>,
    /// A surface mesh (same formats as `model.surface`, scene units) whose vertices are carried.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<PathBuf>,
    /// Label(s) of `model.segmentation` made into a closed mesh on load (a tumour).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_label: Option<Labels>,
    /// Label(s) of `model.segmentation` made into points on load (vessels: voxel centres).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points_label: Option<Labels>,
}

/// One label of a labelmap: its value or its segment name.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(untagged)]
pub enum Label {
    /// A voxel value.
    Value(u16),
    /// A segment name (3D Slicer's), matched exactly, then ignoring case.
    Name(String),
}

/// One label or several (united).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(untagged)]
pub enum Labels {
    /// One label.
    One(Label),
    /// Several labels, united.
    Many(Vec<Label>),
}

impl Labels {
    /// The labels as the segmentation module takes them.
    pub fn refs(&self) -> Vec<crate::segmentation::LabelRef> {
        let one = |l: &Label| match l {
            Label::Value(v) => crate::segmentation::LabelRef::Value(*v),
            Label::Name(n) => crate::segmentation::LabelRef::Name(n.clone()),
        };
        match self {
            Labels::One(l) => vec![one(l)],
            Labels::Many(ls) => ls.iter().map(one).collect(),
        }
    }
}

fn path_is_empty(p: &std::path::Path) -> bool {
    p.as_os_str().is_empty()
}

/// `[grid]`: the regular grid of hexahedral cells laid over the surface.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    /// Edge of a cubic cell, in scene units; finite and > 0. Optional: when omitted it is
    /// derived from the surface when the scene is loaded (the cube root of the volume it
    /// encloses, over 9).
    #[serde(default = "defaults::cell_size_derived")]
    pub cell_size: f64,
    /// Octree levels used on cut cells to compute inside volume fractions (finite-cell:
    /// integration leaves). Default 3; at most 6, since a cut cell has up to 8^L sub-cells.
    #[serde(default = "defaults::subdivisions")]
    pub subdivisions: u32,
    /// Integration of cut cells (default `"weighted-cell"`).
    #[serde(default)]
    pub integration: IntegrationMode,
    /// Fictitious-domain floor (dimensionless, in `[0, 0.5)`, default 1e-2): a cut cell's
    /// (sub-cell's) integration weight fraction is never taken below this, so cells with almost
    /// no inside volume keep a little stiffness and `K` stays non-singular.
    #[serde(default = "defaults::min_fraction")]
    pub min_fraction: f64,
    /// Shift of the grid origin, in *cell units*, each component in `[0, 1)` (default
    /// `[0, 0, 0]`). Used to move the surface relative to the grid, e.g. to test badly cut cells.
    #[serde(default)]
    pub origin_offset: Vec3,
}

impl Default for GridSpec {
    /// Every key at its default: the cell size to be derived from the surface.
    fn default() -> Self {
        Self::with_cell_size(defaults::cell_size_derived())
    }
}

impl GridSpec {
    /// Whether `cell_size` was omitted and is still to be derived from the surface (only before
    /// the scene is loaded: a loaded scene always has one).
    pub fn cell_size_omitted(&self) -> bool {
        self.cell_size.to_bits() == defaults::CELL_SIZE_OMITTED_BITS
    }

    /// A grid with the given cell size (scene units), other keys at their defaults.
    pub fn with_cell_size(cell_size: f64) -> Self {
        GridSpec {
            cell_size,
            subdivisions: defaults::subdivisions(),
            integration: IntegrationMode::WeightedCell,
            min_fraction: defaults::min_fraction(),
            origin_offset: [0.0; 3],
        }
    }
}

/// `[material]`: homogeneous hyperelastic material. Constants are SI whatever `units` says.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// Constitutive law (default `"neo-hookean"`).
    #[serde(default)]
    pub law: LawKind,
    /// Young's modulus E, in Pa. Required; > 0.
    pub young_modulus: f64,
    /// Poisson's ratio ν (dimensionless). Required; −1 < ν < 0.5 (use ≤ 0.499 for "nearly
    /// incompressible").
    pub poisson_ratio: f64,
    /// Mass density in kg/m³, used with gravity (default 1000); ≥ 0.
    #[serde(default = "defaults::density")]
    pub density: f64,
    /// Integration of the volumetric terms (default `"reduced"`).
    #[serde(default)]
    pub volumetric: VolumetricIntegration,
}

impl MaterialSpec {
    /// A material with the given law, Young's modulus (Pa) and Poisson's ratio, other keys at
    /// their defaults.
    pub fn new(law: LawKind, young_modulus: f64, poisson_ratio: f64) -> Self {
        MaterialSpec {
            law,
            young_modulus,
            poisson_ratio,
            density: defaults::density(),
            volumetric: VolumetricIntegration::Reduced,
        }
    }

    /// Lamé's first parameter λ = Eν/((1+ν)(1−2ν)), in Pa.
    pub fn lame_lambda(&self) -> f64 {
        let (e, nu) = (self.young_modulus, self.poisson_ratio);
        e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    }

    /// Shear modulus μ = E/(2(1+ν)), in Pa.
    pub fn lame_mu(&self) -> f64 {
        self.young_modulus / (2.0 * (1.0 + self.poisson_ratio))
    }
}

/// `[boundary]`: Dirichlet conditions.
#[derive(Debug, Clone, PartialEq, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BoundarySpec {
    /// `[[boundary.fixed]]`: parts held at their rest position (by penalty springs).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub fixed: Vec<FixedSpec>,
    /// `[[boundary.support]]`: elastic supports (the organs the liver rests on).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub support: Vec<SupportSpec>,
}

/// One `[[boundary.support]]`: an elastic support (Winkler foundation) under the part of the
/// surface inside `box` — what the liver rests on (retroperitoneum, kidney, diaphragm), known
/// from the pre-operative scan. With a partial intra-operative view it is the only thing that
/// holds the unseen back of the organ; without it the back swings freely (method.md §4).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SupportSpec {
    /// The supported part of the surface (scene units).
    #[serde(rename = "box")]
    pub bbox: BoxRegion,
    /// Spring stiffness per unit surface area, N/m³ (pascals per metre of displacement).
    pub stiffness: f64,
    /// `true` (default): the support pushes back along the surface normal only and lets the
    /// surface slide along it; `false`: it resists motion in every direction.
    #[serde(default = "defaults::sliding")]
    pub sliding: bool,
}

/// One `[[boundary.fixed]]` region: exactly one of `box` and `points` (checked on load).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FixedSpec {
    /// `box = [[x,y,z],[x,y,z]]`: the part of the surface inside this box (scene units).
    #[serde(rename = "box", default, skip_serializing_if = "Option::is_none")]
    pub bbox: Option<BoxRegion>,
    /// `points = "fixed.xyz"` or `points = [[x,y,z], ...]`: these points (on or inside the
    /// surface, scene units) are held in place.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points: Option<PointSource>,
    /// Penalty spring stiffness per held point, in N/m (SI: newtons per metre of displacement).
    /// `None` (default): chosen by the solver. Finite and > 0 when given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stiffness: Option<f64>,
}

/// What a [`FixedSpec`] holds, once validated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FixedRegion<'a> {
    /// The part of the surface inside a box.
    Box(&'a BoxRegion),
    /// Explicit points.
    Points(&'a PointSource),
}

impl FixedSpec {
    /// The region this entry holds, or `None` when it has neither or both of `box`/`points`
    /// (which [`crate::scene::load_scene`] rejects).
    pub fn region(&self) -> Option<FixedRegion<'_>> {
        match (&self.bbox, &self.points) {
            (Some(b), None) => Some(FixedRegion::Box(b)),
            (None, Some(p)) => Some(FixedRegion::Points(p)),
            _ => None,
        }
    }
}

/// `[load]`: external loads (SI).
#[derive(Debug, Clone, PartialEq, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LoadSpec {
    /// Gravitational acceleration in m/s² (default `[0, 0, 0]`); acts through `material.density`.
    #[serde(default)]
    pub gravity: Vec3,
    /// `[[load.traction]]`: dead loads on the surface.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub traction: Vec<TractionSpec>,
}

/// One `[[load.traction]]`: a dead load (force per unit *rest* area) on the surface in a box.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TractionSpec {
    /// The part of the surface loaded (scene units).
    #[serde(rename = "box")]
    pub bbox: BoxRegion,
    /// Traction vector in Pa (N/m² of rest area).
    pub value: Vec3,
}

/// `[solver]`: static Newton–Raphson with load stepping and increment bisection. All optional.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    /// Number of equal load increments (default 10), in `1..=10000`.
    #[serde(default = "defaults::load_steps")]
    pub load_steps: u32,
    /// Newton iterations allowed per increment (default 30), ≥ 1.
    #[serde(default = "defaults::max_newton_iterations")]
    pub max_newton_iterations: u32,
    /// Relative residual tolerance ‖R‖/‖R₀‖ (default 1e-8), in (0, 1).
    #[serde(default = "defaults::tolerance")]
    pub residual_tolerance: f64,
    /// Relative displacement tolerance ‖δu‖/‖u‖ (default 1e-8), in (0, 1).
    #[serde(default = "defaults::tolerance")]
    pub displacement_tolerance: f64,
    /// How many times a failed increment may be halved (default 6), at most 30.
    #[serde(default = "defaults::max_bisections")]
    pub max_bisections: u32,
    /// Backtracking line search on the Newton step (default true).
    #[serde(default = "defaults::yes")]
    pub line_search: bool,
    /// Linear solver (default `"auto"`).
    #[serde(default)]
    pub linear_solver: SolverKind,
    /// Newton steps use the tangent made positive semi-definite per integration point
    /// (corotated law: compressed points' twist modes clamped), so that every step is a
    /// descent direction and the Cholesky factorisation does not fail (default true);
    /// `false`: the exact tangent.
    #[serde(default = "defaults::yes")]
    pub projected_tangent: bool,
    /// Warm frames' modified-Newton steps factorise the tangent in single precision and
    /// refine each solve in double precision (default false): less time on large grids.
    #[serde(default)]
    pub mixed_precision: bool,
    /// Cut-cell step stabilisation γ of warm frames (dimensionless, in `[0, 1e4]`, default
    /// 100; 0: off): a tangent factorised to serve several modified-Newton steps gets a
    /// constant penalty `γ μ h (1 − f)` on the non-affine part of each cut cell's motion, so
    /// the nodes of badly cut cells no longer make its steps overshoot. The energy and
    /// residual are unchanged, hence the equilibrium too (see
    /// `mechanics::cut_cell_stabilization`). Cold frames and forward solves never use it.
    #[serde(default = "defaults::step_stabilization")]
    pub step_stabilization: f64,
    /// Penalty stiffness of Dirichlet springs in N/m, for fixed regions without their own
    /// `stiffness`. `None` (default): automatic. Finite and > 0 when given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub penalty_stiffness: Option<f64>,
}

impl Default for SolverSpec {
    fn default() -> Self {
        SolverSpec {
            load_steps: defaults::load_steps(),
            max_newton_iterations: defaults::max_newton_iterations(),
            residual_tolerance: defaults::tolerance(),
            displacement_tolerance: defaults::tolerance(),
            max_bisections: defaults::max_bisections(),
            line_search: true,
            linear_solver: SolverKind::Auto,
            projected_tangent: true,
            mixed_precision: false,
            step_stabilization: defaults::step_stabilization(),
            penalty_stiffness: None,
        }
    }
}

/// One `[[probe]]`: points whose displacement `livereg simulate` reports.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeSpec {
    /// A point file or inline points (scene units).
    pub points: PointSource,
}

/// The camera pose (scene units, model frame), used to find the visible part of the surface.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// Optical centre.
    pub position: Vec3,
    /// A point on the optical axis; must differ from `position`.
    pub look_at: Vec3,
    /// Up direction (optional; not parallel to the viewing direction).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub up: Option<Vec3>,
}

/// `[registration]`: registration settings. All optional.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RegistrationSpec {
    /// Rigid stage (default `"icp"`).
    #[serde(default)]
    pub rigid: RigidMode,
    /// How the pose evolves across frames (default `"hold"`).
    #[serde(default)]
    pub pose: PoseUpdate,
    /// Camera pose; `None` when unknown.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<Camera>,
    /// α of the imposed displacement (thesis 5.4): weight of the source→target pairs against the
    /// target→source mean. Default 0.75, in [0, 1].
    #[serde(default = "defaults::alpha")]
    pub alpha: f64,
    /// First penalty stiffness k₀ of the exponential ramp, N/m (`None`: automatic); > 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub penalty_start: Option<f64>,
    /// Last penalty stiffness k₁ of the ramp, N/m (`None`: automatic); > 0 and ≥ k₀.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub penalty_end: Option<f64>,
    /// Factor on the automatic ramp's ends (those not given above), > 0 (default 1): stiffer
    /// or softer springs that keep the cloud-noise weight
    /// (docs/data-term.md#the-data-terms-stiffness).
    #[serde(default = "defaults::penalty_scale")]
    pub penalty_scale: f64,
    /// Number of steps n_p of the ramp (default 3), ≥ 1.
    #[serde(default = "defaults::penalty_steps")]
    pub penalty_steps: u32,
    /// ICP iterations allowed per penalty step (default 10), ≥ 1.
    #[serde(default = "defaults::max_icp_iterations")]
    pub max_icp_iterations: u32,
    /// Model–cloud pairs farther apart than this (scene units) are dropped in the non-rigid
    /// stage (`None`: only the mean + 2σ rule); > 0. Useful with small visible patches.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_pair_distance: Option<f64>,
    /// Wall-clock budget of one frame, ms: when exceeded the best state so far is returned,
    /// flagged `time_budget` (`None`: no budget); > 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_budget_ms: Option<f64>,
    /// Clouds with more points are thinned to at most this many (default 2 000); ≥ 3.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_cloud_points: Option<u32>,
    /// Coarse-to-fine start: a cold frame (the first, or after a reset or failure) is first
    /// registered on a grid with cells this many times larger, and the fine registration
    /// starts from its prolongated displacement (`None`, default: off); in `(1, 4]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coarse_to_fine: Option<f64>,
    /// Rigid ICP prunes its pairs at median + 2 × 1.4826 MAD of their distances when true
    /// (the default: docs/bench.md#why-each-default); false: at mean + 2σ as in the thesis,
    /// which gross outliers and small visible patches defeat. (The non-rigid stage has its own
    /// rule: see `NonRigidSettings::robust_pruning`.)
    #[serde(default = "defaults::robust_pruning")]
    pub robust_pruning: bool,
    /// A frame whose pose is not known from the last one (the first, after a reset or a
    /// failure, a re-acquisition) has its rigid pose searched from many starts around the
    /// initial one, every turn up to a half turn (default true;
    /// docs/pose.md#global-pose-search); false: plain ICP from the initial pose.
    #[serde(default = "defaults::pose_search")]
    pub pose_search: bool,
    /// A frame whose cloud the rest shape explains within the cloud's own noise is kept at
    /// rest (flag `at_rest`) instead of being registered (default true;
    /// docs/frames.md#frames-at-rest).
    #[serde(default = "defaults::rest_test")]
    pub rest_test: bool,
    /// Warm frames whose clouds the last registered shape explains within their noise (the
    /// liver has not moved; seen by the same camera) are registered together, the newest up
    /// to this many (and `max_cloud_points` points), each cloud's springs at `1/n` of the
    /// stiffness: the cloud noise averages over the frames while the data term weighs as
    /// one frame's. 1: every frame alone. Default 4 (docs/frames.md#still-frames);
    /// needs `rest_test`'s noise test (off with it).
    #[serde(default = "defaults::still_frames")]
    pub still_frames: u32,
    /// A fitted pose whose uncertainty (the 1σ misplacement of the model's surface from the
    /// noise of its rigid fit, root mean square over the vertices) exceeds this, scene units,
    /// is flagged `pose_uncertain` on every frame that holds it. Omitted: 2 mm
    /// (docs/pose.md#pose-uncertainty).
    #[serde(default)]
    pub max_pose_uncertainty: Option<f64>,
    /// A frame whose expected error (`results.jsonl` `expected_error`: the registration's
    /// estimate of the mean error of the structures) exceeds this, scene units, is flagged
    /// `expected_error_high`, for a display to dim its overlay. Omitted: 5 mm.
    #[serde(default)]
    pub max_expected_error: Option<f64>,
    /// Warm frames refactorise the tangent on a helper thread while their Newton steps go on
    /// with the old factorisation (default false): faster on large grids, slightly less
    /// accurate (docs/frames.md#opt-in-speed-settings). Results stay deterministic.
    #[serde(default)]
    pub background_factorization: bool,
    /// Cloud points far from every other point (statistical outlier removal on the cloud
    /// alone: mean distance to their 8 nearest neighbours above median + 3 × 1.4826 MAD and
    /// 2.5 × the median) are removed before both stages when true (the default:
    /// docs/bench.md#why-each-default); the frame is flagged `isolated_removed`.
    #[serde(default = "defaults::remove_isolated_points")]
    pub remove_isolated_points: bool,
    /// Direction of the non-rigid stage's correspondences (`"surface-to-cloud"`: model
    /// vertices to their nearest cloud points, thesis alg. 3; `"cloud-to-surface"`: every cloud
    /// point to its closest point on the deformed model surface).
    #[serde(default)]
    pub data_term: DataTerm,
    /// Radius of the ball the cloud → surface term averages the surface normal over, scene
    /// units; 0: interpolated vertex normals (the mesh's own scale).
    /// Omitted: 0.125 × the cube root of the surface's volume, about 1.3 cm for a liver
    /// (docs/data-term.md#normals-at-the-organs-scale).
    #[serde(default)]
    pub normal_radius: Option<f64>,
    /// Explain each registered field again by a load at the contact alone, kept when the
    /// cloud away from the contact still lies on the surface (default true:
    /// docs/data-term.md#the-contact-refit); the frame is flagged `contact_refit` when kept.
    #[serde(default = "defaults::contact_refit")]
    pub contact_refit: bool,
    /// Radius of the contact region the refit holds, scene units, > 0. Omitted: 35 mm
    /// (docs/data-term.md#the-contact-refit).
    #[serde(default)]
    pub contact_radius: Option<f64>,
    /// Fresh factorisations one contact refit may make over all its solves, ≥ 1. Omitted: 2,
    /// chosen on the derived cells; grids finer than the derived one may need more
    /// (docs/data-term.md#the-contact-refit).
    #[serde(default)]
    pub refit_factorizations: Option<u32>,
}

impl Default for RegistrationSpec {
    fn default() -> Self {
        RegistrationSpec {
            rigid: RigidMode::Icp,
            pose: PoseUpdate::Hold,
            camera: None,
            alpha: defaults::alpha(),
            penalty_start: None,
            penalty_end: None,
            penalty_scale: defaults::penalty_scale(),
            penalty_steps: defaults::penalty_steps(),
            max_icp_iterations: defaults::max_icp_iterations(),
            max_pair_distance: None,
            time_budget_ms: None,
            max_cloud_points: None,
            coarse_to_fine: None,
            robust_pruning: defaults::robust_pruning(),
            pose_search: defaults::pose_search(),
            rest_test: defaults::rest_test(),
            still_frames: defaults::still_frames(),
            max_pose_uncertainty: None,
            max_expected_error: None,
            background_factorization: false,
            remove_isolated_points: defaults::remove_isolated_points(),
            data_term: DataTerm::default(),
            normal_radius: None,
            contact_refit: defaults::contact_refit(),
            contact_radius: None,
            refit_factorizations: None,
        }
    }
}

/// Documented default values, shared by serde and the `Default` impls.
pub mod defaults {
    use livereg_registration::session::SessionSettings;

    /// `grid.cell_size` when omitted: a NaN with its own payload (an explicit `nan` in a scene
    /// is another NaN, and an error) until the scene is loaded, which derives it from the
    /// surface ([`super::GridSpec::cell_size_omitted`]).
    pub fn cell_size_derived() -> f64 {
        f64::from_bits(CELL_SIZE_OMITTED_BITS)
    }

    /// Bits of [`cell_size_derived`]'s marker.
    pub const CELL_SIZE_OMITTED_BITS: u64 = 0x7ff8_0000_1818_0018;
    /// `grid.subdivisions`.
    pub fn subdivisions() -> u32 {
        3
    }
    /// `grid.min_fraction`.
    pub fn min_fraction() -> f64 {
        1e-2
    }
    /// `solver.step_stabilization` (γ of the cut-cell step stabilisation).
    pub fn step_stabilization() -> f64 {
        100.0
    }
    /// `material.density`, kg/m³.
    pub fn density() -> f64 {
        1000.0
    }
    /// `solver.load_steps`.
    pub fn load_steps() -> u32 {
        10
    }
    /// `solver.max_newton_iterations`.
    pub fn max_newton_iterations() -> u32 {
        30
    }
    /// `solver.residual_tolerance` and `solver.displacement_tolerance`.
    pub fn tolerance() -> f64 {
        1e-8
    }
    /// `solver.max_bisections`.
    pub fn max_bisections() -> u32 {
        6
    }
    /// `solver.line_search`.
    pub fn yes() -> bool {
        true
    }
    /// `boundary.support.sliding`.
    pub fn sliding() -> bool {
        true
    }
    /// `registration.alpha`.
    pub fn alpha() -> f64 {
        0.75
    }
    /// `registration.pose_search`.
    pub fn pose_search() -> bool {
        true
    }
    /// `registration.rest_test`.
    pub fn rest_test() -> bool {
        true
    }
    /// `registration.still_frames`.
    pub fn still_frames() -> u32 {
        livereg_registration::session::DEFAULT_STILL_FRAMES as u32
    }
    /// `registration.robust_pruning`.
    pub fn robust_pruning() -> bool {
        SessionSettings::default().rigid.robust_pruning
    }
    /// `registration.remove_isolated_points`.
    pub fn remove_isolated_points() -> bool {
        SessionSettings::default().remove_isolated_points
    }
    /// `registration.contact_refit`.
    pub fn contact_refit() -> bool {
        SessionSettings::default().contact_refit
    }
    /// `registration.penalty_scale`.
    pub fn penalty_scale() -> f64 {
        1.0
    }
    /// `registration.penalty_steps`.
    pub fn penalty_steps() -> u32 {
        3
    }
    /// `registration.max_icp_iterations`.
    pub fn max_icp_iterations() -> u32 {
        10
    }
}
