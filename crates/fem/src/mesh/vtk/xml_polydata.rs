//! A reader of VTK XML PolyData (`.vtp`) files, written for livereg rather than taken from
//! `vtkio`, whose reader panics on the empty compressed arrays VTK writes by default and
//! sizes its buffers from unchecked headers. Every size read from a file is checked against
//! the bytes actually there before anything is allocated.
//!
//! Supported, as VTK writes them (VTK file format documentation, "XML File Formats"):
//! `format="ascii"`, `"binary"` (base64, inline) and `"appended"` (`<AppendedData
//! encoding="raw">` or `"base64"`), `header_type` `UInt32` (default) or `UInt64`, no
//! compression or `vtkZLibDataCompressor` (blocked zlib), either byte order, and every
//! integer and float array type.

use std::path::Path;

use base64::Engine;
use nalgebra::Point3;
use quick_xml::events::{BytesEnd, BytesStart, BytesText, Event};
use quick_xml::Reader;

use super::super::error::MeshError;
use super::super::finite_points::is_finite_point;
use crate::stored_scalar::{ByteOrder, StoredScalar};

/// The surface cells of one piece: polygons and triangle strips as point-index lists.
#[derive(Debug, Default)]
pub(super) struct XmlPiece {
    /// Point positions, file units.
    pub points: Vec<Point3<f64>>,
    /// Polygons (`Polys`).
    pub polys: Vec<Vec<usize>>,
    /// Triangle strips (`Strips`).
    pub strips: Vec<Vec<usize>>,
}

/// How the file encodes binary data.
#[derive(Debug, Clone, Copy)]
struct Encoding {
    order: ByteOrder,
    /// Bytes of a header word: 4 (`UInt32`) or 8 (`UInt64`).
    header_bytes: usize,
    zlib: bool,
}

/// A `DataArray` element as declared (its data decoded later).
#[derive(Debug, Clone)]
struct ArrayDecl {
    name: String,
    scalar: StoredScalar,
    components: usize,
    format: Format,
    /// Inline text (ascii or base64).
    text: String,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Format {
    Ascii,
    Binary,
    /// Appended at this offset (bytes for raw data, characters for base64).
    Appended(usize),
}

/// The number type a VTK `DataArray`'s `type` attribute names.
fn vtk_scalar(name: &str) -> Option<StoredScalar> {
    Some(match name {
        "Int8" | "Char" => StoredScalar::I8,
        "UInt8" | "UChar" => StoredScalar::U8,
        "Int16" => StoredScalar::I16,
        "UInt16" => StoredScalar::U16,
        "Int32" => StoredScalar::I32,
        "UInt32" => StoredScalar::U32,
        "Int64" | "IdType" => StoredScalar::I64,
        "UInt64" => StoredScalar::U64,
        "Float32" => StoredScalar::F32,
        "Float64" => StoredScalar::F64,
        _ => return None,
    })
}

/// Which section of a piece the parser is in.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Section {
    Other,
    Points,
    Polys,
    Strips,
}

/// Parses a `.vtp` file's content into its pieces.
pub(super) fn parse_xml_polydata(path: &Path, bytes: &[u8]) -> Result<Vec<XmlPiece>, MeshError> {
    let bad = |m: String| MeshError::malformed(path, m);
    // Raw appended data is not XML: cut it off before parsing the rest.
    let (xml, appended) = split_appended(path, bytes)?;
    let walk = walk_xml(path, xml)?;
    let encoding = walk
        .encoding
        .ok_or_else(|| bad("no <VTKFile> element: not a VTK XML file".into()))?;
    let mut out = Vec::with_capacity(walk.pieces.len());
    for (piece, arrays) in walk.pieces {
        out.push(decode_piece(path, piece, arrays, encoding, &appended)?);
    }
    if out.is_empty() {
        return Err(bad("no <Piece> element: not a PolyData file".into()));
    }
    Ok(out)
}

/// A piece as declared: its (still empty) cells and the arrays of its read sections.
type DeclaredPiece = (XmlPiece, Vec<(Section, ArrayDecl)>);

