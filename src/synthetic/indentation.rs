//! The TOOL-INDENTATION scenario class: a tool pressing 2–7 cm into a liver surface
//! that is not the phantom, graded against a ground truth from an INDEPENDENT discretisation —
//! quadratic tetrahedra solved by scikit-fem (`fixtures/liver_indentation/make_truth.py`), not
//! our immersed grid — with the linear and the neo-Hookean law.
//!
//! The fixture holds the tet mesh's vertices (`nodes.xyz`, surface vertices first, so that
//! surface vertex `i` of `liver.obj` is node `i`), the ligament vertices held fixed, and per
//! sequence and law a JSON description of every frame (tool centre and direction, depth, the
//! tool's force on the liver and its centre) with the nodes' displacements as gzip-compressed
//! little-endian `i16` in units of `displacement_scale_mm` (frame-major, then node, then x, y,
//! z). See `fixtures/liver_indentation/README.md`.
//!
//! [`indentation_sequence`] turns a truth into what a camera gives: per frame, the deformed
//! surface seen by a camera looking at the contact from outside, restricted to a patch around
//! it ([`IndentationCloudSpec`]: 300–1,000 points, 10–20 % of the surface, 1–3 mm noise),
//! optionally moved by an unknown rigid offset. Lengths in metres.

use std::io::Read;
use std::path::{Path, PathBuf};

use nalgebra::{Point3, Rotation3, Unit, Vector3};
use serde::Deserialize;

use super::point_cloud::{synthesize_cloud, CloudSpec};
use super::sequence::frame_seed;
use crate::geometry::Camera;
use crate::mesh::{read_points, read_surface, TriSurface};
use crate::registration::RigidTransform;

/// Millimetres per metre.
const MM: f64 = 1e-3;

/// Sequences of the bundled fixture.
pub const INDENTATION_SEQUENCES: [&str; 2] = ["press-slide", "two-sites"];

/// Truth laws of the bundled fixture (scene-file names), frictionless tool; the default set of
/// `bench --indentation`.
pub const INDENTATION_LAWS: [&str; 2] = ["linear", "neo-hookean"];

/// The bundled fixture's truths with a sticking (no-slip) tool, the neo-Hookean one at the
/// nominal depths (`bench --indentation --truth-law neo-hookean-sticking`; see the fixture's
/// README.md).
pub const INDENTATION_STICKING_LAWS: [&str; 2] = ["linear-sticking", "neo-hookean-sticking"];

/// The bundled fixture's directory (relative to the repository root).
pub fn bundled_fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/liver_indentation")
}

/// Errors reading an indentation truth; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum IndentationError {
    /// A file could not be read.
    #[error("{path}: {message}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        message: String,
    },
    /// A file's content is not what the format says.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// The cloud spec is out of range.
    #[error("{message}")]
    Spec {
        /// What is wrong.
        message: String,
    },
    /// A cloud could not be synthesized.
    #[error("cloud of frame {frame}: {message}")]
    Cloud {
        /// The frame.
        frame: usize,
        /// Why.
        message: String,
    },
}

/// One frame of the truth, metres and newtons, model frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolFrame {
    /// Centre of the tool's contact on the REST surface.
    pub tool_centre: Point3<f64>,
    /// Unit direction the tool pushes along.
    pub tool_direction: Vector3<f64>,
    /// Depth the tool pushes the contact along `tool_direction`, m.
    pub depth: f64,
    /// Force the tool applies to the liver, N.
    pub force: Vector3<f64>,
    /// Where that force acts (deformed configuration).
    pub force_centre: Point3<f64>,
}

/// A tool-indentation ground truth: the tet mesh's vertices and their displacement per frame.
#[derive(Debug, Clone)]
pub struct IndentationTruth {
    /// Sequence name (e.g. `press-slide`).
    pub sequence: String,
    /// Constitutive law of the truth (scene-file name: `linear`, `neo-hookean`, or either with
    /// `-sticking` for the no-slip tool).
    pub law: String,
    /// Rest positions of the tet mesh's vertices, m (surface vertices first).
    pub nodes: Vec<Point3<f64>>,
    /// The surface (`liver.obj`), m: its vertex `i` is node `i`.
    pub surface: TriSurface,
    /// Radius of the tool's flat end, m.
    pub tool_radius: f64,
    /// Per frame: the tool.
    pub frames: Vec<ToolFrame>,
    /// Per frame: every node's displacement, m.
    pub displacements: Vec<Vec<Vector3<f64>>>,
}

