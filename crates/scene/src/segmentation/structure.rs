//! Labels turned into the model's structures: a closed surface (the liver, a tumour) through
//! crop → clean-up → marching cubes → LPS → Taubin → decimation, and vessel points.

use nalgebra::Point3;

use super::decimate::{decimate_closed, Decimation};
use super::error::SegmentationError;
use super::isosurface::{marching_cubes, BinaryGrid};
use super::labelmap::{LabelSet, Labelmap};
use super::mask::Mask;
use super::taubin::{taubin_smooth, Taubin};
use crate::mesh::{orient_outward, validate, SurfaceReport, TriSurface};

/// How [`extract_surface`] turns labels into a surface. The defaults suit an organ (the liver);
/// [`SurfaceOptions::small_structure`] suits a tumour.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceOptions {
    /// Keep only the largest face-connected (6-connected) piece of the label (default `true`):
    /// stray voxels and islands disappear.
    pub keep_largest_component: bool,
    /// Fill background pockets enclosed by the label (default `true`), e.g. vessels labelled
    /// separately inside the liver, so the result is the outer surface only.
    pub fill_cavities: bool,
    /// Taubin λ|μ smoothing (default `true`).
    pub smooth: bool,
    /// Taubin parameters (default 20 λ|μ pairs, λ = 0.5, μ = −0.53).
    pub taubin: Taubin,
    /// Decimate to this many triangles (default 20 000; 0 = no decimation). The marching-cubes
    /// surface has about 2 triangles per boundary voxel face.
    pub target_triangles: usize,
    /// Decimation safeguards (its `target_triangles` is replaced by the one above).
    pub decimation: Decimation,
}

impl Default for SurfaceOptions {
    fn default() -> Self {
        Self {
            keep_largest_component: true,
            fill_cavities: true,
            smooth: true,
            taubin: Taubin::default(),
            target_triangles: 20_000,
            decimation: Decimation::default(),
        }
    }
}

impl SurfaceOptions {
    /// For a tumour or other small structure: every piece kept (several lesions give several
    /// closed components), 2 000 triangles, otherwise the defaults.
    pub fn small_structure() -> Self {
        Self {
            keep_largest_component: false,
            target_triangles: 2_000,
            ..Self::default()
        }
    }
}

/// A surface extracted from a labelmap, with what happened on the way.
#[derive(Debug, Clone)]
pub struct ExtractedSurface {
    /// The closed, outward-oriented surface in LPS millimetres.
    pub surface: TriSurface,
    /// Its validation report (watertight, no degenerate triangle: checked).
    pub report: SurfaceReport,
    /// Voxels of the labels in the labelmap.
    pub label_voxels: usize,
    /// Voxels dropped as smaller components.
    pub removed_voxels: usize,
    /// Background voxels filled as cavities.
    pub filled_voxels: usize,
    /// Triangles of the marching-cubes surface, before decimation.
    pub marching_cubes_triangles: usize,
    /// Wall-clock time of each stage: crop, clean-up, marching cubes (with the mapping to
    /// LPS), smoothing, decimation, check.
    pub timings: Vec<(&'static str, std::time::Duration)>,
}

/// Names or values of the labels a structure is made of.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LabelRef {
    /// A voxel value.
    Value(u16),
    /// A segment name (3D Slicer's `SegmentN_Name`), matched exactly, then case-insensitively.
    Name(String),
}

impl From<u16> for LabelRef {
    fn from(v: u16) -> Self {
        Self::Value(v)
    }
}

impl From<&str> for LabelRef {
    fn from(s: &str) -> Self {
        s.parse()
            .map(Self::Value)
            .unwrap_or_else(|_| Self::Name(s.to_owned()))
    }
}

/// The voxel values of `refs` in `labelmap`. A name must be a segment of the labelmap.
pub fn resolve_labels(
    labelmap: &Labelmap,
    refs: &[LabelRef],
) -> Result<Vec<u16>, SegmentationError> {
    refs.iter()
        .map(|r| match r {
            LabelRef::Value(v) => Ok(*v),
            LabelRef::Name(n) => labelmap.label_of(n).ok_or_else(|| {
                let known: Vec<String> = labelmap
                    .segments()
                    .iter()
                    .map(|s| format!("'{}' = {}", s.name, s.label))
                    .collect();
                SegmentationError::NoSuchLabel(format!(
                    "no segment is called '{n}' (segments: {})",
                    if known.is_empty() {
                        "none named in the file".to_owned()
                    } else {
                        known.join(", ")
                    }
                ))
            }),
        })
        .collect()
}

fn empty_label(labelmap: &Labelmap, labels: &[u16]) -> SegmentationError {
    SegmentationError::NoSuchLabel(format!(
        "no voxel carries label(s) {labels:?} (labels present: {:?})",
        labelmap.present_labels()
    ))
}

