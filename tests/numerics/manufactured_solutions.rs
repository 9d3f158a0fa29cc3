//! Manufactured solutions: a smooth displacement field u*, its body force b = −Div P(I + ∇u*),
//! and the discrete solution's L2 error under refinement.
//! - grid-aligned box (boundary nodes held at u* = 0): order ≥ 1.8, linear and neo-Hookean;
//! - immersed sphere (u* imposed by penalty springs on the cut surface): order reported, ≥ 1.

use crate::common;

use std::f64::consts::PI;

use common::*;
use livereg::grid::{Embedding, IntegrationMode};
use livereg::mechanics::loads::body_forces;
use livereg::mechanics::{
    LawKind, Material, NewtonSettings, NewtonSolver, Outcome, PenaltySprings, StaticProblem,
    VolumetricIntegration,
};
use livereg::mesh::primitives::{box_surface, icosphere};
use nalgebra::{Matrix3, Point3, Vector3};

/// A smooth field and its gradient.
trait Field: Sync {
    fn u(&self, x: &Point3<f64>) -> Vector3<f64>;
    fn grad(&self, x: &Point3<f64>) -> Matrix3<f64>;
}

/// Products of sines vanishing on the faces of [0, L]³.
struct BoxField {
    l: f64,
    a: f64,
}

impl Field for BoxField {
    fn u(&self, x: &Point3<f64>) -> Vector3<f64> {
        let s = |m: f64, t: f64| (m * PI * t / self.l).sin();
        Vector3::new(
            self.a * s(1.0, x.x) * s(1.0, x.y) * s(1.0, x.z),
            -0.6 * self.a * s(2.0, x.x) * s(1.0, x.y) * s(1.0, x.z),
            0.8 * self.a * s(1.0, x.x) * s(1.0, x.y) * s(2.0, x.z),
        )
    }
    fn grad(&self, x: &Point3<f64>) -> Matrix3<f64> {
        let k = PI / self.l;
        let s = |m: f64, t: f64| (m * k * t).sin();
        let c = |m: f64, t: f64| m * k * (m * k * t).cos();
        let row = |amp: f64, m: [f64; 3]| {
            [
                amp * c(m[0], x.x) * s(m[1], x.y) * s(m[2], x.z),
                amp * s(m[0], x.x) * c(m[1], x.y) * s(m[2], x.z),
                amp * s(m[0], x.x) * s(m[1], x.y) * c(m[2], x.z),
            ]
        };
        let (r0, r1, r2) = (
            row(self.a, [1.0, 1.0, 1.0]),
            row(-0.6 * self.a, [2.0, 1.0, 1.0]),
            row(0.8 * self.a, [1.0, 1.0, 2.0]),
        );
        Matrix3::new(
            r0[0], r0[1], r0[2], r1[0], r1[1], r1[2], r2[0], r2[1], r2[2],
        )
    }
}

/// A smooth field that does not vanish on a sphere of radius R.
struct SphereField {
    r: f64,
    a: f64,
}

impl Field for SphereField {
    fn u(&self, x: &Point3<f64>) -> Vector3<f64> {
        let k = 1.3 / self.r;
        Vector3::new(
            self.a * (k * x.y).sin() * (0.5 * k * x.z).cos(),
            self.a * (k * x.z + 0.3).sin(),
            self.a * (k * x.x).cos() * (0.7 * k * x.y).sin(),
        )
    }
    fn grad(&self, x: &Point3<f64>) -> Matrix3<f64> {
        let k = 1.3 / self.r;
        let a = self.a;
        Matrix3::new(
            0.0,
            a * k * (k * x.y).cos() * (0.5 * k * x.z).cos(),
            -a * 0.5 * k * (k * x.y).sin() * (0.5 * k * x.z).sin(),
            0.0,
            0.0,
            a * k * (k * x.z + 0.3).cos(),
            -a * k * (k * x.x).sin() * (0.7 * k * x.y).sin(),
            a * 0.7 * k * (k * x.x).cos() * (0.7 * k * x.y).cos(),
            0.0,
        )
    }
}

/// b = −Div P(I + ∇u*), the divergence by central differences of the exact stress field.
fn body_force(material: &Material, field: &dyn Field, x: &Point3<f64>, scale: f64) -> Vector3<f64> {
    let d = 1e-6 * scale;
    let mut div = Vector3::zeros();
    for j in 0..3 {
        let mut e = Vector3::zeros();
        e[j] = d;
        let p = |y: Point3<f64>| {
            material
                .pk1(
                    &(Matrix3::identity() + field.grad(&y)),
                    livereg::mechanics::Part::Full,
                )
                .unwrap()
        };
        let dp = (p(x + e) - p(x - e)) / (2.0 * d);
        div += dp.column(j);
    }
    -div
}

