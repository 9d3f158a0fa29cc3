//! The contact refit: the registered field explained again by a load at the contact alone.
//!
//! A cloud shows where the surface is, not how its points slid along it. The data term's
//! point-to-plane springs fix the seen surface along its normal everywhere it is seen, and the
//! elastic energy then picks the least-energy field that does so: a field loaded over the whole
//! seen patch, whose seen surface lies where the cloud says but has slid along itself, and
//! whose unseen part has moved too little. A liver pushed by a tool is loaded at the contact
//! and nowhere else: away from the contact its surface is free.
//!
//! The refit uses that. The seen surface vertices within `radius` of the dent's centre (the
//! contact region) are held where the registration put them, shifted by a slide `δ` in the
//! region's mean tangent plane; every other spring is removed, so the rest of the liver follows
//! the contact region as a free body does. The slide is chosen by Gauss–Newton so that the
//! cloud's points away from the contact lie on the refitted surface: the seen surface away
//! from the contact becomes evidence, not load. The refit is refused when it leaves a share of
//! the motion seen there unexplained ([`ContactRefit::unexplained_share`]): a liver loaded over
//! a wide area (pressure, gravity, a support) has no such explanation. It is also
//! refused when the registration did not reach the cloud at the contact (beyond its noise and
//! the allowance): the refit holds the contact region where the registration put it, and a
//! dent the grid did not reach (a noisy cloud whose deepest pairs were pruned) would carry
//! its error to the whole liver.
//!
//! Measured with the force-driven truths' budget (`cargo run --release --example
//! force_truth_budget`): with a perfect point-to-plane fit of the seen vertices the warped
//! liver's neo-Hookean press ends 8.7 mm off on its deepest frame, with the seen vertices' whole
//! motion known 1.6 mm. Lengths in metres.

use std::sync::Arc;

use nalgebra::{Matrix2, Point3, Vector2, Vector3};

use super::contact_force::RestCompliance;
use super::correspondences::rejection_threshold;
use super::linear_held_body::{HeldColumns, LinearHeldBody};
use super::surface_distances::{SurfaceDistances, SurfaceTopology};
use crate::grid::Embedding;
use crate::mechanics::{NewtonSolver, PenaltySprings, StaticProblem};

/// How the refit runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactRefitSettings {
    /// Radius (m, rest) of the contact region around the dent's centre.
    pub radius: f64,
    /// Stiffness (N/m) of each spring holding a contact-region vertex.
    pub hold_stiffness: f64,
    /// Newton iterations per solve of the refitted body (each bounded).
    pub newton_iterations: usize,
    /// Fresh factorisations of the refitted body's tangent one refit may make, over all its
    /// solves: a solve whose step would need one more stops at its last iterate (not
    /// converged). Every iteration of a modified-Newton solve may otherwise refactorise.
    pub factorizations: usize,
    /// Gauss–Newton steps on the slide.
    pub slide_steps: usize,
    /// What the grid cannot shape (m, RMS): the registration must have reached the cloud at
    /// the contact within the noise and this.
    pub allowance: f64,
    /// Largest share of the motion seen away from the contact the refit may leave unexplained
    /// beyond the registration's own misfit there ([`ContactRefit::unexplained_share`]).
    pub max_unexplained_share: f64,
}

