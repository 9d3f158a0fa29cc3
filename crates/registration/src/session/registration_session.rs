//! [`Session`]: one patient's model registered to a stream of frames. Its parts, each in its
//! own file: [`pose`] (the pose), [`change`] (what changed since the last frame),
//! [`recovery`] (the recovery ladder) and [`outcome`] (a frame's result).

mod change;
mod outcome;
mod pose;
mod recovery;
mod refit;

use change::{CloudNoise, StillData, SAME_VIEW_FIT_RATIO, SAME_VIEW_FIT_SLACK};
use outcome::Done;
use recovery::solver_failed;
pub(crate) use recovery::RUNG_NAMES;
pub use recovery::{
    damped_newton, recovery_ladder, recovery_settings, RecoveryRung, BEFORE_RECOVERY,
};

use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::Point3;

use super::frame::{Frame, FrameError, FrameResult, StageTimes};
use super::frame_flag::FrameFlag;
use super::memory_estimate::{still_window_bytes, ModelSize};
use super::settings::SessionSettings;
use super::settings::{PoseUpdate, RigidMode};
use super::still_window::StillWindow;
use crate::geometry::Camera;
use crate::linalg::SolverKind;
use crate::mechanics::{NewtonSettings, NewtonSolver, PenaltySprings};
use crate::mesh::TriSurface;
use crate::model::{Model, ModelError};
use crate::registration::change_evidence::{cloud_noise_sigma_near, ChangeTest};
use crate::registration::isolated_points::{
    isolated_mask, ISOLATION_MEDIAN_FACTOR, ISOLATION_NEIGHBOURS, ISOLATION_SIGMA,
};
use crate::registration::non_rigid_icp::{NonRigidReport, NonRigidTimings};
use crate::registration::pose_search::centroid;
use crate::registration::surface_normals::NormalsAtScale;
use crate::registration::{expected_error, ErrorEstimate, ErrorEvidence};
use crate::registration::{ContactForce, RestCompliance};
use crate::registration::{
    IcpResult, IndexedPoints, ModelTarget, NonRigidIcp, NonRigidSettings, Prolongation, RigidIcp,
    RigidTransform, SurfaceDistances, SurfaceTopology,
};

/// The last state a frame ended in successfully.
#[derive(Debug, Clone)]
struct GoodState {
    /// Grid displacements, m.
    u: Vec<f64>,
    /// Model → cloud pose.
    model_to_cloud: RigidTransform,
    /// Whether a frame has succeeded since the start or the last reset.
    registered: bool,
    /// The last good frame's cloud as registered (metres, cloud frame, after thinning): its
    /// centroid and fit are where a lost pose is searched first ([`Session::reacquire_pose`]).
    cloud: Option<Vec<Point3<f64>>>,
    /// The surface loads the last good frame's registration needed (model frame, SI).
    contact_force: Option<ContactForce>,
    /// The pose was committed by a global search that found another pose about as good
    /// (flag `pose_ambiguous`); every frame holding it says so too.
    pose_ambiguous: bool,
    /// The pose's uncertainty when it was fitted (m, [`Session::pose_uncertainty`]); `None`
    /// when the pose was given (`rigid = "none"`) or its fit did not determine it.
    pose_uncertainty: Option<f64>,
    /// The expected error of the good state (m, [`Session::error_estimate`]); `None` before
    /// the first good frame.
    expected_error: Option<ErrorEstimate>,
}

