//! The recovery ladder: a frame whose solver failed is registered again with gentler
//! settings before it is given up (docs/registration.md, step 8): its rungs
//! ([`RecoveryRung`], [`recovery_ladder`]) and the climb ([`recover`]).

use std::sync::Arc;
use std::time::Instant;

use super::super::frame::FrameError;
use super::super::frame_flag::FrameFlag;
use super::non_rigid_stage::{add_timings, all_finite};
use super::still_data::StillData;
use crate::geometry::Camera;
use crate::linalg::SolverKind;
use crate::mechanics::NewtonSettings;
use crate::model::Model;
use crate::registration::non_rigid_icp::{NonRigidReport, NonRigidTimings};
use crate::registration::surface_normals::NormalsAtScale;
use crate::registration::{NonRigidIcp, NonRigidSettings};

/// The recovery ladder ([`recovery_ladder`] of the `cold` settings and `model`'s solver) after
/// a first attempt that ended with the displacement and report `first` (a solver failure or a
/// non-finite state): each rung registers the frame's `data` (seen by `camera`) on `model`
/// again from the last good displacement `good_u` (m), with the scene's own material law and
/// the shared surface `normals`, until one ends without a solver failure and with a finite
/// state (flag `recovered:<rung>`; the first attempt's warnings are kept, prefixed
/// [`BEFORE_RECOVERY`]). When none does, or the `deadline` passes first, the first attempt
/// stands, flagged `recovery_failed`, with its warnings (the causes). The rungs' time is added
/// to `spent`.
#[allow(clippy::too_many_arguments)]
pub(super) fn recover(
    model: &mut Model,
    cold: &NonRigidSettings,
    normals: Option<Arc<NormalsAtScale>>,
    good_u: &[f64],
    first: (Vec<f64>, NonRigidReport),
    data: &StillData,
    camera: Option<&Camera>,
    deadline: Option<Instant>,
    spent: &mut NonRigidTimings,
    flags: &mut Vec<FrameFlag>,
) -> Result<(Vec<f64>, NonRigidReport), FrameError> {
    let (first_u, first) = first;
    for rung in recovery_ladder(cold, &model.newton) {
        if deadline.is_some_and(|d| Instant::now() >= d) {
            break;
        }
        let settings = NonRigidSettings {
            data_weight: data.weight,
            cloud_noise: data.noise,
            ..rung.settings
        };
        let mut icp = NonRigidIcp::new(settings, rung.newton).with_normals(normals.clone());
        let mut u = good_u.to_vec();
        let r = icp
            .register(model, &data.points, camera, &mut u, deadline)
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

/// Prefix of the warnings of a failed attempt that a recovery then rescued.
pub const BEFORE_RECOVERY: &str = "before recovery: ";

/// Name of the ladder's first rung (flag `recovered:smaller-steps`).
pub(super) const SMALLER_STEPS: &str = "smaller-steps";
/// Name of the ladder's second rung (flag `recovered:damped-newton`).
pub(super) const DAMPED_NEWTON: &str = "damped-newton";
/// Every rung's name, in the ladder's order.
pub(crate) const RUNG_NAMES: [&str; 2] = [SMALLER_STEPS, DAMPED_NEWTON];

/// Whether the Newton solver reported a failure (diverged, inverted, iteration cap) during
/// a non-rigid registration.
pub(super) fn solver_failed(r: &NonRigidReport) -> bool {
    !r.warnings.is_empty()
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
/// direct solve rescues those frames with the scene's law (`src/session_tests.rs`,
/// `the_recovery_keeps_the_scenes_law`).
pub fn recovery_ladder(cold: &NonRigidSettings, newton: &NewtonSettings) -> [RecoveryRung; 2] {
    let smaller = recovery_settings(cold);
    [
        RecoveryRung {
            name: SMALLER_STEPS,
            settings: smaller,
            newton: *newton,
        },
        RecoveryRung {
            name: DAMPED_NEWTON,
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