/// The closed surface of the voxels whose label is one of `labels`, in LPS mm, outward CCW:
///
/// 1. crop to the labels' bounding box plus 2 background voxels;
/// 2. optionally keep the largest 6-connected component and fill enclosed cavities;
/// 3. marching cubes on the binary mask (consistent table: always closed and manifold);
/// 4. map through the labelmap's affine (a negative determinant flips the triangles back);
/// 5. optional Taubin smoothing, then quadric decimation to the target triangle count;
/// 6. check: watertight with no degenerate triangle, or an error.
pub fn extract_surface(
    labelmap: &Labelmap,
    labels: &[u16],
    options: &SurfaceOptions,
) -> Result<ExtractedSurface, SegmentationError> {
    let mut clock = std::time::Instant::now();
    let mut timings = Vec::new();
    let mut lap = |name: &'static str| {
        let now = std::time::Instant::now();
        timings.push((name, now - clock));
        clock = now;
    };
    let mut mask =
        Mask::from_labels(labelmap, labels).ok_or_else(|| empty_label(labelmap, labels))?;
    lap("crop");
    let label_voxels = mask.count();
    let removed_voxels = if options.keep_largest_component {
        mask.keep_largest_component()
    } else {
        0
    };
    let filled_voxels = if options.fill_cavities {
        mask.fill_cavities()
    } else {
        0
    };
    lap("clean-up");
    let (index_vertices, triangles) = marching_cubes(&BinaryGrid {
        dims: mask.dims,
        data: &mask.data,
    });
    drop(mask.data);
    let marching_cubes_triangles = triangles.len();
    let origin = mask.origin.map(|o| o as f64);
    let affine = labelmap.affine();
    let vertices = index_vertices
        .into_iter()
        .map(|p| {
            affine.transform_point(&Point3::new(
                p.x + origin[0],
                p.y + origin[1],
                p.z + origin[2],
            ))
        })
        .collect();
    let mut surface = TriSurface::new(vertices, triangles);
    if labelmap.directions().determinant() < 0.0 {
        for t in &mut surface.triangles {
            t.swap(1, 2);
        }
    }
    orient_outward(&mut surface);
    lap("marching cubes");
    if options.smooth {
        taubin_smooth(&mut surface, &options.taubin);
    }
    lap("smoothing");
    if options.target_triangles > 0 {
        let params = Decimation {
            target_triangles: options.target_triangles,
            ..options.decimation
        };
        // Marching cubes gave a closed manifold; Taubin keeps the connectivity.
        surface = decimate_closed(&surface, &params);
    }
    lap("decimation");
    orient_outward(&mut surface);
    let report = validate(&surface);
    lap("check");
    if !report.watertight || report.degenerate_triangles > 0 {
        return Err(SegmentationError::Surface(format!(
            "the surface of label(s) {labels:?} is not a clean closed surface: {report}"
        )));
    }
    Ok(ExtractedSurface {
        surface,
        report,
        label_voxels,
        removed_voxels,
        filled_voxels,
        marching_cubes_triangles,
        timings,
    })
}

/// The liver (or any organ) surface: [`extract_surface`] with `options`, the labels given by
/// value or segment name.
pub fn organ_surface(
    labelmap: &Labelmap,
    labels: &[LabelRef],
    options: &SurfaceOptions,
) -> Result<TriSurface, SegmentationError> {
    let values = resolve_labels(labelmap, labels)?;
    extract_surface(labelmap, &values, options).map(|e| e.surface)
}

/// A tumour as a closed mesh: [`extract_surface`] with [`SurfaceOptions::small_structure`]
/// (every lesion kept, 2 000 triangles).
pub fn tumour_mesh(
    labelmap: &Labelmap,
    labels: &[LabelRef],
) -> Result<TriSurface, SegmentationError> {
    organ_surface(labelmap, labels, &SurfaceOptions::small_structure())
}

/// Vessels as points: the LPS mm centres of the voxels carrying one of `labels`. When there are
/// more than `max_points`, exactly `max_points` are kept, evenly spaced in the voxels' scan
/// order (x fastest, then y, then z) — deterministic, and every part of the vessel tree keeps
/// a share proportional to its voxel count.
pub fn vessel_points(
    labelmap: &Labelmap,
    labels: &[LabelRef],
    max_points: usize,
) -> Result<Vec<Point3<f64>>, SegmentationError> {
    let values = resolve_labels(labelmap, labels)?;
    let set = LabelSet::new(&values);
    let total = labelmap.count(&values);
    if total == 0 {
        return Err(empty_label(labelmap, &values));
    }
    let [nx, ny, _] = labelmap.dims();
    let keep = total.min(max_points);
    let mut out = Vec::with_capacity(keep);
    let mut seen = 0usize;
    for (idx, &l) in labelmap.labels().iter().enumerate() {
        if !set.contains(l) {
            continue;
        }
        // Voxel number `seen` is kept when ⌊seen·keep/total⌋ steps up: exactly `keep` of them.
        let chosen = keep > 0 && ((seen + 1) * keep) / total > (seen * keep) / total;
        seen += 1;
        if chosen {
            let (i, j, k) = (idx % nx, (idx / nx) % ny, idx / (nx * ny));
            out.push(labelmap.index_to_physical(&Point3::new(i as f64, j as f64, k as f64)));
        }
    }
    Ok(out)
}
