//! The accuracy claim on the bundled phantom: with partial clouds (30 % of the surface
//! visible, 1 mm noise, 10 % outliers), non-rigid target TRE is at most 60 % of rigid-only
//! TRE, averaged over the scenarios.
//!
//! For each scenario of [`ScenarioKind::ALL`], a synthetic sequence
//! ([`SequenceSpec::phantom_default`]: the truth is a finer 10 mm finite-cell grid, ν = 0.49,
//! on an elastic bed — not the registration model) is registered rigid only
//! (`settings.non_rigid = false`) and with the full session, both with the thesis's rigid ICP
//! (pairs pruned at mean + 2σ, `registration.robust_pruning = false`). TRE = mean distance of
//! every target point (vessel bifurcations and tumour vertices) to its truth over all frames
//! ([`evaluate`]). The assertion is on the mean over the scenarios of the per-scenario ratio
//! non-rigid / rigid: what the non-rigid stage adds to the same rigid stage.
//!
//! The default rigid ICP prunes at median + 2 × 1.4826 MAD, which absorbs much of the error
//! the non-rigid stage corrects after the thesis's rigid stage: the ratio of the *default*
//! pipeline to its own rigid stage says little of what the non-rigid stage adds. So the claim
//! is checked with the thesis's rigid stage in both runs, and the default session is
//! registered too: its mean TRE must be within 5 % of the thesis pipeline's, and at most 60 %
//! of the thesis's rigid-only TRE on average.
//!
//! Frames: [`FRAMES`] = 10 per scenario, as the demo. Fewer frames would be faster but are
//! not a fair measurement: with 6 frames the mean ratio is 40 %, with 20 it is 57 % as with
//! 10. 40–100 s in the dev profile on a shared 2-core machine.
//!
//! Run: `cargo test --test registration partial_cloud_accuracy:: -- --nocapture` (prints the table).

use livereg::simulation::FromScene;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use livereg::benchmark::workload::Workload;
use livereg::evaluation::{evaluate, EvalReport, ResultRecord, TruthRecord};
use livereg::scene::{load_scene, LoadedScene};
use livereg::session::{FrameResult, Session};
use livereg::synthetic::{generate_sequence, ScenarioKind, SequenceSpec, SyntheticSequence};
use nalgebra::Point3;

/// Frames per scenario (as the demo). Overridable with `LIVEREG_ACCURACY_FRAMES` to measure
/// the ratio with another count.
const FRAMES: usize = 10;

/// The claim: non-rigid TRE at most this share of rigid-only TRE, averaged over the scenarios.
const MAX_MEAN_RATIO: f64 = 0.60;

fn frames() -> usize {
    std::env::var("LIVEREG_ACCURACY_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&n: &usize| n >= 1)
        .unwrap_or(FRAMES)
}

fn phantom(tag: &str) -> LoadedScene {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("livereg-accuracy-{}-{tag}", std::process::id()));
    livereg::phantom::write_phantom(&dir).expect("phantom written");
    load_scene(&dir.join("scene.toml")).expect("phantom scene loads")
}

/// `[x, y, z] / scale` (metres → scene units).
fn units(p: &Point3<f64>, scale: f64) -> [f64; 3] {
    [p.x / scale, p.y / scale, p.z / scale]
}

/// The truth file's records, in scene units, camera frame.
fn truth_records(seq: &SyntheticSequence, scale: f64) -> Vec<TruthRecord> {
    seq.frames
        .iter()
        .enumerate()
        .map(|(k, f)| TruthRecord {
            frame: k,
            structures: f
                .truth_structures
                .iter()
                .map(|(n, pts)| (n.clone(), pts.iter().map(|p| units(p, scale)).collect()))
                .collect(),
        })
        .collect()
}

/// Registers every frame of `seq` (points in scene units, as `register` reads them).
fn run(session: &mut Session, seq: &SyntheticSequence, scale: f64) -> Vec<FrameResult> {
    Workload::from_sequence(seq, scale)
        .frames
        .iter()
        .map(|f| session.register(f))
        .collect()
}