#[derive(Deserialize)]
struct TruthFile {
    sequence: String,
    law: String,
    nodes: usize,
    surface_vertices: usize,
    tool_radius: f64,
    displacements: String,
    displacement_scale_mm: f64,
    frames: Vec<TruthFrameFile>,
}

#[derive(Deserialize)]
struct TruthFrameFile {
    tool_centre: [f64; 3],
    tool_direction: [f64; 3],
    depth: f64,
    force: [f64; 3],
    force_centre: [f64; 3],
}

impl IndentationTruth {
    /// Reads sequence `sequence` with law `law` from the fixture directory `dir` (files in
    /// millimetres; the result in metres).
    pub fn load(dir: &Path, sequence: &str, law: &str) -> Result<Self, IndentationError> {
        let io = |p: &Path, e: &dyn std::fmt::Display| IndentationError::Io {
            path: p.display().to_string(),
            message: e.to_string(),
        };
        let format = |p: &Path, m: String| IndentationError::Format {
            path: p.display().to_string(),
            message: m,
        };
        let json_path = dir.join("truth").join(format!("{sequence}_{law}.json"));
        let text = std::fs::read_to_string(&json_path).map_err(|e| io(&json_path, &e))?;
        let file: TruthFile =
            serde_json::from_str(&text).map_err(|e| format(&json_path, e.to_string()))?;
        let nodes_path = dir.join("nodes.xyz");
        let nodes: Vec<Point3<f64>> = read_points(&nodes_path)
            .map_err(|e| io(&nodes_path, &e))?
            .into_iter()
            .map(|p| p * MM)
            .collect();
        if nodes.len() != file.nodes {
            return Err(format(
                &json_path,
                format!("says {} nodes, nodes.xyz has {}", file.nodes, nodes.len()),
            ));
        }
        let surface_path = dir.join("liver.obj");
        let mut surface = read_surface(&surface_path).map_err(|e| io(&surface_path, &e))?;
        surface.scale(MM);
        if surface.vertices.len() != file.surface_vertices
            || surface
                .vertices
                .iter()
                .zip(&nodes)
                .any(|(a, b)| (a - b).norm() > 1e-6)
        {
            return Err(format(
                &surface_path,
                format!(
                    "its {} vertices must be the first {} nodes of nodes.xyz, in order",
                    surface.vertices.len(),
                    file.surface_vertices
                ),
            ));
        }
        let bin_path = dir.join("truth").join(&file.displacements);
        let raw = std::fs::read(&bin_path).map_err(|e| io(&bin_path, &e))?;
        let mut bytes = Vec::new();
        flate2::read::GzDecoder::new(&raw[..])
            .read_to_end(&mut bytes)
            .map_err(|e| format(&bin_path, format!("not a gzip stream: {e}")))?;
        let per_frame = file.nodes * 3 * 2;
        if bytes.len() != per_frame * file.frames.len() {
            return Err(format(
                &bin_path,
                format!(
                    "{} bytes, expected {} frames × {} nodes × 3 × 2",
                    bytes.len(),
                    file.frames.len(),
                    file.nodes
                ),
            ));
        }
        let unit = file.displacement_scale_mm * MM;
        let displacements = bytes
            .chunks_exact(per_frame)
            .map(|frame| {
                frame
                    .chunks_exact(6)
                    .map(|c| {
                        let v = |i: usize| f64::from(i16::from_le_bytes([c[i], c[i + 1]])) * unit;
                        Vector3::new(v(0), v(2), v(4))
                    })
                    .collect()
            })
            .collect();
        let p = |v: [f64; 3]| Point3::new(v[0], v[1], v[2]) * MM;
        let frames = file
            .frames
            .iter()
            .map(|f| ToolFrame {
                tool_centre: p(f.tool_centre),
                tool_direction: Vector3::from(f.tool_direction).normalize(),
                depth: f.depth * MM,
                force: Vector3::from(f.force),
                force_centre: p(f.force_centre),
            })
            .collect();
        Ok(Self {
            sequence: file.sequence,
            law: file.law,
            nodes,
            surface,
            tool_radius: file.tool_radius * MM,
            frames,
            displacements,
        })
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether there is no frame.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Keeps the first `n` frames (all of them when there are fewer).
    pub fn truncate(&mut self, n: usize) {
        self.frames.truncate(n);
        self.displacements.truncate(n);
    }

    /// The truth restricted to the frames `indices` (in that order): a frame subset or stride
    /// of the sequence. An index past the last frame is an error.
    pub fn select_frames(&self, indices: &[usize]) -> Result<Self, IndentationError> {
        if let Some(&k) = indices.iter().find(|&&k| k >= self.len()) {
            return Err(IndentationError::Format {
                path: format!("{}_{}", self.sequence, self.law),
                message: format!("no frame {k}: the sequence has {} frames", self.len()),
            });
        }
        Ok(Self {
            frames: indices.iter().map(|&k| self.frames[k].clone()).collect(),
            displacements: indices
                .iter()
                .map(|&k| self.displacements[k].clone())
                .collect(),
            ..self.clone()
        })
    }

    /// Frame `k`'s deformed node positions, m, model frame.
    pub fn deformed_nodes(&self, k: usize) -> Vec<Point3<f64>> {
        self.nodes
            .iter()
            .zip(&self.displacements[k])
            .map(|(p, u)| p + u)
            .collect()
    }

    /// Frame `k`'s deformed surface, m, model frame.
    pub fn deformed_surface(&self, k: usize) -> TriSurface {
        self.surface_of(&self.deformed_nodes(k))
    }

    /// The surface whose vertices are the first nodes of `nodes` (positions of every node).
    fn surface_of(&self, nodes: &[Point3<f64>]) -> TriSurface {
        let n = self.surface.vertices.len();
        TriSurface::new(nodes[..n].to_vec(), self.surface.triangles.clone())
    }

    /// The nodes of the indented region at frame `k`: within [`INDENTED_REGION_RADIUS`] (rest
    /// distance) of the tool's centre.
    pub fn indented_region(&self, k: usize) -> Vec<bool> {
        let c = self.frames[k].tool_centre;
        self.nodes
            .iter()
            .map(|p| (p - c).norm() <= INDENTED_REGION_RADIUS)
            .collect()
    }
}

/// Radius (m, rest configuration) around the tool's centre within which a node counts as part
/// of the indented region (4 cm: the tool's 12 mm radius and the dent's walls).
pub const INDENTED_REGION_RADIUS: f64 = 0.04;

/// The clouds of an indentation sequence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IndentationCloudSpec {
    /// Inliers per cloud (about; the patch is sampled at the density this gives).
    pub points: usize,
    /// The patch's share of the whole surface area, in `(0, 1]`.
    pub visible_fraction: f64,
    /// Gaussian noise per axis, m.
    pub noise_sigma: f64,
    /// Share of outliers, in `[0, 1)`.
    pub outlier_fraction: f64,
    /// Distance of the camera from the contact, m.
    pub camera_distance: f64,
    /// Angle between the camera's axis and the tool's axis, degrees.
    pub camera_tilt_deg: f64,
    /// The constant model → camera transform (`None`: clouds in the model's frame, as with
    /// `rigid = "none"`).
    pub rigid_offset: Option<RigidTransform>,
    /// Base seed; frame `k` uses [`frame_seed`]`(seed, k)`.
    pub seed: u64,
}

