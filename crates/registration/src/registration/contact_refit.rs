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

use super::correspondences::rejection_threshold;
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
    /// Seen vertices held in the contact region.
    pub held_vertices: usize,
    /// Cloud points away from the contact the slide was fitted to.
    pub outer_points: usize,
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
    /// A solve gave a state that is not finite, or a surface could not be built.
    Failed,
}

/// Steps one factorisation of the refitted body's tangent serves (modified Newton).
const REFIT_FACTOR_USES: usize = 32;

/// Fewest cloud points away from the contact that may decide the slide.
pub const MIN_OUTER_POINTS: usize = 30;

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
}

impl Evaluated {
    fn rms(&self) -> f64 {
        rms(&self.distances)
    }
}

fn rms(d: &[f64]) -> f64 {
    (d.iter().map(|v| v * v).sum::<f64>() / d.len().max(1) as f64).sqrt()
}

/// Refits the registered field of `input` with the load at the contact alone (module doc).
/// `problem` is the model's (its own holds stay), `solver` one kept for this purpose. Refuses
/// ([`RefitSkip`]) when the registration did not reach the cloud at the contact, or when the
/// refit leaves more than [`ContactRefitSettings::max_unexplained_share`] of the motion seen
/// away from it unexplained.
pub fn refit_at_contact(
    problem: &mut StaticProblem,
    solver: &mut NewtonSolver,
    input: &RefitInput<'_>,
    settings: &ContactRefitSettings,
) -> Result<ContactRefit, RefitSkip> {
    let rest = &input.surface_embedding.rest;
    let x = input.surface_embedding.positions(input.u);
    // The registered surface: its vertices' tree, normals and signed distances.
    let full = SurfaceDistances::new(x.clone(), input.topology.clone()).ok_or(RefitSkip::Failed)?;
    let in_contact = |v: usize| (rest[v] - input.centre).norm() < settings.radius;
    let mut seen = vec![false; x.len()];
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
    let held_ids: Vec<usize> = (0..x.len()).filter(|&v| seen[v] && in_contact(v)).collect();
    if held_ids.len() < 3 {
        return Err(RefitSkip::NoContactRegion);
    }
    // The points the slide is fitted to: those the registered surface explains (mean + 2σ of
    // their distances), the same set for every slide tried.
    let d_full = full.signed_distances(&outside);
    let limit = rejection_threshold(&d_full.iter().map(|d| d.abs()).collect::<Vec<_>>(), 2.0);
    let keep: Vec<usize> = (0..outside.len())
        .filter(|&i| d_full[i].abs() <= limit)
        .collect();
    if keep.len() < MIN_OUTER_POINTS {
        return Err(RefitSkip::TooLittleOutside);
    }
    let outside: Vec<Point3<f64>> = keep.iter().map(|&i| outside[i]).collect();
    let outer_rms_full = rms(&keep.iter().map(|&i| d_full[i]).collect::<Vec<_>>());
    let inner_rms_full = rms(&full.signed_distances(&inside));
    let at_rest =
        SurfaceDistances::new(rest.clone(), input.topology.clone()).ok_or(RefitSkip::Failed)?;
    let outer_motion = rms(&at_rest.signed_distances(&outside));
    let beyond_noise = (inner_rms_full.powi(2) - input.noise.powi(2))
        .max(0.0)
        .sqrt();
    if beyond_noise > settings.allowance {
        return Err(RefitSkip::ContactNotReached(inner_rms_full));
    }

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
    let t2 = mean_normal.cross(&t1);
    let tangent = |d: &Vector2<f64>| t1 * d.x + t2 * d.y;

    let embedding = Embedding {
        points: held_ids
            .iter()
            .map(|&v| input.surface_embedding.points[v])
            .collect(),
        rest: held_ids.iter().map(|&v| rest[v]).collect(),
    };
    // One factorisation of the refitted body's tangent serves every solve of this frame: the
    // springs are the same in all of them, only their targets move.
    solver.invalidate_factorization();
    solver.set_factor_reuse(REFIT_FACTOR_USES);
    let mut evaluate =
        |slide: &Vector2<f64>, start: &[f64], iterations: usize| -> Result<Evaluated, RefitSkip> {
            let shift = tangent(slide);
            let held = PenaltySprings {
                embedding: embedding.clone(),
                target: held_ids.iter().map(|&v| x[v] + shift - rest[v]).collect(),
                stiffness: vec![settings.hold_stiffness; held_ids.len()],
                follows_load: false,
                normals: None,
            };
            let mut u = start.to_vec();
            solver.improve(problem, std::slice::from_ref(&held), &mut u, iterations);
            if !u.iter().all(|v| v.is_finite()) {
                return Err(RefitSkip::Failed);
            }
            let surface = SurfaceDistances::new(
                input.surface_embedding.positions(&u),
                input.topology.clone(),
            )
            .ok_or(RefitSkip::Failed)?;
            Ok(Evaluated {
                distances: surface.signed_distances(&outside),
                u,
            })
        };

    let mut slide = Vector2::zeros();
    let mut best = evaluate(&slide, input.u, settings.newton_iterations)?;
    let mut best_slide = slide;
    // The slide's Jacobian by differences of a tenth of the region's radius, each probe one
    // Newton step from the relaxed state (exact for a linear law: the map is affine), once;
    // the steps reuse it (a chord method).
    let h = 0.1 * settings.radius;
    let base = best.u.clone();
    let mut jacobian = Vec::with_capacity(2);
    for axis in 0..2 {
        let probe = evaluate(&(slide + Vector2::ith(axis, h)), &base, 1)?;
        jacobian.push(
            probe
                .distances
                .iter()
                .zip(&best.distances)
                .map(|(a, b)| (a - b) / h)
                .collect::<Vec<f64>>(),
        );
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
    normal += Matrix2::identity() * (1e-9 * normal.trace()).max(f64::MIN_POSITIVE);
    let Some(inverse) = normal.try_inverse() else {
        return Err(RefitSkip::Failed);
    };
    let mut current = best.distances.clone();
    let mut from = base;
    for _ in 0..settings.slide_steps {
        let gradient = Vector2::new(
            jacobian[0].iter().zip(&current).map(|(j, r)| j * r).sum(),
            jacobian[1].iter().zip(&current).map(|(j, r)| j * r).sum(),
        );
        let mut next = slide - inverse * gradient;
        if next.norm() > settings.radius {
            next *= settings.radius / next.norm();
        }
        let trial = evaluate(&next, &from, settings.newton_iterations)?;
        if trial.rms() >= best.rms() {
            break;
        }
        slide = next;
        current = trial.distances.clone();
        from = trial.u.clone();
        best_slide = next;
        best = trial;
    }
    let refit = ContactRefit {
        outer_rms: best.rms(),
        u: best.u,
        slide: tangent(&best_slide),
        outer_rms_full,
        outer_motion,
        inner_rms_full,
        held_vertices: held_ids.len(),
        outer_points: outside.len(),
    };
    let share = refit.unexplained_share(input.noise);
    if share > settings.max_unexplained_share {
        return Err(RefitSkip::LoadedElsewhere(share));
    }
    Ok(refit)
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
