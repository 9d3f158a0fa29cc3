//! A warm-started frame on the bundled phantom (the goal: 30 ms per warm frame):
//! `Session::register` of a partial cloud (30 % of the surface, 3 samples/cm², 1 mm noise,
//! 10 % outliers: ~800 points) after the session has followed the first frames of a
//! tool-push sequence. The bench alternates between two nearby frames (the end of the load
//! ramp: 94 % and 100 % of the full load, ~2 mm apart at the surface), so every measured
//! frame has something to follow. Two grids: the phantom's 15 mm cells (~865 nodes) and
//! 12 mm (~1,500 nodes), each with refactorisation in place (`phantom_nodes`), without the
//! cut-cell step stabilisation (`unstabilised_nodes`, `solver.step_stabilization = 0`) and on
//! a helper thread (`background_nodes`, `registration.background_factorization`), and the
//! 12 mm grid with single-precision factorisations (`mixed_nodes`, `solver.mixed_precision`),
//! alone and with the helper thread (`background_mixed_nodes`).
//!
//! Run: `cargo bench --bench warm_frame` (a few minutes; `-- --quick` for a rough number).

use livereg::simulation::FromScene;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, SamplingMode};
use livereg::benchmark::workload::Workload;
use livereg::scene::load_scene;
use livereg::session::Session;
use livereg::synthetic::{generate_sequence, ScenarioKind, SequenceSpec};

#[path = "support/alternating_frames.rs"]
mod alternating_frames;
use alternating_frames::bench_alternating_frames;

/// Frames of the sequence; frames 5 and 6 are the bench's pair (load 0.94 and 1.0).
const FRAMES: usize = 10;

fn bench_warm_frame(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("livereg-bench-warm-{}", std::process::id()));
    livereg::phantom::write_phantom(&dir).unwrap();
    let loaded = load_scene(&dir.join("scene.toml")).unwrap();
    let scale = loaded.length_scale();
    let mut spec = SequenceSpec::phantom_default(ScenarioKind::ToolPush);
    spec.frames = FRAMES;
    let seq = generate_sequence(&loaded, &spec).unwrap();
    let frames = Workload::from_sequence(&seq, scale).frames;
    let (a, b) = (&frames[5], &frames[6]);
    eprintln!(
        "clouds of {} and {} points; load {:.3} and {:.3}",
        a.points.len(),
        b.points.len(),
        seq.frames[5].load_fraction,
        seq.frames[6].load_fraction
    );

    let mut group = c.benchmark_group("warm_frame");
    group.sample_size(10);
    // Frames take 0.1–1 s: the same number of iterations in every sample.
    group.sampling_mode(SamplingMode::Flat);
    group.warm_up_time(std::time::Duration::from_secs(2));
    group.measurement_time(std::time::Duration::from_secs(8));
    // (cell mm, helper thread, mixed precision, cut-cell step stabilisation on)
    for (cell_mm, background, mixed, stabilised) in [
        (15.0, false, false, true),
        (12.0, false, false, true),
        (15.0, false, false, false),
        (12.0, false, false, false),
        (15.0, true, false, true),
        (12.0, true, false, true),
        (12.0, false, true, true),
        (12.0, true, true, true),
    ] {
        let mut scene = loaded.clone();
        scene.scene.grid.cell_size = cell_mm;
        scene.scene.solver.mixed_precision = mixed;
        if !stabilised {
            scene.scene.solver.step_stabilization = 0.0;
        }
        scene
            .scene
            .registration
            .get_or_insert_with(Default::default)
            .background_factorization = background;
        let t = Instant::now();
        let mut session = Session::from_scene(&scene).unwrap();
        let nodes = session.model.problem.grid.node_count();
        let build_ms = t.elapsed().as_secs_f64() * 1e3;
        // Follow the sequence up to the pair (frame 0 is cold).
        let mut last = None;
        for f in &frames[..=6] {
            let r = session.register(f);
            assert!(r.error.is_none(), "{:?}", r.error);
            last = Some(r);
        }
        let r = last.unwrap();
        eprintln!(
            "{cell_mm} mm cells, background {background}, mixed precision {mixed}, stabilised \
             {stabilised}: {nodes} nodes \
             (session built in \
             {build_ms:.0} ms); warm frame \
             {:.1} ms: {} ICP / {} Newton iterations, {} factorisations, {} sources, \
             stages {:?}",
            r.wall_ms, r.icp_iterations, r.newton_iterations, r.factorizations, r.sources, r.times
        );
        let id = match (background, mixed, stabilised) {
            (_, _, false) => "unstabilised_nodes",
            (true, true, _) => "background_mixed_nodes",
            (true, false, _) => "background_nodes",
            (false, true, _) => "mixed_nodes",
            (false, false, _) => "phantom_nodes",
        };
        bench_alternating_frames(&mut group, BenchmarkId::new(id, nodes), &mut session, a, b);
    }
    group.finish();
}

criterion_group!(benches, bench_warm_frame);
criterion_main!(benches);