impl Default for IndentationCloudSpec {
    /// 500 points on 15 % of the surface, 1.5 mm noise per axis (≈ 2.4 mm off the surface in
    /// 3-D on average), no outliers, a camera 25 cm from the contact tilted by 25°, clouds in
    /// the model's frame.
    fn default() -> Self {
        Self {
            points: 500,
            visible_fraction: 0.15,
            noise_sigma: 1.5e-3,
            outlier_fraction: 0.0,
            camera_distance: 0.25,
            camera_tilt_deg: 25.0,
            rigid_offset: None,
            seed: 1808,
        }
    }
}

impl IndentationCloudSpec {
    /// Checks every parameter's range: at least one point, visible fraction in `(0, 1]`,
    /// finite non-negative noise (m), outlier fraction in `[0, 1)`, finite positive camera
    /// distance (m) and finite tilt (degrees). The message names the field.
    pub fn validate(&self) -> Result<(), IndentationError> {
        let bad = |m: String| {
            Err(IndentationError::Spec {
                message: format!("cloud spec: {m}"),
            })
        };
        if self.points == 0 {
            return bad("points must be >= 1".into());
        }
        if !(self.visible_fraction > 0.0 && self.visible_fraction <= 1.0) {
            return bad(format!(
                "visible_fraction {} is outside (0, 1]",
                self.visible_fraction
            ));
        }
        if !(self.noise_sigma.is_finite() && self.noise_sigma >= 0.0) {
            return bad(format!(
                "noise_sigma {} m must be finite and >= 0",
                self.noise_sigma
            ));
        }
        if !(0.0..1.0).contains(&self.outlier_fraction) {
            return bad(format!(
                "outlier_fraction {} is outside [0, 1)",
                self.outlier_fraction
            ));
        }
        if !(self.camera_distance.is_finite() && self.camera_distance > 0.0) {
            return bad(format!(
                "camera_distance {} m must be finite and > 0",
                self.camera_distance
            ));
        }
        if !self.camera_tilt_deg.is_finite() {
            return bad(format!(
                "camera_tilt_deg {} must be finite",
                self.camera_tilt_deg
            ));
        }
        Ok(())
    }
}

