//! NRRD labelmaps (`.nrrd`, 3D Slicer's `.seg.nrrd`): a small reader of the attached-data subset
//! of the format (no maintained Rust crate exists).
//!
//! Read: magic `NRRD0001`–`NRRD0005`; `type` (every integer type, `float`, `double`);
//! `dimension` 3, or 4 with a leading `list` axis (multi-layer `.seg.nrrd`: one labelmap per
//! layer, see [`read_nrrd_layers`]); `sizes`; `encoding` `raw`, `gzip` and `ascii`; `endian`;
//! `space` (`left-posterior-superior`/`LPS`, `right-anterior-superior`/`RAS`,
//! `left-anterior-superior`/`LAS`), `space dimension`, `space directions`, `space origin`,
//! `space units` (mm, cm, m, um); `spacings` when there are no space directions (then the file's
//! axes are taken as LPS with the origin at voxel 0); `kinds`; `line skip`, `byte skip`; and
//! Slicer's segment key/values `SegmentN_Name`, `SegmentN_LabelValue` (1 when absent, as in
//! Slicer's older one-segment-per-layer files) and `SegmentN_Layer` (0 when absent).
//!
//! Refused with an error naming the field: detached data (`data file`), `bzip2` and `hex`
//! encodings, `block` type, non-anatomical spaces (`scanner-xyz`, `3D-right-handed`, …), a list
//! axis elsewhere than first, sizes over [`MAX_VOXELS`](super::labelmap::MAX_VOXELS) or larger
//! than the data present.

use std::io::{BufRead, Read};
use std::path::Path;

use flate2::read::MultiGzDecoder;
use nalgebra::{Matrix4, Vector3};

use super::error::SegmentationError;
use super::labelmap::{voxel_count, Labelmap, Segment, MAX_VOXELS};
use super::samples::{ascii_to_labels, to_labels};
use crate::stored_scalar::{ByteOrder, StoredScalar};

/// Longest header accepted (bytes).
const MAX_HEADER: usize = 1 << 20;

/// Reads a single-layer NRRD labelmap (3-D, or 4-D with a list axis of size 1). A file with
/// several layers is refused with an error saying how many: read it with
/// [`read_nrrd_layers`].
pub fn read_nrrd(path: &Path) -> Result<Labelmap, SegmentationError> {
    single_layer(path, read_nrrd_layers(path)?)
}

/// The one layer of `layers` read from `path`, or an error saying how many there are.
pub(crate) fn single_layer(
    path: &Path,
    mut layers: Vec<Labelmap>,
) -> Result<Labelmap, SegmentationError> {
    if layers.len() != 1 {
        return Err(SegmentationError::unsupported(
            path,
            format!(
                "the file has {} layers (overlapping segments); read it with read_nrrd_layers, \
                 which gives one labelmap per layer",
                layers.len()
            ),
        ));
    }
    Ok(layers.pop().unwrap())
}

/// Reads every layer of a NRRD labelmap: one [`Labelmap`] per layer (a 3-D file has one),
/// each with the segments whose `SegmentN_Layer` is that layer.
pub fn read_nrrd_layers(path: &Path) -> Result<Vec<Labelmap>, SegmentationError> {
    let bytes = std::fs::read(path).map_err(|e| SegmentationError::io(path, e))?;
    read_nrrd_layers_bytes(path, &bytes)
}

