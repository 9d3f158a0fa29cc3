//! Reading a VTK file's polygons ([`read_vtk`]) or points ([`read_vtk_points`]).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use nalgebra::Point3;
use vtkio::model::{CellType, DataSet, IOBuffer, Piece, VertexNumbers};
use vtkio::Vtk;

use super::super::assemble::{fan, finish};
use super::super::error::MeshError;
use super::super::extension;
use super::super::surface::TriSurface;
use super::super::text::read_bytes;
use super::xml_polydata::{finite_points, parse_xml_polydata, XmlPiece};

/// Reads the polygons of a VTK file as a triangle surface (scene units):
/// - `.vtk` (legacy, ASCII or binary): `DATASET POLYDATA` (its `POLYGONS` and
///   `TRIANGLE_STRIPS`) or `DATASET UNSTRUCTURED_GRID` (its triangle, quad, polygon and
///   triangle-strip cells; volume cells are refused: extract their boundary first);
/// - `.vtp` (XML PolyData, ASCII, base64 or appended data, zlib compression or none):
///   `Polys` and `Strips` of every piece.
///
/// Polygons are fan-triangulated keeping their orientation; vertices, lines and point or cell
/// data are ignored. Errors name the file and what is wrong (an index out of range, a
/// non-finite coordinate, a file with no polygon).
pub fn read_vtk(path: &Path) -> Result<TriSurface, MeshError> {
    parse_vtk(path, &read_bytes(path)?)
}

/// [`read_vtk`] of the file content `bytes` (`path` tells the format and names errors).
pub(crate) fn parse_vtk(path: &Path, bytes: &[u8]) -> Result<TriSurface, MeshError> {
    let pieces = import(path, bytes)?;
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for piece in pieces {
        let base = vertices.len();
        let count = piece.points.len();
        vertices.extend(piece.points);
        for cell in piece.cells {
            let cell = offset_cell(path, &cell, base, count)?;
            match cell.kind {
                CellKind::Polygon => fan(&cell.points, &mut triangles, |m| {
                    MeshError::malformed(path, format!("cell {}: {m}", cell.index))
                })?,
                CellKind::Strip => strip(&cell.points, &mut triangles),
            }
        }
    }
    finish(path, vertices, triangles)
}

/// Reads every point of a VTK file (`.vtk` or `.vtp`, as [`read_vtk`]), in file order,
/// whatever cells refer to them (a camera cloud saved as PolyData with or without vertex
/// cells). An empty file is an error.
pub fn read_vtk_points(path: &Path) -> Result<Vec<Point3<f64>>, MeshError> {
    let bytes = read_bytes(path)?;
    let points: Vec<Point3<f64>> = import(path, &bytes)?
        .into_iter()
        .flat_map(|p| p.points)
        .collect();
    if points.is_empty() {
        return Err(MeshError::empty(path, "points"));
    }
    Ok(points)
}

/// What a cell contributes to a surface.
#[derive(Debug, Clone, Copy, PartialEq)]
enum CellKind {
    /// A triangle, quad or polygon: fan-triangulated.
    Polygon,
    /// A triangle strip: consecutive triangles alternating orientation.
    Strip,
}

/// A surface cell of one piece, its point indices local to the piece.
#[derive(Debug)]
struct Cell {
    /// 0-based index of the cell in its list (for error messages).
    index: usize,
    kind: CellKind,
    points: Vec<usize>,
}

/// One piece of a file: its points (scene units) and surface cells.
#[derive(Debug, Default)]
struct PieceData {
    points: Vec<Point3<f64>>,
    cells: Vec<Cell>,
}

/// The cell with its indices checked against the piece's `count` points and shifted by
/// `base`.
fn offset_cell(path: &Path, cell: &Cell, base: usize, count: usize) -> Result<Cell, MeshError> {
    let mut points = Vec::with_capacity(cell.points.len());
    for &i in &cell.points {
        if i >= count {
            return Err(MeshError::malformed(
                path,
                format!(
                    "cell {} refers to point {i}, but its piece has {count} points",
                    cell.index
                ),
            ));
        }
        points.push(base + i);
    }
    Ok(Cell {
        index: cell.index,
        kind: cell.kind,
        points,
    })
}

