//! POLYDATA (spec "PolyData Message"): a VTK-style polygonal data set.
//!
//! Content, big-endian:
//! - a 40-byte header of ten u32: `NPOINTS, NVERTICES, SIZE_VERTICES, NLINES, SIZE_LINES,
//!   NPOLYGONS, SIZE_POLYGONS, NTRIANGLE_STRIPS, SIZE_TRIANGLE_STRIPS, NATTRIBUTES` (N… are cell
//!   counts, SIZE_… byte sizes of the cell arrays);
//! - POINTS: `NPOINTS × 3` float32, x y z in millimetres;
//! - VERTICES, LINES, POLYGONS, TRIANGLE_STRIPS: cell arrays of u32, each cell its point count
//!   followed by that many point indices (VTK's legacy cell array);
//! - per attribute a 6-byte header `TYPE: u8, NCOMPONENTS: u8, N: u32` (the spec's 16-bit
//!   TYPE_ATTRIBUTE with the type in its high byte), then the attribute names, each
//!   NUL-terminated, plus one padding byte when their total length is odd, then per attribute
//!   `N × components` float32.
//!
//! Attribute types (low nibble): 0 scalars (NCOMPONENTS components), 1 vectors (3), 2 normals
//! (3), 3 tensors (9), 4 RGBA (4); bit 0x10 marks cell data instead of point data.

use nalgebra::Point3;

use super::error::IgtlError;
use super::message::MessageContent;
use crate::mesh::TriSurface;

use super::wire::{finite, to_f32, to_u32, Reader};

/// Longest attribute name in bytes (spec: 255).
pub(crate) const MAX_ATTRIBUTE_NAME: usize = 255;

/// What a data set attribute holds, with its number of components per point or cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AttributeKind {
    /// Scalars with 1 to 255 components.
    Scalars {
        /// Components per tuple.
        components: u8,
    },
    /// 3-component vectors.
    Vectors,
    /// 3-component normals.
    Normals,
    /// 9-component tensors.
    Tensors,
    /// 4-component colours in [0, 1].
    Rgba,
}

impl AttributeKind {
    /// Components per tuple.
    pub fn components(self) -> usize {
        match self {
            AttributeKind::Scalars { components } => usize::from(components),
            AttributeKind::Vectors | AttributeKind::Normals => 3,
            AttributeKind::Tensors => 9,
            AttributeKind::Rgba => 4,
        }
    }

    fn type_code(self) -> u8 {
        match self {
            AttributeKind::Scalars { .. } => 0,
            AttributeKind::Vectors => 1,
            AttributeKind::Normals => 2,
            AttributeKind::Tensors => 3,
            AttributeKind::Rgba => 4,
        }
    }
}

/// A point-data or cell-data attribute.
#[derive(Debug, Clone, PartialEq)]
pub struct PolyDataAttribute {
    /// Name (at most 255 bytes, no NUL).
    pub name: String,
    /// Kind and components.
    pub kind: AttributeKind,
    /// True for cell data, false for point data.
    pub cell_data: bool,
    /// Tuples, flattened: `N × components` values.
    pub data: Vec<f32>,
}

/// A POLYDATA message's content. Cells are lists of point indices; every index is checked
/// against the number of points when decoding and encoding.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PolyDataMessage {
    /// Points in millimetres.
    pub points: Vec<Point3<f64>>,
    /// Vertex cells (usually one point each).
    pub vertices: Vec<Vec<u32>>,
    /// Polylines.
    pub lines: Vec<Vec<u32>>,
    /// Polygons (triangles for a triangle surface).
    pub polygons: Vec<Vec<u32>>,
    /// Triangle strips.
    pub triangle_strips: Vec<Vec<u32>>,
    /// Point or cell attributes.
    pub attributes: Vec<PolyDataAttribute>,
}

impl PolyDataMessage {
    /// A triangle surface as points and triangular polygons (coordinates taken as mm). Errors
    /// when an index is out of range or does not fit in u32.
    pub fn from_tri_surface(surface: &TriSurface) -> Result<Self, IgtlError> {
        Self::from_triangles(surface.vertices.clone(), &surface.triangles)
    }

