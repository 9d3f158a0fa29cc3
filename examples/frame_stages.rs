//! Registers a tool-indentation sequence (`fixtures/liver_indentation`) or the phantom's three
//! synthetic scenarios and prints, per frame, the wall time and each stage's share
//! (`FrameResult::times`), the ICP and Newton iterations, the factorisations and the flags;
//! then the warm frames' p50, p95 and mean, and each stage's mean over them. A diagnostic for
//! where a warm frame's time goes (docs/frames.md#the-cost-of-a-warm-frame). Run:
//!
//! `cargo run --release --example frame_stages -- press-slide linear` (a sequence and a truth
//! law of the fixture; clouds in the model's frame, no camera), or
//! `cargo run --release --example frame_stages -- phantom` (10 frames per scenario), or
//! `cargo run --release --example frame_stages -- force NAME-PART` (every force truth of
//! `fixtures/liver_force` whose name contains NAME-PART, e.g. `indentation-liver/press_neo`, with its own
//! law's scene; no camera).
//! `REPEAT=N` registers it N times, each with a fresh session; `QUIET=1` prints the summary only.

use livereg::benchmark::indentation::{
    indentation_cases, indentation_workload, scene_for, IndentationVariant,
};
use livereg::benchmark::Workload;
use livereg::evaluation::percentile;
use livereg::scene::{load_scene, LoadedScene};
use livereg::session::{Session, StageTimes};
use livereg::simulation::FromScene;

fn workloads(args: &[String]) -> Result<(LoadedScene, Vec<Workload>), String> {
    let what = args.get(1).map_or("press-slide", String::as_str);
    if what == "phantom" {
        let dir = std::env::temp_dir().join("livereg-frame-stages-phantom");
        livereg::phantom::write_phantom(&dir).map_err(|e| e.to_string())?;
        let scene = load_scene(&dir.join("scene.toml")).map_err(|e| e.to_string())?;
        let w = livereg::cli::bench::synthetic_workloads(&scene, &[], 10, false, 0, None)?;
        return Ok((scene, w));
    }
    if what == "force" {
        return force_workloads(args.get(2).map_or("", String::as_str));
    }
    let law = args.get(2).map_or("linear", String::as_str);
    let dir = livereg::synthetic::indentation::bundled_fixture_dir();
    let scene = load_scene(&dir.join("scene.toml")).map_err(|e| e.to_string())?;
    let cases = indentation_cases(&dir, &[what], &[law], &[IndentationVariant::NoCamera], None)?;
    let case = cases.first().ok_or("no such case")?;
    let applied = scene_for(&scene, case.variant);
    let w = indentation_workload(&case.truth, &case.frames, applied.length_scale(), false);
    Ok((applied, vec![w]))
}

/// The force truths whose name contains `part`, all registered with the first one's scene.
fn force_workloads(part: &str) -> Result<(LoadedScene, Vec<Workload>), String> {
    use livereg::benchmark::force_truths::{
        force_truth_cases, force_truth_scene, force_truths_dir, ForceTruthOptions, TruthSet,
    };
    let cases: Vec<_> = force_truth_cases(&force_truths_dir(), TruthSet::All)?
        .into_iter()
        .filter(|c| c.name.contains(part))
        .collect();
    let first = cases.first().ok_or("no force truth of that name")?;
    let scene = force_truth_scene(first, &ForceTruthOptions::default())?;
    let mut workloads = Vec::new();
    for case in cases.iter().filter(|c| c.law == first.law) {
        let files = livereg::session::frame_files(&case.dir.join("frames"))?.frames;
        let frames = files
            .iter()
            .map(|f| {
                livereg::cli::register::FrameInput::File(f.clone())
                    .read()
                    .map_err(|(source, e)| format!("{source}: {e}"))
            })
            .collect::<Result<Vec<_>, _>>()?;
        workloads.push(Workload {
            name: case.name.clone(),
            frames,
            truth: Vec::new(),
            max_displacement_mm: None,
            truth_law: Some(case.law.clone()),
        });
    }
    Ok((scene, workloads))
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().collect();
    let repeat: usize = std::env::var("REPEAT")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let quiet = std::env::var("QUIET").is_ok();
    let (scene, workloads) = workloads(&args)?;
    let mut warm = Vec::new();
    // Each stage's name and summed time over the warm frames.
    let mut stage_sums = StageTimes::default().named();
    for _ in 0..repeat {
        for w in &workloads {
            let mut session = Session::from_scene(&scene).map_err(|e| e.to_string())?;
            for (i, frame) in w.frames.iter().enumerate() {
                let r = session.register(frame);
                if r.warm {
                    warm.push(r.wall_ms);
                    for (sum, (_, v)) in stage_sums.iter_mut().zip(r.times.named()) {
                        sum.1 += v;
                    }
                }
                if quiet {
                    continue;
                }
                let stages: Vec<String> = r
                    .times
                    .named()
                    .iter()
                    .map(|(name, v)| format!("{name} {v:5.1}"))
                    .collect();
                println!(
                    "{i:3} {:7.1} ms | {} | icp {} newton {} factorisations {} | {:?}",
                    r.wall_ms,
                    stages.join(" "),
                    r.icp_iterations,
                    r.newton_iterations,
                    r.factorizations,
                    r.flags
                );
            }
        }
    }
    warm.sort_by(f64::total_cmp);
    if !warm.is_empty() {
        println!(
            "warm frames {}: p50 {:.2} ms, p95 {:.2} ms, mean {:.2} ms",
            warm.len(),
            percentile(&warm, 0.5),
            percentile(&warm, 0.95),
            warm.iter().sum::<f64>() / warm.len() as f64
        );
        let means: Vec<String> = stage_sums
            .iter()
            .map(|(name, sum)| format!("{name} {:.2}", sum / warm.len() as f64))
            .collect();
        println!("warm frames' stage means, ms: {}", means.join(", "));
    }
    Ok(())
}
