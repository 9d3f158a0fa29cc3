//! PLY (Stanford polygon format), ASCII and binary little- or big-endian: the `vertex` element's
//! x, y, z and the `face` element's vertex index lists; every other property and element is
//! skipped.

use std::path::Path;

use nalgebra::Point3;

use super::assemble::{bounded_capacity, fan, finish};
use super::error::MeshError;
use super::finite_points::is_finite_point;
use super::surface::TriSurface;
use super::text::{decode, quote, read_bytes, Line, Lines, Tokens};
use crate::stored_scalar::{ByteOrder, StoredScalar};

/// Reads a PLY surface: vertices from the `vertex` element (x, y, z of any scalar type) and
/// fan-triangulated polygons from the `face` element's `vertex_indices` (or `vertex_index`) list.
/// Other properties and elements are skipped. Lengths are in the file's units.
pub fn read_ply(path: &Path) -> Result<TriSurface, MeshError> {
    let (vertices, triangles) = parse(path, &read_bytes(path)?, true)?;
    finish(path, vertices, triangles)
}

/// Reads only the `vertex` element's x, y, z of a PLY file (a point cloud; faces, if any, are
/// skipped). The result may be empty. Lengths are in the file's units.
pub fn read_ply_vertices(path: &Path) -> Result<Vec<Point3<f64>>, MeshError> {
    Ok(parse(path, &read_bytes(path)?, false)?.0)
}

/// The number type a PLY property type names (`uchar`, `float32`, …).
fn ply_scalar(name: &str) -> Option<StoredScalar> {
    Some(match name {
        "char" | "int8" => StoredScalar::I8,
        "uchar" | "uint8" => StoredScalar::U8,
        "short" | "int16" => StoredScalar::I16,
        "ushort" | "uint16" => StoredScalar::U16,
        "int" | "int32" => StoredScalar::I32,
        "uint" | "uint32" => StoredScalar::U32,
        "float" | "float32" => StoredScalar::F32,
        "double" | "float64" => StoredScalar::F64,
        _ => return None,
    })
}

/// A property: a scalar, or a list with its length type and item type.
#[derive(Debug, Clone, Copy)]
enum Kind {
    Scalar(StoredScalar),
    List {
        count: StoredScalar,
        item: StoredScalar,
    },
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
    /// Header line declaring the element.
    line: usize,
}

impl Element {
    /// Bytes per instance in binary, if the element has no list property.
    fn fixed_size(&self) -> Option<usize> {
        self.properties
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => Some(s.size()),
                Kind::List { .. } => None,
            })
            .sum()
    }

    /// Smallest possible size of an instance in binary (empty lists).
    fn min_size(&self) -> usize {
        self.properties
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) | Kind::List { count: s, .. } => s.size(),
            })
            .sum()
    }

    fn scalar(&self, name: &str) -> Option<usize> {
        self.properties
            .iter()
            .position(|p| p.name == name && matches!(p.kind, Kind::Scalar(_)))
    }

    fn err(&self, path: &Path, message: impl Into<String>) -> MeshError {
        MeshError::parse(path, self.line, message)
    }
}

/// The parsed header.
struct Header {
    /// `None` for ASCII, else whether the binary data is big-endian.
    big_endian: Option<bool>,
    elements: Vec<Element>,
    /// Byte offset of the data.
    body: usize,
    /// Line number of the first data line (ASCII).
    body_line: usize,
}

