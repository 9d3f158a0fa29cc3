//! Segmentation labelmaps turned into the model's structures: reading NIfTI-1 and NRRD
//! labelmaps, and extracting closed surfaces (the liver, a tumour) and point sets (vessels).
//!
//! **Coordinates are LPS millimetres** (x → patient's left, y → posterior, z → superior), the
//! convention of DICOM, ITK and 3D Slicer's files; NIfTI's RAS+ is converted by negating x and
//! y. See `docs/segmentation.md`.
//!
//! ```no_run
//! use livereg_scene::segmentation::{read_labelmap, organ_surface, SurfaceOptions, LabelRef};
//! let map = read_labelmap("liver.seg.nrrd".as_ref()).unwrap();
//! let liver = organ_surface(&map, &[LabelRef::from("liver")], &SurfaceOptions::default()).unwrap();
//! livereg_fem::mesh::write_obj("liver.obj".as_ref(), &liver).unwrap();
//! ```
//!
//! What it offers: [`Labelmap`] (the grid, affine, segment names) read by [`read_labelmap`]
//! ([`read_nifti`], [`read_nrrd`], [`read_nrrd_layers`]); labels turned into surfaces and points
//! ([`organ_surface`], [`extract_surface`], [`tumour_mesh`], [`vessel_points`], with
//! [`SurfaceOptions`]: crop and voxel clean-up, marching cubes, [`taubin_smooth`],
//! [`decimate`]); a scene's model derived from a labelmap ([`derive_model`], [`DerivedModel`]);
//! [`voxelise`] (a closed surface → labels, for phantoms and tests); [`SegmentationError`].

pub(crate) mod decimate;
pub(crate) mod error;
pub(crate) mod isosurface;
pub(crate) mod labelmap;
pub(crate) mod mask;
pub(crate) mod model;
pub(crate) mod nifti;
pub(crate) mod nrrd;
pub(crate) mod samples;
pub(crate) mod structure;
pub(crate) mod taubin;
pub(crate) mod voxelise;

#[cfg(test)]
mod tests;

use std::path::Path;

pub use decimate::{decimate, Decimation};
pub use error::SegmentationError;
pub use labelmap::{Labelmap, Segment, MAX_VOXELS};
pub use model::{
    default_request, derive_model, derive_model_from, derive_model_from_bytes, DerivedModel,
    ModelRequest, DEFAULT_MAX_POINTS,
};
pub use nifti::{read_nifti, read_nifti_bytes, read_nifti_with_transform, NiftiTransform};
pub use nrrd::{read_nrrd, read_nrrd_layers, read_nrrd_layers_bytes};
pub use structure::{
    extract_surface, organ_surface, resolve_labels, tumour_mesh, vessel_points, ExtractedSurface,
    LabelRef, SurfaceOptions,
};
pub use taubin::{taubin_smooth, Taubin};
pub use voxelise::{voxelise, voxelise_into};

/// Reads a labelmap, choosing the reader by the file name (case-insensitive): `.nii` and
/// `.nii.gz` (NIfTI-1), `.nrrd` and `.seg.nrrd` (NRRD, a single layer; see
/// [`read_nrrd_layers`] for several).
pub fn read_labelmap(path: &Path) -> Result<Labelmap, SegmentationError> {
    labelmap_kind(path)?;
    let bytes = std::fs::read(path).map_err(|e| SegmentationError::io(path, e))?;
    read_labelmap_bytes(path, &bytes)
}

/// [`read_labelmap`] of a file's bytes already in memory (e.g. read once to hash them too);
/// `path` chooses the reader by its name and names the file in errors.
pub fn read_labelmap_bytes(path: &Path, bytes: &[u8]) -> Result<Labelmap, SegmentationError> {
    match labelmap_kind(path)? {
        LabelmapKind::Nifti => read_nifti_bytes(path, bytes).map(|(l, _)| l),
        LabelmapKind::Nrrd => nrrd::single_layer(path, read_nrrd_layers_bytes(path, bytes)?),
    }
}

/// The labelmap formats, told apart by the file name.
enum LabelmapKind {
    Nifti,
    Nrrd,
}

/// The format of the labelmap at `path`, or an error naming the supported extensions.
fn labelmap_kind(path: &Path) -> Result<LabelmapKind, SegmentationError> {
    let name = path.to_string_lossy().to_ascii_lowercase();
    if name.ends_with(".nii") || name.ends_with(".nii.gz") {
        Ok(LabelmapKind::Nifti)
    } else if name.ends_with(".nrrd") {
        Ok(LabelmapKind::Nrrd)
    } else {
        Err(SegmentationError::unsupported(
            path,
            "unknown labelmap extension (supported: .nii, .nii.gz, .nrrd, .seg.nrrd)",
        ))
    }
}
