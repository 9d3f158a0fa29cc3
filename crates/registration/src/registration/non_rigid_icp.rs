//! Biomechanical non-rigid ICP (thesis alg. 3, eq. 5.4): penalty springs pull the model's
//! visible surface towards the intra-operative cloud while the hyperelastic grid decides how
//! the whole volume follows.

use std::collections::HashSet;
use std::sync::Arc;
use std::time::Instant;

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::correspondences::{
    pair, Correspondences, IndexedPoints, PairingRule, RIM_NEIGHBOURS, RIM_RATIO,
};
use super::surface_anchors::{incident_triangles, pair_cloud_to_surface, AnchoredPairs};
use super::surface_normals::NormalsAtScale;
use crate::geometry::{Camera, VisibleSurface};
use crate::grid::Embedding;
use crate::mechanics::{NewtonSettings, NewtonSolver, PenaltySprings, StaticProblem};
use crate::mesh::TriSurface;
use crate::model::Model;

/// The direction of the correspondences of non-rigid ICP.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DataTerm {
    /// Model vertices (visible from the camera, or all) → nearest cloud point, blended with
    /// the reverse direction by eq. 5.4 (thesis alg. 3), rim sources dropped.
    SurfaceToCloud,
    /// Every cloud point → its closest point on the deformed model surface, a barycentric
    /// point of a triangle (`registration::surface_anchors`): the spring acts there.
    #[default]
    CloudToSurface,
}

impl DataTerm {
    /// Scene-file name: `"surface-to-cloud"`, `"cloud-to-surface"`.
    pub fn name(self) -> &'static str {
        match self {
            DataTerm::SurfaceToCloud => "surface-to-cloud",
            DataTerm::CloudToSurface => "cloud-to-surface",
        }
    }
}

/// Settings of the non-rigid stage. Stiffnesses in N/m per source point, lengths in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NonRigidSettings {
    /// Blending α of eq. 5.4 between the source's own nearest target and the targets that
    /// chose it (0.75 in the thesis's fig. 5.4).
    pub alpha: f64,
    /// First penalty stiffness k₀ (soft: follow the global shape). `None`: 0.02 E h
    /// ([`PENALTY_START_PER_EH`]) times [`noise_weight`].
    pub penalty_start: Option<f64>,
    /// Last penalty stiffness k₁ (stiff: match detail). `None`: 2 E h ([`PENALTY_END_PER_EH`])
    /// times [`noise_weight`].
    pub penalty_end: Option<f64>,
    /// Factor on the automatic ramp's k₀ and k₁ (those not given by `penalty_start` /
    /// `penalty_end`), > 0; default 1. Unlike giving the stiffnesses, it keeps the
    /// [`noise_weight`] (scene key `registration.penalty_scale`).
    pub penalty_scale: f64,
    /// Steps of the exponential ramp from k₀ to k₁ (1: k₁ only).
    pub penalty_steps: usize,
    /// ICP iterations allowed per penalty step.
    pub max_icp_iterations: usize,
    /// Newton iterations per ICP iteration.
    pub newton_iterations: usize,
    /// A penalty step ends when the pulled surface points moved by at most this (root mean
    /// square, m; and none by more than [`LOCAL_MOTION_FACTOR`] times this) during the last
    /// ICP iteration: the displacement stopped changing (thesis alg. 3); a body whose surface
    /// moved by more elsewhere is then relaxed under the same springs
    /// ([`RELAX_NEWTON_ITERATIONS`]). An RMS, not a maximum: with a noisy cloud single pairs
    /// keep switching between neighbouring cloud points (measured on the phantom at 1 mm
    /// noise: the largest target jump stays at 2–9 mm after 10 iterations while the surface
    /// moves by 0.1–0.4 mm RMS).
    pub tolerance: f64,
    /// Pairs farther apart than mean + this × standard deviation are outliers (thesis: 2).
    pub outlier_sigma: f64,
    /// Prune with the median and MAD instead of the mean and standard deviation
    /// ([`robust_threshold`](super::correspondences::robust_threshold)). Default false for
    /// a cold registration (from rest, or after a reset), true for warm frames
    /// ([`NonRigidSettings::warm`]) with the cloud → surface data term. From rest a large
    /// *local* deformation (a lifted lobe: a few percent of the pairs centimetres long) looks
    /// like outliers to it and is never pulled (a full-surface, noise-free cloud of a 27 mm
    /// lobe lift ended at 0.78 mm TRE with the surface → cloud term, 0.91 mm with cloud →
    /// surface, against 0.58 mm with mean + 2σ). A warm frame starts from the last one, so
    /// its true pairs are short, and there it stops the drift of a sliding tool
    /// (tool-indentation press-slide, linear truth, 12 mm cells: 6.75 → 1.24 mm mean node
    /// error; docs/data-term.md#which-pairs-are-kept). The rigid stage uses it too
    /// (`RigidIcp::robust_pruning`).
    pub robust_pruning: bool,
    /// Pairs farther apart than this (m) are dropped as well: with a partial cloud, visible
    /// model points beyond the seen patch would otherwise be dragged onto its rim. `None`: no cap.
    pub max_pair_distance: Option<f64>,
    /// Drop model points whose nearest cloud point lies on the rim of the cloud's patch
    /// ([`IndexedPoints::rim_mask`]): the unseen surface is not dragged onto the rim.
    pub reject_rim: bool,
    /// Visibility (ray casts on the deformed surface) is recomputed every this many ICP
    /// iterations, counted across calls (frames); 1: at every iteration. In between, the last
    /// visible set is reused (the surface moves little between iterations and frames).
    pub visibility_interval: usize,
    /// Most Newton steps one factorisation of the tangent may serve (modified Newton, see
    /// [`NewtonSolver::with_factor_reuse`]); 1 refactorises at every step.
    pub factor_reuse: usize,
    /// Point-to-plane springs: each source is pulled along its current surface normal only,
    /// by the normal component of its blended displacement; otherwise
    /// point-to-point springs as in the thesis.
    pub point_to_plane: bool,
    /// With `factor_reuse > 1`: refactorisations run on a helper thread and are swapped in
    /// this many Newton steps after they were asked for, the steps in between using the old
    /// factorisation ([`NewtonSolver::set_background_lag`]); 0 (default): refactorise in
    /// place. Faster on large grids, less accurate (docs/frames.md#opt-in-speed-settings).
    pub background_lag: usize,
    /// Which way points are paired: model surface vertices to their nearest cloud points
    /// (thesis alg. 3), or every cloud point to its closest point on the model surface
    /// ([`DataTerm::CloudToSurface`]).
    pub data_term: DataTerm,
    /// The scale of the surface normals the cloud → surface term's point-to-plane springs
    /// pull along ([`NormalScale`]).
    pub normal_scale: NormalScale,
    /// Factor on every data-term spring's stiffness (the whole penalty ramp), > 0: 1 for one
    /// frame's cloud; `1/n` when the clouds of `n` still frames are registered together, so
    /// that they weigh as one frame against the body (`Session`,
    /// docs/frames.md#still-frames).
    pub data_weight: f64,
    /// The noise of the cloud being registered (m, 1σ along the normal), when measured: the
    /// automatic penalty ramp (no `penalty_start`/`penalty_end` given) is scaled by
    /// [`noise_weight`] of it. `None`: the reference stiffnesses.
    pub cloud_noise: Option<f64>,
}

