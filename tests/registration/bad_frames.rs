//! Bad frames on the bundled phantom: an empty frame, a NaN coordinate, a cloud far
//! from the model (1 m away: `no-match`) and a million-point frame (thinned, flagged
//! `decimated`, registered in bounded time). A rejected frame leaves the session exactly as
//! it was, and the next good frame continues from the last good state: the good frames of a
//! session that also saw the bad ones give the same results as a session that saw only the
//! good ones.
//!
//! Run: `cargo test --test registration bad_frames:: -- --nocapture`.

use crate::common;

use livereg::simulation::FromScene;
use std::time::Instant;

use livereg::mesh::TriSurface;
use livereg::registration::RigidTransform;
use livereg::scene::{load_scene, LoadedScene};
use livereg::session::{Frame, FrameError, FrameResult, Session};
use livereg::synthetic::{
    generate_sequence, synthesize_cloud, CloudSpec, ScenarioKind, SequenceSpec, SyntheticFrame,
    SyntheticSequence,
};
use nalgebra::{Point3, Rotation3, Vector3};

/// Points in a million-point frame (about).
const MILLION: usize = 1_000_000;

fn frame(points: Vec<Point3<f64>>, source: &str) -> Frame {
    Frame {
        source: source.into(),
        points,
        camera: None,
    }
}

/// Mean distance of the registered targets of `r` to the frame's truth, scene units.
fn tre(r: &FrameResult, f: &SyntheticFrame, scale: f64) -> f64 {
    common::frame_tre(r, &f.truth_structures, scale)
}

/// What a session's good state is made of.
fn state(s: &Session) -> (Vec<f64>, livereg::registration::RigidTransform, bool) {
    (s.displacement().to_vec(), s.pose(), s.is_warm())
}

fn assert_ok(r: &FrameResult) {
    assert!(r.error.is_none(), "{}: {:?}", r.source, r.error);
    assert!(!r.flags.iter().any(|f| f == "failed"), "{}", r.source);
}

/// Registers a frame that must be rejected: checks its cause, its flags, the last good state
/// in its result, and that the session is exactly as before.
fn reject(s: &mut Session, f: &Frame, cause: &str, last: &FrameResult) -> FrameResult {
    let before = state(s);
    let r = s.register(f);
    let e = r
        .error
        .as_ref()
        .unwrap_or_else(|| panic!("{} was accepted: {:?}", f.source, r.flags));
    assert_eq!(e.cause(), cause, "{}: {e}", f.source);
    assert!(r.flags.iter().any(|g| g == "failed"), "{:?}", r.flags);
    assert!(!r.converged);
    assert_eq!(
        (r.icp_iterations, r.newton_iterations, r.factorizations),
        (0, 0, 0)
    );
    assert_eq!(r.cloud_points.0, f.points.len());
    assert_eq!(r.model_to_cloud, last.model_to_cloud, "{}", f.source);
    assert_eq!(
        r.structures, last.structures,
        "{}: last good state",
        f.source
    );
    assert_eq!(r.surface, last.surface, "{}: last good surface", f.source);
    assert!(state(s) == before, "{}: the session changed", f.source);
    println!("{:<9} rejected in {:>6.1} ms: {e}", f.source, r.wall_ms);
    r
}

/// The phantom and a 4-frame tool-push sequence (default clouds) with its frames in scene
/// units.
fn setup(tag: &str) -> (LoadedScene, SequenceSpec, SyntheticSequence, Vec<Frame>) {
    let dir = std::env::temp_dir().join(format!("livereg-bad-frames-{}-{tag}", std::process::id()));
    livereg::phantom::write_phantom(&dir).unwrap();
    let loaded = load_scene(&dir.join("scene.toml")).unwrap();
    let scale = loaded.length_scale();
    let mut spec = SequenceSpec::phantom_default(ScenarioKind::ToolPush);
    spec.frames = 4;
    let seq = generate_sequence(&loaded, &spec).unwrap();
    let good: Vec<Frame> = seq
        .frames
        .iter()
        .enumerate()
        .map(|(k, f)| {
            frame(
                f.cloud.iter().map(|p| p / scale).collect(),
                &format!("good_{k}"),
            )
        })
        .collect();
    (loaded, spec, seq, good)
}

