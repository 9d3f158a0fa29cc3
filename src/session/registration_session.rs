//! [`Session`]: one patient's model registered to a stream of frames.

use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::Point3;

use super::frame::{Frame, FrameError, FrameResult, StageTimes};
use super::frame_flag::FrameFlag;
use super::memory_estimate::{still_window_bytes, ModelSize};
use super::settings::SessionSettings;
use super::still_window::StillWindow;
use crate::geometry::Camera;
use crate::linalg::SolverKind;
use crate::mechanics::{NewtonSettings, PenaltySprings};
use crate::mesh::TriSurface;
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
use crate::scene::{LoadedScene, PoseUpdate, RigidMode};
use crate::simulation::{ModelError, SceneModel};

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
    pub model: SceneModel,
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
}

/// The surface of `model` (of `topology`) deformed by `u` (m), for signed distances; `None`
/// for an empty surface.
fn deformed_surface(
    model: &SceneModel,
    topology: &std::sync::Arc<SurfaceTopology>,
    u: &[f64],
) -> Option<SurfaceDistances> {
    SurfaceDistances::new(model.surface_embedding.positions(u), topology.clone())
}

/// The coarse model of a coarse-to-fine start and its prolongation to the fine grid.
struct CoarseStart {
    model: SceneModel,
    icp: NonRigidIcp,
    prolongation: Prolongation,
}

impl Session {
    /// A session for a loaded scene, with settings from its `[registration]` section.
    pub fn from_scene(loaded: &LoadedScene) -> Result<Self, ModelError> {
        let model = SceneModel::build(loaded)?;
        let settings = SessionSettings::from_scene(&loaded.scene, loaded.length_scale());
        let scale = loaded.length_scale();
        let scene_camera = match loaded
            .scene
            .registration
            .as_ref()
            .and_then(|r| r.camera.as_ref())
        {
            Some(c) => {
                let p = |v: [f64; 3]| Point3::new(v[0], v[1], v[2]) * scale;
                let cam = match c.up {
                    None => Camera::looking_at(p(c.position), p(c.look_at)),
                    Some(up) => Camera::new(
                        p(c.position),
                        p(c.look_at),
                        nalgebra::Vector3::from(up),
                        crate::geometry::camera::DEFAULT_FOV_DEG,
                    ),
                }
                .map_err(|e| ModelError::Invalid(format!("registration.camera: {e}")))?;
                Some(cam)
            }
            None => None,
        };
        let coarse_factor = settings.coarse_to_fine;
        let mut session = Self::new(model, settings, scene_camera);
        if let Some(f) = coarse_factor {
            let mut coarse_scene = loaded.clone();
            coarse_scene.scene.grid.cell_size *= f;
            let coarse = SceneModel::build(&coarse_scene)
                .map_err(|e| ModelError::Invalid(format!("registration.coarse_to_fine: {e}")))?;
            session = session.with_coarse_start(coarse)?;
        }
        Ok(session)
    }

