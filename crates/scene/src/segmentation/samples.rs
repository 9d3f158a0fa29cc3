//! Voxel samples as stored in files (integer or float, either byte order) turned into `u16`
//! labels, refusing anything that is not a label: negative values, values above 65535 and
//! non-integer floats (a probability map or an intensity image).

use std::path::Path;

use super::error::SegmentationError;
use crate::stored_scalar::{ByteOrder, StoredScalar};

/// Linear value scaling `value = stored × slope + inter` (NIfTI's `scl_slope`/`scl_inter`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Scaling {
    /// Multiplier.
    pub slope: f64,
    /// Offset.
    pub inter: f64,
}

/// Converts raw samples (first index fastest) into labels. `dims` only serves the error
/// messages (voxel position of the first bad value).
pub(crate) fn to_labels(
    path: &Path,
    bytes: &[u8],
    ty: StoredScalar,
    order: ByteOrder,
    scaling: Option<Scaling>,
    dims: [usize; 3],
) -> Result<Vec<u16>, SegmentationError> {
    let size = ty.size();
    let n = bytes.len() / size;
    let mut out = Vec::with_capacity(n);
    // Fast paths: unscaled unsigned bytes and shorts in any order need no check at all.
    match (ty, scaling) {
        (StoredScalar::U8, None) => return Ok(bytes.iter().map(|&b| b as u16).collect()),
        (StoredScalar::U16, None) => {
            return Ok(bytes
                .chunks_exact(2)
                .map(|c| match order {
                    ByteOrder::Little => u16::from_le_bytes([c[0], c[1]]),
                    ByteOrder::Big => u16::from_be_bytes([c[0], c[1]]),
                })
                .collect())
        }
        _ => {}
    }
    for (idx, chunk) in bytes.chunks_exact(size).enumerate() {
        let mut v = ty.decode(chunk, order);
        if let Some(s) = scaling {
            v = v * s.slope + s.inter;
        }
        if let Some(label) = as_label(v) {
            out.push(label);
            continue;
        }
        let at = voxel_of(idx, dims);
        let what = if !v.is_finite() {
            "is not finite".to_owned()
        } else if v.fract() != 0.0 {
            format!(
                "is not an integer{}: this looks like a {} image, not a labelmap",
                if scaling.is_some() {
                    " after scl_slope/scl_inter"
                } else {
                    ""
                },
                if ty.is_float() || scaling.is_some() {
                    "probability or intensity"
                } else {
                    "scaled"
                }
            )
        } else {
            "is outside the label range 0..=65535".to_owned()
        };
        return Err(SegmentationError::data(
            path,
            format!("value {v} at voxel {at:?} {what}"),
        ));
    }
    Ok(out)
}

/// Parses ASCII samples (NRRD `encoding: ascii`): whitespace-separated numbers.
pub(crate) fn ascii_to_labels(
    path: &Path,
    text: &str,
    count: usize,
    dims: [usize; 3],
) -> Result<Vec<u16>, SegmentationError> {
    let mut out = Vec::with_capacity(count.min(1 << 24));
    for (idx, word) in text.split_ascii_whitespace().enumerate() {
        if idx == count {
            return Err(SegmentationError::data(
                path,
                format!("more than the {count} ASCII values the header's sizes call for"),
            ));
        }
        let v: f64 = word.parse().map_err(|_| {
            SegmentationError::data(
                path,
                format!(
                    "'{word}' at voxel {:?} is not a number",
                    voxel_of(idx, dims)
                ),
            )
        })?;
        out.push(as_label(v).ok_or_else(|| {
            SegmentationError::data(
                path,
                format!(
                    "value {v} at voxel {:?} is not a label (an integer in 0..=65535)",
                    voxel_of(idx, dims)
                ),
            )
        })?);
    }
    if out.len() != count {
        return Err(SegmentationError::data(
            path,
            format!(
                "{} ASCII values where the header's sizes call for {count}",
                out.len()
            ),
        ));
    }
    Ok(out)
}

#[inline]
fn as_label(v: f64) -> Option<u16> {
    (v.is_finite() && v.fract() == 0.0 && (0.0..=65535.0).contains(&v)).then_some(v as u16)
}

fn voxel_of(idx: usize, dims: [usize; 3]) -> [usize; 3] {
    let (nx, ny) = (dims[0].max(1), dims[1].max(1));
    [idx % nx, (idx / nx) % ny, idx / (nx * ny)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integers_of_every_type_and_order() {
        let p = Path::new("x");
        let be: Vec<u8> = [3i32, 0, 65535]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        assert_eq!(
            to_labels(p, &be, StoredScalar::I32, ByteOrder::Big, None, [3, 1, 1]).unwrap(),
            vec![3, 0, 65535]
        );
        let le: Vec<u8> = [3u16, 9].iter().flat_map(|v| v.to_le_bytes()).collect();
        assert_eq!(
            to_labels(
                p,
                &le,
                StoredScalar::U16,
                ByteOrder::Little,
                None,
                [2, 1, 1]
            )
            .unwrap(),
            vec![3, 9]
        );
        let f: Vec<u8> = [1.0f64, 2.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        assert_eq!(
            to_labels(p, &f, StoredScalar::F64, ByteOrder::Little, None, [2, 1, 1]).unwrap(),
            vec![1, 2]
        );
    }

    #[test]
    fn non_labels_are_refused_with_their_voxel() {
        let p = Path::new("prob.nii");
        let f: Vec<u8> = [0.0f32, 0.0, 0.25]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let e =
            to_labels(p, &f, StoredScalar::F32, ByteOrder::Little, None, [1, 3, 1]).unwrap_err();
        let s = e.to_string();
        assert!(
            s.contains("prob.nii") && s.contains("0.25") && s.contains("[0, 2, 0]"),
            "{s}"
        );
        assert!(s.contains("not an integer"), "{s}");
        let neg: Vec<u8> = [-1i16].iter().flat_map(|v| v.to_le_bytes()).collect();
        let e = to_labels(
            p,
            &neg,
            StoredScalar::I16,
            ByteOrder::Little,
            None,
            [1, 1, 1],
        );
        assert!(e
            .unwrap_err()
            .to_string()
            .contains("outside the label range"));
        // Scaling applies first: 3 × 0.5 is not an integer.
        let s = Some(Scaling {
            slope: 0.5,
            inter: 0.0,
        });
        let e = to_labels(p, &[3], StoredScalar::U8, ByteOrder::Little, s, [1, 1, 1]).unwrap_err();
        assert!(e.to_string().contains("scl_slope"), "{e}");
        let s = Some(Scaling {
            slope: 2.0,
            inter: 1.0,
        });
        assert_eq!(
            to_labels(p, &[3], StoredScalar::U8, ByteOrder::Little, s, [1, 1, 1]).unwrap(),
            vec![7]
        );
    }

    #[test]
    fn ascii_values() {
        let p = Path::new("a.nrrd");
        assert_eq!(
            ascii_to_labels(p, "1 2\n3", 3, [3, 1, 1]).unwrap(),
            vec![1, 2, 3]
        );
        assert!(ascii_to_labels(p, "1 2", 3, [3, 1, 1]).is_err());
        assert!(ascii_to_labels(p, "1 2.5 3", 3, [3, 1, 1]).is_err());
    }
}
