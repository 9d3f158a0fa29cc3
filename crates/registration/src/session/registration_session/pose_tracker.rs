//! [`PoseTracker`]: the session's pose, held, followed or tracked, searched again when it
//! stops fitting, and how uncertain it is (docs/pose.md).

use nalgebra::Point3;

use super::super::frame::{FrameError, FrameResult};
use super::super::frame_flag::FrameFlag;
use super::super::settings::{PoseUpdate, RigidMode, SessionSettings};
use super::good_state::GoodState;
use super::session_view::SessionView;
use crate::geometry::Camera;
use crate::mesh::TriSurface;
use crate::registration::pose_search::centroid;
use crate::registration::{IcpResult, ModelTarget, RigidIcp, RigidTransform};

/// The model → cloud pose from frame to frame: held (checked against the last registered
/// shape, and searched again when it no longer fits), followed or tracked by rigid ICP, with
/// the pose's uncertainty (m) when a frame fitted it. Clouds are in metres, cloud frame; the
/// scene's camera and the rigid target in metres, model frame.
pub(super) struct PoseTracker {
    /// The scene's camera in the model frame, metres: used when a frame brings none.
    scene_camera: Option<Camera>,
    /// The rigid stage's target (samples and k-d tree of the deformed surface) and the
    /// displacement (m) it was built for: rebuilt only when the good state changed, so
    /// rigid-only sessions (the state never changes) build it once.
    rigid_target: Option<(Vec<f64>, ModelTarget)>,
    /// The uncertainty (m) of a pose fitted by this frame's rigid stage; `None` when the
    /// stage held the pose or fitted none.
    fitted_uncertainty: Option<f64>,
}

impl PoseTracker {
    /// A tracker with the scene's `camera` (model frame, metres), no pose fitted yet.
    pub(super) fn new(camera: Option<Camera>) -> Self {
        Self {
            scene_camera: camera,
            rigid_target: None,
            fitted_uncertainty: None,
        }
    }

    /// The camera of a frame in the model frame, metres: the frame's own `camera` (cloud
    /// frame, scene units; `scale`: metres per scene unit) moved by `cloud_to_model`, else the
    /// scene's.
    pub(super) fn camera(
        &self,
        camera: Option<&Camera>,
        scale: f64,
        cloud_to_model: &RigidTransform,
    ) -> Result<Option<Camera>, FrameError> {
        Ok(match camera {
            Some(c) => Some(camera_to_model(c, scale, cloud_to_model)?),
            None => self.scene_camera,
        })
    }

    /// The pose: held (checked, and searched again when it no longer fits) or tracked against
    /// the current deformed surface; the model → cloud transform and rigid ICP iterations.
    pub(super) fn rigid_stage(
        &mut self,
        view: &SessionView<'_>,
        cloud: &[Point3<f64>],
        flags: &mut Vec<FrameFlag>,
    ) -> Result<(RigidTransform, usize), FrameError> {
        // Rigid stage: hold the pose, or track it against the current deformed surface.
        self.fitted_uncertainty = None;
        let settings = view.settings;
        let hold = settings.non_rigid
            && matches!(settings.pose_update, PoseUpdate::Hold | PoseUpdate::Follow)
            && settings.rigid_mode == RigidMode::Icp
            && view.good.registered;
        let (model_to_cloud, rigid_iterations) = if hold {
            let rms = held_pose_rms(view, cloud);
            if rms <= settings.pose_reacquire_rms {
                self.held_or_moved_pose(view, cloud, rms)?
            } else {
                flags.push(FrameFlag::PoseReacquired);
                self.reacquire_pose(view, cloud, rms, flags)?
            }
        } else {
            self.track_pose(view, cloud, view.good.model_to_cloud.inverse(), flags)?
        };
        Ok((model_to_cloud, rigid_iterations))
    }

