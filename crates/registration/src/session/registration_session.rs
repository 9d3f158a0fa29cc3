//! [`Session`]: one patient's model registered to a stream of frames. The session composes
//! its parts, each a type in its own file, and runs a frame through them as named stages:
//! - [`prepare_cloud`](cloud_preparation::prepare_cloud): the input checks, thinning and
//!   isolated points;
//! - [`PoseTracker`](pose_tracker::PoseTracker): the pose (held, followed or tracked,
//!   re-acquired, searched) and its uncertainty, with the scene's camera and the rigid target;
//! - [`ChangeTests`](change_tests::ChangeTests): what changed since the last frame (the rest
//!   test, the still test and its window), on a cloud with its noise
//!   ([`CloudNoise`](cloud_noise::CloudNoise)), giving the non-rigid stage its data
//!   ([`StillData`](still_data::StillData));
//! - [`NonRigidStage`](non_rigid_stage::NonRigidStage): the shape, from the last good state
//!   or the [`CoarseStart`](coarse_start::CoarseStart), and the recovery ladder when its
//!   solver failed ([`recover`](recovery_ladder::recover));
//! - [`ContactForceEstimator`](contact_force_estimator::ContactForceEstimator): the contact
//!   refit and the contact force;
//! - then the gate on the registered fit, and the frame's
//!   [`FrameSuccess`](frame_success::FrameSuccess) committed as the
//!   [`GoodState`](good_state::GoodState).
//!
//! The parts read the session through a [`SessionView`](session_view::SessionView) (the
//! model, the settings, the good state and the [`ModelSurfaces`](model_surfaces::ModelSurfaces)).

mod change_tests;
mod cloud_noise;
mod cloud_preparation;
mod coarse_start;
mod contact_force_estimator;
mod frame_success;
mod good_state;
mod model_surfaces;
mod non_rigid_stage;
mod pose_tracker;
mod recovery_ladder;
mod session_view;
mod still_data;

pub(crate) use recovery_ladder::RUNG_NAMES;
pub use recovery_ladder::{
    damped_newton, recovery_ladder, recovery_settings, RecoveryRung, BEFORE_RECOVERY,
};

use std::time::{Duration, Instant};

use nalgebra::Point3;

use super::frame::{Frame, FrameError, FrameResult, StageTimes};
use super::frame_flag::FrameFlag;
use super::memory_estimate::{still_window_bytes, ModelSize};
use super::settings::SessionSettings;
use crate::geometry::Camera;
use crate::model::{Model, ModelError};
use crate::registration::linear_held_body::most_vertices_within;
use crate::registration::non_rigid_icp::NonRigidReport;
use crate::registration::{ErrorEstimate, RigidTransform, SurfaceDistances};
use change_tests::ChangeTests;
use cloud_noise::CloudNoise;
use cloud_preparation::prepare_cloud;
use contact_force_estimator::ContactForceEstimator;
use frame_success::FrameSuccess;
use good_state::GoodState;
use model_surfaces::ModelSurfaces;
use non_rigid_stage::{all_finite, NonRigidStage};
use pose_tracker::PoseTracker;
use session_view::SessionView;
use still_data::StillData;

/// Registers a stream of frames to one model, carrying the state from frame to frame.
///
/// Per frame: checks (empty, non-finite → rejected; too many points → thinned and flagged);
/// rigid ICP of the cloud to the model's *current deformed* surface, starting from the last
/// pose (tracking), rejected when its RMS exceeds [`SessionSettings::max_rigid_rms`]; non-rigid
/// ICP from the last good displacement (cold settings on the first frame, warm after), stopped
/// by the time budget if set. The state is committed only when the frame succeeds and the
/// displacement is finite, so a failed frame never corrupts the session.
pub struct Session {
    /// The model (SI units).
    pub model: Model,
    /// Settings.
    pub settings: SessionSettings,
    /// The pose from frame to frame.
    pose: PoseTracker,
    /// What changed since the last frame, and the still window.
    change: ChangeTests,
    /// The shape: the non-rigid registration, its coarse start and recovery.
    non_rigid: NonRigidStage,
    /// The contact force and the contact refit.
    contact: ContactForceEstimator,
    /// The model's surfaces for signed distances (rest, last good state).
    surfaces: ModelSurfaces,
    /// The last good state.
    good: GoodState,
    /// Frames seen so far (including rejected ones).
    frames: usize,
}