    /// Adds a coarse-to-fine start: cold frames are first registered on `coarse` (the same
    /// body on a coarser grid, SI units) and the fine registration starts from its
    /// prolongated displacement, with one stiff penalty step.
    pub fn with_coarse_start(mut self, coarse: SceneModel) -> Result<Self, ModelError> {
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
    /// one of a coarse-to-fine start (see [`super::memory_estimate`]).
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
    /// ([`ModelSize::rest_compliance_bytes`]) and its still window at its point cap
    /// ([`still_window_bytes`]). A rigid-only session (`settings.non_rigid`
    /// false) never factorises: its factors are not counted.
    pub fn memory_estimate_bytes(&self) -> Result<u64, String> {
        let mut sizes = self.model_sizes()?;
        let per_frame = if self.settings.non_rigid {
            sizes[0].rest_compliance_bytes()
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
    pub fn new(model: SceneModel, settings: SessionSettings, camera: Option<Camera>) -> Self {
        let u = vec![0.0; model.problem.dofs()];
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
            good: GoodState {
                u,
                model_to_cloud: RigidTransform::identity(),
                registered: false,
                cloud: None,
                contact_force: None,
                pose_ambiguous: false,
                pose_uncertainty: None,
                expected_error: None,
            },
            frames: 0,
            coarse: None,
            rigid_target: None,
            still: StillWindow::default(),
            rest_surface: std::sync::OnceLock::new(),
            surface_topology,
            good_surface: std::sync::OnceLock::new(),
            rest_compliance: None,
            fitted_pose_uncertainty: None,
        }
    }

    /// Forgets every frame: back to the rest shape and the identity pose; the next frame is
    /// registered cold.
    pub fn reset(&mut self) {
        self.good = GoodState {
            u: vec![0.0; self.model.problem.dofs()],
            model_to_cloud: RigidTransform::identity(),
            registered: false,
            cloud: None,
            contact_force: None,
            pose_ambiguous: false,
            pose_uncertainty: None,
            expected_error: None,
        };
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
        outcome: Result<Done, FrameError>,
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
        self.write_positions(&mut result);
        result.times.output_ms = ms(t);
        result.wall_ms = ms(start);
        result
    }

    /// A frame that succeeded: its pose flags and uncertainty, its expected error, and its
    /// state as the session's new good state, written into `result`.
    fn accept(&mut self, done: Done, result: &mut FrameResult) {
        let scale = self.model.length_scale;
        let held = self.good.registered && done.model_to_cloud == self.good.model_to_cloud;
        let (pose_ambiguous, pose_uncertainty) = self.pose_flags(held, result);
        let estimate = self.error_estimate(&done, pose_uncertainty);
        if estimate.expected > self.settings.max_expected_error {
            result.flags.push(FrameFlag::ExpectedErrorHigh);
        }
        result.expected_error = Some(scaled_estimate(&estimate, scale));
        if let Some(surface) = done.surface {
            self.good_surface = std::sync::OnceLock::from(Some(surface));
        } else if done.u != self.good.u {
            self.good_surface = std::sync::OnceLock::new();
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
        self.still = done.still;
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

    /// Whether the frame's pose is ambiguous and how uncertain it is (m), flagged in
    /// `result` (`pose_ambiguous`, `pose_uncertain`) with the uncertainty in scene units. A
    /// `held` pose keeps both from the frame that fitted it; a pose fitted anew without
    /// ambiguity clears them.
    fn pose_flags(&mut self, held: bool, result: &mut FrameResult) -> (bool, Option<f64>) {
        let searched_ambiguous = result.flags.contains(&FrameFlag::PoseAmbiguous);
        let pose_ambiguous = searched_ambiguous || (held && self.good.pose_ambiguous);
        if pose_ambiguous && !searched_ambiguous {
            result.flags.push(FrameFlag::PoseAmbiguous);
        }
        let fitted = self.fitted_pose_uncertainty.take();
        let pose_uncertainty = if held {
            self.good.pose_uncertainty
        } else {
            fitted
        };
        if pose_uncertainty.is_some_and(|v| v > self.settings.max_pose_uncertainty) {
            result.flags.push(FrameFlag::PoseUncertain);
        }
        result.pose_uncertainty = pose_uncertainty.map(|v| v / self.model.length_scale);
        (pose_ambiguous, pose_uncertainty)
    }

    /// The good state's (new or kept) surface, structures and contact force into `result`,
    /// in the cloud frame and scene units.
    fn write_positions(&self, result: &mut FrameResult) {
        let scale = self.model.length_scale;
        let pose = self.good.model_to_cloud;
        let out = |p: &Point3<f64>| pose.apply(p) / scale;
        result.surface = self
            .model
            .surface_embedding
            .positions(&self.good.u)
            .iter()
            .map(out)
            .collect();
        result.structures = self
            .model
            .structures
            .iter()
            .map(|s| {
                (
                    s.name.clone(),
                    s.embedding
                        .positions(&self.good.u)
                        .iter()
                        .map(out)
                        .collect(),
                )
            })
            .collect();
        result.contact_force = self.good.contact_force.map(|c| ContactForce {
            resultant: pose.apply_vector(&c.resultant),
            centre: out(&c.centre),
        });
    }

    /// The expected error of the frame `done` whose pose has the uncertainty
    /// `pose_uncertainty` (m): the evidence of [`ErrorEvidence`] from the registered
    /// displacement of the structures, the fit of the cloud and its noise, metres.
    fn error_estimate(&self, done: &Done, pose_uncertainty: Option<f64>) -> ErrorEstimate {
        let (mut sum, mut count) = (0.0, 0usize);
        for s in &self.model.structures {
            for d in s.embedding.interpolate(&done.u) {
                sum += d.norm_squared();
                count += 1;
            }
        }
        expected_error(&ErrorEvidence {
            pose_uncertainty: pose_uncertainty.unwrap_or(0.0),
            displacement_rms: (sum / count.max(1) as f64).sqrt(),
            fit_rms: done.fit_rms,
            noise: done.noise,
        })
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
        if report.deadline_reached {
            flags.push(FrameFlag::TimeBudget);
        }
        // A re-acquired pose must not need a new shape: measured on the phantom, a right
        // re-acquisition changes the surface by 0.2 mm RMS, ordinary frames by 0.8–1.6 mm,
        // and a 109° wrong minimum of rigid ICP by 25 mm (`tests/bad_frames.rs`).
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
        let contact_force = report
            .data_term
            .as_ref()
            .and_then(|springs| self.contact_force(springs, &u));
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

    /// The pose: held (checked, and searched again when it no longer fits) or tracked against
    /// the current deformed surface; the model → cloud transform and rigid ICP iterations.
    fn rigid_stage(
        &mut self,
        cloud: &[Point3<f64>],
        flags: &mut Vec<FrameFlag>,
    ) -> Result<(RigidTransform, usize), FrameError> {
        // Rigid stage: hold the pose, or track it against the current deformed surface.
        self.fitted_pose_uncertainty = None;
        let hold = self.settings.non_rigid
            && matches!(
                self.settings.pose_update,
                PoseUpdate::Hold | PoseUpdate::Follow
            )
            && self.settings.rigid_mode == RigidMode::Icp
            && self.good.registered;
        let (model_to_cloud, rigid_iterations) = if hold {
            let rms = self.held_pose_rms(cloud);
            if rms <= self.settings.pose_reacquire_rms {
                self.held_or_moved_pose(cloud, rms)?
            } else {
                flags.push(FrameFlag::PoseReacquired);
                self.reacquire_pose(cloud, rms, flags)?
            }
        } else {
            self.track_pose(cloud, self.good.model_to_cloud.inverse(), flags)?
        };
        Ok((model_to_cloud, rigid_iterations))
    }

    /// The held pose, or with [`PoseUpdate::Follow`] the pose rigid ICP finds from it against
    /// the last registered shape when the whole view moved: when the best-fitting half of the
    /// cloud ([`Session::best_half_rms`]) lies [`MOVED_VIEW_FIT_RATIO`] times closer to that
    /// shape at the fitted pose than at the held one, and closer by more than
    /// [`MOVED_VIEW_MIN_GAIN`].
    /// A deformation moves a part of the seen surface and leaves the best half where it was,
    /// so the held pose stays; a camera that moved shifts every point, which the elastic model
    /// would otherwise absorb frame after frame (a camera turning to 10° and moving 20 mm over
    /// 30 frames left the pose 22 mm off). `held_rms` (m): the held pose's whole fit.
    fn held_or_moved_pose(
        &mut self,
        cloud: &[Point3<f64>],
        held_rms: f64,
    ) -> Result<(RigidTransform, usize), FrameError> {
        let held = self.good.model_to_cloud;
        if self.settings.pose_update != PoseUpdate::Follow || held_rms <= MOVED_VIEW_MIN_GAIN {
            return Ok((held, 0));
        }
        let held_fit = self.best_half_rms(cloud, &held);
        if held_fit <= MOVED_VIEW_MIN_GAIN {
            return Ok((held, 0));
        }
        let mut no_flags = Vec::new();
        let fit = self.rigid_fit(cloud, held.inverse(), true, false, &mut no_flags)?;
        let moved_fit = self.best_half_rms(cloud, &fit.model_to_cloud);
        if moved_fit * MOVED_VIEW_FIT_RATIO < held_fit && held_fit - moved_fit > MOVED_VIEW_MIN_GAIN
        {
            self.fitted_pose_uncertainty = self.pose_uncertainty(&fit);
            Ok((fit.model_to_cloud, fit.iterations))
        } else {
            Ok((held, fit.iterations))
        }
    }

    /// RMS distance (m) of the half of `cloud` (metres, cloud frame) nearest the last
    /// registered shape at the model → cloud pose `model_to_cloud`.
    fn best_half_rms(&self, cloud: &[Point3<f64>], model_to_cloud: &RigidTransform) -> f64 {
        let Some(surface) = self.good_surface() else {
            return f64::INFINITY;
        };
        let mut d2: Vec<f64> = surface
            .signed_distances(&in_model_frame(cloud, model_to_cloud))
            .iter()
            .map(|d| d * d)
            .collect();
        if d2.is_empty() {
            return f64::INFINITY;
        }
        let half = d2.len().div_ceil(2);
        d2.select_nth_unstable_by(half - 1, f64::total_cmp);
        (d2[..half].iter().sum::<f64>() / half as f64).sqrt()
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

    /// The recovery ladder ([`recovery_ladder`]) after a first attempt that ended with
    /// `first_u` and `first` (a solver failure or a non-finite state): each rung registers
    /// the frame again from the last good state, with the scene's own material law, until one
    /// ends without a solver failure and with a finite state (flag `recovered:<rung>`; the
    /// first attempt's warnings are kept, prefixed [`BEFORE_RECOVERY`]). When none does, or
    /// the deadline passes first, the first attempt stands, flagged `recovery_failed`, with
    /// its warnings (the causes).
    #[allow(clippy::too_many_arguments)]
    fn recover(
        &mut self,
        first_u: Vec<f64>,
        first: NonRigidReport,
        data: &StillData,
        camera: Option<&Camera>,
        deadline: Option<Instant>,
        spent: &mut NonRigidTimings,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<(Vec<f64>, NonRigidReport), FrameError> {
        for rung in recovery_ladder(&self.settings.cold, &self.model.newton) {
            if deadline.is_some_and(|d| Instant::now() >= d) {
                break;
            }
            let settings = NonRigidSettings {
                data_weight: data.weight,
                cloud_noise: data.noise,
                ..rung.settings
            };
            let mut icp =
                NonRigidIcp::new(settings, rung.newton).with_normals(self.normals.clone());
            let mut u = self.good.u.clone();
            let r = icp
                .register(&mut self.model, &data.points, camera, &mut u, deadline)
                .map_err(|e| FrameError::NonRigid(e.to_string()))?;
            add_timings(spent, &r.timings);
            if !solver_failed(&r) && all_finite(&u) {
                flags.push(FrameFlag::Recovered(rung.name));
                let mut r = r;
                r.warnings = first
                    .warnings
                    .iter()
                    .map(|w| format!("{BEFORE_RECOVERY}{w}"))
                    .chain(r.warnings)
                    .collect();
                r.icp_iterations += first.icp_iterations;
                r.newton_iterations += first.newton_iterations;
                r.factorizations += first.factorizations;
                return Ok((u, r));
            }
        }
        flags.push(FrameFlag::RecoveryFailed);
        Ok((first_u, first))
    }
}

/// Prefix of the warnings of a failed attempt that a recovery then rescued.
pub const BEFORE_RECOVERY: &str = "before recovery: ";

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

    /// Rigid ICP of `cloud` (metres, cloud frame) to the current deformed surface from the
    /// last pose (or the identity fit when the rigid stage is off); rejects a cloud whose fit
    /// leaves an RMS above [`SessionSettings::max_rigid_rms`].
    fn track_pose(
        &mut self,
        cloud: &[Point3<f64>],
        start: RigidTransform,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<(RigidTransform, usize), FrameError> {
        // Frame to frame (rigid-only or tracked pose): the start is the last pose.
        let tracking = self.good.registered;
        let r = self.rigid_fit(cloud, start, tracking, !tracking, flags)?;
        // A fit stopped by its iteration cap says so (rigid ICP on a partial patch can stop
        // there 43–88° off).
        if r.iterations > 0 && !r.converged {
            flags.push(FrameFlag::RigidNotConverged);
        }
        let limit = if self.settings.non_rigid {
            self.settings.max_unregistered_rms
        } else {
            // Rigid-only: the rigid fit is the registration.
            self.settings.max_rigid_rms
        };
        if r.rms > limit {
            return Err(FrameError::NoMatch {
                rms_mm: r.rms * 1e3,
                limit_mm: limit * 1e3,
            });
        }
        self.fitted_pose_uncertainty = self.pose_uncertainty(&r);
        Ok((r.model_to_cloud, r.iterations))
    }

    /// The pose searched again when the held one no longer fits (its RMS `held_rms`, metres,
    /// is above [`SessionSettings::pose_reacquire_rms`]): rigid ICP from the held pose, and
    /// from the held pose shifted by the motion of the cloud's centroid since the last good
    /// frame (a bumped or moved camera, or a liver moved by more than ICP's basin of attraction:
    /// from the held pose alone, a 1 m jump ended in a wrong minimum turned by ~96° whose RMS
    /// passed the no-match limit). The converged fit with the smallest RMS wins. A re-acquired
    /// pose must have converged: if neither start converges below
    /// [`SessionSettings::max_rigid_rms`], the frame is rejected (`no-match`) and the session
    /// keeps its state, instead of committing a pose that may be wrong.
    fn reacquire_pose(
        &mut self,
        cloud: &[Point3<f64>],
        held_rms: f64,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<(RigidTransform, usize), FrameError> {
        let held = self.good.model_to_cloud.inverse();
        let mut starts = vec![held];
        if let Some(previous) = &self.good.cloud {
            let shift = centroid(cloud) - centroid(previous);
            if shift.norm() > 0.0 {
                let shifted = held.compose(&RigidTransform::from_translation(-shift));
                // The same view moved as a whole: at the shifted pose the cloud fits the model
                // as well as the last frame's cloud did at the held pose (plus the noise of a
                // new frame), and that pose is kept as it is. A view that also turned fits
                // worse, and is searched by ICP from there.
                let fit = self.pose_rms(previous, &self.good.model_to_cloud);
                let shifted_fit = self.pose_rms(cloud, &shifted.inverse());
                if shifted_fit <= SAME_VIEW_FIT_RATIO * fit + SAME_VIEW_FIT_SLACK {
                    return Ok((shifted.inverse(), 0));
                }
                starts.push(shifted);
            }
        }
        let mut best: Option<(IcpResult, Vec<FrameFlag>)> = None;
        let mut iterations = 0;
        let mut last_error = None;
        for start in starts {
            let mut start_flags = Vec::new();
            match self.rigid_fit(cloud, start, false, true, &mut start_flags) {
                Ok(r) => {
                    iterations += r.iterations;
                    let usable = r.converged && r.rms <= self.settings.max_rigid_rms;
                    if usable && best.as_ref().is_none_or(|(b, _)| r.rms < b.rms) {
                        best = Some((r, start_flags));
                    }
                }
                Err(e) => last_error = Some(e),
            }
        }
        match (best, last_error) {
            (Some((r, start_flags)), _) => {
                flags.extend(start_flags);
                self.fitted_pose_uncertainty = self.pose_uncertainty(&r);
                Ok((r.model_to_cloud, iterations))
            }
            (None, Some(e)) if iterations == 0 => Err(e),
            (None, _) => Err(FrameError::PoseLost {
                held_rms_mm: held_rms * 1e3,
                limit_mm: self.settings.max_rigid_rms * 1e3,
            }),
        }
    }

    /// The uncertainty of the pose fitted by `fit` (m): the 1σ misplacement of the model's
    /// rest surface, root mean square over its vertices, under the fit's own noise
    /// ([`PoseCovariance::rms_displacement_std`](crate::registration::PoseCovariance::rms_displacement_std)); `None` without a rigid stage
    /// (`rigid = "none"`: the pose is given) or when the fit did not determine the pose.
    fn pose_uncertainty(&self, fit: &IcpResult) -> Option<f64> {
        if self.settings.rigid_mode != RigidMode::Icp {
            return None;
        }
        fit.covariance
            .map(|c| c.rms_displacement_std(&self.model.surface.vertices))
    }

    /// The rigid target of the last good state's deformed surface, rebuilt when that state
    /// changed.
    fn rigid_target(&mut self) -> Result<&ModelTarget, FrameError> {
        let fresh = matches!(&self.rigid_target, Some((u, _)) if *u == self.good.u);
        if !fresh {
            let deformed = TriSurface::new(
                self.model.surface_embedding.positions(&self.good.u),
                self.model.surface.triangles.clone(),
            );
            let target = ModelTarget::new(&deformed, self.settings.target_spacing)
                .map_err(|e| FrameError::Rigid(e.to_string()))?;
            self.rigid_target = Some((self.good.u.clone(), target));
        }
        Ok(&self.rigid_target.as_ref().expect("built above").1)
    }

    /// Rigid ICP of `cloud` (metres, cloud frame) to the current deformed surface from the
    /// cloud → model motion `start`; `tracking` (the start is the last frame's pose) stops at
    /// [`SessionSettings::tracking_relative_tolerance`] if that is looser than the rigid
    /// settings' own. With `search` (a pose not known from the last frame: the first frame, a
    /// re-acquisition) and [`SessionSettings::pose_search`] set, the multi-start search runs
    /// around `start` ([`PoseSearch::search`](crate::registration::PoseSearch::search)) and flags `pose_searched` when it found a pose
    /// plain ICP from `start` missed, `pose_ambiguous` when the cloud fits two poses about as
    /// well.
    fn rigid_fit(
        &mut self,
        cloud: &[Point3<f64>],
        start: RigidTransform,
        tracking: bool,
        search: bool,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<IcpResult, FrameError> {
        // With no rigid stage the fit of the identity is still checked (0 iterations).
        let (icp, initial) = match self.settings.rigid_mode {
            RigidMode::Identity => (
                RigidIcp {
                    max_iterations: 0,
                    ..self.settings.rigid.clone()
                },
                RigidTransform::identity(),
            ),
            RigidMode::Icp => {
                let mut icp = self.settings.rigid.clone();
                if tracking {
                    icp.relative_tolerance = icp
                        .relative_tolerance
                        .max(self.settings.tracking_relative_tolerance);
                }
                (icp, start)
            }
        };
        let pose_search = match self.settings.rigid_mode {
            RigidMode::Icp if search => self.settings.pose_search.clone(),
            _ => None,
        };
        let target = self.rigid_target()?;
        match pose_search {
            Some(p) => {
                let found = p
                    .search(&icp, target, cloud, initial)
                    .map_err(|e| FrameError::Rigid(e.to_string()))?;
                if found.replaced_plain {
                    flags.push(FrameFlag::PoseSearched);
                }
                if found.ambiguous {
                    flags.push(FrameFlag::PoseAmbiguous);
                }
                let mut best = found.best;
                best.iterations = found.iterations;
                Ok(best)
            }
            None => icp
                .register(target, cloud, Some(initial))
                .map_err(|e| FrameError::Rigid(e.to_string())),
        }
    }

    /// RMS distance (metres) from the points of `cloud` (metres, cloud frame), taken to the
    /// model frame by the held pose, to the current deformed surface — measured to its
    /// closest point on the triangles, so the vertex spacing does not count — after the
    /// mean + 2σ outlier rule: how well the held pose still fits.
    fn held_pose_rms(&self, cloud: &[Point3<f64>]) -> f64 {
        self.pose_rms(cloud, &self.good.model_to_cloud)
    }

    /// [`Session::held_pose_rms`] at the model → cloud pose `model_to_cloud`.
    fn pose_rms(&self, cloud: &[Point3<f64>], model_to_cloud: &RigidTransform) -> f64 {
        let aligned = in_model_frame(cloud, model_to_cloud);
        self.good_surface()
            .map_or(f64::INFINITY, |s| s.fit_rms(&aligned))
    }

    /// The last good state's deformed surface index ([`Session::good_surface`]'s cache);
    /// `None` for an empty surface.
    fn good_surface(&self) -> Option<&SurfaceDistances> {
        self.good_surface
            .get_or_init(|| deformed_surface(&self.model, &self.surface_topology, &self.good.u))
            .as_ref()
    }

    /// The rest shape, kept without registering when it explains the frame's cloud
    /// (`aligned`, metres, model frame) within the cloud's own noise
    /// ([`SessionSettings::rest_test`]; flag `at_rest`): registering a liver at rest can only
    /// fit noise. `None` (register) otherwise. Returns the displacement (zero), the fit RMS
    /// (m) and a zero contact force.
    fn rest_shape_if_unchanged(
        &mut self,
        aligned: &[Point3<f64>],
        noise: Option<&CloudNoise>,
        flags: &mut Vec<FrameFlag>,
    ) -> Option<(Vec<f64>, f64, Option<ContactForce>)> {
        let test = self.settings.rest_test.clone()?;
        let noise = noise?;
        let rest = vec![0.0; self.good.u.len()];
        let d = self
            .rest_surface
            .get_or_init(|| deformed_surface(&self.model, &self.surface_topology, &rest))
            .as_ref()?
            .signed_distances(aligned);
        if test.evaluate_near(&noise.near, &d, noise.sigma).significant {
            return None;
        }
        flags.push(FrameFlag::AtRest);
        // The solvers' warm state belongs to the shape left behind.
        self.non_rigid_cold.invalidate();
        self.non_rigid_warm.invalidate();
        let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
        let force = ContactForce {
            resultant: nalgebra::Vector3::zeros(),
            centre: centroid(aligned),
        };
        Some((rest, rms, Some(force)))
    }

    /// The data of the non-rigid stage: the frame's cloud `aligned` (model frame, m) seen by
    /// `camera` joins the still window ([`StillWindow`]) when it shows the surface where the
    /// window's first cloud showed it, within its `noise` ([`Session::same_as_window`]; a warm
    /// frame, the same camera, [`SessionSettings::still_frames`] > 1),
    /// and the stage registers the window's union, each spring at `1/n` of its stiffness
    /// (flag `still:<n>` for `n` > 1). Otherwise the window starts again with this cloud.
    /// Returns the new window (the session keeps it only if the frame succeeds: a failed
    /// frame leaves no trace) and the data.
    fn still_frames(
        &self,
        aligned: &[Point3<f64>],
        camera: Option<Camera>,
        noise: Option<&CloudNoise>,
        flags: &mut Vec<FrameFlag>,
    ) -> (StillWindow, StillData) {
        let max_frames = self.settings.still_frames.max(1);
        let Some(noise) = noise else {
            // No noise measured (an empty cloud): alone, the window cleared.
            let data = StillData {
                points: aligned.to_vec(),
                weight: 1.0,
                noise: None,
            };
            return (StillWindow::default(), data);
        };
        // A new camera restarts the window in `admit` whatever the test says: the test (about
        // 1.5 ms) is made only for the window's own camera.
        let unchanged = max_frames > 1
            && self.good.registered
            && camera == self.still.camera()
            && self.same_as_window(noise);
        let mut still = self.still.clone();
        let n = still.admit(
            noise.points.clone(),
            camera,
            unchanged,
            max_frames,
            self.settings.max_cloud_points,
        );
        if n > 1 {
            flags.push(FrameFlag::Still(n));
        }
        let data = StillData {
            points: still.union(),
            weight: 1.0 / n as f64,
            noise: Some(noise.sigma).filter(|s| *s > 0.0),
        };
        (still, data)
    }

    /// Whether the frame's cloud (`noise`: the cloud, model frame, m, its neighbour lists and
    /// noise) shows the surface where the still window's first cloud showed it: both measured
    /// to the last good surface, their local medians compared
    /// ([`ChangeTest::evaluate_against`]). False without the test, a window or a surface.
    fn same_as_window(&self, noise: &CloudNoise) -> bool {
        let (Some(test), Some(first)) = (&self.settings.rest_test, self.still.first()) else {
            return false;
        };
        let Some(surface) = self.good_surface() else {
            return false;
        };
        let cloud = &noise.points.points;
        let first_near = test.neighbours_in(cloud, first);
        let d = surface.signed_distances(cloud);
        let d_first = surface.signed_distances(&first.points);
        !test
            .evaluate_against(&noise.near, &d, &first_near, &d_first, noise.sigma)
            .significant
    }
}

/// A re-acquired pose that is the held one shifted by the cloud centroid's motion is kept
/// without ICP when the cloud's fit there is at most this times the last frame's fit at the
/// held pose, plus [`SAME_VIEW_FIT_SLACK`].
const SAME_VIEW_FIT_RATIO: f64 = 1.2;
/// See [`SAME_VIEW_FIT_RATIO`], metres (a new frame's noise changes the fit by a fraction of
/// a millimetre).
const SAME_VIEW_FIT_SLACK: f64 = 0.5e-3;
/// With `pose = "follow"`, a held pose is replaced on a warm frame by rigid ICP's fit from it
/// when that fit leaves the best-fitting half of the cloud this many times closer to the last
/// registered shape ([`Session::held_or_moved_pose`]).
const MOVED_VIEW_FIT_RATIO: f64 = 2.0;
/// See [`MOVED_VIEW_FIT_RATIO`]: and closer by more than this, metres; a view that moved by
/// less is left to the elastic model, as a cloud's noise moves its fit by a fraction of a
/// millimetre.
const MOVED_VIEW_MIN_GAIN: f64 = 0.3e-3;

/// A frame's cloud with its own noise, for the tests of change
/// ([`Session::rest_shape_if_unchanged`], [`Session::still_frames`]) and the data term's
/// weight ([`NonRigidSettings::cloud_noise`]).
struct CloudNoise {
    /// The cloud, indexed (the still window keeps it).
    points: Arc<IndexedPoints>,
    /// [`ChangeTest::neighbours`] of each cloud point (empty without a test).
    near: Vec<Vec<usize>>,
    /// [`cloud_noise_sigma`](crate::registration::change_evidence::cloud_noise_sigma), m.
    sigma: f64,
}

impl CloudNoise {
    /// The noise of `aligned` (m) and its neighbours for `test` (none without a test);
    /// `None` for an empty cloud.
    fn measure(aligned: &[Point3<f64>], test: Option<&ChangeTest>) -> Option<Self> {
        let points = IndexedPoints::new(aligned.to_vec())?;
        let near = test.map_or_else(Vec::new, |t| t.neighbours(&points));
        // The test's neighbour lists (32 nearest) hold the estimator's 16: one search.
        let sigma = cloud_noise_sigma_near(&points, &near);
        Some(Self {
            points: Arc::new(points),
            near,
            sigma,
        })
    }
}

/// What the non-rigid stage registers: the points of the still window (model frame, m) and
/// the weight of each one's spring ([`NonRigidSettings::data_weight`]).
struct StillData {
    points: Vec<Point3<f64>>,
    weight: f64,
    /// The frame's cloud noise (m, [`cloud_noise_sigma`](crate::registration::change_evidence::cloud_noise_sigma)), which weakens the automatic
    /// penalty ramp ([`NonRigidSettings::cloud_noise`]); `None` when not measured.
    noise: Option<f64>,
}

/// A successful frame's new state and counters.
struct Done {
    u: Vec<f64>,
    model_to_cloud: RigidTransform,
    converged: bool,
    rigid_iterations: usize,
    icp_iterations: usize,
    newton_iterations: usize,
    factorizations: usize,
    surface_rms: f64,
    used_points: usize,
    cloud: Vec<Point3<f64>>,
    sources: usize,
    warnings: Vec<String>,
    contact_force: Option<ContactForce>,
    /// The still window with this frame's cloud (empty for a frame without the non-rigid
    /// stage): it replaces the session's when the frame succeeds.
    still: StillWindow,
    /// The surface index of `u` the frame's fit built (`None` when it built none): the next
    /// frame's [`Session::good_surface`].
    surface: Option<SurfaceDistances>,
    /// RMS distance of the cloud to the registered surface after the outlier rule, m.
    fit_rms: f64,
    /// The cloud's measured noise, m (0 when not measured).
    noise: f64,
}

impl Done {
    /// A frame that ends without the non-rigid stage (rigid only, or kept at rest): the shape
    /// `u` (m), the pose, the rigid iterations, the cloud (m, cloud frame), the fit RMS (m)
    /// and the contact force.
    fn without_non_rigid(
        u: Vec<f64>,
        model_to_cloud: RigidTransform,
        rigid_iterations: usize,
        cloud: Vec<Point3<f64>>,
        surface_rms: f64,
        contact_force: Option<ContactForce>,
    ) -> Self {
        Done {
            u,
            model_to_cloud,
            converged: true,
            rigid_iterations,
            icp_iterations: 0,
            newton_iterations: 0,
            factorizations: 0,
            surface_rms,
            used_points: cloud.len(),
            cloud,
            sources: 0,
            warnings: Vec::new(),
            contact_force,
            still: StillWindow::default(),
            surface: None,
            fit_rms: surface_rms,
            noise: 0.0,
        }
    }
}

/// Whether the Newton solver reported a failure (diverged, inverted, iteration cap) during
/// a non-rigid registration.
fn solver_failed(r: &NonRigidReport) -> bool {
    !r.warnings.is_empty()
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

/// The first recovery attempt's settings: the cold ramp with twice its steps (at least 6), so
/// each penalty increment is smaller, and fresh factorisations at every Newton step.
pub fn recovery_settings(cold: &NonRigidSettings) -> NonRigidSettings {
    NonRigidSettings {
        penalty_steps: (2 * cold.penalty_steps).max(6),
        factor_reuse: 1,
        visibility_interval: 1,
        ..*cold
    }
}

/// One rung of the recovery ladder: the frame registered again from the last good state with
/// these settings; the material law is always the scene's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecoveryRung {
    /// Name in the frame's flag `recovered:<name>`.
    pub name: &'static str,
    /// Settings of the non-rigid stage for this attempt.
    pub settings: NonRigidSettings,
    /// Settings of its Newton solver.
    pub newton: NewtonSettings,
}

/// The recovery ladder of a session whose cold frames use `cold` and whose model solves with
/// `newton`, in order:
/// 1. `smaller-steps`: [`recovery_settings`] (twice the cold ramp's steps, at least 6, a
///    fresh factorisation at every Newton step) with the scene's solver;
/// 2. `damped-newton`: four times the cold ramp's steps (at least 12), fresh factorisations,
///    and [`damped_newton`]: a direct factorisation whose indefinite tangent is damped
///    (Levenberg–Marquardt diagonal shift), so every step is a descent direction and the line
///    search on the energy always finds a decrease that keeps every cell uninverted.
///
/// Both rungs keep the scene's material law: what fails on such frames is the linear solve,
/// not the law. With Jacobi-CG, the exact (indefinite) neo-Hookean, Mooney–Rivlin and SVK
/// tangents stop CG ("matrix is not positive definite"), while the corotated law's projected
/// tangent does not; swapping in that law would register another law's answer. The damped
/// direct solve rescues those frames with the scene's law (`src/session/tests.rs`,
/// `the_recovery_keeps_the_scenes_law`).
pub fn recovery_ladder(cold: &NonRigidSettings, newton: &NewtonSettings) -> [RecoveryRung; 2] {
    let smaller = recovery_settings(cold);
    [
        RecoveryRung {
            name: "smaller-steps",
            settings: smaller,
            newton: *newton,
        },
        RecoveryRung {
            name: "damped-newton",
            settings: NonRigidSettings {
                penalty_steps: (4 * cold.penalty_steps).max(12),
                ..smaller
            },
            newton: damped_newton(newton),
        },
    ]
}

/// `newton` made robust for a recovery: a direct sparse Cholesky factorisation that, on an
/// indefinite tangent, raises its diagonal until it factorises (Levenberg–Marquardt; never the
/// explicitly indefinite LDLᵀ or Jacobi-CG, which stops on an indefinite matrix), the
/// projected tangent (positive semi-definite for the corotated law), the energy line search,
/// and double precision throughout.
pub fn damped_newton(newton: &NewtonSettings) -> NewtonSettings {
    NewtonSettings {
        linear_solver: SolverKind::Cholesky,
        projected_tangent: true,
        line_search: true,
        mixed_precision: false,
        ..*newton
    }
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

/// `cloud` (cloud frame) taken to the model frame by the inverse of `model_to_cloud`.
fn in_model_frame(cloud: &[Point3<f64>], model_to_cloud: &RigidTransform) -> Vec<Point3<f64>> {
    let to_model = model_to_cloud.inverse();
    cloud.iter().map(|p| to_model.apply(p)).collect()
}

/// `e` (m) in scene units (`scale`: metres per scene unit).
fn scaled_estimate(e: &ErrorEstimate, scale: f64) -> ErrorEstimate {
    ErrorEstimate {
        expected: e.expected / scale,
        pose: e.pose / scale,
        unseen: e.unseen / scale,
        residual: e.residual / scale,
    }
}