/// What the walk through the XML elements has found so far.
struct Walk {
    /// The binary encoding of `<VTKFile>`, once seen.
    encoding: Option<Encoding>,
    /// The pieces, in file order.
    pieces: Vec<DeclaredPiece>,
    /// The section of the current piece.
    section: Section,
    /// The `<DataArray>` whose text is being read.
    current: Option<ArrayDecl>,
    /// Depth of the elements nested in the current `<DataArray>`.
    inner: usize,
}

/// Walks the XML events of `xml`, collecting the file's encoding and each piece's declared
/// arrays with their inline text.
fn walk_xml(path: &Path, xml: &[u8]) -> Result<Walk, MeshError> {
    let mut reader = Reader::from_reader(xml);
    reader.config_mut().check_end_names = false;
    let mut walk = Walk {
        encoding: None,
        pieces: Vec::new(),
        section: Section::Other,
        current: None,
        inner: 0,
    };
    let mut buf = Vec::new();
    loop {
        let event = reader.read_event_into(&mut buf).map_err(|e| {
            MeshError::malformed(
                path,
                format!("XML error near byte {}: {e}", reader.error_position()),
            )
        })?;
        if walk.nested(&event) {
            buf.clear();
            continue;
        }
        match &event {
            Event::Start(e) => walk.start(path, e, false)?,
            Event::Empty(e) => walk.start(path, e, true)?,
            Event::Text(t) => walk.text(path, t)?,
            Event::End(e) => walk.end(e),
            Event::Eof => break,
            _ => {}
        }
        buf.clear();
    }
    Ok(walk)
}

impl Walk {
    /// Whether `event` belongs to an element nested in the current `<DataArray>` (VTK's
    /// `<InformationKey>` range notes), which is skipped; tracks the nesting depth.
    fn nested(&mut self, event: &Event<'_>) -> bool {
        if self.current.is_none() {
            return false;
        }
        match event {
            Event::Start(_) => {
                self.inner += 1;
                true
            }
            Event::End(_) if self.inner > 0 => {
                self.inner -= 1;
                true
            }
            // The end of the file ends the walk, however deep it stops.
            Event::Eof => false,
            _ => self.inner > 0,
        }
    }

