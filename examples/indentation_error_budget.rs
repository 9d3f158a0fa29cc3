//! Where the tool-indentation class's node error comes from: the fixture's sequences
//! (`fixtures/liver_indentation`, tetrahedral truths) registered with the scene's defaults
//! from clouds that take away one source of error at a time:
//!
//! 1. `camera`: the bench's clouds (500 points on 15 % of the surface around the contact,
//!    1.5 mm noise per axis, no camera pose);
//! 2. `camera, no noise`: the same patch, noise-free;
//! 3. `wider, no noise`: 2,000 noise-free points on 35 % of the surface (about all a camera
//!    at the contact sees);
//! 4. `whole surface`: every vertex and triangle centroid of the deformed truth surface,
//!    noise-free (`whole_surface_sequence`): what is left is the model's error (grid, law,
//!    hold), not the data's.
//!
//! Per case it prints the mean node error over every node and frame against no registration,
//! the mean inside and outside the indented region (4 cm around the tool), and the amplitude
//! `α = Σ u·u* / Σ u*·u*` of the registered displacement `u` along the true one `u*` (1: the
//! right amount of motion; below 1, the registration moves the liver too little). Run:
//!
//! `cargo run --release --example indentation_error_budget [-- SCENE]` (about a minute; SCENE:
//! another scene for the fixture's surface, e.g. finer cells).
//! docs/error-estimate.md#the-error-budget quotes its table.

use livereg::benchmark::indentation::{indentation_workload, scene_for, IndentationVariant};
use livereg::benchmark::Workload;
use livereg::scene::{load_scene, LoadedScene};
use livereg::session::Session;
use livereg::simulation::FromScene;
use livereg::synthetic::indentation::{
    bundled_fixture_dir, indentation_sequence, whole_surface_sequence, IndentationCloudSpec,
    IndentationFrame, IndentationTruth,
};

/// Sums over every node of every frame of one run.
#[derive(Default)]
struct Budget {
    error_mm: f64,
    none_mm: f64,
    region_mm: f64,
    region_nodes: f64,
    outside_mm: f64,
    outside_nodes: f64,
    along: f64,
    truth_sq: f64,
    nodes: f64,
    failed: usize,
}

impl Budget {
    fn row(&self) -> String {
        format!(
            "{:.2} ({:.0} %) | {:.2} / {:.2} | {:.2}{}",
            self.error_mm / self.nodes,
            100.0 * self.error_mm / self.none_mm,
            self.region_mm / self.region_nodes.max(1.0),
            self.outside_mm / self.outside_nodes.max(1.0),
            self.along / self.truth_sq,
            if self.failed > 0 {
                format!(", {} failed", self.failed)
            } else {
                String::new()
            }
        )
    }
}

/// Registers `frames` of `truth` with `scene` (clouds in the model's frame, no camera) and
/// sums the node errors.
fn budget(
    scene: &LoadedScene,
    truth: &IndentationTruth,
    frames: &[IndentationFrame],
) -> Result<Budget, String> {
    let scene = scene_for(scene, IndentationVariant::NoCamera);
    let scale = scene.length_scale();
    let w: Workload = indentation_workload(truth, frames, scale, false);
    let mut session = Session::from_scene(&scene).map_err(|e| e.to_string())?;
    let mut b = Budget::default();
    for (k, frame) in w.frames.iter().enumerate() {
        let r = session.register(frame);
        if r.error.is_some() {
            b.failed += 1;
        }
        let nodes = &r
            .structures
            .iter()
            .find(|(name, _)| name == "nodes")
            .ok_or("the scene has no `nodes` structure")?
            .1;
        let region = truth.indented_region(k);
        for (i, rest) in truth.nodes.iter().enumerate() {
            let u_true = truth.displacements[k][i];
            let u = nodes[i] * scale - rest;
            let e = (u - u_true).norm() * 1e3;
            b.error_mm += e;
            b.none_mm += u_true.norm() * 1e3;
            b.along += u.dot(&u_true);
            b.truth_sq += u_true.norm_squared();
            b.nodes += 1.0;
            if region[i] {
                b.region_mm += e;
                b.region_nodes += 1.0;
            } else {
                b.outside_mm += e;
                b.outside_nodes += 1.0;
            }
        }
    }
    Ok(b)
}

fn main() -> Result<(), String> {
    let dir = bundled_fixture_dir();
    let scene_path = std::env::args()
        .nth(1)
        .map_or_else(|| dir.join("scene.toml"), std::path::PathBuf::from);
    let scene = load_scene(&scene_path).map_err(|e| e.to_string())?;
    println!("scene {}", scene_path.display());
    println!(
        "| case | clouds | mean node error mm (of none) | region / outside mm | amplitude α |"
    );
    println!("|---|---|---|---|---|");
    for sequence in ["press-slide", "two-sites"] {
        for law in ["linear", "neo-hookean"] {
            let truth = IndentationTruth::load(&dir, sequence, law).map_err(|e| e.to_string())?;
            let camera = IndentationCloudSpec::default();
            let conditions = [
                ("camera", Some(camera)),
                (
                    "camera, no noise",
                    Some(IndentationCloudSpec {
                        noise_sigma: 0.0,
                        ..camera
                    }),
                ),
                (
                    "wider, no noise",
                    Some(IndentationCloudSpec {
                        noise_sigma: 0.0,
                        visible_fraction: 0.35,
                        points: 2000,
                        ..camera
                    }),
                ),
                ("whole surface", None),
            ];
            for (name, spec) in conditions {
                let frames = match &spec {
                    Some(spec) => indentation_sequence(&truth, spec),
                    None => whole_surface_sequence(&truth),
                };
                let row = match frames {
                    Ok(frames) => budget(&scene, &truth, &frames)?.row(),
                    Err(e) => format!("not generated: {e} | | "),
                };
                println!("| {sequence} {law} | {name} | {row} |");
            }
        }
    }
    Ok(())
}
