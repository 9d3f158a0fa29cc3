//! Rigid ICP on a liver-ish surface: known motions with noise, outliers and partial overlap.

use nalgebra::{Point3, Vector3};

use crate::mesh::TriSurface;
use crate::registration::test_support::{
    add_noise, cutting_plane, liver, random_motion, sample_surface, Rng,
};
use crate::registration::{IcpError, IcpMetric, IcpResult, ModelTarget, RigidIcp, RigidTransform};

/// Model sample spacing for the tests: 3 mm (≈ 9,000 samples on the 0.07 m² test liver).
const SPACING: f64 = 0.003;
const DEG: f64 = std::f64::consts::PI / 180.0;

/// Rotation error (degrees), translation error (mm) and the largest displacement error over the
/// model's vertices (mm) of the estimated model → cloud motion against the truth.
fn errors(model: &TriSurface, result: &IcpResult, truth: &RigidTransform) -> (f64, f64, f64) {
    let est = result.model_to_cloud;
    let tre = model
        .vertices
        .iter()
        .map(|v| (est.apply(v) - truth.apply(v)).norm())
        .fold(0.0, f64::max);
    (
        est.rotation_angle_to(truth) / DEG,
        est.translation_distance_to(truth) * 1e3,
        tre * 1e3,
    )
}

/// A cloud of `n` points of the model surface (where `keep` holds, in model coordinates),
/// moved by `truth`, with 1 mm Gaussian noise per coordinate.
fn cloud(
    rng: &mut Rng,
    model: &TriSurface,
    truth: &RigidTransform,
    n: usize,
    keep: impl Fn(&Point3<f64>) -> bool,
) -> Vec<Point3<f64>> {
    let mut pts = truth.apply_all(&sample_surface(rng, model, n, keep));
    add_noise(rng, &mut pts, 1e-3);
    pts
}

/// `n` points uniform in the model's bounding box grown by 3 cm, moved by `truth`.
fn box_outliers(
    rng: &mut Rng,
    model: &TriSurface,
    truth: &RigidTransform,
    n: usize,
) -> Vec<Point3<f64>> {
    let (lo, hi) = model.bounding_box().unwrap();
    (0..n)
        .map(|_| {
            let p = Point3::new(
                rng.uniform_in(lo.x - 0.03, hi.x + 0.03),
                rng.uniform_in(lo.y - 0.03, hi.y + 0.03),
                rng.uniform_in(lo.z - 0.03, hi.z + 0.03),
            );
            truth.apply(&p)
        })
        .collect()
}

#[test]
fn full_cloud_recovers_known_motions() {
    let model = liver();
    let target = ModelTarget::new(&model, SPACING).unwrap();
    // Point-to-point ICP creeps along the smooth surface and needed up to ~80 iterations from
    // 30°; the default point-to-plane update needs 9–14. 200 leaves room for either.
    let icp = RigidIcp {
        max_iterations: 200,
        ..RigidIcp::default()
    };
    let mut rng = Rng::new(11);
    for case in 0..6 {
        // The extreme case first (30°, 5 cm), then random magnitudes up to it.
        let (angle, shift) = if case < 2 {
            (30.0 * DEG, 0.05)
        } else {
            (rng.uniform_in(0.0, 30.0) * DEG, rng.uniform_in(0.0, 0.05))
        };
        let truth = random_motion(&mut rng, angle, shift);
        let pts = cloud(&mut rng, &model, &truth, 2000, |_| true);
        let r = icp.register(&target, &pts, None).unwrap();
        let (rot, trans, tre) = errors(&model, &r, &truth);
        eprintln!("full case {case}: {rot:.4}° {trans:.4} mm tre {tre:.4} mm, {} it, rms {:.3} mm, inliers {:.3}, conv {}", r.iterations, r.rms * 1e3, r.inlier_fraction, r.converged);
        // 2,000 points with σ = 1 mm noise: measured 0.10–0.20° / ≤ 0.09 mm (TRE ≤ 0.36 mm),
        // about the same noise-free minus noise, i.e. the optimum of the objective itself (the
        // near-ellipsoid has a soft sliding direction, and the 2σ rule clips noise tails). 0.5° /
        // 1 mm is a 2.5× margin and tighter than the 1° / 2 mm rigid budget; a wrong basin
        // (several degrees) fails.
        assert!(rot <= 0.5 && trans <= 1.0, "case {case}: {rot}° {trans} mm");
        assert!(r.converged, "case {case}");
        // RMS of inliers ≈ noise: ≈ 1 mm normal to the surface (the tangential part is absorbed).
        assert!(r.rms > 0.7e-3 && r.rms < 1.3e-3, "rms {}", r.rms);
        // The two directions are consistent.
        let id = r.cloud_to_model.compose(&r.model_to_cloud);
        assert!(id.rotation_angle() < 1e-12 && id.translation_norm() < 1e-15);
    }
}