    /// Handles the start tag `e` (`empty` for a self-closing element): the file's encoding, a
    /// new piece, a section, or a `<DataArray>` declaration.
    fn start(&mut self, path: &Path, e: &BytesStart<'_>, empty: bool) -> Result<(), MeshError> {
        match e.local_name().as_ref() {
            b"VTKFile" => self.encoding = Some(file_encoding(path, e)?),
            b"Piece" => self.pieces.push((XmlPiece::default(), Vec::new())),
            b"Points" if !empty => self.section = Section::Points,
            b"Polys" if !empty => self.section = Section::Polys,
            b"Strips" if !empty => self.section = Section::Strips,
            b"DataArray" => {
                let decl = array_decl(path, e)?;
                if empty {
                    keep(&mut self.pieces, self.section, decl);
                } else {
                    self.current = Some(decl);
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// Appends text `t`, unescaped, to the current `<DataArray>`'s text, if any.
    fn text(&mut self, path: &Path, t: &BytesText<'_>) -> Result<(), MeshError> {
        if let Some(decl) = self.current.as_mut() {
            let text = t.unescape().map_err(|e| {
                MeshError::malformed(path, format!("XML text of {:?}: {e}", decl.name))
            })?;
            decl.text.push_str(&text);
        }
        Ok(())
    }

    /// Handles the end tag `e`: keeps the finished `<DataArray>`, or leaves a section.
    fn end(&mut self, e: &BytesEnd<'_>) {
        match e.local_name().as_ref() {
            b"DataArray" => {
                if let Some(decl) = self.current.take() {
                    keep(&mut self.pieces, self.section, decl);
                }
            }
            b"Points" | b"Polys" | b"Strips" => self.section = Section::Other,
            _ => {}
        }
    }
}

/// Decodes the declared `arrays` of `piece`: its points, and its polygons and strips from
/// their connectivity and offsets arrays.
fn decode_piece(
    path: &Path,
    mut piece: XmlPiece,
    arrays: Vec<(Section, ArrayDecl)>,
    encoding: Encoding,
    appended: &Appended<'_>,
) -> Result<XmlPiece, MeshError> {
    let mut conn = [None, None];
    let mut offs = [None, None];
    for (section, decl) in arrays {
        let values = decode(path, &decl, encoding, appended)?;
        match section {
            Section::Points => piece.points = points_of(path, &decl, &values)?,
            Section::Polys | Section::Strips => {
                let k = usize::from(section == Section::Strips);
                match decl.name.as_str() {
                    "connectivity" => conn[k] = Some(values),
                    "offsets" => offs[k] = Some(values),
                    _ => {}
                }
            }
            Section::Other => {}
        }
    }
    for (k, what) in [(0, "Polys"), (1, "Strips")] {
        let cells = match (conn[k].take(), offs[k].take()) {
            (Some(c), Some(o)) => cells(path, what, &c, &o)?,
            (None, None) => Vec::new(),
            _ => {
                return Err(MeshError::malformed(
                    path,
                    format!("{what} needs both a connectivity and an offsets array"),
                ))
            }
        };
        if k == 0 {
            piece.polys = cells;
        } else {
            piece.strips = cells;
        }
    }
    Ok(piece)
}

/// The points of the points array `decl` with `values` (x y z triples, file units), each
/// finite.
fn points_of(path: &Path, decl: &ArrayDecl, values: &[f64]) -> Result<Vec<Point3<f64>>, MeshError> {
    if decl.components != 3 || !values.len().is_multiple_of(3) {
        return Err(MeshError::malformed(
            path,
            format!(
                "the points array {:?} has {} components and {} values (expected x y z)",
                decl.name,
                decl.components,
                values.len()
            ),
        ));
    }
    finite_points(path, values)
}

/// Keeps `decl` for the current piece when it belongs to a section that is read.
fn keep(pieces: &mut [DeclaredPiece], section: Section, decl: ArrayDecl) {
    if let (Some((_, arrays)), true) = (pieces.last_mut(), section != Section::Other) {
        arrays.push((section, decl));
    }
}

/// The `<AppendedData>` section: its bytes after the `_` marker and their encoding.
#[derive(Debug, Clone, Copy, Default)]
struct Appended<'a> {
    data: &'a [u8],
    base64: bool,
}

/// The XML part of the file, and the appended data (empty when there is none).
fn split_appended<'a>(path: &Path, bytes: &'a [u8]) -> Result<(&'a [u8], Appended<'a>), MeshError> {
    let Some(at) = find(bytes, b"<AppendedData") else {
        return Ok((bytes, Appended::default()));
    };
    let rest = &bytes[at..];
    let underscore = rest
        .iter()
        .position(|&b| b == b'_')
        .ok_or_else(|| MeshError::malformed(path, "<AppendedData> without its '_' marker"))?;
    let tag = String::from_utf8_lossy(&rest[..underscore]);
    let base64 = if tag.contains("\"base64\"") {
        true
    } else if tag.contains("\"raw\"") {
        false
    } else {
        return Err(MeshError::malformed(
            path,
            "<AppendedData> has no encoding=\"raw\" or \"base64\"",
        ));
    };
    let data = &rest[underscore + 1..];
    // The data ends at the last closing tag (raw data may contain anything, even '<').
    let end = rfind(data, b"</AppendedData>").unwrap_or(data.len());
    Ok((
        &bytes[..at],
        Appended {
            data: &data[..end],
            base64,
        },
    ))
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

fn rfind(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).rposition(|w| w == needle)
}

/// The value of attribute `name` of `e`, if present.
fn attr(path: &Path, e: &BytesStart<'_>, name: &str) -> Result<Option<String>, MeshError> {
    match e.try_get_attribute(name) {
        Ok(Some(a)) => a
            .unescape_value()
            .map(|v| Some(v.trim().to_string()))
            .map_err(|err| MeshError::malformed(path, format!("attribute {name}: {err}"))),
        Ok(None) => Ok(None),
        Err(err) => Err(MeshError::malformed(
            path,
            format!("attribute {name}: {err}"),
        )),
    }
}

/// The binary encoding the `<VTKFile>` element declares.
fn file_encoding(path: &Path, e: &BytesStart<'_>) -> Result<Encoding, MeshError> {
    let ty = attr(path, e, "type")?.unwrap_or_default();
    if ty != "PolyData" {
        return Err(MeshError::unsupported(
            path,
            format!("a VTK XML {ty:?} file holds no PolyData (expected type=\"PolyData\")"),
        ));
    }
    let order = match attr(path, e, "byte_order")?.as_deref() {
        None | Some("LittleEndian") => ByteOrder::Little,
        Some("BigEndian") => ByteOrder::Big,
        Some(other) => {
            return Err(MeshError::malformed(
                path,
                format!("unknown byte_order {other:?}"),
            ))
        }
    };
    let header_bytes = match attr(path, e, "header_type")?.as_deref() {
        None | Some("UInt32") => 4,
        Some("UInt64") => 8,
        Some(other) => {
            return Err(MeshError::malformed(
                path,
                format!("unknown header_type {other:?}"),
            ))
        }
    };
    let zlib = match attr(path, e, "compressor")?.as_deref() {
        None | Some("") => false,
        Some("vtkZLibDataCompressor") => true,
        Some(other) => {
            return Err(MeshError::unsupported(
                path,
                format!(
                    "compressor {other:?} is not read (only vtkZLibDataCompressor); \
                     save without compression or with zlib"
                ),
            ))
        }
    };
    Ok(Encoding {
        order,
        header_bytes,
        zlib,
    })
}

/// A `<DataArray>`'s declaration.
fn array_decl(path: &Path, e: &BytesStart<'_>) -> Result<ArrayDecl, MeshError> {
    let name = attr(path, e, "Name")?.unwrap_or_default();
    let ty = attr(path, e, "type")?.unwrap_or_default();
    let scalar = vtk_scalar(&ty).ok_or_else(|| {
        MeshError::malformed(path, format!("DataArray {name:?}: unknown type {ty:?}"))
    })?;
    let components = match attr(path, e, "NumberOfComponents")? {
        None => 1,
        Some(c) => c
            .parse::<usize>()
            .ok()
            .filter(|&c| (1..=64).contains(&c))
            .ok_or_else(|| {
                MeshError::malformed(
                    path,
                    format!("DataArray {name:?}: NumberOfComponents {c:?}"),
                )
            })?,
    };
    let format = match attr(path, e, "format")?.as_deref() {
        Some("ascii") => Format::Ascii,
        Some("binary") => Format::Binary,
        Some("appended") => {
            let offset = attr(path, e, "offset")?
                .and_then(|o| o.parse::<usize>().ok())
                .ok_or_else(|| {
                    MeshError::malformed(
                        path,
                        format!("DataArray {name:?}: appended without a valid offset"),
                    )
                })?;
            Format::Appended(offset)
        }
        other => {
            return Err(MeshError::malformed(
                path,
                format!(
                    "DataArray {name:?}: unknown format {:?}",
                    other.unwrap_or_default()
                ),
            ))
        }
    };
    Ok(ArrayDecl {
        name,
        scalar,
        components,
        format,
        text: String::new(),
    })
}

/// The values of an array, as f64.
fn decode(
    path: &Path,
    decl: &ArrayDecl,
    enc: Encoding,
    appended: &Appended<'_>,
) -> Result<Vec<f64>, MeshError> {
    let bad = |m: String| MeshError::malformed(path, format!("DataArray {:?}: {m}", decl.name));
    let raw = match decl.format {
        Format::Ascii => {
            return decl
                .text
                .split_ascii_whitespace()
                .map(|t| {
                    t.parse::<f64>()
                        .map_err(|_| bad(format!("{t:?} is not a number")))
                })
                .collect();
        }
        Format::Binary => {
            read_block(&mut Base64Source::new(decl.text.as_bytes()), enc).map_err(bad)?
        }
        Format::Appended(offset) => {
            let data = appended
                .data
                .get(offset..)
                .ok_or_else(|| bad(format!("offset {offset} is past the appended data")))?;
            if appended.base64 {
                read_block(&mut Base64Source::new(data), enc).map_err(bad)?
            } else {
                read_block(&mut RawSource { data }, enc).map_err(bad)?
            }
        }
    };
    let size = decl.scalar.size();
    if raw.len() % size != 0 {
        return Err(bad(format!(
            "{} bytes is not a whole number of {size}-byte values",
            raw.len()
        )));
    }
    Ok(raw
        .chunks_exact(size)
        .map(|b| decl.scalar.decode(b, enc.order))
        .collect())
}

/// Bytes of a binary data block, taken in order.
trait Source {
    /// The next `n` bytes, or an error when fewer remain.
    fn take(&mut self, n: usize) -> Result<Vec<u8>, String>;
    /// The most bytes that can remain (a bound checked before trusting a header).
    fn max_remaining(&self) -> usize;
}

/// Raw appended bytes.
struct RawSource<'a> {
    data: &'a [u8],
}

impl Source for RawSource<'_> {
    fn take(&mut self, n: usize) -> Result<Vec<u8>, String> {
        if n > self.data.len() {
            return Err(format!("{n} bytes announced, {} left", self.data.len()));
        }
        let (head, rest) = self.data.split_at(n);
        self.data = rest;
        Ok(head.to_vec())
    }
    fn max_remaining(&self) -> usize {
        self.data.len()
    }
}