/// [`read_nrrd_layers`] of a file's bytes already in memory; `path` names it in errors.
pub fn read_nrrd_layers_bytes(
    path: &Path,
    file: &[u8],
) -> Result<Vec<Labelmap>, SegmentationError> {
    let mut reader: &[u8] = file;
    let header = Header::read(path, &mut reader)?;
    let layout = header.layout(path)?;
    let encoding = header.encoding(path)?;
    let order = header.byte_order(path, &layout, encoding)?;
    let line_skip = header.integer(path, "line skip", 0)?;
    let byte_skip = header.integer(path, "byte skip", 0)?;
    skip_lines(path, &mut reader, line_skip)?;
    let values = match encoding {
        Encoding::Raw | Encoding::Gzip => {
            check_byte_skip(path, byte_skip, encoding)?;
            if encoding == Encoding::Raw {
                raw_samples(path, file, reader, byte_skip, &layout, order)?
            } else {
                gzip_samples(path, reader, byte_skip, &layout, order)?
            }
        }
        Encoding::Ascii => ascii_samples(path, reader, &layout)?,
    };
    let segments = header.segments(path)?;
    check_segment_layers(path, &segments, layout.layers)?;
    let per_layer = split_layers(values, layout.layers);
    layer_labelmaps(path, per_layer, &segments, &layout)
}

/// Skips the `line skip` lines that precede the data, advancing `reader` past them; errors
/// when the count is negative or the file has fewer lines.
fn skip_lines(path: &Path, reader: &mut &[u8], line_skip: i64) -> Result<(), SegmentationError> {
    if line_skip < 0 {
        return Err(SegmentationError::header(
            path,
            "line skip",
            format!("{line_skip} (must be ≥ 0)"),
        ));
    }
    for skipped in 0..line_skip {
        let mut sink = Vec::new();
        let n = reader
            .by_ref()
            .take(MAX_HEADER as u64)
            .read_until(b'\n', &mut sink)
            .map_err(|e| SegmentationError::io(path, e))?;
        if n == 0 {
            return Err(SegmentationError::header(
                path,
                "line skip",
                format!("{line_skip}, but the file ends after {skipped} lines"),
            ));
        }
    }
    Ok(())
}

/// Checks `byte skip` for binary (raw or gzip) data: ≥ 0, or −1 (data at the end of the file)
/// with raw encoding only.
fn check_byte_skip(
    path: &Path,
    byte_skip: i64,
    encoding: Encoding,
) -> Result<(), SegmentationError> {
    if byte_skip < -1 || (byte_skip == -1 && encoding != Encoding::Raw) {
        return Err(SegmentationError::header(
            path,
            "byte skip",
            format!("{byte_skip} (−1 is only meaningful with raw encoding)"),
        ));
    }
    Ok(())
}

/// The labels of raw data, converted straight from the file's bytes without a copy: `data`
/// is what follows the header (and skipped lines), `byte_skip` bytes further on, or the last
/// bytes of the file when `byte_skip` is −1.
fn raw_samples(
    path: &Path,
    file: &[u8],
    data: &[u8],
    byte_skip: i64,
    layout: &Layout,
    order: ByteOrder,
) -> Result<Vec<u16>, SegmentationError> {
    let bytes_needed = layout.bytes_needed();
    let start = if byte_skip == -1 {
        // At the very end of the file.
        (file.len() as u64).checked_sub(bytes_needed as u64)
    } else {
        let header_len = (file.len() - data.len()) as u64;
        Some(header_len + byte_skip as u64)
    };
    let samples = start
        .and_then(|s| file.get(s as usize..)?.get(..bytes_needed))
        .ok_or_else(|| {
            let available = start.map_or(0, |s| file.len().saturating_sub(s as usize));
            short(path, available, bytes_needed, layout)
        })?;
    to_labels(path, samples, layout.ty, order, None, layout.all_dims())
}

/// The labels of gzip-compressed `data`, after skipping `byte_skip` decompressed bytes.
fn gzip_samples(
    path: &Path,
    data: &[u8],
    byte_skip: i64,
    layout: &Layout,
    order: ByteOrder,
) -> Result<Vec<u16>, SegmentationError> {
    let bytes_needed = layout.bytes_needed();
    let mut data = MultiGzDecoder::new(data);
    if byte_skip > 0 {
        std::io::copy(
            &mut (&mut data).take(byte_skip as u64),
            &mut std::io::sink(),
        )
        .map_err(|e| SegmentationError::data(path, format!("cannot decode: {e}")))?;
    }
    let mut bytes = Vec::with_capacity(bytes_needed.min(64 << 20));
    data.take(bytes_needed as u64)
        .read_to_end(&mut bytes)
        .map_err(|e| SegmentationError::data(path, format!("cannot decode: {e}")))?;
    if bytes.len() < bytes_needed {
        return Err(short(path, bytes.len(), bytes_needed, layout));
    }
    to_labels(path, &bytes, layout.ty, order, None, layout.all_dims())
}

