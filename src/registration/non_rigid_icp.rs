//! Biomechanical non-rigid ICP (thesis alg. 3, eq. 5.4): penalty springs pull the model's
//! visible surface towards the intra-operative cloud while the hyperelastic grid decides how
//! the whole volume follows.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};

use crate::geometry::{Camera, VisibleSurface};
use crate::grid::Embedding;
use crate::mechanics::{NewtonSolver, PenaltySprings};
use crate::mesh::TriSurface;
use crate::simulation::SceneModel;

/// Settings of the non-rigid stage. Stiffnesses in N/m per source point, lengths in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NonRigidSettings {
    /// Blending α of eq. 5.4 between the source's own nearest target and the targets that
    /// chose it (0.75 in the thesis's fig. 5.4).
    pub alpha: f64,
    /// First penalty stiffness k₀ (soft: follow the global shape). `None`: 0.02 E h.
    pub penalty_start: Option<f64>,
    /// Last penalty stiffness k₁ (stiff: match detail). `None`: 2 E h.
    pub penalty_end: Option<f64>,
    /// Steps of the exponential ramp from k₀ to k₁.
    pub penalty_steps: usize,
    /// ICP iterations allowed per penalty step.
    pub max_icp_iterations: usize,
    /// Newton iterations per ICP iteration.
    pub newton_iterations: usize,
    /// A penalty step ends when no imposed displacement changes by more than this, m.
    pub tolerance: f64,
    /// Pairs farther apart than mean + this × standard deviation are outliers (thesis: 2).
    pub outlier_sigma: f64,
    /// Pairs farther apart than this (m) are dropped as well: with a partial cloud, visible
    /// model points beyond the seen patch would otherwise be dragged onto its rim. `None`: no cap.
    pub max_pair_distance: Option<f64>,
}

impl Default for NonRigidSettings {
    fn default() -> Self {
        Self {
            alpha: 0.75,
            penalty_start: None,
            penalty_end: None,
            penalty_steps: 5,
            max_icp_iterations: 20,
            newton_iterations: 5,
            tolerance: 2e-4,
            outlier_sigma: 2.0,
            max_pair_distance: None,
        }
    }
}

/// Errors of the non-rigid stage.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NonRigidError {
    /// The cloud is empty.
    #[error("the point cloud is empty")]
    EmptyCloud,
    /// A cloud point is not finite.
    #[error("cloud point {0} has a non-finite coordinate")]
    NonFinite(usize),
    /// No model point is visible or every pair was an outlier.
    #[error(
        "no model surface point pairs with the cloud (nothing visible, or all pairs rejected)"
    )]
    NoCorrespondence,
    /// The visibility test could not be built.
    #[error("visibility: {0}")]
    Visibility(String),
}

/// What a non-rigid registration did.
#[derive(Debug, Clone, PartialEq)]
pub struct NonRigidReport {
    /// ICP iterations over all penalty steps.
    pub icp_iterations: usize,
    /// Newton iterations over all ICP iterations.
    pub newton_iterations: usize,
    /// RMS distance (m) between the kept source points and their nearest cloud points at the
    /// end.
    pub surface_rms: f64,
    /// Source points used in the last iteration.
    pub sources: usize,
    /// Whether every penalty step converged within its iteration budget.
    pub converged: bool,
    /// Failures the Newton solver reported (the state stays the last valid one).
    pub warnings: Vec<String>,
}

