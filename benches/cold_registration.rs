//! A cold registration on the bundled phantom: one frame showing a ~3 cm deformation at full
//! load (tool-push: the thin lobe lifted by 400 Pa, ~32 mm; gravity-pose: a 25° tilt,
//! ~30 mm), registered from the rest shape by a session that has seen nothing (after
//! `reset()`: identity pose, zero displacement, the full penalty ramp, no kept
//! factorisation). The session is built once (grid, quadrature, embeddings); building it is
//! benched separately.
//!
//! Run: `cargo bench --bench cold_registration` (`-- --quick` for a rough number).

use livereg::simulation::FromScene;
use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, SamplingMode};
use livereg::scene::load_scene;
use livereg::session::{Frame, Session};
use livereg::synthetic::{generate_sequence, ScenarioKind, SequenceSpec};

fn bench_cold_registration(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("livereg-bench-cold-{}", std::process::id()));
    livereg::phantom::write_phantom(&dir).unwrap();
    let loaded = load_scene(&dir.join("scene.toml")).unwrap();
    let scale = loaded.length_scale();

    let mut group = c.benchmark_group("cold_registration");
    group.sample_size(10);
    // Frames take 0.1–1 s: the same number of iterations in every sample.
    group.sampling_mode(SamplingMode::Flat);
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(10));
    for kind in [ScenarioKind::ToolPush, ScenarioKind::GravityPose] {
        // One frame: the full load at once.
        let mut spec = SequenceSpec::phantom_default(kind);
        spec.frames = 1;
        let seq = generate_sequence(&loaded, &spec).unwrap();
        let f = &seq.frames[0];
        assert_eq!(f.load_fraction, 1.0);
        let frame = Frame {
            source: kind.name().into(),
            points: f.cloud.iter().map(|p| p / scale).collect(),
            camera: None,
        };
        let mut session = Session::from_scene(&loaded).unwrap();
        let r = session.register(&frame);
        assert!(r.error.is_none(), "{:?}", r.error);
        assert!(!r.warm);
        eprintln!(
            "{kind}: max displacement {:.1} mm, {} points; cold frame {:.0} ms: {} rigid / {} \
             ICP / {} Newton iterations, {} factorisations, stages {:?}",
            f.max_displacement * 1e3,
            frame.points.len(),
            r.wall_ms,
            r.rigid_iterations,
            r.icp_iterations,
            r.newton_iterations,
            r.factorizations,
            r.times
        );
        group.bench_function(kind.name(), |b| {
            b.iter(|| {
                session.reset();
                let r = session.register(black_box(&frame));
                assert!(r.error.is_none() && !r.warm, "{:?}", r.error);
                r
            })
        });
    }
    group.bench_function("session_from_scene", |b| {
        b.iter(|| Session::from_scene(black_box(&loaded)).unwrap())
    });
    group.finish();
}

criterion_group!(benches, bench_cold_registration);
criterion_main!(benches);