/// Base64 text decoded four characters at a time, so that the header and the data decode
/// alike whether VTK encoded them as one stream or as two (each with its own `=` padding).
struct Base64Source<'a> {
    text: &'a [u8],
    decoded: Vec<u8>,
}

impl<'a> Base64Source<'a> {
    fn new(text: &'a [u8]) -> Self {
        Self {
            text,
            decoded: Vec::new(),
        }
    }
}

impl Source for Base64Source<'_> {
    fn take(&mut self, n: usize) -> Result<Vec<u8>, String> {
        if n > self.max_remaining() {
            return Err(format!(
                "{n} bytes announced, at most {} left",
                self.max_remaining()
            ));
        }
        let mut group = [0u8; 4];
        while self.decoded.len() < n {
            let mut k = 0;
            while k < 4 {
                let (&c, rest) = self
                    .text
                    .split_first()
                    .ok_or_else(|| format!("base64 data ends before the {n} bytes announced"))?;
                self.text = rest;
                if !c.is_ascii_whitespace() {
                    group[k] = c;
                    k += 1;
                }
            }
            let bytes = base64::engine::general_purpose::STANDARD
                .decode(group)
                .map_err(|e| format!("bad base64: {e}"))?;
            self.decoded.extend_from_slice(&bytes);
        }
        let rest = self.decoded.split_off(n);
        Ok(std::mem::replace(&mut self.decoded, rest))
    }
    fn max_remaining(&self) -> usize {
        self.decoded.len() + self.text.len() / 4 * 3
    }
}

