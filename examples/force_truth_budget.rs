//! Where the force truths' node error comes from (`fixtures/liver_force`, tetrahedral truths).
//! Each case's graded frames are registered, with the scene's defaults, from the fixture's
//! clouds and from clouds that take away one source of error at a time, beside solves of the
//! project's grid that are given what the cloud cannot show:
//!
//! 1. `camera`: the fixture's clouds (500 noise-free points on 15 % of the surface), the
//!    bench's registration;
//! 2. `whole surface`: registered from every vertex and triangle centroid of the deformed truth
//!    surface, what a sensor seeing all of the liver would give: what is left is the model's
//!    error (grid, law, hold), not the data's;
//! 3. `forward`: no registration: the grid solved under the truth's own applied load (the nodal
//!    patch forces of `meta.json`), the discretisation's error for the same load;
//! 4. `seen held`: the seen surface vertices (those nearest a cloud point) held at their true
//!    positions by stiff springs, no load: what the seen part determines when its motion is
//!    known whole, tangential part included;
//! 5. `seen near patch held`: the same for the seen vertices within 20 mm of the patch only;
//! 6. `seen held along normal`: the seen vertices held along the true deformed normal only, a
//!    perfect point-to-plane fit: what a cloud (which shows where the surface is, not how its
//!    points slid along it) can determine at best.
//!
//! Per case and row: the mean node error over every truth node of the graded frames, and the
//! same near the patch (within 10 mm of its centre at rest), mm. Run:
//!
//! `cargo run --release --example force_truth_budget [-- --set tuning|test|all] [--frames K,…]
//! [--cell-size MM] [--only NAME-PART]` (default: every case, frames 9, 19 and 29; ~5 min).
//! docs/force-truths.md#the-error-budget quotes its table.

use livereg::simulation::FromScene;
use std::path::Path;

use livereg::benchmark::force_truths::{
    force_truth_cases, force_truth_scene, force_truths_dir, ForceTruthCase, ForceTruthOptions,
    TruthSet, NEAR_TOOL_MM,
};
use livereg::evaluation::read_truth;
use livereg::mechanics::{NewtonSolver, Outcome};
use livereg::mesh::{read_obj, read_points};
use livereg::session::{Frame, Session};
use livereg::simulation::SceneModel;
use nalgebra::{Point3, Vector3};

/// The truth's load (meta.json).
#[derive(serde::Deserialize)]
struct Meta {
    patch_centre_vertex: usize,
    patch_vertex_indices: Vec<usize>,
    patch_vertex_force_shares: Vec<f64>,
    #[serde(rename = "force_vector_N")]
    force_vector_n: Vec<[f64; 3]>,
}

/// Mean error over all nodes and over the nodes near the patch, mm.
fn errors(a: &[Point3<f64>], b: &[Point3<f64>], near: &[bool]) -> (f64, f64) {
    let (mut all, mut n_near, mut sum_near) = (0.0f64, 0.0f64, 0.0f64);
    for ((p, q), &m) in a.iter().zip(b).zip(near) {
        let e = (p - q).norm();
        all += e;
        if m {
            sum_near += e;
            n_near += 1.0;
        }
    }
    (all / a.len() as f64, sum_near / n_near.max(1.0))
}