#[test]
fn bad_frames_are_rejected_and_leave_no_trace_on_the_phantom() {
    let start = Instant::now();
    let (loaded, spec, seq, good) = setup("main");
    let scale = loaded.length_scale();

    // The control: the good frames alone.
    let mut control = Session::from_scene(&loaded).unwrap();
    let expected: Vec<FrameResult> = good.iter().map(|f| control.register(f)).collect();
    expected.iter().for_each(assert_ok);

    let mut s = Session::from_scene(&loaded).unwrap();
    let mut seen = 0;
    // 1. A good (cold) frame.
    let r0 = s.register(&good[0]);
    seen += 1;
    assert_ok(&r0);
    assert!(!r0.warm);

    // 2. Empty.
    reject(&mut s, &frame(Vec::new(), "empty"), "empty", &r0);
    seen += 1;
    let r1 = s.register(&good[1]);
    seen += 1;
    assert_ok(&r1);
    assert!(r1.warm, "the frame after a rejected one starts warm");

    // 3. A NaN coordinate (and an unreadable input, reported by the caller).
    let mut nan = good[2].points.clone();
    nan[123].z = f64::NAN;
    let r = reject(&mut s, &frame(nan, "nan"), "non-finite", &r1);
    assert!(
        matches!(r.error, Some(FrameError::NonFinite { index: 123, .. })),
        "{:?}",
        r.error
    );
    let before = state(&s);
    let r = s.reject("broken.xyz", FrameError::Input("broken.xyz:3: bad".into()));
    assert_eq!(r.error.as_ref().map(FrameError::cause), Some("input"));
    assert_eq!(r.structures, r1.structures);
    assert!(state(&s) == before);
    seen += 2;
    let r2 = s.register(&good[2]);
    seen += 1;
    assert_ok(&r2);

    // 4. Points 1 m from the model that no pose of this liver fits: a flat 40 × 40 cm grid
    // (1 cm spacing) — what a camera pointed at a drape or the table would see.
    let centre = good[2]
        .points
        .iter()
        .fold(Vector3::zeros(), |a, p| a + p.coords)
        / good[2].points.len() as f64;
    let far: Vec<Point3<f64>> = (0..40)
        .flat_map(|i| (0..40).map(move |j| (i, j)))
        .map(|(i, j)| {
            let d = Vector3::new(i as f64 - 19.5, j as f64 - 19.5, 0.0) * 0.01;
            Point3::from(centre + (Vector3::new(1.0, 0.0, 0.0) + d) / scale)
        })
        .collect();
    reject(&mut s, &frame(far, "far"), "no-match", &r2);
    seen += 1;
    let r3 = s.register(&good[3]);
    seen += 1;
    assert_ok(&r3);
    assert_eq!(s.frames_seen(), seen);

    // The good frames continued from the last good state: the same results as the control's
    // (the non-rigid stage never ran on a rejected frame, so nothing it carries changed).
    for (r, e) in [&r0, &r1, &r2, &r3].into_iter().zip(&expected) {
        let d = r
            .structures
            .iter()
            .zip(&e.structures)
            .flat_map(|((_, p), (_, q))| p.iter().zip(q).map(|(a, b)| (a - b).norm()))
            .fold(0.0, f64::max);
        println!("{}: {d:.2e} mm from the control", r.source);
        assert!(
            d < 1e-6,
            "{}: {d} mm from the session without bad frames",
            r.source
        );
        assert_eq!(r.icp_iterations, e.icp_iterations, "{}", r.source);
    }

    // 5. A million-point frame: the last frame's deformed truth surface sampled densely by
    // the same camera (30 % patch, 1 mm noise, 10 % outliers, the same camera offset).
    let last = &seq.frames[3];
    let truth_surface = TriSurface::new(last.truth_surface.clone(), seq.triangles.clone());
    let probe = CloudSpec {
        seed: 99,
        rigid_offset: None,
        ..spec.cloud
    };
    let t = Instant::now();
    let area_cm2 = synthesize_cloud(&truth_surface, &seq.camera, &probe)
        .unwrap()
        .surface_area
        * 1e4;
    let dense = CloudSpec {
        density_per_cm2: MILLION as f64 * (1.0 - probe.outlier_fraction) / (0.3 * area_cm2),
        ..probe
    };
    let big = synthesize_cloud(&truth_surface, &seq.camera, &dense).unwrap();
    let big_frame = frame(big.points.iter().map(|p| p / scale).collect(), "million");
    println!(
        "million-point frame: {} points ({} outliers), synthesized in {:.1} s",
        big.points.len(),
        big.outlier_count(),
        t.elapsed().as_secs_f64()
    );
    assert!(
        (900_000..1_100_000).contains(&big_frame.points.len()),
        "{}",
        big_frame.points.len()
    );
    let r = s.register(&big_frame);
    assert_ok(&r);
    assert!(r.flags.iter().any(|f| f == "decimated"), "{:?}", r.flags);
    let limit = s.settings.max_cloud_points;
    assert_eq!(r.cloud_points.0, big_frame.points.len());
    assert!(
        r.cloud_points.1 <= limit && r.cloud_points.1 >= limit / 2,
        "{:?} points used, limit {limit}",
        r.cloud_points
    );
    let normal_tre = tre(&r3, last, scale);
    let big_tre = tre(&r, last, scale);
    println!(
        "million-point frame: {:.0} ms (prepare {:.0}, rigid {:.0}, pairing {:.0}, newton {:.0}), \
         {} ICP iterations, TRE {big_tre:.2} mm (normal cloud of the same frame: {normal_tre:.2} mm)",
        r.wall_ms,
        r.times.prepare_ms,
        r.times.rigid_ms,
        r.times.pairing_ms,
        r.times.newton_ms,
        r.icp_iterations
    );
    // Bounded time: thinned to the limit, the frame costs what a 5,000-point frame costs
    // (~0.2 s in the dev profile here, ~5× a normal frame's cloud); 15 s is a ceiling with
    // room for a loaded 2-core machine. The checks and the thinning themselves are cheap.
    assert!(r.wall_ms < 15_000.0, "{:.0} ms", r.wall_ms);
    assert!(r.times.prepare_ms < 1_000.0, "{:.0} ms", r.times.prepare_ms);
    // Registered, not lost: within twice the noise σ of the truth. (Not as good as the
    // normal cloud of the same frame: on the phantom the non-rigid TRE grows with the
    // cloud's density — 3 → 30 → 83 samples/cm²: 0.41 → 0.68 → 1.04 mm from the same warm
    // state — see docs/registration.md#known-limits.)
    let sigma_mm = spec.cloud.noise_sigma / scale;
    assert!(
        big_tre < 2.0 * sigma_mm,
        "{big_tre:.2} mm vs {normal_tre:.2} mm for the normal cloud"
    );

    // 6. The session goes on.
    let r = s.register(&good[3]);
    assert_ok(&r);
    assert!(r.warm);
    let after = tre(&r, last, scale);
    println!(
        "after the million-point frame, the normal cloud again: TRE {after:.2} mm; total {:.1} s",
        start.elapsed().as_secs_f64()
    );
    assert!(after < 2.0 * sigma_mm, "{after:.2} mm");
}