#[test]
fn outlier_rule_beats_no_rejection() {
    let model = liver();
    let target = ModelTarget::new(&model, SPACING).unwrap();
    let thesis = RigidIcp::default();
    let plain = RigidIcp {
        outlier_sigma: None,
        ..RigidIcp::default()
    };
    let mut rng = Rng::new(23);
    for case in 0..3 {
        let (angle, shift) = (rng.uniform_in(10.0, 30.0) * DEG, rng.uniform_in(0.01, 0.05));
        let truth = random_motion(&mut rng, angle, shift);
        // 30 % of the cloud: uniform in the box around the (moved) model.
        let mut pts = cloud(&mut rng, &model, &truth, 1400, |_| true);
        pts.extend(box_outliers(&mut rng, &model, &truth, 600));
        let with = thesis.register(&target, &pts, None).unwrap();
        let without = plain.register(&target, &pts, None).unwrap();
        let (rot_w, trans_w, tre_w) = errors(&model, &with, &truth);
        let (rot_n, trans_n, tre_n) = errors(&model, &without, &truth);
        eprintln!("outliers case {case}: rule {rot_w:.4}° {trans_w:.4} mm tre {tre_w:.3} ({} it, inl {:.3}) | none {rot_n:.4}° {trans_n:.4} mm tre {tre_n:.3}", with.iterations, with.inlier_fraction);
        // Box outliers within mean + 2σ of the surface (a quarter of them) survive the rule and
        // pull the fit: measured 2.4–5.7° / ≤ 2 mm (TRE ≤ 8 mm) on these seeds. This bound only
        // catches a wrong basin; the comparison below is the real check of the rule.
        assert!(
            rot_w <= 8.0 && trans_w <= 4.0,
            "case {case}: {rot_w}° {trans_w} mm"
        );
        assert!(
            tre_w < tre_n,
            "case {case}: rule {tre_w} mm vs none {tre_n} mm"
        );
        // The rule keeps the surface points and some of the outliers: between 70 % and 100 %.
        assert!(with.inlier_fraction > 0.7 && with.inlier_fraction < 0.95);
    }
}

#[test]
fn partial_overlap_recovers_known_motions() {
    let model = liver();
    let target = ModelTarget::new(&model, SPACING).unwrap();
    let icp = RigidIcp {
        max_iterations: 300,
        ..RigidIcp::default()
    };
    let mut rng = Rng::new(37);
    for case in 0..6 {
        let fraction = rng.uniform_in(0.3, 0.4);
        let (n, offset) = cutting_plane(&mut rng, &model, fraction);
        let (angle, shift) = if case < 2 {
            (30.0 * DEG, 0.05)
        } else {
            (rng.uniform_in(0.0, 30.0) * DEG, rng.uniform_in(0.0, 0.05))
        };
        let truth = random_motion(&mut rng, angle, shift);
        let pts = cloud(&mut rng, &model, &truth, 2000, |p| {
            n.dot(&p.coords) > offset
        });
        let r = icp.register(&target, &pts, None).unwrap();
        let (rot, trans, tre) = errors(&model, &r, &truth);
        eprintln!("partial case {case} ({fraction:.2}): {rot:.4}° {trans:.4} mm tre {tre:.3} mm, {} it, rms {:.3} mm, conv {}", r.iterations, r.rms * 1e3, r.converged);
        // A third of a curved surface still pins all six degrees of freedom, but with a lever
        // arm about half as long and the sigma rule clipping the noise tails at the patch rim:
        // allow 5× the full-cloud tolerance.
        assert!(rot <= 1.0 && trans <= 2.5, "case {case}: {rot}° {trans} mm");
    }
}

