//! Benchmark of rigid ICP (`livereg::registration::RigidIcp`): 2,000 cloud points against a
//! liver-ish model (ellipsoid 20 × 15 × 10 cm with a lump) sampled to ~5,000 points, from a
//! 10° / 2 cm offset. Goal: ≤ 5 ms per full registration.
//!
//! Run: `cargo bench --bench rigid_icp -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use livereg::mesh::primitives::icosphere;
use livereg::registration::{ModelTarget, RigidIcp, RigidTransform};
use nalgebra::{Point3, Rotation3, Unit, Vector3};

fn bench_rigid_icp(c: &mut Criterion) {
    let mut model = icosphere(Point3::origin(), 1.0, 3);
    let lump = Vector3::new(0.6, 0.5, 0.62).normalize();
    for v in &mut model.vertices {
        let u = v.coords;
        let p = Vector3::new(0.10 * u.x, 0.075 * u.y, 0.05 * u.z)
            + u * (0.02 * (-(u - lump).norm_squared() / 0.15).exp());
        *v = Point3::from(p);
    }
    let target = ModelTarget::new(&model, 0.006).unwrap();
    eprintln!("model samples: {}", target.len());

    // 2,000 cloud points: a deterministic spread of barycentric points over the triangles.
    let truth = RigidTransform::new(
        Rotation3::from_axis_angle(
            &Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8)),
            10f64.to_radians(),
        ),
        Vector3::new(0.012, -0.01, 0.012).normalize() * 0.02,
    );
    let cloud: Vec<Point3<f64>> = (0..2000)
        .map(|k| {
            let t = (k * 7919) % model.triangles.len();
            let [a, b, c] = model.corners(t);
            let (u, w) = (((k * 37) % 97) as f64 / 97.0, ((k * 53) % 89) as f64 / 89.0);
            let (u, w) = if u + w > 1.0 {
                (1.0 - u, 1.0 - w)
            } else {
                (u, w)
            };
            // ±1 mm deterministic pseudo-noise, so the stopping test behaves as on real data.
            let noise = Vector3::new(
                ((k * 31) % 101) as f64 / 50.0 - 1.0,
                ((k * 43) % 103) as f64 / 51.0 - 1.0,
                ((k * 59) % 107) as f64 / 53.0 - 1.0,
            ) * 1e-3;
            truth.apply(&(a + (b - a) * u + (c - a) * w)) + noise
        })
        .collect();
    let icp = RigidIcp::default();
    let r = icp.register(&target, &cloud, None).unwrap();
    eprintln!(
        "iterations {}, converged {}, rotation error {:.4}°, translation error {:.4} mm",
        r.iterations,
        r.converged,
        r.model_to_cloud.rotation_angle_to(&truth).to_degrees(),
        r.model_to_cloud.translation_distance_to(&truth) * 1e3
    );

    c.bench_function("rigid_icp_2000_points_10deg_2cm", |b| {
        b.iter(|| {
            icp.register(black_box(&target), black_box(&cloud), None)
                .unwrap()
        })
    });
    c.bench_function("model_target_build", |b| {
        b.iter(|| ModelTarget::new(black_box(&model), 0.006).unwrap())
    });
}

criterion_group!(benches, bench_rigid_icp);
criterion_main!(benches);