/// The scale at which the cloud → surface term takes the surface normal at an anchor.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum NormalScale {
    /// Interpolated vertex normals: the scale of the mesh's triangles (the registration then
    /// depends on the triangulation, docs/data-term.md#normals-at-the-organs-scale).
    Vertex,
    /// Averaged over a ball whose radius follows the organ's size
    /// ([`NormalsAtScale::default_radius`]: 0.125 × ∛volume, about 1.3 cm for a liver).
    #[default]
    OrganSize,
    /// Averaged over a ball of this radius, m.
    Radius(f64),
}

impl NormalScale {
    /// The averaging for a surface whose rest vertices are `rest` (m) and triangles
    /// `triangles`; `None` for [`NormalScale::Vertex`] (or a surface without a volume).
    pub fn build(self, rest: &[Point3<f64>], triangles: &[[usize; 3]]) -> Option<NormalsAtScale> {
        let radius = match self {
            NormalScale::Vertex => None,
            NormalScale::OrganSize => NormalsAtScale::default_radius(rest, triangles),
            NormalScale::Radius(r) => Some(r),
        }?;
        NormalsAtScale::new(rest, triangles, radius)
    }
}

impl Default for NonRigidSettings {
    fn default() -> Self {
        Self {
            alpha: 0.75,
            penalty_start: None,
            penalty_end: None,
            penalty_scale: 1.0,
            penalty_steps: 3,
            max_icp_iterations: 10,
            newton_iterations: 2,
            tolerance: 5e-4,
            outlier_sigma: 2.0,
            robust_pruning: false,
            max_pair_distance: None,
            reject_rim: true,
            visibility_interval: 1,
            factor_reuse: 1,
            point_to_plane: true,
            background_lag: 0,
            data_term: DataTerm::default(),
            normal_scale: NormalScale::default(),
            data_weight: 1.0,
            cloud_noise: None,
        }
    }
}

impl NonRigidSettings {
    /// Settings for a frame that starts from the previous frame's result: the shape is
    /// already close, so one stiff penalty step with cheap (modified-Newton) iterations, one
    /// Newton step per ICP iteration, and a tighter ICP stop (0.3 mm RMS surface motion). A
    /// second step on the same springs with the kept factorisation is often cut by the line
    /// search below ½, which drops the factorisation; one step with the 0.5 mm stop ends the
    /// ICP loop before coarse grids have followed (45 mm cells: 1.52 against 1.44 mm).
    /// `livereg bench --only "default,cell x2,full-cell,cell x0.75"`: TRE 1.22 / 1.45 / 1.36 /
    /// 1.22 mm, as with two steps and 0.5 mm, at warm p95 29–30 ms on the default grid and
    /// 45–46 ms on 646 nodes (two steps: 41–48 and 131–151 ms).
    ///
    /// At most 6 ICP iterations: on a noisy cloud the surface never stops moving by the
    /// 0.3 mm test — after 4–5 iterations it keeps moving 0.4–0.8 mm RMS per iteration
    /// chasing single pairs that switch between neighbouring noisy samples — so more
    /// iterations buy nothing. `livereg bench --only "default,cell x0.75,cell x2"`: TRE 1.23
    /// mm on the default grid at warm p50 15 ms (10 iterations: 1.22 mm at 22 ms; 4: 1.30 mm).
    pub fn warm() -> Self {
        Self {
            penalty_steps: 1,
            max_icp_iterations: 6,
            newton_iterations: 1,
            tolerance: 3e-4,
            visibility_interval: 16,
            factor_reuse: 8,
            robust_pruning: true,
            ..Self::default()
        }
    }

    /// Checks ranges; the message names the setting.
    pub fn validate(&self) -> Result<(), NonRigidError> {
        let bad = |m: String| Err(NonRigidError::InvalidSetting(m));
        if !(0.0..=1.0).contains(&self.alpha) {
            return bad(format!("alpha {} is outside [0, 1]", self.alpha));
        }
        if !(self.penalty_scale.is_finite() && self.penalty_scale > 0.0) {
            return bad(format!(
                "penalty_scale {} must be finite and > 0",
                self.penalty_scale
            ));
        }
        for (name, v) in [
            ("penalty_start", self.penalty_start),
            ("penalty_end", self.penalty_end),
            ("max_pair_distance", self.max_pair_distance),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && v > 0.0) {
                    return bad(format!("{name} {v} must be finite and > 0"));
                }
            }
        }
        if !(self.tolerance.is_finite() && self.tolerance >= 0.0) {
            return bad(format!(
                "tolerance {} must be finite and >= 0",
                self.tolerance
            ));
        }
        if !(self.outlier_sigma.is_finite() && self.outlier_sigma > 0.0) {
            return bad(format!(
                "outlier_sigma {} must be finite and > 0",
                self.outlier_sigma
            ));
        }
        if !(self.data_weight.is_finite() && self.data_weight > 0.0) {
            return bad(format!(
                "data_weight {} must be finite and > 0",
                self.data_weight
            ));
        }
        Ok(())
    }
}

/// A penalty step is not converged while any pulled point still moved by more than this many
/// times the RMS `tolerance` in the last ICP iteration: an RMS alone averages a local
/// deformation (a lifted lobe, a few percent of the surface moving by centimetres) away. With
/// a noisy cloud the largest motion settles at 1–2 mm (phantom, 1 mm noise), below the 5 mm
/// this gives with the default tolerance.
pub const LOCAL_MOTION_FACTOR: f64 = 10.0;

/// Errors of the non-rigid stage.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NonRigidError {
    /// The cloud is empty.
    #[error("the point cloud is empty")]
    EmptyCloud,
    /// A cloud point is not finite.
    #[error("cloud point {0} has a non-finite coordinate")]
    NonFinite(usize),
    /// No model point is visible or every pair was an outlier.
    #[error(
        "no model surface point pairs with the cloud (nothing visible, or all pairs rejected)"
    )]
    NoCorrespondence,
    /// The visibility test could not be built.
    #[error("visibility: {0}")]
    Visibility(String),
    /// A setting is out of range.
    #[error("non-rigid settings: {0}")]
    InvalidSetting(String),
}