/// The refit's result.
#[derive(Debug, Clone)]
pub struct ContactRefit {
    /// Grid displacements of the refitted field, m.
    pub u: Vec<f64>,
    /// The contact region's slide, m (model frame).
    pub slide: Vector3<f64>,
    /// RMS signed distance (m) of the cloud's points away from the contact to the surface the
    /// registration gave (its springs pulled them).
    pub outer_rms_full: f64,
    /// The same to the refitted surface (nothing pulled them).
    pub outer_rms: f64,
    /// RMS signed distance (m) of the cloud's points away from the contact to the rest
    /// surface: how far the surface there moved along its normal, what the refit explains.
    pub outer_motion: f64,
    /// RMS signed distance (m) of the cloud's points at the contact to the registered
    /// surface: how well the registration reached the dent the refit holds.
    pub inner_rms_full: f64,
    /// The force (N, model frame) the held contact region applies to the refitted body, read
    /// from what balances it: the negated resultant of the body's own holds and dead loads
    /// ([`StaticProblem::holds_and_loads_resultant`]), through the model's own law (not
    /// linearised). At the body's equilibrium it equals the held springs' summed force
    /// `Σ k (d_j − u_j)`; off balance (a solve stopped short) that sum is `k` times the
    /// springs' leftover gap, which the stiff holds make arbitrarily wrong (up to 4·10⁴ times
    /// the true force on the force-driven truths' deep neo-Hookean frames), while the holds'
    /// reaction stays with the body's state.
    pub contact_force: Vector3<f64>,
    /// Where it acts (m, deformed configuration): the held vertices' positions weighted by
    /// their springs' force magnitudes.
    pub force_centre: Point3<f64>,
    /// Seen vertices held in the contact region.
    pub held_vertices: usize,
    /// Cloud points away from the contact the slide was fitted to.
    pub outer_points: usize,
    /// Whether the kept state is the held body's equilibrium: its solve met the solver's
    /// tolerance within [`ContactRefitSettings::newton_iterations`]. When it did not, the
    /// state is the solve's last iterate, off balance.
    pub converged: bool,
}

/// Why no refit was made.
#[derive(Debug, Clone, PartialEq)]
pub enum RefitSkip {
    /// Fewer than three seen vertices lie in the contact region.
    NoContactRegion,
    /// Too few cloud points lie away from the contact to fit a slide to.
    TooLittleOutside,
    /// The registration did not reach the cloud at the contact (RMS distance of its points
    /// there, m, beyond the noise and the allowance): the refit would hold a wrong dent.
    ContactNotReached(f64),
    /// The refit leaves more than [`ContactRefitSettings::max_unexplained_share`] of the
    /// motion seen away from the contact unexplained (the share): the liver is loaded
    /// elsewhere too.
    LoadedElsewhere(f64),
    /// The slide could not be fitted: the probes of its Jacobian could not move the body (the
    /// frame's factorisation budget was spent on the first solve).
    SlideNotFitted,
    /// A solve gave a state that is not finite, or a surface could not be built.
    Failed,
}

/// Steps one factorisation of the refitted body's tangent serves (modified Newton).
const REFIT_FACTOR_USES: usize = 32;

/// Fewest cloud points away from the contact that may decide the slide.
pub(crate) const MIN_OUTER_POINTS: usize = 30;

/// What [`refit_at_contact`] works on.
pub struct RefitInput<'a> {
    /// The model's surface at rest, for signed distances.
    pub rest_surface: &'a SurfaceDistances,
    /// The surface's vertices embedded in the grid.
    pub surface_embedding: &'a Embedding,
    /// The surface's topology, for distances.
    pub topology: &'a Arc<SurfaceTopology>,
    /// The registered grid displacements, m.
    pub u: &'a [f64],
    /// The cloud in the model frame, m.
    pub cloud: &'a [Point3<f64>],
    /// The cloud's measured noise (m, 1σ), 0 when unknown.
    pub noise: f64,
    /// Rest position (m) of the dent's centre.
    pub centre: Point3<f64>,
}

/// One evaluated slide: the refitted state and the signed distances of the outside points.
struct Evaluated {
    u: Vec<f64>,
    distances: Vec<f64>,
    /// Whether the body's solve reached equilibrium ([`NewtonSolver::improve`]'s tests).
    converged: bool,
}

impl Evaluated {
    fn rms(&self) -> f64 {
        rms(&self.distances)
    }
}

fn rms(d: &[f64]) -> f64 {
    (d.iter().map(|v| v * v).sum::<f64>() / d.len().max(1) as f64).sqrt()
}

