//! Issue 18: the tool-indentation class against a truth from an independent discretisation
//! (quadratic tetrahedra solved by scikit-fem, `fixtures/liver_indentation`), with clouds as a
//! camera gives them (500 points on 15 % of the surface around the contact, 1.5 mm noise per
//! axis, `rigid = "none"`, no camera pose). Tolerances come from the measurements recorded in
//! docs/registration.md (release build, `livereg bench --indentation`), with margin.

use livereg::benchmark::indentation::{
    indentation_cases, run_indentation, IndentationMetrics, IndentationVariant,
};
use livereg::scene::{load_scene, DataTerm, LoadedScene};
use livereg::synthetic::indentation::bundled_fixture_dir;

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

fn run(data_term: DataTerm) -> IndentationMetrics {
    let cases = indentation_cases(
        &bundled_fixture_dir(),
        &["two-sites"],
        &["linear"],
        &[IndentationVariant::NoCamera],
        None,
    )
    .expect("cases");
    let mut rows = run_indentation(&scene(data_term), &cases, &mut |_| {}).expect("runs");
    rows.remove(0)
}

/// Two sites, the first on the thin left lobe (30 mm deep), the second 70 mm deep on the
/// thick lobe, 50 frames, no camera pose: the default registration follows (measured mean
/// node error 0.83 mm against 1.75 mm unregistered, p95 1.97 against 5.48 mm, no failed
/// frame), and better than the thesis's surface → cloud pairing (measured 1.26 mm here; with
/// the linear law that pairing pulled the thin lobe's far side onto the dent and ended at
/// 6.74 mm, worse than no registration: docs/registration.md).
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
    // The deepest frame (70 mm): the registration explains most of the motion (measured
    // 1.67 mm against 4.49 mm unregistered).
    let last = m.frames.last().expect("frames");
    assert!(
        last.mean_mm <= 0.5 * last.none_mean_mm,
        "last frame {:.2} mm against {:.2} mm unregistered",
        last.mean_mm,
        last.none_mean_mm
    );
    // The contact force: on the deep frames (true force above half the sequence's largest) the
    // estimate's size is the tool's within a factor of two (measured median ratio printed;
    // the direction is not yet reliable: median relative vector error ~70 %, issue 18's 15 %
    // goal is not met — docs/registration.md).
    let largest = m.frames.iter().map(|f| f.force_true_n).fold(0.0, f64::max);
    let mut ratios: Vec<f64> = m
        .frames
        .iter()
        .filter(|f| f.force_true_n > 0.5 * largest)
        .map(|f| f.force_estimate_n.expect("an estimate on every frame") / f.force_true_n)
        .collect();
    ratios.sort_by(f64::total_cmp);
    let median = ratios[ratios.len() / 2];
    println!(
        "contact force magnitude ratio on deep frames: median {median:.2}, range {:.2}–{:.2}",
        ratios[0],
        ratios[ratios.len() - 1]
    );
    assert!(
        (0.5..=2.0).contains(&median),
        "median force ratio {median:.2}"
    );

    let old = run(DataTerm::SurfaceToCloud);
    println!("surface → cloud: mean {:.2} mm", old.mean_mm);
    assert!(
        old.mean_mm > 1.3 * m.mean_mm,
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