fn nodes_of(r: &livereg::session::FrameResult) -> Vec<Point3<f64>> {
    r.structures
        .iter()
        .find(|(n, _)| n == "nodes")
        .map(|(_, p)| p.clone())
        .unwrap_or_default()
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut set = TruthSet::All;
    let mut graded = vec![9usize, 19, 29];
    let mut options = ForceTruthOptions::default();
    let mut only: Option<String> = None;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--set" => set = TruthSet::from_name(it.next().ok_or("--set needs a value")?)?,
            "--frames" => {
                graded = it
                    .next()
                    .ok_or("--frames needs a value")?
                    .split(',')
                    .map(|s| s.parse().map_err(|e| format!("--frames {s}: {e}")))
                    .collect::<Result<_, _>>()?
            }
            "--cell-size" => {
                let v = it.next().ok_or("--cell-size needs a value")?;
                options.cell_size = Some(v.parse().map_err(|e| format!("--cell-size {v}: {e}"))?)
            }
            "--only" => only = Some(it.next().ok_or("--only needs a value")?.clone()),
            other => return Err(format!("unknown argument {other}")),
        }
    }
    println!(
        "| case | none | camera | whole surface | forward | seen held | seen near patch held | seen held along normal |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for case in force_truth_cases(&force_truths_dir(), set)? {
        if only
            .as_ref()
            .is_some_and(|o| !case.name.contains(o.as_str()))
        {
            continue;
        }
        println!("{}", budget_row(&case, &graded, &options)?);
    }
    println!("\nEach cell: mean node error over all nodes / within {NEAR_TOOL_MM} mm of the patch, mm, frames {graded:?}.");
    Ok(())
}