/// Milliseconds spent in each part of a non-rigid registration.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct NonRigidTimings {
    /// Ray-cast visibility.
    pub visibility_ms: f64,
    /// Nearest neighbours, pruning and blending.
    pub pairing_ms: f64,
    /// Newton iterations (assembly, factorisation, solves, line search).
    pub newton_ms: f64,
}

/// What a non-rigid registration did.
#[derive(Debug, Clone, PartialEq)]
pub struct NonRigidReport {
    /// ICP iterations over all penalty steps.
    pub icp_iterations: usize,
    /// Newton iterations over all ICP iterations.
    pub newton_iterations: usize,
    /// Tangent factorisations.
    pub factorizations: usize,
    /// RMS distance (m) between the kept source points and their nearest cloud points at the
    /// last pairing (the one that made the last Newton iterations' springs).
    pub surface_rms: f64,
    /// Source points used in the last iteration.
    pub sources: usize,
    /// Whether every penalty step converged within its iteration budget.
    pub converged: bool,
    /// Whether the deadline stopped the iterations (the state is the last valid one).
    pub deadline_reached: bool,
    /// Failures the Newton solver reported (the state stays the last valid one).
    pub warnings: Vec<String>,
    /// Where the time went.
    pub timings: NonRigidTimings,
    /// The data term's springs at the final state (`None` when no spring was applied): the
    /// loads the registration applied, from which the session estimates the contact force
    /// ([`RestCompliance::fit`](super::RestCompliance::fit)).
    pub data_term: Option<PenaltySprings>,
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The non-rigid stage with the state worth keeping between frames: the Newton solver (its
/// fill-reducing ordering, symbolic analysis and, with factor reuse, its last factorisation
/// and the data-term springs it was made with).
pub struct NonRigidIcp {
    /// Settings used by [`NonRigidIcp::register`].
    pub settings: NonRigidSettings,
    newton: NewtonSolver,
    /// Candidate source vertices of the last visibility test, ICP iterations since, and the
    /// camera it was made for.
    visible: Option<(Vec<usize>, usize, Option<Camera>)>,
    /// The model surface's triangles around each vertex (cloud → surface pairing), with the
    /// vertex and triangle counts it was built for: the topology never changes between frames.
    incident: Option<(usize, usize, Vec<Vec<usize>>)>,
    /// Normals at a fixed scale of the model surface at rest (cloud → surface pairing with
    /// [`NormalScale::OrganSize`] or [`NormalScale::Radius`]), and the setting they were made
    /// for.
    normals: Option<(NormalScale, Arc<NormalsAtScale>)>,
}

/// Pairs no longer than this many cell edges are never pruned as outliers
/// ([`PairingRule::min_outlier_distance`]): 0.6 mm on 11.5 mm cells, the order of a trilinear
/// field's own error over a curved surface (`h²/8R`: 0.3 mm at R = 5 cm), well below any
/// camera's noise, so a noisy cloud's threshold (2–4 mm at 1–1.5 mm noise) never reaches it.
const MIN_OUTLIER_DISTANCE_CELLS: f64 = 0.05;

/// How near (m) a cloud point must lie to a part of the model surface the camera should not
/// see for it to pair there ([`PairingRule::hidden_match`]): three times the cloud's noise
/// (1σ along the normal, m; `None` or 0 for a noise-free cloud), at least
/// [`MIN_OUTLIER_DISTANCE_CELLS`] cell edges `h` (m), the trilinear field's own error.
/// Without it a cloud that shows more than the camera model predicts (a full-surface cloud,
/// or a camera placed by guess) pulls every such point onto the nearest visible triangle:
/// 1,500 noise-free points on the whole phantom surface at rest ended 21 mm RMS from it.
pub(crate) fn hidden_match_tolerance(cloud_noise: Option<f64>, h: f64) -> f64 {
    (3.0 * cloud_noise.unwrap_or(0.0)).max(MIN_OUTLIER_DISTANCE_CELLS * h)
}

/// The largest cloud noise (m, 1σ along the normal) at which the cloud → surface term of a
/// warm frame (median/MAD pruning, [`NonRigidSettings::robust_pruning`]) keeps long pairs in
/// coherent regions ([`PairingRule::keep_coherent`]); a noisier cloud, and a cold frame, are
/// pruned by the pair-length threshold alone (a cold frame from rest with 30 % outliers
/// moved the structures 2.9 → 4.6 mm with it). Measured
/// (docs/data-term.md#which-pairs-are-kept): on noise-free clouds of force-driven 50 mm
/// dents the kept pairs reach the dent (distance of the cloud to the registered surface at
/// the dent 4.5 → 1.0 mm, node error 1.41 → 1.07 mm);
/// on the bundled tool-indentation class (1.5 mm noise, 50–70 mm displacement-driven dents)
/// they made the registration drift (press-slide linear 1.08 → 5.9 mm).
pub(crate) const COHERENT_MAX_NOISE: f64 = 0.5e-3;

/// The cloud a registration pulls towards, prepared once per call: indexed, its rim points
/// flagged, and the pairing rule.
struct Target {
    /// The cloud (m, model frame), with its k-d tree.
    cloud: IndexedPoints,
    /// Which cloud points lie on the rim of the seen patch (`reject_rim`).
    rim: Option<Vec<bool>>,
    /// Blending and pruning of the pairs.
    rule: PairingRule,
}

impl Target {
    /// Checks `cloud` (m; not empty, finite) and prepares it with `settings` for a model of
    /// cell edge `h` (m).
    fn new(
        cloud: &[Point3<f64>],
        settings: &NonRigidSettings,
        h: f64,
    ) -> Result<Self, NonRigidError> {
        if cloud.is_empty() {
            return Err(NonRigidError::EmptyCloud);
        }
        if let Some(i) = crate::mesh::first_non_finite_point(cloud) {
            return Err(NonRigidError::NonFinite(i));
        }
        let cloud = IndexedPoints::new(cloud.to_vec()).ok_or(NonRigidError::EmptyCloud)?;
        // Only the model → cloud direction pairs with rim points; the cloud → surface term
        // never asks (the mask cost 13 % of a phantom warm frame).
        let rim = (settings.reject_rim && settings.data_term == DataTerm::SurfaceToCloud)
            .then(|| cloud.rim_mask(RIM_NEIGHBOURS, RIM_RATIO));
        let rule = PairingRule {
            alpha: settings.alpha,
            outlier_sigma: settings.outlier_sigma,
            robust: settings.robust_pruning,
            max_pair_distance: settings.max_pair_distance,
            min_outlier_distance: MIN_OUTLIER_DISTANCE_CELLS * h,
            hidden_match: Some(hidden_match_tolerance(settings.cloud_noise, h)),
            keep_coherent: settings.robust_pruning
                && settings
                    .cloud_noise
                    .is_none_or(|s| s.is_nan() || s <= COHERENT_MAX_NOISE),
        };
        Ok(Self { cloud, rim, rule })
    }
}

/// The automatic first stiffness of the penalty ramp, k₀, per E h (N/m per spring for a
/// Young's modulus E in Pa and a cell edge h in m).
pub const PENALTY_START_PER_EH: f64 = 0.02;

/// The automatic last stiffness of the penalty ramp, k₁, per E h, for a cloud of
/// [`REFERENCE_NOISE`] or less: the stiffness every warm frame's springs pull with.
pub const PENALTY_END_PER_EH: f64 = 2.0;

/// The cloud noise (m, 1σ along the surface normal) the automatic ramp's stiffnesses are
/// made for: the phantom's clouds, on which they were chosen. A noisier cloud's springs are
/// weakened by [`noise_weight`].
pub const REFERENCE_NOISE: f64 = 1e-3;

/// The smallest [`noise_weight`]: a cloud noisier than 2 mm is weighted as one of 2 mm.
/// Measured with the quick stability matrices (docs/data-term.md#the-data-terms-stiffness):
/// without the bound, the phantom at 4 mm noise went from 1.87 to 2.08 mm mean
/// TRE (weight 1/16: the large deformation was no longer followed); with it, 1.84 mm, while
/// tool-indentation at 3 mm noise kept most of its gain (1.33 → 1.18 mm, 1.12 unbounded).
pub const MIN_NOISE_WEIGHT: f64 = 0.25;

/// The factor on the automatic penalty ramp for a cloud whose noise is `sigma` (m, 1σ along
/// the normal; [`cloud_noise_sigma`](super::change_evidence::cloud_noise_sigma)):
/// `(REFERENCE_NOISE / σ)²`, within [[`MIN_NOISE_WEIGHT`], 1]; 1 when not measured. Each
/// spring is one point's evidence, and evidence weighs as the inverse of its variance: the
/// data term `Σ k (n·(x − q))²/2` is the log-likelihood of points of noise σ when
/// `k ∝ 1/σ²`, against the elastic energy as the prior
/// (docs/data-term.md#the-data-terms-stiffness). With a fixed k a noisy cloud's springs
/// pulled the surface onto its noise: tool-indentation (1.5 mm noise, weight 0.44)
/// press-slide neo-Hookean went from 0.54 to 0.32 mm mean node error. Never above 1: a
/// cleaner cloud than the reference keeps the reference stiffness (stiffer springs were not
/// measured to pay, and σ → 0 would make them unbounded).
pub fn noise_weight(sigma: Option<f64>) -> f64 {
    match sigma {
        Some(s) if s.is_finite() && s > REFERENCE_NOISE => {
            (REFERENCE_NOISE / s).powi(2).max(MIN_NOISE_WEIGHT)
        }
        _ => 1.0,
    }
}

/// The penalty stiffness schedule: `steps` values from `k0` to `k1` (N/m per spring),
/// exponentially spaced (thesis alg. 3).
#[derive(Debug, Clone, Copy, PartialEq)]
struct PenaltyRamp {
    k0: f64,
    k1: f64,
    steps: usize,
}

impl PenaltyRamp {
    /// The ramp of `settings` on `problem`: k₀ = 0.02 E h and k₁ = 2 E h unless set, times
    /// [`NonRigidSettings::penalty_scale`] and [`noise_weight`] of the cloud's noise (E the
    /// Young's modulus, Pa; h the cell size, m), both times
    /// [`NonRigidSettings::data_weight`].
    fn new(settings: &NonRigidSettings, problem: &StaticProblem) -> Self {
        Self::for_model(
            settings,
            problem.material.young_modulus(),
            problem.cell_size(),
        )
    }

    /// The ramp of `settings` on a model of Young's modulus `young` (Pa) and cell edge `h`
    /// (m).
    fn for_model(settings: &NonRigidSettings, young: f64, h: f64) -> Self {
        let w = settings.data_weight;
        let automatic = settings.penalty_scale * noise_weight(settings.cloud_noise) * young * h;
        Self {
            k0: w * settings
                .penalty_start
                .unwrap_or(PENALTY_START_PER_EH * automatic),
            k1: w * settings
                .penalty_end
                .unwrap_or(PENALTY_END_PER_EH * automatic),
            steps: settings.penalty_steps.max(1),
        }
    }

    /// Stiffness of step `step` (0-based), N/m: k₁ when there is one step.
    fn stiffness(&self, step: usize) -> f64 {
        if self.steps == 1 {
            self.k1
        } else {
            self.k0 * (self.k1 / self.k0).powf(step as f64 / (self.steps - 1) as f64)
        }
    }
}

/// How a penalty step ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StepEnd {
    /// The pulled points stopped moving ([`surface_settled`]), the body relaxed under them.
    Converged,
    /// The ICP iterations ran out first.
    IterationCap,
    /// The deadline stopped it (the state is the last valid one).
    Deadline,
}

impl NonRigidIcp {
    /// A registration stage with `settings`, solving with `newton` (its linear solver kind
    /// and line search; iteration counts come from `settings`).
    pub fn new(settings: NonRigidSettings, newton: NewtonSettings) -> Self {
        Self {
            settings,
            newton: NewtonSolver::new(newton).with_factor_reuse(settings.factor_reuse),
            visible: None,
            incident: None,
            normals: None,
        }
    }

