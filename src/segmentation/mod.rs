//! Segmentation labelmaps turned into the model's structures: reading NIfTI-1 and NRRD
//! labelmaps, and extracting closed surfaces (the liver, a tumour) and point sets (vessels).
//!
//! **Coordinates are LPS millimetres** (x → patient's left, y → posterior, z → superior), the
//! convention of DICOM, ITK and 3D Slicer's files; NIfTI's RAS+ is converted by negating x and
//! y. See `docs/segmentation.md`.
//!
//! ```no_run
//! use livereg::segmentation::{read_labelmap, organ_surface, SurfaceOptions, LabelRef};
//! let map = read_labelmap("liver.seg.nrrd".as_ref()).unwrap();
//! let liver = organ_surface(&map, &[LabelRef::from("liver")], &SurfaceOptions::default()).unwrap();
//! livereg::mesh::write_obj("liver.obj".as_ref(), &liver).unwrap();
//! ```
//!
//! One concept per file: [`labelmap`] (the grid, affine, segment names), [`nifti`], [`nrrd`],
//! [`samples`] (stored values → labels), [`mask`] (crop and voxel clean-up), [`isosurface`]
//! (marching cubes), [`taubin`], [`decimate`], [`structure`] (labels → surfaces and points),
//! [`voxelise`] (a closed surface → labels, for phantoms and tests), [`error`].

pub mod decimate;
pub mod error;
pub mod isosurface;
pub mod labelmap;
pub mod mask;
pub mod model;
pub mod nifti;
pub mod nrrd;
pub mod samples;
pub mod structure;
pub mod taubin;
pub mod voxelise;

#[cfg(test)]
mod tests;

use std::path::Path;

pub use decimate::{decimate, Decimation};
pub use error::SegmentationError;
pub use labelmap::{Labelmap, Segment, MAX_VOXELS};
pub use model::{
    default_request, derive_model, derive_model_from, DerivedModel, ModelRequest,
    DEFAULT_MAX_POINTS,
};
pub use nifti::{read_nifti, read_nifti_with_transform, NiftiTransform};
pub use nrrd::{read_nrrd, read_nrrd_layers};
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
    let name = path.to_string_lossy().to_ascii_lowercase();
    if name.ends_with(".nii") || name.ends_with(".nii.gz") {
        read_nifti(path)
    } else if name.ends_with(".nrrd") {
        read_nrrd(path)
    } else {
        Err(SegmentationError::unsupported(
            path,
            "unknown labelmap extension (supported: .nii, .nii.gz, .nrrd, .seg.nrrd)",
        ))
    }
}
