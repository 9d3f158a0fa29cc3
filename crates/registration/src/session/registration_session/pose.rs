//! The session's pose: held, followed or tracked, searched again when it stops fitting, and
//! how uncertain it is (docs/pose.md).

use super::*;

impl Session {
    /// The pose: held (checked, and searched again when it no longer fits) or tracked against
    /// the current deformed surface; the model → cloud transform and rigid ICP iterations.
    pub(super) fn rigid_stage(
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
    pub(super) fn held_or_moved_pose(
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
    pub(super) fn best_half_rms(
        &self,
        cloud: &[Point3<f64>],
        model_to_cloud: &RigidTransform,
    ) -> f64 {
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

    /// Rigid ICP of `cloud` (metres, cloud frame) to the current deformed surface from the
    /// last pose (or the identity fit when the rigid stage is off); rejects a cloud whose fit
    /// leaves an RMS above [`SessionSettings::max_rigid_rms`].
    pub(super) fn track_pose(
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
    pub(super) fn reacquire_pose(
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
    pub(super) fn pose_uncertainty(&self, fit: &IcpResult) -> Option<f64> {
        if self.settings.rigid_mode != RigidMode::Icp {
            return None;
        }
        fit.covariance
            .map(|c| c.rms_displacement_std(&self.model.surface.vertices))
    }

    /// The rigid target of the last good state's deformed surface, rebuilt when that state
    /// changed.
    pub(super) fn rigid_target(&mut self) -> Result<&ModelTarget, FrameError> {
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
    pub(super) fn rigid_fit(
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
    pub(super) fn held_pose_rms(&self, cloud: &[Point3<f64>]) -> f64 {
        self.pose_rms(cloud, &self.good.model_to_cloud)
    }

    /// [`Session::held_pose_rms`] at the model → cloud pose `model_to_cloud`.
    pub(super) fn pose_rms(&self, cloud: &[Point3<f64>], model_to_cloud: &RigidTransform) -> f64 {
        let aligned = in_model_frame(cloud, model_to_cloud);
        self.good_surface()
            .map_or(f64::INFINITY, |s| s.fit_rms(&aligned))
    }
}

/// With `pose = "follow"`, a held pose is replaced on a warm frame by rigid ICP's fit from it
/// when that fit leaves the best-fitting half of the cloud this many times closer to the last
/// registered shape ([`Session::held_or_moved_pose`]).
pub(super) const MOVED_VIEW_FIT_RATIO: f64 = 2.0;

/// See [`MOVED_VIEW_FIT_RATIO`]: and closer by more than this, metres; a view that moved by
/// less is left to the elastic model, as a cloud's noise moves its fit by a fraction of a
/// millimetre.
pub(super) const MOVED_VIEW_MIN_GAIN: f64 = 0.3e-3;

/// `cloud` (cloud frame) taken to the model frame by the inverse of `model_to_cloud`.
pub(super) fn in_model_frame(
    cloud: &[Point3<f64>],
    model_to_cloud: &RigidTransform,
) -> Vec<Point3<f64>> {
    let to_model = model_to_cloud.inverse();
    cloud.iter().map(|p| to_model.apply(p)).collect()
}
