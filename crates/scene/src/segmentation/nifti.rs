//! NIfTI-1 labelmaps (`.nii`, `.nii.gz`), the header parsed by the `nifti` crate, the voxel
//! data read and checked here.
//!
//! * **Affine**: the sform if `sform_code > 0`, else the qform (quaternion, `pixdim`, `qfac`)
//!   if `qform_code > 0`, else plain `pixdim` scaling with the origin at voxel 0 (NIfTI's
//!   "method 1"). NIfTI's world is RAS+; it is turned into LPS by negating x and y (the first
//!   two rows of the affine).
//! * **Units**: `xyzt_units` metres or micrometres are converted to mm; unknown (0) is taken
//!   as mm.
//! * **Scaling**: `scl_slope ≠ 0` applies `value × scl_slope + scl_inter`; the result must be an
//!   integer label in 0..=65535.
//! * **Refused with a clear error**: NIfTI-2 (540-byte header: the crate parses NIfTI-1 only),
//!   `.hdr`/`.img` pairs, more than three non-singleton dimensions, complex/RGB/128-bit types,
//!   sizes over [`MAX_VOXELS`](super::labelmap::MAX_VOXELS), a file shorter than its header says.

use std::io::Read;
use std::path::Path;

use flate2::read::MultiGzDecoder;
use nalgebra::{Matrix4, Quaternion, UnitQuaternion};
use nifti::{Endianness, NiftiHeader, NiftiType};

use super::error::SegmentationError;
use super::labelmap::{voxel_count, Labelmap, MAX_VOXELS};
use super::samples::{to_labels, Scaling};
use crate::stored_scalar::{ByteOrder, StoredScalar};

/// Where the affine of a NIfTI file came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NiftiTransform {
    /// `srow_x/y/z` (`sform_code > 0`).
    Sform,
    /// The quaternion, `pixdim` and `qfac` (`qform_code > 0`, `sform_code = 0`).
    Qform,
    /// Neither code set: `pixdim` scaling, origin at voxel 0.
    Pixdim,
}

/// Reads a NIfTI-1 labelmap (`.nii`, or gzip-compressed `.nii.gz`); the affine is converted to
/// LPS mm (see the module documentation).
pub fn read_nifti(path: &Path) -> Result<Labelmap, SegmentationError> {
    read_nifti_with_transform(path).map(|(l, _)| l)
}

/// [`read_nifti`], also telling which transform of the header was used.
pub fn read_nifti_with_transform(
    path: &Path,
) -> Result<(Labelmap, NiftiTransform), SegmentationError> {
    refuse_pairs(path)?;
    let bytes = std::fs::read(path).map_err(|e| SegmentationError::io(path, e))?;
    read_nifti_bytes(path, &bytes)
}

/// NIfTI/Analyze `.hdr`/`.img` pairs are not read: an error saying so.
fn refuse_pairs(path: &Path) -> Result<(), SegmentationError> {
    let name = path.to_string_lossy().to_ascii_lowercase();
    if name.ends_with(".hdr") || name.ends_with(".img") || name.ends_with(".hdr.gz") {
        return Err(SegmentationError::unsupported(
            path,
            "NIfTI/Analyze .hdr/.img pairs; convert to a single .nii or .nii.gz",
        ));
    }
    Ok(())
}

/// [`read_nifti_with_transform`] of a file's bytes already in memory; `path` names it in
/// errors, and its name ending in `.gz` says the bytes are gzip-compressed.
pub fn read_nifti_bytes(
    path: &Path,
    file: &[u8],
) -> Result<(Labelmap, NiftiTransform), SegmentationError> {
    refuse_pairs(path)?;
    let name = path.to_string_lossy().to_ascii_lowercase();
    let gz = name.ends_with(".gz");
    let mut reader: Box<dyn Read + '_> = if gz {
        Box::new(MultiGzDecoder::new(file))
    } else {
        Box::new(file)
    };
    let h = read_header(path, &mut reader)?;
    let dims = dims_of(path, &h)?;
    let ty = sample_type(path, &h)?;
    let order = match h.endianness {
        Endianness::Little => ByteOrder::Little,
        Endianness::Big => ByteOrder::Big,
    };
    let bytes = data_size(path, dims, ty)?;
    let offset = vox_offset(path, &h)?;
    let data: std::borrow::Cow<[u8]> = if gz {
        decompress_voxels(path, reader, offset, bytes)?.into()
    } else {
        file_voxels(path, file, offset, bytes, dims, ty)?.into()
    };
    if data.len() < bytes {
        return Err(SegmentationError::data(
            path,
            format!(
                "the data end after {} bytes but dim {dims:?} of {ty:?} needs {bytes}",
                data.len()
            ),
        ));
    }
    let labels = to_labels(path, &data, ty, order, scaling(&h), dims)?;
    drop(data);
    let (lps, transform) = affine_lps_mm(path, &h)?;
    let map = Labelmap::new(dims, labels, lps)
        .map_err(|e| SegmentationError::header(path, transform.field(), e.to_string()))?;
    Ok((map, transform))
}

