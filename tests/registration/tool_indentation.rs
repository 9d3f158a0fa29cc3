//! The tool-indentation class against a truth from an independent discretisation
//! (quadratic tetrahedra solved by scikit-fem, `fixtures/liver_indentation`), with clouds as a
//! camera gives them (500 points on 15 % of the surface around the contact, 1.5 mm noise per
//! axis, `rigid = "none"`, no camera pose). Tolerances come from the measurements recorded in
//! docs/indentation.md#results (release build, `livereg bench --indentation`), with margin.

use livereg::benchmark::indentation::{
    indentation_cases, run_indentation, IndentationCase, IndentationMetrics, IndentationVariant,
};
use livereg::scene::{load_scene, DataTerm, LoadedScene};
use livereg::simulation::FromScene;
use livereg::synthetic::indentation::{
    bundled_fixture_dir, whole_surface_sequence, IndentationTruth,
};

/// The fixture's scene (every default: the derived 11.5 mm cells, neo-Hookean), with the given
/// data term.
fn scene(data_term: DataTerm) -> LoadedScene {
    let mut s = load_scene(&bundled_fixture_dir().join("scene.toml")).expect("fixture scene");
    s.scene
        .registration
        .get_or_insert_with(Default::default)
        .data_term = data_term;
    s
}

/// `scene` on one sequence of the fixture against one truth law, without camera.
fn run_sequence(scene: &LoadedScene, sequence: &str, law: &str) -> IndentationMetrics {
    let cases = indentation_cases(
        &bundled_fixture_dir(),
        &[sequence],
        &[law],
        &[IndentationVariant::NoCamera],
        None,
    )
    .expect("cases");
    let mut rows = run_indentation(scene, &cases, &mut |_| {}).expect("runs");
    rows.remove(0)
}

fn run(data_term: DataTerm) -> IndentationMetrics {
    run_sequence(&scene(data_term), "two-sites", "linear")
}

