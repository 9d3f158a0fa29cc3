//! A release after a deep press on cells finer than the derived ones, against the force-driven
//! tetrahedral truth (`fixtures/liver_force`, quadratic tetrahedra solved by scikit-fem; a
//! tuning case of SPLIT.md): the registered liver unwinds the press as the tool lifts.
//!
//! The data term's springs put the seen patch back on the cloud within one or two ICP
//! iterations, while the far side, which only the elastic energy moves, is still on its way
//! there a few modified-Newton steps at a time. A penalty step that ends when only the pulled
//! points stopped moving leaves the far side carrying the press, and more so the finer the
//! cells; the body is relaxed under the step's last springs until its whole surface settles
//! (`registration::RELAX_NEWTON_ITERATIONS`).

use livereg::benchmark::force_truths::{
    force_truth_cases, force_truths_dir, run_force_truth, ForceTruthOptions, TruthSet,
};

/// Random liver 2's press-release neo-Hookean sequence (tuning set) on 8 mm cells: the first
/// five release frames (20–24, the press falling from 63 mm deep) end within 12 % of no
/// registration's error. Measured 1.22 against 14.1 mm (8.7 %, frames 0.62–2.25 mm); without
/// the body's relaxation the step ended on the pulled points alone and left 2.83 mm (20 %, frames
/// up to 4.3 mm). The same numbers in release (`cargo run --release -- bench --force-truths
/// --set tuning --cell-size 8`).
#[test]
fn a_released_liver_unwinds_the_press_on_finer_cells() {
    let cases = force_truth_cases(&force_truths_dir(), TruthSet::Tuning).expect("SPLIT.md");
    let case = cases
        .iter()
        .find(|c| c.name == "random-liver-2/press-release_neo-hookean")
        .expect("the case is in the tuning set");
    let options = ForceTruthOptions {
        cell_size: Some(8.0),
        ..Default::default()
    };
    let metrics = run_force_truth(case, &options).expect("registers");
    assert_eq!(metrics.frames.len(), 30, "the sequence has 30 frames");
    let release = &metrics.frames[20..25];
    let error: f64 = release.iter().map(|f| f.mean_mm).sum::<f64>() / release.len() as f64;
    let none: f64 = release.iter().map(|f| f.none_mm).sum::<f64>() / release.len() as f64;
    let per_frame: Vec<String> = release
        .iter()
        .map(|f| format!("{:.2}/{:.1}", f.mean_mm, f.none_mm))
        .collect();
    println!("release frames 20-24 (error/none, mm): {per_frame:?}; mean {error:.2} against {none:.1} mm");
    assert!(
        error <= 0.12 * none,
        "release frames {error:.2} mm against {none:.1} mm unregistered ({per_frame:?})"
    );
}