/// The largest uncompressed array read (bytes): far above any surface, far below memory.
const MAX_ARRAY_BYTES: usize = 1 << 31;

/// A header word.
fn word(b: &[u8], enc: Encoding) -> usize {
    let v = if enc.header_bytes == 8 {
        let a: [u8; 8] = b.try_into().expect("8 bytes");
        match enc.order {
            ByteOrder::Little => u64::from_le_bytes(a),
            ByteOrder::Big => u64::from_be_bytes(a),
        }
    } else {
        let a: [u8; 4] = b.try_into().expect("4 bytes");
        u64::from(match enc.order {
            ByteOrder::Little => u32::from_le_bytes(a),
            ByteOrder::Big => u32::from_be_bytes(a),
        })
    };
    usize::try_from(v).unwrap_or(usize::MAX)
}

/// One array's bytes: a header (the byte count; or, compressed, the block count, block
/// size, last block size and each block's compressed size) and the data it announces.
fn read_block(src: &mut dyn Source, enc: Encoding) -> Result<Vec<u8>, String> {
    let hb = enc.header_bytes;
    if !enc.zlib {
        let n = word(&src.take(hb)?, enc);
        if n > MAX_ARRAY_BYTES {
            return Err(format!("{n} bytes announced (more than {MAX_ARRAY_BYTES})"));
        }
        return src.take(n);
    }
    let head = src.take(3 * hb)?;
    let (blocks, block_size, last) = (
        word(&head[..hb], enc),
        word(&head[hb..2 * hb], enc),
        word(&head[2 * hb..], enc),
    );
    if blocks == 0 {
        return Ok(Vec::new());
    }
    if blocks > src.max_remaining() / hb {
        return Err(format!(
            "{blocks} compressed blocks announced; the data is shorter"
        ));
    }
    let total = if last == 0 {
        block_size.checked_mul(blocks)
    } else {
        block_size
            .checked_mul(blocks - 1)
            .and_then(|t| t.checked_add(last))
    }
    .filter(|&t| t <= MAX_ARRAY_BYTES && last <= block_size)
    .ok_or_else(|| {
        format!("compressed header: {blocks} blocks of {block_size} bytes, last {last}: too large")
    })?;
    let sizes: Vec<usize> = src
        .take(blocks * hb)?
        .chunks_exact(hb)
        .map(|b| word(b, enc))
        .collect();
    let mut out = Vec::with_capacity(total.min(src.max_remaining().saturating_mul(1032)));
    for (k, &size) in sizes.iter().enumerate() {
        let expect = if k + 1 == blocks && last != 0 {
            last
        } else {
            block_size
        };
        let compressed = src.take(size)?;
        let before = out.len();
        let mut z = flate2::read::ZlibDecoder::new(&compressed[..]);
        std::io::Read::read_to_end(
            &mut std::io::Read::take(&mut z, expect as u64 + 1),
            &mut out,
        )
        .map_err(|e| format!("zlib block {k}: {e}"))?;
        if out.len() - before != expect {
            return Err(format!(
                "zlib block {k} holds {} bytes, the header says {expect}",
                out.len() - before
            ));
        }
    }
    Ok(out)
}