fn parse_header(path: &Path, data: &[u8]) -> Result<Header, MeshError> {
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut pos = 0;
    let mut no = 0;
    loop {
        no += 1;
        if pos >= data.len() {
            return Err(MeshError::malformed(
                path,
                "the header has no 'end_header' line (truncated or not a PLY file)",
            ));
        }
        let end = data[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(data.len(), |i| pos + i);
        let raw = decode(&data[pos..end]);
        pos = end + 1;
        let line = Line {
            path,
            no,
            text: raw.trim(),
        };
        if no == 1 {
            if line.text != "ply" {
                return Err(line.err(format!(
                    "not a PLY file: the first line is {} instead of 'ply'",
                    quote(line.text)
                )));
            }
            continue;
        }
        let mut t = line.tokens();
        match t.next() {
            None | Some("comment" | "obj_info") => {}
            Some("format") => {
                format = Some(match t.expect("a format")? {
                    "ascii" => None,
                    "binary_little_endian" => Some(false),
                    "binary_big_endian" => Some(true),
                    other => return Err(line.err(format!("unknown PLY format {}", quote(other)))),
                });
                let version = t.expect("a format version")?;
                if version != "1.0" && version != "1" {
                    return Err(MeshError::unsupported(
                        path,
                        format!("PLY version {} (only 1.0 is read)", quote(version)),
                    ));
                }
                t.end()?;
            }
            Some("element") => {
                let name = t.expect("an element name")?.to_owned();
                let count = t.uint("an element count")?;
                t.end()?;
                elements.push(Element {
                    name,
                    count,
                    properties: Vec::new(),
                    line: no,
                });
            }
            Some("property") => {
                let kind =
                    match t.expect("a property type")? {
                        "list" => Kind::List {
                            count: scalar_type(&mut t)?,
                            item: scalar_type(&mut t)?,
                        },
                        ty => Kind::Scalar(ply_scalar(ty).ok_or_else(|| {
                            line.err(format!("unknown property type {}", quote(ty)))
                        })?),
                    };
                let name = t.expect("a property name")?.to_owned();
                t.end()?;
                let element = elements
                    .last_mut()
                    .ok_or_else(|| line.err("'property' before any 'element'"))?;
                element.properties.push(Property { name, kind });
            }
            Some("end_header") => {
                t.end()?;
                let big_endian =
                    format.ok_or_else(|| line.err("the header has no 'format' line"))?;
                return Ok(Header {
                    big_endian,
                    elements,
                    body: pos.min(data.len()),
                    body_line: no + 1,
                });
            }
            Some(other) => return Err(line.err(format!("unknown header keyword {}", quote(other)))),
        }
    }
}

fn scalar_type(t: &mut Tokens<'_>) -> Result<StoredScalar, MeshError> {
    let name = t.expect("a list type")?;
    ply_scalar(name).ok_or_else(|| t.err(format!("unknown property type {}", quote(name))))
}

/// The data after the header, read one element instance at a time.
enum Body<'a> {
    Ascii {
        lines: Lines<'a>,
        /// Tokens of the instance being read.
        tokens: Option<Tokens<'a>>,
    },
    Binary {
        path: &'a Path,
        data: &'a [u8],
        pos: usize,
        order: ByteOrder,
    },
}

impl<'a> Body<'a> {
    /// An error at the current instance: at its line (ASCII) or for the file (binary).
    fn err(&self, message: impl Into<String>) -> MeshError {
        match self {
            Self::Ascii {
                tokens: Some(t), ..
            } => t.err(message),
            Self::Ascii { lines, .. } => MeshError::malformed(lines.path(), message),
            Self::Binary { path, .. } => MeshError::malformed(path, message),
        }
    }

    /// Line number of the current instance (ASCII).
    fn line(&self) -> Option<usize> {
        match self {
            Self::Ascii {
                tokens: Some(t), ..
            } => Some(t.line().no),
            _ => None,
        }
    }

    /// Advances past `n` bytes (binary).
    fn skip_bytes(&mut self, n: Option<usize>, what: &dyn Fn() -> String) -> Result<(), MeshError> {
        if let Self::Binary { data, pos, .. } = self {
            match n.and_then(|n| pos.checked_add(n)) {
                Some(end) if end <= data.len() => *pos = end,
                _ => return Err(self.truncated(what)),
            }
        }
        Ok(())
    }

    fn truncated(&self, what: &dyn Fn() -> String) -> MeshError {
        self.err(format!("the file ends inside {} (truncated file?)", what()))
    }