    /// Uses `normals` (made by `settings.normal_scale` for the surface of the model this
    /// registers) instead of building its own on the first pairing, so that the stages of a
    /// session share one.
    pub fn with_normals(mut self, normals: Option<Arc<NormalsAtScale>>) -> Self {
        self.normals = normals.map(|n| (self.settings.normal_scale, n));
        self
    }

    /// Forgets the kept factorisation (call after a reset or a failed frame).
    pub fn invalidate(&mut self) {
        self.newton.invalidate_factorization();
        self.visible = None;
    }

    /// Registers `model` (its fixed regions stay held) to `cloud` (m, already rigidly aligned
    /// to the model's frame), starting from grid displacements `u` (m; warm start), updated in
    /// place and always a valid state. Source points are the surface vertices visible from
    /// `camera` on the current deformed surface (parry3d ray casts); without a camera every
    /// vertex is a candidate and the outlier rule removes those far from the cloud (the
    /// documented fallback). Stops at `deadline` (checked before each ICP iteration) with the
    /// state reached so far and `deadline_reached` set.
    ///
    /// The stages: the cloud's preparation, the penalty ramp (per step, ICP iterations of
    /// visibility, pairing, the
    /// convergence check, spring building and Newton), then the contact force of the last
    /// springs. The model is not modified: the data term's springs are passed to the solver.
    pub fn register(
        &mut self,
        model: &mut Model,
        cloud: &[Point3<f64>],
        camera: Option<&Camera>,
        u: &mut [f64],
        deadline: Option<Instant>,
    ) -> Result<NonRigidReport, NonRigidError> {
        let settings = self.settings;
        settings.validate()?;
        self.newton.set_factor_reuse(settings.factor_reuse);
        self.newton.set_background_lag(settings.background_lag);
        let t = Instant::now();
        let target = Target::new(cloud, &settings, model.problem.cell_size())?;
        let prepare_ms = ms(t);
        let ramp = PenaltyRamp::new(&settings, &model.problem);
        let factorizations_before = self.newton.factorizations();
        let mut report = NonRigidReport {
            icp_iterations: 0,
            newton_iterations: 0,
            factorizations: 0,
            surface_rms: 0.0,
            sources: 0,
            converged: true,
            deadline_reached: false,
            warnings: Vec::new(),
            timings: NonRigidTimings {
                pairing_ms: prepare_ms,
                ..NonRigidTimings::default()
            },
            data_term: None,
        };
        let mut pull = None;
        let result = self.penalty_ramp(
            model,
            &target,
            camera,
            u,
            deadline,
            ramp,
            &mut report,
            &mut pull,
        );
        report.data_term = pull;
        report.factorizations = self.newton.factorizations() - factorizations_before;
        result.map(|()| report)
    }

