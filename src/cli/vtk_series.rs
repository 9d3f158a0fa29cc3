//! `--vtk DIR` of `register`, `demo` and `replay`: every registered frame's deformed liver
//! surface and structures as VTK PolyData files, with one ParaView `.pvd` time series per
//! object, for ParaView or 3D Slicer.
//!
//! Layout of `DIR` (scene units, the cloud frame, as `results.jsonl`):
//! - `liver.pvd` and `liver_NNNNNN.vtp`: the deformed surface of frame `NNNNNN` (0-based, the
//!   frame index of `results.jsonl`), its triangles those of the scene's model;
//! - `<structure>.pvd` and `<structure>_NNNNNN.vtp` for every structure of the scene: a mesh
//!   structure with its triangles, a point structure as vertices. Names are kept to
//!   `A–Z a–z 0–9 - _` (anything else becomes `_`); a name met twice gets `-2`, `-3`, ….
//!
//! The time step of a `.pvd` entry is the frame index. A failed frame is written too, with
//! the last good state its result carries, and a point array `failed` (1 on every point)
//! so that it can be told apart in ParaView.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use crate::mesh::vtk::{PointArray, PvdSeries, VtkPolyData};
use crate::mesh::write_vtk;
use crate::session::{Frame, FrameObserver, FrameResult, Session};

/// One object of the series: its file stem, triangles (empty for points) and collection.
#[derive(Debug)]
struct SeriesObject {
    stem: String,
    triangles: Vec<[usize; 3]>,
    series: PvdSeries,
}

/// Writes each frame's deformed surface and structures to a directory as VTK files and
/// keeps a `.pvd` time series per object (see the module documentation for the layout).
#[derive(Debug)]
pub struct VtkSeriesWriter {
    dir: PathBuf,
    liver: SeriesObject,
    structures: Vec<SeriesObject>,
}

impl VtkSeriesWriter {
    /// A writer into `dir` (created) for the objects of `session`'s scene.
    pub fn create(dir: &Path, session: &Session) -> Result<Self, String> {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("--vtk {}: cannot create the directory: {e}", dir.display()))?;
        let mut taken = HashSet::new();
        let mut object = |name: &str, triangles: Vec<[usize; 3]>| {
            let stem = unique_stem(name, &mut taken);
            SeriesObject {
                series: PvdSeries::new(dir.join(format!("{stem}.pvd"))),
                stem,
                triangles,
            }
        };
        let liver = object("liver", session.model.surface.triangles.clone());
        let structures = session
            .model
            .structures
            .iter()
            .map(|s| object(&s.name, s.triangles.clone().unwrap_or_default()))
            .collect();
        Ok(Self {
            dir: dir.to_path_buf(),
            liver,
            structures,
        })
    }

    /// The directory written to.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes frame `index` of `result` and adds it to every object's series.
    pub fn write_frame(&mut self, index: usize, result: &FrameResult) -> Result<(), String> {
        let failed = result.error.is_some();
        write_object(&self.dir, &mut self.liver, index, &result.surface, failed)?;
        for (object, (_, points)) in self.structures.iter_mut().zip(&result.structures) {
            write_object(&self.dir, object, index, points, failed)?;
        }
        Ok(())
    }
}

impl FrameObserver for VtkSeriesWriter {
    fn frame_done(
        &mut self,
        index: usize,
        _frame: Option<&Frame>,
        _received_ns: u64,
        result: &FrameResult,
    ) -> Result<(), String> {
        self.write_frame(index, result)
    }
}

/// Writes `points` of `object` for frame `index` and adds the file to its series.
fn write_object(
    dir: &Path,
    object: &mut SeriesObject,
    index: usize,
    points: &[nalgebra::Point3<f64>],
    failed: bool,
) -> Result<(), String> {
    let file = format!("{}_{index:06}.vtp", object.stem);
    let arrays = if failed {
        vec![PointArray {
            name: "failed".into(),
            components: 1,
            values: vec![1.0; points.len()],
        }]
    } else {
        Vec::new()
    };
    // A result without positions (no frame ever succeeded) still gets its triangles only
    // when the counts agree.
    let triangles: &[[usize; 3]] = if points.is_empty() {
        &[]
    } else {
        &object.triangles
    };
    write_vtk(
        &dir.join(&file),
        &VtkPolyData {
            points,
            triangles,
            arrays: &arrays,
        },
    )
    .map_err(|e| format!("--vtk: {e}"))?;
    object
        .series
        .push(index as f64, file)
        .map_err(|e| format!("--vtk: {e}"))
}

/// `name` reduced to `A–Z a–z 0–9 - _` (others become `_`, empty becomes `structure`),
/// suffixed `-2`, `-3`, … when already in `taken`.
pub(crate) fn unique_stem(name: &str, taken: &mut HashSet<String>) -> String {
    let mut base: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if base.is_empty() {
        base = "structure".into();
    }
    let mut stem = base.clone();
    let mut k = 1;
    while !taken.insert(stem.to_ascii_lowercase()) {
        k += 1;
        stem = format!("{base}-{k}");
    }
    stem
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stems_are_safe_and_unique() {
        let mut taken = HashSet::new();
        assert_eq!(unique_stem("liver", &mut taken), "liver");
        assert_eq!(unique_stem("Liver", &mut taken), "Liver-2");
        assert_eq!(unique_stem("../portal vein", &mut taken), "___portal_vein");
        assert_eq!(unique_stem("", &mut taken), "structure");
        assert_eq!(unique_stem("tumour_1", &mut taken), "tumour_1");
        assert_eq!(unique_stem("tumour 1", &mut taken), "tumour_1-2");
    }
}
