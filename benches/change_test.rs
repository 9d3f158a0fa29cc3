//! Benchmark of a warm frame's test of change (`registration::change_evidence`, the session's
//! "change" stage): the cloud's k-d tree, the 32-neighbour lists of `ChangeTest::neighbours`,
//! the noise estimate's quadric fits over each point's 16 nearest
//! (`cloud_noise_sigma_near`) and the test itself over given signed distances
//! (`ChangeTest::evaluate_near`). The cloud: a camera's patch of 680 points (the phantom's
//! warm clouds) on a curved 12 × 9 cm surface with 1.5 mm noise.
//!
//! Run: `cargo bench --bench change_test -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;

#[path = "support/camera_patch.rs"]
mod camera_patch;
use camera_patch::camera_patch;

use criterion::{criterion_group, criterion_main, Criterion};
use livereg::random::Rng;
use livereg::registration::change_evidence::{cloud_noise_sigma_near, ChangeTest};
use livereg::registration::correspondences::IndexedPoints;

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
    group.finish();
}

criterion_group!(benches, bench_change_test);
criterion_main!(benches);