    /// [`PolyDataMessage::from_tri_surface`] of `points` (taken as mm) and `triangles`
    /// indexing them, without building a surface.
    pub fn from_triangles(
        points: Vec<Point3<f64>>,
        triangles: &[[usize; 3]],
    ) -> Result<Self, IgtlError> {
        let polygons = triangles
            .iter()
            .map(|triangle| {
                triangle
                    .iter()
                    .map(|&i| check_index(i, points.len(), "TriSurface triangle index"))
                    .collect::<Result<Vec<u32>, IgtlError>>()
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            points,
            polygons,
            ..Self::default()
        })
    }

    /// The triangle surface: polygons with n ≥ 3 points become n − 2 triangles fanned from
    /// their first point (exact for triangles, right for convex polygons), triangle strips
    /// become triangles with VTK's alternating orientation; vertices and lines are ignored.
    /// Polygons with fewer than 3 points or strips with fewer than 3 are
    /// [`IgtlError::InvalidField`].
    pub fn to_tri_surface(&self) -> Result<TriSurface, IgtlError> {
        let n = self.points.len();
        let mut triangles = Vec::new();
        for polygon in &self.polygons {
            if polygon.len() < 3 {
                return Err(IgtlError::InvalidField {
                    field: "POLYDATA polygon size",
                    value: polygon.len() as u64,
                    expected: "at least 3 points".to_owned(),
                });
            }
            let p: Vec<usize> = polygon
                .iter()
                .map(|&i| index_in(i, n, "POLYDATA polygon index"))
                .collect::<Result<_, _>>()?;
            for k in 1..p.len() - 1 {
                triangles.push([p[0], p[k], p[k + 1]]);
            }
        }
        for strip in &self.triangle_strips {
            if strip.len() < 3 {
                return Err(IgtlError::InvalidField {
                    field: "POLYDATA triangle strip size",
                    value: strip.len() as u64,
                    expected: "at least 3 points".to_owned(),
                });
            }
            let p: Vec<usize> = strip
                .iter()
                .map(|&i| index_in(i, n, "POLYDATA triangle strip index"))
                .collect::<Result<_, _>>()?;
            for k in 0..p.len() - 2 {
                triangles.push(if k % 2 == 0 {
                    [p[k], p[k + 1], p[k + 2]]
                } else {
                    [p[k + 1], p[k], p[k + 2]]
                });
            }
        }
        Ok(TriSurface::new(self.points.clone(), triangles))
    }

    /// A point cloud (mm). With `vertex_cells`, each point also gets a one-point vertex cell,
    /// which VTK-based viewers (3D Slicer) need to draw the points.
    pub fn from_point_cloud(points: &[Point3<f64>], vertex_cells: bool) -> Result<Self, IgtlError> {
        let count = to_u32(points.len(), "POLYDATA NPOINTS")?;
        Ok(Self {
            points: points.to_vec(),
            vertices: if vertex_cells {
                (0..count).map(|i| vec![i]).collect()
            } else {
                Vec::new()
            },
            ..Self::default()
        })
    }

    /// All points as a point cloud (mm), whether or not cells refer to them.
    pub fn to_point_cloud(&self) -> Vec<Point3<f64>> {
        self.points.clone()
    }
}

fn check_index(index: usize, count: usize, field: &'static str) -> Result<u32, IgtlError> {
    if index >= count {
        return Err(IgtlError::InvalidField {
            field,
            value: index as u64,
            expected: format!("less than the {count} points"),
        });
    }
    to_u32(index, field)
}

fn index_in(index: u32, count: usize, field: &'static str) -> Result<usize, IgtlError> {
    let index = index as usize;
    if index >= count {
        return Err(IgtlError::InvalidField {
            field,
            value: index as u64,
            expected: format!("less than the {count} points"),
        });
    }
    Ok(index)
}

/// The four cell arrays in message order, with their field names.
const CELL_FIELDS: [(&str, &str); 4] = [
    ("POLYDATA NVERTICES", "POLYDATA SIZE_VERTICES"),
    ("POLYDATA NLINES", "POLYDATA SIZE_LINES"),
    ("POLYDATA NPOLYGONS", "POLYDATA SIZE_POLYGONS"),
    ("POLYDATA NTRIANGLE_STRIPS", "POLYDATA SIZE_TRIANGLE_STRIPS"),
];

fn encode_cells(
    cells: &[Vec<u32>],
    points: usize,
    count_field: &'static str,
) -> Result<(u32, Vec<u8>), IgtlError> {
    let count = to_u32(cells.len(), count_field)?;
    let mut bytes = Vec::new();
    for cell in cells {
        bytes.extend_from_slice(&to_u32(cell.len(), count_field)?.to_be_bytes());
        for &index in cell {
            index_in(index, points, "POLYDATA cell index")?;
            bytes.extend_from_slice(&index.to_be_bytes());
        }
    }
    to_u32(bytes.len(), count_field)?;
    Ok((count, bytes))
}