    /// The held pose, or with [`PoseUpdate::Follow`] the pose rigid ICP finds from it against
    /// the last registered shape when the whole view moved: when the best-fitting half of the
    /// cloud ([`best_half_rms`]) lies [`MOVED_VIEW_FIT_RATIO`] times closer to that
    /// shape at the fitted pose than at the held one, and closer by more than
    /// [`MOVED_VIEW_MIN_GAIN`].
    /// A deformation moves a part of the seen surface and leaves the best half where it was,
    /// so the held pose stays; a camera that moved shifts every point, which the elastic model
    /// would otherwise absorb frame after frame (a camera turning to 10° and moving 20 mm over
    /// 30 frames left the pose 22 mm off). `held_rms` (m): the held pose's whole fit.
    pub(super) fn held_or_moved_pose(
        &mut self,
        view: &SessionView<'_>,
        cloud: &[Point3<f64>],
        held_rms: f64,
    ) -> Result<(RigidTransform, usize), FrameError> {
        let held = view.good.model_to_cloud;
        if view.settings.pose_update != PoseUpdate::Follow || held_rms <= MOVED_VIEW_MIN_GAIN {
            return Ok((held, 0));
        }
        let held_fit = best_half_rms(view, cloud, &held);
        if held_fit <= MOVED_VIEW_MIN_GAIN {
            return Ok((held, 0));
        }
        let mut no_flags = Vec::new();
        let fit = self.rigid_fit(view, cloud, held.inverse(), true, false, &mut no_flags)?;
        let moved_fit = best_half_rms(view, cloud, &fit.model_to_cloud);
        if moved_fit * MOVED_VIEW_FIT_RATIO < held_fit && held_fit - moved_fit > MOVED_VIEW_MIN_GAIN
        {
            self.fitted_uncertainty = fitted_pose_uncertainty(view, &fit);
            Ok((fit.model_to_cloud, fit.iterations))
        } else {
            Ok((held, fit.iterations))
        }
    }