fn tre(results: &[FrameResult], truth: &[TruthRecord], scale: f64) -> EvalReport {
    let records: Vec<ResultRecord> = results
        .iter()
        .map(|r| ResultRecord::from_frame(r, scale))
        .collect();
    evaluate(&records, truth).expect("evaluates")
}

/// The rest shape at the TRUE pose, as a result: its TRE is how far the targets moved.
fn rest_at_true_pose(seq: &SyntheticSequence, scale: f64) -> Vec<ResultRecord> {
    (0..seq.frames.len())
        .map(|k| ResultRecord {
            frame: k,
            source: "rest".into(),
            wall_ms: 0.0,
            converged: true,
            rigid: livereg::evaluation::RigidRecord::from_transform(&seq.model_to_camera, scale),
            diagnostics: Default::default(),
            contact_force: None,
            expected_error: None,
            structures: seq
                .rest_structures
                .iter()
                .map(|(n, pts)| {
                    (
                        n.clone(),
                        pts.iter()
                            .map(|p| units(&seq.model_to_camera.apply(p), scale))
                            .collect(),
                    )
                })
                .collect::<BTreeMap<_, _>>(),
        })
        .collect()
}

struct Row {
    kind: ScenarioKind,
    max_disp_mm: f64,
    moved_mm: f64,
    rigid_mm: f64,
    non_rigid_mm: f64,
    ms_full: f64,
    not_converged: usize,
    /// The default session (median/MAD rigid pruning), mm.
    default_mm: f64,
}

