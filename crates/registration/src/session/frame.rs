//! One intra-operative frame in, one registration result out.

use nalgebra::Point3;

use crate::geometry::Camera;
use crate::registration::RigidTransform;

/// An intra-operative point cloud, in the scene's units and the camera's (cloud's) frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Name of the input (file name, sequence number), carried into the result.
    pub source: String,
    /// The points, scene units.
    pub points: Vec<Point3<f64>>,
    /// Pose of the camera that saw the points, in the cloud's frame and scene units, when
    /// known; otherwise the scene's camera (model frame) is used, or none.
    pub camera: Option<Camera>,
}

/// Why a frame was rejected. The session is unchanged by a rejected frame.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FrameError {
    /// The frame could not be read or decoded (the message names the file or field).
    #[error("{0}")]
    Input(String),
    /// No points.
    #[error("the frame holds no points")]
    Empty,
    /// A point with a NaN or infinite coordinate.
    #[error("point {index} has a non-finite coordinate ({x}, {y}, {z})")]
    NonFinite {
        /// Index in the frame.
        index: usize,
        /// Its coordinates as received.
        x: f64,
        /// See `x`.
        y: f64,
        /// See `x`.
        z: f64,
    },
    /// The rigid stage failed.
    #[error("rigid registration: {0}")]
    Rigid(String),
    /// The cloud does not fit the model even roughly before registration: its RMS distance
    /// (after rigid ICP, or at the identity with `rigid = "none"`) is beyond what any
    /// deformation of this liver explains ([`crate::session::SessionSettings::max_unregistered_rms`]).
    #[error(
        "the cloud does not match the model: RMS {rms_mm:.1} mm before registration exceeds \
         {limit_mm:.1} mm"
    )]
    NoMatch {
        /// RMS distance after rigid ICP, mm.
        rms_mm: f64,
        /// The limit, mm.
        limit_mm: f64,
    },
    /// The held pose no longer fits the cloud and rigid ICP found no other usable pose (one
    /// with an RMS under the no-match limit that either converged or fits the cloud as well
    /// as the last good frame fitted the held pose): the frame is rejected rather than
    /// registered at a pose that may be wrong.
    #[error(
        "the cloud no longer fits the held pose (RMS {held_rms_mm:.1} mm) and no pose was \
         re-acquired: rigid ICP found no fit under {limit_mm:.1} mm that converged or fits as \
         well as the last frame, from the held pose or from the cloud's centroid shift"
    )]
    PoseLost {
        /// RMS distance of the cloud to the model at the held pose, mm.
        held_rms_mm: f64,
        /// The no-match limit, mm.
        limit_mm: f64,
    },
    /// After registration the cloud still does not lie on the deformed model: whatever the
    /// deformation, this cloud is not this liver's surface (or the registration could not
    /// follow it); the last good state is kept.
    #[error(
        "the cloud does not lie on the registered model: RMS {rms_mm:.1} mm after registration \
         exceeds {limit_mm:.1} mm"
    )]
    NoFit {
        /// RMS distance (to the surface's closest point, after mean + 2σ) of the cloud to the
        /// registered surface, mm.
        rms_mm: f64,
        /// The limit, mm.
        limit_mm: f64,
    },
    /// A pose re-acquired by rigid ICP fits only with a jump of the deformation: the
    /// registration moved the surface by more than
    /// [`crate::session::SessionSettings::pose_reacquire_rms`] (RMS) from the last good
    /// frame. The organ seen again after a camera move has not changed shape that much
    /// between two frames, so the pose is taken to be a wrong minimum of rigid ICP (on a
    /// partial view one fits nearly as well) and the frame is refused; the last good state
    /// is kept.
    #[error(
        "the re-acquired pose fits only with the surface moved {change_mm:.1} mm (RMS) from the last good frame, more than {limit_mm:.1} mm: the pose is likely wrong"
    )]
    ImplausibleReacquisition {
        /// RMS change of the surface vertices from the last good frame, mm.
        change_mm: f64,
        /// The limit, mm.
        limit_mm: f64,
    },
    /// The non-rigid stage failed.
    #[error("non-rigid registration: {0}")]
    NonRigid(String),
    /// The solver produced a non-finite state (never returned; the last good one is kept).
    #[error("the solver produced a non-finite displacement")]
    NonFiniteState,
}

impl FrameError {
    /// Short cause for diagnostics and metrics (`input`, `empty`, `non-finite`, `rigid`, `no-match`,
    /// `non-rigid`, `non-finite-state`).
    pub fn cause(&self) -> &'static str {
        match self {
            FrameError::Input(_) => "input",
            FrameError::Empty => "empty",
            FrameError::NonFinite { .. } => "non-finite",
            FrameError::Rigid(_) => "rigid",
            FrameError::NoMatch { .. }
            | FrameError::PoseLost { .. }
            | FrameError::NoFit { .. }
            | FrameError::ImplausibleReacquisition { .. } => "no-match",
            FrameError::NonRigid(_) => "non-rigid",
            FrameError::NonFiniteState => "non-finite-state",
        }
    }
}

