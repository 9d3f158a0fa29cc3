//! What a session does per frame, and its limits.

use serde::{Deserialize, Serialize};

use crate::registration::change_evidence::ChangeTest;
use crate::registration::{NonRigidSettings, PoseSearch, RigidIcp};

/// The rigid stage of registration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Deserialize, Serialize)]
pub enum RigidMode {
    /// `"icp"` (default): rigid ICP before the non-rigid stage.
    #[default]
    #[serde(rename = "icp")]
    Icp,
    /// `"none"`: no rigid stage (identity); the clouds are already in the model's frame.
    #[serde(rename = "none")]
    Identity,
}

/// How the model → cloud pose evolves across the frames of a session (with the non-rigid stage
/// on; rigid-only registration always tracks).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Deserialize, Serialize)]
pub enum PoseUpdate {
    /// `"hold"` (default): the pose found on the first frame (or after a reset) is kept, and
    /// the deformation explains all later change; the pose is searched again only when the
    /// cloud no longer fits the deformed model at it (the camera or the patient moved). Right
    /// for clouds in a fixed frame (a static or tracked camera): a rigid fit to a partly seen,
    /// deforming organ otherwise turns the pose to absorb deformation, and the error drifts.
    #[default]
    #[serde(rename = "hold")]
    Hold,
    /// `"track"`: rigid ICP against the current deformed model on every frame, from the last
    /// pose (clouds in a moving camera's frame with no tracker).
    #[serde(rename = "track")]
    Track,
    /// `"follow"`: held as with `"hold"`, but a warm frame whose whole view moved (the
    /// best-fitting half of the cloud lies at least twice as close to the last registered
    /// shape after rigid ICP from the held pose, and closer by more than 0.3 mm) takes the
    /// fitted pose: clouds from a camera that moves slowly and has no tracker, which the
    /// elastic model would otherwise absorb frame after frame
    /// (docs/pose.md#hold-track-or-follow).
    #[serde(rename = "follow")]
    Follow,
}

