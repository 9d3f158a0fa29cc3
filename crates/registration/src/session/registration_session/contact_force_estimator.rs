//! [`ContactForceEstimator`]: the contact force a registered frame implies, from the model's
//! rest compliance or through the contact refit (`registration.contact_refit`,
//! [`refit_at_contact`]: the field explained again by a load at the contact alone, kept when
//! the cloud away from the contact still lies on the surface).

use super::super::frame_flag::FrameFlag;
use super::super::settings::SessionSettings;
use super::model_surfaces::ModelSurfaces;
use super::still_data::StillData;
use crate::grid::derived_cell_size;
use crate::mechanics::{NewtonSettings, NewtonSolver, PenaltySprings};
use crate::mesh::TriSurface;
use crate::model::{Model, DEFAULT_FIXED_PENALTY_FACTOR};
use crate::registration::contact_force::dent_centre;
use crate::registration::contact_refit::{refit_at_contact, ContactRefitSettings, RefitInput};
use crate::registration::{ContactForce, HeldColumns, RestCompliance};

/// What the registration may miss the cloud by at the contact (RMS, beyond its noise) for the
/// refit to hold the contact region where it is, as a share of a cell edge: a tenth of the
/// cell edge (what a trilinear cell cannot shape), but never less than a tenth of the organ's
/// derived default cell ([`derived_cell_size`], `V^(1/3) / 9`; 1.1–1.2 mm on the force-driven
/// truths' livers). The bundled tool-indentation class's noisy deep dents (`livereg bench
/// --indentation`) miss it by 2–3 mm and are refused. The registration reaches a 10–12 mm patch
/// pushed 40 mm deep no closer on finer cells (0.8–1.2 mm RMS on random liver 1's
/// press-release linear at 8 mm): a tenth of the cell alone would refuse those refits as the cells
/// shrink and the error would grow with refinement; with the floor the force-driven sets fall from
/// 11.5 to 8 to 5.75 mm cells (tuning 1.10 / 1.03 / 0.96 mm, `livereg bench --force-truths
/// --set tuning --cell-size 8|5.75`; docs/force-truths.md#grid-refinement). Coarser cells than
/// the derived ones keep their tenth: the phantom's 22.5 mm cells miss its body-load
/// deformations by more, and a floor alone raised its TRE from 0.49 to 0.51 mm.
const REFIT_ALLOWANCE_PER_CELL: f64 = 0.1;

/// Largest share of the motion seen away from the contact the refit may leave unexplained
/// ([`ContactRefit::unexplained_share`](crate::registration::contact_refit::ContactRefit::unexplained_share)).
/// On the indentation liver's force-driven truths (a load at one patch) the share is
/// 0.02–0.06; a load spread evenly over the seen half of a body leaves 0.77
/// (`session::tests::the_contact_refit_is_refused_for_a_load_spread_over_the_liver`).
const MAX_UNEXPLAINED_SHARE: f64 = 0.25;

/// Newton iterations per solve of the refitted body (modified Newton on at most
/// `registration.refit_factorizations` factorisations per frame,
/// [`DEFAULT_REFIT_FACTORIZATIONS`](crate::session::DEFAULT_REFIT_FACTORIZATIONS) by default).
/// A kept refit whose solve has not converged within them is flagged `refit_not_converged`: on
/// the indentation liver's force-driven truths (`livereg bench --force-truths --set tuning`)
/// that is 37 of 114 kept refits, all on the deep neo-Hookean frames.
const REFIT_NEWTON_ITERATIONS: usize = 8;

/// Gauss–Newton steps on the contact region's slide.
const REFIT_SLIDE_STEPS: usize = 2;

/// The contact refit's reaction's expected relative error. Chosen on the force-driven tuning
/// set (`livereg bench --force-truths --set tuning`): the neo-Hookean reactions are 11–60 %
/// off, 90 % of frames within 47 %: the grid's near field is stiffer than the truth's
/// (docs/contact-force.md#limits).
const REFIT_FORCE_SHARE: f64 = 0.5;