/// Milliseconds per stage of a frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    /// Input checks and thinning.
    pub prepare_ms: f64,
    /// Rigid ICP (including the tracking target's rebuild).
    pub rigid_ms: f64,
    /// Ray-cast visibility inside the non-rigid stage.
    pub visibility_ms: f64,
    /// Pairing inside the non-rigid stage.
    pub pairing_ms: f64,
    /// Newton iterations inside the non-rigid stage.
    pub newton_ms: f64,
    /// The tests of change before the non-rigid stage: the cloud's noise and neighbour lists,
    /// whether the rest shape or the last registered one explains it (rest test, still frames).
    pub change_ms: f64,
    /// The contact refit (`registration.contact_refit`).
    pub refit_ms: f64,
    /// The gate on the registered fit (the cloud's distances to the registered surface).
    pub gate_ms: f64,
    /// The contact force estimate.
    pub force_ms: f64,
    /// Deformed surface and structures.
    pub output_ms: f64,
}

impl StageTimes {
    /// Each stage's name (the key of `results.jsonl`'s `timings_ms`) and time, ms, in the
    /// order a frame runs them.
    pub fn named(&self) -> [(&'static str, f64); 10] {
        [
            ("prepare", self.prepare_ms),
            ("rigid", self.rigid_ms),
            ("change", self.change_ms),
            ("visibility", self.visibility_ms),
            ("pairing", self.pairing_ms),
            ("newton", self.newton_ms),
            ("refit", self.refit_ms),
            ("gate", self.gate_ms),
            ("force", self.force_ms),
            ("output", self.output_ms),
        ]
    }
}

/// The registration of one frame. Positions are in the scene's units and the cloud's frame
/// (what an AR display overlays on its video).
#[derive(Debug, Clone, PartialEq)]
pub struct FrameResult {
    /// Index of the frame in the session (counting rejected frames too).
    pub frame: usize,
    /// The frame's `source`.
    pub source: String,
    /// Wall time of the frame, ms.
    pub wall_ms: f64,
    /// Whether both stages converged within their iteration caps and the time budget.
    pub converged: bool,
    /// Model → cloud rigid transform (translation in metres).
    pub model_to_cloud: RigidTransform,
    /// Rigid ICP iterations.
    pub rigid_iterations: usize,
    /// Non-rigid ICP iterations.
    pub icp_iterations: usize,
    /// Newton iterations.
    pub newton_iterations: usize,
    /// Tangent factorisations.
    pub factorizations: usize,
    /// RMS distance between the model's paired surface points and the cloud, scene units.
    pub surface_rms: f64,
    /// Points received, and used after thinning.
    pub cloud_points: (usize, usize),
    /// Model surface points paired in the last ICP iteration.
    pub sources: usize,
    /// Whether this frame started from the previous frame's state.
    pub warm: bool,
    /// What the frame's registration says about itself ([`FrameFlag`](super::FrameFlag)),
    /// in the order they arose.
    pub flags: Vec<super::FrameFlag>,
    /// Solver warnings with their cause.
    pub warnings: Vec<String>,
    /// Why the frame failed; then the positions below are the last good state's.
    pub error: Option<FrameError>,
    /// Deformed surface vertices, scene units, cloud frame.
    pub surface: Vec<Point3<f64>>,
    /// Every structure of the scene: name and deformed points, scene units, cloud frame.
    pub structures: Vec<(String, Vec<Point3<f64>>)>,
    /// Where the time went.
    pub times: StageTimes,
    /// The surface loads the registration needed (resultant in N, centre in scene units,
    /// both in the cloud frame); `None` for rigid-only registration or before any frame
    /// succeeded. A failed frame carries the last good state's.
    pub contact_force: Option<crate::registration::ContactForce>,
    /// How uncertain the pose is, scene units: the 1σ misplacement of the model's surface
    /// (root mean square over its vertices) that the noise of the fit that found the pose
    /// implies (`registration::PoseCovariance`), carried while the pose is held; `None` when
    /// the pose was given (`rigid = "none"`) or not determined. A lower bound: deformation
    /// and a wrong pose basin are not in it.
    pub pose_uncertainty: Option<f64>,
    /// The registration's estimate of the mean error of the structures in this frame, and its
    /// parts, scene units ([`expected_error`](crate::registration::expected_error)); a failed frame carries
    /// the last good state's. `None` before any frame succeeded.
    pub expected_error: Option<crate::registration::ErrorEstimate>,
}