impl GoodState {
    /// The state before any frame: displacements `u` (m; the rest shape, zeros), the identity
    /// pose, nothing registered or estimated.
    fn at_rest(u: Vec<f64>) -> Self {
        GoodState {
            u,
            model_to_cloud: RigidTransform::identity(),
            registered: false,
            cloud: None,
            contact_force: None,
            pose_ambiguous: false,
            pose_uncertainty: None,
            expected_error: None,
        }
    }
}

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
    /// The scene's camera in the model frame, metres.
    scene_camera: Option<Camera>,
    non_rigid_cold: NonRigidIcp,
    non_rigid_warm: NonRigidIcp,
    good: GoodState,
    /// The clouds of the frames since the liver last moved ([`StillWindow`]).
    still: StillWindow,
    frames: usize,
    coarse: Option<CoarseStart>,
    /// The rigid stage's target (samples and k-d tree of the deformed surface) and the
    /// displacement it was built for: rebuilt only when the good state changed, so
    /// rigid-only sessions (the state never changes) build it once.
    rigid_target: Option<(Vec<f64>, ModelTarget)>,
    /// The surface normals' averaging the non-rigid stages share (`None`: vertex normals).
    normals: Option<std::sync::Arc<NormalsAtScale>>,
    /// The rest surface's vertices and normals, built on the first frame that asks whether
    /// the rest shape explains it ([`Session::rest_shape_if_unchanged`]): the same every
    /// frame.
    rest_surface: std::sync::OnceLock<Option<SurfaceDistances>>,
    /// The model surface's triangles and the triangles around each vertex, which every
    /// deformed surface of the session's signed distances shares.
    surface_topology: std::sync::Arc<SurfaceTopology>,
    /// The last good state's deformed surface index, which the next frame's held-pose check,
    /// still-frame test and re-acquisition read: the one the frame's own fit built, kept with
    /// the state it measured, or built on first use.
    good_surface: std::sync::OnceLock<Option<SurfaceDistances>>,
    /// The model's rest compliance for the contact force, factorised on the first frame that
    /// estimates one (an error, kept, when it cannot be: no estimate then).
    rest_compliance: Option<Result<RestCompliance, String>>,
    /// The uncertainty (m) of a pose fitted by this frame's rigid stage; `None` when the
    /// stage held the pose or fitted none.
    fitted_pose_uncertainty: Option<f64>,
    /// The contact refit's own Newton solver (its factorisation holds the contact region's
    /// springs, not the data term's).
    refit_solver: NewtonSolver,
}

/// The surface of `model` (of `topology`) deformed by `u` (m), for signed distances; `None`
/// for an empty surface.
fn deformed_surface(
    model: &Model,
    topology: &std::sync::Arc<SurfaceTopology>,
    u: &[f64],
) -> Option<SurfaceDistances> {
    SurfaceDistances::new(model.surface_embedding.positions(u), topology.clone())
}

/// The coarse model of a coarse-to-fine start and its prolongation to the fine grid.
struct CoarseStart {
    model: Model,
    icp: NonRigidIcp,
    prolongation: Prolongation,
}

impl Session {
    /// Adds a coarse-to-fine start: cold frames are first registered on `coarse` (the same
    /// body on a coarser grid, SI units) and the fine registration starts from its
    /// prolongated displacement, with one stiff penalty step.
    pub fn with_coarse_start(mut self, coarse: Model) -> Result<Self, ModelError> {
        let prolongation = Prolongation::new(&coarse.problem.grid, &self.model.problem.grid)
            .map_err(|e| ModelError::Invalid(format!("coarse-to-fine prolongation: {e}")))?;
        self.coarse = Some(CoarseStart {
            icp: NonRigidIcp::new(self.settings.cold, coarse.newton)
                .with_normals(self.normals.clone()),
            model: coarse,
            prolongation,
        });
        Ok(self)
    }

    /// Sizes of the models this session registers with, the fine model first, then the coarse
    /// one of a coarse-to-fine start.
    pub fn model_sizes(&self) -> Result<Vec<ModelSize>, String> {
        let mut sizes = vec![ModelSize::of(&self.model, self.model.newton.linear_solver)?];
        sizes[0].normal_bytes = self.normals.as_ref().map_or(0, |n| n.heap_bytes());
        sizes[0].topology_bytes = self.surface_topology.heap_bytes();
        if let Some(c) = &self.coarse {
            sizes.push(ModelSize::of(&c.model, c.model.newton.linear_solver)?);
        }
        Ok(sizes)
    }