fn decode_cells(
    bytes: &[u8],
    expected_cells: u32,
    points: usize,
    count_field: &'static str,
) -> Result<Vec<Vec<u32>>, IgtlError> {
    let mut reader = Reader::new(bytes);
    // Every cell takes at least one word: this bounds both the loop and the allocation.
    if u64::from(expected_cells) > (bytes.len() / 4) as u64 {
        return Err(IgtlError::InvalidField {
            field: count_field,
            value: u64::from(expected_cells),
            expected: format!("at most {} cells in {} bytes", bytes.len() / 4, bytes.len()),
        });
    }
    let mut cells = Vec::with_capacity(expected_cells as usize);
    while reader.remaining() > 0 {
        if cells.len() == expected_cells as usize {
            return Err(IgtlError::InvalidField {
                field: count_field,
                value: u64::from(expected_cells),
                expected: format!(
                    "more cells: {} bytes left after the last",
                    reader.remaining()
                ),
            });
        }
        let size = reader.u32("POLYDATA cell")? as usize;
        if size > reader.remaining() / 4 {
            return Err(IgtlError::InvalidField {
                field: "POLYDATA cell size",
                value: size as u64,
                expected: format!(
                    "at most {} indices left in the array",
                    reader.remaining() / 4
                ),
            });
        }
        let mut cell = Vec::with_capacity(size);
        for _ in 0..size {
            let index = reader.u32("POLYDATA cell")?;
            index_in(index, points, "POLYDATA cell index")?;
            cell.push(index);
        }
        cells.push(cell);
    }
    if cells.len() != expected_cells as usize {
        return Err(IgtlError::InvalidField {
            field: count_field,
            value: u64::from(expected_cells),
            expected: format!("{} (cells found in the array)", cells.len()),
        });
    }
    Ok(cells)
}

impl MessageContent for PolyDataMessage {
    const TYPE_NAME: &'static str = "POLYDATA";

    /// Writes the layout of the module documentation. Errors for out-of-range indices, counts
    /// or sizes above u32, coordinates not finite in float32, attribute names too long or with
    /// NUL, and attribute data whose length is not a multiple of the components.
    fn encode_content(&self, out: &mut Vec<u8>) -> Result<(), IgtlError> {
        let npoints = to_u32(self.points.len(), "POLYDATA NPOINTS")?;
        to_u32(self.points.len() * 12, "POLYDATA NPOINTS")?;
        let arrays = [
            &self.vertices,
            &self.lines,
            &self.polygons,
            &self.triangle_strips,
        ];
        let mut encoded = Vec::with_capacity(4);
        for (cells, (count_field, _)) in arrays.iter().zip(CELL_FIELDS) {
            encoded.push(encode_cells(cells, self.points.len(), count_field)?);
        }
        let nattributes = to_u32(self.attributes.len(), "POLYDATA NATTRIBUTES")?;
        out.extend_from_slice(&npoints.to_be_bytes());
        for (count, bytes) in &encoded {
            out.extend_from_slice(&count.to_be_bytes());
            out.extend_from_slice(&(bytes.len() as u32).to_be_bytes());
        }
        out.extend_from_slice(&nattributes.to_be_bytes());
        for (i, point) in self.points.iter().enumerate() {
            for axis in 0..3 {
                let value = to_f32(point[axis], "POLYDATA point", i * 3 + axis)?;
                out.extend_from_slice(&value.to_be_bytes());
            }
        }
        for (_, bytes) in &encoded {
            out.extend_from_slice(bytes);
        }
        let mut names_length = 0usize;
        for attribute in &self.attributes {
            let components = attribute.kind.components();
            if components == 0 || !attribute.data.len().is_multiple_of(components) {
                return Err(IgtlError::InvalidField {
                    field: "POLYDATA attribute data length",
                    value: attribute.data.len() as u64,
                    expected: format!("a multiple of {components} components (non-zero)"),
                });
            }
            if attribute.name.len() > MAX_ATTRIBUTE_NAME {
                return Err(IgtlError::NameTooLong {
                    field: "POLYDATA attribute name",
                    length: attribute.name.len(),
                    max: MAX_ATTRIBUTE_NAME,
                });
            }
            super::wire::check_text(&attribute.name, "POLYDATA attribute name", false)?;
            let tuples = to_u32(attribute.data.len() / components, "POLYDATA attribute N")?;
            let type_code = attribute.kind.type_code() | if attribute.cell_data { 0x10 } else { 0 };
            out.push(type_code);
            out.push(components as u8);
            out.extend_from_slice(&tuples.to_be_bytes());
            names_length += attribute.name.len() + 1;
        }
        for attribute in &self.attributes {
            out.extend_from_slice(attribute.name.as_bytes());
            out.push(0);
        }
        if names_length % 2 == 1 {
            out.push(0);
        }
        for attribute in &self.attributes {
            for (i, value) in attribute.data.iter().enumerate() {
                if !value.is_finite() {
                    return Err(IgtlError::NonFinite {
                        field: "POLYDATA attribute",
                        index: i,
                    });
                }
                out.extend_from_slice(&value.to_be_bytes());
            }
        }
        Ok(())
    }