/// The cloud split at the contact: the seen vertices held there, the points away from it the
/// slide is fitted to, and how well the registration explains each part.
struct ContactSplit {
    /// Seen surface vertices within the contact radius.
    held_ids: Vec<usize>,
    /// Cloud points away from the contact that the registered surface explains (mean + 2σ of
    /// their distances), m.
    outside: Vec<Point3<f64>>,
    /// RMS signed distance (m) of `outside` to the registered surface.
    outer_rms_full: f64,
    /// RMS signed distance (m) of the points at the contact to the registered surface.
    inner_rms_full: f64,
    /// RMS signed distance (m) of `outside` to the rest surface.
    outer_motion: f64,
}

impl ContactSplit {
    /// Splits the cloud of `input` between the contact region and the rest, against the
    /// registered surface `full` (vertices `x`, m).
    fn of(
        input: &RefitInput<'_>,
        full: &SurfaceDistances,
        vertex_count: usize,
        radius: f64,
    ) -> Result<Self, RefitSkip> {
        let rest = &input.surface_embedding.rest;
        let in_contact = |v: usize| (rest[v] - input.centre).norm() < radius;
        let mut seen = vec![false; vertex_count];
        let mut outside = Vec::new();
        let mut inside = Vec::new();
        for p in input.cloud {
            let v = full.nearest_vertex(p);
            seen[v] = true;
            if in_contact(v) {
                inside.push(*p);
            } else {
                outside.push(*p);
            }
        }
        let held_ids: Vec<usize> = (0..vertex_count)
            .filter(|&v| seen[v] && in_contact(v))
            .collect();
        if held_ids.len() < 3 {
            return Err(RefitSkip::NoContactRegion);
        }
        // The points the slide is fitted to: those the registered surface explains (mean + 2σ
        // of their distances), the same set for every slide tried.
        let d_full = full.signed_distances(&outside);
        let limit = rejection_threshold(&d_full.iter().map(|d| d.abs()).collect::<Vec<_>>(), 2.0);
        let keep: Vec<usize> = (0..outside.len())
            .filter(|&i| d_full[i].abs() <= limit)
            .collect();
        if keep.len() < MIN_OUTER_POINTS {
            return Err(RefitSkip::TooLittleOutside);
        }
        let outside: Vec<Point3<f64>> = keep.iter().map(|&i| outside[i]).collect();
        Ok(Self {
            held_ids,
            outer_rms_full: rms(&keep.iter().map(|&i| d_full[i]).collect::<Vec<_>>()),
            inner_rms_full: rms(&full.signed_distances(&inside)),
            outer_motion: rms(&input.rest_surface.signed_distances(&outside)),
            outside,
        })
    }

    /// Refuses a contact the registration did not reach within the cloud's `noise` (m) and
    /// the `allowance` (m).
    fn check_reached(&self, noise: f64, allowance: f64) -> Result<(), RefitSkip> {
        let beyond_noise = (self.inner_rms_full.powi(2) - noise.powi(2))
            .max(0.0)
            .sqrt();
        if beyond_noise > allowance {
            return Err(RefitSkip::ContactNotReached(self.inner_rms_full));
        }
        Ok(())
    }
}

/// Two unit vectors spanning the contact region's mean tangent plane at the registered
/// surface (normals of `full` averaged over the held vertices).
fn tangent_plane(
    full: &SurfaceDistances,
    held_ids: &[usize],
) -> Result<[Vector3<f64>; 2], RefitSkip> {
    let normals = full.vertex_normals();
    let mean_normal = held_ids
        .iter()
        .map(|&v| normals[v])
        .sum::<Vector3<f64>>()
        .try_normalize(1e-12)
        .ok_or(RefitSkip::Failed)?;
    let t1 = mean_normal
        .cross(&Vector3::x())
        .try_normalize(0.1)
        .unwrap_or_else(|| mean_normal.cross(&Vector3::y()).normalize());
    Ok([t1, mean_normal.cross(&t1)])
}

