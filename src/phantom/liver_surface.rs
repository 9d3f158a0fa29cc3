//! The liver-shaped closed surface, as the image of the unit sphere under a smooth,
//! injective map.
//!
//! The map [`liver_map`] takes reference coordinates `(u, v, w)` to metres by
//! a *triangular* monotone map: `x` depends on `u` only, `y` on `(u, v)` and is strictly
//! increasing in `v`, `z` on `(u, v, w)` and is strictly increasing in `w`. Such a map is
//! injective with a positive Jacobian everywhere, so the image of a subdivided icosphere is a
//! closed, watertight, outward-oriented surface without self-intersections (up to the
//! piecewise-linear approximation, which is fine at the resolution used), and the image of any
//! point inside the reference solid (see [`reference_gauge`]) lies inside the liver.
//!
//! The reference solid is a rounded, star-shaped body of half-extent 1 on every axis (fuller
//! than the unit ball, so that the liver's cross-sections are rounded rectangles rather than
//! ellipses); the surface is a subdivided icosphere pushed radially onto its boundary.

use nalgebra::{Point3, Vector3};

use crate::mesh::primitives::icosphere;
use crate::mesh::TriSurface;

/// Icosphere subdivision levels of the liver surface (level 4: 2562 vertices, 5120 triangles).
pub const SURFACE_LEVELS: usize = 4;

/// Grid to which every generated coordinate is rounded, in metres (0.1 µm), so that the files
/// written in millimetres with 4 decimals hold exactly the in-memory values.
pub const COORDINATE_QUANTUM: f64 = 1e-7;

/// Rounds each coordinate of `p` (metres) to a multiple of [`COORDINATE_QUANTUM`].
pub fn quantize(p: Point3<f64>) -> Point3<f64> {
    p.map(|c| {
        let q = (c * 1e7).round() / 1e7;
        // Avoid "-0" so that the written text does not depend on the sign of zero.
        if q == 0.0 {
            0.0
        } else {
            q
        }
    })
}

/// Smooth step from 0 (right lobe, `u` < 0) to 1 (left lobe, `u` > 0.3), dimensionless.
fn left_share(u: f64) -> f64 {
    0.5 * (1.0 + ((u - 0.20) / 0.22).tanh())
}

/// Smooth, monotone "positive part": ≈ 0 for `t ≪ −EPS`, ≈ `t` for `t ≫ EPS`, derivative in
/// (0, 1), value 0 at `t = 0`.
fn soft_plus(t: f64) -> f64 {
    const EPS: f64 = 0.15;
    0.5 * (t + (t * t + EPS * EPS).sqrt() - EPS)
}

/// Gaussian bump `exp(−(t/width)²)`, dimensionless.
fn bump(t: f64, width: f64) -> f64 {
    (-(t / width).powi(2)).exp()
}

/// Exponent of the super-ellipse that shapes the (v, w) cross-sections of the reference
/// solid (2 would be a disc; larger is fuller, closer to a rounded rectangle).
const SECTION_EXPONENT: f64 = 4.0;

/// Exponent combining `|u|` with the cross-section gauge (2 would give ellipsoid-like ends).
const LENGTH_EXPONENT: f64 = 2.5;

/// The reference solid's boundary point in the direction of `n` (any non-zero vector):
/// `n / N(n)` with the 1-homogeneous gauge `N(n) = (|u|^q + (|v|^p + |w|^p)^(q/p))^(1/q)`, which
/// is ≤ 1 exactly inside the reference solid (a ball whose cross-sections across x are
/// super-ellipses). Star-shaped around the origin, so the result is a closed surface.
pub fn reference_boundary(n: Vector3<f64>) -> Vector3<f64> {
    n / reference_gauge(n)
}

/// The gauge `N` of [`reference_boundary`]: < 1 strictly inside the reference solid,
/// 1 on its boundary (dimensionless, positively homogeneous of degree 1).
pub fn reference_gauge(n: Vector3<f64>) -> f64 {
    let p = SECTION_EXPONENT;
    let section = (n.y.abs().powf(p) + n.z.abs().powf(p)).powf(1.0 / p);
    let q = LENGTH_EXPONENT;
    (n.x.abs().powf(q) + section.powf(q)).powf(1.0 / q)
}

/// Maps reference coordinates (`u`: right → left, `v`: back → front, `w`: bottom → top, all
/// dimensionless, the reference solid spanning [−1, 1] on each axis) to liver coordinates in metres
/// (x: patient right → left, y: back → front, z: bottom → top).
///
/// Points with [`reference_gauge`] < 1 map inside the liver, those with gauge 1 onto its
/// (smooth) surface. Liver shape: thick right lobe (u < 0), thin left lobe (u > 0.3), the
/// umbilical notch in the front edge at u ≈ 0.24, a dome on top and a concave visceral face
/// below the right lobe.
pub fn liver_map(b: Vector3<f64>) -> Point3<f64> {
    let (u, v, w) = (b.x, b.y, b.z);
    let left = left_share(u);

    // x: 20 cm long, the left-lobe tip slightly stretched.
    let x = 0.100 * u + 0.004 * (1.0 - u * u) * left;

    // y: back half-depth and front half-depth (both > 0 ⇒ monotone in v); the front edge has
    // the umbilical notch between the right and the left lobe.
    let back = 0.070 - 0.022 * left;
    let notch = 0.034 * bump(u - 0.24, 0.10);
    let front = 0.082 - 0.030 * left - notch;
    let y = 0.004 * left + back * v + (front - back) * soft_plus(v);

    // z: bottom and top half-thickness (both > 0 ⇒ monotone in w), thick at the back of the
    // right lobe, thin at the anterior edge and in the left lobe; the mid-surface carries a
    // bump that domes the diaphragmatic face and makes the visceral face concave.
    let taper = 1.0 - 0.25 * v;
    let below = (0.034 - 0.024 * left) * taper;
    let above = (0.051 - 0.036 * left) * taper;
    let dome = 0.020 * bump(u + 0.32, 0.28) * bump(v + 0.05, 0.32);
    let mid = -0.014 + 0.010 * left + dome;
    let z = mid + below * w + (above - below) * soft_plus(w);

    Point3::new(x, y, z)
}

/// The liver surface in metres: a level-[`SURFACE_LEVELS`] icosphere pushed onto the
/// reference solid's boundary ([`reference_boundary`]) and mapped by [`liver_map`], coordinates rounded to [`COORDINATE_QUANTUM`]. Closed, watertight,
/// outward-oriented, 5120 triangles.
pub fn liver_surface() -> TriSurface {
    let sphere = icosphere(Point3::origin(), 1.0, SURFACE_LEVELS);
    let vertices = sphere
        .vertices
        .iter()
        .map(|p| quantize(liver_map(reference_boundary(p.coords))))
        .collect();
    TriSurface::new(vertices, sphere.triangles)
}
