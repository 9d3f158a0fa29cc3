//! Volumetric locking: a cantilever of nearly incompressible material (ν = 0.499) must bend like
//! its converged reference (Timoshenko beam theory), not like a brick. Selective reduced
//! integration of the volumetric part is compared with full integration on the same grid.

use crate::common;

use common::*;
use livereg::grid::{Embedding, IntegrationMode};
use livereg::mechanics::loads::traction_forces;
use livereg::mechanics::{LawKind, NewtonSettings, NewtonSolver, Outcome, VolumetricIntegration};
use livereg::mesh::primitives::box_surface;
use nalgebra::{Point3, Vector3};

const L: f64 = 0.4;
const T: f64 = 0.04;
const E: f64 = 1e4;
const TRACTION: f64 = 5.0; // Pa, downward on the end face: a small, linear-regime load

/// Tip deflection (m, positive downwards) of the cantilever on cells of edge `h`.
fn tip_deflection(nu: f64, vol: VolumetricIntegration, h: f64) -> f64 {
    let s = box_surface(Point3::new(0.0, 0.0, 0.0), Point3::new(L, T, T), 8);
    let mut p = problem(
        &s,
        &options(h, 1, IntegrationMode::WeightedCell),
        material(LawKind::Linear, E, nu),
        vol,
    );
    p.springs = vec![hold(
        &p,
        &s,
        aabb([-1e-4, -1.0, -1.0], [1e-4, 1.0, 1.0]),
        1e4,
        E,
    )];
    let mut f = vec![0.0; p.dofs()];
    traction_forces(
        &p.grid,
        &s,
        &aabb([L - 1e-4, -1.0, -1.0], [L + 1e-4, 1.0, 1.0]),
        Vector3::new(0.0, 0.0, -TRACTION),
        &mut f,
    )
    .unwrap();
    p.external = f;
    let u0 = vec![0.0; p.dofs()];
    let r = NewtonSolver::new(NewtonSettings {
        load_steps: 1,
        ..NewtonSettings::default()
    })
    .solve(&mut p, &[], &u0);
    assert_eq!(r.outcome, Outcome::Converged);
    let e = Embedding::new(&p.grid, &[Point3::new(L - 1e-6, 0.5 * T, 0.5 * T)]).unwrap();
    -e.interpolate(&r.u)[0].z
}

/// Timoshenko beam: δ = P L³ / (3 E I) + P L / (κ G A), κ = 5/6.
fn timoshenko(nu: f64) -> f64 {
    let area = T * T;
    let force = TRACTION * area;
    let inertia = T.powi(4) / 12.0;
    let g = E / (2.0 * (1.0 + nu));
    force * L.powi(3) / (3.0 * E * inertia) + force * L / (5.0 / 6.0 * g * area)
}

#[test]
fn nearly_incompressible_cantilever_bends_like_its_reference() {
    let nu = 0.499;
    let reference = timoshenko(nu);
    let h = T / 4.0;
    let reduced = tip_deflection(nu, VolumetricIntegration::Reduced, h);
    let full = tip_deflection(nu, VolumetricIntegration::Full, h);
    let reduced_compressible = tip_deflection(0.3, VolumetricIntegration::Reduced, h);
    println!(
        "ν = 0.499, 4 cells through the thickness: Timoshenko {reference:.5e} m, reduced {reduced:.5e} ({:.3}), full {full:.5e} ({:.3}); ν = 0.3 reduced / Timoshenko {:.3}",
        reduced / reference,
        full / reference,
        reduced_compressible / timoshenko(0.3)
    );
    assert!(
        (reduced / reference - 1.0).abs() < 0.06,
        "reduced integration ratio {}",
        reduced / reference
    );
    // Full integration locks: more than 30 % too stiff on the same grid.
    assert!(
        full / reference < 0.7,
        "full integration should lock: ratio {}",
        full / reference
    );
}