/// One frame as a camera sees it, with its truth: metres, CAMERA (cloud) frame.
#[derive(Debug, Clone)]
pub struct IndentationFrame {
    /// The cloud.
    pub cloud: Vec<Point3<f64>>,
    /// How many points of `cloud` are outliers (the rest are noisy surface samples).
    pub outliers: usize,
    /// The camera that saw it.
    pub camera: Camera,
    /// True node positions.
    pub truth_nodes: Vec<Point3<f64>>,
}

/// A camera looking at the bottom of the dent from outside: from `distance` along the tool's
/// axis (outwards), turned by `tilt_deg` about an axis across it.
fn contact_camera(tool: &ToolFrame, distance: f64, tilt_deg: f64) -> Result<Camera, String> {
    let look_at = tool.tool_centre + tool.tool_direction * tool.depth;
    let out = -tool.tool_direction;
    let across = out.cross(&Vector3::z());
    let across = if across.norm() < 1e-6 {
        out.cross(&Vector3::x())
    } else {
        across
    };
    let r = Rotation3::from_axis_angle(&Unit::new_normalize(across), tilt_deg.to_radians());
    let position = look_at + r * out * distance;
    Camera::looking_at(position, look_at).map_err(|e| e.to_string())
}

/// The clouds a camera gives of `truth` under `spec`, with the true node positions, per frame.
pub fn indentation_sequence(
    truth: &IndentationTruth,
    spec: &IndentationCloudSpec,
) -> Result<Vec<IndentationFrame>, IndentationError> {
    spec.validate()?;
    let area = truth.surface.area();
    let density_per_cm2 = spec.points as f64 / (spec.visible_fraction * area * 1e4);
    let offset = spec.rigid_offset.unwrap_or_else(RigidTransform::identity);
    (0..truth.len())
        .map(|k| {
            let err = |m: String| IndentationError::Cloud {
                frame: k,
                message: m,
            };
            let camera =
                contact_camera(&truth.frames[k], spec.camera_distance, spec.camera_tilt_deg)
                    .map_err(err)?;
            let cloud_spec = CloudSpec {
                density_per_cm2,
                noise_sigma: spec.noise_sigma,
                outlier_fraction: spec.outlier_fraction,
                visible_fraction: Some(spec.visible_fraction),
                rigid_offset: None,
                seed: frame_seed(spec.seed, k),
            };
            let nodes = truth.deformed_nodes(k);
            let cloud = synthesize_cloud(&truth.surface_of(&nodes), &camera, &cloud_spec)
                .map_err(|e| err(e.to_string()))?;
            let moved_camera = Camera::new(
                offset.apply(&camera.position),
                offset.apply(&camera.look_at),
                offset.apply_vector(&camera.up),
                camera.fov_deg,
            )
            .map_err(|e| err(e.to_string()))?;
            Ok(IndentationFrame {
                outliers: cloud.outlier_count(),
                cloud: offset.apply_all(&cloud.points),
                camera: moved_camera,
                truth_nodes: offset.apply_all(&nodes),
            })
        })
        .collect()
}