/// Triples of `values` as finite points (an error names the first point that is not).
pub(super) fn finite_points(path: &Path, values: &[f64]) -> Result<Vec<Point3<f64>>, MeshError> {
    values
        .chunks_exact(3)
        .enumerate()
        .map(|(i, c)| {
            let p = Point3::new(c[0], c[1], c[2]);
            if is_finite_point(&p) {
                Ok(p)
            } else {
                Err(MeshError::malformed(
                    path,
                    format!("point {i} has a non-finite coordinate: {p:?}"),
                ))
            }
        })
        .collect()
}

/// Cells from a connectivity and an offsets array (each offset the end of a cell; a leading
/// 0, as some writers put, is skipped).
fn cells(
    path: &Path,
    what: &str,
    conn: &[f64],
    offsets: &[f64],
) -> Result<Vec<Vec<usize>>, MeshError> {
    let bad = |m: String| MeshError::malformed(path, format!("{what}: {m}"));
    let index = |v: f64| -> Option<usize> {
        (v >= 0.0 && v.fract() == 0.0 && v < usize::MAX as f64).then_some(v as usize)
    };
    let skip = usize::from(offsets.len() > 1 && offsets[0] == 0.0);
    let mut start = 0usize;
    let mut out = Vec::with_capacity(offsets.len());
    for (c, &end) in offsets.iter().enumerate().skip(skip) {
        let end = index(end).ok_or_else(|| bad(format!("offset {c} is {end}")))?;
        let cell = conn
            .get(start..end)
            .ok_or_else(|| bad(format!("cell {c} ends at {end}, outside 0..{}", conn.len())))?;
        let cell = cell
            .iter()
            .map(|&v| index(v).ok_or_else(|| bad(format!("cell {c} has point index {v}"))))
            .collect::<Result<Vec<_>, _>>()?;
        out.push(cell);
        start = end;
    }
    Ok(out)
}
