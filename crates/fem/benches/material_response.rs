//! Criterion benchmark of the material laws' point kernels (`Material::response`, `pk1`,
//! `energy`): what one quadrature point costs the cell kernel, per law, E 4.5 kPa, ν 0.45,
//! over 64 deformation gradients `Q₁ diag(λ) Q₂` with stretches λ in [0.7, 1.4] and random
//! rotations (a seeded generator: the same gradients every run).
//!
//! Run: `cargo bench --bench material_response -- --warm-up-time 1 --measurement-time 2`

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use livereg_fem::mechanics::material::Mat3;
use livereg_fem::mechanics::{LawKind, Material, Part};
use livereg_fem::random::Rng;
use nalgebra::{Rotation3, Vector3};

/// A rotation about a random axis by a random angle in [0, π).
fn rotation(rng: &mut Rng) -> Mat3 {
    let axis = Vector3::from_fn(|_, _| rng.uniform_in(-0.5, 0.5));
    Rotation3::from_scaled_axis(axis.normalize() * rng.uniform_in(0.0, std::f64::consts::PI))
        .into_inner()
}

/// The 64 gradients, from the crate's seeded generator (the same every run).
fn gradients() -> Vec<Mat3> {
    let mut rng = Rng::new(0x5EED_0007);
    (0..64)
        .map(|_| {
            let (q1, q2) = (rotation(&mut rng), rotation(&mut rng));
            let l = Vector3::from_fn(|_, _| rng.uniform_in(0.7, 1.4));
            q1 * Mat3::from_diagonal(&l) * q2
        })
        .collect()
}

fn bench_material_response(c: &mut Criterion) {
    let fs = gradients();
    let mut group = c.benchmark_group("material_response");
    for law in LawKind::ALL {
        let m = Material::from_young_poisson(law, 4500.0, 0.45).expect("material");
        let name = format!("{law:?}");
        group.bench_function(format!("{name}/response x64"), |b| {
            b.iter(|| {
                for f in &fs {
                    black_box(m.response(black_box(f), Part::Full).expect("response"));
                }
            })
        });
        group.bench_function(format!("{name}/pk1 x64"), |b| {
            b.iter(|| {
                for f in &fs {
                    black_box(m.pk1(black_box(f), Part::Full).expect("pk1"));
                }
            })
        });
        group.bench_function(format!("{name}/energy x64"), |b| {
            b.iter(|| {
                for f in &fs {
                    black_box(m.energy(black_box(f), Part::Full).expect("energy"));
                }
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_material_response);
criterion_main!(benches);