/// Appends the triangles of a strip `p0 p1 p2 p3 ...`: `(p0 p1 p2)`, `(p2 p1 p3)`, ... (VTK's
/// orientation rule), leaving out triangles with a repeated point (strip joins).
fn strip(points: &[usize], out: &mut Vec<[usize; 3]>) {
    for (k, w) in points.windows(3).enumerate() {
        let t = if k % 2 == 0 {
            [w[0], w[1], w[2]]
        } else {
            [w[1], w[0], w[2]]
        };
        if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
            out.push(t);
        }
    }
}

/// Parses the file (`.vtp` with [`parse_xml_polydata`], legacy `.vtk` with `vtkio`, any
/// panic inside which becomes an error) and returns its pieces; legacy files titled
/// `SPACE=RAS` are turned into LPS.
fn import(path: &Path, bytes: &[u8]) -> Result<Vec<PieceData>, MeshError> {
    let ext = extension(path);
    if ext.as_deref() == Some("vtp") {
        return Ok(parse_xml_polydata(path, bytes)?
            .into_iter()
            .map(xml_piece)
            .collect());
    }
    let parsed = catch_unwind(AssertUnwindSafe(|| match ext.as_deref() {
        Some("vtk") => Vtk::parse_legacy_be(bytes).map_err(|e| e.to_string()),
        other => Err(format!(
            "not a VTK file extension: {:?} (expected vtk or vtp)",
            other.unwrap_or_default()
        )),
    }))
    .map_err(|_| MeshError::malformed(path, "the VTK parser failed on this file"))?;
    let vtk =
        parsed.map_err(|e| MeshError::malformed(path, format!("not a readable VTK file: {e}")))?;
    let ras = vtk.title.to_ascii_uppercase().contains("SPACE=RAS");
    let mut pieces = match vtk.data {
        DataSet::PolyData { pieces, .. } => pieces
            .into_iter()
            .map(|p| inline(path, p))
            .map(|p| p.and_then(|p| polydata_piece(path, p)))
            .collect::<Result<Vec<_>, _>>()?,
        DataSet::UnstructuredGrid { pieces, .. } => pieces
            .into_iter()
            .map(|p| inline(path, p))
            .map(|p| p.and_then(|p| grid_piece(path, p)))
            .collect::<Result<Vec<_>, _>>()?,
        other => {
            return Err(MeshError::unsupported(
                path,
                format!(
                    "a VTK {} data set holds no polygons (expected POLYDATA or \
                     UNSTRUCTURED_GRID)",
                    dataset_name(&other)
                ),
            ))
        }
    };
    if ras {
        for p in pieces.iter_mut().flat_map(|piece| piece.points.iter_mut()) {
            p.x = -p.x;
            p.y = -p.y;
        }
    }
    Ok(pieces)
}

/// The name of a data set kind, for messages.
fn dataset_name(data: &DataSet) -> &'static str {
    match data {
        DataSet::ImageData { .. } => "image data (STRUCTURED_POINTS)",
        DataSet::StructuredGrid { .. } => "STRUCTURED_GRID",
        DataSet::RectilinearGrid { .. } => "RECTILINEAR_GRID",
        DataSet::UnstructuredGrid { .. } => "UNSTRUCTURED_GRID",
        DataSet::PolyData { .. } => "POLYDATA",
        DataSet::Field { .. } => "FIELD",
    }
}

/// The data of an inline piece; pieces in other files (parallel `.pvtp`) are refused.
fn inline<P>(path: &Path, piece: Piece<P>) -> Result<P, MeshError> {
    match piece {
        Piece::Inline(p) => Ok(*p),
        Piece::Source(file, _) => Err(MeshError::unsupported(
            path,
            format!("the piece is stored in another file ({file:?}); give that file instead"),
        )),
        Piece::Loaded(_) => Err(MeshError::unsupported(
            path,
            "nested data sets are not read; give a serial PolyData file",
        )),
    }
}

/// The points of a piece as finite positions.
fn points(path: &Path, buffer: &IOBuffer) -> Result<Vec<Point3<f64>>, MeshError> {
    let values: Vec<f64> = buffer
        .cast_into::<f64>()
        .ok_or_else(|| MeshError::malformed(path, "point coordinates are not numbers"))?;
    if !values.len().is_multiple_of(3) {
        return Err(MeshError::malformed(
            path,
            format!(
                "{} point coordinates is not a multiple of 3 (x y z)",
                values.len()
            ),
        ));
    }
    finite_points(path, &values)
}

