//! [`ModelSurfaces`]: the model's surfaces indexed for signed distances.

use std::sync::{Arc, OnceLock};

use crate::model::Model;
use crate::registration::{SurfaceDistances, SurfaceTopology};

/// The model's surface indexed for signed distances (metres, model frame) in the shapes a
/// frame measures clouds against: the rest shape (the rest test, the contact refit) and the
/// last good state's (the held pose's fit, the still test, re-acquisition), each built on first
/// use, and any other shape on demand. Every one shares the surface's triangles and the
/// triangles around each vertex.
pub(super) struct ModelSurfaces {
    /// The model surface's triangles and the triangles around each vertex.
    topology: Arc<SurfaceTopology>,
    /// The rest surface: the same every frame.
    rest: OnceLock<Option<SurfaceDistances>>,
    /// The last good state's deformed surface: the one the frame's own fit built, kept with
    /// the state it measured, or built on first use.
    good: OnceLock<Option<SurfaceDistances>>,
}

impl ModelSurfaces {
    /// The surfaces of `model`, none built yet.
    pub(super) fn new(model: &Model) -> Self {
        Self {
            topology: Arc::new(SurfaceTopology::new(
                model.surface.vertices.len(),
                &model.surface.triangles,
            )),
            rest: OnceLock::new(),
            good: OnceLock::new(),
        }
    }

    /// The topology every surface shares.
    pub(super) fn topology(&self) -> &Arc<SurfaceTopology> {
        &self.topology
    }

    /// The surface of `model` deformed by `u` (m); `None` for an empty surface.
    pub(super) fn deformed(&self, model: &Model, u: &[f64]) -> Option<SurfaceDistances> {
        SurfaceDistances::new(model.surface_embedding.positions(u), self.topology.clone())
    }

    /// The rest surface of `model`, built on first use; `None` for an empty surface.
    pub(super) fn rest(&self, model: &Model) -> Option<&SurfaceDistances> {
        self.rest
            .get_or_init(|| self.deformed(model, &vec![0.0; model.problem.dofs()]))
            .as_ref()
    }

    /// The surface of `model` at the last good state's displacement `good_u` (m), built on
    /// first use; `None` for an empty surface.
    pub(super) fn good(&self, model: &Model, good_u: &[f64]) -> Option<&SurfaceDistances> {
        self.good
            .get_or_init(|| self.deformed(model, good_u))
            .as_ref()
    }

    /// Keeps `surface`, built for a new good state, as that state's surface.
    pub(super) fn keep_good(&mut self, surface: SurfaceDistances) {
        self.good = OnceLock::from(Some(surface));
    }

    /// Forgets the good state's surface (the state changed): the next use builds it again.
    pub(super) fn forget_good(&mut self) {
        self.good = OnceLock::new();
    }
}
