//! Scenario tests of the synthetic camera against analytic expectations.

use std::f64::consts::PI;

use nalgebra::{Point3, Rotation3, Vector3};

use super::*;
use crate::mesh::primitives::{box_surface, icosphere};
use crate::mesh::TriSurface;

const R: f64 = 0.1;

/// Sphere of radius [`R`] at the origin, `levels` subdivisions.
fn sphere(levels: usize) -> TriSurface {
    icosphere(Point3::origin(), R, levels)
}

/// Camera at distance `d` from the origin along a skew direction, looking at the origin.
fn skew_camera(d: f64) -> Camera {
    let dir = Vector3::new(1.0, 2.0, 3.0).normalize();
    Camera::looking_at(Point3::from(dir * d), Point3::origin()).unwrap()
}

/// Longest edge of the surface.
fn max_edge(s: &TriSurface) -> f64 {
    (0..s.triangles.len())
        .flat_map(|t| {
            let [a, b, c] = s.corners(t);
            [(b - a).norm(), (c - b).norm(), (a - c).norm()]
        })
        .fold(0.0, f64::max)
}

/// Union of two surfaces (as one triangle list).
fn merge(a: &TriSurface, b: &TriSurface) -> TriSurface {
    let n = a.vertices.len();
    let mut s = a.clone();
    s.vertices.extend_from_slice(&b.vertices);
    s.triangles
        .extend(b.triangles.iter().map(|t| [t[0] + n, t[1] + n, t[2] + n]));
    s
}

#[test]
fn sphere_visible_cap_matches_analytic_area_and_lies_on_near_side() {
    let s = sphere(5);
    let d = 3.0 * R;
    let cam = skew_camera(d);
    let spec = CloudSpec {
        density_per_cm2: 20.0,
        seed: 11,
        ..Default::default()
    };
    let cloud = synthesize_cloud(&s, &cam, &spec).unwrap();
    // Analytic cap area, rescaled by the icosphere's own (slightly smaller) total area.
    let cap = 2.0 * PI * R * R * (1.0 - R / d);
    let expected = cap * cloud.surface_area / (4.0 * PI * R * R);
    let rel = cloud.visible_area / expected - 1.0;
    assert!(
        rel.abs() < 0.02,
        "visible {} vs cap {expected}: {rel}",
        cloud.visible_area
    );
    assert_eq!(cloud.patch_area, cloud.visible_area);
    assert!((cloud.surface_area / (4.0 * PI * R * R) - 1.0).abs() < 0.01);

    // Near side: (p − c)·(camera − c) ≥ R² up to the facet resolution.
    let tol = d * max_edge(&s);
    let cam_v = cam.position.coords;
    for p in &cloud.points {
        assert!(
            p.coords.dot(&cam_v) >= R * R - tol,
            "{p} is on the far side"
        );
    }
    // And on a facet facing the camera (up to grazing round-off).
    for (p, t) in cloud.points.iter().zip(&cloud.source_triangle) {
        let n = s.scaled_normal(t.unwrap()).normalize();
        assert!(n.dot(&(cam.position - p)) > -1e-4, "{p} on a back face");
    }

    // Conversely, every sample well inside the cap is visible (no spurious self-occlusion).
    let vs = VisibleSurface::new(&s).unwrap();
    let mut rng = Rng::new(5);
    let mut inside = 0;
    for _ in 0..20_000 {
        let t = rng.below(s.triangles.len());
        let [a, b, c] = s.corners(t);
        let (u, v) = (rng.uniform(), rng.uniform());
        let (u, v) = if u + v > 1.0 {
            (1.0 - u, 1.0 - v)
        } else {
            (u, v)
        };
        let p = a + (b - a) * u + (c - a) * v;
        let cos = p.coords.normalize().dot(&cam_v.normalize());
        if cos > R / d + 0.05 {
            inside += 1;
            assert!(vs.is_visible(&cam, &p), "{p} (cos {cos}) should be visible");
        } else if cos < R / d - 0.05 {
            assert!(!vs.is_visible(&cam, &p), "{p} (cos {cos}) should be hidden");
        }
    }
    assert!(inside > 3_000);
}

#[test]
fn visible_vertices_of_sphere_are_the_near_cap() {
    let s = sphere(4);
    let d = 3.0 * R;
    let cam = skew_camera(d);
    let vis = VisibleSurface::new(&s).unwrap().visible_vertices(&cam);
    assert_eq!(vis.len(), s.vertices.len());
    let dir = cam.position.coords.normalize();
    // The polyhedron lies inside the sphere, so its silhouette may be off the sphere's
    // tangent circle by up to about one edge (in angle).
    let margin = max_edge(&s) / R;
    let theta0 = (R / d).acos();
    let (mut seen_count, mut hidden_count) = (0, 0);
    for (v, &seen) in s.vertices.iter().zip(&vis) {
        let theta = (v.coords.dot(&dir) / R).clamp(-1.0, 1.0).acos();
        if theta < theta0 - margin {
            assert!(seen, "{v} should be visible");
            seen_count += 1;
        }
        if theta > theta0 + margin {
            assert!(!seen, "{v} should be hidden");
            hidden_count += 1;
        }
    }
    assert!(
        seen_count > 500 && hidden_count > 1_000,
        "{seen_count} {hidden_count}"
    );
}