impl Session {
    /// Adds a coarse-to-fine start: cold frames are first registered on `coarse` (the same
    /// body on a coarser grid, SI units) and the fine registration starts from its
    /// prolongated displacement, with one stiff penalty step.
    pub fn with_coarse_start(mut self, coarse: Model) -> Result<Self, ModelError> {
        self.non_rigid
            .add_coarse_start(coarse, &self.model, self.settings.cold)?;
        Ok(self)
    }

    /// Sizes of the models this session registers with, the fine model first, then the coarse
    /// one of a coarse-to-fine start.
    pub fn model_sizes(&self) -> Result<Vec<ModelSize>, String> {
        let mut sizes = vec![ModelSize::of(&self.model, self.model.newton.linear_solver)?];
        sizes[0].normal_bytes = self.non_rigid.normal_bytes();
        sizes[0].topology_bytes = self.surfaces.topology().heap_bytes();
        if let Some(c) = self.non_rigid.coarse_model() {
            sizes.push(ModelSize::of(c, c.newton.linear_solver)?);
        }
        Ok(sizes)
    }

    /// Estimated peak memory of this session's registration, bytes: the fine model's
    /// [`ModelSize::estimated_bytes`] plus the coarse model's
    /// [`ModelSize::estimated_grid_bytes`] (see [`Session::model_sizes`]). Made before the
    /// first frame, so that a server can refuse a session its memory budget cannot hold.
    /// A non-rigid session adds its rest compliance for the contact force
    /// ([`ModelSize::rest_compliance_bytes`]), the contact refit's solver when it refits
    /// ([`ModelSize::contact_refit_bytes`]; a linear law's refit also its compliance columns,
    /// [`ModelSize::held_columns_bytes`]) and its still window at its point cap
    /// ([`still_window_bytes`]), and a small-strain linear model its kept stiffness per grid
    /// ([`ModelSize::linear_stiffness_bytes`]). A rigid-only session (`settings.non_rigid`
    /// false) never factorises: its factors are not counted.
    pub fn memory_estimate_bytes(&self) -> Result<u64, String> {
        let mut sizes = self.model_sizes()?;
        let linear = self.model.problem.material.is_linear();
        // Only a linear law's refit keeps compliance columns: the region is measured for it alone.
        let held_region = if linear && self.settings.contact_refit {
            most_vertices_within(&self.model.surface.vertices, self.settings.contact_radius)
        } else {
            0
        };
        let per_frame = if self.settings.non_rigid {
            sizes[0].rest_compliance_bytes()
                + if self.settings.contact_refit {
                    sizes[0].contact_refit_bytes() + sizes[0].held_columns_bytes(held_region)
                } else {
                    0
                }
                + still_window_bytes(self.settings.still_frames, self.settings.max_cloud_points)
                + sizes
                    .iter()
                    .map(|s| s.linear_stiffness_bytes(linear))
                    .sum::<u64>()
        } else {
            sizes.iter_mut().for_each(|s| s.factor_values = 0);
            0
        };
        Ok(sizes[0].estimated_bytes()
            + per_frame
            + sizes[1..]
                .iter()
                .map(ModelSize::estimated_grid_bytes)
                .sum::<u64>())
    }

    /// Whether cold frames start on a coarse grid.
    pub fn has_coarse_start(&self) -> bool {
        self.non_rigid.coarse_model().is_some()
    }

    /// A session for `model` with `settings` and the camera (model frame, metres) used when a
    /// frame brings none.
    pub fn new(model: Model, settings: SessionSettings, camera: Option<Camera>) -> Self {
        let u = vec![0.0; model.problem.dofs()];
        Self {
            pose: PoseTracker::new(camera),
            change: ChangeTests::default(),
            non_rigid: NonRigidStage::new(&model, &settings),
            contact: ContactForceEstimator::new(model.newton),
            surfaces: ModelSurfaces::new(&model),
            good: GoodState::at_rest(u),
            frames: 0,
            model,
            settings,
        }
    }

    /// Forgets every frame: back to the rest shape and the identity pose; the next frame is
    /// registered cold.
    pub fn reset(&mut self) {
        self.good = GoodState::at_rest(vec![0.0; self.model.problem.dofs()]);
        self.surfaces.forget_good();
        self.non_rigid.reset();
        self.change.clear();
    }

    /// Frames seen so far (including rejected ones).
    pub fn frames_seen(&self) -> usize {
        self.frames
    }

    /// Grid displacements of the last good state, m.
    pub fn displacement(&self) -> &[f64] {
        &self.good.u
    }

    /// Model → cloud pose of the last good state.
    pub fn pose(&self) -> RigidTransform {
        self.good.model_to_cloud
    }