    /// Estimated peak memory of this session's registration, bytes: the fine model's
    /// [`ModelSize::estimated_bytes`] plus the coarse model's
    /// [`ModelSize::estimated_grid_bytes`] (see [`Session::model_sizes`]). Made before the
    /// first frame, so that a server can refuse a session its memory budget cannot hold.
    /// A non-rigid session adds its rest compliance for the contact force
    /// ([`ModelSize::rest_compliance_bytes`]), the contact refit's solver when it refits
    /// ([`ModelSize::contact_refit_bytes`]) and its still window at its point cap
    /// ([`still_window_bytes`]). A rigid-only session (`settings.non_rigid`
    /// false) never factorises: its factors are not counted.
    pub fn memory_estimate_bytes(&self) -> Result<u64, String> {
        let mut sizes = self.model_sizes()?;
        let per_frame = if self.settings.non_rigid {
            sizes[0].rest_compliance_bytes()
                + if self.settings.contact_refit {
                    sizes[0].contact_refit_bytes()
                } else {
                    0
                }
                + still_window_bytes(self.settings.still_frames, self.settings.max_cloud_points)
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
        self.coarse.is_some()
    }

    /// A session for `model` with `settings` and the camera (model frame, metres) used when a
    /// frame brings none.
    pub fn new(model: Model, settings: SessionSettings, camera: Option<Camera>) -> Self {
        let u = vec![0.0; model.problem.dofs()];
        let model_newton = model.newton;
        // One averaging of the surface normals for every stage (cold, warm, coarse, recovery).
        let normals = settings
            .cold
            .normal_scale
            .build(&model.surface.vertices, &model.surface.triangles)
            .map(std::sync::Arc::new);
        let surface_topology = std::sync::Arc::new(SurfaceTopology::new(
            model.surface.vertices.len(),
            &model.surface.triangles,
        ));
        Self {
            non_rigid_cold: NonRigidIcp::new(settings.cold, model.newton)
                .with_normals(normals.clone()),
            non_rigid_warm: NonRigidIcp::new(settings.warm, model.newton)
                .with_normals(normals.clone()),
            normals,
            model,
            settings,
            scene_camera: camera,
            good: GoodState::at_rest(u),
            frames: 0,
            coarse: None,
            rigid_target: None,
            still: StillWindow::default(),
            rest_surface: std::sync::OnceLock::new(),
            surface_topology,
            good_surface: std::sync::OnceLock::new(),
            rest_compliance: None,
            fitted_pose_uncertainty: None,
            refit_solver: NewtonSolver::new(NewtonSettings {
                step_stabilization: 0.0,
                mixed_precision: false,
                ..model_newton
            }),
        }
    }

    /// Forgets every frame: back to the rest shape and the identity pose; the next frame is
    /// registered cold.
    pub fn reset(&mut self) {
        self.good = GoodState::at_rest(vec![0.0; self.model.problem.dofs()]);
        self.good_surface = std::sync::OnceLock::new();
        self.non_rigid_cold.invalidate();
        self.non_rigid_warm.invalidate();
        self.still.clear();
        if let Some(c) = &mut self.coarse {
            c.icp.invalidate();
        }
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

    /// One frame through the named stages: [`Session::prepare_cloud`] (checks, thinning,
    /// isolated points), [`Session::rigid_stage`] (the pose), [`Session::non_rigid_stage`]
    /// (coarse start, the registration, the recovery ladder), then the gate on the registered
    /// fit.
    fn try_register(
        &mut self,
        frame: &Frame,
        start: Instant,
        times: &mut StageTimes,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<Done, FrameError> {
        let t = Instant::now();
        let scale = self.model.length_scale;
        let cloud = self.prepare_cloud(frame, flags)?;
        times.prepare_ms = ms(t);

        let t = Instant::now();
        let (model_to_cloud, rigid_iterations) = self.rigid_stage(&cloud, flags)?;
        times.rigid_ms = ms(t);

        if !self.settings.non_rigid {
            return Ok(Done::without_non_rigid(
                self.good.u.clone(),
                model_to_cloud,
                rigid_iterations,
                cloud,
                0.0,
                None,
            ));
        }

        // Non-rigid stage in the model frame.
        let cloud_to_model = model_to_cloud.inverse();
        let aligned: Vec<Point3<f64>> = cloud.iter().map(|p| cloud_to_model.apply(p)).collect();
        let t = Instant::now();
        let noise = CloudNoise::measure(&aligned, self.settings.rest_test.as_ref());
        let at_rest = self.rest_shape_if_unchanged(&aligned, noise.as_ref(), flags);
        times.change_ms = ms(t);
        if let Some((u, fit, force)) = at_rest {
            return Ok(Done {
                noise: noise.as_ref().map_or(0.0, |n| n.sigma),
                ..Done::without_non_rigid(u, model_to_cloud, rigid_iterations, cloud, fit, force)
            });
        }
        let camera = match &frame.camera {
            Some(c) => Some(camera_to_model(c, scale, &cloud_to_model)?),
            None => self.scene_camera,
        };
        let deadline = self
            .settings
            .time_budget_ms
            .map(|b| start + Duration::from_secs_f64(b.max(0.0) * 1e-3));
        let t = Instant::now();
        let (still, data) = self.still_frames(&aligned, frame.camera, noise.as_ref(), flags);
        times.change_ms += ms(t);
        let (u, report, spent) = self.non_rigid_stage(&data, camera.as_ref(), deadline, flags)?;
        times.visibility_ms = spent.visibility_ms;
        times.pairing_ms = spent.pairing_ms;
        times.newton_ms = spent.newton_ms;
        if !all_finite(&u) {
            self.non_rigid_cold.invalidate();
            self.non_rigid_warm.invalidate();
            return Err(FrameError::NonFiniteState);
        }
        let t = Instant::now();
        let (u, refit_force) = self.contact_refit(&data, u, report.data_term.as_ref(), flags);
        times.refit_ms = ms(t);
        if report.deadline_reached {
            flags.push(FrameFlag::TimeBudget);
        }
        // A re-acquired pose must not need a new shape: measured on the phantom, a right
        // re-acquisition changes the surface by 0.2 mm RMS, ordinary frames by 0.8–1.6 mm,
        // and a 109° wrong minimum of rigid ICP by 25 mm
        // (`tests/registration/bad_frames.rs`).
        if flags.contains(&FrameFlag::PoseReacquired) {
            let change = self.surface_change_rms(&u);
            if change > self.settings.pose_reacquire_rms {
                return Err(FrameError::ImplausibleReacquisition {
                    change_mm: change * 1e3,
                    limit_mm: self.settings.pose_reacquire_rms * 1e3,
                });
            }
        }
        // The gate on what the frame is: does the cloud lie on the registered surface?
        let t = Instant::now();
        let surface = deformed_surface(&self.model, &self.surface_topology, &u);
        let fit = surface
            .as_ref()
            .map_or(f64::INFINITY, |s| s.fit_rms(&aligned));
        times.gate_ms = ms(t);
        if fit > self.settings.max_rigid_rms {
            return Err(FrameError::NoFit {
                rms_mm: fit * 1e3,
                limit_mm: self.settings.max_rigid_rms * 1e3,
            });
        }
        let t = Instant::now();
        // The rest compliance is linear in the load, exact for the linear law; for the other
        // laws a kept contact refit gives the load through the model's own law.
        let contact_force = match refit_force {
            Some(force) if !self.model.problem.material.is_linear() => Some(force),
            _ => report
                .data_term
                .as_ref()
                .and_then(|springs| self.contact_force(springs, &u)),
        };
        times.force_ms = ms(t);
        Ok(Done {
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

    /// The contact force the data term `springs` of the registered state `u` (m) imply
    /// ([`RestCompliance::fit`]); the model's rest compliance is factorised on first use.
    fn contact_force(&mut self, springs: &PenaltySprings, u: &[f64]) -> Option<ContactForce> {
        let compliance = self
            .rest_compliance
            .get_or_insert_with(|| {
                RestCompliance::new(
                    &mut self.model.problem,
                    self.model.newton.linear_solver,
                    &self.model.point_holds,
                )
            })
            .as_mut()
            .ok()?;
        compliance.fit(&self.model.problem, &self.model.surface, springs, u)
    }

    /// Input checks (empty, non-finite: rejected), thinning to `max_cloud_points` (flag
    /// `decimated`) and isolated-point removal (flag `isolated_removed`): the cloud in metres,
    /// cloud frame.
    fn prepare_cloud(
        &self,
        frame: &Frame,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<Vec<Point3<f64>>, FrameError> {
        let scale = self.model.length_scale;
        if frame.points.is_empty() {
            return Err(FrameError::Empty);
        }
        if let Some(index) = crate::mesh::first_non_finite_point(&frame.points) {
            let p = frame.points[index];
            return Err(FrameError::NonFinite {
                index,
                x: p.x,
                y: p.y,
                z: p.z,
            });
        }
        let stride = frame
            .points
            .len()
            .div_ceil(self.settings.max_cloud_points.max(3));
        if stride > 1 {
            flags.push(FrameFlag::Decimated);
        }
        let cloud: Vec<Point3<f64>> = frame
            .points
            .iter()
            .step_by(stride)
            .map(|p| p * scale)
            .collect();
        let cloud = if self.settings.remove_isolated_points {
            let (kept, removed) = without_isolated_points(cloud);
            if removed > 0 {
                flags.push(FrameFlag::IsolatedRemoved);
            }
            kept
        } else {
            cloud
        };
        if cloud.len() < 3 {
            return Err(FrameError::Rigid(format!(
                "{} points; at least 3 are needed",
                cloud.len()
            )));
        }
        Ok(cloud)
    }

    /// RMS distance (m) between the surface vertices at displacement `u` and at the last good
    /// state's.
    fn surface_change_rms(&self, u: &[f64]) -> f64 {
        let now = self.model.surface_embedding.positions(u);
        let last = self.model.surface_embedding.positions(&self.good.u);
        let sum: f64 = now
            .iter()
            .zip(&last)
            .map(|(p, q)| (p - q).norm_squared())
            .sum();
        (sum / now.len().max(1) as f64).sqrt()
    }

    /// The non-rigid stage of a frame (`data`: the clouds of the still window, model frame,
    /// metres, with their springs' weight): the coarse-to-fine start of a cold frame, the
    /// registration from the last good state, and the recovery ladder when the solver failed
    /// (flags `coarse_start`, `recovered:…`, `recovery_failed`). Returns the displacement, the
    /// report and the time spent by stage.
    fn non_rigid_stage(
        &mut self,
        data: &StillData,
        camera: Option<&Camera>,
        deadline: Option<Instant>,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<(Vec<f64>, NonRigidReport, NonRigidTimings), FrameError> {
        let aligned = &data.points[..];
        let warm = self.good.registered;
        let mut settings = if warm {
            self.settings.warm
        } else {
            self.settings.cold
        };
        settings.data_weight = data.weight;
        settings.cloud_noise = data.noise;
        // Coarse-to-fine start of a cold frame: the coarse registration's field, prolongated,
        // is the fine stage's start, which then needs only the stiff end of the ramp.
        let mut start_u = None;
        let mut coarse_counts = (0, 0, 0);
        let mut spent = NonRigidTimings::default();
        if !warm {
            if let Some(c) = &mut self.coarse {
                let mut uc = vec![0.0; c.model.problem.dofs()];
                c.icp.settings = NonRigidSettings {
                    cloud_noise: data.noise,
                    ..self.settings.cold
                };
                if let Ok(r) = c
                    .icp
                    .register(&mut c.model, aligned, camera, &mut uc, deadline)
                {
                    add_timings(&mut spent, &r.timings);
                    if r.warnings.is_empty() && all_finite(&uc) {
                        start_u = Some(c.prolongation.apply(&uc));
                        settings.penalty_steps = 1;
                        coarse_counts = (r.icp_iterations, r.newton_iterations, r.factorizations);
                        flags.push(FrameFlag::CoarseStart);
                    }
                } else {
                    c.icp.invalidate();
                }
            }
        }
        let (u, mut report) =
            self.non_rigid_attempt(warm, settings, start_u, aligned, camera, deadline)?;
        report.icp_iterations += coarse_counts.0;
        report.newton_iterations += coarse_counts.1;
        report.factorizations += coarse_counts.2;
        add_timings(&mut spent, &report.timings);
        if self.settings.recovery && (solver_failed(&report) || !all_finite(&u)) {
            // The stage's kept factorisation and visible set are those of a failed attempt.
            self.icp(warm).invalidate();
            let (u, report) = self.recover(u, report, data, camera, deadline, &mut spent, flags)?;
            return Ok((u, report, spent));
        }
        Ok((u, report, spent))
    }
}

impl Session {
    /// The non-rigid stage of warm frames (`warm`) or of cold ones.
    fn icp(&mut self, warm: bool) -> &mut NonRigidIcp {
        if warm {
            &mut self.non_rigid_warm
        } else {
            &mut self.non_rigid_cold
        }
    }

    /// One non-rigid attempt from `start` (default: the last good state) with `settings`
    /// (the warm stage's solver when `warm`, else the cold one's). Returns the new
    /// displacement and the report.
    fn non_rigid_attempt(
        &mut self,
        warm: bool,
        settings: NonRigidSettings,
        start: Option<Vec<f64>>,
        aligned: &[Point3<f64>],
        camera: Option<&Camera>,
        deadline: Option<Instant>,
    ) -> Result<(Vec<f64>, NonRigidReport), FrameError> {
        let mut u = start.unwrap_or_else(|| self.good.u.clone());
        let icp = if warm {
            &mut self.non_rigid_warm
        } else {
            &mut self.non_rigid_cold
        };
        // The data term's weight changes as the still window fills and empties, and with
        // each cloud's noise; the kept factorisation, a modified-Newton approximation of the
        // tangent anyway, stays.
        let same_but_weight = NonRigidSettings {
            data_weight: settings.data_weight,
            cloud_noise: settings.cloud_noise,
            ..icp.settings
        } == settings;
        if !same_but_weight {
            icp.invalidate();
        }
        icp.settings = settings;
        let report = icp.register(&mut self.model, aligned, camera, &mut u, deadline);
        if !all_finite(&u) {
            icp.invalidate();
        }
        let report = report.map_err(|e| FrameError::NonRigid(e.to_string()))?;
        Ok((u, report))
    }

    /// The last good state's deformed surface index ([`Session::good_surface`]'s cache);
    /// `None` for an empty surface.
    fn good_surface(&self) -> Option<&SurfaceDistances> {
        self.good_surface
            .get_or_init(|| deformed_surface(&self.model, &self.surface_topology, &self.good.u))
            .as_ref()
    }
}

/// `cloud` without its isolated points ([`isolated_mask`] with the module's constants), and
/// how many were removed.
fn without_isolated_points(cloud: Vec<Point3<f64>>) -> (Vec<Point3<f64>>, usize) {
    let n = cloud.len();
    let Some(indexed) = IndexedPoints::new(cloud.clone()) else {
        return (cloud, 0);
    };
    let mask = isolated_mask(
        &indexed,
        ISOLATION_NEIGHBOURS,
        ISOLATION_SIGMA,
        ISOLATION_MEDIAN_FACTOR,
    );
    let kept: Vec<Point3<f64>> = cloud
        .into_iter()
        .zip(&mask)
        .filter(|(_, &m)| !m)
        .map(|(p, _)| p)
        .collect();
    let removed = n - kept.len();
    (kept, removed)
}

fn all_finite(u: &[f64]) -> bool {
    u.iter().all(|v| v.is_finite())
}

fn add_timings(a: &mut NonRigidTimings, b: &NonRigidTimings) {
    a.visibility_ms += b.visibility_ms;
    a.pairing_ms += b.pairing_ms;
    a.newton_ms += b.newton_ms;
}

/// The frame's camera (cloud frame, scene units) moved into the model frame, metres.
fn camera_to_model(
    c: &Camera,
    scale: f64,
    cloud_to_model: &RigidTransform,
) -> Result<Camera, FrameError> {
    let cam = Camera::new(
        cloud_to_model.apply(&(c.position * scale)),
        cloud_to_model.apply(&(c.look_at * scale)),
        cloud_to_model.apply_vector(&c.up),
        c.fov_deg,
    )
    .map_err(|e| FrameError::Rigid(format!("camera: {e}")))?;
    Ok(cam)
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