/// The labels of ASCII `data` (whitespace-separated numbers).
fn ascii_samples(path: &Path, data: &[u8], layout: &Layout) -> Result<Vec<u16>, SegmentationError> {
    let mut text = String::new();
    data.take((layout.count as u64).saturating_mul(24) + 4096)
        .read_to_string(&mut text)
        .map_err(|e| SegmentationError::data(path, format!("ASCII data: {e}")))?;
    ascii_to_labels(path, &text, layout.count, layout.all_dims())
}

/// Checks that every segment's `SegmentN_Layer` is one of the file's `layers`.
fn check_segment_layers(
    path: &Path,
    segments: &[(Segment, usize, String)],
    layers: usize,
) -> Result<(), SegmentationError> {
    if let Some(s) = segments.iter().find(|s| s.1 >= layers) {
        return Err(SegmentationError::header(
            path,
            &format!("{}_Layer", s.2),
            format!("layer {} but the file has {} layer(s)", s.1, layers),
        ));
    }
    Ok(())
}

/// The labels of each layer, from `values` where the layers are interleaved (the list axis
/// varies fastest).
fn split_layers(values: Vec<u16>, layers: usize) -> Vec<Vec<u16>> {
    if layers == 1 {
        vec![values]
    } else {
        (0..layers)
            .map(|layer| values.iter().skip(layer).step_by(layers).copied().collect())
            .collect()
    }
}

/// One [`Labelmap`] per layer, each named with the segments of its layer.
fn layer_labelmaps(
    path: &Path,
    per_layer: Vec<Vec<u16>>,
    segments: &[(Segment, usize, String)],
    layout: &Layout,
) -> Result<Vec<Labelmap>, SegmentationError> {
    let mut out = Vec::with_capacity(layout.layers);
    for (layer, labels) in per_layer.into_iter().enumerate() {
        let names = segments
            .iter()
            .filter(|s| s.1 == layer)
            .map(|s| s.0.clone())
            .collect();
        let map = Labelmap::new(layout.dims, labels, layout.affine)
            .map_err(|e| SegmentationError::header(path, "space directions", e.to_string()))?;
        out.push(map.with_segments(names));
    }
    Ok(out)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Raw,
    Gzip,
    Ascii,
}

fn missing(path: &Path, field: &str) -> SegmentationError {
    SegmentationError::header(path, field, "missing (required)")
}

fn short(path: &Path, got: usize, need: usize, l: &Layout) -> SegmentationError {
    SegmentationError::data(
        path,
        format!(
            "{got} bytes of data where sizes {:?}{} of type {:?} need {need}",
            l.dims,
            if l.layers > 1 {
                format!(" × {} layers", l.layers)
            } else {
                String::new()
            },
            l.ty
        ),
    )
}

/// What the header says about the samples and their place in space.
struct Layout {
    ty: StoredScalar,
    dims: [usize; 3],
    layers: usize,
    count: usize,
    affine: Matrix4<f64>,
}

impl Layout {
    /// Bytes of binary data that hold every sample of every layer.
    fn bytes_needed(&self) -> usize {
        self.count * self.ty.size()
    }

    /// The grid of samples in file order: the first axis counts the layers too.
    fn all_dims(&self) -> [usize; 3] {
        [self.dims[0] * self.layers, self.dims[1], self.dims[2]]
    }
}

