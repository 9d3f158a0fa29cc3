//! The scene file mapped onto the registration's own types: its model
//! ([`FromScene`] for [`Model`]), its sessions ([`FromScene`] for [`Session`]) and their
//! settings ([`session_settings`]).

use nalgebra::Point3;

use super::model::{build_model, Model, ModelError};
use crate::geometry::Camera;
use crate::mechanics::LawKind;
use crate::registration::NormalScale;
use crate::scene::{DataTerm, LoadedScene, Scene};
use crate::session::BACKGROUND_FACTORIZATION_LAG;
use crate::session::{Session, SessionSettings};

/// A value built from a loaded scene: its files read, its lengths in metres.
pub trait FromScene: Sized {
    /// Builds `Self` from `loaded`; an error names the file or key at fault.
    fn from_scene(loaded: &LoadedScene) -> Result<Self, ModelError>;
}

impl FromScene for Model {
    /// Reads the scene's files and builds the model ([`build_model`], without the surface's
    /// validation report).
    fn from_scene(loaded: &LoadedScene) -> Result<Self, ModelError> {
        build_model(loaded).map(|(model, _)| model)
    }
}

impl FromScene for Session {
    /// A session for a loaded scene, with settings from its `[registration]` section
    /// ([`session_settings`]), the scene's camera, and the coarse model of
    /// `registration.coarse_to_fine`.
    fn from_scene(loaded: &LoadedScene) -> Result<Self, ModelError> {
        let model = Model::from_scene(loaded)?;
        let settings = session_settings(&loaded.scene, loaded.length_scale());
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
                        crate::geometry::DEFAULT_FOV_DEG,
                    ),
                }
                .map_err(|e| ModelError::Invalid(format!("registration.camera: {e}")))?;
                Some(cam)
            }
            None => None,
        };
        let coarse_factor = settings.coarse_to_fine;
        let mut session = Session::new(model, settings, scene_camera);
        if let Some(f) = coarse_factor {
            let mut coarse_scene = loaded.clone();
            coarse_scene.scene.grid.cell_size *= f;
            let coarse = Model::from_scene(&coarse_scene)
                .map_err(|e| ModelError::Invalid(format!("registration.coarse_to_fine: {e}")))?;
            session = session.with_coarse_start(coarse)?;
        }
        Ok(session)
    }
}

/// Session settings from a scene's `[registration]` section (defaults when absent); `scale` is
/// metres per scene unit.
pub fn session_settings(scene: &Scene, scale: f64) -> SessionSettings {
    let mut s = SessionSettings::default();
    if let Some(r) = &scene.registration {
        s.rigid_mode = r.rigid;
        s.pose_update = r.pose;
        for n in [&mut s.cold, &mut s.warm] {
            n.alpha = r.alpha;
            n.penalty_end = r.penalty_end;
            n.penalty_scale = r.penalty_scale;
            n.max_pair_distance = r.max_pair_distance.map(|d| d * scale);
            n.data_term = r.data_term;
            n.normal_scale = match r.normal_radius {
                None => NormalScale::OrganSize,
                Some(0.0) => NormalScale::Vertex,
                Some(d) => NormalScale::Radius(d * scale),
            };
        }
        s.rigid.robust_pruning = r.robust_pruning;
        if !r.pose_search {
            s.pose_search = None;
        }
        if !r.rest_test {
            s.rest_test = None;
        }
        s.still_frames = r.still_frames as usize;
        if let Some(d) = r.max_pose_uncertainty {
            s.max_pose_uncertainty = d * scale;
        }
        if let Some(d) = r.max_expected_error {
            s.max_expected_error = d * scale;
        }
        // Warm frames prune at median/MAD with the cloud → surface term (measured in
        // docs/data-term.md#which-pairs-are-kept); the thesis's direction keeps mean + 2σ.
        s.warm.robust_pruning = r.data_term == DataTerm::CloudToSurface;
        if r.background_factorization {
            s.warm.background_lag = BACKGROUND_FACTORIZATION_LAG;
        }
        s.cold.penalty_start = r.penalty_start;
        s.cold.penalty_steps = r.penalty_steps as usize;
        s.cold.max_icp_iterations = r.max_icp_iterations as usize;
        s.time_budget_ms = r.time_budget_ms;
        if let Some(n) = r.max_cloud_points {
            s.max_cloud_points = n as usize;
        }
        s.coarse_to_fine = r.coarse_to_fine;
        s.remove_isolated_points = r.remove_isolated_points;
        s.contact_refit = r.contact_refit;
        if let Some(d) = r.contact_radius {
            s.contact_radius = d * scale;
        }
        if let Some(n) = r.refit_factorizations {
            s.refit_factorizations = n as usize;
        }
    }
    if matches!(
        scene.material.law,
        LawKind::NeoHookean | LawKind::Svk | LawKind::MooneyRivlin
    ) {
        // `NonRigidSettings::warm`'s single Newton step per ICP iteration and 0.3 mm stop
        // are measured on the corotated and linear laws. The hyperelastic laws take two
        // steps and 0.5 mm (`livereg bench`: neo-Hookean 1.72 mm TRE with one step against
        // 1.32 with two; SVK 1.40 with one step and 0.3 mm against 1.32).
        s.warm.newton_iterations = 2;
        s.warm.tolerance = 5e-4;
    }
    s
}
