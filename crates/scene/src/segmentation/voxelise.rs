//! The reverse of surface extraction: a closed surface turned into labels on a voxel grid
//! (for phantoms, tests and benchmarks).

use nalgebra::Matrix4;
use rayon::prelude::*;

use super::error::SegmentationError;
use super::labelmap::{check_affine, voxel_count, Labelmap, MAX_VOXELS};
use crate::geometry::InsideTest;
use crate::mesh::TriSurface;

/// Sets `label` on every voxel of `labelmap`-shaped `labels` whose centre is inside `surface`
/// (LPS mm, closed; generalised winding number ≥ ½). The surface is mapped into index space, so
/// each grid column is classified at once along its line ([`InsideTest::classify_line`]),
/// whatever the affine (rotations, anisotropy, negative determinant).
pub fn voxelise_into(
    surface: &TriSurface,
    dims: [usize; 3],
    affine: &Matrix4<f64>,
    labels: &mut [u16],
    label: u16,
) -> Result<(), SegmentationError> {
    check_affine(affine).map_err(SegmentationError::Labelmap)?;
    if voxel_count(dims) != Some(labels.len()) {
        return Err(SegmentationError::Labelmap(format!(
            "{} labels for sizes {dims:?}",
            labels.len()
        )));
    }
    let inv = affine
        .try_inverse()
        .ok_or_else(|| SegmentationError::Labelmap("the affine cannot be inverted".to_owned()))?;
    let vertices: Vec<_> = surface
        .vertices
        .iter()
        .map(|p| inv.transform_point(p))
        .collect();
    let mut triangles = surface.triangles.clone();
    if affine.fixed_view::<3, 3>(0, 0).determinant() < 0.0 {
        // A mirror turns the outward orientation inward; the winding number would be −1.
        for t in &mut triangles {
            t.swap(1, 2);
        }
    }
    let inside = InsideTest::try_new(&vertices, &triangles)
        .map_err(|e| SegmentationError::Surface(e.to_string()))?;
    let [nx, ny, nz] = dims;
    let zs: Vec<f64> = (0..nz).map(|k| k as f64).collect();
    let columns: Vec<Vec<bool>> = (0..nx * ny)
        .into_par_iter()
        .map(|c| {
            let mut out = Vec::with_capacity(nz);
            inside.classify_line((c % nx) as f64, (c / nx) as f64, &zs, &mut out);
            out
        })
        .collect();
    for (c, col) in columns.iter().enumerate() {
        for (k, &is_in) in col.iter().enumerate() {
            if is_in {
                labels[c + nx * ny * k] = label;
            }
        }
    }
    Ok(())
}

/// A labelmap of `dims` with `affine` carrying `label` inside `surface` and 0 elsewhere.
pub fn voxelise(
    surface: &TriSurface,
    dims: [usize; 3],
    affine: Matrix4<f64>,
    label: u16,
) -> Result<Labelmap, SegmentationError> {
    let n = voxel_count(dims)
        .filter(|&n| n <= MAX_VOXELS)
        .ok_or_else(|| SegmentationError::Labelmap(format!("sizes {dims:?} are too large")))?;
    let mut labels = vec![0u16; n];
    voxelise_into(surface, dims, &affine, &mut labels, label)?;
    Labelmap::new(dims, labels, affine)
}