/// The header: fields (`name: value`, names lower-cased, spaces removed) and key/value pairs
/// (`key:=value`), in file order.
struct Header {
    fields: Vec<(String, String)>,
    keyvals: Vec<(String, String)>,
}

impl Header {
    fn read(path: &Path, reader: &mut impl BufRead) -> Result<Self, SegmentationError> {
        let mut line = Vec::new();
        let mut total = 0usize;
        let mut next_line =
            |reader: &mut dyn BufRead, line: &mut Vec<u8>| -> Result<bool, SegmentationError> {
                line.clear();
                let n = reader
                    .take((MAX_HEADER - total.min(MAX_HEADER)) as u64 + 1)
                    .read_until(b'\n', line)
                    .map_err(|e| SegmentationError::io(path, e))?;
                total += n;
                if total > MAX_HEADER {
                    return Err(SegmentationError::header(
                        path,
                        "header",
                        format!("longer than {MAX_HEADER} bytes (no blank line ends it)"),
                    ));
                }
                while line.last().is_some_and(|&c| c == b'\n' || c == b'\r') {
                    line.pop();
                }
                Ok(n > 0)
            };
        if !next_line(reader, &mut line)? {
            return Err(SegmentationError::header(
                path,
                "magic",
                "the file is empty",
            ));
        }
        let magic = String::from_utf8_lossy(&line).into_owned();
        let ok = magic.len() == 8
            && magic.starts_with("NRRD000")
            && matches!(magic.as_bytes()[7], b'1'..=b'5');
        if !ok {
            return Err(SegmentationError::header(
                path,
                "magic",
                format!(
                    "first line '{}' is not NRRD0001…NRRD0005",
                    magic.chars().take(40).collect::<String>()
                ),
            ));
        }
        let mut header = Header {
            fields: Vec::new(),
            keyvals: Vec::new(),
        };
        let mut ended = false;
        while next_line(reader, &mut line)? {
            if line.is_empty() {
                ended = true;
                break;
            }
            let text = String::from_utf8_lossy(&line);
            if text.starts_with('#') {
                continue;
            }
            if let Some((k, v)) = text.split_once(":=") {
                header.keyvals.push((k.to_owned(), v.to_owned()));
            } else if let Some((k, v)) = text.split_once(": ") {
                let name: String = k
                    .to_ascii_lowercase()
                    .chars()
                    .filter(|c| !c.is_whitespace())
                    .collect();
                header.fields.push((name, v.trim().to_owned()));
            } else {
                return Err(SegmentationError::header(
                    path,
                    "header",
                    format!("line '{text}' is neither 'field: value' nor 'key:=value'"),
                ));
            }
        }
        if header.field("datafile").is_some() {
            return Err(SegmentationError::unsupported(
                path,
                format!(
                    "detached data ('data file: {}'); save the segmentation with attached data \
                     (a single .nrrd or .seg.nrrd file)",
                    header.field("datafile").unwrap_or_default()
                ),
            ));
        }
        if !ended {
            return Err(SegmentationError::header(
                path,
                "header",
                "the file ends before the blank line that separates the header from the data",
            ));
        }
        Ok(header)
    }