#[test]
fn box_behind_box_is_occluded_in_its_shadow() {
    let front = box_surface(
        Point3::new(-0.03, -0.03, -0.02),
        Point3::new(0.03, 0.03, 0.02),
        4,
    );
    let back = box_surface(
        Point3::new(-0.1, -0.1, -0.12),
        Point3::new(0.1, 0.1, -0.1),
        8,
    );
    let scene = merge(&front, &back);
    let cam = Camera::new(
        Point3::new(0.0, 0.0, 0.5),
        Point3::origin(),
        Vector3::y(),
        DEFAULT_FOV_DEG,
    )
    .unwrap();
    // The front box's top face (z = 0.02, 0.48 from the camera) casts a shadow of half-width
    // 0.03 × 0.6 / 0.48 = 0.0375 on the back box's top face (z = −0.1, 0.6 from the camera).
    let shadow = 0.0375;
    let vs = VisibleSurface::new(&scene).unwrap();
    let mut grid = Vec::new();
    for i in 0..=80 {
        for j in 0..=80 {
            let x = -0.099 + 0.198 * i as f64 / 80.0;
            let y = -0.099 + 0.198 * j as f64 / 80.0;
            grid.push(Point3::new(x, y, -0.1));
        }
    }
    let vis = vs.visible(&cam, &grid);
    let (mut hidden, mut seen) = (0, 0);
    for (p, &v) in grid.iter().zip(&vis) {
        let m = p.x.abs().max(p.y.abs());
        if m < shadow - 1e-3 {
            assert!(!v, "{p} is in the shadow of the front box");
            hidden += 1;
        } else if m > shadow + 1e-3 {
            assert!(v, "{p} is outside the shadow");
            seen += 1;
        }
    }
    assert!(hidden > 500 && seen > 3_000, "{hidden} {seen}");
    // The underside of the back box is never seen, the front box's top always is.
    assert!(!vs.is_visible(&cam, &Point3::new(0.05, 0.05, -0.12)));
    assert!(vs.is_visible(&cam, &Point3::new(0.0, 0.0, 0.02)));

    // Through the generator: no inlier on the back box's top inside the shadow.
    let spec = CloudSpec {
        density_per_cm2: 10.0,
        ..Default::default()
    };
    let cloud = synthesize_cloud(&scene, &cam, &spec).unwrap();
    let mut on_back_top = 0;
    for p in &cloud.points {
        if (p.z + 0.1).abs() < 1e-9 {
            on_back_top += 1;
            assert!(
                p.x.abs().max(p.y.abs()) > shadow - 1e-3,
                "{p} seen through the front box"
            );
        }
        assert!(p.z > -0.1 - 1e-9, "{p} below the back box's top face");
    }
    assert!(on_back_top > 1_000);
}

#[test]
fn narrow_field_of_view_sees_only_near_axis() {
    let s = sphere(5);
    let d = 5.0 * R;
    let cam = skew_camera(d).with_fov(4.0).unwrap();
    let spec = CloudSpec {
        density_per_cm2: 50.0,
        ..Default::default()
    };
    let cloud = synthesize_cloud(&s, &cam, &spec).unwrap();
    assert!(cloud.points.len() > 20);
    let half = cam.half_angle_rad();
    let axis = cam.view_direction();
    for p in &cloud.points {
        let v = p - cam.position;
        let angle = (v.dot(&axis) / v.norm()).clamp(-1.0, 1.0).acos();
        assert!(angle <= half + 1e-12, "{p} at {angle} rad off axis");
    }
    // The default cone sees the whole cap: far more points.
    let wide = synthesize_cloud(&s, &cam.with_fov(70.0).unwrap(), &spec).unwrap();
    assert!(wide.points.len() > 20 * cloud.points.len());
    // A cone pointing away sees nothing.
    let away = Camera::looking_at(cam.position, Point3::from(cam.position.coords * 2.0)).unwrap();
    let err = synthesize_cloud(&s, &away, &spec).unwrap_err();
    assert!(matches!(err, SynthError::NothingVisible { .. }), "{err}");
    assert!(err.to_string().contains("nothing is visible"));
}