/// Settings of a [`Session`](super::Session). Lengths in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionSettings {
    /// Rigid stage: ICP (tracking from the last frame's pose) or none (the clouds are in the
    /// model's frame).
    pub rigid_mode: RigidMode,
    /// How the pose evolves across frames when the non-rigid stage runs.
    pub pose_update: PoseUpdate,
    /// With [`PoseUpdate::Hold`], the pose is searched again (flag `pose_reacquired`) when
    /// the cloud's RMS distance to the deformed surface's vertices at the held pose exceeds
    /// this, metres (default 8 mm). In normal operation it is 3–5 mm on the phantom's
    /// sequences (1 mm noise, and the deformation since the last frame, which the non-rigid
    /// stage is there to explain); smaller camera moves are absorbed as deformation.
    pub pose_reacquire_rms: f64,
    /// A fitted pose whose uncertainty ([`PoseCovariance`](crate::registration::PoseCovariance):
    /// the 1σ misplacement of the model's surface, root mean square over its vertices, from
    /// the fit's own noise) exceeds this, metres, is flagged `pose_uncertain` on every frame
    /// that holds it (`registration.max_pose_uncertainty`, default 2 mm;
    /// docs/pose.md#pose-uncertainty).
    pub max_pose_uncertainty: f64,
    /// A frame whose expected error ([`expected_error`](crate::registration::expected_error)) exceeds this,
    /// metres, is flagged `expected_error_high`: a display should dim its overlay
    /// (`registration.max_expected_error`, default 5 mm: a tumour margin's order).
    pub max_expected_error: f64,
    /// Rigid ICP settings.
    pub rigid: RigidIcp,
    /// The multi-start search of the rigid pose on a frame whose pose is not known from the
    /// last one (the first frame, after a reset or failure, and a re-acquisition): `None`
    /// fits by plain ICP from the start alone (`registration.pose_search = false`). Default
    /// [`PoseSearch::default`] (docs/pose.md#global-pose-search).
    pub pose_search: Option<PoseSearch>,
    /// A frame whose cloud (after the rigid stage) the rest shape explains within the cloud's
    /// own noise is kept at rest (flag `at_rest`), without the non-rigid stage
    /// ([`ChangeTest`](crate::registration::change_evidence::ChangeTest)); `None`: every frame
    /// is registered (`registration.rest_test = false`).
    pub rest_test: Option<ChangeTest>,
    /// Most still frames registered together (`registration.still_frames`; 1: each frame
    /// alone). Needs [`SessionSettings::rest_test`]'s noise test.
    pub still_frames: usize,
    /// Rigid ICP from the last frame's pose (rigid-only sessions, `pose = "track"`) stops
    /// when the mean squared inlier distance changes by at most this fraction (default 1e-4,
    /// an RMS change of 0.005 %), if looser than `rigid.relative_tolerance` (1e-6, kept for
    /// the first frame and pose re-acquisition). On noisy clouds the mean + 2σ inlier set
    /// keeps switching and 1e-6 is never met: every tracked frame would run all 50 iterations
    /// (`livereg bench`, the rigid-only row: 1.5 ms per frame p50 against 21 ms with 1e-6,
    /// TRE 2.21 against 2.22 mm).
    pub tracking_relative_tolerance: f64,
    /// Spacing of the surface samples rigid ICP pairs with, metres.
    pub target_spacing: f64,
    /// A frame whose cloud, after the whole registration, still lies farther than this from the
    /// registered surface (RMS of point-to-tangent-plane distances after mean + 2σ, metres) is
    /// rejected as not showing this liver (the default 2 cm is far above noise and the
    /// residual of any frame the registration followed). Judged after the non-rigid stage: a
    /// deep indentation is far from the *rest* shape, not from the registered one (a 5 cm
    /// tool push is 23 mm from it before registration: a gate on the rigid fit would refuse
    /// it). Re-acquiring a lost pose also uses it.
    pub max_rigid_rms: f64,
    /// Before registration, a cloud whose RMS distance to the current surface (after rigid
    /// ICP, or at the identity with `rigid = "none"`) exceeds this (metres) is rejected at
    /// once (`no-match`): no deformation of this liver is that far from its last state — a
    /// 7 cm tool push over a 15 % patch stays under 4 cm — and registering it would only cost
    /// time. Default 6 cm (3 × `max_rigid_rms`).
    pub max_unregistered_rms: f64,
    /// Whether the non-rigid stage runs (`false`: rigid only, the model keeps its rest shape;
    /// the baseline that TRE evaluations compare against).
    pub non_rigid: bool,
    /// Non-rigid settings of the first frame (and of the first after a reset or a failure):
    /// the full penalty ramp.
    pub cold: NonRigidSettings,
    /// Non-rigid settings of a frame that starts from the previous frame's result.
    pub warm: NonRigidSettings,
    /// Wall-clock budget of one frame, ms: when exceeded, the best state so far is returned
    /// and flagged `time_budget`. `None`: no budget.
    pub time_budget_ms: Option<f64>,
    /// Clouds with more points are thinned (every k-th point) to at most this many, and the
    /// frame is flagged `decimated`.
    pub max_cloud_points: usize,
    /// Remove isolated cloud points (far from every other point) before both stages
    /// ([`isolated_mask`](crate::registration::isolated_mask)); the frame
    /// is flagged `isolated_removed` when it removed any (default true).
    pub remove_isolated_points: bool,
    /// When a frame's non-rigid stage reports a solver failure (diverged, inverted element,
    /// Newton iteration cap) or a non-finite state, retry it from the last good state with
    /// smaller penalty increments, then also with a damped direct Newton solver
    /// ([`recovery_ladder`](super::recovery_ladder)), always with the scene's law; the frame
    /// is flagged `recovered:<how>` or `recovery_failed` (default true).
    pub recovery: bool,
    /// Coarse-to-fine start of cold frames: the factor on the cell size of the coarse grid
    /// (`None`: off). Takes effect when the session is built from a scene (the scene layer
    /// builds the coarse model and adds it by
    /// [`Session::with_coarse_start`](super::Session::with_coarse_start)).
    pub coarse_to_fine: Option<f64>,
    /// Explain each registered field again by a load at the contact alone
    /// ([`refit_at_contact`](crate::registration::contact_refit::refit_at_contact)) and keep
    /// it when the cloud away from the contact still lies on the surface (default true).
    pub contact_refit: bool,
    /// Radius (m, rest) of the contact region the refit holds around the dent's centre
    /// (`registration.contact_radius`, default [`DEFAULT_CONTACT_RADIUS`]).
    pub contact_radius: f64,
    /// Fresh factorisations one contact refit may make over all its solves
    /// (`registration.refit_factorizations`, default [`DEFAULT_REFIT_FACTORIZATIONS`]).
    pub refit_factorizations: usize,
}

/// Default of [`SessionSettings::contact_radius`], m: a tool's contact and the dent around
/// it. Chosen on the force-driven tuning set's first liver (29–40 mm give the same mean node
/// error within 0.03 mm, 14 mm leaves the dent's rim free and 0.02 mm more). On the four-liver
/// tuning set (`cargo run --release -- bench --force-truths --set tuning`): 1.45 mm at 25 and
/// 35 mm, 1.37–1.38 mm at 45–55 mm, 1.46 mm at 65 mm (the neo-Hookean cases 1.90 → 1.75 mm at
/// 45; with 8 mm cells 35 and 45 mm both give 1.12 mm) at a higher neo-Hookean force error
/// (median 40 → 43 %). The test set (`--set test`) did not follow: 1.80 → 1.94 mm at 45 mm,
/// every warped-liver case worse. A gain this small against the spread between livers is not
/// a reason to move the default.
pub const DEFAULT_CONTACT_RADIUS: f64 = 0.035;

