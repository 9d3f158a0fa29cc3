//! The rigid stage's global pose search, graded by the truth of synthetic
//! clouds of the bundled phantom (the cloud is made, then moved by a known motion).
//!
//! The study: 27 first frames, a 30 % patch seen from 3 viewpoints × 9 random rotation axes,
//! 3 samples/cm², 1 mm noise, 10 % outliers, the patch turned by 90° about its centroid and
//! shifted by 2 cm, the pose otherwise unknown (ICP starts from the identity). Plain ICP ends
//! in a wrong minimum in most of them (17 of 27; a session without the search takes one of
//! those frames 104.5° off without any flag or error); the search must find every pose within
//! 2° and 3 mm (its error is the noise's: 0.1–0.5°). A session then shows
//! the search on its first frame and says so (`pose_searched`).
//!
//! Run: `cargo test --release --test registration rigid_pose_search:: -- --nocapture`.

use livereg::geometry::Camera;
use livereg::phantom::liver_phantom;
use livereg::random::Rng;
use livereg::registration::{ModelTarget, PoseSearch, RigidIcp, RigidTransform};
use livereg::scene::load_scene;
use livereg::session::{Frame, Session};
use livereg::simulation::FromScene;
use livereg::synthetic::{synthesize_cloud, CloudSpec};
use nalgebra::{Point3, Rotation3, Unit, Vector3};

/// A first frame and the true cloud → model motion (metres).
struct Case {
    cloud: Vec<Point3<f64>>,
    truth: RigidTransform,
}

/// The study's cases: every view × 9 rotation axes, turned by `turn_deg` about the patch's
/// centroid and shifted by `shift` metres.
fn cases(views: &[Vector3<f64>], turn_deg: f64, shift: f64) -> Vec<Case> {
    let phantom = liver_phantom();
    let (lo, hi) = phantom.surface.bounding_box().unwrap();
    let mid = nalgebra::center(&lo, &hi);
    // The bundled scene's look-at point, on the anterior-superior face.
    let look_at = Point3::new(
        mid.x,
        lo.y + 0.7 * (hi.y - lo.y),
        lo.z + 0.7 * (hi.z - lo.z),
    );
    let mut rng = Rng::new(18);
    let mut out = Vec::new();
    for (v, view) in views.iter().enumerate() {
        let camera = Camera::looking_at(look_at + view.normalize() * 0.25, look_at).unwrap();
        for a in 0..9 {
            let spec = CloudSpec {
                density_per_cm2: 3.0,
                noise_sigma: 1e-3,
                outlier_fraction: 0.1,
                visible_fraction: Some(0.3),
                rigid_offset: None,
                seed: 1000 + 10 * v as u64 + a as u64,
            };
            let cloud = synthesize_cloud(&phantom.surface, &camera, &spec).unwrap();
            let inliers: Vec<Vector3<f64>> = cloud
                .points
                .iter()
                .zip(&cloud.is_outlier)
                .filter(|(_, o)| !**o)
                .map(|(p, _)| p.coords)
                .collect();
            let c = inliers.iter().sum::<Vector3<f64>>() / inliers.len() as f64;
            let axis = Unit::new_normalize(rng.gaussian_vector(1.0));
            let r = Rotation3::from_axis_angle(&axis, turn_deg.to_radians());
            let offset = rng.gaussian_vector(1.0).normalize() * shift;
            // model → camera: a turn about the patch's centroid, then the shift.
            let model_to_cloud = RigidTransform::new(r, c - r * c + offset);
            out.push(Case {
                cloud: model_to_cloud.apply_all(&cloud.points),
                truth: model_to_cloud.inverse(),
            });
        }
    }
    out
}

/// The bundled scene's view direction and two others, 25 cm from the look-at point.
fn views() -> [Vector3<f64>; 3] {
    [
        Vector3::new(0.0, 1.0, 0.8),
        Vector3::new(0.6, 1.0, 0.3),
        Vector3::new(-0.5, 0.8, 0.9),
    ]
}

#[test]
fn the_search_finds_the_pose_where_plain_icp_stops_in_a_wrong_minimum() {
    let phantom = liver_phantom();
    let target = ModelTarget::new(&phantom.surface, 0.005).unwrap();
    // The session's rigid settings (median/MAD pruning).
    let icp = RigidIcp {
        robust_pruning: true,
        ..RigidIcp::default()
    };
    let search = PoseSearch::default();
    let (mut plain_wrong, mut worst) = (0, 0.0f64);
    for (k, case) in cases(&views(), 90.0, 0.02).iter().enumerate() {
        let plain = icp.register(&target, &case.cloud, None).unwrap();
        let t0 = std::time::Instant::now();
        let found = search
            .search(&icp, &target, &case.cloud, RigidTransform::identity())
            .unwrap();
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        let turn = |t: &RigidTransform| t.rotation_angle_to(&case.truth).to_degrees();
        let (plain_deg, found_deg) = (
            turn(&plain.cloud_to_model),
            turn(&found.best.cloud_to_model),
        );
        let shift_mm = found
            .best
            .cloud_to_model
            .translation_distance_to(&case.truth)
            * 1e3;
        plain_wrong += usize::from(plain_deg > 5.0);
        worst = worst.max(found_deg);
        println!(
            "case {k:2}: plain ICP {plain_deg:6.1}° off (converged {}), search {found_deg:4.2}° \
             {shift_mm:4.2} mm off, score {:.2} mm² (plain {:.2}), replaced {}, ambiguous {}, \
             {} fits, {ms:.0} ms",
            plain.converged,
            found.score * 1e6,
            found.plain_score * 1e6,
            found.replaced_plain,
            found.ambiguous,
            found.fits,
        );
        assert!(
            found_deg < 2.0 && shift_mm < 3.0,
            "case {k}: the search ended {found_deg:.2}° and {shift_mm:.2} mm off"
        );
        assert!(!found.ambiguous, "case {k}: {found:?}");
        // The plain fit is replaced exactly when it was wrong.
        assert_eq!(found.replaced_plain, plain_deg > 5.0, "case {k}");
    }
    println!("plain ICP wrong (> 5°) in {plain_wrong} of 27; the search's worst {worst:.2}°");
    // The study must exercise the search: most 90° starts are outside plain ICP's basin.
    assert!(
        plain_wrong >= 10,
        "plain ICP wrong in only {plain_wrong} of 27"
    );
}