    /// The penalty ramp: one [`NonRigidIcp::penalty_step`] per stiffness of `ramp`, until the
    /// deadline. `pull` ends as the data term's springs of the last Newton iteration.
    #[allow(clippy::too_many_arguments)]
    fn penalty_ramp(
        &mut self,
        model: &mut Model,
        target: &Target,
        camera: Option<&Camera>,
        u: &mut [f64],
        deadline: Option<Instant>,
        ramp: PenaltyRamp,
        report: &mut NonRigidReport,
        pull: &mut Option<PenaltySprings>,
    ) -> Result<(), NonRigidError> {
        for step in 0..ramp.steps {
            let k = ramp.stiffness(step);
            let last = step + 1 == ramp.steps;
            match self.penalty_step(model, target, camera, u, deadline, k, last, report, pull)? {
                StepEnd::Converged => {}
                StepEnd::IterationCap => report.converged = false,
                StepEnd::Deadline => {
                    report.deadline_reached = true;
                    report.converged = false;
                    break;
                }
            }
        }
        Ok(())
    }

    /// One penalty step at stiffness `k` (N/m per spring; `last`: the ramp's last step, whose
    /// state is the frame's result): at most `max_icp_iterations` ICP
    /// iterations, each of visibility ([`NonRigidIcp::update_visibility`]), pairing
    /// ([`NonRigidIcp::pair_points`]), spring building ([`NonRigidIcp::data_springs`]) and
    /// `newton_iterations` Newton iterations ([`NonRigidIcp::newton_stage`]). Before each
    /// iteration but the first, the convergence check ([`surface_settled`]): the surface
    /// points the last iteration pulled stopped moving; a body still moving elsewhere, or, on
    /// the last step, one a step on a fresh tangent still moves
    /// ([`NonRigidIcp::fresh_tangent_moves_body`]; the ramp's earlier steps are stepping stones
    /// whose rest need not be proven), is then relaxed under the same springs
    /// ([`RELAX_NEWTON_ITERATIONS`]). It needs no pairing, so a
    /// converged step ends without one (the pairs it would make are not used). The deadline is
    /// checked next, before each iteration but the first of the call.
    #[allow(clippy::too_many_arguments)]
    fn penalty_step(
        &mut self,
        model: &mut Model,
        target: &Target,
        camera: Option<&Camera>,
        u: &mut [f64],
        deadline: Option<Instant>,
        k: f64,
        last: bool,
        report: &mut NonRigidReport,
        pull: &mut Option<PenaltySprings>,
    ) -> Result<StepEnd, NonRigidError> {
        let settings = self.settings;
        // Surface positions at the start of the previous ICP iteration, and the surface
        // points it pulled.
        let mut previous: Option<(Vec<Point3<f64>>, Vec<usize>)> = None;
        let mut solver_settled = false;
        let mut refactorised = false;
        for _ in 0..settings.max_icp_iterations {
            let x = model.surface_embedding.positions(u);
            // A solver that only made shortened steps has not moved the surface because it
            // could not, not because it is done.
            let converged = solver_settled
                && previous.as_ref().is_some_and(|(prev, sources)| {
                    surface_settled(sources, &x, prev, settings.tolerance)
                });
            if converged {
                // A kept factorisation taken at a state far from this one (the last frame's
                // deep press, when the tool lifts) makes full steps that barely move the
                // surface while the pairs are still far apart: not settled. Once per step,
                // the tangent is factorised afresh and the iterations go on.
                if refactorised || !gap_open(report.surface_rms, settings.cloud_noise) {
                    if let (Some(springs), Some((prev, _))) = (pull.as_ref(), previous.as_ref()) {
                        let t = Instant::now();
                        if !body_settled(&x, prev, settings.tolerance)
                            || (last
                                && !noise_above(settings.tolerance, settings.cloud_noise)
                                && self.fresh_tangent_moves_body(model, springs, u, report, &x))
                        {
                            self.newton_stage(model, springs, u, report, RELAX_NEWTON_ITERATIONS);
                        }
                        report.timings.newton_ms += ms(t);
                    }
                    return Ok(StepEnd::Converged);
                }
                refactorised = true;
                self.newton.invalidate_factorization();
            }
            if deadline.is_some_and(|d| Instant::now() >= d) && report.icp_iterations > 0 {
                return Ok(StepEnd::Deadline);
            }
            report.icp_iterations += 1;
            self.update_visibility(model, &x, camera, &mut report.timings)?;
            let t = Instant::now();
            let paired = self.pair_points(model, target, &x, camera, u, k)?;
            let (sources, rms) = paired.sources_and_rms();
            report.sources = sources.len();
            report.surface_rms = rms;
            report.timings.pairing_ms += ms(t);
            let t = Instant::now();
            let springs = self.data_springs(paired, &model.surface_embedding, k);
            solver_settled =
                self.newton_stage(model, &springs, u, report, settings.newton_iterations);
            *pull = Some(springs);
            report.timings.newton_ms += ms(t);
            previous = Some((x, sources));
        }
        Ok(StepEnd::IterationCap)
    }