/// The model's body with the contact region held: solves it for a slide of the region and
/// measures the outside points against the result.
struct HeldBody<'a, 'b> {
    problem: &'a mut StaticProblem,
    solver: &'a mut NewtonSolver,
    input: &'a RefitInput<'b>,
    hold_stiffness: f64,
    /// The held vertices' embedding (with their rest positions, m).
    embedding: Embedding,
    /// Their registered positions, m.
    registered: Vec<Point3<f64>>,
    outside: &'a [Point3<f64>],
    plane: [Vector3<f64>; 2],
    /// A linear law's held body through its compliance: every slide solved exactly, without
    /// the Newton solver.
    linear: Option<LinearHeldBody<'a>>,
}

impl HeldBody<'_, '_> {
    /// The slide (m, model frame) of plane coordinates `d`.
    fn tangent(&self, d: &Vector2<f64>) -> Vector3<f64> {
        self.plane[0] * d.x + self.plane[1] * d.y
    }

    /// The held vertices' imposed displacements (m) for the slide `slide` (plane coordinates,
    /// m): their registered positions slid, from rest.
    fn targets(&self, slide: &Vector2<f64>) -> Vec<Vector3<f64>> {
        let shift = self.tangent(slide);
        self.registered
            .iter()
            .zip(&self.embedding.rest)
            .map(|(x, r)| x + shift - r)
            .collect()
    }

    /// Where the held springs load the body for the slide `slide` (plane coordinates, m) at
    /// grid displacements `u` (m) ([`ContactRefit::force_centre`]).
    fn force_centre(&self, slide: &Vector2<f64>, u: &[f64]) -> Point3<f64> {
        let moved = self.embedding.interpolate(u);
        let mut weighted = Vector3::zeros();
        let mut weight = 0.0;
        for ((target, r), d) in self
            .targets(slide)
            .iter()
            .zip(&self.embedding.rest)
            .zip(&moved)
        {
            let f = ((target - d) * self.hold_stiffness).norm();
            weighted += (r.coords + d) * f;
            weight += f;
        }
        if weight > 0.0 {
            Point3::from(weighted / weight)
        } else {
            Point3::from(
                self.registered
                    .iter()
                    .fold(Vector3::zeros(), |a, x| a + x.coords)
                    / self.registered.len() as f64,
            )
        }
    }

    /// The body solved by at most `iterations` Newton iterations from `start` with the
    /// contact region slid by `slide` (plane coordinates, m).
    fn evaluate(
        &mut self,
        slide: &Vector2<f64>,
        start: &[f64],
        iterations: usize,
    ) -> Result<Evaluated, RefitSkip> {
        if let Some(linear) = &self.linear {
            return self.measure(linear.solve(&self.targets(slide)), true);
        }
        let held = PenaltySprings {
            embedding: self.embedding.clone(),
            target: self.targets(slide),
            stiffness: vec![self.hold_stiffness; self.registered.len()],
            follows_load: false,
            normals: None,
        };
        let mut u = start.to_vec();
        let converged = self
            .solver
            .improve(
                self.problem,
                std::slice::from_ref(&held),
                &mut u,
                iterations,
            )
            .converged;
        self.measure(u, converged)
    }

    /// The state `u` (m) with the outside points' signed distances to its surface; `converged`
    /// says whether it is the held body's equilibrium.
    fn measure(&self, u: Vec<f64>, converged: bool) -> Result<Evaluated, RefitSkip> {
        if !u.iter().all(|v| v.is_finite()) {
            return Err(RefitSkip::Failed);
        }
        let surface = SurfaceDistances::new(
            self.input.surface_embedding.positions(&u),
            self.input.topology.clone(),
        )
        .ok_or(RefitSkip::Failed)?;
        Ok(Evaluated {
            distances: surface.signed_distances(self.outside),
            u,
            converged,
        })
    }
}