    fn value(&mut self, ty: StoredScalar, what: &dyn Fn() -> String) -> Result<f64, MeshError> {
        match self {
            Self::Ascii { tokens, .. } => {
                let t = tokens.as_mut().expect("an instance has been started");
                if ty.is_float() {
                    t.float("a property value")
                } else {
                    t.int("a property value").map(|v| v as f64)
                }
            }
            Self::Binary {
                data, pos, order, ..
            } => {
                let Some(bytes) = data.get(*pos..*pos + ty.size()) else {
                    return Err(self.truncated(what));
                };
                *pos += ty.size();
                Ok(ty.decode(bytes, *order))
            }
        }
    }

    /// Reads instance `i` of `element`: scalar values go to `scalars` (one slot per property),
    /// the items of list property `keep` go to `list`, other lists are skipped.
    fn instance(
        &mut self,
        element: &Element,
        i: usize,
        keep: Option<usize>,
        scalars: &mut [f64],
        list: &mut Vec<f64>,
    ) -> Result<(), MeshError> {
        let what = || format!("'{}' {i} of {}", element.name, element.count);
        if let Self::Ascii { lines, tokens } = self {
            *tokens = Some(lines.expect(&what())?.tokens());
        }
        for (k, property) in element.properties.iter().enumerate() {
            match property.kind {
                Kind::Scalar(ty) => scalars[k] = self.value(ty, &what)?,
                Kind::List { count, item } => {
                    let n = self.value(count, &what)?;
                    if n < 0.0 || n.fract() != 0.0 {
                        return Err(self.err(format!(
                            "{}: invalid list length {n} for '{}'",
                            what(),
                            property.name
                        )));
                    }
                    let n = n as usize;
                    if keep == Some(k) {
                        list.clear();
                        for _ in 0..n {
                            list.push(self.value(item, &what)?);
                        }
                    } else if matches!(self, Self::Binary { .. }) {
                        self.skip_bytes(n.checked_mul(item.size()), &what)?;
                    } else {
                        for _ in 0..n {
                            self.value(item, &what)?;
                        }
                    }
                }
            }
        }
        if let Self::Ascii {
            tokens: Some(t), ..
        } = self
        {
            t.end()?;
        }
        Ok(())
    }

    /// Skips all instances of `element`.
    fn skip(&mut self, element: &Element) -> Result<(), MeshError> {
        if element.properties.is_empty() {
            return Ok(());
        }
        if let (true, Some(size)) = (matches!(self, Self::Binary { .. }), element.fixed_size()) {
            let what = || format!("element '{}'", element.name);
            return self.skip_bytes(element.count.checked_mul(size), &what);
        }
        let mut scalars = vec![0.0; element.properties.len()];
        let mut list = Vec::new();
        (0..element.count)
            .try_for_each(|i| self.instance(element, i, None, &mut scalars, &mut list))
    }
}

type Parsed = (Vec<Point3<f64>>, Vec<[usize; 3]>);

/// Vertices and (if `faces`) triangles of the PLY data `data` read from `path`.
fn parse(path: &Path, data: &[u8], faces: bool) -> Result<Parsed, MeshError> {
    let header = parse_header(path, data)?;
    let text;
    let mut body = match header.big_endian {
        None => {
            text = decode(&data[header.body..]);
            Body::Ascii {
                lines: Lines::starting_at(path, &text, header.body_line, None),
                tokens: None,
            }
        }
        Some(big_endian) => Body::Binary {
            path,
            data,
            pos: header.body,
            order: ByteOrder::big_if(big_endian),
        },
    };
    // Each ASCII value takes at least two bytes (digit and separator).
    let available = match body {
        Body::Ascii { .. } => (data.len() - header.body) / 2,
        Body::Binary { .. } => data.len() - header.body,
    };
    let vertex_count = header
        .elements
        .iter()
        .find(|e| e.name == "vertex")
        .map_or(0, |e| e.count);
    let (mut vertices, mut triangles) = (None, None);
    for element in &header.elements {
        match element.name.as_str() {
            "vertex" if vertices.is_none() => {
                vertices = Some(read_vertices(path, &mut body, element, available)?);
            }
            "face" if faces && triangles.is_none() => {
                triangles = Some(read_faces(path, &mut body, element, vertex_count)?);
            }
            _ => body.skip(element)?,
        }
    }
    Ok((vertices.unwrap_or_default(), triangles.unwrap_or_default()))
}