/// Reads and parses the 348-byte NIfTI-1 header at the start of `reader`; errors for a short
/// file, NIfTI-2, another header size, and a magic other than single-file `n+1`.
fn read_header(path: &Path, reader: &mut dyn Read) -> Result<NiftiHeader, SegmentationError> {
    let mut raw = [0u8; 348];
    reader.read_exact(&mut raw).map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            SegmentationError::header(
                path,
                "sizeof_hdr",
                "the file is shorter than a 348-byte NIfTI-1 header",
            )
        } else {
            SegmentationError::io(path, e)
        }
    })?;
    check_sizeof_hdr(path, &raw)?;
    let h = NiftiHeader::from_reader(&raw[..]).map_err(|e| {
        SegmentationError::header(path, "magic", format!("not a NIfTI-1 header ({e})"))
    })?;
    if &h.magic != b"n+1\0" {
        return Err(SegmentationError::unsupported(
            path,
            format!(
                "magic {:?} announces a separate .img file; only single-file .nii is read",
                String::from_utf8_lossy(&h.magic)
            ),
        ));
    }
    Ok(h)
}

/// Checks `sizeof_hdr` (the first 4 bytes of the header, either byte order) is 348; 540
/// (NIfTI-2) is refused with an error saying so.
fn check_sizeof_hdr(path: &Path, raw: &[u8; 348]) -> Result<(), SegmentationError> {
    let sizeof = i32::from_le_bytes(raw[..4].try_into().unwrap());
    if sizeof == 540 || sizeof.swap_bytes() == 540 {
        return Err(SegmentationError::unsupported(
            path,
            "NIfTI-2 (sizeof_hdr = 540): the nifti crate reads NIfTI-1 only; save as NIfTI-1 \
             (e.g. nibabel.Nifti1Image)",
        ));
    }
    if sizeof != 348 && sizeof.swap_bytes() != 348 {
        return Err(SegmentationError::header(
            path,
            "sizeof_hdr",
            format!("{sizeof} (expected 348): not a NIfTI-1 file"),
        ));
    }
    Ok(())
}

/// Bytes of voxel data for `dims` samples of type `ty`; errors above [`MAX_VOXELS`] voxels.
fn data_size(path: &Path, dims: [usize; 3], ty: StoredScalar) -> Result<usize, SegmentationError> {
    let n = voxel_count(dims)
        .filter(|&n| n <= MAX_VOXELS)
        .ok_or_else(|| {
            SegmentationError::header(
                path,
                "dim",
                format!("{dims:?} is more than the {MAX_VOXELS} voxels accepted"),
            )
        })?;
    Ok(n * ty.size())
}

/// `vox_offset`: where the voxel data start, bytes from the start of the file (a whole
/// number ≥ 348).
fn vox_offset(path: &Path, h: &NiftiHeader) -> Result<u64, SegmentationError> {
    let offset = h.vox_offset;
    if !(offset.is_finite() && offset >= 348.0 && offset.fract() == 0.0) {
        return Err(SegmentationError::header(
            path,
            "vox_offset",
            format!("{offset} (must be a whole number ≥ 348)"),
        ));
    }
    Ok(offset as u64)
}