#[test]
fn trimmed_icp_ignores_a_nearby_sheet() {
    // 20 % overlap: half the cloud on a fifth of the surface, half on a flat 8 × 8 cm sheet
    // 1.5 cm above that patch (e.g. an instrument or the abdominal wall). Trimming to the
    // closest 45 % keeps (mostly) the patch; plain ICP with the 2σ rule bends towards the sheet.
    // The start is a tracking frame's motion, under the sheet's clearance (2–5°, 3–8 mm; at most
    // about 12 mm at the lobe's tips): a start displaced by the clearance itself puts the sheet
    // nearer the model than the patch, and no local method tells them apart (measured: a 5°,
    // 13.8 mm start ended 39.5° off, trimmed or not).
    let model = liver();
    let target = ModelTarget::new(&model, SPACING).unwrap();
    let plain = RigidIcp::default();
    let trimmed = RigidIcp {
        trim_fraction: Some(0.45),
        ..RigidIcp::default()
    };
    let mut rng = Rng::new(41);
    for case in 0..6 {
        let (n, offset) = cutting_plane(&mut rng, &model, 0.2);
        let (angle, shift) = (rng.uniform_in(2.0, 5.0) * DEG, rng.uniform_in(0.003, 0.008));
        let truth = random_motion(&mut rng, angle, shift);
        let patch = sample_surface(&mut rng, &model, 1000, |p| n.dot(&p.coords) > offset);
        let centre = patch.iter().map(|p| p.coords).sum::<Vector3<f64>>() / patch.len() as f64;
        let top = patch
            .iter()
            .map(|p| n.dot(&p.coords))
            .fold(f64::MIN, f64::max);
        let u = n.cross(&Vector3::new(0.3, -0.7, 0.2)).normalize();
        let v = n.cross(&u);
        let base = centre + n * (top + 0.015 - n.dot(&centre));
        let mut pts = patch;
        pts.extend((0..1000).map(|_| {
            Point3::from(base + u * rng.uniform_in(-0.04, 0.04) + v * rng.uniform_in(-0.04, 0.04))
        }));
        let mut pts = truth.apply_all(&pts);
        add_noise(&mut rng, &mut pts, 1e-3);
        let t = trimmed.register(&target, &pts, None).unwrap();
        let p = plain.register(&target, &pts, None).unwrap();
        let (rot_t, trans_t, tre_t) = errors(&model, &t, &truth);
        let (rot_p, trans_p, tre_p) = errors(&model, &p, &truth);
        eprintln!("trim case {case}: trimmed {rot_t:.3}° {trans_t:.3} mm tre {tre_t:.3} mm ({} it, inl {:.3}) | plain {rot_p:.3}° {trans_p:.3} mm tre {tre_p:.3} mm ({} it, inl {:.3})", t.iterations, t.inlier_fraction, p.iterations, p.inlier_fraction);
        // Measured: trimmed 0.3–1.3° / ≤ 1.1 mm (TRE 0.6–3.3 mm; a fifth of the surface has a
        // short lever arm, and trimming clips the noise tails); plain 22–65° (TRE ≥ 58 mm).
        assert!(
            rot_t <= 2.5 && trans_t <= 2.0,
            "case {case}: {rot_t}° {trans_t} mm"
        );
        assert!(tre_t < 4.0, "case {case}: trimmed TRE {tre_t} mm");
        assert!(
            tre_p > 10.0 * tre_t,
            "case {case}: plain {tre_p} mm vs trimmed {tre_t} mm"
        );
        // At most the trimmed 45 %, of which the sigma rule drops a few more.
        assert!(t.inlier_fraction <= 0.45 && t.inlier_fraction > 0.35);
    }
}

