//! Criterion benchmark of camera visibility and cloud synthesis on a 5,120-triangle sphere of
//! 10 cm radius seen from 30 cm: `VisibleSurface::new` (the triangles' BVH, built on every
//! visibility update of a warm frame with a camera), `visible_vertices` (a ray per vertex),
//! and `synthesize_cloud` (about 2,000 points at 5 samples/cm², 1 mm noise, 5 % outliers: what
//! the synthetic scenarios and the bench generate per frame).
//!
//! Run: `cargo bench --bench cloud_synthesis -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use livereg::mesh::primitives::icosphere;
use livereg::synthetic::{synthesize_cloud, Camera, CloudSpec, VisibleSurface};
use nalgebra::{Point3, Vector3};

fn bench_cloud_synthesis(c: &mut Criterion) {
    let radius = 0.1;
    let surface = icosphere(Point3::origin(), radius, 4);
    let direction = Vector3::new(1.0, 2.0, 3.0).normalize();
    let camera =
        Camera::looking_at(Point3::from(direction * 3.0 * radius), Point3::origin()).unwrap();
    let spec = CloudSpec {
        density_per_cm2: 5.0,
        noise_sigma: 1e-3,
        outlier_fraction: 0.05,
        seed: 1,
        ..Default::default()
    };
    let points = synthesize_cloud(&surface, &camera, &spec)
        .unwrap()
        .points
        .len();
    eprintln!(
        "{} triangles, {} vertices, {points} cloud points",
        surface.triangles.len(),
        surface.vertices.len()
    );
    let mut group = c.benchmark_group("cloud_synthesis");
    group.sample_size(20);
    group.bench_function("VisibleSurface::new", |b| {
        b.iter(|| black_box(VisibleSurface::new(black_box(&surface)).unwrap()))
    });
    let visible = VisibleSurface::new(&surface).unwrap();
    group.bench_function("visible_vertices", |b| {
        b.iter(|| black_box(visible.visible_vertices(black_box(&camera))))
    });
    let mut seed = 0;
    group.bench_function("synthesize_cloud", |b| {
        b.iter(|| {
            seed += 1;
            black_box(synthesize_cloud(&surface, &camera, &CloudSpec { seed, ..spec }).unwrap())
        })
    });
    group.finish();
}

criterion_group!(benches, bench_cloud_synthesis);
criterion_main!(benches);