    /// A field by name (lower case, without spaces: `spacedirections`).
    fn field(&self, name: &str) -> Option<&str> {
        let key: String = name.chars().filter(|c| !c.is_whitespace()).collect();
        self.fields
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, v)| v.as_str())
    }

    fn integer(&self, path: &Path, name: &str, default: i64) -> Result<i64, SegmentationError> {
        match self.field(name) {
            None => Ok(default),
            Some(v) => v.trim().parse().map_err(|_| {
                SegmentationError::header(path, name, format!("'{v}' is not an integer"))
            }),
        }
    }

    /// The `encoding` field: raw, gzip or ascii (other encodings are refused).
    fn encoding(&self, path: &Path) -> Result<Encoding, SegmentationError> {
        let encoding = self
            .field("encoding")
            .ok_or_else(|| missing(path, "encoding"))?;
        Ok(match encoding.to_ascii_lowercase().as_str() {
            "raw" => Encoding::Raw,
            "gzip" | "gz" => Encoding::Gzip,
            "ascii" | "text" | "txt" => Encoding::Ascii,
            "bzip2" | "bz2" | "hex" => {
                return Err(SegmentationError::unsupported(
                    path,
                    format!("encoding '{encoding}' (raw, gzip and ascii are read)"),
                ))
            }
            _ => {
                return Err(SegmentationError::header(
                    path,
                    "encoding",
                    format!("unknown value '{encoding}'"),
                ))
            }
        })
    }

    /// The `endian` field; it may be absent for one-byte samples and ASCII data (then
    /// little-endian, which does not matter).
    fn byte_order(
        &self,
        path: &Path,
        layout: &Layout,
        encoding: Encoding,
    ) -> Result<ByteOrder, SegmentationError> {
        Ok(
            match self.field("endian").map(str::to_ascii_lowercase).as_deref() {
                Some("little") => ByteOrder::Little,
                Some("big") => ByteOrder::Big,
                Some(other) => {
                    return Err(SegmentationError::header(
                        path,
                        "endian",
                        format!("'{other}' (expected little or big)"),
                    ))
                }
                None if layout.ty.size() == 1 || encoding == Encoding::Ascii => ByteOrder::Little,
                None => return Err(missing(path, "endian")),
            },
        )
    }

    /// The sample type, its sizes, layers and index → LPS mm affine.
    fn layout(&self, path: &Path) -> Result<Layout, SegmentationError> {
        let ty = self.scalar_type(path)?;
        let nd = self.dimension(path)?;
        let (sizes, sizes_text) = self.sizes(path, nd)?;
        let kinds = self.kinds(path, nd)?;
        let directions = self.directions(path, nd)?;
        let spatial_axes = spatial_axes(nd, directions.as_deref(), kinds.as_deref());
        let layers = layer_count(path, nd, &spatial_axes, &sizes)?;
        let off = nd - 3;
        let dims = [sizes[off], sizes[off + 1], sizes[off + 2]];
        let count = voxel_count(dims)
            .and_then(|n| n.checked_mul(layers))
            .filter(|&n| n <= MAX_VOXELS)
            .ok_or_else(|| {
                SegmentationError::header(
                    path,
                    "sizes",
                    format!("'{sizes_text}' is more than the {MAX_VOXELS} voxels accepted"),
                )
            })?;
        let affine = self.affine_lps(path, directions.as_deref(), nd)?;
        Ok(Layout {
            ty,
            dims,
            layers,
            count,
            affine,
        })
    }

    /// The `type` field as a sample type that can hold labels.
    fn scalar_type(&self, path: &Path) -> Result<StoredScalar, SegmentationError> {
        let ty_name = self.field("type").ok_or_else(|| missing(path, "type"))?;
        sample_type(ty_name).ok_or_else(|| {
            SegmentationError::header(path, "type", format!("'{ty_name}' cannot hold labels"))
        })
    }

    /// The `dimension` field: 3, or 4 with a list axis of layers.
    fn dimension(&self, path: &Path) -> Result<usize, SegmentationError> {
        let dimension = self.integer(path, "dimension", -1)?;
        if dimension == -1 && self.field("dimension").is_none() {
            return Err(missing(path, "dimension"));
        }
        if dimension != 3 && dimension != 4 {
            return Err(SegmentationError::header(
                path,
                "dimension",
                format!("{dimension}: a labelmap has 3 axes (or 4 with a leading list of layers)"),
            ));
        }
        Ok(dimension as usize)
    }

    /// The `sizes` field: `nd` positive sample counts, with the field's text.
    fn sizes(&self, path: &Path, nd: usize) -> Result<(Vec<usize>, &str), SegmentationError> {
        let sizes_text = self.field("sizes").ok_or_else(|| missing(path, "sizes"))?;
        let sizes: Vec<usize> = sizes_text
            .split_ascii_whitespace()
            .map(|w| w.parse::<usize>().ok().filter(|&s| s > 0))
            .collect::<Option<_>>()
            .filter(|s: &Vec<usize>| s.len() == nd)
            .ok_or_else(|| {
                SegmentationError::header(
                    path,
                    "sizes",
                    format!("'{sizes_text}' is not {nd} positive integers"),
                )
            })?;
        Ok((sizes, sizes_text))
    }

    /// The `kinds` field, lower-cased: one entry per axis, if present.
    fn kinds(&self, path: &Path, nd: usize) -> Result<Option<Vec<String>>, SegmentationError> {
        let kinds: Option<Vec<String>> = self.field("kinds").map(|k| {
            k.split_ascii_whitespace()
                .map(str::to_ascii_lowercase)
                .collect()
        });
        if let Some(k) = &kinds {
            if k.len() != nd {
                return Err(SegmentationError::header(
                    path,
                    "kinds",
                    format!("{} entries for dimension {nd}", k.len()),
                ));
            }
        }
        Ok(kinds)
    }

    /// The index → LPS mm affine: the spatial axes' `space directions` (or `spacings` on the
    /// diagonal when there are none) and `space origin`, scaled by `space units` to mm and
    /// flipped from the file's space to LPS.
    fn affine_lps(
        &self,
        path: &Path,
        directions: Option<&[Option<Vector3<f64>>]>,
        nd: usize,
    ) -> Result<Matrix4<f64>, SegmentationError> {
        let off = nd - 3;
        // Index → file space, then file space → LPS.
        let (to_lps, unit) = self.space(path)?;
        let mut affine = Matrix4::identity();
        match directions {
            Some(d) => {
                for a in 0..3 {
                    let v = d[off + a].expect("spatial axis has a direction");
                    affine.fixed_view_mut::<3, 1>(0, a).copy_from(&v);
                }
            }
            None => {
                let spacings = self.spacings(path, nd)?;
                for a in 0..3 {
                    affine[(a, a)] = spacings[off + a];
                }
            }
        }
        if let Some(o) = self.field("spaceorigin") {
            let v = parse_vector(o).ok_or_else(|| {
                SegmentationError::header(
                    path,
                    "space origin",
                    format!("'{o}' is not a vector '(x,y,z)' of finite numbers"),
                )
            })?;
            affine.fixed_view_mut::<3, 1>(0, 3).copy_from(&v);
        }
        affine.fixed_view_mut::<3, 4>(0, 0).scale_mut(unit);
        Ok(
            Matrix4::from_diagonal(&nalgebra::Vector4::new(to_lps.x, to_lps.y, to_lps.z, 1.0))
                * affine,
        )
    }

    /// `space directions`: one `(x,y,z)` or `none` per axis.
    fn directions(
        &self,
        path: &Path,
        nd: usize,
    ) -> Result<Option<Vec<Option<Vector3<f64>>>>, SegmentationError> {
        let Some(text) = self.field("spacedirections") else {
            return Ok(None);
        };
        let bad = |why: String| SegmentationError::header(path, "space directions", why);
        let mut out = Vec::new();
        let mut rest = text.trim();
        while !rest.is_empty() {
            if let Some(r) = rest.strip_prefix("none") {
                out.push(None);
                rest = r.trim_start();
            } else if rest.starts_with('(') {
                let end = rest
                    .find(')')
                    .ok_or_else(|| bad(format!("'{text}': unclosed '('")))?;
                let v = parse_vector(&rest[..=end]).ok_or_else(|| {
                    bad(format!(
                        "'{}' is not a 3-vector of finite numbers",
                        &rest[..=end]
                    ))
                })?;
                out.push(Some(v));
                rest = rest[end + 1..].trim_start();
            } else {
                return Err(bad(format!("'{text}': expected '(x,y,z)' or 'none'")));
            }
        }
        if out.len() != nd {
            return Err(bad(format!("{} entries for dimension {nd}", out.len())));
        }
        Ok(Some(out))
    }

    fn spacings(&self, path: &Path, nd: usize) -> Result<Vec<f64>, SegmentationError> {
        let Some(text) = self.field("spacings") else {
            return Ok(vec![1.0; nd]);
        };
        let v: Vec<f64> = text
            .split_ascii_whitespace()
            .map(|w| w.parse::<f64>().unwrap_or(f64::NAN))
            .collect();
        if v.len() != nd {
            return Err(SegmentationError::header(
                path,
                "spacings",
                format!("'{text}' has {} entries for dimension {nd}", v.len()),
            ));
        }
        Ok(v.into_iter()
            .map(|s| if s.is_finite() && s != 0.0 { s } else { 1.0 })
            .collect())
    }

    /// Sign flips taking the file's space to LPS, and the unit's size in mm.
    fn space(&self, path: &Path) -> Result<(Vector3<f64>, f64), SegmentationError> {
        let flips = match self.field("space") {
            None => {
                if let Some(d) = self.field("spacedimension") {
                    if d.trim() != "3" {
                        return Err(SegmentationError::header(
                            path,
                            "space dimension",
                            format!("{d} (3 expected)"),
                        ));
                    }
                }
                Vector3::new(1.0, 1.0, 1.0)
            }
            Some(s) => match s.to_ascii_lowercase().as_str() {
                "left-posterior-superior" | "lps" => Vector3::new(1.0, 1.0, 1.0),
                "right-anterior-superior" | "ras" => Vector3::new(-1.0, -1.0, 1.0),
                "left-anterior-superior" | "las" => Vector3::new(1.0, -1.0, 1.0),
                _ => {
                    return Err(SegmentationError::unsupported(
                        path,
                        format!(
                            "space '{s}': only the anatomical 3-D spaces (LPS, RAS, LAS) can be \
                             placed in LPS"
                        ),
                    ))
                }
            },
        };
        let unit = match self.field("spaceunits") {
            None => 1.0,
            Some(u) => {
                let words: Vec<String> = u
                    .split_ascii_whitespace()
                    .map(|w| w.trim_matches('"').to_ascii_lowercase())
                    .collect();
                let first = words.first().cloned().unwrap_or_default();
                if words.iter().any(|w| *w != first) {
                    return Err(SegmentationError::unsupported(
                        path,
                        format!("space units '{u}' differ between axes"),
                    ));
                }
                match first.as_str() {
                    "mm" | "" => 1.0,
                    "cm" => 10.0,
                    "m" => 1000.0,
                    "um" | "µm" => 1e-3,
                    _ => {
                        return Err(SegmentationError::header(
                            path,
                            "space units",
                            format!("unknown unit '{first}' (mm, cm, m, um)"),
                        ))
                    }
                }
            }
        };
        Ok((flips, unit))
    }

    /// Slicer's segments: (name and label, layer, key prefix `SegmentN`) in index order.
    fn segments(&self, path: &Path) -> Result<Vec<(Segment, usize, String)>, SegmentationError> {
        let mut found: Vec<(usize, Option<String>, Option<u16>, usize)> = Vec::new();
        for (k, v) in &self.keyvals {
            let Some(rest) = k.strip_prefix("Segment") else {
                continue;
            };
            let Some((n, what)) = rest.split_once('_') else {
                continue;
            };
            let Ok(n) = n.parse::<usize>() else { continue };
            let pos = match found.iter().position(|f| f.0 == n) {
                Some(p) => p,
                None => {
                    found.push((n, None, None, 0));
                    found.len() - 1
                }
            };
            let entry = &mut found[pos];
            match what {
                "Name" => entry.1 = Some(v.clone()),
                "LabelValue" => {
                    entry.2 = Some(v.trim().parse().map_err(|_| {
                        SegmentationError::header(
                            path,
                            k,
                            format!("'{v}' is not a label value (0..=65535)"),
                        )
                    })?)
                }
                "Layer" => {
                    entry.3 = v.trim().parse().map_err(|_| {
                        SegmentationError::header(path, k, format!("'{v}' is not a layer index"))
                    })?
                }
                _ => {}
            }
        }
        found.sort_by_key(|f| f.0);
        Ok(found
            .into_iter()
            .filter_map(|(n, name, label, layer)| {
                name.map(|name| {
                    (
                        Segment {
                            name,
                            label: label.unwrap_or(1),
                        },
                        layer,
                        format!("Segment{n}"),
                    )
                })
            })
            .collect())
    }
}

