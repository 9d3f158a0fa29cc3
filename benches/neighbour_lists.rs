//! Benchmark of every cloud point's nearest-neighbour list at once
//! (`IndexedPoints::nearest_k_all`, on a uniform grid) against one k-d tree query per point
//! (what it replaced): a camera's patch of 680 points (the phantom's warm clouds) on a curved
//! 12 × 9 cm surface with 1.5 mm noise, for the change test's 32 neighbours and the isolated
//! points' 9.
//!
//! Run: `cargo bench --bench neighbour_lists -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;

#[path = "support/camera_patch.rs"]
mod camera_patch;
use camera_patch::camera_patch;

use criterion::{criterion_group, criterion_main, Criterion};
use livereg::random::Rng;
use livereg::registration::IndexedPoints;
use rayon::prelude::*;

fn bench_neighbour_lists(c: &mut Criterion) {
    let mut rng = Rng::new(11);
    let points = camera_patch(&mut rng);
    let cloud = IndexedPoints::new(points).unwrap();
    let mut group = c.benchmark_group("neighbour_lists");
    for k in [32, 9] {
        group.bench_function(format!("tree per point, k {k}"), |b| {
            b.iter(|| {
                let lists: Vec<Vec<(usize, f64)>> = cloud
                    .points
                    .par_iter()
                    .map(|p| cloud.nearest_k(p, k))
                    .collect();
                black_box(lists)
            })
        });
        group.bench_function(format!("grid, k {k}"), |b| {
            b.iter(|| black_box(cloud.nearest_k_all(k)))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_neighbour_lists);
criterion_main!(benches);
