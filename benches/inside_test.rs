//! Benchmarks of `livereg::geometry::InsideTest` on a 20 480-triangle sphere of radius 10 cm.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use livereg::geometry::{shapes, InsideTest};
use nalgebra::Point3;

fn bench_inside_test(c: &mut Criterion) {
    let radius = 0.1;
    let (vertices, triangles) = shapes::icosphere(5, radius);
    assert_eq!(triangles.len(), 20_480);

    c.bench_function("build_sphere_20k", |b| {
        b.iter(|| InsideTest::new(black_box(&vertices), black_box(&triangles)))
    });

    let inside = InsideTest::new(&vertices, &triangles);
    // 1024 lines on a 32×32 lattice over the sphere's shadow, 64 points each.
    let lines: Vec<(f64, f64)> = (0..1024)
        .map(|k| {
            let (i, j) = (k % 32, k / 32);
            (
                -radius + (i as f64 + 0.5) * 2.0 * radius / 32.0,
                -radius + (j as f64 + 0.5) * 2.0 * radius / 32.0,
            )
        })
        .collect();
    let zs: Vec<f64> = (0..64)
        .map(|k| -radius + (k as f64 + 0.5) * 2.0 * radius / 64.0)
        .collect();
    let mut out = Vec::with_capacity(64);
    let mut k = 0;
    c.bench_function("classify_line_64_points", |b| {
        b.iter(|| {
            let (x, y) = lines[k % lines.len()];
            k += 1;
            inside.classify_line(black_box(x), black_box(y), black_box(&zs), &mut out);
            black_box(&out);
        })
    });

    // Points spread through the bounding box (inside, outside and near the surface).
    let points: Vec<Point3<f64>> = (0..4096)
        .map(|k| {
            let f = |s: u32| ((k as u32).wrapping_mul(s) % 1000) as f64 / 1000.0;
            Point3::new(
                (f(7919) * 2.4 - 1.2) * radius,
                (f(104_729) * 2.4 - 1.2) * radius,
                (f(1_299_709) * 2.4 - 1.2) * radius,
            )
        })
        .collect();
    let mut k = 0;
    c.bench_function("winding_number", |b| {
        b.iter(|| {
            let p = &points[k % points.len()];
            k += 1;
            black_box(inside.winding_number(black_box(p)))
        })
    });
    let mut k = 0;
    c.bench_function("contains", |b| {
        b.iter(|| {
            let p = &points[k % points.len()];
            k += 1;
            black_box(inside.contains(black_box(p)))
        })
    });
}

criterion_group!(benches, bench_inside_test);
criterion_main!(benches);
