//! Writing a surface or a point set as a VTK PolyData file ([`write_vtk`]).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use nalgebra::Point3;
use vtkio::model::{
    Attribute, Attributes, ByteOrder, DataSet, PolyDataPiece, Version, VertexNumbers,
};
use vtkio::Vtk;

use super::super::error::MeshError;
use super::super::extension;

/// Values attached to every point of a [`VtkPolyData`] (a VTK point-data array).
#[derive(Debug, Clone, PartialEq)]
pub struct PointArray {
    /// Array name as ParaView and 3D Slicer show it.
    pub name: String,
    /// Components per point: 1 (a scalar) or 3 (a vector).
    pub components: usize,
    /// `components` values per point, point after point.
    pub values: Vec<f64>,
}

/// A polygonal data set to write: points (file units) and triangles, or points alone.
#[derive(Debug, Clone, Copy)]
pub struct VtkPolyData<'a> {
    /// Point positions, file units.
    pub points: &'a [Point3<f64>],
    /// Triangles indexing `points`. When empty, every point is written as a vertex cell, so
    /// that ParaView draws a point set.
    pub triangles: &'a [[usize; 3]],
    /// Point data arrays.
    pub arrays: &'a [PointArray],
}

/// Writes `data` to `path` as VTK PolyData, choosing the format from the extension:
/// `.vtp` (XML, binary data base64-encoded inline, little-endian) or `.vtk` (legacy 4.2,
/// binary, big-endian as the format requires). Coordinates are written as 64-bit floats, so a
/// reader gets back exactly the positions given. The file is written beside its final name
/// and renamed into place, so a reader polling the directory never sees half a file.
///
/// An index out of range, an array of the wrong length or an unknown extension is an error
/// naming the file.
pub fn write_vtk(path: &Path, data: &VtkPolyData<'_>) -> Result<(), MeshError> {
    let n = data.points.len();
    if let Some(t) = data
        .triangles
        .iter()
        .position(|t| t.iter().any(|&i| i >= n))
    {
        return Err(MeshError::malformed(
            path,
            format!("triangle {t} refers to a point past the {n} points"),
        ));
    }
    for a in data.arrays {
        if a.components == 0 || a.values.len() != a.components * n {
            return Err(MeshError::malformed(
                path,
                format!(
                    "point array {:?} has {} values for {n} points × {} components",
                    a.name,
                    a.values.len(),
                    a.components
                ),
            ));
        }
    }
    let xml = match extension(path).as_deref() {
        Some("vtp") => true,
        Some("vtk") => false,
        other => {
            return Err(MeshError::unsupported(
                path,
                format!(
                    "cannot write VTK to extension {:?} (use .vtp or .vtk)",
                    other.unwrap_or_default()
                ),
            ))
        }
    };
    let vtk = model(data, xml);
    let partial = partial_path(path);
    let written = File::create(&partial)
        .map_err(|e| MeshError::io(&partial, e))
        .and_then(|file| {
            let mut out = BufWriter::new(file);
            let result = if xml {
                vtk.write_xml(&mut out)
            } else {
                vtk.write_legacy(&mut out)
            };
            result.map_err(|e| MeshError::malformed(path, format!("VTK writer: {e}")))?;
            out.flush().map_err(|e| MeshError::io(&partial, e))
        })
        .and_then(|()| std::fs::rename(&partial, path).map_err(|e| MeshError::io(path, e)));
    if written.is_err() {
        let _ = std::fs::remove_file(&partial);
    }
    written
}

/// The file a write goes to before it is renamed to `path`.
fn partial_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    path.with_file_name(name)
}

/// The `vtkio` model of `data`.
fn model(data: &VtkPolyData<'_>, xml: bool) -> Vtk {
    let coords: Vec<f64> = data.points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    let cells = |lists: &mut dyn Iterator<Item = Vec<u32>>| {
        let mut num_cells = 0u32;
        let mut vertices = Vec::new();
        for cell in lists {
            num_cells += 1;
            vertices.push(cell.len() as u32);
            vertices.extend(cell);
        }
        VertexNumbers::Legacy {
            num_cells,
            vertices,
        }
    };
    let (verts, polys) = if data.triangles.is_empty() {
        let mut it = (0..data.points.len()).map(|i| vec![i as u32]);
        (Some(cells(&mut it)), None)
    } else {
        let mut it = data
            .triangles
            .iter()
            .map(|t| t.iter().map(|&i| i as u32).collect());
        (None, Some(cells(&mut it)))
    };
    let point = data
        .arrays
        .iter()
        .map(|a| {
            let attribute = if a.components == 3 {
                Attribute::vectors(a.name.clone())
            } else {
                Attribute::scalars(a.name.clone(), a.components as u32)
            };
            attribute.with_data(a.values.clone())
        })
        .collect();
    Vtk {
        version: if xml {
            Version::new_xml(1, 0)
        } else {
            Version::new_legacy(4, 2)
        },
        title: "livereg".into(),
        byte_order: if xml {
            ByteOrder::LittleEndian
        } else {
            ByteOrder::BigEndian
        },
        file_path: None,
        data: DataSet::inline(PolyDataPiece {
            points: coords.into(),
            verts,
            polys,
            data: Attributes {
                point,
                cell: Vec::new(),
            },
            ..Default::default()
        }),
    }
}
