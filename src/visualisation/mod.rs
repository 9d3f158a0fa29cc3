//! 3D visualisation with rerun (feature `rerun`): the pre-operative model, each cloud, the
//! deformed surface coloured by displacement, the structures (coloured by their error where a
//! truth is known), correspondences and penalty targets, and per-frame metrics on a timeline.
//!
//! Entity paths (under an optional prefix, e.g. the demo's scenario name), in scene units:
//! - `model/surface` (static): the rest surface; `model/structures/<name>` (static);
//! - `frame/cloud`: the frame's points;
//! - `frame/surface`: the deformed surface, vertex colours by displacement magnitude from the
//!   rigidly placed rest shape (blue 0 → red at the largest displacement of the frame);
//! - `frame/structures/<name>`: deformed structures; with a truth, coloured by error (green
//!   0 → red ≥ 10 mm), with `frame/structures/<name>/truth` and `…/error` (segments);
//! - `frame/correspondences`: each deformed-surface vertex's nearest cloud point, pruned at
//!   mean + 2σ like the pipeline's pairs; `frame/targets`: the imposed targets (α blend of
//!   the two pairings, thesis eq. 5.4) — both recomputed from the frame's final state, since
//!   the session does not expose its internal pairs;
//! - `metrics/*`: wall_ms, surface_rms, icp_iterations, newton_iterations, and
//!   `metrics/tre_mean_mm` with a truth. Timeline: `frame` (sequence).

use std::path::Path;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Point3;
use rerun::{Color, LineStrips3D, Mesh3D, Points3D, RecordingStream, Scalars};

use crate::evaluation::TruthRecord;
use crate::session::FrameObserver;
use crate::session::{Frame, FrameResult, Session};

/// Opens a rerun stream `app` writing to `save` (an `.rrd` file) or connected to a viewer at
/// `connect` (gRPC URL); `None` when neither is given.
pub fn open_stream(
    app: &'static str,
    save: Option<&Path>,
    connect: Option<&str>,
) -> Result<Option<RecordingStream>, String> {
    let builder = rerun::RecordingStreamBuilder::new(app);
    match (save, connect) {
        (Some(_), Some(_)) => Err("give --rerun or --rerun-connect, not both".into()),
        (Some(p), None) => {
            if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir).map_err(|e| {
                    format!(
                        "{}: cannot create the rerun file's directory: {e}",
                        dir.display()
                    )
                })?;
            }
            builder
                .save(p)
                .map(Some)
                .map_err(|e| format!("{}: cannot write the rerun file: {e}", p.display()))
        }
        (None, Some(url)) => builder
            .connect_grpc_opts(url.to_string())
            .map(Some)
            .map_err(|e| format!("--rerun-connect {url}: {e}")),
        (None, None) => Ok(None),
    }
}

/// Logs a session's model once and every frame's registration (see the module doc).
pub struct Visualiser {
    rec: RecordingStream,
    prefix: String,
    /// Rest surface vertices, scene units.
    rest: Vec<Point3<f64>>,
    triangles: Vec<[u32; 3]>,
    /// Metres per scene unit.
    scale: f64,
    truth: Option<Vec<TruthRecord>>,
    alpha: f64,
}

fn f32s(p: &Point3<f64>) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

/// Blue → red ramp for `t` in [0, 1].
fn ramp(t: f64) -> Color {
    let t = t.clamp(0.0, 1.0);
    Color::from_rgb(
        (255.0 * t) as u8,
        (80.0 * (1.0 - t)) as u8,
        (255.0 * (1.0 - t)) as u8,
    )
}