fn read_vertices(
    path: &Path,
    body: &mut Body<'_>,
    element: &Element,
    available: usize,
) -> Result<Vec<Point3<f64>>, MeshError> {
    let [x, y, z] = ["x", "y", "z"].map(|c| element.scalar(c));
    let (Some(x), Some(y), Some(z)) = (x, y, z) else {
        return Err(element.err(path, "element 'vertex' lacks a scalar property x, y or z"));
    };
    let capacity = bounded_capacity(element.count, available, element.min_size().max(1));
    let mut vertices = Vec::with_capacity(capacity);
    let mut scalars = vec![0.0; element.properties.len()];
    let mut list = Vec::new();
    for i in 0..element.count {
        body.instance(element, i, None, &mut scalars, &mut list)?;
        let p = Point3::new(scalars[x], scalars[y], scalars[z]);
        if !is_finite_point(&p) {
            return Err(body.err(format!(
                "vertex {i} has a non-finite coordinate ({}, {}, {})",
                p.x, p.y, p.z
            )));
        }
        vertices.push(p);
    }
    Ok(vertices)
}

fn read_faces(
    path: &Path,
    body: &mut Body<'_>,
    element: &Element,
    vertex_count: usize,
) -> Result<Vec<[usize; 3]>, MeshError> {
    let Some(keep) = element.properties.iter().position(|p| {
        matches!(p.kind, Kind::List { .. }) && matches!(&*p.name, "vertex_indices" | "vertex_index")
    }) else {
        return Err(element.err(path, "element 'face' has no list property 'vertex_indices'"));
    };
    let mut triangles = Vec::new();
    let mut scalars = vec![0.0; element.properties.len()];
    let (mut list, mut poly) = (Vec::new(), Vec::new());
    for i in 0..element.count {
        body.instance(element, i, Some(keep), &mut scalars, &mut list)?;
        poly.clear();
        for &v in &list {
            if v.fract() != 0.0 {
                return Err(body.err(format!("face {i}: vertex index {v} is not an integer")));
            }
            if v < 0.0 || v >= vertex_count as f64 {
                return Err(MeshError::IndexOutOfRange {
                    path: path.into(),
                    line: body.line(),
                    index: v as i64,
                    count: vertex_count,
                });
            }
            poly.push(v as usize);
        }
        fan(&poly, &mut triangles, |m| {
            body.err(format!("face {i}: {m}"))
        })?;
    }
    Ok(triangles)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::fixtures::{
        assert_err, assert_robust, assert_same_surface, cube, octahedron, TempDir, CUBE_QUADS,
    };
    use crate::mesh::validate::validate;
    use std::io::Write as _;

    /// Appends `v` as PLY type `ty` in `encoding`.
    fn put(out: &mut Vec<u8>, encoding: &str, ty: &str, v: f64) {
        let big = encoding == "binary_big_endian";
        macro_rules! bytes {
            ($t:ty) => {{
                let x = v as $t;
                out.extend(if big {
                    x.to_be_bytes()
                } else {
                    x.to_le_bytes()
                })
            }};
        }
        if encoding == "ascii" {
            write!(out, "{v} ").unwrap();
            return;
        }
        match ty {
            "char" | "int8" => bytes!(i8),
            "uchar" | "uint8" => bytes!(u8),
            "short" | "int16" => bytes!(i16),
            "ushort" | "uint16" => bytes!(u16),
            "int" | "int32" => bytes!(i32),
            "uint" | "uint32" => bytes!(u32),
            "float" | "float32" => bytes!(f32),
            "double" | "float64" => bytes!(f64),
            _ => panic!("type {ty}"),
        }
    }

    fn end_instance(out: &mut Vec<u8>, encoding: &str) {
        if encoding == "ascii" {
            out.pop();
            out.push(b'\n');
        }
    }

    /// Writes `vertices` and `faces` as PLY with extra vertex properties (`uchar red` before x,
    /// `float nx` between x and y), an extra `material` element with a list between the vertices
    /// and the faces, extra face properties and an extra `edge` element at the end.
    fn write_ply(
        vertices: &[Point3<f64>],
        faces: &[&[usize]],
        encoding: &str,
        [coord, count, index]: [&str; 3],
    ) -> Vec<u8> {
        let mut out = format!(
            "ply\nformat {encoding} 1.0\ncomment written by the tests\nobj_info none\n\
             element vertex {}\nproperty uchar red\nproperty {coord} x\nproperty float nx\n\
             property {coord} y\nproperty {coord} z\n\
             element material 2\nproperty float shininess\nproperty list uchar int tags\n\
             element face {}\nproperty uchar flags\n\
             property list {count} {index} vertex_indices\nproperty float quality\n\
             element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n",
            vertices.len(),
            faces.len()
        )
        .into_bytes();
        for (i, p) in vertices.iter().enumerate() {
            put(&mut out, encoding, "uchar", (i % 256) as f64);
            put(&mut out, encoding, coord, p.x);
            put(&mut out, encoding, "float", 0.5);
            put(&mut out, encoding, coord, p.y);
            put(&mut out, encoding, coord, p.z);
            end_instance(&mut out, encoding);
        }
        for tags in [&[7.0][..], &[1.0, 2.0, 3.0]] {
            put(&mut out, encoding, "float", 0.25);
            put(&mut out, encoding, "uchar", tags.len() as f64);
            for &t in tags {
                put(&mut out, encoding, "int", t);
            }
            end_instance(&mut out, encoding);
        }
        for face in faces {
            put(&mut out, encoding, "uchar", 1.0);
            put(&mut out, encoding, count, face.len() as f64);
            for &i in *face {
                put(&mut out, encoding, index, i as f64);
            }
            put(&mut out, encoding, "float", -1.5);
            end_instance(&mut out, encoding);
        }
        put(&mut out, encoding, "int", 0.0);
        put(&mut out, encoding, "int", 1.0);
        end_instance(&mut out, encoding);
        out
    }

    fn write_surface(s: &TriSurface, encoding: &str, types: [&str; 3]) -> Vec<u8> {
        let faces: Vec<&[usize]> = s.triangles.iter().map(|t| &t[..]).collect();
        write_ply(&s.vertices, &faces, encoding, types)
    }

    const ENCODINGS: [&str; 3] = ["ascii", "binary_little_endian", "binary_big_endian"];

    #[test]
    fn round_trip_all_encodings_and_types() {
        let dir = TempDir::new("ply-rt");
        let list_types = [
            ["uchar", "int"],
            ["uint8", "uint32"],
            ["int", "ushort"],
            ["ushort", "uint"],
        ];
        let cases = [
            (
                cube(),
                &["int", "uchar", "short", "float", "double", "int8", "uint16"][..],
            ),
            (octahedron(), &["float", "double", "float32", "float64"][..]),
        ];
        let mut n = 0;
        for (mesh, coords) in &cases {
            for &coord in *coords {
                for encoding in ENCODINGS {
                    let [count, index] = list_types[n % list_types.len()];
                    n += 1;
                    let name = format!("m{n}-{coord}-{encoding}.ply");
                    let path =
                        dir.write(&name, write_surface(mesh, encoding, [coord, count, index]));
                    let back = read_ply(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
                    assert_eq!(&back, mesh, "{name}");
                    assert!(validate(&back).watertight, "{name}");
                    assert_eq!(read_ply_vertices(&path).unwrap(), mesh.vertices);
                }
            }
        }
        let back = read_ply(&dir.path("m1-int-ascii.ply")).unwrap();
        assert_eq!(back.signed_volume(), 1.0);
    }

    #[test]
    fn polygons_are_fan_triangulated() {
        let dir = TempDir::new("ply-quads");
        let quads: Vec<&[usize]> = CUBE_QUADS.iter().map(|q| &q[..]).collect();
        for encoding in ENCODINGS {
            let data = write_ply(
                &cube().vertices,
                &quads,
                encoding,
                ["double", "uchar", "int"],
            );
            let back = read_ply(&dir.write(&format!("quads-{encoding}.ply"), data)).unwrap();
            assert_same_surface(&back, &cube());
        }
    }

    #[test]
    fn corrupted_files_never_panic() {
        for encoding in ENCODINGS {
            let data = write_surface(&octahedron(), encoding, ["double", "uchar", "int"]);
            assert_robust("ply", &data, |p, d| parse(p, d, true));
            assert_robust("ply", &data, |p, d| parse(p, d, false));
        }
    }

    #[test]
    fn vertex_index_name_and_crlf_header_are_accepted() {
        let dir = TempDir::new("ply-crlf");
        let text = "ply\r\nformat ascii 1.0\r\nelement vertex 3\r\nproperty float32 x\r\n\
                    property float32 y\r\nproperty float32 z\r\nelement face 1\r\n\
                    property list uint8 int32 vertex_index\r\nend_header\r\n\
                    0 0 0\r\n1 0 0\r\n0 1 0\r\n3 0 1 2\r\n";
        let back = read_ply(&dir.write("crlf.ply", text)).unwrap();
        assert_eq!(back.triangles, vec![[0, 1, 2]]);
    }

    /// A small ASCII file: header lines 1-9, vertices on lines 10-12, the face on line 13.
    fn small(vertices: &str, face: &str) -> String {
        format!(
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
             property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
             end_header\n{vertices}{face}"
        )
    }

    #[test]
    fn bad_ascii_input_names_file_and_line() {
        let dir = TempDir::new("ply-bad");
        let v = "0 0 0\n1 0 0\n0 1 0\n";
        let cases: Vec<(&str, String, &[&str])> = vec![
            (
                "magic.ply",
                "plx\nformat ascii 1.0\n".into(),
                &[":1:", "not a PLY file", "'plx'"],
            ),
            (
                "noend.ply",
                "ply\nformat ascii 1.0\nelement vertex 3\n".into(),
                &["end_header"],
            ),
            (
                "type.ply",
                small(v, "3 0 1 2\n").replace("float y", "flaot y"),
                &[":5:", "'flaot'"],
            ),
            (
                "format.ply",
                small(v, "").replace("ascii 1.0", "binary_middle_endian 1.0"),
                &[":2:", "'binary_middle_endian'"],
            ),
            (
                "version.ply",
                small(v, "").replace("ascii 1.0", "ascii 2.0"),
                &["'2.0'"],
            ),
            (
                "nox.ply",
                small(v, "").replace("float x", "float u"),
                &[":3:", "x, y or z"],
            ),
            (
                "noformat.ply",
                small(v, "").replace("format ascii 1.0\n", ""),
                &[":8:", "format"],
            ),
            (
                "orphan.ply",
                "ply\nformat ascii 1.0\nproperty float x\nend_header\n".into(),
                &[":3:", "before any"],
            ),
            (
                "trunc.ply",
                small("0 0 0\n1 0 0\n", ""),
                &["truncated", "'vertex' 2 of 3"],
            ),
            ("noface.ply", small(v, ""), &["truncated", "'face' 0 of 1"]),
            (
                "range.ply",
                small(v, "3 0 1 5\n"),
                &[
                    ":13:",
                    "face index 5 out of range (the file has 3 vertices)",
                ],
            ),
            (
                "negative.ply",
                small(v, "3 0 -1 2\n"),
                &[":13:", "face index -1"],
            ),
            (
                "nan.ply",
                small("0 0 0\n1 nan 0\n0 1 0\n", "3 0 1 2\n"),
                &[":11:", "non-finite"],
            ),
            (
                "word.ply",
                small("0 0 0\n1 0 0\n0 one 0\n", "3 0 1 2\n"),
                &[":12:", "'one'"],
            ),
            (
                "extra.ply",
                small("0 0 0 9\n1 0 0\n0 1 0\n", "3 0 1 2\n"),
                &[":10:", "extra value '9'"],
            ),
            ("short.ply", small(v, "3 0 1\n"), &[":13:", "end of line"]),
            ("two.ply", small(v, "2 0 1\n"), &[":13:", "at least 3"]),
            ("intcoord.ply", small(v, "3 0 1 2.5\n"), &[":13:", "'2.5'"]),
            (
                "noindex.ply",
                small(v, "3 0 1 2\n").replace("vertex_indices", "corners"),
                &[":7:", "vertex_indices"],
            ),
            (
                "huge.ply",
                small(v, "3 0 1 2\n").replace("vertex 3", "vertex 4000000000"),
                &[":13:", "extra value"],
            ),
            (
                "hugeface.ply",
                small(v, "3 0 1 2\n").replace("face 1", "face 4000000000"),
                &["truncated", "'face' 1 of 4000000000"],
            ),
            (
                "empty.ply",
                small(v, "").replace("face 1", "face 0"),
                &["no triangles"],
            ),
        ];
        for (name, text, parts) in &cases {
            let path = dir.write(name, text);
            assert_err(read_ply(&path), &path, parts);
        }
        let path = dir.write("garbage.ply", [0x00, 0xff, 0x13, 0x80, b'\n', 0xfe]);
        assert_err(read_ply(&path), &path, &[":1:", "not a PLY file"]);
        let path = dir.write("void.ply", "");
        assert_err(read_ply(&path), &path, &["end_header"]);
    }

    #[test]
    fn bad_binary_input_names_file() {
        let dir = TempDir::new("ply-badbin");
        let types = ["float", "uchar", "int"];
        for encoding in &ENCODINGS[1..] {
            let good = write_surface(&cube(), encoding, types);
            let body = good.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;

            let path = dir.write("trunc.ply", &good[..good.len() - 3]);
            assert_err(read_ply(&path), &path, &["truncated", "edge"]);
            let path = dir.write("trunc-face.ply", &good[..good.len() - 40]);
            assert_err(read_ply(&path), &path, &["truncated", "'face'"]);

            // x of vertex 2: after 2 vertices of 17 bytes and the red byte.
            let mut nan = good.clone();
            let at = body + 2 * 17 + 1;
            let bits = f32::NAN.to_bits() as i32;
            put_index(&mut nan[at..at + 4], encoding, bits);
            let path = dir.write("nan.ply", nan);
            assert_err(read_ply(&path), &path, &["vertex 2", "non-finite"]);

            // First index of the first face, after the vertices, the materials (4+1+4 and
            // 4+1+12 bytes), the flags and the list count.
            let mut range = good.clone();
            let at = body + 8 * 17 + 9 + 17 + 2;
            put_index(&mut range[at..at + 4], encoding, 8);
            let path = dir.write("range.ply", &range);
            let msg = assert_err(
                read_ply(&path),
                &path,
                &["face index 8 out of range (the file has 8 vertices)"],
            );
            assert!(
                msg.contains("range.ply: face index"),
                "no line number: {msg}"
            );
            put_index(&mut range[at..at + 4], encoding, -3);
            let path = dir.write("negative.ply", &range);
            assert_err(read_ply(&path), &path, &["face index -3"]);

            // A huge vertex count with a short body fails without allocating for it.
            let text =
                String::from_utf8_lossy(&good[..body]).replace("vertex 8", "vertex 4000000000");
            let mut huge = text.into_bytes();
            huge.extend(&good[body..]);
            let path = dir.write("huge.ply", huge);
            assert_err(read_ply(&path), &path, &["truncated"]);
            assert_err(read_ply_vertices(&path), &path, &["truncated"]);
        }
    }

    /// Overwrites 4 bytes with `v` in the byte order of `encoding`.
    fn put_index(slot: &mut [u8], encoding: &str, v: i32) {
        let b = if *encoding == *"binary_big_endian" {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        };
        slot.copy_from_slice(&b);
    }
}
