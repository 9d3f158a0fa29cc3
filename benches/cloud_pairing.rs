//! Benchmark of the cloud → surface pairing of one ICP iteration
//! (`registration::pair_cloud_to_surface`): 500 cloud points 1 mm off a
//! liver-ish surface (ellipsoid 20 × 15 × 10 cm with a lump, 5,120 triangles), with the normal
//! at each anchor interpolated from the vertex normals or from the vertex normals averaged over
//! a ball of 0.125 × ∛V (`NormalsAtScale::smooth`, ~15 mm here, once per ICP iteration),
//! whose building is measured too (once per session).
//!
//! Run: `cargo bench --bench cloud_pairing -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use livereg::mesh::primitives::icosphere;
use livereg::mesh::TriSurface;
use livereg::registration::{
    incident_triangles, pair_cloud_to_surface, IndexedPoints, NormalsAtScale, PairingRule,
};
use nalgebra::{Point3, Vector3};

fn bench_cloud_pairing(c: &mut Criterion) {
    let mut model = icosphere(Point3::origin(), 1.0, 4);
    let lump = Vector3::new(0.6, 0.5, 0.62).normalize();
    for v in &mut model.vertices {
        let u = v.coords;
        let p = Vector3::new(0.10 * u.x, 0.075 * u.y, 0.05 * u.z)
            + u * (0.02 * (-(u - lump).norm_squared() / 0.15).exp());
        *v = Point3::from(p);
    }
    let normals = model.vertex_normals();
    // 500 points over a sixth of the triangles (a camera's patch), 1 mm along the normal.
    let cloud: Vec<Point3<f64>> = (0..500)
        .map(|k| {
            let t = (k * 7) % (model.triangles.len() / 6);
            let [a, b, c] = model.corners(t);
            let p = Point3::from((a.coords + b.coords + c.coords) / 3.0);
            let [i, _, _] = model.triangles[t];
            p + normals[i] * 0.001 * (((k * 37) % 7) as f64 / 3.0 - 1.0)
        })
        .collect();
    let cloud = IndexedPoints::new(cloud).unwrap();
    let incident = incident_triangles(model.vertices.len(), &model.triangles);
    let rule = PairingRule {
        alpha: 1.0,
        outlier_sigma: 2.0,
        robust: true,
        max_pair_distance: None,
        min_outlier_distance: 0.0,
        hidden_match: None,
        keep_coherent: true,
    };
    let radius = NormalsAtScale::default_radius(&model.vertices, &model.triangles).unwrap();
    let at_scale = NormalsAtScale::new(&model.vertices, &model.triangles, radius).unwrap();
    eprintln!(
        "{} triangles, radius {:.1} mm, {} samples",
        model.triangles.len(),
        radius * 1e3,
        at_scale.samples()
    );
    let pair = |n: &[Vector3<f64>], s: &TriSurface| {
        pair_cloud_to_surface(&s.vertices, &s.triangles, &incident, n, None, &cloud, &rule).unwrap()
    };
    let mut group = c.benchmark_group("cloud_pairing");
    group.bench_function("interpolated normals", |b| {
        b.iter(|| black_box(pair(&normals, &model)))
    });
    group.bench_function("normals at the organ's scale", |b| {
        b.iter(|| {
            let smoothed = at_scale.smooth(&normals, &model.triangles);
            black_box(pair(&smoothed, &model))
        })
    });
    group.bench_function("building the averaging", |b| {
        b.iter(|| {
            black_box(NormalsAtScale::new(
                &model.vertices,
                &model.triangles,
                radius,
            ))
        })
    });
    group.finish();
}

criterion_group!(benches, bench_cloud_pairing);
criterion_main!(benches);
