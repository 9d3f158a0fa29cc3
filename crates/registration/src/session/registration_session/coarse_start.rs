//! [`CoarseStart`]: the coarse-to-fine start of a cold frame.

use std::sync::Arc;
use std::time::Instant;

use super::non_rigid_stage::{add_timings, all_finite};
use super::still_data::StillData;
use crate::geometry::Camera;
use crate::model::{Model, ModelError};
use crate::registration::non_rigid_icp::NonRigidTimings;
use crate::registration::surface_normals::NormalsAtScale;
use crate::registration::{NonRigidIcp, NonRigidSettings, Prolongation};

/// The coarse model of a coarse-to-fine start (the same body on a coarser grid, SI units) and
/// its prolongation to the fine grid: a cold frame is registered on it first, and its
/// displacement (m), prolongated, starts the fine registration.
pub(super) struct CoarseStart {
    /// The coarse model.
    model: Model,
    /// Its own non-rigid ICP (the cold settings).
    icp: NonRigidIcp,
    /// Coarse grid displacements → fine grid displacements.
    prolongation: Prolongation,
}

impl CoarseStart {
    /// The start of `fine`'s cold frames on `coarse`, registered with the `cold` settings and
    /// the surface `normals` the fine stages share.
    pub(super) fn new(
        coarse: Model,
        fine: &Model,
        cold: NonRigidSettings,
        normals: Option<Arc<NormalsAtScale>>,
    ) -> Result<Self, ModelError> {
        let prolongation = Prolongation::new(&coarse.problem.grid, &fine.problem.grid)
            .map_err(|e| ModelError::Invalid(format!("coarse-to-fine prolongation: {e}")))?;
        Ok(CoarseStart {
            icp: NonRigidIcp::new(cold, coarse.newton).with_normals(normals),
            model: coarse,
            prolongation,
        })
    }

    /// The coarse model.
    pub(super) fn model(&self) -> &Model {
        &self.model
    }

    /// Forgets the kept factorisation and visible set.
    pub(super) fn invalidate(&mut self) {
        self.icp.invalidate();
    }

    /// The coarse registration of `data` (seen by `camera`, stopped at `deadline`) with the
    /// `cold` settings, its time added to `spent`: the fine grid's start displacement (m) and
    /// the coarse run's ICP iterations, Newton iterations and factorisations, or `None` when
    /// it failed, warned or ended with a non-finite state.
    pub(super) fn start(
        &mut self,
        cold: NonRigidSettings,
        data: &StillData,
        camera: Option<&Camera>,
        deadline: Option<Instant>,
        spent: &mut NonRigidTimings,
    ) -> Option<(Vec<f64>, (usize, usize, usize))> {
        let mut uc = vec![0.0; self.model.problem.dofs()];
        self.icp.settings = NonRigidSettings {
            cloud_noise: data.noise,
            ..cold
        };
        if let Ok(r) = self
            .icp
            .register(&mut self.model, &data.points, camera, &mut uc, deadline)
        {
            add_timings(spent, &r.timings);
            if r.warnings.is_empty() && all_finite(&uc) {
                let counts = (r.icp_iterations, r.newton_iterations, r.factorizations);
                return Some((self.prolongation.apply(&uc), counts));
            }
        } else {
            self.icp.invalidate();
        }
        None
    }
}
