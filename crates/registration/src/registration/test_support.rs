//! Test helpers: random rigid motions, a liver-ish test surface and clouds drawn from the
//! crate's seeded generator ([`crate::random::Rng`]).

use nalgebra::{Point3, Rotation3, Unit, Vector3};

use crate::mesh::primitives::icosphere;
use crate::mesh::TriSurface;
use crate::registration::RigidTransform;

pub(crate) use crate::random::Rng;

/// A rigid motion with rotation `angle` (radians) about a random axis and a translation of
/// length `shift` (metres) in a random direction.
pub(crate) fn random_motion(rng: &mut Rng, angle: f64, shift: f64) -> RigidTransform {
    let axis = Unit::new_normalize(rng.unit_vector());
    RigidTransform::new(
        Rotation3::from_axis_angle(&axis, angle),
        rng.unit_vector() * shift,
    )
}

/// A liver-ish closed surface: an ellipsoid 20 × 15 × 10 cm (semi-axes 10, 7.5, 5 cm) centred at
/// the origin, with a 2 cm lump and a 1 cm dent at generic places so that no rigid symmetry of
/// the ellipsoid survives. 5,120 triangles.
pub(crate) fn liver() -> TriSurface {
    let mut s = icosphere(Point3::origin(), 1.0, 4);
    let lump = Vector3::new(0.6, 0.5, 0.62).normalize();
    let dent = Vector3::new(-0.5, -0.7, 0.5).normalize();
    for v in &mut s.vertices {
        let u = v.coords;
        let mut p = Vector3::new(0.10 * u.x, 0.075 * u.y, 0.05 * u.z);
        p += u * (0.02 * (-(u - lump).norm_squared() / 0.15).exp());
        p -= u * (0.01 * (-(u - dent).norm_squared() / 0.1).exp());
        *v = Point3::from(p);
    }
    s
}

/// Total area (m²) and cumulative triangle areas, for area-weighted sampling.
fn cumulative_areas(s: &TriSurface) -> Vec<f64> {
    let mut acc = 0.0;
    (0..s.triangles.len())
        .map(|t| {
            acc += s.triangle_area(t);
            acc
        })
        .collect()
}

/// `n` points uniformly distributed (by area) on `s`, kept only if `keep` says so.
pub(crate) fn sample_surface(
    rng: &mut Rng,
    s: &TriSurface,
    n: usize,
    keep: impl Fn(&Point3<f64>) -> bool,
) -> Vec<Point3<f64>> {
    let cum = cumulative_areas(s);
    let total = *cum.last().unwrap();
    let mut out = Vec::with_capacity(n);
    let mut attempts = 0;
    while out.len() < n {
        attempts += 1;
        assert!(attempts < 1000 * n, "keep() rejects nearly everything");
        let r = rng.uniform() * total;
        let t = cum.partition_point(|&c| c < r).min(cum.len() - 1);
        let p = rng.point_on_triangle(&s.corners(t));
        if keep(&p) {
            out.push(p);
        }
    }
    out
}

/// A plane `{x : n·x = offset}` with random normal `n` cutting off about `fraction` of the
/// surface area of `s` on its positive side (found by the quantile of sampled points).
pub(crate) fn cutting_plane(rng: &mut Rng, s: &TriSurface, fraction: f64) -> (Vector3<f64>, f64) {
    let n = rng.unit_vector();
    let probe = sample_surface(rng, s, 4000, |_| true);
    let mut heights: Vec<f64> = probe.iter().map(|p| n.dot(&p.coords)).collect();
    heights.sort_by(f64::total_cmp);
    let offset = heights[((1.0 - fraction) * heights.len() as f64) as usize];
    (n, offset)
}

/// Adds isotropic Gaussian noise of standard deviation `sigma` (metres) per coordinate.
pub(crate) fn add_noise(rng: &mut Rng, points: &mut [Point3<f64>], sigma: f64) {
    for p in points {
        p.coords += Vector3::new(rng.gaussian(), rng.gaussian(), rng.gaussian()) * sigma;
    }
}