    /// Reads and bounds-checks every section: counts against the bytes present before any
    /// allocation, byte sizes multiple of 4, cell counts against the arrays, indices against
    /// NPOINTS, attribute names terminated within the content, no trailing bytes.
    fn decode_content(content: &[u8]) -> Result<Self, IgtlError> {
        let mut reader = Reader::new(content);
        let header = read_header(&mut reader)?;
        let points = read_points(&mut reader, header.npoints)?;
        let arrays = read_cell_arrays(&mut reader, &header.cells, points.len())?;
        let headers = read_attribute_headers(&mut reader, header.nattributes)?;
        let names = read_attribute_names(&mut reader, headers.len())?;
        let attributes = read_attribute_data(&mut reader, headers, names)?;
        if reader.remaining() != 0 {
            return Err(IgtlError::ContentSize {
                type_name: Self::TYPE_NAME,
                actual: content.len() as u64,
                expected: format!(
                    "{} bytes as its header describes ({} trailing bytes)",
                    content.len() - reader.remaining(),
                    reader.remaining()
                ),
            });
        }
        let [vertices, lines, polygons, triangle_strips] = arrays;
        Ok(Self {
            points,
            vertices,
            lines,
            polygons,
            triangle_strips,
            attributes,
        })
    }
}

/// An attribute's header: its kind, whether it is cell data, and its number of tuples.
type AttributeHeader = (AttributeKind, bool, u32);

/// The fixed 40-byte header.
struct Header {
    /// NPOINTS.
    npoints: u32,
    /// (N…, SIZE_…) of the four cell arrays in message order: cell count, byte size.
    cells: [(u32, u32); 4],
    /// NATTRIBUTES.
    nattributes: u32,
}

/// Reads the fixed header.
fn read_header(reader: &mut Reader<'_>) -> Result<Header, IgtlError> {
    let npoints = reader.u32("POLYDATA header")?;
    let mut cells = [(0u32, 0u32); 4];
    for count in cells.iter_mut() {
        *count = (
            reader.u32("POLYDATA header")?,
            reader.u32("POLYDATA header")?,
        );
    }
    let nattributes = reader.u32("POLYDATA header")?;
    Ok(Header {
        npoints,
        cells,
        nattributes,
    })
}

/// The `npoints` points (float32 x y z, mm), checked against the bytes left before
/// allocating, each coordinate finite.
fn read_points(reader: &mut Reader<'_>, npoints: u32) -> Result<Vec<Point3<f64>>, IgtlError> {
    let points_size = u64::from(npoints) * 12;
    if points_size > reader.remaining() as u64 {
        return Err(IgtlError::Truncated {
            section: "POLYDATA points",
            expected: points_size,
            actual: reader.remaining() as u64,
        });
    }
    let points_bytes = reader.take(points_size as usize, "POLYDATA points")?;
    let mut points = Vec::with_capacity(npoints as usize);
    let mut point_reader = Reader::new(points_bytes);
    for i in 0..npoints as usize {
        let mut xyz = [0.0; 3];
        for (axis, value) in xyz.iter_mut().enumerate() {
            *value = finite(
                point_reader.f32("POLYDATA points")?,
                "POLYDATA point",
                i * 3 + axis,
            )?;
        }
        points.push(Point3::from(xyz));
    }
    Ok(points)
}