/// The contact force a registered frame implies (model frame: a resultant in newtons at a
/// centre in metres): the force the data term's springs exert on the registered state through
/// the model's rest compliance, or, with the contact refit, the reaction at the contact of the
/// field explained again by a load there alone (and that field, m).
pub(super) struct ContactForceEstimator {
    /// The model's rest compliance for the contact force, factorised on the first frame that
    /// estimates one (an error, kept, when it cannot be: no estimate then).
    rest_compliance: Option<Result<RestCompliance, String>>,
    /// The contact refit's own Newton solver (its factorisation holds the contact region's
    /// springs, not the data term's).
    refit_solver: NewtonSolver,
    /// Compliance columns of the vertices a linear law's refit holds, kept across frames
    /// ([`LinearHeldBody`](crate::registration::LinearHeldBody)).
    held_columns: HeldColumns,
}

impl ContactForceEstimator {
    /// An estimator for a model that solves with `newton`; nothing factorised yet.
    pub(super) fn new(newton: NewtonSettings) -> Self {
        Self {
            rest_compliance: None,
            refit_solver: NewtonSolver::new(NewtonSettings {
                step_stabilization: 0.0,
                mixed_precision: false,
                ..newton
            }),
            held_columns: HeldColumns::new(),
        }
    }

    /// The frame's contact force for the registered state `u` (m) of `model`: the refit's
    /// `refit_force` when one was kept (the body's reaction to the held contact through the
    /// model's own law; for the linear law too: its median error on the force-driven tuning
    /// set's linear cases is 2–12 % against the rest-compliance fit's 4–19 %,
    /// docs/contact-force.md), else the force the data term `springs` imply
    /// ([`ContactForceEstimator::springs_force`]): the rest compliance is linear in the load,
    /// exact for the linear law and first order for the others: `None` with the flag
    /// `force_beyond_linear` (into `flags`) when its expected error exceeds the force itself
    /// ([`FIT_GRADIENT_SLOPE`](crate::registration::contact_force::FIT_GRADIENT_SLOPE)).
    pub(super) fn frame_force(
        &mut self,
        model: &mut Model,
        refit_force: Option<ContactForce>,
        springs: Option<&PenaltySprings>,
        u: &[f64],
        flags: &mut Vec<FrameFlag>,
    ) -> Option<ContactForce> {
        if let Some(force) = refit_force {
            return Some(force);
        }
        let force = self.springs_force(model, springs?, u)?;
        if force.expected_error > force.resultant.norm() {
            flags.push(FrameFlag::ForceBeyondLinear);
            return None;
        }
        Some(force)
    }

    /// The contact force the data term `springs` of the registered state `u` (m) of `model`
    /// imply ([`RestCompliance::fit`]); the model's rest compliance is factorised on first use.
    fn springs_force(
        &mut self,
        model: &mut Model,
        springs: &PenaltySprings,
        u: &[f64],
    ) -> Option<ContactForce> {
        let compliance = self
            .rest_compliance
            .get_or_insert_with(|| {
                RestCompliance::new(&mut model.problem, model.newton.linear_solver)
            })
            .as_mut()
            .ok()?;
        compliance.fit(&model.problem, &model.surface, springs, u)
    }