    /// Whether the next frame starts from a registered state.
    pub fn is_warm(&self) -> bool {
        self.good.registered
    }

    /// Registers one frame. Never panics on any input: a rejected frame gives a result with
    /// `error` set, flagged `failed`, carrying the last good state.
    pub fn register(&mut self, frame: &Frame) -> FrameResult {
        let start = Instant::now();
        let mut times = StageTimes::default();
        let mut flags = Vec::new();
        let outcome = self.try_register(frame, start, &mut times, &mut flags);
        self.finish(
            &frame.source,
            frame.points.len(),
            start,
            times,
            flags,
            outcome,
        )
    }

    /// Counts a frame that could not even be read (`error`, typically [`FrameError::Input`])
    /// and returns its flagged result carrying the last good state; the session is unchanged.
    pub fn reject(&mut self, source: &str, error: FrameError) -> FrameResult {
        let start = Instant::now();
        self.finish(
            source,
            0,
            start,
            StageTimes::default(),
            Vec::new(),
            Err(error),
        )
    }

    /// One frame through the named stages: [`prepare_cloud`](cloud_preparation::prepare_cloud)
    /// (checks, thinning, isolated points), the pose
    /// ([`PoseTracker::rigid_stage`](pose_tracker::PoseTracker::rigid_stage)), then, with the
    /// non-rigid stage on, the shape ([`Session::register_shape`]).
    fn try_register(
        &mut self,
        frame: &Frame,
        start: Instant,
        times: &mut StageTimes,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<FrameSuccess, FrameError> {
        let t = Instant::now();
        let cloud = prepare_cloud(frame, &self.settings, self.model.length_scale, flags)?;
        times.prepare_ms = ms(t);

        let t = Instant::now();
        let view = SessionView {
            model: &self.model,
            settings: &self.settings,
            good: &self.good,
            surfaces: &self.surfaces,
        };
        let (model_to_cloud, rigid_iterations) = self.pose.rigid_stage(&view, &cloud, flags)?;
        times.rigid_ms = ms(t);

        if !self.settings.non_rigid {
            return Ok(FrameSuccess::without_non_rigid(
                self.good.u.clone(),
                model_to_cloud,
                rigid_iterations,
                cloud,
                0.0,
                None,
            ));
        }
        self.register_shape(
            frame,
            start,
            cloud,
            (model_to_cloud, rigid_iterations),
            times,
            flags,
        )
    }

    /// The shape of a frame whose `cloud` (metres, cloud frame) the pose stage placed
    /// (`pose`: the model → cloud transform and its rigid iterations), through the named
    /// stages: what changed ([`ChangeTests`]: a cloud the rest shape explains ends here, the
    /// still window gives the data), the non-rigid registration
    /// ([`Session::non_rigid_stage`]), the contact refit ([`ContactForceEstimator::refit`]),
    /// the check of a re-acquired pose ([`Session::check_reacquisition`]), the gate on the
    /// registered fit ([`Session::fit_gate`]), and the contact force
    /// ([`ContactForceEstimator::frame_force`]).
    fn register_shape(
        &mut self,
        frame: &Frame,
        start: Instant,
        cloud: Vec<Point3<f64>>,
        pose: (RigidTransform, usize),
        times: &mut StageTimes,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<FrameSuccess, FrameError> {
        let (model_to_cloud, rigid_iterations) = pose;
        let view = SessionView {
            model: &self.model,
            settings: &self.settings,
            good: &self.good,
            surfaces: &self.surfaces,
        };
        // Non-rigid stage in the model frame.
        let cloud_to_model = model_to_cloud.inverse();
        let aligned: Vec<Point3<f64>> = cloud.iter().map(|p| cloud_to_model.apply(p)).collect();
        let t = Instant::now();
        let noise = CloudNoise::measure(&aligned, self.settings.rest_test.as_ref());
        let at_rest = self
            .change
            .rest_shape_if_unchanged(&view, &aligned, noise.as_ref(), flags);
        times.change_ms = ms(t);
        if let Some((u, fit, force)) = at_rest {
            // The solvers' warm state belongs to the shape left behind.
            self.non_rigid.invalidate();
            return Ok(FrameSuccess {
                noise: noise.as_ref().map_or(0.0, |n| n.sigma),
                ..FrameSuccess::without_non_rigid(
                    u,
                    model_to_cloud,
                    rigid_iterations,
                    cloud,
                    fit,
                    force,
                )
            });
        }
        let camera = self.pose.camera(
            frame.camera.as_ref(),
            self.model.length_scale,
            &cloud_to_model,
        )?;
        let deadline = self
            .settings
            .time_budget_ms
            .map(|b| start + Duration::from_secs_f64(b.max(0.0) * 1e-3));
        let t = Instant::now();
        let (still, data) =
            self.change
                .still_frames(&view, &aligned, frame.camera, noise.as_ref(), flags);
        times.change_ms += ms(t);
        let (u, report) = self.non_rigid_stage(&data, camera.as_ref(), deadline, times, flags)?;
        let t = Instant::now();
        let (u, refit_force) = self.contact.refit(
            &mut self.model,
            &self.settings,
            &self.surfaces,
            &data,
            u,
            report.data_term.as_ref(),
            flags,
        );
        times.refit_ms = ms(t);
        if report.deadline_reached {
            flags.push(FrameFlag::TimeBudget);
        }
        self.check_reacquisition(&u, flags)?;
        let (surface, fit) = self.fit_gate(&u, &aligned, times)?;
        let t = Instant::now();
        let contact_force = self.contact.frame_force(
            &mut self.model,
            refit_force,
            report.data_term.as_ref(),
            &u,
            flags,
        );
        times.force_ms = ms(t);
        Ok(FrameSuccess {
            u,
            model_to_cloud,
            converged: report.converged,
            rigid_iterations,
            icp_iterations: report.icp_iterations,
            newton_iterations: report.newton_iterations,
            factorizations: report.factorizations,
            surface_rms: report.surface_rms,
            used_points: cloud.len(),
            cloud,
            sources: report.sources,
            warnings: report.warnings,
            contact_force,
            still,
            surface,
            fit_rms: fit,
            noise: noise.as_ref().map_or(0.0, |n| n.sigma),
        })
    }

    /// The non-rigid stage ([`NonRigidStage::register`]) of the still window's `data` seen by
    /// `camera`, stopped at `deadline`, from the last good state, its time by stage into
    /// `times`: the displacement (m) and the report; `non-finite-state` when the displacement
    /// is not finite.
    fn non_rigid_stage(
        &mut self,
        data: &StillData,
        camera: Option<&Camera>,
        deadline: Option<Instant>,
        times: &mut StageTimes,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<(Vec<f64>, NonRigidReport), FrameError> {
        let (u, report, spent) = self.non_rigid.register(
            &mut self.model,
            &self.settings,
            &self.good.u,
            self.good.registered,
            data,
            camera,
            deadline,
            flags,
        )?;
        times.visibility_ms = spent.visibility_ms;
        times.pairing_ms = spent.pairing_ms;
        times.newton_ms = spent.newton_ms;
        if !all_finite(&u) {
            self.non_rigid.invalidate();
            return Err(FrameError::NonFiniteState);
        }
        Ok((u, report))
    }

    /// The gate on what the frame is: does the cloud `aligned` (model frame, m) lie on the
    /// surface registered at `u` (m)? The surface and the cloud's fit RMS (m, after the mean +
    /// 2σ outlier rule) when the fit is within [`SessionSettings::max_rigid_rms`], `no-fit`
    /// otherwise; its time into `times`.
    fn fit_gate(
        &self,
        u: &[f64],
        aligned: &[Point3<f64>],
        times: &mut StageTimes,
    ) -> Result<(Option<SurfaceDistances>, f64), FrameError> {
        let t = Instant::now();
        let surface = self.surfaces.deformed(&self.model, u);
        let fit = surface
            .as_ref()
            .map_or(f64::INFINITY, |s| s.fit_rms(aligned));
        times.gate_ms = ms(t);
        if fit > self.settings.max_rigid_rms {
            return Err(FrameError::NoFit {
                rms_mm: fit * 1e3,
                limit_mm: self.settings.max_rigid_rms * 1e3,
            });
        }
        Ok((surface, fit))
    }

    /// A re-acquired pose (flag `pose_reacquired`) must not need a new shape: the frame's
    /// registered displacement `u` (m) may move the surface from the last good state's by at
    /// most [`SessionSettings::pose_reacquire_rms`] (RMS). Measured on the phantom, a right
    /// re-acquisition changes the surface by 0.2 mm RMS, ordinary frames by 0.8–1.6 mm, and a
    /// 109° wrong minimum of rigid ICP by 25 mm (`tests/registration/bad_frames.rs`).
    fn check_reacquisition(&self, u: &[f64], flags: &[FrameFlag]) -> Result<(), FrameError> {
        if flags.contains(&FrameFlag::PoseReacquired) {
            let change = self.good.surface_change_rms(&self.model, u);
            if change > self.settings.pose_reacquire_rms {
                return Err(FrameError::ImplausibleReacquisition {
                    change_mm: change * 1e3,
                    limit_mm: self.settings.pose_reacquire_rms * 1e3,
                });
            }
        }
        Ok(())
    }

    /// The result of frame `source` (`received` points, started at `start`, with its stage
    /// `times` and `flags`) from its `outcome`: a success becomes the session's good state
    /// ([`Session::accept`]); a failure leaves the state as it was, flagged `failed` with its
    /// cause. Either way the result carries the good state's positions.
    fn finish(
        &mut self,
        source: &str,
        received: usize,
        start: Instant,
        times: StageTimes,
        flags: Vec<FrameFlag>,
        outcome: Result<FrameSuccess, FrameError>,
    ) -> FrameResult {
        let index = self.frames;
        self.frames += 1;
        let warm = self.good.registered;
        let t = Instant::now();
        let scale = self.model.length_scale;
        let mut result = FrameResult {
            frame: index,
            source: source.to_string(),
            wall_ms: 0.0,
            converged: false,
            model_to_cloud: self.good.model_to_cloud,
            rigid_iterations: 0,
            icp_iterations: 0,
            newton_iterations: 0,
            factorizations: 0,
            surface_rms: 0.0,
            cloud_points: (received, 0),
            sources: 0,
            warm,
            flags,
            warnings: Vec::new(),
            error: None,
            surface: Vec::new(),
            structures: Vec::new(),
            times,
            contact_force: None,
            pose_uncertainty: None,
            expected_error: self.good.expected_error.map(|e| scaled_estimate(&e, scale)),
        };
        match outcome {
            Ok(done) => self.accept(done, &mut result),
            Err(e) => {
                result.flags.push(FrameFlag::Failed);
                result.error = Some(e);
            }
        }
        self.good.write_positions(&self.model, &mut result);
        result.times.output_ms = ms(t);
        result.wall_ms = ms(start);
        result
    }

    /// A frame that succeeded: its pose flags and uncertainty, its expected error, and its
    /// state as the session's new good state, written into `result`.
    fn accept(&mut self, done: FrameSuccess, result: &mut FrameResult) {
        let scale = self.model.length_scale;
        let held = self.good.registered && done.model_to_cloud == self.good.model_to_cloud;
        let (pose_ambiguous, pose_uncertainty) =
            self.pose
                .pose_flags(&self.settings, scale, &self.good, held, result);
        let contact_explained = result.flags.contains(&FrameFlag::ContactRefit)
            && !result.flags.contains(&FrameFlag::RefitNotConverged);
        let estimate = done.error_estimate(&self.model, pose_uncertainty, contact_explained);
        if estimate.expected > self.settings.max_expected_error {
            result.flags.push(FrameFlag::ExpectedErrorHigh);
        }
        result.expected_error = Some(scaled_estimate(&estimate, scale));
        if let Some(surface) = done.surface {
            self.surfaces.keep_good(surface);
        } else if done.u != self.good.u {
            self.surfaces.forget_good();
        }
        self.good = GoodState {
            u: done.u,
            model_to_cloud: done.model_to_cloud,
            registered: true,
            cloud: Some(done.cloud),
            contact_force: done.contact_force,
            pose_ambiguous,
            pose_uncertainty,
            expected_error: Some(estimate),
        };
        self.change.keep(done.still);
        result.model_to_cloud = done.model_to_cloud;
        result.converged = done.converged;
        result.rigid_iterations = done.rigid_iterations;
        result.icp_iterations = done.icp_iterations;
        result.newton_iterations = done.newton_iterations;
        result.factorizations = done.factorizations;
        result.surface_rms = done.surface_rms / scale;
        result.cloud_points.1 = done.used_points;
        result.sources = done.sources;
        result.warnings = done.warnings;
        if !done.converged && !result.flags.contains(&FrameFlag::TimeBudget) {
            result.flags.push(FrameFlag::IcpNotConverged);
        }
    }
}

/// `e` (m) in scene units (`scale`: metres per scene unit).
fn scaled_estimate(e: &ErrorEstimate, scale: f64) -> ErrorEstimate {
    ErrorEstimate {
        expected: e.expected / scale,
        pose: e.pose / scale,
        unseen: e.unseen / scale,
        residual: e.residual / scale,
        noise: e.noise / scale,
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
