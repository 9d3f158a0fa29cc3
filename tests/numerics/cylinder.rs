//! The thesis's cylinder experiments (§4.6): bending of a 60 cm neo-Hookean cylinder under a
//! dead end-face traction (weighted-cell against finite-cell, and both against a much finer
//! reference solve committed in `fixtures/reference/cylinder_bending.json`), and stretching of a
//! 5 cm one to three times its length at every subdivision level.

use livereg::grid::IntegrationMode;
use livereg::mechanics::Outcome;
use livereg::scenarios::{CylinderBending, CylinderStretching};
use nalgebra::Vector3;

fn reference() -> Vec<Vector3<f64>> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/fixtures/reference/cylinder_bending.json"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).expect("reference file")).unwrap();
    assert_eq!(v["outcome"], "converged");
    v["displacements"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| {
            Vector3::new(
                d[0].as_f64().unwrap(),
                d[1].as_f64().unwrap(),
                d[2].as_f64().unwrap(),
            )
        })
        .collect()
}

#[test]
fn bending_weighted_cell_matches_finite_cell_and_both_converge_to_the_reference() {
    let reference = reference();
    let mut errors = Vec::new();
    for cells_across in [4.0, 6.0] {
        let h = 2.0 * livereg::scenarios::cylinder::RADIUS / cells_across;
        let wc = CylinderBending {
            cell_size: h,
            levels: 2,
            mode: IntegrationMode::WeightedCell,
        }
        .solve();
        let fc = CylinderBending {
            cell_size: h,
            levels: 2,
            mode: IntegrationMode::FiniteCell,
        }
        .solve();
        assert_eq!(
            wc.report.outcome,
            Outcome::Converged,
            "{:?}",
            wc.report.message
        );
        assert_eq!(
            fc.report.outcome,
            Outcome::Converged,
            "{:?}",
            fc.report.message
        );
        let wc_fc = wc.relative_difference(&fc.displacements);
        let (e_wc, e_fc) = (
            wc.relative_difference(&reference),
            fc.relative_difference(&reference),
        );
        println!(
            "h = {h:.4} m: tip {:?}; |WC−FC|/|FC| = {wc_fc:.4}; error vs reference: WC {e_wc:.4}, FC {e_fc:.4}",
            wc.displacements[wc.displacements.len() - 3]
        );
        assert!(
            wc_fc < 0.05,
            "weighted-cell differs from finite-cell by {wc_fc}"
        );
        errors.push((e_wc, e_fc));
    }
    // Refinement brings both closer to the reference.
    assert!(
        errors[1].0 < errors[0].0 && errors[1].1 < errors[0].1,
        "{errors:?}"
    );
}

#[test]
fn stretching_to_three_times_the_length_solves_at_every_level() {
    let length = CylinderStretching::LENGTH;
    let mut cells = None;
    for levels in 0..=4 {
        let r = CylinderStretching {
            cell_size: 0.0125,
            levels,
            mode: IntegrationMode::WeightedCell,
        }
        .solve();
        assert_eq!(
            r.report.outcome,
            Outcome::Converged,
            "level {levels}: {:?}",
            r.report.message
        );
        // The same cells at every level: none removed.
        assert_eq!(*cells.get_or_insert(r.nodes), r.nodes);
        let (top, bottom) = (r.displacements[0].z, r.displacements[1].z);
        println!(
            "level {levels}: {} iterations, {} bisections, top {top:.4} m, bottom {bottom:.4} m",
            r.report.newton_iterations, r.report.bisections
        );
        // Penalty-imposed: within 5 % of the imposed ±L.
        assert!((top - length).abs() < 0.05 * length && (bottom + length).abs() < 0.05 * length);
    }
}