    /// Visibility: the candidate source vertices of the deformed surface at `x` (m), from
    /// `camera` (ray casts) or every vertex without one, recomputed every
    /// `visibility_interval` ICP iterations (counted across calls) or when the camera
    /// changed; kept in `self.visible`.
    fn update_visibility(
        &mut self,
        model: &Model,
        x: &[Point3<f64>],
        camera: Option<&Camera>,
        timings: &mut NonRigidTimings,
    ) -> Result<(), NonRigidError> {
        let interval = self.settings.visibility_interval.max(1);
        if let Some((v, age, cam)) = &mut self.visible {
            if *age < interval && cam.as_ref() == camera && v.iter().all(|&i| i < x.len()) {
                *age += 1;
                return Ok(());
            }
        }
        let t = Instant::now();
        let candidates = match camera {
            Some(cam) => {
                let deformed = TriSurface::new(x.to_vec(), model.surface.triangles.clone());
                let vis = VisibleSurface::new(&deformed)
                    .map_err(|e| NonRigidError::Visibility(e.to_string()))?;
                let mask = vis.visible_vertices(cam);
                (0..x.len()).filter(|&i| mask[i]).collect()
            }
            None => (0..x.len()).collect(),
        };
        self.visible = Some((candidates, 1, camera.copied()));
        timings.visibility_ms += ms(t);
        Ok(())
    }

    /// Pairing: the deformed surface at `x` (m; grid displacement `u`) with the target
    /// cloud, by the data term — candidate vertices to their nearest cloud points (thesis
    /// alg. 3, eq. 5.4), or every cloud point to its closest surface point, whose springs of
    /// stiffness `k` (N/m) are made here since they need the anchors' embedding.
    fn pair_points(
        &mut self,
        model: &Model,
        target: &Target,
        x: &[Point3<f64>],
        camera: Option<&Camera>,
        u: &[f64],
        k: f64,
    ) -> Result<Paired, NonRigidError> {
        let settings = self.settings;
        let candidates = &self.visible.as_ref().expect("visibility runs first").0;
        let triangles = &model.surface.triangles;
        match settings.data_term {
            DataTerm::SurfaceToCloud => {
                let normals = settings
                    .point_to_plane
                    .then(|| TriSurface::vertex_normals_at(x, triangles));
                let pairs = pair(
                    x,
                    normals.as_deref(),
                    candidates,
                    &target.cloud,
                    target.rim.as_deref(),
                    &target.rule,
                )
                .ok_or(NonRigidError::NoCorrespondence)?;
                Ok(Paired::Vertices(pairs))
            }
            DataTerm::CloudToSurface => {
                if self
                    .incident
                    .as_ref()
                    .is_none_or(|(n, t, _)| (*n, *t) != (x.len(), triangles.len()))
                {
                    self.incident = Some((
                        x.len(),
                        triangles.len(),
                        incident_triangles(x.len(), triangles),
                    ));
                }
                let rest = &model.surface.vertices;
                let scale = settings.normal_scale;
                if scale != NormalScale::Vertex
                    && self
                        .normals
                        .as_ref()
                        .is_none_or(|(s, n)| *s != scale || !n.fits(triangles.len()))
                {
                    self.normals = scale.build(rest, triangles).map(|n| (scale, Arc::new(n)));
                }
                let incident = &self.incident.as_ref().expect("set above").2;
                let vertex_normals = TriSurface::vertex_normals_at(x, triangles);
                let smoothed = match &self.normals {
                    Some((_, n)) if scale != NormalScale::Vertex => {
                        Some(n.smooth(&vertex_normals, triangles))
                    }
                    _ => None,
                };
                let normals = smoothed.as_deref().unwrap_or(&vertex_normals);
                let allowed = camera.map(|_| {
                    let mut m = vec![false; x.len()];
                    for &i in candidates {
                        m[i] = true;
                    }
                    m
                });
                let pairs = pair_cloud_to_surface(
                    x,
                    triangles,
                    incident,
                    normals,
                    allowed.as_deref(),
                    &target.cloud,
                    &target.rule,
                )
                .ok_or(NonRigidError::NoCorrespondence)?;
                let pulled = Pulled::from_anchors(
                    pairs,
                    x,
                    triangles,
                    &target.cloud,
                    &model.problem.grid,
                    &model.surface_embedding,
                    u,
                    k,
                    settings.point_to_plane,
                )
                .ok_or(NonRigidError::NoCorrespondence)?;
                Ok(Paired::Anchors(pulled))
            }
        }
    }

    /// Spring building: the data term's springs of stiffness `k` (N/m) towards the targets,
    /// as displacements from rest (`emb`: the surface vertices' embedding).
    ///
    /// With the vertex data term, a step with a kept factorisation pulls only the vertices
    /// that had a spring when it was made ([`NewtonSolver::factorization_springs`]): at a
    /// point the body barely holds (a badly cut cell) a spring the factorisation lacks makes
    /// its step overshoot by orders of magnitude (measured: a node moved by 2 m), and the line
    /// search then cuts the whole step to 1/16. Newly paired vertices join at the next
    /// factorisation. Not with the cloud → surface term: its anchors move with each frame's
    /// noise, the restriction dropped a changing part of them, and a still scene drifted
    /// (tests/registration/session_stability.rs: targets 1.40 mm from frame 25 to 49 with it,
    /// 0.31 mm without; phantom TRE 0.69 → 0.67 mm).
    fn data_springs(&self, paired: Paired, emb: &Embedding, k: f64) -> PenaltySprings {
        match paired {
            Paired::Vertices(pairs) => {
                let pairs = match self.newton.factorization_springs() {
                    Some(factored) => pairs.restricted_to(&pulled_vertices(factored, emb)),
                    None => pairs,
                };
                vertex_springs(pairs, emb, k)
            }
            Paired::Anchors(pulled) => pulled.springs,
        }
    }

    /// Whether one Newton step on a freshly factorised tangent, under the penalty step's last
    /// `springs`, moves the surface from `x` (m) by more than the step's tolerance
    /// ([`body_settled`]). A kept factorisation taken at a stiffer state (the deep press,
    /// when the tool lifts) makes steps too short to show that the body is still far from
    /// equilibrium: small motion is then no proof of rest. The step is kept (a descent step
    /// of the same energy). Asked only of clouds whose noise is within the tolerance
    /// ([`noise_above`]): on a noisier cloud a fresh tangent each frame lets the structures
    /// follow each frame's noise, which a kept factorisation's partial steps average out.
    fn fresh_tangent_moves_body(
        &mut self,
        model: &mut Model,
        springs: &PenaltySprings,
        u: &mut [f64],
        report: &mut NonRigidReport,
        x: &[Point3<f64>],
    ) -> bool {
        self.newton.invalidate_factorization();
        self.newton_stage(model, springs, u, report, 1);
        let after = model.surface_embedding.positions(u);
        !body_settled(&after, x, self.settings.tolerance)
    }