/// Two sites, the first on the thin left lobe (30 mm deep), the second 70 mm deep on the
/// thick lobe, 50 frames, no camera pose: the default registration follows (measured mean
/// node error 0.73 mm against 2.90 mm unregistered, p95 2.29 against 10.16 mm, no failed
/// frame; its expected error bounds every frame at a median 3.3× the true error), and better
/// than the thesis's surface → cloud pairing (measured 4.25 mm here; docs/data-term.md).
#[test]
fn the_default_follows_a_deep_indentation_without_camera_and_the_old_pairing_did_not() {
    let m = run(DataTerm::CloudToSurface);
    println!(
        "cloud → surface: mean {:.2} mm (none {:.2}), p95 {:.2} (none {:.2}), region {:.2} (none {:.2}), force error median {:?}",
        m.mean_mm, m.none_mean_mm, m.p95_mm, m.none_p95_mm, m.region_mean_mm, m.none_region_mean_mm,
        m.force_relative_error_median
    );
    assert_eq!(m.failed_frames, 0, "a deep indentation must not be refused");
    assert!(
        m.mean_mm <= 0.6 * m.none_mean_mm,
        "mean {:.2} mm",
        m.mean_mm
    );
    assert!(m.p95_mm <= 0.5 * m.none_p95_mm, "p95 {:.2} mm", m.p95_mm);
    assert!(m.region_mean_mm <= 0.75 * m.none_region_mean_mm);
    // The expected error, whose constants were chosen on the force-driven tuning set, on a
    // class it was not chosen on (1.5 mm noise, displacement-driven): it bounds the true mean
    // node error on at least 90 % of the frames and stays useful, its median within 5× the
    // true error (measured: every frame bounded at a median 3.3×; with a share of 0.3 of the
    // displacement and no noise part, 74 % at 1.6×).
    let bounded = m
        .expected_error_bounded
        .expect("an estimate on every frame");
    let ratio = m
        .expected_error_ratio_median
        .expect("an estimate on every frame");
    println!(
        "expected error: bounds {bounded:.2} of the frames at a median {ratio:.2}× the true error"
    );
    assert!(
        bounded >= 0.9,
        "the expected error bounds only {bounded:.2} of the frames"
    );
    assert!(
        ratio <= 5.0,
        "the expected error is {ratio:.2}× the true error (median)"
    );
    // The deepest frame (70 mm): the registration explains most of the motion (measured
    // 1.86 mm against 8.33 mm unregistered).
    let last = m.frames.last().expect("frames");
    assert!(
        last.mean_mm <= 0.5 * last.none_mean_mm,
        "last frame {:.2} mm against {:.2} mm unregistered",
        last.mean_mm,
        last.none_mean_mm
    );
    // The contact force on the deep frames (true force above half the sequence's largest):
    // the concentrated load fitted to the registered field (docs/contact-force.md). Measured:
    // median vector error 0.47, magnitude ratio median 0.66 (0.58–0.83). Too small: the
    // registered dent is shallower than the truth's (the 11.5 mm cells do not reach a 15 mm
    // wide, 70 mm deep dent; docs/error-estimate.md#deep-dents), and the ligament, held
    // through its layer, no longer stiffens the model to make up for it (held rigidly: 0.87,
    // 0.78–1.08). A 15 % error is out of reach: the dent's depth and the unobservable
    // sideways part.
    let largest = m.frames.iter().map(|f| f.force_true_n).fold(0.0, f64::max);
    let deep: Vec<_> = m
        .frames
        .iter()
        .filter(|f| f.force_true_n > 0.5 * largest)
        .collect();
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let ratios: Vec<f64> = deep
        .iter()
        .map(|f| f.force_estimate_n.expect("an estimate on every frame") / f.force_true_n)
        .collect();
    let errors: Vec<f64> = deep
        .iter()
        .map(|f| f.force_relative_error.expect("an estimate on every frame"))
        .collect();
    let (ratio, error) = (median(ratios.clone()), median(errors));
    println!(
        "contact force on deep frames: median vector error {error:.2}, magnitude ratio median {ratio:.2}, range {:.2}–{:.2}",
        ratios.iter().cloned().fold(f64::INFINITY, f64::min),
        ratios.iter().cloned().fold(0.0, f64::max),
    );
    assert!(
        (0.55..=1.5).contains(&ratio),
        "median force ratio {ratio:.2}"
    );
    assert!(error <= 0.5, "median force vector error {error:.2}");

    let old = run(DataTerm::SurfaceToCloud);
    println!("surface → cloud: mean {:.2} mm", old.mean_mm);
    assert!(
        old.mean_mm > 1.15 * m.mean_mm,
        "surface → cloud {:.2} mm against cloud → surface {:.2} mm",
        old.mean_mm,
        m.mean_mm
    );
}

/// The sticking-tool truths (`--truth-law linear-sticking | neo-hookean-sticking`) load with
/// the same loader; the neo-Hookean one goes to the nominal 70 mm at site C (its last frame
/// moves a node about that far), and its press-slide holds the 12 press frames only (to
/// 42.3 mm; see the fixture's README.md).
#[test]
fn the_sticking_truths_load_and_the_neo_hookean_one_goes_deep() {
    use livereg::synthetic::indentation::{IndentationTruth, INDENTATION_STICKING_LAWS};
    let dir = bundled_fixture_dir();
    for law in INDENTATION_STICKING_LAWS {
        for seq in ["press-slide", "two-sites"] {
            let t = IndentationTruth::load(&dir, seq, law).expect("truth");
            assert!(!t.is_empty(), "{seq}/{law}");
            assert_eq!(t.displacements.len(), t.len(), "{seq}/{law}");
        }
    }
    let deepest = |t: &IndentationTruth| t.frames.iter().map(|f| f.depth).fold(0.0, f64::max);
    let t = IndentationTruth::load(&dir, "two-sites", "neo-hookean-sticking").expect("truth");
    assert_eq!(t.len(), 50);
    assert!((deepest(&t) - 0.070).abs() < 1e-9, "{}", deepest(&t));
    let last = &t.displacements[t.len() - 1];
    let umax = last.iter().map(|u| u.norm()).fold(0.0, f64::max);
    assert!(umax > 0.065, "largest displacement at 70 mm: {umax} m");
    let p = IndentationTruth::load(&dir, "press-slide", "neo-hookean-sticking").expect("truth");
    assert_eq!(p.len(), 12);
    assert!((deepest(&p) - 0.0423).abs() < 1e-9, "{}", deepest(&p));
}

