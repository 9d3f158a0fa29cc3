//! [`Workload`]: a sequence of frames with the true positions of the scene's structures — what
//! a configuration is graded on.

use nalgebra::Point3;

use crate::session::Frame;
use crate::synthetic::SyntheticSequence;

/// Frames to register and, for each, the true positions of every structure of the scene.
/// Scene units, cloud (camera) frame — the frame registration results are reported in.
#[derive(Debug, Clone)]
pub struct Workload {
    /// Name (scenario or directory), shown in reports.
    pub name: String,
    /// The frames, in order.
    pub frames: Vec<Frame>,
    /// Per frame: each structure's name and true points (scene units), in scene order.
    pub truth: Vec<Vec<(String, Vec<Point3<f64>>)>>,
    /// Largest true surface displacement over the frames, mm (`None` when unknown).
    pub max_displacement_mm: Option<f64>,
    /// Constitutive law the truth was simulated with (scene-file name; `None` when unknown,
    /// as for the user's own frames).
    pub truth_law: Option<String>,
}

impl Workload {
    /// The frames and truth of a synthetic sequence (metres) in a scene whose unit is
    /// `scale` metres. The frames carry no camera: the scene's is used, as when the frames
    /// are read from files.
    pub fn from_sequence(seq: &SyntheticSequence, scale: f64) -> Self {
        let to_scene = |p: &Point3<f64>| p / scale;
        Self {
            name: seq.kind.name().to_string(),
            frames: seq
                .frames
                .iter()
                .enumerate()
                .map(|(k, f)| Frame {
                    source: crate::synthetic::sequence::frame_file_name(k, seq.frames.len()),
                    points: f.cloud.iter().map(to_scene).collect(),
                    camera: None,
                })
                .collect(),
            truth: seq
                .frames
                .iter()
                .map(|f| {
                    f.truth_structures
                        .iter()
                        .map(|(n, pts)| (n.clone(), pts.iter().map(to_scene).collect()))
                        .collect()
                })
                .collect(),
            max_displacement_mm: Some(
                seq.frames
                    .iter()
                    .map(|f| f.max_displacement)
                    .fold(0.0, f64::max)
                    * 1e3,
            ),
            truth_law: Some(crate::benchmark::config::law_name(seq.spec.truth.law).to_string()),
        }
    }

    /// Checks that there is a truth entry per frame and that every truth entry names the
    /// structures of `structures` (name, point count) in order; the message says what differs.
    pub fn check_against(&self, structures: &[(String, usize)]) -> Result<(), String> {
        if self.frames.is_empty() {
            return Err(format!("workload `{}` has no frames", self.name));
        }
        if self.truth.len() != self.frames.len() {
            return Err(format!(
                "workload `{}`: {} frames but {} truth records",
                self.name,
                self.frames.len(),
                self.truth.len()
            ));
        }
        for (k, t) in self.truth.iter().enumerate() {
            for (name, count) in structures {
                match t.iter().find(|(n, _)| n == name) {
                    None => {
                        return Err(format!(
                            "workload `{}`, truth of frame {k}: no structure `{name}`",
                            self.name
                        ))
                    }
                    Some((_, pts)) if pts.len() != *count => {
                        return Err(format!(
                            "workload `{}`, truth of frame {k}: structure `{name}` has {} \
                             points, the model {count}",
                            self.name,
                            pts.len()
                        ))
                    }
                    Some(_) => {}
                }
            }
        }
        Ok(())
    }
}
