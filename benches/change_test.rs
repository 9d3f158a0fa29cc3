//! Benchmark of a warm frame's test of change (`registration::change_evidence`, the session's
//! "change" stage): the cloud's k-d tree, the 32-neighbour lists of `ChangeTest::neighbours`,
//! the noise estimate's quadric fits over each point's 16 nearest
//! (`cloud_noise_sigma_near`) and the test itself over given signed distances
//! (`ChangeTest::evaluate_near`). The cloud: a camera's patch of 680 points (the phantom's
//! warm clouds) on a curved 12 × 9 cm surface with 1.5 mm noise. And the signed distances
//! the test is given (`SurfaceDistances`: the k-d tree and normals of a 2,562-vertex surface,
//! then each point's closest point on the triangles around its nearest vertex), for 680
//! points off a 10 cm sphere. And the still window's test against its first cloud: each
//! point's 32 nearest points of a second cloud of the same patch
//! (`ChangeTest::neighbours_in`) and the comparison of the two clouds' local medians
//! (`ChangeTest::evaluate_against`).
//!
//! Run: `cargo bench --bench change_test -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;
use std::sync::Arc;

#[path = "support/camera_patch.rs"]
mod camera_patch;
use camera_patch::camera_patch;

use criterion::{criterion_group, criterion_main, Criterion};
use livereg::mesh::primitives::icosphere;
use livereg::random::Rng;
use livereg::registration::IndexedPoints;
use livereg::registration::{cloud_noise_sigma_near, ChangeTest};
use livereg::registration::{SurfaceDistances, SurfaceTopology};
use nalgebra::Point3;

fn bench_change_test(c: &mut Criterion) {
    let mut rng = Rng::new(11);
    let points = camera_patch(&mut rng);
    // Signed distances as a cloud at rest gives them: noise only.
    let signed: Vec<f64> = points.iter().map(|_| 0.0015 * rng.gaussian()).collect();
    let test = ChangeTest::default();
    let cloud = IndexedPoints::new(points.clone()).unwrap();
    let near = test.neighbours(&cloud);
    let mut group = c.benchmark_group("change_test");
    group.bench_function("k-d tree", |b| {
        b.iter(|| black_box(IndexedPoints::new(points.clone())))
    });
    group.bench_function("neighbour lists", |b| {
        b.iter(|| black_box(test.neighbours(&cloud)))
    });
    group.bench_function("noise", |b| {
        b.iter(|| black_box(cloud_noise_sigma_near(&cloud, &near)))
    });
    group.bench_function("test", |b| {
        b.iter(|| black_box(test.evaluate_near(&near, &signed, 0.0015)))
    });
    let reference_points = camera_patch(&mut rng);
    let reference = IndexedPoints::new(reference_points.clone()).unwrap();
    let reference_signed: Vec<f64> = reference_points
        .iter()
        .map(|_| 0.0015 * rng.gaussian())
        .collect();
    group.bench_function("neighbours in the first cloud", |b| {
        b.iter(|| black_box(test.neighbours_in(&points, &reference)))
    });
    let reference_near = test.neighbours_in(&points, &reference);
    group.bench_function("test against the first cloud", |b| {
        b.iter(|| {
            black_box(test.evaluate_against(
                &near,
                &signed,
                &reference_near,
                &reference_signed,
                0.0015,
            ))
        })
    });
    let sphere = icosphere(Point3::origin(), 0.1, 4);
    let off: Vec<Point3<f64>> = (0..680)
        .map(|_| Point3::from(rng.unit_vector() * (0.1 + 0.0015 * rng.gaussian())))
        .collect();
    let topology = Arc::new(SurfaceTopology::new(
        sphere.vertices.len(),
        &sphere.triangles,
    ));
    group.bench_function("surface index", |b| {
        b.iter(|| {
            black_box(SurfaceDistances::new(
                sphere.vertices.clone(),
                topology.clone(),
            ))
        })
    });
    let surface = SurfaceDistances::new(sphere.vertices.clone(), topology.clone()).unwrap();
    group.bench_function("signed distances", |b| {
        b.iter(|| black_box(surface.signed_distances(&off)))
    });
    group.finish();
}

criterion_group!(benches, bench_change_test);
criterion_main!(benches);
