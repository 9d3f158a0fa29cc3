//! Benchmark of the contact force of one frame (`registration::RestCompliance`): on the
//! tool-indentation liver's model (`fixtures/liver_indentation`, the derived 11.5 mm cells),
//! the rest tangent's factorisation (once per session) and the fit of a concentrated load to
//! the displacements of the seen surface vertices (every frame: three solves and the least
//! squares), here the tetrahedral truth's press-slide frame 20 (50 mm deep) within 6 cm of the
//! tool, about the clouds' 15 %.
//!
//! Run: `cargo bench --bench contact_force -- --warm-up-time 1 --measurement-time 3`

use livereg::simulation::FromScene;
use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use livereg::grid::Embedding;
use livereg::registration::RestCompliance;
use livereg::scene::load_scene;
use livereg::session::Session;
use livereg::synthetic::indentation::{bundled_fixture_dir, IndentationTruth};

fn bench_contact_force(c: &mut Criterion) {
    let scene = load_scene(&bundled_fixture_dir().join("scene.toml")).unwrap();
    let mut session = Session::from_scene(&scene).unwrap();
    let kind = session.model.newton.linear_solver;
    let truth = IndentationTruth::load(&bundled_fixture_dir(), "press-slide", "linear").unwrap();
    let k = 20;
    let tool = &truth.frames[k];
    let model = &session.model;
    let seen: Vec<usize> = (0..model.surface.vertices.len())
        .filter(|&v| (model.surface.vertices[v] - tool.tool_centre).norm() < 0.06)
        .collect();
    let points: Vec<_> = seen.iter().map(|&v| model.surface.vertices[v]).collect();
    let embedding = Embedding::new(&model.problem.grid, &points).unwrap();
    let moved: Vec<_> = seen.iter().map(|&v| truth.displacements[k][v]).collect();
    let all_normals = model.surface.vertex_normals();
    let normals: Vec<_> = seen.iter().map(|&v| all_normals[v]).collect();
    eprintln!(
        "{} unknowns, {} seen vertices",
        model.problem.dofs(),
        seen.len()
    );

    let mut group = c.benchmark_group("contact_force");
    group.sample_size(20);
    group.bench_function("rest factorisation (once per session)", |b| {
        b.iter(|| black_box(RestCompliance::new(&mut session.model.problem, kind).unwrap()))
    });
    let mut compliance = RestCompliance::new(&mut session.model.problem, kind).unwrap();
    let model = &session.model;
    group.bench_function("fit (every frame)", |b| {
        b.iter(|| {
            black_box(compliance.fit_displacements(
                &model.problem,
                &model.surface,
                &embedding,
                &moved,
                Some(&normals),
            ))
        })
    });
    group.finish();
}

criterion_group!(benches, bench_contact_force);
criterion_main!(benches);