#[test]
fn non_rigid_tre_is_at_most_60_percent_of_the_thesis_rigid_stage_on_partial_clouds() {
    let start = Instant::now();
    let default_scene = phantom("all");
    assert!(
        default_scene
            .scene
            .registration
            .as_ref()
            .is_some_and(|r| r.robust_pruning),
        "the phantom uses the default median/MAD rigid pruning"
    );
    // The thesis's rigid ICP (mean + 2σ), for the claim.
    let mut loaded = default_scene.clone();
    if let Some(r) = loaded.scene.registration.as_mut() {
        r.robust_pruning = false;
    }
    let scale = loaded.length_scale();
    let n = frames();
    let mut rows = Vec::new();
    for kind in ScenarioKind::ALL {
        let mut spec = SequenceSpec::phantom_default(kind);
        spec.frames = n;
        // The claim's conditions.
        assert_eq!(spec.cloud.visible_fraction, Some(0.3));
        assert_eq!(spec.cloud.noise_sigma, 1e-3);
        assert_eq!(spec.cloud.outlier_fraction, 0.1);
        let seq = generate_sequence(&loaded, &spec).expect("truth sequence");
        // A fair measurement: the load reaches its full value and the liver deforms by
        // 1.5–3.5 cm (the scenarios' design range).
        assert_eq!(seq.frames.last().unwrap().load_fraction, 1.0);
        let max_disp = seq
            .frames
            .iter()
            .map(|f| f.max_displacement)
            .fold(0.0, f64::max);
        assert!(
            (0.015..=0.035).contains(&max_disp),
            "{kind}: max surface displacement {:.1} mm",
            max_disp * 1e3
        );
        let truth = truth_records(&seq, scale);

        let mut rigid = Session::from_scene(&loaded).expect("session");
        rigid.settings.non_rigid = false;
        let rigid_results = run(&mut rigid, &seq, scale);
        let mut full = Session::from_scene(&loaded).expect("session");
        let t = Instant::now();
        let full_results = run(&mut full, &seq, scale);
        let ms_full = t.elapsed().as_secs_f64() * 1e3 / n as f64;
        let mut default = Session::from_scene(&default_scene).expect("session");
        assert!(default.settings.rigid.robust_pruning && !full.settings.rigid.robust_pruning);
        let default_results = run(&mut default, &seq, scale);
        for r in rigid_results
            .iter()
            .chain(&full_results)
            .chain(&default_results)
        {
            assert!(r.error.is_none(), "{kind} {}: {:?}", r.source, r.error);
        }
        let moved = evaluate(&rest_at_true_pose(&seq, scale), &truth).expect("evaluates");
        let e_rigid = tre(&rigid_results, &truth, scale);
        let e_full = tre(&full_results, &truth, scale);
        rows.push(Row {
            kind,
            max_disp_mm: max_disp / scale,
            moved_mm: moved.overall.mean,
            rigid_mm: e_rigid.overall.mean,
            non_rigid_mm: e_full.overall.mean,
            ms_full,
            not_converged: full_results.iter().filter(|r| !r.converged).count(),
            default_mm: tre(&default_results, &truth, scale).overall.mean,
        });
    }

    println!(
        "{:<17} {:>6} {:>9} {:>11} {:>10} {:>10} {:>7} {:>8} {:>6} {:>12}",
        "scenario",
        "frames",
        "max disp",
        "targets mv",
        "TRE rigid",
        "TRE full",
        "ratio",
        "ms/frm",
        "!conv",
        "TRE default"
    );
    for r in &rows {
        println!(
            "{:<17} {:>6} {:>6.1} mm {:>8.2} mm {:>7.2} mm {:>7.2} mm {:>6.1}% {:>8.0} {:>6} {:>9.2} mm",
            r.kind.name(),
            n,
            r.max_disp_mm,
            r.moved_mm,
            r.rigid_mm,
            r.non_rigid_mm,
            100.0 * r.non_rigid_mm / r.rigid_mm,
            r.ms_full,
            r.not_converged,
            r.default_mm
        );
    }
    let k = rows.len() as f64;
    let mean_ratio = rows
        .iter()
        .map(|r| r.non_rigid_mm / r.rigid_mm)
        .sum::<f64>()
        / k;
    let ratio_of_means = rows.iter().map(|r| r.non_rigid_mm).sum::<f64>()
        / rows.iter().map(|r| r.rigid_mm).sum::<f64>();
    println!(
        "mean of ratios {:.1} % (asserted <= {:.0} %), ratio of mean TREs {:.1} %; {:.1} s",
        100.0 * mean_ratio,
        100.0 * MAX_MEAN_RATIO,
        100.0 * ratio_of_means,
        start.elapsed().as_secs_f64()
    );
    assert!(
        mean_ratio <= MAX_MEAN_RATIO,
        "non-rigid TRE is {:.1} % of rigid-only on average (claimed: <= {:.0} %)",
        100.0 * mean_ratio,
        100.0 * MAX_MEAN_RATIO
    );
    // The default pipeline: as accurate as the thesis's, and within the claim's bound
    // against the thesis's rigid registration.
    let mean_of = |f: &dyn Fn(&Row) -> f64| rows.iter().map(f).sum::<f64>() / k;
    let (default_mm, thesis_mm) = (mean_of(&|r| r.default_mm), mean_of(&|r| r.non_rigid_mm));
    let default_ratio = mean_of(&|r| r.default_mm / r.rigid_mm);
    println!(
        "default session: mean TRE {default_mm:.2} mm against {thesis_mm:.2} mm with the thesis's rigid stage; {:.1} % of the thesis's rigid-only on average",
        100.0 * default_ratio
    );
    // Both pipelines pair cloud → surface, and the rigid stage's pruning hardly tells them
    // apart (0.69 against 0.68 mm); the default must not be worse than the thesis's rigid
    // stage by more than 5 %.
    assert!(
        default_mm <= 1.05 * thesis_mm,
        "the default session ({default_mm:.3} mm) is more than 5 % less accurate than the thesis's rigid stage ({thesis_mm:.3} mm)"
    );
    assert!(
        default_ratio <= MAX_MEAN_RATIO,
        "the default session's TRE is {:.1} % of the thesis's rigid-only on average",
        100.0 * default_ratio
    );
}