/// Refits the registered field of `input` with the load at the contact alone (module doc).
/// `problem` is the model's (its own holds stay), `solver` one kept for this purpose. With
/// `linear` (the model's rest compliance and the compliance columns kept across frames), a
/// linear law's held body is solved through its compliance ([`LinearHeldBody`]) instead of by
/// `solver`: exact for every slide, no factorisation of the held body. Refuses
/// ([`RefitSkip`]) when the registration did not reach the cloud at the contact, or when the
/// refit leaves more than [`ContactRefitSettings::max_unexplained_share`] of the motion seen
/// away from it unexplained.
pub fn refit_at_contact(
    problem: &mut StaticProblem,
    solver: &mut NewtonSolver,
    linear: Option<(&mut RestCompliance, &mut HeldColumns)>,
    input: &RefitInput<'_>,
    settings: &ContactRefitSettings,
) -> Result<ContactRefit, RefitSkip> {
    let x = input.surface_embedding.positions(input.u);
    // The registered surface: its vertices' tree, normals and signed distances.
    let full = SurfaceDistances::new(x.clone(), input.topology.clone()).ok_or(RefitSkip::Failed)?;
    let split = ContactSplit::of(input, &full, x.len(), settings.radius)?;
    split.check_reached(input.noise, settings.allowance)?;
    let plane = tangent_plane(&full, &split.held_ids)?;
    let held_ids = &split.held_ids;
    // A compliance that cannot serve (a law that is not linear, a failed solve) leaves the
    // held body to the Newton solver.
    let linear = linear.and_then(|(compliance, columns)| {
        LinearHeldBody::new(
            problem,
            compliance,
            columns,
            input.surface_embedding,
            held_ids,
            settings.hold_stiffness,
        )
        .ok()
    });
    let mut body = HeldBody {
        problem,
        solver,
        input,
        hold_stiffness: settings.hold_stiffness,
        embedding: input.surface_embedding.select(held_ids),
        registered: held_ids.iter().map(|&v| x[v]).collect(),
        outside: &split.outside,
        plane,
        linear,
    };
    // One factorisation of the refitted body's tangent serves every solve of this frame: the
    // springs are the same in all of them, only their targets move. The budget bounds the
    // frame's time where line searches that fail with the kept factorisation would
    // refactorise again and again.
    body.solver.invalidate_factorization();
    body.solver.set_factor_reuse(REFIT_FACTOR_USES);
    body.solver
        .set_factorization_budget(Some(settings.factorizations));
    let fitted = fit_slide(&mut body, settings);
    body.solver.set_factorization_budget(None);
    let (best, best_slide) = fitted?;
    let refit = ContactRefit {
        converged: best.converged,
        contact_force: -body.problem.holds_and_loads_resultant(&best.u, 1.0),
        force_centre: body.force_centre(&best_slide, &best.u),
        outer_rms: best.rms(),
        u: best.u,
        slide: body.tangent(&best_slide),
        outer_rms_full: split.outer_rms_full,
        outer_motion: split.outer_motion,
        inner_rms_full: split.inner_rms_full,
        held_vertices: held_ids.len(),
        outer_points: split.outside.len(),
    };
    let share = refit.unexplained_share(input.noise);
    if share > settings.max_unexplained_share {
        return Err(RefitSkip::LoadedElsewhere(share));
    }
    Ok(refit)
}