/// Up to `bytes` bytes of voxel data from the decompressed stream `reader`, positioned just
/// after the 348-byte header: the extensions up to `offset` are skipped.
fn decompress_voxels(
    path: &Path,
    mut reader: impl Read,
    offset: u64,
    bytes: usize,
) -> Result<Vec<u8>, SegmentationError> {
    // Extensions between the header and the data.
    std::io::copy(&mut (&mut reader).take(offset - 348), &mut std::io::sink())
        .map_err(|e| SegmentationError::data(path, format!("cannot decompress: {e}")))?;
    // Grows with the data actually decompressed: a tiny file claiming huge sizes
    // allocates little before it fails.
    let mut data = Vec::with_capacity(bytes.min(64 << 20));
    reader
        .take(bytes as u64)
        .read_to_end(&mut data)
        .map_err(|e| SegmentationError::data(path, format!("cannot decompress: {e}")))?;
    Ok(data)
}

/// The `bytes` bytes of voxel data of an uncompressed `file` from `offset`, read straight
/// from the file's bytes; errors when the file is shorter.
fn file_voxels<'a>(
    path: &Path,
    file: &'a [u8],
    offset: u64,
    bytes: usize,
    dims: [usize; 3],
    ty: StoredScalar,
) -> Result<&'a [u8], SegmentationError> {
    let file_len = file.len() as u64;
    if file_len < offset + bytes as u64 {
        return Err(SegmentationError::data(
            path,
            format!(
                "the file has {file_len} bytes but dim {dims:?} of {ty:?} from vox_offset {offset} \
                 needs {}",
                offset + bytes as u64
            ),
        ));
    }
    let start = (offset as usize).min(file.len());
    Ok(&file[start..(start + bytes).min(file.len())])
}

/// The value scaling `scl_slope`/`scl_inter`: none when the slope is 0 or not finite, or the
/// scaling is the identity; a non-finite intercept counts as 0.
fn scaling(h: &NiftiHeader) -> Option<Scaling> {
    let slope = h.scl_slope as f64;
    (slope != 0.0 && slope.is_finite())
        .then_some(Scaling {
            slope,
            inter: if h.scl_inter.is_finite() {
                h.scl_inter as f64
            } else {
                0.0
            },
        })
        .filter(|s| {
            *s != Scaling {
                slope: 1.0,
                inter: 0.0,
            }
        })
}

/// The header's index → LPS mm affine (units from `xyzt_units`) and where it came from.
fn affine_lps_mm(
    path: &Path,
    h: &NiftiHeader,
) -> Result<(Matrix4<f64>, NiftiTransform), SegmentationError> {
    let (mut ras, transform) = affine_ras(path, h)?;
    // xyzt_units: metres and micrometres are converted; unknown (0) is taken as millimetres.
    let to_mm = match h.xyzt_units & 0x07 {
        1 => 1000.0,
        3 => 1e-3,
        _ => 1.0,
    };
    ras.fixed_view_mut::<3, 4>(0, 0).scale_mut(to_mm);
    Ok((ras_to_lps(&ras), transform))
}

impl NiftiTransform {
    fn field(self) -> &'static str {
        match self {
            Self::Sform => "srow_x/srow_y/srow_z",
            Self::Qform => "quatern_b/c/d, pixdim",
            Self::Pixdim => "pixdim",
        }
    }
}

/// RAS ↔ LPS: negate the first two rows (x and y) of an index → world affine.
pub(crate) fn ras_to_lps(a: &Matrix4<f64>) -> Matrix4<f64> {
    Matrix4::from_diagonal(&nalgebra::Vector4::new(-1.0, -1.0, 1.0, 1.0)) * a
}

fn dims_of(path: &Path, h: &NiftiHeader) -> Result<[usize; 3], SegmentationError> {
    let nd = h.dim[0] as usize;
    if !(3..=7).contains(&nd) {
        return Err(SegmentationError::header(
            path,
            "dim[0]",
            format!("{nd}: a labelmap needs 3 dimensions"),
        ));
    }
    if let Some(extra) = (4..=nd).find(|&d| h.dim[d] > 1) {
        return Err(SegmentationError::unsupported(
            path,
            format!(
                "dim[{extra}] = {}: only 3-D labelmaps are read (no time series or vector images)",
                h.dim[extra]
            ),
        ));
    }
    let dims = [h.dim[1] as usize, h.dim[2] as usize, h.dim[3] as usize];
    if let Some(a) = (0..3).find(|&a| dims[a] == 0 || h.dim[a + 1] as i16 <= 0) {
        return Err(SegmentationError::header(
            path,
            &format!("dim[{}]", a + 1),
            format!("{} (sizes must be positive)", h.dim[a + 1] as i16),
        ));
    }
    Ok(dims)
}