/// The four cell arrays (vertices, lines, polygons, triangle strips) of the header's
/// (count, byte size) `counts`: sizes multiple of 4, indices below `npoints`.
fn read_cell_arrays(
    reader: &mut Reader<'_>,
    counts: &[(u32, u32); 4],
    npoints: usize,
) -> Result<[Vec<Vec<u32>>; 4], IgtlError> {
    let mut arrays: [Vec<Vec<u32>>; 4] = Default::default();
    for ((array, &(count, size)), (count_field, size_field)) in
        arrays.iter_mut().zip(counts.iter()).zip(CELL_FIELDS)
    {
        if !size.is_multiple_of(4) {
            return Err(IgtlError::InvalidField {
                field: size_field,
                value: u64::from(size),
                expected: "a multiple of 4".to_owned(),
            });
        }
        let bytes = reader.take(size as usize, "POLYDATA cell array")?;
        *array = decode_cells(bytes, count, npoints, count_field)?;
    }
    Ok(arrays)
}

/// The `nattributes` 6-byte attribute headers, checked against the bytes left before
/// allocating.
fn read_attribute_headers(
    reader: &mut Reader<'_>,
    nattributes: u32,
) -> Result<Vec<AttributeHeader>, IgtlError> {
    if u64::from(nattributes) * 6 > reader.remaining() as u64 {
        return Err(IgtlError::Truncated {
            section: "POLYDATA attribute headers",
            expected: u64::from(nattributes) * 6,
            actual: reader.remaining() as u64,
        });
    }
    let mut headers = Vec::with_capacity(nattributes as usize);
    for _ in 0..nattributes {
        let type_code = reader.u8("POLYDATA attribute header")?;
        let ncomponents = reader.u8("POLYDATA attribute header")?;
        let tuples = reader.u32("POLYDATA attribute header")?;
        let kind = attribute_kind(type_code, ncomponents)?;
        headers.push((kind, type_code & 0x10 != 0, tuples));
    }
    Ok(headers)
}

/// The attribute kind of a header's TYPE byte (low nibble; 0x10 marks cell data, no higher
/// bit may be set) and NCOMPONENTS (used by scalars only).
fn attribute_kind(type_code: u8, ncomponents: u8) -> Result<AttributeKind, IgtlError> {
    let kind = match type_code & 0x0F {
        0 if ncomponents > 0 => AttributeKind::Scalars {
            components: ncomponents,
        },
        1 => AttributeKind::Vectors,
        2 => AttributeKind::Normals,
        3 => AttributeKind::Tensors,
        4 => AttributeKind::Rgba,
        _ => {
            return Err(IgtlError::InvalidField {
                field: "POLYDATA attribute type",
                value: u64::from(u16::from_be_bytes([type_code, ncomponents])),
                expected: "type 0 (with 1–255 components), 1, 2, 3 or 4, optionally | 0x10"
                    .to_owned(),
            })
        }
    };
    if type_code & 0xE0 != 0 {
        return Err(IgtlError::InvalidField {
            field: "POLYDATA attribute type",
            value: u64::from(type_code),
            expected: "no bits set above 0x10".to_owned(),
        });
    }
    Ok(kind)
}

/// `count` NUL-terminated UTF-8 attribute names of at most [`MAX_ATTRIBUTE_NAME`] bytes, then
/// the padding byte that makes their total length even.
fn read_attribute_names(reader: &mut Reader<'_>, count: usize) -> Result<Vec<String>, IgtlError> {
    let mut names = Vec::with_capacity(count);
    let mut names_length = 0usize;
    for _ in 0..count {
        let rest = reader.take(reader.remaining(), "POLYDATA attribute name")?;
        let end = rest
            .iter()
            .take(MAX_ATTRIBUTE_NAME + 1)
            .position(|&b| b == 0)
            .ok_or_else(|| IgtlError::InvalidName {
                field: "POLYDATA attribute name",
                reason: format!(
                    "no NUL terminator within {} bytes",
                    rest.len().min(MAX_ATTRIBUTE_NAME + 1)
                ),
            })?;
        let name = std::str::from_utf8(&rest[..end]).map_err(|e| IgtlError::InvalidName {
            field: "POLYDATA attribute name",
            reason: format!("invalid UTF-8 at byte {}", e.valid_up_to()),
        })?;
        names.push(name.to_owned());
        names_length += end + 1;
        // Give back what follows the name.
        *reader = Reader::new(&rest[end + 1..]);
    }
    if names_length % 2 == 1 {
        reader.take(1, "POLYDATA attribute name padding")?;
    }
    Ok(names)
}