/// The slide that puts the outside points on the refitted surface: Gauss–Newton from no
/// slide, at most `settings.slide_steps` steps, each kept only when it lowers their RMS.
/// Returns the best evaluation and its slide (plane coordinates, m).
fn fit_slide(
    body: &mut HeldBody<'_, '_>,
    settings: &ContactRefitSettings,
) -> Result<(Evaluated, Vector2<f64>), RefitSkip> {
    let mut slide = Vector2::zeros();
    let mut best = body.evaluate(&slide, body.input.u, settings.newton_iterations)?;
    let mut best_slide = slide;
    // The slide's Jacobian by differences of a tenth of the region's radius, each probe one
    // Newton step from the relaxed state (exact for a linear law: the map is affine), once;
    // the steps reuse it (a chord method).
    let h = 0.1 * settings.radius;
    let base = best.u.clone();
    let mut jacobian = Vec::with_capacity(2);
    let mut probes = Vec::with_capacity(2);
    for axis in 0..2 {
        let probe = body.evaluate(&(slide + Vector2::ith(axis, h)), &base, 1)?;
        jacobian.push(
            probe
                .distances
                .iter()
                .zip(&best.distances)
                .map(|(a, b)| (a - b) / h)
                .collect::<Vec<f64>>(),
        );
        probes.push(probe.u);
    }
    let mut normal = Matrix2::zeros();
    for a in 0..2 {
        for b in 0..2 {
            normal[(a, b)] = jacobian[a]
                .iter()
                .zip(&jacobian[b])
                .map(|(p, q)| p * q)
                .sum::<f64>();
        }
    }
    // Probes that could not move the body (the frame's factorisation budget spent on the
    // relaxed solve, so their one step was refused) leave no Jacobian: the slide, the refit's
    // check against the cloud away from the contact, cannot be fitted.
    if normal.trace().is_nan() || normal.trace() <= 0.0 {
        return Err(RefitSkip::SlideNotFitted);
    }
    normal += Matrix2::identity() * 1e-9 * normal.trace();
    let Some(inverse) = normal.try_inverse() else {
        return Err(RefitSkip::SlideNotFitted);
    };
    // A linear law's held body responds to the slide affinely and each probe, one step on
    // the exact factorisation from the relaxed equilibrium, is its exact response: a slid
    // state is their combination, no solve needed.
    let affine = body.problem.material.is_linear() && best.converged;
    let mut current = best.distances.clone();
    let mut from = base.clone();
    for _ in 0..settings.slide_steps {
        let gradient = Vector2::new(
            jacobian[0].iter().zip(&current).map(|(j, r)| j * r).sum(),
            jacobian[1].iter().zip(&current).map(|(j, r)| j * r).sum(),
        );
        let mut next = slide - inverse * gradient;
        if next.norm() > settings.radius {
            next *= settings.radius / next.norm();
        }
        let trial = if affine {
            body.measure(
                slid_affinely(&base, [&probes[0], &probes[1]], &next, h),
                true,
            )?
        } else {
            body.evaluate(&next, &from, settings.newton_iterations)?
        };
        if trial.rms() >= best.rms() {
            break;
        }
        slide = next;
        current = trial.distances.clone();
        from = trial.u.clone();
        best_slide = next;
        best = trial;
    }
    Ok((best, best_slide))
}

/// The state of a body whose response to the slide is affine: `base` (m) at no slide plus the
/// probes' differences from it (`probes[i]` the state at a slide of `h` m along plane axis `i`),
/// weighted by `slide` (plane coordinates, m) over `h`.
fn slid_affinely(base: &[f64], probes: [&[f64]; 2], slide: &Vector2<f64>, h: f64) -> Vec<f64> {
    let (a, b) = (slide.x / h, slide.y / h);
    base.iter()
        .zip(probes[0].iter().zip(probes[1]))
        .map(|(u0, (px, py))| u0 + a * (px - u0) + b * (py - u0))
        .collect()
}

