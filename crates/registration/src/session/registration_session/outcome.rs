//! A frame's outcome made its result: the good state it leaves, its flags, its expected
//! error and the positions it reports.

use super::*;

impl Session {
    /// The result of frame `source` (`received` points, started at `start`, with its stage
    /// `times` and `flags`) from its `outcome`: a success becomes the session's good state
    /// ([`Session::accept`]); a failure leaves the state as it was, flagged `failed` with its
    /// cause. Either way the result carries the good state's positions.
    pub(super) fn finish(
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
    pub(super) fn accept(&mut self, done: Done, result: &mut FrameResult) {
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
    pub(super) fn pose_flags(
        &mut self,
        held: bool,
        result: &mut FrameResult,
    ) -> (bool, Option<f64>) {
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
    pub(super) fn write_positions(&self, result: &mut FrameResult) {
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
    pub(super) fn error_estimate(
        &self,
        done: &Done,
        pose_uncertainty: Option<f64>,
    ) -> ErrorEstimate {
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
}

/// A successful frame's new state and counters.
pub(super) struct Done {
    pub(super) u: Vec<f64>,
    pub(super) model_to_cloud: RigidTransform,
    pub(super) converged: bool,
    pub(super) rigid_iterations: usize,
    pub(super) icp_iterations: usize,
    pub(super) newton_iterations: usize,
    pub(super) factorizations: usize,
    pub(super) surface_rms: f64,
    pub(super) used_points: usize,
    pub(super) cloud: Vec<Point3<f64>>,
    pub(super) sources: usize,
    pub(super) warnings: Vec<String>,
    pub(super) contact_force: Option<ContactForce>,
    /// The still window with this frame's cloud (empty for a frame without the non-rigid
    /// stage): it replaces the session's when the frame succeeds.
    pub(super) still: StillWindow,
    /// The surface index of `u` the frame's fit built (`None` when it built none): the next
    /// frame's [`Session::good_surface`].
    pub(super) surface: Option<SurfaceDistances>,
    /// RMS distance of the cloud to the registered surface after the outlier rule, m.
    pub(super) fit_rms: f64,
    /// The cloud's measured noise, m (0 when not measured).
    pub(super) noise: f64,
}

impl Done {
    /// A frame that ends without the non-rigid stage (rigid only, or kept at rest): the shape
    /// `u` (m), the pose, the rigid iterations, the cloud (m, cloud frame), the fit RMS (m)
    /// and the contact force.
    pub(super) fn without_non_rigid(
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

/// `e` (m) in scene units (`scale`: metres per scene unit).
pub(super) fn scaled_estimate(e: &ErrorEstimate, scale: f64) -> ErrorEstimate {
    ErrorEstimate {
        expected: e.expected / scale,
        pose: e.pose / scale,
        unseen: e.unseen / scale,
        residual: e.residual / scale,
    }
}