/// Each attribute's `tuples × components` float32 values (checked against the bytes left
/// before allocating, each finite), with its header and name.
fn read_attribute_data(
    reader: &mut Reader<'_>,
    headers: Vec<AttributeHeader>,
    names: Vec<String>,
) -> Result<Vec<PolyDataAttribute>, IgtlError> {
    let mut attributes = Vec::with_capacity(headers.len());
    for ((kind, cell_data, tuples), name) in headers.into_iter().zip(names) {
        let values = u64::from(tuples) * kind.components() as u64;
        if values * 4 > reader.remaining() as u64 {
            return Err(IgtlError::Truncated {
                section: "POLYDATA attribute data",
                expected: values * 4,
                actual: reader.remaining() as u64,
            });
        }
        let mut data = Vec::with_capacity(values as usize);
        for i in 0..values as usize {
            let value = reader.f32("POLYDATA attribute data")?;
            if !value.is_finite() {
                return Err(IgtlError::NonFinite {
                    field: "POLYDATA attribute",
                    index: i,
                });
            }
            data.push(value);
        }
        attributes.push(PolyDataAttribute {
            name,
            kind,
            cell_data,
            data,
        });
    }
    Ok(attributes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetrahedron() -> TriSurface {
        TriSurface::new(
            vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(10.0, 0.0, 0.0),
                Point3::new(0.0, 10.0, 0.0),
                Point3::new(0.0, 0.0, 10.0),
            ],
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        )
    }

    fn encode(message: &PolyDataMessage) -> Vec<u8> {
        let mut out = Vec::new();
        message.encode_content(&mut out).unwrap();
        out
    }

    #[test]
    fn tri_surface_round_trip_and_layout() {
        let message = PolyDataMessage::from_tri_surface(&tetrahedron()).unwrap();
        let bytes = encode(&message);
        let header: Vec<u32> = bytes[..40]
            .chunks(4)
            .map(|c| u32::from_be_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert_eq!(header, vec![4, 0, 0, 0, 0, 4, 64, 0, 0, 0]);
        assert_eq!(bytes.len(), 40 + 48 + 64);
        assert_eq!(&bytes[88..92], &3u32.to_be_bytes());
        let back = PolyDataMessage::decode_content(&bytes).unwrap();
        assert_eq!(back, message);
        let surface = back.to_tri_surface().unwrap();
        assert_eq!(surface.vertices, tetrahedron().vertices);
        assert_eq!(surface.triangles, tetrahedron().triangles);
    }

    #[test]
    fn point_cloud_with_and_without_vertices() {
        let cloud = vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-4.5, 5.0, 6.25)];
        for vertex_cells in [false, true] {
            let message = PolyDataMessage::from_point_cloud(&cloud, vertex_cells).unwrap();
            let back = PolyDataMessage::decode_content(&encode(&message)).unwrap();
            assert_eq!(back.to_point_cloud(), cloud);
            assert_eq!(back.vertices.len(), if vertex_cells { 2 } else { 0 });
        }
    }

    #[test]
    fn polygons_and_strips_triangulate() {
        let mut message = PolyDataMessage::from_point_cloud(
            &(0..5)
                .map(|i| Point3::new(f64::from(i), 0.0, 0.0))
                .collect::<Vec<_>>(),
            false,
        )
        .unwrap();
        message.polygons = vec![vec![0, 1, 2, 3]];
        message.triangle_strips = vec![vec![0, 1, 2, 3, 4]];
        let surface = message.to_tri_surface().unwrap();
        assert_eq!(
            surface.triangles,
            vec![[0, 1, 2], [0, 2, 3], [0, 1, 2], [2, 1, 3], [2, 3, 4]]
        );
        message.polygons = vec![vec![0, 1]];
        assert!(matches!(
            message.to_tri_surface(),
            Err(IgtlError::InvalidField { .. })
        ));
    }

    #[test]
    fn attributes_round_trip_with_padding() {
        let mut message = PolyDataMessage::from_tri_surface(&tetrahedron()).unwrap();
        message.lines = vec![vec![0, 1, 2]];
        message.attributes = vec![
            PolyDataAttribute {
                name: "Temperature".to_owned(), // 11 + 1 bytes
                kind: AttributeKind::Scalars { components: 1 },
                cell_data: false,
                data: vec![1.0, 2.0, 3.0, 4.0],
            },
            PolyDataAttribute {
                name: "Nrm".to_owned(), // 3 + 1: total 16, no padding
                kind: AttributeKind::Normals,
                cell_data: true,
                data: vec![0.0; 15],
            },
        ];
        let bytes = encode(&message);
        assert_eq!(PolyDataMessage::decode_content(&bytes).unwrap(), message);
        message.attributes[1].name = "Nr".to_owned(); // total 15: one padding byte
        let padded = encode(&message);
        assert_eq!(padded.len(), bytes.len());
        assert_eq!(PolyDataMessage::decode_content(&padded).unwrap(), message);
    }

    #[test]
    fn malformed_content_gives_specific_errors() {
        let good = encode(&PolyDataMessage::from_tri_surface(&tetrahedron()).unwrap());
        // NPOINTS far beyond the content: refused before allocating.
        let mut bad = good.clone();
        bad[0..4].copy_from_slice(&u32::MAX.to_be_bytes());
        assert!(matches!(
            PolyDataMessage::decode_content(&bad),
            Err(IgtlError::Truncated {
                section: "POLYDATA points",
                ..
            })
        ));
        // SIZE_POLYGONS not a multiple of 4.
        let mut bad = good.clone();
        bad[24..28].copy_from_slice(&63u32.to_be_bytes());
        assert!(matches!(
            PolyDataMessage::decode_content(&bad),
            Err(IgtlError::InvalidField {
                field: "POLYDATA SIZE_POLYGONS",
                value: 63,
                ..
            })
        ));
        // NPOLYGONS disagreeing with the array.
        let mut bad = good.clone();
        bad[20..24].copy_from_slice(&3u32.to_be_bytes());
        assert!(matches!(
            PolyDataMessage::decode_content(&bad),
            Err(IgtlError::InvalidField {
                field: "POLYDATA NPOLYGONS",
                value: 3,
                ..
            })
        ));
        // A cell claiming more indices than the array holds.
        let mut bad = good.clone();
        bad[88..92].copy_from_slice(&1000u32.to_be_bytes());
        assert!(matches!(
            PolyDataMessage::decode_content(&bad),
            Err(IgtlError::InvalidField {
                field: "POLYDATA cell size",
                value: 1000,
                ..
            })
        ));
        // An index past NPOINTS.
        let mut bad = good.clone();
        bad[92..96].copy_from_slice(&4u32.to_be_bytes());
        assert!(matches!(
            PolyDataMessage::decode_content(&bad),
            Err(IgtlError::InvalidField {
                field: "POLYDATA cell index",
                value: 4,
                ..
            })
        ));
        // Trailing bytes.
        let mut bad = good.clone();
        bad.extend_from_slice(&[0; 4]);
        assert!(matches!(
            PolyDataMessage::decode_content(&bad),
            Err(IgtlError::ContentSize {
                type_name: "POLYDATA",
                ..
            })
        ));
        // Attributes announced but absent; an unterminated name.
        let mut bad = good.clone();
        bad[36..40].copy_from_slice(&1u32.to_be_bytes());
        assert!(matches!(
            PolyDataMessage::decode_content(&bad),
            Err(IgtlError::Truncated {
                section: "POLYDATA attribute headers",
                ..
            })
        ));
        bad.extend_from_slice(&[0, 1, 0, 0, 0, 1, b'a', b'b']);
        assert!(matches!(
            PolyDataMessage::decode_content(&bad),
            Err(IgtlError::InvalidName {
                field: "POLYDATA attribute name",
                ..
            })
        ));
        assert!(matches!(
            PolyDataMessage::decode_content(&good[..39]),
            Err(IgtlError::Truncated {
                section: "POLYDATA header",
                ..
            })
        ));
    }

    #[test]
    fn encoding_checks_indices() {
        let mut message = PolyDataMessage::from_tri_surface(&tetrahedron()).unwrap();
        message.lines = vec![vec![0, 9]];
        assert!(matches!(
            message.encode_content(&mut Vec::new()),
            Err(IgtlError::InvalidField {
                field: "POLYDATA cell index",
                value: 9,
                ..
            })
        ));
        let mut surface = tetrahedron();
        surface.triangles.push([0, 1, 7]);
        assert!(matches!(
            PolyDataMessage::from_tri_surface(&surface),
            Err(IgtlError::InvalidField { value: 7, .. })
        ));
    }
}