fn tree_of(points: &[Point3<f64>]) -> ImmutableKdTree<f64, 3> {
    let coords: Vec<[f64; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
    ImmutableKdTree::new_from_slice(&coords).expect("non-empty finite points")
}

fn nearest(tree: &ImmutableKdTree<f64, 3>, p: &Point3<f64>) -> (usize, f64) {
    let nn = tree
        .query(&[p.x, p.y, p.z])
        .nearest_one::<SquaredEuclidean<f64>>()
        .execute();
    (nn.item as usize, nn.distance.sqrt())
}

/// Mean + `sigma` × standard deviation of `d`.
fn rejection_threshold(d: &[f64], sigma: f64) -> f64 {
    let n = d.len().max(1) as f64;
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    mean + sigma * var.sqrt()
}

/// Registers `model` (its fixed regions stay held) to `cloud` (m, already rigidly aligned to
/// the model's frame), starting from grid displacements `u` (m; warm start) which are updated
/// in place. Source points are the surface vertices visible from `camera` on the current
/// deformed surface (parry3d ray casts); without a camera every vertex is a candidate and the
/// outlier rule removes those far from the cloud (documented fallback).
pub fn register_non_rigid(
    model: &mut SceneModel,
    cloud: &[Point3<f64>],
    camera: Option<&Camera>,
    u: &mut [f64],
    settings: &NonRigidSettings,
) -> Result<NonRigidReport, NonRigidError> {
    if cloud.is_empty() {
        return Err(NonRigidError::EmptyCloud);
    }
    if let Some(i) = cloud
        .iter()
        .position(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(NonRigidError::NonFinite(i));
    }
    let cloud_tree = tree_of(cloud);
    let fixed_sets = model.problem.springs.len();
    let h = model.problem.grid.grid.cell_size;
    let young = model.problem.material.mu * 2.0 * (1.0 + poisson(&model.problem.material));
    let k0 = settings.penalty_start.unwrap_or(0.02 * young * h);
    let k1 = settings.penalty_end.unwrap_or(2.0 * young * h);
    let steps = settings.penalty_steps.max(1);
    let mut newton = NewtonSolver::new(model.newton);
    let mut report = NonRigidReport {
        icp_iterations: 0,
        newton_iterations: 0,
        surface_rms: 0.0,
        sources: 0,
        converged: true,
        warnings: Vec::new(),
    };
    let emb = model.surface_embedding.clone();
    let triangles = model.surface.triangles.clone();
    for step in 0..steps {
        let k = if steps == 1 {
            k1
        } else {
            k0 * (k1 / k0).powf(step as f64 / (steps - 1) as f64)
        };
        let mut previous: Option<Vec<(usize, Point3<f64>)>> = None;
        let mut step_converged = false;
        for _ in 0..settings.max_icp_iterations {
            report.icp_iterations += 1;
            let x = emb.positions(u);
            let candidates: Vec<usize> = match camera {
                Some(cam) => {
                    let deformed = TriSurface::new(x.clone(), triangles.clone());
                    let vis = VisibleSurface::new(&deformed)
                        .map_err(|e| NonRigidError::Visibility(e.to_string()))?;
                    let mask = vis.visible_vertices(cam);
                    (0..x.len()).filter(|&i| mask[i]).collect()
                }
                None => (0..x.len()).collect(),
            };
            // Source → target pairs, pruned by the thesis's rule.
            let pairs: Vec<(usize, usize, f64)> = candidates
                .iter()
                .map(|&i| {
                    let (j, d) = nearest(&cloud_tree, &x[i]);
                    (i, j, d)
                })
                .collect();
            let dists: Vec<f64> = pairs.iter().map(|p| p.2).collect();
            let limit = rejection_threshold(&dists, settings.outlier_sigma)
                .min(settings.max_pair_distance.unwrap_or(f64::INFINITY));
            let kept: Vec<(usize, usize, f64)> =
                pairs.into_iter().filter(|p| p.2 <= limit).collect();
            if kept.len() < 3 {
                return Err(NonRigidError::NoCorrespondence);
            }
            // Target → source: V(i), the cloud points whose nearest kept source is i.
            let sources: Vec<Point3<f64>> = kept.iter().map(|p| x[p.0]).collect();
            let source_tree = tree_of(&sources);
            let back: Vec<(usize, f64)> = cloud.iter().map(|q| nearest(&source_tree, q)).collect();
            let back_limit = rejection_threshold(
                &back.iter().map(|b| b.1).collect::<Vec<_>>(),
                settings.outlier_sigma,
            );
            let mut sum = vec![Vector3::zeros(); kept.len()];
            let mut count = vec![0usize; kept.len()];
            for (j, &(s, d)) in back.iter().enumerate() {
                if d <= back_limit {
                    sum[s] += cloud[j] - sources[s];
                    count[s] += 1;
                }
            }
            // Imposed displacement of each source (eq. 5.4).
            let imposed: Vec<(usize, Vector3<f64>)> = kept
                .iter()
                .enumerate()
                .map(|(s, &(i, j, _))| {
                    let own = cloud[j] - x[i];
                    let d = if count[s] > 0 {
                        own * settings.alpha + (sum[s] / count[s] as f64) * (1.0 - settings.alpha)
                    } else {
                        own
                    };
                    (i, d)
                })
                .collect();
            report.sources = imposed.len();
            report.surface_rms =
                (kept.iter().map(|p| p.2 * p.2).sum::<f64>() / kept.len() as f64).sqrt();
            // Convergence: imposed displacements stopped changing.
            if let Some(prev) = &previous {
                let prev_map: std::collections::HashMap<usize, Point3<f64>> =
                    prev.iter().copied().collect();
                let change = imposed
                    .iter()
                    .map(|(i, d)| {
                        prev_map
                            .get(i)
                            .map_or(f64::INFINITY, |p| ((x[*i] + d) - p).norm())
                    })
                    .fold(0.0, f64::max);
                if change <= settings.tolerance {
                    step_converged = true;
                    break;
                }
            }
            // Springs from the current positions' targets, expressed as displacements from rest.
            let points = imposed.iter().map(|&(i, _)| emb.points[i]).collect();
            let rest = imposed.iter().map(|&(i, _)| emb.rest[i]).collect();
            let target = imposed
                .iter()
                .map(|&(i, d)| x[i] + d - emb.rest[i])
                .collect();
            let pull = PenaltySprings {
                embedding: Embedding { points, rest },
                target,
                stiffness: vec![k; imposed.len()],
                follows_load: false,
            };
            model.problem.springs.truncate(fixed_sets);
            model.problem.springs.push(pull);
            let r = newton.improve(&mut model.problem, u, settings.newton_iterations);
            report.newton_iterations += r.iterations;
            if let Some((outcome, msg)) = r.failure {
                report.warnings.push(format!("{}: {msg}", outcome.name()));
            }
            previous = Some(imposed.iter().map(|&(i, d)| (i, x[i] + d)).collect());
        }
        report.converged &= step_converged;
    }
    model.problem.springs.truncate(fixed_sets);
    Ok(report)
}

/// Poisson's ratio from the Lamé parameters.
fn poisson(m: &crate::mechanics::Material) -> f64 {
    m.lambda / (2.0 * (m.lambda + m.mu))
}