impl Visualiser {
    /// A visualiser logging to `rec` under `prefix` (empty: the root); logs the rest model of
    /// `session` statically. `truth` (frame-indexed) enables error colours and TRE.
    pub fn new(
        rec: RecordingStream,
        prefix: &str,
        session: &Session,
        truth: Option<Vec<TruthRecord>>,
    ) -> Self {
        let model = &session.model;
        let scale = model.length_scale;
        let rest: Vec<Point3<f64>> = model.surface.vertices.iter().map(|p| p / scale).collect();
        let triangles: Vec<[u32; 3]> = model
            .surface
            .triangles
            .iter()
            .map(|t| [t[0] as u32, t[1] as u32, t[2] as u32])
            .collect();
        let v = Self {
            rec,
            prefix: prefix.trim_matches('/').to_string(),
            rest,
            triangles,
            scale,
            truth,
            alpha: session.settings.warm.alpha,
        };
        let _ = v.rec.log_static(
            v.path("model/surface"),
            &Mesh3D::new(v.rest.iter().map(f32s))
                .with_triangle_indices(v.triangles.iter().copied())
                .with_albedo_factor(rerun::datatypes::Rgba32::from_unmultiplied_rgba(
                    200, 200, 200, 90,
                )),
        );
        for s in &model.structures {
            let pts: Vec<[f32; 3]> = s
                .embedding
                .positions(&vec![0.0; model.problem.dofs()])
                .iter()
                .map(|p| f32s(&(p / scale)))
                .collect();
            let _ = v.rec.log_static(
                v.path(&format!("model/structures/{}", s.name)),
                &Points3D::new(pts).with_colors([Color::from_rgb(120, 120, 120)]),
            );
        }
        v
    }

    fn path(&self, p: &str) -> String {
        if self.prefix.is_empty() {
            p.to_string()
        } else {
            format!("{}/{p}", self.prefix)
        }
    }

    fn scalar(&self, name: &str, v: f64) {
        let _ = self
            .rec
            .log(self.path(&format!("metrics/{name}")), &Scalars::new([v]));
    }

    fn log_frame(&mut self, index: usize, frame: Option<&Frame>, r: &FrameResult) {
        self.rec.set_time_sequence("frame", index as i64);
        let rec = &self.rec;
        if let Some(f) = frame {
            let _ = rec.log(
                self.path("frame/cloud"),
                &Points3D::new(f.points.iter().map(f32s))
                    .with_colors([Color::from_rgb(250, 200, 40)])
                    .with_radii([0.004 / self.scale as f32]),
            );
        }
        // Displacement = deformed − rigidly placed rest shape (scene units).
        if r.surface.len() == self.rest.len() {
            let pose = r.model_to_cloud;
            let placed = |p: &Point3<f64>| pose.rotation * p + pose.translation / self.scale;
            let disp: Vec<f64> = r
                .surface
                .iter()
                .zip(&self.rest)
                .map(|(d, p)| (d - placed(p)).norm())
                .collect();
            let max = disp.iter().copied().fold(0.0, f64::max).max(1e-12);
            let _ = rec.log(
                self.path("frame/surface"),
                &Mesh3D::new(r.surface.iter().map(f32s))
                    .with_triangle_indices(self.triangles.iter().copied())
                    .with_vertex_colors(disp.iter().map(|d| ramp(d / max))),
            );
            self.scalar("max_displacement", max);
        }
        // Structures, with their error where the truth is known.
        let truth = self
            .truth
            .as_ref()
            .and_then(|t| t.iter().find(|t| t.frame == index));
        let mut errors = Vec::new();
        for (name, pts) in &r.structures {
            let base = self.path(&format!("frame/structures/{name}"));
            let truth_pts = truth.and_then(|t| t.structures.get(name));
            match truth_pts.filter(|t| t.len() == pts.len()) {
                Some(tp) => {
                    let e_mm: Vec<f64> = pts
                        .iter()
                        .zip(tp)
                        .map(|(p, q)| (p - Point3::from(*q)).norm() * self.scale * 1e3)
                        .collect();
                    errors.extend_from_slice(&e_mm);
                    let _ = rec.log(
                        base.clone(),
                        &Points3D::new(pts.iter().map(f32s))
                            .with_colors(e_mm.iter().map(|e| {
                                let t = (e / 10.0).clamp(0.0, 1.0);
                                Color::from_rgb((255.0 * t) as u8, (255.0 * (1.0 - t)) as u8, 60)
                            }))
                            .with_labels(e_mm.iter().map(|e| format!("{e:.1} mm"))),
                    );
                    let _ = rec.log(
                        format!("{base}/truth"),
                        &Points3D::new(tp.iter().map(|q| [q[0] as f32, q[1] as f32, q[2] as f32]))
                            .with_colors([Color::from_rgb(255, 255, 255)]),
                    );
                    let _ =
                        rec.log(
                            format!("{base}/error"),
                            &LineStrips3D::new(pts.iter().zip(tp).map(|(p, q)| {
                                vec![f32s(p), [q[0] as f32, q[1] as f32, q[2] as f32]]
                            }))
                            .with_colors([Color::from_rgb(255, 60, 60)]),
                        );
                }
                None => {
                    let _ = rec.log(
                        base,
                        &Points3D::new(pts.iter().map(f32s))
                            .with_colors([Color::from_rgb(60, 220, 90)]),
                    );
                }
            }
        }
        if !errors.is_empty() {
            self.scalar(
                "tre_mean_mm",
                errors.iter().sum::<f64>() / errors.len() as f64,
            );
        }
        if let Some(f) = frame {
            self.log_pairs(&f.points, &r.surface);
        }
        self.scalar("wall_ms", r.wall_ms);
        self.scalar("surface_rms", r.surface_rms);
        self.scalar("icp_iterations", r.icp_iterations as f64);
        self.scalar("newton_iterations", r.newton_iterations as f64);
    }

