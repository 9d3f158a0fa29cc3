//! Test helpers: a seeded RNG with Box–Muller normals, a liver-ish test surface and clouds.

use nalgebra::{Point3, Rotation3, Unit, Vector3};

use crate::mesh::primitives::icosphere;
use crate::mesh::TriSurface;
use crate::registration::RigidTransform;

/// SplitMix64: small, seeded, good enough for test data.
pub(crate) struct Rng(u64);

impl Rng {
    pub(crate) fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03)
    }

    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub(crate) fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    pub(crate) fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    pub(crate) fn index(&mut self, n: usize) -> usize {
        ((self.unit() * n as f64) as usize).min(n - 1)
    }

    /// Standard normal by Box–Muller.
    pub(crate) fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.unit(); // (0, 1]
        let u2 = self.unit();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    pub(crate) fn unit_vector(&mut self) -> Vector3<f64> {
        loop {
            let v = Vector3::new(self.normal(), self.normal(), self.normal());
            let n = v.norm();
            if n > 1e-6 {
                return v / n;
            }
        }
    }

    pub(crate) fn point_on_triangle(&mut self, [a, b, c]: &[Point3<f64>; 3]) -> Point3<f64> {
        let (mut u, mut v) = (self.unit(), self.unit());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        a + (b - a) * u + (c - a) * v
    }

    /// A rigid motion with rotation `angle` (radians) about a random axis and a translation of
    /// length `shift` (metres) in a random direction.
    pub(crate) fn motion(&mut self, angle: f64, shift: f64) -> RigidTransform {
        let axis = Unit::new_normalize(self.unit_vector());
        RigidTransform::new(
            Rotation3::from_axis_angle(&axis, angle),
            self.unit_vector() * shift,
        )
    }
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
        let r = rng.unit() * total;
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
        p.coords += Vector3::new(rng.normal(), rng.normal(), rng.normal()) * sigma;
    }
}