/// Whether axis `a` is spatial: it has a space direction, or (without `space directions`) a
/// spatial kind; every axis is spatial when neither field is given.
fn is_spatial(
    a: usize,
    directions: Option<&[Option<Vector3<f64>>]>,
    kinds: Option<&[String]>,
) -> bool {
    let by_dir = directions.map(|d| d[a].is_some());
    let by_kind = kinds.map(|k| {
        matches!(k[a].as_str(), "domain" | "space" | "time")
            || (k[a] == "???" && by_dir != Some(false))
    });
    by_dir.or(by_kind).unwrap_or(true)
}

/// The spatial axes among the `nd` axes, in order; the list (layer) axis is the one without a
/// space direction, or with a non-spatial kind.
fn spatial_axes(
    nd: usize,
    directions: Option<&[Option<Vector3<f64>>]>,
    kinds: Option<&[String]>,
) -> Vec<usize> {
    (0..nd)
        .filter(|&a| is_spatial(a, directions, kinds))
        .collect()
}

/// The number of layers: the size of the leading list axis of 4-D data, 1 for 3-D data.
/// Errors when the spatial axes are not the last three (4-D) or not three (3-D).
fn layer_count(
    path: &Path,
    nd: usize,
    spatial_axes: &[usize],
    sizes: &[usize],
) -> Result<usize, SegmentationError> {
    if nd == 4 {
        if spatial_axes != [1, 2, 3] {
            return Err(SegmentationError::unsupported(
                path,
                format!(
                    "4-D data whose non-spatial axis is not the first (spatial axes {spatial_axes:?}, from \
                     'space directions'/'kinds'); only a leading list of layers is read"
                ),
            ));
        }
        Ok(sizes[0])
    } else {
        if spatial_axes.len() != 3 {
            return Err(SegmentationError::header(
                path,
                "space directions",
                "a 3-D labelmap needs three spatial axes ('none' given)",
            ));
        }
        Ok(1)
    }
}