fn budget_row(
    case: &ForceTruthCase,
    graded: &[usize],
    options: &ForceTruthOptions,
) -> Result<String, String> {
    let at = |p: &Path, e: &dyn std::fmt::Display| format!("{}: {e}", p.display());
    let scene = force_truth_scene(case, options)?;
    let surface_path = case.liver_dir.join("liver.obj");
    let surface = read_obj(&surface_path).map_err(|e| at(&surface_path, &e))?;
    let rest = read_points(&case.liver_dir.join("nodes.xyz")).map_err(|e| e.to_string())?;
    let meta_path = case.dir.join("meta.json");
    let meta: Meta =
        serde_json::from_str(&std::fs::read_to_string(&meta_path).map_err(|e| at(&meta_path, &e))?)
            .map_err(|e| at(&meta_path, &e))?;
    let truth = read_truth(case.dir.join("truth.jsonl")).map_err(|e| e.to_string())?;
    let frames = livereg::session::frame_files(&case.dir.join("frames"))?.frames;
    let near: Vec<bool> = rest
        .iter()
        .map(|p| (p - rest[meta.patch_centre_vertex]).norm() < NEAR_TOOL_MM)
        .collect();
    let nv = surface.vertices.len();
    let last = *graded.iter().max().unwrap_or(&0);
    let mut camera = Session::from_scene(&scene).map_err(|e| e.to_string())?;
    let mut whole = Session::from_scene(&scene).map_err(|e| e.to_string())?;
    let mut model = SceneModel::from_scene(&scene).map_err(|e| e.to_string())?;
    let patch: Vec<Point3<f64>> = meta
        .patch_vertex_indices
        .iter()
        .map(|&i| surface.vertices[i] * 1e-3)
        .collect();
    let patch_embedding =
        livereg::grid::Embedding::new(&model.problem.grid, &patch).map_err(|e| e.to_string())?;
    let nodes = model
        .structures
        .iter()
        .position(|s| s.name == "nodes")
        .ok_or("no `nodes` structure")?;
    let mut sums = [(0.0, 0.0); 7];
    let radius_mm = 20.0;
    let surface_embedding = model.surface_embedding.clone();
    let mut u = vec![0.0; model.problem.dofs()];
    for k in 0..=last.min(frames.len() - 1) {
        let true_nodes: Vec<Point3<f64>> = truth[k].structures["nodes"]
            .iter()
            .map(|p| Point3::from(*p))
            .collect();
        let cloud_points = read_points(&frames[k]).map_err(|e| e.to_string())?;
        let r_camera = camera.register(&Frame {
            source: format!("{k}"),
            points: cloud_points.clone(),
            camera: None,
        });
        let mut full: Vec<Point3<f64>> = true_nodes[..nv].to_vec();
        for t in &surface.triangles {
            full.push(Point3::from(
                (true_nodes[t[0]].coords + true_nodes[t[1]].coords + true_nodes[t[2]].coords) / 3.0,
            ));
        }
        let r_whole = whole.register(&Frame {
            source: format!("{k}"),
            points: full,
            camera: None,
        });
        // Forward: the truth's nodal patch forces, from the last frame's state.
        let f = Vector3::from(meta.force_vector_n[k]);
        let forces: Vec<Vector3<f64>> = meta
            .patch_vertex_force_shares
            .iter()
            .map(|s| f * *s)
            .collect();
        model.problem.external.iter_mut().for_each(|x| *x = 0.0);
        patch_embedding.spread_forces(&forces, &mut model.problem.external);
        let mut solver = NewtonSolver::new(model.newton);
        let report = solver.solve(&mut model.problem, &[], &vec![0.0; u.len()]);
        if report.outcome != Outcome::Converged {
            eprintln!("{} frame {k}: forward {:?}", case.name, report.message);
        }
        u = report.u;
        if !graded.contains(&k) {
            continue;
        }
        // Oracle: the seen vertices (within 1 mm of a cloud point's nearest vertex) held at
        // their true positions by stiff isotropic springs, no load.
        let index = livereg::registration::IndexedPoints::new(true_nodes[..nv].to_vec())
            .ok_or("no surface")?;
        let mut seen = vec![false; nv];
        for p in &cloud_points {
            seen[index.nearest(p).0] = true;
        }
        let deformed = livereg::mesh::TriSurface {
            vertices: true_nodes[..nv].to_vec(),
            triangles: surface.triangles.clone(),
        };
        let normals = deformed.vertex_normals();
        let centre = surface.vertices[meta.patch_centre_vertex];
        let mut held = |radius: f64, plane: bool| -> Result<Vec<Point3<f64>>, String> {
            let ids: Vec<usize> = (0..nv)
                .filter(|&i| seen[i] && (surface.vertices[i] - centre).norm() < radius)
                .collect();
            let stiffness =
                200.0 * model.problem.material.young_modulus() * model.problem.cell_size();
            let springs = livereg::mechanics::PenaltySprings {
                embedding: livereg::grid::Embedding {
                    points: ids.iter().map(|&i| surface_embedding.points[i]).collect(),
                    rest: ids.iter().map(|&i| surface_embedding.rest[i]).collect(),
                },
                target: ids
                    .iter()
                    .map(|&i| (true_nodes[i] - surface.vertices[i]) * 1e-3)
                    .collect(),
                stiffness: vec![stiffness; ids.len()],
                follows_load: true,
                normals: plane.then(|| ids.iter().map(|&i| normals[i]).collect()),
            };
            model.problem.external.iter_mut().for_each(|x| *x = 0.0);
            let mut solver = NewtonSolver::new(model.newton);
            let report = solver.solve(&mut model.problem, &[springs], &vec![0.0; u.len()]);
            if report.outcome != Outcome::Converged {
                eprintln!("{} frame {k}: oracle {:?}", case.name, report.message);
            }
            Ok(model.structures[nodes]
                .embedding
                .positions(&report.u)
                .iter()
                .map(|p| p * 1e3)
                .collect())
        };
        let oracle = held(f64::INFINITY, false)?;
        let oracle_near = held(radius_mm, false)?;
        let plane = held(f64::INFINITY, true)?;
        let forward: Vec<Point3<f64>> = model.structures[nodes]
            .embedding
            .positions(&u)
            .iter()
            .map(|p| p * 1e3)
            .collect();
        for (slot, pts) in [
            &rest,
            &nodes_of(&r_camera),
            &nodes_of(&r_whole),
            &forward,
            &oracle,
            &oracle_near,
            &plane,
        ]
        .into_iter()
        .enumerate()
        {
            let (a, b) = errors(pts, &true_nodes, &near);
            sums[slot].0 += a;
            sums[slot].1 += b;
        }
    }
    let n = graded.len() as f64;
    let cell = |s: (f64, f64)| format!("{:.2} / {:.2}", s.0 / n, s.1 / n);
    Ok(format!(
        "| {} | {} | {} | {} | {} | {} | {} | {} |",
        case.name,
        cell(sums[0]),
        cell(sums[1]),
        cell(sums[2]),
        cell(sums[3]),
        cell(sums[4]),
        cell(sums[5]),
        cell(sums[6])
    ))
}