    /// Rigid ICP of `cloud` (metres, cloud frame) to the current deformed surface from the
    /// last pose (or the identity fit when the rigid stage is off); rejects a cloud whose fit
    /// leaves an RMS above [`SessionSettings::max_rigid_rms`].
    pub(super) fn track_pose(
        &mut self,
        view: &SessionView<'_>,
        cloud: &[Point3<f64>],
        start: RigidTransform,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<(RigidTransform, usize), FrameError> {
        // Frame to frame (rigid-only or tracked pose): the start is the last pose.
        let tracking = view.good.registered;
        let r = self.rigid_fit(view, cloud, start, tracking, !tracking, flags)?;
        // A fit stopped by its iteration cap says so (rigid ICP on a partial patch can stop
        // there 43–88° off).
        if r.iterations > 0 && !r.converged {
            flags.push(FrameFlag::RigidNotConverged);
        }
        let limit = if view.settings.non_rigid {
            view.settings.max_unregistered_rms
        } else {
            // Rigid-only: the rigid fit is the registration.
            view.settings.max_rigid_rms
        };
        if r.rms > limit {
            return Err(FrameError::NoMatch {
                rms_mm: r.rms * 1e3,
                limit_mm: limit * 1e3,
            });
        }
        self.fitted_uncertainty = fitted_pose_uncertainty(view, &r);
        Ok((r.model_to_cloud, r.iterations))
    }

    /// The pose searched again when the held one no longer fits (its RMS `held_rms`, metres,
    /// is above [`SessionSettings::pose_reacquire_rms`]): rigid ICP from the held pose, and
    /// from the held pose shifted by the motion of the cloud's centroid since the last good
    /// frame (a bumped or moved camera, or a liver moved by more than ICP's basin of attraction:
    /// from the held pose alone, a 1 m jump ended in a wrong minimum turned by ~96° whose RMS
    /// passed the no-match limit). The fit with the smallest RMS wins among the usable ones:
    /// below [`SessionSettings::max_rigid_rms`], and either converged or fitting the cloud as
    /// well as the last good frame's cloud fitted the held pose (at most
    /// [`SAME_VIEW_FIT_RATIO`] times that fit plus [`SAME_VIEW_FIT_SLACK`], the evidence that
    /// keeps a centroid-shifted pose without ICP). A deformed cloud against the last
    /// registered shape can leave ICP creeping at the right pose until its iteration cap
    /// (0.9 mm RMS after 50 iterations on the phantom turned by 10°), while a wrong minimum
    /// fits far worse than the last frame. When no start gives a usable fit the frame is
    /// rejected (`no-match`) and the session keeps its state, instead of committing a pose
    /// that may be wrong.
    pub(super) fn reacquire_pose(
        &mut self,
        view: &SessionView<'_>,
        cloud: &[Point3<f64>],
        held_rms: f64,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<(RigidTransform, usize), FrameError> {
        let held = view.good.model_to_cloud.inverse();
        let mut starts = vec![held];
        // How well the last good frame's cloud fitted the held pose (m).
        let last_fit = view
            .good
            .cloud
            .as_ref()
            .map(|previous| pose_rms(view, previous, &view.good.model_to_cloud));
        let fits_as_well = |model_to_cloud: &RigidTransform| {
            last_fit.is_some_and(|fit| {
                pose_rms(view, cloud, model_to_cloud)
                    <= SAME_VIEW_FIT_RATIO * fit + SAME_VIEW_FIT_SLACK
            })
        };
        if let Some(previous) = &view.good.cloud {
            let shift = centroid(cloud) - centroid(previous);
            if shift.norm() > 0.0 {
                let shifted = held.compose(&RigidTransform::from_translation(-shift));
                // The same view moved as a whole: at the shifted pose the cloud fits the model
                // as well as the last frame's cloud did at the held pose (plus the noise of a
                // new frame), and that pose is kept as it is. A view that also turned fits
                // worse, and is searched by ICP from there.
                if fits_as_well(&shifted.inverse()) {
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
            match self.rigid_fit(view, cloud, start, false, true, &mut start_flags) {
                Ok(r) => {
                    iterations += r.iterations;
                    let usable = r.rms <= view.settings.max_rigid_rms
                        && (r.converged || fits_as_well(&r.model_to_cloud));
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
                self.fitted_uncertainty = fitted_pose_uncertainty(view, &r);
                Ok((r.model_to_cloud, iterations))
            }
            (None, Some(e)) if iterations == 0 => Err(e),
            (None, _) => Err(FrameError::PoseLost {
                held_rms_mm: held_rms * 1e3,
                limit_mm: view.settings.max_rigid_rms * 1e3,
            }),
        }
    }

    /// The rigid target of the last good state's deformed surface, rebuilt when that state
    /// changed.
    fn rigid_target(&mut self, view: &SessionView<'_>) -> Result<&ModelTarget, FrameError> {
        let fresh = matches!(&self.rigid_target, Some((u, _)) if *u == view.good.u);
        if !fresh {
            let deformed = TriSurface::new(
                view.model.surface_embedding.positions(&view.good.u),
                view.model.surface.triangles.clone(),
            );
            let target = ModelTarget::new(&deformed, view.settings.target_spacing)
                .map_err(|e| FrameError::Rigid(e.to_string()))?;
            self.rigid_target = Some((view.good.u.clone(), target));
        }
        Ok(&self.rigid_target.as_ref().expect("built above").1)
    }

    /// Rigid ICP of `cloud` (metres, cloud frame) to the current deformed surface from the
    /// cloud → model motion `start`; `tracking` (the start is the last frame's pose) stops at
    /// [`SessionSettings::tracking_relative_tolerance`] if that is looser than the rigid
    /// settings' own. With `search` (a pose not known from the last frame: the first frame, a
    /// re-acquisition) and [`SessionSettings::pose_search`] set, the multi-start search runs
    /// around `start` ([`PoseSearch::search`](crate::registration::PoseSearch::search)) and
    /// flags `pose_searched` when it found a pose plain ICP from `start` missed,
    /// `pose_ambiguous` when the cloud fits two poses about as well.
    fn rigid_fit(
        &mut self,
        view: &SessionView<'_>,
        cloud: &[Point3<f64>],
        start: RigidTransform,
        tracking: bool,
        search: bool,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<IcpResult, FrameError> {
        let settings = view.settings;
        // With no rigid stage the fit of the identity is still checked (0 iterations).
        let (icp, initial) = match settings.rigid_mode {
            RigidMode::Identity => (
                RigidIcp {
                    max_iterations: 0,
                    ..settings.rigid.clone()
                },
                RigidTransform::identity(),
            ),
            RigidMode::Icp => {
                let mut icp = settings.rigid.clone();
                if tracking {
                    icp.relative_tolerance = icp
                        .relative_tolerance
                        .max(settings.tracking_relative_tolerance);
                }
                (icp, start)
            }
        };
        let pose_search = match settings.rigid_mode {
            RigidMode::Icp if search => settings.pose_search.clone(),
            _ => None,
        };
        let target = self.rigid_target(view)?;
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

    /// Whether the frame's pose is ambiguous and how uncertain it is (m), flagged in
    /// `result` (`pose_ambiguous`, `pose_uncertain`, against `settings`) with the uncertainty
    /// in scene units (`scale`: metres per scene unit). A `held` pose keeps both from the
    /// frame that fitted it (of the `good` state); a pose fitted anew without ambiguity clears
    /// them.
    pub(super) fn pose_flags(
        &mut self,
        settings: &SessionSettings,
        scale: f64,
        good: &GoodState,
        held: bool,
        result: &mut FrameResult,
    ) -> (bool, Option<f64>) {
        let searched_ambiguous = result.flags.contains(&FrameFlag::PoseAmbiguous);
        let pose_ambiguous = searched_ambiguous || (held && good.pose_ambiguous);
        if pose_ambiguous && !searched_ambiguous {
            result.flags.push(FrameFlag::PoseAmbiguous);
        }
        let fitted = self.fitted_uncertainty.take();
        let pose_uncertainty = if held { good.pose_uncertainty } else { fitted };
        if pose_uncertainty.is_some_and(|v| v > settings.max_pose_uncertainty) {
            result.flags.push(FrameFlag::PoseUncertain);
        }
        result.pose_uncertainty = pose_uncertainty.map(|v| v / scale);
        (pose_ambiguous, pose_uncertainty)
    }
}

/// The uncertainty of the pose fitted by `fit` (m): the 1σ misplacement of the model's
/// rest surface, root mean square over its vertices, under the fit's own noise
/// ([`PoseCovariance::rms_displacement_std`](crate::registration::PoseCovariance::rms_displacement_std));
/// `None` without a rigid stage (`rigid = "none"`: the pose is given) or when the fit did not
/// determine the pose.
pub(super) fn fitted_pose_uncertainty(view: &SessionView<'_>, fit: &IcpResult) -> Option<f64> {
    if view.settings.rigid_mode != RigidMode::Icp {
        return None;
    }
    fit.covariance
        .map(|c| c.rms_displacement_std(&view.model.surface.vertices))
}

/// RMS distance (m) of the half of `cloud` (metres, cloud frame) nearest the last
/// registered shape at the model → cloud pose `model_to_cloud`.
fn best_half_rms(
    view: &SessionView<'_>,
    cloud: &[Point3<f64>],
    model_to_cloud: &RigidTransform,
) -> f64 {
    let Some(surface) = view.good_surface() else {
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

/// RMS distance (metres) from the points of `cloud` (metres, cloud frame), taken to the
/// model frame by the held pose, to the current deformed surface — measured to its
/// closest point on the triangles, so the vertex spacing does not count — after the
/// mean + 2σ outlier rule: how well the held pose still fits.
fn held_pose_rms(view: &SessionView<'_>, cloud: &[Point3<f64>]) -> f64 {
    pose_rms(view, cloud, &view.good.model_to_cloud)
}

/// [`held_pose_rms`] at the model → cloud pose `model_to_cloud`.
fn pose_rms(view: &SessionView<'_>, cloud: &[Point3<f64>], model_to_cloud: &RigidTransform) -> f64 {
    let aligned = in_model_frame(cloud, model_to_cloud);
    view.good_surface()
        .map_or(f64::INFINITY, |s| s.fit_rms(&aligned))
}

/// With `pose = "follow"`, a held pose is replaced on a warm frame by rigid ICP's fit from it
/// when that fit leaves the best-fitting half of the cloud this many times closer to the last
/// registered shape ([`PoseTracker::held_or_moved_pose`]).
const MOVED_VIEW_FIT_RATIO: f64 = 2.0;

/// See [`MOVED_VIEW_FIT_RATIO`]: and closer by more than this, metres; a view that moved by
/// less is left to the elastic model, as a cloud's noise moves its fit by a fraction of a
/// millimetre.
const MOVED_VIEW_MIN_GAIN: f64 = 0.3e-3;

/// A re-acquired pose that is the held one shifted by the cloud centroid's motion is kept
/// without ICP, and an ICP fit that stopped at its iteration cap is usable, when the cloud's
/// fit there is at most this times the last frame's fit at the held pose, plus
/// [`SAME_VIEW_FIT_SLACK`].
const SAME_VIEW_FIT_RATIO: f64 = 1.2;

/// See [`SAME_VIEW_FIT_RATIO`], metres (a new frame's noise changes the fit by a fraction of
/// a millimetre).
const SAME_VIEW_FIT_SLACK: f64 = 0.5e-3;

/// `cloud` (cloud frame) taken to the model frame by the inverse of `model_to_cloud`.
fn in_model_frame(cloud: &[Point3<f64>], model_to_cloud: &RigidTransform) -> Vec<Point3<f64>> {
    let to_model = model_to_cloud.inverse();
    cloud.iter().map(|p| to_model.apply(p)).collect()
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