/// The same liver seen 1 m away: the last frame's cloud moved as a whole by `motion`
/// (metres, cloud frame). The held pose no longer fits, so the pose is searched again and
/// the frame is registered at the moved pose (`pose_reacquired`), with the targets where they
/// belong: TRE against the moved truth within `tolerance_mm` of the unmoved frame's, the pose
/// within `pose_tolerance_deg` of the moved one. A rejection is wrong here: the cloud is the
/// last good frame's, moved. So is an acceptance at a wrong pose: before the centroid-shift
/// start of `Session` re-acquisition, rigid ICP from the held pose stopped at its iteration
/// cap in a wrong minimum turned by ~96° whose RMS was under the 2 cm no-match limit (TRE
/// ~47 mm), and the session committed it. `motion` is built from the unmoved cloud (metres).
/// Returns the frame's rigid ICP iterations.
fn jump_is_reacquired(
    name: &str,
    motion: impl Fn(&[Point3<f64>]) -> RigidTransform,
    tolerance_mm: f64,
    pose_tolerance_deg: f64,
) -> usize {
    let (loaded, _, seq, good) = setup(name);
    let scale = loaded.length_scale();
    let last = &seq.frames[3];
    let mut s = Session::from_scene(&loaded).unwrap();
    let results: Vec<FrameResult> = good.iter().map(|f| s.register(f)).collect();
    results.iter().for_each(assert_ok);
    let normal_tre = tre(&results[3], last, scale);
    let before = s.pose();
    let motion = motion(&last.cloud);
    let moved: Vec<Point3<f64>> = last.cloud.iter().map(|p| motion.apply(p) / scale).collect();
    let r = s.register(&frame(moved, name));
    let expected = motion.compose(&before);
    let pose_off_deg = expected.rotation_angle_to(&r.model_to_cloud).to_degrees();
    println!(
        "{name}: error {:?}, flags {:?}, pose {:.2} mm and {pose_off_deg:.3}° off the moved pose, \
         {} rigid iterations",
        r.error.as_ref().map(|e| e.to_string()),
        r.flags,
        expected.translation_distance_to(&r.model_to_cloud) / scale,
        r.rigid_iterations
    );
    assert!(r.error.is_none(), "rejected: {:?}", r.error);
    assert!(
        r.flags.iter().any(|f| f == "pose_reacquired"),
        "{:?}",
        r.flags
    );
    assert!(
        pose_off_deg < pose_tolerance_deg,
        "re-acquired {pose_off_deg:.3}° off the moved pose"
    );
    let moved_truth = SyntheticFrame {
        truth_structures: last
            .truth_structures
            .iter()
            .map(|(n, p)| (n.clone(), p.iter().map(|q| motion.apply(q)).collect()))
            .collect(),
        ..last.clone()
    };
    let moved_tre = tre(&r, &moved_truth, scale);
    println!(
        "{name}: TRE against the moved truth {moved_tre:.2} mm (unmoved frame {normal_tre:.2} mm)"
    );
    assert!(
        moved_tre < normal_tre + tolerance_mm,
        "accepted with a wrong pose: TRE {moved_tre:.2} mm against the moved truth"
    );
    r.rigid_iterations
}

