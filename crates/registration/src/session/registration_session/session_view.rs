//! [`SessionView`]: what the session's parts read of it during a frame.

use super::super::settings::SessionSettings;
use super::good_state::GoodState;
use super::model_surfaces::ModelSurfaces;
use crate::model::Model;
use crate::registration::SurfaceDistances;

/// What a part of the session reads of it during a frame: the model (SI units), the settings,
/// the last good state and the model's surfaces.
#[derive(Clone, Copy)]
pub(super) struct SessionView<'a> {
    /// The model, SI units.
    pub(super) model: &'a Model,
    /// The session's settings.
    pub(super) settings: &'a SessionSettings,
    /// The last good state.
    pub(super) good: &'a GoodState,
    /// The model's surfaces for signed distances.
    pub(super) surfaces: &'a ModelSurfaces,
}

impl<'a> SessionView<'a> {
    /// The last good state's deformed surface (metres, model frame), built on first use;
    /// `None` for an empty surface.
    pub(super) fn good_surface(&self) -> Option<&'a SurfaceDistances> {
        self.surfaces.good(self.model, &self.good.u)
    }
}
