//! A warm frame of the force-driven deep indentation (`fixtures/liver_force`, tuning liver
//! `indentation-liver`, 4,539 unknowns at the derived 11.5 mm cells, 500-point clouds on 15 %
//! of the surface), where the contact refit runs: `Session::register` alternating between the
//! press's frames 24 and 25 (about 2 mm apart at the tool) after the session has followed
//! frames 0–25, for the linear and the neo-Hookean truth with each law's own scene. The
//! stage times of one such frame are printed first (the refit's share: docs/frames.md, "The
//! cost of a warm frame").
//!
//! Run: `cargo bench --bench force_driven_frame` (about a minute; `-- --quick` for a rough
//! number).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, SamplingMode};
use livereg::benchmark::force_truths::{
    force_truth_cases, force_truth_scene, force_truths_dir, ForceTruthOptions, TruthSet,
};
use livereg::cli::register::FrameInput;
use livereg::session::{frame_files, Frame, Session};
use livereg::simulation::FromScene;

#[path = "support/alternating_frames.rs"]
mod alternating_frames;
use alternating_frames::bench_alternating_frames;

/// The frames followed before the bench's pair, and the pair.
const FOLLOWED: usize = 26;
const PAIR: (usize, usize) = (24, 25);

fn bench_force_driven_frame(c: &mut Criterion) {
    let cases = force_truth_cases(&force_truths_dir(), TruthSet::Tuning).unwrap();
    let mut group = c.benchmark_group("force_driven_frame");
    group.sample_size(10);
    group.sampling_mode(SamplingMode::Flat);
    group.warm_up_time(std::time::Duration::from_secs(2));
    group.measurement_time(std::time::Duration::from_secs(8));
    for name in [
        "indentation-liver/press_linear",
        "indentation-liver/press_neo-hookean",
    ] {
        let case = cases.iter().find(|c| c.name == name).unwrap();
        let scene = force_truth_scene(case, &ForceTruthOptions::default()).unwrap();
        let files = frame_files(&case.dir.join("frames")).unwrap().frames;
        let frames: Vec<Frame> = files
            .iter()
            .map(|f| FrameInput::File(f.clone()).read().unwrap())
            .collect();
        let mut session = Session::from_scene(&scene).unwrap();
        let mut last = None;
        for f in &frames[..FOLLOWED] {
            let r = session.register(f);
            assert!(r.error.is_none(), "{name}: {:?}", r.error);
            last = Some(r);
        }
        let r = last.unwrap();
        eprintln!(
            "{name}: {} unknowns; a warm frame {:.1} ms, {} factorisations, flags {:?}, \
             stages {:?}",
            session.model.problem.dofs(),
            r.wall_ms,
            r.factorizations,
            r.flags,
            r.times
        );
        bench_alternating_frames(
            &mut group,
            BenchmarkId::new("warm_frame", name),
            &mut session,
            &frames[PAIR.0],
            &frames[PAIR.1],
        );
    }
    group.finish();
}

criterion_group!(benches, bench_force_driven_frame);
criterion_main!(benches);
