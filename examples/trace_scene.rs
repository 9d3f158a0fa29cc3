//! Solves a scene and prints every Newton iteration (load, relative residual, step length):
//! a diagnostic for convergence problems. Run:
//! `cargo run --release --example trace_scene -- fixtures/lobe_gravity/scene.toml`

use livereg::mechanics::NewtonSolver;
use livereg::scene::load_scene;
use livereg::simulation::FromScene;
use livereg::simulation::SceneModel;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).ok_or("usage: trace_scene SCENE")?;
    let loaded = load_scene(std::path::Path::new(&path))?;
    let mut model = SceneModel::from_scene(&loaded)?;
    let u0 = vec![0.0; model.problem.dofs()];
    let r = NewtonSolver::new(model.newton).solve(&mut model.problem, &[], &u0);
    for it in &r.history {
        println!(
            "load {:.4}  residual {:.3e}  step {:.4}  {} shift {:.0e}",
            it.load, it.relative_residual, it.step, it.linear_method, it.regularization
        );
    }
    println!(
        "{:?}: {} iterations, {} bisections, {:.0} ms",
        r.outcome, r.newton_iterations, r.bisections, r.wall_ms
    );
    Ok(())
}