/// Default of [`SessionSettings::refit_factorizations`]: fresh factorisations one contact refit
/// may make over all its solves. A step the kept factorisation cannot make (its line search
/// fails) refactorises while the budget lasts and otherwise ends that solve at its last
/// iterate; the refit is then flagged `refit_not_converged`, or refused when the state leaves
/// the motion away from the contact unexplained. Without a budget the deepest neo-Hookean
/// frames refactorise up to 33 times. Chosen on the indentation liver's force-driven truths at
/// the default cells and at 8 mm (`livereg bench --force-truths --set tuning [--cell-size 8]`),
/// mean node error / neo-Hookean warm p95:
///
/// | budget | 11.5 mm cells | 8 mm cells |
/// | --- | --- | --- |
/// | 1 | 1.07 mm / 210–260 ms | 0.89 mm / 0.95–1.1 s |
/// | **2** | **1.09 mm / 280–370 ms** | **0.81 mm / 1.1–1.5 s** |
/// | none | 1.09 mm / 390–470 ms | 0.80 mm / 2.9–5.2 s |
///
/// One factorisation leaves the finer grid's refits unconverged (neo-Hookean force 23 → 78 %
/// on the press); two keep the accuracy of none at both sizes. On the four-liver tuning set at
/// the default cells, 3 and 4 give 1.447 and 1.461 mm against 1.449 mm, 4 at a slower
/// neo-Hookean warm p50 (183 against 155 ms). At half the default cells (5.75 mm) some release
/// frames' refits spend two on their first solve, cannot fit their slide and are refused; 4
/// keep them, right on some livers and wrong on others: the tuning set at 5.75 mm is 1.03 mm
/// with 2 and 1.12 mm with 4 (indentation liver's press-release neo-Hookean 1.27 → 0.92 mm,
/// random liver 1's 2.96 → 4.90 mm; docs/data-term.md#the-contact-refit).
pub const DEFAULT_REFIT_FACTORIZATIONS: usize = 2;

/// Default of [`SessionSettings::max_cloud_points`]: about twice a normal frame's cloud on the
/// phantom. Denser clouds register worse there: a million-point frame thinned to 5,000 points
/// gives TRE 1.36 mm, to 2,000: 0.98 mm, to 1,000: 0.88 mm (the next normal frame then 0.52
/// against 0.44 mm); the normal ~700-point cloud of that frame: 0.45 mm
/// (`cargo test --test registration bad_frames:: -- --nocapture`).
pub(crate) const DEFAULT_MAX_CLOUD_POINTS: usize = 2_000;

/// Default of [`SessionSettings::still_frames`]: the most still frames registered together.
pub const DEFAULT_STILL_FRAMES: usize = 4;

/// Newton steps a helper-thread refactorisation lags behind its request when the scene asks
/// for `registration.background_factorization` (`NonRigidSettings::background_lag`). Two steps
/// hide most of a 1,443-node factorisation (20 ms against ~5 ms per step); three lose more
/// accuracy (docs/frames.md#opt-in-speed-settings).
pub const BACKGROUND_FACTORIZATION_LAG: usize = 2;

impl Default for SessionSettings {
    fn default() -> Self {
        Self {
            rigid_mode: RigidMode::Icp,
            pose_update: PoseUpdate::Hold,
            pose_reacquire_rms: 0.008,
            max_pose_uncertainty: 0.002,
            max_expected_error: 0.005,
            // Median/MAD pruning (`registration.robust_pruning`, default true); the rigid
            // ICP's own default stays the thesis's mean + 2σ.
            rigid: RigidIcp {
                robust_pruning: true,
                ..RigidIcp::default()
            },
            pose_search: Some(PoseSearch::default()),
            rest_test: Some(ChangeTest::default()),
            still_frames: DEFAULT_STILL_FRAMES,
            tracking_relative_tolerance: 1e-4,
            target_spacing: 0.005,
            max_rigid_rms: 0.02,
            max_unregistered_rms: 0.06,
            non_rigid: true,
            cold: NonRigidSettings::default(),
            warm: NonRigidSettings::warm(),
            time_budget_ms: None,
            max_cloud_points: DEFAULT_MAX_CLOUD_POINTS,
            remove_isolated_points: true,
            recovery: true,
            coarse_to_fine: None,
            contact_refit: true,
            contact_radius: DEFAULT_CONTACT_RADIUS,
            refit_factorizations: DEFAULT_REFIT_FACTORIZATIONS,
        }
    }
}