/// What the contact force can reach on this model: the concentrated-load fit
/// (`RestCompliance::fit_displacements`) given the truth's own displacements of the surface
/// vertices within 6 cm of the tool (about the clouds' 15 %), on the fixture scene's model
/// (11.5 mm cells). No registration error enters, so what is left is the model's compliance
/// against the tetrahedral truth. Measured on the linear truth's frames deeper than 20 mm
/// (force ratio, median over the frames):
/// - the ligament's 100 fixed points held per cell, as the scene model holds them: 1.09 on
///   press-slide, 1.09 on two-sites;
/// - held point by point: 1.31 and 1.18. Eight or more points in a cell clamp the whole cell,
///   so the hold reaches up to a cell beyond the truth's fixed patch.
///
/// Asserted: per cell within 15 % of the truth on both and closer to it than point by point;
/// the direction within 15°.
#[test]
fn the_fit_of_the_true_field_measures_the_models_compliance() {
    use livereg::grid::Embedding;
    use livereg::mechanics::PenaltySprings;
    use livereg::mesh::read_points;
    use livereg::registration::RestCompliance;
    use livereg::session::Session;
    use livereg::synthetic::indentation::IndentationTruth;

    let mut session = Session::from_scene(&scene(DataTerm::CloudToSurface)).expect("session");
    let kind = session.model.newton.linear_solver;
    let mut lumped =
        RestCompliance::new(&mut session.model.problem, kind).expect("rest compliance");
    // The same ligament held point by point: the fixture's points, each with its share of the
    // model's hold (every point has the same stiffness).
    let scale = session.model.length_scale;
    let fixed: Vec<_> = read_points(&bundled_fixture_dir().join("fixed.xyz"))
        .expect("the fixture's ligament")
        .iter()
        .map(|p| p * scale)
        .collect();
    let [hold] = session.model.problem.springs.as_slice() else {
        panic!("the fixture holds one ligament")
    };
    assert!(
        hold.stiffness.len() < fixed.len(),
        "the model holds the ligament per cell"
    );
    let k = hold.stiffness.iter().sum::<f64>() / fixed.len() as f64;
    let mut by_point_problem = session.model.problem.clone();
    by_point_problem.springs = vec![PenaltySprings::fixed(
        Embedding::new(&by_point_problem.grid, &fixed).expect("ligament embedded"),
        vec![k; fixed.len()],
    )];
    let mut by_point = RestCompliance::new(&mut by_point_problem, kind).expect("rest compliance");
    let model = &session.model;
    let normals = model.surface.vertex_normals();
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    for sequence in ["press-slide", "two-sites"] {
        let truth =
            IndentationTruth::load(&bundled_fixture_dir(), sequence, "linear").expect("truth");
        let (mut ratios, mut by_point_ratios, mut angles) = (Vec::new(), Vec::new(), Vec::new());
        for (k, tool) in truth.frames.iter().enumerate() {
            if tool.depth < 0.02 {
                continue;
            }
            let seen: Vec<usize> = (0..model.surface.vertices.len())
                .filter(|&v| (model.surface.vertices[v] - tool.tool_centre).norm() < 0.06)
                .collect();
            let points: Vec<_> = seen.iter().map(|&v| model.surface.vertices[v]).collect();
            let embedding = Embedding::new(&model.problem.grid, &points).expect("embedded");
            let moved: Vec<_> = seen.iter().map(|&v| truth.displacements[k][v]).collect();
            let n: Vec<_> = seen.iter().map(|&v| normals[v]).collect();
            let fit = |c: &mut RestCompliance| {
                c.fit_displacements(&model.problem, &model.surface, &embedding, &moved, Some(&n))
                    .expect("a fit")
                    .resultant
            };
            let f = fit(&mut lumped);
            ratios.push(f.norm() / tool.force.norm());
            angles.push(f.angle(&tool.force).to_degrees());
            by_point_ratios.push(fit(&mut by_point).norm() / tool.force.norm());
        }
        let frames = ratios.len();
        let (ratio, by_point_ratio, angle) =
            (median(ratios), median(by_point_ratios), median(angles));
        println!(
            "{sequence}: {frames} frames, force ratio median {ratio:.2} lumped, {by_point_ratio:.2} point by point; angle median {angle:.1}°"
        );
        assert!(
            (0.85..=1.15).contains(&ratio),
            "{sequence}: ratio {ratio:.2}"
        );
        assert!(
            (ratio - 1.0).abs() < (by_point_ratio - 1.0).abs(),
            "{sequence}: lumped {ratio:.2}, point by point {by_point_ratio:.2}"
        );
        assert!(angle < 15.0, "{sequence}: angle {angle:.1}°");
    }
}