#[test]
fn noise_has_requested_deviation_along_the_normal() {
    let s = sphere(5);
    let cam = skew_camera(3.0 * R);
    let sigma = 1e-3;
    let spec = CloudSpec {
        density_per_cm2: 12.0,
        noise_sigma: sigma,
        seed: 3,
        ..Default::default()
    };
    let cloud = synthesize_cloud(&s, &cam, &spec).unwrap();
    let n = cloud.points.len();
    assert!(n >= 5_000, "{n}");
    let dist: Vec<f64> = cloud.points.iter().map(|p| p.coords.norm() - R).collect();
    let mean = dist.iter().sum::<f64>() / n as f64;
    let std = (dist.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
    assert!(
        (std / sigma - 1.0).abs() < 0.1,
        "std {std} vs sigma {sigma}"
    );
    assert!(mean.abs() < 0.1 * sigma, "mean {mean}");
}

#[test]
fn outliers_are_the_requested_share_and_flagged() {
    let s = sphere(4);
    let cam = skew_camera(3.0 * R);
    let base = CloudSpec {
        density_per_cm2: 5.0,
        seed: 9,
        ..Default::default()
    };
    let clean = synthesize_cloud(&s, &cam, &base).unwrap();
    for f in [0.2, 0.5, 0.1] {
        let cloud = synthesize_cloud(
            &s,
            &cam,
            &CloudSpec {
                outlier_fraction: f,
                ..base
            },
        )
        .unwrap();
        let n_in = cloud.inlier_count();
        let n_out = cloud.outlier_count();
        assert_eq!(
            n_in,
            clean.points.len(),
            "outliers do not change the inliers"
        );
        assert_eq!(n_out, (f * n_in as f64 / (1.0 - f)).round() as usize);
        let share = n_out as f64 / cloud.points.len() as f64;
        assert!(
            (share - f).abs() <= 1.0 / cloud.points.len() as f64,
            "{share} vs {f}"
        );
        // Flags agree with provenance; inliers lie on the (faceted) sphere, outliers in the box.
        let (lo, hi) = clean.inliers().iter().fold(
            (Point3::from([f64::MAX; 3]), Point3::from([f64::MIN; 3])),
            |(lo, hi), p| (lo.inf(p), hi.sup(p)),
        );
        let mut off_surface = 0;
        for ((p, &o), t) in cloud
            .points
            .iter()
            .zip(&cloud.is_outlier)
            .zip(&cloud.source_triangle)
        {
            assert_eq!(o, t.is_none());
            let r = p.coords.norm();
            if o {
                for k in 0..3 {
                    assert!(p[k] >= lo[k] - OUTLIER_MARGIN && p[k] <= hi[k] + OUTLIER_MARGIN);
                }
                if (r - R).abs() > 1e-3 {
                    off_surface += 1;
                }
            } else {
                assert!(r <= R + 1e-12 && r > R * 0.99, "{p}");
            }
        }
        assert!(off_surface as f64 > 0.8 * n_out as f64);
        // Same inliers as the clean cloud, just shuffled in with the outliers.
        let key = |p: &Point3<f64>| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
        let mut a: Vec<_> = cloud.inliers().iter().map(key).collect();
        let mut b: Vec<_> = clean.points.iter().map(key).collect();
        a.sort();
        b.sort();
        assert_eq!(a, b);
    }
}

#[test]
fn visible_fraction_keeps_a_cap_of_the_requested_area() {
    let s = sphere(5);
    let d = 3.0 * R;
    let cam = skew_camera(d);
    let f = 0.2;
    let spec = CloudSpec {
        density_per_cm2: 10.0,
        visible_fraction: Some(f),
        seed: 4,
        ..Default::default()
    };
    let cloud = synthesize_cloud(&s, &cam, &spec).unwrap();
    assert!((cloud.patch_area / cloud.surface_area / f - 1.0).abs() < 0.15);
    assert!(cloud.visible_area > cloud.patch_area);
    // Geometric check, independent of the sample count: the patch is a cap around the
    // axis point whose angular radius gives area f·4πR².
    let axis = cam.position.coords.normalize();
    let max_angle = cloud
        .points
        .iter()
        .map(|p| (p.coords.normalize().dot(&axis)).clamp(-1.0, 1.0).acos())
        .fold(0.0, f64::max);
    let cap_fraction = (1.0 - max_angle.cos()) / 2.0;
    assert!(
        (cap_fraction / f - 1.0).abs() < 0.15,
        "cap {cap_fraction} vs {f}"
    );

    // More than the visible third of the sphere cannot be delivered.
    let err = synthesize_cloud(
        &s,
        &cam,
        &CloudSpec {
            visible_fraction: Some(0.5),
            ..spec
        },
    )
    .unwrap_err();
    assert!(matches!(err, SynthError::PatchTooLarge { .. }), "{err}");
    assert!(err.to_string().contains("only"), "{err}");
}

#[test]
fn same_seed_same_cloud_different_seed_different_cloud() {
    let s = sphere(4);
    let cam = skew_camera(3.0 * R);
    let spec = CloudSpec {
        density_per_cm2: 3.0,
        noise_sigma: 1e-3,
        outlier_fraction: 0.1,
        visible_fraction: Some(0.25),
        seed: 42,
        ..Default::default()
    };
    let a = synthesize_cloud(&s, &cam, &spec).unwrap();
    let b = synthesize_cloud(&s, &cam, &spec).unwrap();
    assert_eq!(a, b);
    let c = synthesize_cloud(&s, &cam, &CloudSpec { seed: 43, ..spec }).unwrap();
    assert_ne!(a.points, c.points);
    // Single-threaded gives the same result as the default pool.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let d = pool.install(|| synthesize_cloud(&s, &cam, &spec).unwrap());
    assert_eq!(a, d);
}

#[test]
fn rigid_offset_is_applied_last_and_invertible() {
    let s = sphere(4);
    let cam = skew_camera(3.0 * R);
    let spec = CloudSpec {
        density_per_cm2: 3.0,
        noise_sigma: 5e-4,
        outlier_fraction: 0.1,
        seed: 8,
        ..Default::default()
    };
    let rot = Rotation3::from_axis_angle(
        &nalgebra::Unit::new_normalize(Vector3::new(0.3, -1.0, 0.5)),
        0.7,
    );
    let t = Vector3::new(0.05, -0.2, 0.12);
    let plain = synthesize_cloud(&s, &cam, &spec).unwrap();
    let moved = synthesize_cloud(
        &s,
        &cam,
        &CloudSpec {
            rigid_offset: Some((rot, t)),
            ..spec
        },
    )
    .unwrap();
    assert_eq!(plain.is_outlier, moved.is_outlier);
    assert_eq!(plain.source_triangle, moved.source_triangle);
    let mut max_moved: f64 = 0.0;
    for (p, q) in plain.points.iter().zip(&moved.points) {
        let back = rot.inverse() * (q - t);
        assert!((back - p).norm() < 1e-12, "{p} vs {back}");
        max_moved = max_moved.max((q - p).norm());
    }
    assert!(max_moved > 0.1);
}

#[test]
fn invalid_inputs_are_rejected_with_clear_messages() {
    let s = sphere(2);
    let cam = skew_camera(3.0 * R);
    let msg = |spec: CloudSpec| synthesize_cloud(&s, &cam, &spec).unwrap_err().to_string();
    let d = CloudSpec::default();
    assert!(msg(CloudSpec {
        density_per_cm2: 0.0,
        ..d
    })
    .contains("density_per_cm2 0"));
    assert!(msg(CloudSpec {
        noise_sigma: -1.0,
        ..d
    })
    .contains("noise_sigma -1"));
    assert!(msg(CloudSpec {
        outlier_fraction: 1.0,
        ..d
    })
    .contains("outlier_fraction 1"));
    assert!(msg(CloudSpec {
        outlier_fraction: -0.1,
        ..d
    })
    .contains("[0, 1)"));
    assert!(msg(CloudSpec {
        visible_fraction: Some(0.0),
        ..d
    })
    .contains("(0, 1]"));
    assert!(msg(CloudSpec {
        visible_fraction: Some(1.2),
        ..d
    })
    .contains("visible_fraction 1.2"));
    let skewed = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::identity() * 2.0);
    assert!(msg(CloudSpec {
        rigid_offset: Some((skewed, Vector3::zeros())),
        ..d
    })
    .contains("rotation"));

    let empty = TriSurface::default();
    let e = synthesize_cloud(&empty, &cam, &d).unwrap_err();
    assert!(
        matches!(
            e,
            SynthError::View(crate::geometry::ViewError::EmptySurface { .. })
        ),
        "{e}"
    );
    assert!(e.to_string().contains("empty"));
    assert!(VisibleSurface::new(&empty).is_err());
    let mut broken = s.clone();
    broken.triangles[3][1] = 10_000;
    assert!(synthesize_cloud(&broken, &cam, &d)
        .unwrap_err()
        .to_string()
        .contains("triangle 3"));

    let bad_cam = Camera {
        look_at: cam.position,
        ..cam
    };
    let e = synthesize_cloud(&s, &bad_cam, &d).unwrap_err();
    assert!(e.to_string().starts_with("invalid camera"), "{e}");

    // A surface in millimetres mistaken for metres.
    let huge = icosphere(Point3::origin(), 100.0, 2);
    let e = synthesize_cloud(&huge, &cam, &d).unwrap_err();
    assert!(e.to_string().contains("is the surface in metres"), "{e}");
}