/// Parses `(x,y,z)`.
fn parse_vector(text: &str) -> Option<Vector3<f64>> {
    let inner = text.trim().strip_prefix('(')?.strip_suffix(')')?;
    let v: Vec<f64> = inner
        .split(',')
        .map(|w| w.trim().parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect::<Option<_>>()?;
    (v.len() == 3).then(|| Vector3::new(v[0], v[1], v[2]))
}

fn sample_type(name: &str) -> Option<StoredScalar> {
    let n: String = name
        .split_ascii_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .to_ascii_lowercase();
    Some(match n.as_str() {
        "signed char" | "int8" | "int8_t" => StoredScalar::I8,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => StoredScalar::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            StoredScalar::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => {
            StoredScalar::U16
        }
        "int" | "signed int" | "int32" | "int32_t" => StoredScalar::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => StoredScalar::U32,
        "longlong"
        | "long long"
        | "long long int"
        | "signed long long"
        | "signed long long int"
        | "int64"
        | "int64_t" => StoredScalar::I64,
        "ulonglong" | "unsigned long long" | "unsigned long long int" | "uint64" | "uint64_t" => {
            StoredScalar::U64
        }
        "float" => StoredScalar::F32,
        "double" => StoredScalar::F64,
        _ => return None,
    })
}