    /// Correspondences and imposed targets recomputed at the final state (module doc).
    fn log_pairs(&self, cloud: &[Point3<f64>], surface: &[Point3<f64>]) {
        let cloud: Vec<Point3<f64>> = cloud
            .iter()
            .filter(|p| crate::mesh::is_finite_point(p))
            .copied()
            .collect();
        if cloud.len() < 3 || surface.len() < 3 {
            return;
        }
        let coords = |pts: &[Point3<f64>]| -> Vec<[f64; 3]> {
            pts.iter().map(|p| [p.x, p.y, p.z]).collect()
        };
        let (Ok(cloud_tree), Ok(surf_tree)) = (
            ImmutableKdTree::<f64, 3>::new_from_slice(&coords(&cloud)),
            ImmutableKdTree::<f64, 3>::new_from_slice(&coords(surface)),
        ) else {
            return;
        };
        let nearest = |tree: &ImmutableKdTree<f64, 3>, p: &Point3<f64>| {
            let nn = tree
                .query(&[p.x, p.y, p.z])
                .nearest_one::<SquaredEuclidean<f64>>()
                .execute();
            (nn.item as usize, nn.distance.sqrt())
        };
        let prune = |d: &[f64]| {
            let n = d.len().max(1) as f64;
            let mean = d.iter().sum::<f64>() / n;
            let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
            mean + 2.0 * sd
        };
        let fwd: Vec<(usize, f64)> = surface.iter().map(|p| nearest(&cloud_tree, p)).collect();
        let bwd: Vec<(usize, f64)> = cloud.iter().map(|p| nearest(&surf_tree, p)).collect();
        let fwd_cut = prune(&fwd.iter().map(|x| x.1).collect::<Vec<_>>());
        let bwd_cut = prune(&bwd.iter().map(|x| x.1).collect::<Vec<_>>());
        let mut back_sum = vec![(nalgebra::Vector3::zeros(), 0usize); surface.len()];
        for (c, &(i, d)) in bwd.iter().enumerate() {
            if d <= bwd_cut {
                back_sum[i].0 += cloud[c] - surface[i];
                back_sum[i].1 += 1;
            }
        }
        let mut lines = Vec::new();
        let mut targets = Vec::new();
        for (i, &(c, d)) in fwd.iter().enumerate() {
            if d > fwd_cut {
                continue;
            }
            let p = surface[i];
            lines.push(vec![f32s(&p), f32s(&cloud[c])]);
            let fwd_disp = cloud[c] - p;
            let (sum, n) = back_sum[i];
            let back = if n > 0 { sum / n as f64 } else { fwd_disp };
            targets.push(f32s(
                &(p + self.alpha * fwd_disp + (1.0 - self.alpha) * back),
            ));
        }
        let _ = self.rec.log(
            self.path("frame/correspondences"),
            &LineStrips3D::new(lines).with_colors([Color::from_rgb(90, 160, 255)]),
        );
        let _ = self.rec.log(
            self.path("frame/targets"),
            &Points3D::new(targets).with_colors([Color::from_rgb(255, 90, 200)]),
        );
    }
}

impl FrameObserver for Visualiser {
    fn frame_done(
        &mut self,
        index: usize,
        frame: Option<&Frame>,
        _received_ns: u64,
        result: &FrameResult,
    ) -> Result<(), String> {
        self.log_frame(index, frame, result);
        Ok(())
    }
}

impl Drop for Visualiser {
    fn drop(&mut self) {
        let _ = self.rec.flush_blocking();
    }
}