    /// Newton: at most `iterations` iterations on the model with the data term's `springs`
    /// added to its own (`newton_iterations` per ICP iteration, [`RELAX_NEWTON_ITERATIONS`] to
    /// relax the body); a failure (inversion, divergence) is reported as a warning and drops
    /// the kept factorisation (a stale one is the first suspect). Returns whether the solver
    /// settled: no failure and no step shortened below ½ by the line search.
    fn newton_stage(
        &mut self,
        model: &mut Model,
        springs: &PenaltySprings,
        u: &mut [f64],
        report: &mut NonRigidReport,
        iterations: usize,
    ) -> bool {
        let r = self.newton.improve(
            &mut model.problem,
            std::slice::from_ref(springs),
            u,
            iterations,
        );
        report.newton_iterations += r.iterations;
        let settled = r.failure.is_none() && r.steps.iter().all(|&a| a >= 0.5);
        if let Some((outcome, msg)) = r.failure {
            report.warnings.push(format!("{}: {msg}", outcome.name()));
            self.newton.invalidate_factorization();
        }
        settled
    }
}

/// RMS distance (m) of a penalty step's pairs, beyond the cloud's noise, above which a surface
/// that stopped moving has not settled ([`gap_open`]). Chosen on the force-driven tuning set
/// (noise-free clouds; `livereg bench --force-truths --set tuning [--cell-size 8|5.75]`): mean
/// node error 1.113 / 1.047 / 1.032 → 1.102 / 1.026 / 0.959 mm at 11.5 / 8 / 5.75 mm cells, only
/// press-release neo-Hookean cases changing (random liver 1 at 5.75 mm 2.96 → 2.28 mm: its
/// release frames had stopped 3–5 mm from the cloud after one ICP iteration).
pub(crate) const UNSETTLED_GAP: f64 = 1e-3;

/// Newton iterations that relax the body under a penalty step's last springs when its pulled
/// points have stopped moving but the rest of its surface has not ([`body_settled`]). The data
/// term's springs put the seen patch on the cloud within an iteration or two, while the part of
/// the body only the elastic energy moves gets there a few modified-Newton steps at a time: on
/// a release after a deep press the step ended with the far side still carrying the press, more
/// so the finer the cells (the phantom liver's press-release neo-Hookean on 5.75 mm cells:
/// release frames 3.5–5.2 mm off, 0.6–1.1 mm on the derived 11.5 mm cells;
/// `tests/registration/release_after_press.rs`). Relaxing under the same springs, not
/// pairing again, leaves a noisy cloud's jitter alone: the pairs have settled, the solve has
/// not. A body that did not move is confirmed at rest by one Newton step on a fresh tangent
/// first ([`NonRigidIcp::fresh_tangent_moves_body`]): the kept factorisation of a deep press
/// makes steps too short to show the released body's imbalance (the indentation liver's
/// press-release neo-Hookean on the derived cells: release frames 22–23 3.5–3.9 mm off against
/// 5.1–6.9 mm for no registration, 0.46–0.68 mm with the check).
pub const RELAX_NEWTON_ITERATIONS: usize = 8;

/// Whether the cloud's measured `noise` (m, 1σ; none: 0) exceeds `tolerance` (m): the
/// surface motion a penalty step calls settled is then within what each frame's noise moves
/// it by. On the noisy still frames of `session_stability` (1 mm per axis) a fresh tangent
/// on every frame made one target's error grow by 0.22–0.30 mm over 25 still frames, where
/// the kept factorisation's grows by under 0.1 mm.
fn noise_above(tolerance: f64, noise: Option<f64>) -> bool {
    noise.is_some_and(|s| s.is_finite() && s > tolerance)
}

/// Whether pairs of RMS distance `rms` (m) leave more than [`UNSETTLED_GAP`] unexplained
/// beyond the cloud's `noise` (m, 1σ; none: 0): `√(rms² − σ²) > UNSETTLED_GAP`.
fn gap_open(rms: f64, noise: Option<f64>) -> bool {
    let sigma = noise.filter(|s| s.is_finite()).unwrap_or(0.0);
    (rms * rms - sigma * sigma).max(0.0).sqrt() > UNSETTLED_GAP
}

/// Convergence check of a penalty step: the pulled surface points `sources` (indices into
/// `x`, m) moved since `previous` by at most `tolerance` (m, root mean square) and none by
/// more than [`LOCAL_MOTION_FACTOR`] × `tolerance`: the fit stopped changing.
fn surface_settled(
    sources: &[usize],
    x: &[Point3<f64>],
    previous: &[Point3<f64>],
    tolerance: f64,
) -> bool {
    points_settled(sources.iter().copied(), x, previous, tolerance)
}

/// Whether the whole surface `x` (m) moved since `previous` by at most `tolerance` (m, RMS)
/// and no vertex by more than [`LOCAL_MOTION_FACTOR`] × `tolerance`: the body, not only its
/// pulled points, stopped moving ([`RELAX_NEWTON_ITERATIONS`]).
fn body_settled(x: &[Point3<f64>], previous: &[Point3<f64>], tolerance: f64) -> bool {
    points_settled(0..x.len(), x, previous, tolerance)
}

/// Whether the points `ids` of `x` (m) moved since `previous` by at most `tolerance` (m, root
/// mean square) and none by more than [`LOCAL_MOTION_FACTOR`] × `tolerance`.
fn points_settled(
    ids: impl ExactSizeIterator<Item = usize>,
    x: &[Point3<f64>],
    previous: &[Point3<f64>],
    tolerance: f64,
) -> bool {
    let n = ids.len().max(1) as f64;
    let (sum, max) = ids.fold((0.0, 0.0f64), |(s, m), i| {
        let d2 = (x[i] - previous[i]).norm_squared();
        (s + d2, m.max(d2))
    });
    (sum / n).sqrt() <= tolerance && max.sqrt() <= LOCAL_MOTION_FACTOR * tolerance
}

/// Which surface vertices (`emb`: their embedding) carry a spring in `springs`: those whose
/// rest position is, bit for bit, a spring's (vertex springs are made at the vertices' own
/// embedded points, [`vertex_springs`]).
fn pulled_vertices(springs: &[PenaltySprings], emb: &Embedding) -> Vec<bool> {
    let key = |p: &Point3<f64>| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
    let at: HashSet<[u64; 3]> = springs
        .iter()
        .flat_map(|s| s.embedding.rest.iter().map(key))
        .collect();
    emb.rest.iter().map(|p| at.contains(&key(p))).collect()
}

/// Registers `model` to `cloud` from `u` (updated in place) with a fresh [`NonRigidIcp`]: the
/// one-shot form of [`NonRigidIcp::register`] (no deadline, Newton settings from the scene).
pub fn register_non_rigid(
    model: &mut Model,
    cloud: &[Point3<f64>],
    camera: Option<&Camera>,
    u: &mut [f64],
    settings: &NonRigidSettings,
) -> Result<NonRigidReport, NonRigidError> {
    NonRigidIcp::new(*settings, model.newton).register(model, cloud, camera, u, None)
}

/// The pairs of one ICP iteration, by data term: the thesis's vertex pairs (turned into springs
/// after the factorisation's spring set has restricted them, [`vertex_springs`]) or the cloud →
/// surface anchors' springs.
enum Paired {
    Vertices(Correspondences),
    Anchors(Pulled),
}

impl Paired {
    /// The surface vertices whose motion decides convergence, and the pairs' RMS (m).
    fn sources_and_rms(&self) -> (Vec<usize>, f64) {
        match self {
            Paired::Vertices(p) => (p.sources.clone(), p.rms),
            Paired::Anchors(p) => (p.sources.clone(), p.rms),
        }
    }
}

/// Springs of stiffness `k` (N/m) at the paired surface vertices (`emb`: the surface vertices'
/// embedding), towards their targets.
fn vertex_springs(pairs: Correspondences, emb: &Embedding, k: f64) -> PenaltySprings {
    PenaltySprings {
        embedding: emb.select(&pairs.sources),
        target: pairs
            .sources
            .iter()
            .zip(&pairs.targets)
            .map(|(&i, p)| p - emb.rest[i])
            .collect(),
        stiffness: vec![k; pairs.sources.len()],
        follows_load: false,
        normals: pairs.normals,
    }
}

/// The cloud → surface term's springs of one ICP iteration and what they pull: the anchors'
/// dominant surface vertices (their motion decides convergence) and the pairs' RMS (m).
struct Pulled {
    sources: Vec<usize>,
    springs: PenaltySprings,
    rms: f64,
}

impl Pulled {
    /// Springs of stiffness `k` (N/m) at the anchors of `pairs` (surface points at `x`, of
    /// `triangles`; their rest positions from `emb`, the surface vertices' embedding, embedded
    /// in `grid`): each moves the anchor's grid point by its normal offset (point-to-plane),
    /// or by the whole anchor → cloud point vector. `None` when fewer than 3 anchors embed.
    #[allow(clippy::too_many_arguments)]
    fn from_anchors(
        pairs: AnchoredPairs,
        x: &[Point3<f64>],
        triangles: &[[usize; 3]],
        cloud: &IndexedPoints,
        grid: &crate::grid::WeightedCellGrid,
        emb: &Embedding,
        u: &[f64],
        k: f64,
        point_to_plane: bool,
    ) -> Option<Self> {
        let rest: Vec<Point3<f64>> = pairs
            .anchors
            .iter()
            .map(|a| a.position(&emb.rest, triangles))
            .collect();
        let (embedding, kept) = Embedding::new_where_possible(grid, &rest);
        if kept.len() < 3 {
            return None;
        }
        let now = embedding.positions(u);
        let target = kept
            .iter()
            .zip(&now)
            .zip(&embedding.rest)
            .map(|((&s, p), r)| {
                let motion = if point_to_plane {
                    pairs.normals[s] * pairs.offsets[s]
                } else {
                    cloud.points[pairs.cloud_index[s]] - pairs.anchors[s].position(x, triangles)
                };
                p + motion - r
            })
            .collect();
        let springs = PenaltySprings {
            embedding,
            target,
            stiffness: vec![k; kept.len()],
            follows_load: false,
            normals: point_to_plane.then(|| kept.iter().map(|&s| pairs.normals[s]).collect()),
        };
        Some(Self {
            sources: kept.iter().map(|&s| pairs.dominant[s]).collect(),
            springs,
            rms: pairs.rms,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// E h of a 4.5 kPa liver on 11.5 mm cells, N/m.
    const EH: f64 = 4500.0 * 0.0115;

    fn ramp(settings: NonRigidSettings) -> PenaltyRamp {
        PenaltyRamp::for_model(&settings, 4500.0, 0.0115)
    }

    /// The gap beyond the noise is the root of the difference of squares: 1.5 mm pairs on a
    /// 1 mm cloud leave √1.25 = 1.118 mm (open), 1.2 mm pairs 0.663 mm (closed); a cloud of
    /// unknown noise counts the whole RMS.
    #[test]
    fn the_gap_beyond_the_noise_decides_whether_a_still_surface_has_settled() {
        assert!(gap_open(1.5e-3, Some(1e-3)));
        assert!(!gap_open(1.2e-3, Some(1e-3)));
        assert!(gap_open(1.1e-3, None));
        assert!(!gap_open(0.9e-3, None));
        assert!(!gap_open(0.5e-3, Some(2e-3)));
        assert!(gap_open(1.1e-3, Some(f64::NAN)));
    }

    #[test]
    fn a_noisy_clouds_springs_weigh_as_the_inverse_of_its_noise_variance() {
        let clean = ramp(NonRigidSettings::default());
        assert!((clean.k0 - 0.02 * EH).abs() < 1e-12 && (clean.k1 - 2.0 * EH).abs() < 1e-12);
        let at = |sigma: f64| {
            ramp(NonRigidSettings {
                cloud_noise: Some(sigma),
                ..NonRigidSettings::default()
            })
        };
        // 1.5 mm: (1 / 1.5)² of the reference, at both ends of the ramp.
        let r = at(1.5e-3);
        assert!((r.k1 / clean.k1 - 1.0 / 2.25).abs() < 1e-12);
        assert!((r.k0 / clean.k0 - 1.0 / 2.25).abs() < 1e-12);
        // At or below the reference noise, the reference; above 2 mm, the bound.
        assert_eq!(at(0.5e-3), clean);
        assert_eq!(at(1e-3), clean);
        assert!((at(4e-3).k1 / clean.k1 - MIN_NOISE_WEIGHT).abs() < 1e-12);
        assert_eq!(at(f64::NAN), clean);
        // The still window's weight multiplies it.
        let both = ramp(NonRigidSettings {
            cloud_noise: Some(1.5e-3),
            data_weight: 0.5,
            ..NonRigidSettings::default()
        });
        assert!((both.k1 - 0.5 * r.k1).abs() < 1e-12);
        // So does the scale, at both ends, keeping the noise weight.
        let scaled = ramp(NonRigidSettings {
            cloud_noise: Some(1.5e-3),
            penalty_scale: 4.0,
            ..NonRigidSettings::default()
        });
        assert!((scaled.k1 - 4.0 * r.k1).abs() < 1e-12);
        assert!((scaled.k0 - 4.0 * r.k0).abs() < 1e-12);
    }

    #[test]
    fn stiffnesses_the_scene_gives_are_not_weighted_by_the_noise() {
        let given = NonRigidSettings {
            penalty_start: Some(3.0),
            penalty_end: Some(300.0),
            cloud_noise: Some(1.5e-3),
            ..NonRigidSettings::default()
        };
        let r = ramp(given);
        assert_eq!((r.k0, r.k1), (3.0, 300.0));
        // Nor by the automatic ramp's scale.
        let r = ramp(NonRigidSettings {
            penalty_scale: 4.0,
            ..given
        });
        assert_eq!((r.k0, r.k1), (3.0, 300.0));
    }
}