#[test]
fn a_session_searches_the_first_frames_pose_and_says_so() {
    let dir = std::env::temp_dir().join(format!("livereg-pose-search-{}", std::process::id()));
    livereg::phantom::write_phantom(&dir).unwrap();
    let loaded = load_scene(&dir.join("scene.toml")).unwrap();
    let scale = loaded.length_scale();
    // The first case whose 90° turn plain ICP gets wrong.
    let case = cases(&views()[..1], 90.0, 0.02)
        .into_iter()
        .find(|c| {
            let target = ModelTarget::new(&liver_phantom().surface, 0.005).unwrap();
            let icp = RigidIcp {
                robust_pruning: true,
                ..RigidIcp::default()
            };
            let plain = icp.register(&target, &c.cloud, None).unwrap();
            plain
                .cloud_to_model
                .rotation_angle_to(&c.truth)
                .to_degrees()
                > 5.0
        })
        .expect("a case plain ICP gets wrong");
    let frame = Frame {
        source: "turned".into(),
        points: case.cloud.iter().map(|p| p / scale).collect(),
        camera: None,
    };
    let truth = case.truth.inverse();
    let run = |search: bool| {
        let mut s = Session::from_scene(&loaded).unwrap();
        if !search {
            s.settings.pose_search = None;
        }
        s.register(&frame)
    };
    let searched = run(true);
    let plain = run(false);
    let off =
        |r: &livereg::session::FrameResult| r.model_to_cloud.rotation_angle_to(&truth).to_degrees();
    println!(
        "session: searched {:.2}° off {:?} {:?}; plain {:.1}° off {:?} {:?}",
        off(&searched),
        searched.flags,
        searched.error,
        off(&plain),
        plain.flags,
        plain.error,
    );
    assert!(searched.error.is_none(), "{:?}", searched.error);
    assert!(off(&searched) < 2.0, "{:.2}°", off(&searched));
    assert!(
        searched.flags.iter().any(|f| f == "pose_searched"),
        "{:?}",
        searched.flags
    );
    // Without the search the same frame ends elsewhere (refused or wrongly posed), unflagged.
    assert!(plain.error.is_some() || off(&plain) > 5.0);
    assert!(!plain.flags.iter().any(|f| f == "pose_searched"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_ambiguous_pose_is_flagged_on_every_frame_that_holds_it() {
    // The indentation class's press-slide with its clouds moved by an unknown offset and only
    // 5 % of the surface seen: the stability matrix's failing cell
    // (docs/indentation.md#the-classs-stability-matrix). The search finds two poses about as
    // good on the first frame; the session holds that pose, and every frame built on it must
    // say the pose is ambiguous.
    use livereg::benchmark::indentation::{
        run_case, scene_for, IndentationCase, IndentationVariant,
    };
    use livereg::synthetic::indentation::{
        bundled_fixture_dir, indentation_sequence, IndentationCloudSpec, IndentationTruth,
    };
    let dir = bundled_fixture_dir();
    let mut truth = IndentationTruth::load(&dir, "press-slide", "linear").unwrap();
    truth.truncate(4);
    let spec = IndentationCloudSpec {
        visible_fraction: 0.05,
        rigid_offset: IndentationVariant::RigidIcp.offset(),
        ..IndentationCloudSpec::default()
    };
    let frames = indentation_sequence(&truth, &spec).unwrap();
    let case = IndentationCase {
        truth,
        frames,
        variant: IndentationVariant::RigidIcp,
    };
    let scene = scene_for(
        &load_scene(&dir.join("scene.toml")).unwrap(),
        IndentationVariant::RigidIcp,
    );
    let mut session = Session::from_scene(&scene).unwrap();
    let (_, samples) = run_case(&mut session, &case, scene.length_scale()).unwrap();
    for (k, f) in samples.iter().enumerate() {
        println!("frame {k}: flags {:?}", f.flags);
        assert!(f.causes.is_empty(), "frame {k}: {:?}", f.causes);
        assert!(
            f.flags.iter().any(|x| x == "pose_ambiguous"),
            "frame {k} holds an ambiguous pose without saying so: {:?}",
            f.flags
        );
    }
    // The pose was searched once, on the first frame, and held after it.
    assert!(samples[1..]
        .iter()
        .all(|f| f.flags.iter().all(|x| x != "pose_reacquired")));
}