impl ContactRefit {
    /// The share of the motion seen away from the contact (beyond the cloud's `noise`, m) that
    /// the refit leaves unexplained beyond the registration's own misfit there:
    /// `√(outer_rms² − outer_rms_full²) / √(outer_motion² − noise²)`; infinite when nothing
    /// moved there.
    pub fn unexplained_share(&self, noise: f64) -> f64 {
        let excess = (self.outer_rms.powi(2) - self.outer_rms_full.powi(2))
            .max(0.0)
            .sqrt();
        let motion = (self.outer_motion.powi(2) - noise.powi(2)).max(0.0).sqrt();
        if motion > 0.0 {
            excess / motion
        } else {
            f64::INFINITY
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mechanics::test_fixtures::cut_box_held_at_end;
    use crate::mechanics::{LawKind, Material, NewtonSettings};

    /// A linear law's held body responds to the contact region's slide affinely: the state the
    /// slide's fit combines from the relaxed state and its two one-step probes is the held
    /// body's equilibrium for that slide, as a full solve from the relaxed state finds it. The
    /// body: a 10 × 6 × 5 cm box on 2 cm cut cells, held at its end face, its top face's
    /// vertices within 2 cm of a point near the other end held where a 5 mm push put them.
    #[test]
    fn a_linear_bodys_slid_state_is_the_combination_of_its_probes() {
        let (s, mut problem) = cut_box_held_at_end(0.05, 1e3);
        problem.material = Material::from_young_poisson(LawKind::Linear, 4500.0, 0.45).unwrap();
        let centre = Point3::new(0.08, 0.05, 0.03);
        let held_ids: Vec<usize> = (0..s.vertices.len())
            .filter(|&v| (s.vertices[v] - centre).norm() < 0.02)
            .collect();
        assert!(held_ids.len() >= 3, "{}", held_ids.len());
        let surface_embedding = Embedding::new(&problem.grid, &s.vertices).unwrap();
        let topology = Arc::new(SurfaceTopology::new(s.vertices.len(), &s.triangles));
        let rest_surface = SurfaceDistances::new(s.vertices.clone(), topology.clone()).unwrap();
        let outside: Vec<Point3<f64>> = s
            .vertices
            .iter()
            .filter(|v| v.y > 0.049 && (*v - centre).norm() > 0.03)
            .copied()
            .collect();
        let u0 = vec![0.0; problem.dofs()];
        let input = RefitInput {
            rest_surface: &rest_surface,
            surface_embedding: &surface_embedding,
            topology: &topology,
            u: &u0,
            cloud: &outside,
            noise: 0.0,
            centre,
        };
        let mut solver = NewtonSolver::new(NewtonSettings {
            step_stabilization: 0.0,
            ..NewtonSettings::default()
        });
        solver.set_factor_reuse(REFIT_FACTOR_USES);
        let mut body = HeldBody {
            problem: &mut problem,
            solver: &mut solver,
            input: &input,
            hold_stiffness: 1e3,
            embedding: surface_embedding.select(&held_ids),
            registered: held_ids
                .iter()
                .map(|&v| s.vertices[v] - Vector3::new(0.0, 0.005, 0.0))
                .collect(),
            outside: &outside,
            plane: [Vector3::x(), Vector3::z()],
            linear: None,
        };
        let relaxed = body.evaluate(&Vector2::zeros(), &u0, 8).unwrap();
        assert!(relaxed.converged);
        let h = 0.002;
        let probes: Vec<Vec<f64>> = (0..2)
            .map(|axis| {
                body.evaluate(&Vector2::ith(axis, h), &relaxed.u, 1)
                    .unwrap()
                    .u
            })
            .collect();
        let slide = Vector2::new(0.003, -0.0045);
        let combined = slid_affinely(&relaxed.u, [&probes[0], &probes[1]], &slide, h);
        let solved = body.evaluate(&slide, &relaxed.u, 20).unwrap();
        assert!(solved.converged);
        let moved = solved
            .u
            .iter()
            .zip(&relaxed.u)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let apart = solved
            .u
            .iter()
            .zip(&combined)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        println!("the slide moves the body {moved:.3e} m; combined and solved {apart:.3e} m apart");
        assert!(moved > 1e-4, "{moved}");
        assert!(apart < 1e-6 * moved, "{apart} against {moved}");
    }
}