/// The cells of a vertex-number list as index lists, checked for consistency (never
/// trusting counts).
fn cell_lists(
    path: &Path,
    what: &str,
    numbers: &VertexNumbers,
) -> Result<Vec<Vec<usize>>, MeshError> {
    let bad = |m: String| MeshError::malformed(path, format!("{what}: {m}"));
    let mut out = Vec::new();
    match numbers {
        VertexNumbers::Legacy {
            num_cells,
            vertices,
        } => {
            let mut at = 0usize;
            for c in 0..*num_cells as usize {
                let n = *vertices
                    .get(at)
                    .ok_or_else(|| bad(format!("cell {c} is missing ({num_cells} announced)")))?
                    as usize;
                let cell = vertices
                    .get(at + 1..at + 1 + n)
                    .ok_or_else(|| bad(format!("cell {c} announces {n} points past the end")))?;
                out.push(cell.iter().map(|&i| i as usize).collect());
                at += 1 + n;
            }
            if at != vertices.len() {
                return Err(bad(format!(
                    "{} numbers left after {num_cells} cells",
                    vertices.len() - at
                )));
            }
        }
        VertexNumbers::XML {
            connectivity,
            offsets,
        } => {
            let mut start = 0usize;
            let skip_leading_zero = offsets.first() == Some(&0) && offsets.len() > 1;
            for (c, &end) in offsets
                .iter()
                .enumerate()
                .skip(usize::from(skip_leading_zero))
            {
                let end = usize::try_from(end).unwrap_or(usize::MAX);
                let cell = connectivity.get(start..end).ok_or_else(|| {
                    bad(format!(
                        "cell {c} ends at {end}, outside 0..{}",
                        connectivity.len()
                    ))
                })?;
                out.push(
                    cell.iter()
                        .map(|&i| usize::try_from(i).unwrap_or(usize::MAX))
                        .collect(),
                );
                start = end;
            }
        }
    }
    Ok(out)
}

/// A PolyData piece: its points, polygons and strips.
fn polydata_piece(path: &Path, p: vtkio::model::PolyDataPiece) -> Result<PieceData, MeshError> {
    let mut cells = Vec::new();
    for (numbers, kind, what) in [
        (&p.polys, CellKind::Polygon, "polygons"),
        (&p.strips, CellKind::Strip, "triangle strips"),
    ] {
        if let Some(numbers) = numbers {
            for (index, points) in cell_lists(path, what, numbers)?.into_iter().enumerate() {
                cells.push(Cell {
                    index,
                    kind,
                    points,
                });
            }
        }
    }
    Ok(PieceData {
        points: points(path, &p.points)?,
        cells,
    })
}

/// An unstructured-grid piece: its points and surface cells; a volume cell is refused.
fn grid_piece(path: &Path, p: vtkio::model::UnstructuredGridPiece) -> Result<PieceData, MeshError> {
    let lists = cell_lists(path, "cells", &p.cells.cell_verts)?;
    if lists.len() != p.cells.types.len() {
        return Err(MeshError::malformed(
            path,
            format!(
                "{} cells but {} cell types",
                lists.len(),
                p.cells.types.len()
            ),
        ));
    }
    let mut cells = Vec::new();
    for (index, (points, ty)) in lists.into_iter().zip(&p.cells.types).enumerate() {
        let kind = match ty {
            CellType::Triangle | CellType::Quad | CellType::Polygon => CellKind::Polygon,
            CellType::TriangleStrip => CellKind::Strip,
            CellType::Vertex | CellType::PolyVertex | CellType::Line | CellType::PolyLine => {
                continue
            }
            other => {
                return Err(MeshError::unsupported(
                    path,
                    format!(
                        "cell {index} is a {other:?}: only surface cells (triangles, quads, \
                         polygons, strips) are read; extract the boundary surface first"
                    ),
                ))
            }
        };
        cells.push(Cell {
            index,
            kind,
            points,
        });
    }
    Ok(PieceData {
        points: points(path, &p.points)?,
        cells,
    })
}

/// A piece of a `.vtp` file: its points, polygons and strips.
fn xml_piece(p: XmlPiece) -> PieceData {
    let cells = p
        .polys
        .into_iter()
        .enumerate()
        .map(|(index, points)| Cell {
            index,
            kind: CellKind::Polygon,
            points,
        })
        .chain(
            p.strips
                .into_iter()
                .enumerate()
                .map(|(index, points)| Cell {
                    index,
                    kind: CellKind::Strip,
                    points,
                }),
        )
        .collect();
    PieceData {
        points: p.points,
        cells,
    }
}