/// The data term weighed by the cloud's noise (`registration::noise_weight`): press-slide on
/// the neo-Hookean truth, whose dent is shallow (at most 9.6 mm) against the clouds' 1.5 mm of
/// noise, registered with the default (the ramp scaled by (1 mm / σ̂)², about 0.44 here) and
/// with the reference stiffnesses given explicitly (0.02 E h … 2 E h, no noise weight).
/// Measured (release, `livereg bench --indentation`): 0.32 against 0.54 mm mean node error,
/// 1.06 mm unregistered; the springs at the reference stiffness pull the surface onto the
/// noise, far from the dent as well.
#[test]
fn a_noisy_clouds_springs_weigh_less_and_its_noise_is_not_registered() {
    let weighted = run_sequence(
        &scene(DataTerm::CloudToSurface),
        "press-slide",
        "neo-hookean",
    );
    let mut reference = scene(DataTerm::CloudToSurface);
    // E h in N/m: the scene is in millimetres.
    let eh = reference.scene.material.young_modulus * reference.scene.grid.cell_size * 1e-3;
    let r = reference
        .scene
        .registration
        .get_or_insert_with(Default::default);
    r.penalty_start = Some(0.02 * eh);
    r.penalty_end = Some(2.0 * eh);
    let fixed = run_sequence(&reference, "press-slide", "neo-hookean");
    println!(
        "press-slide neo-Hookean: noise-weighted {:.2} mm, reference stiffness {:.2} mm, none {:.2} mm",
        weighted.mean_mm, fixed.mean_mm, weighted.none_mean_mm
    );
    assert_eq!(weighted.failed_frames, 0);
    assert!(
        weighted.mean_mm <= 0.75 * fixed.mean_mm,
        "noise-weighted {:.2} mm against {:.2} mm",
        weighted.mean_mm,
        fixed.mean_mm
    );
    assert!(
        weighted.mean_mm <= 0.4 * weighted.none_mean_mm,
        "{:.2} mm against {:.2} mm unregistered",
        weighted.mean_mm,
        weighted.none_mean_mm
    );
}