/// Solves the problem with body force from `field` and returns the relative RMS error of the
/// displacement over `samples` (points inside the body, independent of the grid).
fn solve_and_measure(
    mut p: StaticProblem,
    field: &dyn Field,
    samples: &[Point3<f64>],
    scale: f64,
    steps: usize,
) -> f64 {
    let material = p.material;
    let mut f = vec![0.0; p.dofs()];
    body_forces(&p.grid, |x| body_force(&material, field, x, scale), &mut f);
    p.external = f;
    let settings = NewtonSettings {
        load_steps: steps,
        residual_tolerance: 1e-10,
        ..NewtonSettings::default()
    };
    let u0 = vec![0.0; p.dofs()];
    let report = NewtonSolver::new(settings).solve(&mut p, &[], &u0);
    assert_eq!(report.outcome, Outcome::Converged, "{:?}", report.message);
    let emb = Embedding::new(&p.grid, samples).unwrap();
    let uh = emb.interpolate(&report.u);
    let (mut num, mut den) = (0.0, 0.0);
    for (x, v) in samples.iter().zip(uh) {
        let ue = field.u(x);
        num += (v - ue).norm_squared();
        den += ue.norm_squared();
    }
    (num / den).sqrt()
}

/// A lattice of points inside a region, offset so that none falls on a grid node.
fn lattice(lo: f64, hi: f64, n: usize, keep: impl Fn(&Point3<f64>) -> bool) -> Vec<Point3<f64>> {
    let mut out = Vec::new();
    let t = |i: usize| lo + (hi - lo) * (i as f64 + 0.37) / n as f64;
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                let p = Point3::new(t(i), t(j), t(k));
                if keep(&p) {
                    out.push(p);
                }
            }
        }
    }
    out
}

fn box_errors(law: LawKind, amplitude: f64, steps: usize) -> Vec<f64> {
    let l = 0.1;
    let field = BoxField { l, a: amplitude };
    let surface = box_surface(Point3::origin(), Point3::new(l, l, l), 4);
    let young = 1e4;
    let samples = lattice(0.0, l, 17, |_| true);
    [4usize, 8, 16]
        .iter()
        .map(|&n| {
            let h = l / n as f64;
            let mut p = problem(
                &surface,
                &options(h, 1, IntegrationMode::WeightedCell),
                material(law, young, 0.3),
                VolumetricIntegration::Reduced,
            );
            // Hold every boundary node at u* = 0 with a stiff spring (1e6 E h).
            let dims = p.grid.grid.dims;
            let boundary: Vec<Point3<f64>> = (0..p.grid.node_count())
                .filter(|&a| {
                    let c = p.grid.node_coords[a];
                    (0..3).any(|d| c[d] == 0 || c[d] == dims[d])
                })
                .map(|a| p.grid.node_position(a))
                .collect();
            let k = vec![1e6 * young * h; boundary.len()];
            p.springs = vec![PenaltySprings::fixed(
                Embedding::new(&p.grid, &boundary).unwrap(),
                k,
            )];
            solve_and_measure(p, &field, &samples, l, steps)
        })
        .collect()
}

fn rates(e: &[f64]) -> Vec<f64> {
    e.windows(2).map(|w| (w[0] / w[1]).log2()).collect()
}

#[test]
fn box_linear_elasticity_converges_at_second_order() {
    let e = box_errors(LawKind::Linear, 1e-3, 1);
    let r = rates(&e);
    println!("box, linear: errors {e:?}, orders {r:?}");
    assert!(r.iter().all(|&x| x >= 1.8), "orders {r:?}");
}

#[test]
fn box_neo_hookean_large_strain_converges_at_second_order() {
    // Amplitude 1 cm on a 10 cm box: strains up to ~30 %.
    let e = box_errors(LawKind::NeoHookean, 1e-2, 4);
    let r = rates(&e);
    println!("box, neo-Hookean: errors {e:?}, orders {r:?}");
    assert!(r.iter().all(|&x| x >= 1.8), "orders {r:?}");
}

#[test]
fn immersed_sphere_with_penalty_boundary_converges() {
    let radius = 0.05;
    let field = SphereField { r: radius, a: 2e-3 };
    let surface = icosphere(Point3::new(0.0013, -0.0007, 0.0004), radius, 5);
    let young = 1e4;
    let samples = lattice(-radius, radius, 16, |p| p.coords.norm() < 0.97 * radius);
    let mut errors = Vec::new();
    for n in [3usize, 6, 12, 24] {
        let h = 2.0 * radius / n as f64;
        let mut p = problem(
            &surface,
            &options(h, 3, IntegrationMode::WeightedCell),
            material(LawKind::Linear, young, 0.3),
            VolumetricIntegration::Reduced,
        );
        // Penalty springs on the whole surface, density κ E / h, pulling to u*.
        let mut s = hold(&p, &surface, aabb([-1.0; 3], [1.0; 3]), 1e4, young);
        s.target = s.embedding.rest.iter().map(|x| field.u(x)).collect();
        s.follows_load = true;
        p.springs = vec![s];
        errors.push(solve_and_measure(p, &field, &samples, radius, 1));
    }
    let r = rates(&errors);
    println!("immersed sphere (weighted-cell, 3 levels): errors {errors:?}, observed orders {r:?}");
    assert!(*r.last().unwrap() >= 1.0, "orders {r:?}");
}