fn sample_type(path: &Path, h: &NiftiHeader) -> Result<StoredScalar, SegmentationError> {
    let t = h.data_type().map_err(|_| {
        SegmentationError::header(path, "datatype", format!("unknown code {}", h.datatype))
    })?;
    Ok(match t {
        NiftiType::Uint8 => StoredScalar::U8,
        NiftiType::Int8 => StoredScalar::I8,
        NiftiType::Int16 => StoredScalar::I16,
        NiftiType::Uint16 => StoredScalar::U16,
        NiftiType::Int32 => StoredScalar::I32,
        NiftiType::Uint32 => StoredScalar::U32,
        NiftiType::Int64 => StoredScalar::I64,
        NiftiType::Uint64 => StoredScalar::U64,
        NiftiType::Float32 => StoredScalar::F32,
        NiftiType::Float64 => StoredScalar::F64,
        other => {
            return Err(SegmentationError::unsupported(
                path,
                format!("datatype {other:?} ({}) cannot hold labels", h.datatype),
            ))
        }
    })
}

/// The header's index → RAS mm affine and where it came from.
fn affine_ras(
    path: &Path,
    h: &NiftiHeader,
) -> Result<(Matrix4<f64>, NiftiTransform), SegmentationError> {
    if h.sform_code > 0 {
        let r = |row: [f32; 4]| row.map(|v| v as f64);
        let [x, y, z] = [r(h.srow_x), r(h.srow_y), r(h.srow_z)];
        #[rustfmt::skip]
        let a = Matrix4::new(
            x[0], x[1], x[2], x[3],
            y[0], y[1], y[2], y[3],
            z[0], z[1], z[2], z[3],
            0.0, 0.0, 0.0, 1.0,
        );
        return Ok((a, NiftiTransform::Sform));
    }
    let spacing = pixdim(path, h)?;
    if h.qform_code > 0 {
        let (b, c, d) = (h.quatern_b as f64, h.quatern_c as f64, h.quatern_d as f64);
        let s = b * b + c * c + d * d;
        if !(s.is_finite() && s <= 1.0 + 1e-6) {
            return Err(SegmentationError::header(
                path,
                "quatern_b/c/d",
                format!("({b}, {c}, {d}) is not part of a unit quaternion (b²+c²+d² = {s})"),
            ));
        }
        let a = (1.0 - s).max(0.0).sqrt();
        let rot = UnitQuaternion::from_quaternion(Quaternion::new(a, b, c, d));
        // qfac = pixdim[0]: −1 flips the third axis; any other value counts as 1 (the standard).
        let qfac = if h.pixdim[0] == -1.0 { -1.0 } else { 1.0 };
        let m = rot.to_rotation_matrix().into_inner()
            * nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(
                spacing[0],
                spacing[1],
                spacing[2] * qfac,
            ));
        let mut out = Matrix4::identity();
        out.fixed_view_mut::<3, 3>(0, 0).copy_from(&m);
        out[(0, 3)] = h.quatern_x as f64;
        out[(1, 3)] = h.quatern_y as f64;
        out[(2, 3)] = h.quatern_z as f64;
        return Ok((out, NiftiTransform::Qform));
    }
    let mut out = Matrix4::identity();
    for a in 0..3 {
        out[(a, a)] = spacing[a];
    }
    Ok((out, NiftiTransform::Pixdim))
}

fn pixdim(path: &Path, h: &NiftiHeader) -> Result<[f64; 3], SegmentationError> {
    let mut s = [0.0; 3];
    for (a, out) in s.iter_mut().enumerate() {
        let v = h.pixdim[a + 1] as f64;
        if !(v.is_finite() && v > 0.0) {
            return Err(SegmentationError::header(
                path,
                &format!("pixdim[{}]", a + 1),
                format!("{v} (voxel sizes must be positive)"),
            ));
        }
        *out = v;
    }
    Ok(s)
}