/// Per frame of `truth`, the whole deformed surface as a noise-free cloud: every vertex of the
/// truth's surface and every triangle's centroid, metres, model frame (the camera is the one
/// [`IndentationCloudSpec::default`] places, for the record only). Not what a camera gives: an
/// oracle's cloud, with nothing hidden and nothing noise, so that what the registration misses
/// on it is the model's error (grid, law, hold) and not the data's
/// (docs/error-estimate.md#the-error-budget).
pub fn whole_surface_sequence(
    truth: &IndentationTruth,
) -> Result<Vec<IndentationFrame>, IndentationError> {
    let spec = IndentationCloudSpec::default();
    (0..truth.len())
        .map(|k| {
            let camera =
                contact_camera(&truth.frames[k], spec.camera_distance, spec.camera_tilt_deg)
                    .map_err(|message| IndentationError::Cloud { frame: k, message })?;
            let nodes = truth.deformed_nodes(k);
            let surface = truth.surface_of(&nodes);
            let centroids = (0..surface.triangles.len()).map(|t| surface.centroid(t));
            let cloud = surface.vertices.iter().copied().chain(centroids).collect();
            Ok(IndentationFrame {
                cloud,
                outliers: 0,
                camera,
                truth_nodes: nodes,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The whole-surface cloud is the deformed truth itself: its first points are the moved
    /// surface vertices (node `i` + its displacement), then one centroid per triangle, each
    /// on its triangle's plane.
    #[test]
    fn the_whole_surface_cloud_is_the_deformed_truth_surface() {
        let truth =
            IndentationTruth::load(&bundled_fixture_dir(), "two-sites", "linear").expect("truth");
        let frames = whole_surface_sequence(&truth).expect("frames");
        assert_eq!(frames.len(), truth.len());
        let k = truth.len() - 1;
        let f = &frames[k];
        let nv = truth.surface.vertices.len();
        assert_eq!(f.cloud.len(), nv + truth.surface.triangles.len());
        assert_eq!(f.outliers, 0);
        let moved = |i: usize| truth.nodes[i] + truth.displacements[k][i];
        for i in [0, nv / 2, nv - 1] {
            assert!((f.cloud[i] - moved(i)).norm() < 1e-12);
        }
        // The last frame moves the surface by centimetres: the cloud is not the rest shape.
        let largest = (0..nv)
            .map(|i| (f.cloud[i] - truth.nodes[i]).norm())
            .fold(0.0, f64::max);
        assert!(largest > 0.03, "largest surface motion {largest} m");
        for (t, c) in truth
            .surface
            .triangles
            .iter()
            .zip(&f.cloud[nv..])
            .step_by(97)
        {
            let (a, b, d) = (moved(t[0]), moved(t[1]), moved(t[2]));
            let normal = (b - a).cross(&(d - a)).normalize();
            assert!((c - a).dot(&normal).abs() < 1e-12);
            assert!((c.coords * 3.0 - a.coords - b.coords - d.coords).norm() < 1e-12);
        }
        assert_eq!(f.truth_nodes.len(), truth.nodes.len());
    }
}