/// The model's own error, apart from the data's: the press of press-slide (frames 0–11, to
/// 50 mm deep, linear truth) registered with the defaults from the whole deformed truth
/// surface, noise-free (`whole_surface_sequence`), must end within 16 % of no registration
/// and, inside the indented region, within 35 %. Measured on these twelve frames: 0.42 mm
/// against 3.23 mm (13 %), region 1.49 against 5.47 mm (27 %); over the whole sequence
/// (`cargo run --release --example indentation_error_budget`) 0.81 mm, 18 %, the sliding
/// frames carrying the rest. The camera's clouds (15 % of the surface, 1.5 mm noise) end at
/// 22 % of no registration on that sequence, and noise-free without the coherent long pairs
/// at 15 %: what keeps 15–20 % of no registration out of reach is what the cloud does not
/// show, not the grid. Noise-free with them (the default for such clouds) the sliding press
/// runs away (179 %; docs/error-estimate.md#the-error-budget).
#[test]
fn the_whole_surface_seen_without_noise_leaves_the_models_own_error() {
    let dir = bundled_fixture_dir();
    let mut truth = IndentationTruth::load(&dir, "press-slide", "linear").expect("truth");
    truth.truncate(12);
    let frames = whole_surface_sequence(&truth).expect("frames");
    let case = IndentationCase {
        truth,
        frames,
        variant: IndentationVariant::NoCamera,
    };
    let m = run_indentation(&scene(DataTerm::CloudToSurface), &[case], &mut |_| {})
        .expect("runs")
        .remove(0);
    println!(
        "whole surface: mean {:.2} mm (none {:.2}), region {:.2} (none {:.2}), p95 {:.2} (none {:.2})",
        m.mean_mm, m.none_mean_mm, m.region_mean_mm, m.none_region_mean_mm, m.p95_mm, m.none_p95_mm
    );
    assert_eq!(m.failed_frames, 0);
    assert!(
        m.mean_mm <= 0.16 * m.none_mean_mm,
        "mean {:.2} mm against {:.2} mm unregistered",
        m.mean_mm,
        m.none_mean_mm
    );
    assert!(
        m.region_mean_mm <= 0.35 * m.none_region_mean_mm,
        "region {:.2} mm against {:.2} mm",
        m.region_mean_mm,
        m.none_region_mean_mm
    );
}

/// Distance (scene units) from `q` to the nearest of `triangles` over `vertices`.
fn distance_to_surface(
    q: &nalgebra::Point3<f64>,
    vertices: &[nalgebra::Point3<f64>],
    triangles: &[[usize; 3]],
) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let corners = t.map(|i| vertices[i]);
            let (w, _) = livereg::geometry::closest_barycentric(q, &corners);
            let p = corners[0].coords * w[0] + corners[1].coords * w[1] + corners[2].coords * w[2];
            (q.coords - p).norm()
        })
        .fold(f64::INFINITY, f64::min)
}

/// A force-driven dent, not a displacement-driven one, on noise-free clouds (the tuning set's
/// linear press of `fixtures/liver_force`: a 12 mm patch of 3 surface vertices pushed 50 mm by
/// a dead load, P2 tetrahedra): the registration reaches what the cloud shows at the dent —
/// the cloud points within 15 mm of the true patch centre lie on average within 1.5 mm of the
/// registered surface over the sequence (the length-based outlier rule alone left them 4.5 mm
/// off, 11 mm at the deepest frame) — and the nodes end at most 15 % of no registration's
/// error (measured 1.13 against 9.76 mm: `python3 fixtures/liver_force/grade.py --set tuning`).
#[test]
fn a_force_driven_dent_on_a_noise_free_cloud_is_reached() {
    use livereg::session::{Frame, Session};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/liver_force/indentation-liver");
    let case = dir.join("press_linear");
    let loaded = load_scene(&dir.join("scene_linear.toml")).expect("scene");
    let surface = livereg::mesh::read_surface(&dir.join("liver.obj")).expect("surface");
    let rest = livereg::mesh::read_points(&dir.join("nodes.xyz")).expect("nodes");
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(case.join("meta.json")).unwrap()).unwrap();
    let centre = meta["patch_centre_vertex"].as_u64().unwrap() as usize;
    let truth = livereg::evaluation::read_truth(case.join("truth.jsonl")).expect("truth");
    let mut session = Session::from_scene(&loaded).expect("session");
    let (mut dent, mut error, mut none) = (0.0, 0.0, 0.0);
    for t in &truth {
        let points =
            livereg::mesh::read_points(&case.join(format!("frames/frame_{:03}.xyz", t.frame)))
                .expect("frame");
        let r = session.register(&Frame {
            source: format!("{}", t.frame),
            points: points.clone(),
            camera: None,
        });
        assert!(r.error.is_none(), "frame {}: {:?}", t.frame, r.error);
        let truth_nodes: Vec<nalgebra::Point3<f64>> = t.structures["nodes"]
            .iter()
            .map(|p| nalgebra::Point3::new(p[0], p[1], p[2]))
            .collect();
        let registered = &r.structures.iter().find(|s| s.0 == "nodes").unwrap().1;
        let mean_distance = |nodes: &[nalgebra::Point3<f64>]| {
            nodes
                .iter()
                .zip(&truth_nodes)
                .map(|(a, b)| (a - b).norm())
                .sum::<f64>()
                / truth_nodes.len() as f64
        };
        error += mean_distance(registered);
        none += mean_distance(&rest);
        let near: Vec<_> = points
            .iter()
            .filter(|p| (*p - truth_nodes[centre]).norm() < 15.0)
            .collect();
        let registered_surface = &registered[..surface.vertices.len()];
        dent += near
            .iter()
            .map(|q| distance_to_surface(q, registered_surface, &surface.triangles))
            .sum::<f64>()
            / near.len().max(1) as f64;
    }
    let frames = truth.len() as f64;
    let (dent, error, none) = (dent / frames, error / frames, none / frames);
    println!("dent {dent:.2} mm, node error {error:.2} mm, no registration {none:.2} mm");
    assert!(
        dent <= 1.5,
        "the cloud at the dent is {dent:.2} mm from the registered surface"
    );
    assert!(
        error <= 0.15 * none,
        "node error {error:.2} mm against {none:.2} mm unregistered"
    );
}

