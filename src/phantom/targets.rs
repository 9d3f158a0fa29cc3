//! Vessel-bifurcation-like internal target points: a small deterministic branching tree
//! grown from the hilum on the visceral face into both lobes.
//!
//! The tree is grown in the reference coordinates of [`liver_map`] (where "inside" is simply
//! [`reference_gauge`] < 1) and mapped to metres; each bifurcation point is then pulled towards the core of
//! its lobe until it is at least [`TARGET_CLEARANCE`] from the liver surface.

use nalgebra::{Point3, Rotation3, Unit, Vector3};

use super::distance::distance_to_surface;
use super::liver_surface::{liver_map, quantize, reference_gauge};
use crate::geometry::InsideTest;
use crate::mesh::TriSurface;

/// Minimum distance of every target from the liver surface, in metres (10 mm).
pub const TARGET_CLEARANCE: f64 = 0.010;

/// Minimum distance between two targets, in metres (6 mm): closer bifurcations are merged.
pub const TARGET_SEPARATION: f64 = 0.006;

/// Hilum (porta hepatis) in reference coordinates: low, slightly posterior, right of
/// the centre.
const HILUM: [f64; 3] = [-0.10, -0.12, -0.45];

/// One branch to grow: start, unit direction and length in reference units, remaining
/// bifurcation levels, and the lobe core towards which its points are pulled if needed.
struct Branch {
    start: Vector3<f64>,
    dir: Vector3<f64>,
    length: f64,
    levels: usize,
    core: Vector3<f64>,
}

/// Bifurcation points of the vessel tree in reference coordinates, in a fixed
/// (depth-first) order, each paired with the core of its lobe.
fn bifurcations_ref() -> Vec<(Vector3<f64>, Vector3<f64>)> {
    let hilum = Vector3::from(HILUM);
    let right_core = Vector3::new(-0.45, -0.05, 0.0);
    let left_core = Vector3::new(0.35, 0.0, 0.0);
    let mut out = vec![(hilum, right_core)];
    // Right portal vein (into the thick right lobe, one level deeper) and left portal vein.
    let mut stack = vec![
        Branch {
            start: hilum,
            dir: Vector3::new(0.5, 0.15, 0.3).normalize(),
            length: 0.40,
            levels: 3,
            core: left_core,
        },
        Branch {
            start: hilum,
            dir: Vector3::new(-0.6, 0.05, 0.45).normalize(),
            length: 0.36,
            levels: 4,
            core: right_core,
        },
    ];
    while let Some(b) = stack.pop() {
        let end = b.start + b.dir * b.length;
        if b.levels == 0 {
            continue;
        }
        out.push((end, b.core));
        // The split plane alternates between (nearly) horizontal and vertical with depth.
        let reference = if b.levels % 2 == 0 {
            Vector3::z()
        } else {
            Vector3::y()
        };
        let mut axis = b.dir.cross(&reference);
        if axis.norm() < 1e-3 {
            axis = b.dir.cross(&Vector3::x());
        }
        let axis = Unit::new_normalize(axis);
        for angle in [0.75, -0.65] {
            let dir = Rotation3::from_axis_angle(&axis, angle) * b.dir;
            stack.push(Branch {
                start: end,
                dir,
                length: b.length * 0.85,
                levels: b.levels - 1,
                core: b.core,
            });
        }
    }
    out
}

/// The vessel-bifurcation targets in metres for the liver `surface` (the one built by
/// [`super::liver_surface::liver_surface`]): every point is inside and at least
/// [`TARGET_CLEARANCE`] from the surface, no two closer than [`TARGET_SEPARATION`];
/// coordinates rounded to [`super::liver_surface::COORDINATE_QUANTUM`]. Deterministic order.
pub fn vessel_targets(surface: &TriSurface) -> Vec<Point3<f64>> {
    let inside = InsideTest::new(&surface.vertices, &surface.triangles);
    let ok = |p: &Point3<f64>| {
        inside.contains(p) && distance_to_surface(surface, p) >= TARGET_CLEARANCE + 1e-4
    };
    let mut targets: Vec<Point3<f64>> = Vec::new();
    for (mut r, core) in bifurcations_ref() {
        // Keep well inside the reference solid, then pull towards the lobe core until clear.
        let gauge = reference_gauge(r);
        if gauge > 0.8 {
            r *= 0.8 / gauge;
        }
        let mut p = quantize(liver_map(r));
        let mut tries = 0;
        while !ok(&p) && tries < 40 {
            r = core + (r - core) * 0.9;
            p = quantize(liver_map(r));
            tries += 1;
        }
        if ok(&p) && targets.iter().all(|q| (q - p).norm() >= TARGET_SEPARATION) {
            targets.push(p);
        }
    }
    targets
}