/// The cloud shifted by 1 m along x: the centroid-shifted held pose fits as it is, with no
/// ICP at all, and it is the moved pose to round-off.
#[test]
fn a_liver_seen_1m_away_is_reacquired_by_the_centroid_shift() {
    let shift = |_: &[Point3<f64>]| RigidTransform::from_translation(Vector3::new(1.0, 0.0, 0.0));
    let iterations = jump_is_reacquired("shifted", shift, 1.0, 1e-6);
    assert_eq!(iterations, 0, "the centroid shift alone re-acquires it");
}

/// The cloud shifted by 1 m and turned by 10° about the vertical axis through its centroid:
/// the shifted held pose no longer fits, and rigid ICP from it re-acquires the pose. ICP
/// stops at its iteration cap there (the deformed cloud against the last registered shape)
/// with the cloud fitting as well as the last frame did, which makes the fit usable. Pose
/// within 1° of the moved one; TRE within 2 mm of the unmoved frame's: the pose is now a
/// rigid fit of a partial patch of the deformed surface, not the held pose, and the non-rigid
/// stage follows from it (a wrong minimum is tens of millimetres off).
#[test]
fn a_liver_seen_1m_away_and_turned_is_reacquired() {
    let motion = |cloud: &[Point3<f64>]| {
        let c = cloud.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / cloud.len() as f64;
        let turn = Rotation3::from_axis_angle(&Vector3::z_axis(), 10f64.to_radians());
        RigidTransform::from_translation(Vector3::new(1.0, 0.0, 0.0))
            .compose(&RigidTransform::new(turn, c - turn * c))
    };
    let iterations = jump_is_reacquired("turned", motion, 2.0, 1.0);
    assert!(iterations > 0, "the turn is searched by ICP");
}