/// A deep neo-Hookean press without the contact refit leaves the contact force to the
/// first-order rest-compliance fit; beyond small strain it is null and flagged
/// `force_beyond_linear`, never a number. The truth's force (`meta.json`, a tetrahedral FE
/// solve) is the independent reference. On the tuning set's neo-Hookean press (every third
/// frame) the fit's error grows with depth (measured 29 % at 2 mm, 53–73 % at 8–20 mm, 99 % at
/// 26 mm, displacement gradient 0.02 → 0.24); the frames from 31 mm on (gradient 0.30–0.55)
/// carry none. Asserted: the shallowest frame's force is within 35 % of the truth, the flag
/// and the missing force always go together, once beyond the limit a deeper frame stays beyond
/// it, and the deepest frames (from 45 mm) are flagged.
#[test]
fn a_first_order_force_beyond_small_strain_is_null_and_flagged() {
    use livereg::session::{FrameFlag, Session};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/liver_force/indentation-liver");
    let case = dir.join("press_neo-hookean");
    let mut loaded = load_scene(&dir.join("scene_neo-hookean.toml")).expect("scene");
    loaded
        .scene
        .registration
        .as_mut()
        .expect("the scene has [registration]")
        .contact_refit = false;
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(case.join("meta.json")).unwrap()).unwrap();
    let mut session = Session::from_scene(&loaded).expect("session");
    let mut flagged = Vec::new();
    for k in (0..30).step_by(3).chain([29]) {
        let points = livereg::mesh::read_points(&case.join(format!("frames/frame_{k:03}.xyz")))
            .expect("frame");
        let r = session.register(&livereg::session::Frame {
            source: format!("{k}"),
            points,
            camera: None,
        });
        assert!(r.error.is_none(), "frame {k}: {:?}", r.error);
        let v = &meta["force_vector_N"][k];
        let truth = nalgebra::Vector3::new(
            v[0].as_f64().unwrap(),
            v[1].as_f64().unwrap(),
            v[2].as_f64().unwrap(),
        );
        let beyond = r.flags.contains(&FrameFlag::ForceBeyondLinear);
        match &r.contact_force {
            Some(f) => {
                assert!(!beyond, "frame {k}: a force and the flag");
                assert!(
                    flagged.is_empty(),
                    "frame {k} has a force after {flagged:?}"
                );
                let error = (f.resultant - truth).norm() / truth.norm();
                if k == 0 {
                    assert!(error < 0.35, "frame 0: force error {error:.2}");
                }
            }
            None => {
                assert!(beyond, "frame {k}: no force and no flag saying why");
                flagged.push(k);
            }
        }
    }
    for k in [21, 24, 27, 29] {
        assert!(flagged.contains(&k), "frame {k} not flagged: {flagged:?}");
    }
}