#[test]
fn point_to_point_metric_still_recovers_known_motions() {
    // Thesis alg. 2 (Kabsch + Anderson), selectable; fewer cases than the default metric.
    let model = liver();
    let target = ModelTarget::new(&model, SPACING).unwrap();
    let icp = RigidIcp {
        metric: IcpMetric::PointToPoint,
        max_iterations: 200,
        ..RigidIcp::default()
    };
    let mut rng = Rng::new(11);
    for case in 0..2 {
        let truth = random_motion(&mut rng, 30.0 * DEG, 0.05);
        let pts = cloud(&mut rng, &model, &truth, 2000, |_| true);
        let r = icp.register(&target, &pts, None).unwrap();
        let (rot, trans, _) = errors(&model, &r, &truth);
        eprintln!(
            "point-to-point case {case}: {rot:.4}° {trans:.4} mm, {} it",
            r.iterations
        );
        assert!(rot <= 0.5 && trans <= 1.0, "case {case}: {rot}° {trans} mm");
        assert!(r.converged, "case {case}");
    }
}

#[test]
fn warm_start_from_the_truth_stays_put() {
    let model = liver();
    let target = ModelTarget::new(&model, SPACING).unwrap();
    let mut rng = Rng::new(5);
    let truth = random_motion(&mut rng, 0.4, 0.03);
    let pts = cloud(&mut rng, &model, &truth, 2000, |_| true);
    let r = RigidIcp::default()
        .register(&target, &pts, Some(truth.inverse()))
        .unwrap();
    let (rot, trans, _) = errors(&model, &r, &truth);
    assert!(rot <= 0.5 && trans <= 1.0, "{rot}° {trans} mm");
}

#[test]
fn bad_input_gives_clear_errors() {
    let model = liver();
    let target = ModelTarget::new(&model, 0.01).unwrap();
    let icp = RigidIcp::default();
    let err = icp.register(&target, &[], None).unwrap_err();
    assert_eq!(err, IcpError::EmptyCloud);
    assert!(err.to_string().contains("empty"));

    let mut pts = model.vertices.clone();
    pts[42].z = f64::NAN;
    let err = icp.register(&target, &pts, None).unwrap_err();
    assert!(
        matches!(err, IcpError::NonFiniteCloudPoint { index: 42, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("cloud point 42"), "{err}");

    let far: Vec<_> = model
        .vertices
        .iter()
        .map(|p| p + nalgebra::Vector3::new(1.0, 0.0, 0.0))
        .collect();
    let strict = RigidIcp {
        max_correspondence_distance: Some(0.01),
        ..RigidIcp::default()
    };
    let err = strict.register(&target, &far, None).unwrap_err();
    assert!(
        matches!(err, IcpError::TooFewInliers { inliers: 0, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("only 0 of"), "{err}");

    let line: Vec<_> = (0..50)
        .map(|i| Point3::new(0.002 * i as f64, 0.0, 0.0))
        .collect();
    let err = icp.register(&target, &line, None).unwrap_err();
    assert!(matches!(err, IcpError::Degenerate { .. }), "{err}");

    let bad = RigidIcp {
        trim_fraction: Some(1.5),
        ..RigidIcp::default()
    };
    let err = bad.register(&target, &model.vertices, None).unwrap_err();
    assert!(err.to_string().contains("trim_fraction"), "{err}");

    let mut nan_init = RigidTransform::identity();
    nan_init.translation.x = f64::INFINITY;
    let err = icp
        .register(&target, &model.vertices, Some(nan_init))
        .unwrap_err();
    assert_eq!(err, IcpError::NonFiniteInitial);
}