    /// The registered field `u` (m) of the cloud `data` refitted on `model` with the load at
    /// the contact alone, when `registration.contact_refit` is on (`settings`), a dent is seen
    /// in the data term's `springs`, and the refit keeps the cloud away from the contact on the
    /// surface (flag `contact_refit`) with the contact's reaction force
    /// ([`ContactRefit::contact_force`](crate::registration::contact_refit::ContactRefit::contact_force));
    /// `u` itself and no force otherwise. The refit measures the cloud against the rest
    /// surface of `surfaces`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn refit(
        &mut self,
        model: &mut Model,
        settings: &SessionSettings,
        surfaces: &ModelSurfaces,
        data: &StillData,
        u: Vec<f64>,
        springs: Option<&PenaltySprings>,
        flags: &mut Vec<FrameFlag>,
    ) -> (Vec<f64>, Option<ContactForce>) {
        if !settings.contact_refit {
            return (u, None);
        }
        let Some(springs) = springs else {
            return (u, None);
        };
        let moved = springs.embedding.interpolate(&u);
        let Some(centre) = dent_centre(&springs.embedding.rest, &moved, springs.normals.as_deref())
        else {
            return (u, None);
        };
        let h = model.problem.cell_size();
        let refit_settings = ContactRefitSettings {
            radius: settings.contact_radius,
            hold_stiffness: DEFAULT_FIXED_PENALTY_FACTOR
                * model.problem.material.young_modulus()
                * h,
            newton_iterations: REFIT_NEWTON_ITERATIONS,
            factorizations: settings.refit_factorizations,
            slide_steps: REFIT_SLIDE_STEPS,
            allowance: refit_allowance(&model.surface, h),
            max_unexplained_share: MAX_UNEXPLAINED_SHARE,
        };
        let Some(rest_surface) = surfaces.rest(model) else {
            return (u, None);
        };
        let input = RefitInput {
            rest_surface,
            surface_embedding: &model.surface_embedding,
            topology: surfaces.topology(),
            u: &u,
            cloud: &data.points,
            noise: data.noise.unwrap_or(0.0),
            centre,
        };
        // A linear law's held body is solved through the rest compliance, factorised once
        // (also the data term's force fit's); a direct factor solves the new columns in one pass.
        let linear = if model.problem.material.is_linear() {
            self.rest_compliance
                .get_or_insert_with(|| {
                    RestCompliance::new(&mut model.problem, model.newton.linear_solver)
                })
                .as_mut()
                .ok()
                .filter(|c| c.is_direct())
                .map(|c| (c, &mut self.held_columns))
        } else {
            None
        };
        let result = refit_at_contact(
            &mut model.problem,
            &mut self.refit_solver,
            linear,
            &input,
            &refit_settings,
        );
        match result {
            Ok(refit) => {
                flags.push(FrameFlag::ContactRefit);
                if !refit.converged {
                    flags.push(FrameFlag::RefitNotConverged);
                }
                let force = ContactForce {
                    resultant: refit.contact_force,
                    centre: refit.force_centre,
                    expected_error: REFIT_FORCE_SHARE * refit.contact_force.norm(),
                };
                (refit.u, Some(force))
            }
            Err(_) => (u, None),
        }
    }
}

/// The contact refit's reach allowance (m) on cells of edge `h` (m) for an organ of closed
/// `surface` (m): [`REFIT_ALLOWANCE_PER_CELL`] of the larger of `h` and the organ's derived
/// cell ([`derived_cell_size`]; `h` alone when the surface encloses no volume).
fn refit_allowance(surface: &TriSurface, h: f64) -> f64 {
    REFIT_ALLOWANCE_PER_CELL * derived_cell_size(surface).map_or(h, |d| d.max(h))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::icosphere;
    use nalgebra::Point3;

    /// On cells finer than the organ's derived cell (`V^(1/3) / 9`) the allowance is a tenth
    /// of the derived cell, the same for any cell edge; on coarser cells a tenth of the cell. A
    /// sphere of radius 60 mm (V = 4/3 π r³ less its polyhedral deficit, derived cell
    /// 10.75 mm) gets 1.075 mm at 8, 5.75 or 2 mm cells and 2.25 mm at 22.5 mm cells. A surface
    /// that encloses nothing gets a tenth of the cell.
    #[test]
    fn the_reach_allowance_follows_the_organ_on_fine_cells_and_the_cell_on_coarse_ones() {
        let r = 0.06;
        let sphere = icosphere(Point3::origin(), r, 4);
        let analytic = 0.1 * (4.0 / 3.0 * std::f64::consts::PI * r.powi(3)).cbrt() / 9.0;
        for h in [0.008, 0.00575, 0.002] {
            let a = refit_allowance(&sphere, h);
            assert!(
                (a - analytic).abs() < 0.01 * analytic,
                "{a} against {analytic} at {h}"
            );
        }
        assert_eq!(refit_allowance(&sphere, 0.0225), 0.1 * 0.0225);
        let empty = TriSurface {
            vertices: sphere.vertices.clone(),
            triangles: Vec::new(),
        };
        assert_eq!(refit_allowance(&empty, 0.008), 0.1 * 0.008);
    }
}
