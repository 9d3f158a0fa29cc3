//! [`NonRigidStage`]: the frame's shape, registered by the biomechanical non-rigid ICP.

use std::sync::Arc;
use std::time::Instant;

use super::super::frame::FrameError;
use super::super::frame_flag::FrameFlag;
use super::super::settings::SessionSettings;
use super::coarse_start::CoarseStart;
use super::recovery_ladder::{recover, solver_failed};
use super::still_data::StillData;
use crate::geometry::Camera;
use crate::model::{Model, ModelError};
use crate::registration::non_rigid_icp::{NonRigidReport, NonRigidTimings};
use crate::registration::surface_normals::NormalsAtScale;
use crate::registration::{NonRigidIcp, NonRigidSettings};

/// The non-rigid stage of a frame: the displacement field (grid displacements, m) that fits
/// the still window's clouds (model frame, m), registered from the last good state with the
/// cold settings on a cold frame (after the coarse-to-fine start, when there is one) and the
/// warm settings after, then, when the solver failed, again up the recovery ladder
/// ([`recovery_ladder`](super::recovery_ladder::recovery_ladder)). Keeps each stage's solver
/// (its factorisation and visible set) from frame to frame.
pub(super) struct NonRigidStage {
    /// The stage of cold frames.
    cold: NonRigidIcp,
    /// The stage of warm frames.
    warm: NonRigidIcp,
    /// The coarse-to-fine start of cold frames, if any.
    coarse: Option<CoarseStart>,
    /// The surface normals' averaging every stage shares (`None`: vertex normals).
    normals: Option<Arc<NormalsAtScale>>,
}

impl NonRigidStage {
    /// The stage of `model` with `settings`' cold and warm settings.
    pub(super) fn new(model: &Model, settings: &SessionSettings) -> Self {
        // One averaging of the surface normals for every stage (cold, warm, coarse, recovery).
        let normals = settings
            .cold
            .normal_scale
            .build(&model.surface.vertices, &model.surface.triangles)
            .map(Arc::new);
        Self {
            cold: NonRigidIcp::new(settings.cold, model.newton).with_normals(normals.clone()),
            warm: NonRigidIcp::new(settings.warm, model.newton).with_normals(normals.clone()),
            coarse: None,
            normals,
        }
    }

    /// Adds a coarse-to-fine start on `coarse` (the same body as `fine` on a coarser grid, SI
    /// units), registered with the `cold` settings.
    pub(super) fn add_coarse_start(
        &mut self,
        coarse: Model,
        fine: &Model,
        cold: NonRigidSettings,
    ) -> Result<(), ModelError> {
        self.coarse = Some(CoarseStart::new(coarse, fine, cold, self.normals.clone())?);
        Ok(())
    }

    /// The coarse model of the coarse-to-fine start, if any.
    pub(super) fn coarse_model(&self) -> Option<&Model> {
        self.coarse.as_ref().map(CoarseStart::model)
    }

    /// Heap bytes of the shared surface normals' averaging (0 without one).
    pub(super) fn normal_bytes(&self) -> usize {
        self.normals.as_ref().map_or(0, |n| n.heap_bytes())
    }

    /// Forgets the cold and warm stages' kept factorisations and visible sets: they belong to
    /// a shape no longer registered.
    pub(super) fn invalidate(&mut self) {
        self.cold.invalidate();
        self.warm.invalidate();
    }

    /// [`NonRigidStage::invalidate`], and the coarse start's too.
    pub(super) fn reset(&mut self) {
        self.invalidate();
        if let Some(c) = &mut self.coarse {
            c.invalidate();
        }
    }

    /// The non-rigid stage of a frame (`data`: the clouds of the still window, model frame,
    /// metres, with their springs' weight) on `model` from the last good displacement `good_u`
    /// (m), `warm` when a frame has succeeded since the start or the last reset: the
    /// coarse-to-fine start of a cold frame, the registration from the last good state, and the
    /// recovery ladder when the solver failed (flags `coarse_start`, `recovered:…`,
    /// `recovery_failed`). Returns the displacement, the report and the time spent by stage.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn register(
        &mut self,
        model: &mut Model,
        session: &SessionSettings,
        good_u: &[f64],
        warm: bool,
        data: &StillData,
        camera: Option<&Camera>,
        deadline: Option<Instant>,
        flags: &mut Vec<FrameFlag>,
    ) -> Result<(Vec<f64>, NonRigidReport, NonRigidTimings), FrameError> {
        let aligned = &data.points[..];
        let mut settings = if warm { session.warm } else { session.cold };
        settings.data_weight = data.weight;
        settings.cloud_noise = data.noise;
        // Coarse-to-fine start of a cold frame: the coarse registration's field, prolongated,
        // is the fine stage's start, which then needs only the stiff end of the ramp.
        let mut start_u = None;
        let mut coarse_counts = (0, 0, 0);
        let mut spent = NonRigidTimings::default();
        if !warm {
            if let Some(c) = &mut self.coarse {
                if let Some((u, counts)) = c.start(session.cold, data, camera, deadline, &mut spent)
                {
                    start_u = Some(u);
                    settings.penalty_steps = 1;
                    coarse_counts = counts;
                    flags.push(FrameFlag::CoarseStart);
                }
            }
        }
        let start = start_u.unwrap_or_else(|| good_u.to_vec());
        let (u, mut report) =
            self.attempt(model, warm, settings, start, aligned, camera, deadline)?;
        report.icp_iterations += coarse_counts.0;
        report.newton_iterations += coarse_counts.1;
        report.factorizations += coarse_counts.2;
        add_timings(&mut spent, &report.timings);
        if session.recovery && (solver_failed(&report) || !all_finite(&u)) {
            // The stage's kept factorisation and visible set are those of a failed attempt.
            self.icp(warm).invalidate();
            let (u, report) = recover(
                model,
                &session.cold,
                self.normals.clone(),
                good_u,
                (u, report),
                data,
                camera,
                deadline,
                &mut spent,
                flags,
            )?;
            return Ok((u, report, spent));
        }
        Ok((u, report, spent))
    }

    /// The non-rigid stage of warm frames (`warm`) or of cold ones.
    fn icp(&mut self, warm: bool) -> &mut NonRigidIcp {
        if warm {
            &mut self.warm
        } else {
            &mut self.cold
        }
    }

    /// One non-rigid attempt on `model` from the displacement `u` (m) with `settings` (the
    /// warm stage's solver when `warm`, else the cold one's). Returns the new displacement and
    /// the report.
    #[allow(clippy::too_many_arguments)]
    fn attempt(
        &mut self,
        model: &mut Model,
        warm: bool,
        settings: NonRigidSettings,
        mut u: Vec<f64>,
        aligned: &[nalgebra::Point3<f64>],
        camera: Option<&Camera>,
        deadline: Option<Instant>,
    ) -> Result<(Vec<f64>, NonRigidReport), FrameError> {
        let icp = self.icp(warm);
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
        let report = icp.register(model, aligned, camera, &mut u, deadline);
        if !all_finite(&u) {
            icp.invalidate();
        }
        let report = report.map_err(|e| FrameError::NonRigid(e.to_string()))?;
        Ok((u, report))
    }
}

/// Whether every value of `u` is finite.
pub(super) fn all_finite(u: &[f64]) -> bool {
    u.iter().all(|v| v.is_finite())
}

/// Adds the time spent `b` to `a`, stage by stage.
pub(super) fn add_timings(a: &mut NonRigidTimings, b: &NonRigidTimings) {
    a.visibility_ms += b.visibility_ms;
    a.pairing_ms += b.pairing_ms;
    a.newton_ms += b.newton_ms;
}
