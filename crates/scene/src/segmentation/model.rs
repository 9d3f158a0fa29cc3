//! A whole patient model from one labelmap: the organ's closed surface, tumours as closed
//! meshes, vessels as points — what `livereg model` writes and what a scene's
//! `model.segmentation` key builds on load.

use std::path::Path;
use std::time::Instant;

use nalgebra::Point3;

use super::{
    extract_surface, read_labelmap, read_labelmap_bytes, resolve_labels, vessel_points, LabelRef,
    Labelmap, SegmentationError, SurfaceOptions,
};
use crate::mesh::{SurfaceReport, TriSurface};

/// What to derive from a labelmap.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelRequest {
    /// The organ's labels (values or segment names), united into one surface.
    pub organ: Vec<LabelRef>,
    /// Structures as closed meshes (a tumour): name and labels.
    pub meshes: Vec<(String, Vec<LabelRef>)>,
    /// Structures as points (vessels: voxel centres): name and labels.
    pub points: Vec<(String, Vec<LabelRef>)>,
    /// The organ surface's options (its `target_triangles` is the organ's size).
    pub organ_options: SurfaceOptions,
    /// Most points per point structure.
    pub max_points: usize,
}

impl ModelRequest {
    /// The organ of `organ` alone, default options, 2 000 points per point structure.
    pub fn organ(organ: Vec<LabelRef>) -> Self {
        Self {
            organ,
            meshes: Vec::new(),
            points: Vec::new(),
            organ_options: SurfaceOptions::default(),
            max_points: DEFAULT_MAX_POINTS,
        }
    }
}

/// What to derive when nothing is named: the organ is the segment whose name contains
/// "liver" (ignoring case), else the only label, else label 1; every other label present
/// becomes a structure named after its segment (or `label-N`): points when the name says it
/// is a vessel (`vessel`, `vein`, `artery`, `portal`, `hepatic`, `cava`), a closed mesh
/// otherwise (a tumour). An error lists the labels present when no organ can be told.
pub fn default_request(map: &Labelmap, path: &Path) -> Result<ModelRequest, SegmentationError> {
    let present = map.present_labels();
    let named = |l: u16| {
        map.segments()
            .iter()
            .find(|s| s.label == l)
            .map(|s| s.name.clone())
    };
    let organ = map
        .segments()
        .iter()
        .find(|s| s.name.to_ascii_lowercase().contains("liver") && present.contains(&s.label))
        .map(|s| s.label)
        .or_else(|| (present.len() == 1).then(|| present[0]))
        .or_else(|| present.contains(&1).then_some(1))
        .ok_or_else(|| {
            SegmentationError::data(
                path,
                format!(
                    "cannot tell the organ's label (no segment named like \"liver\", no label 1; \
                     labels present: {present:?}): name it with --label"
                ),
            )
        })?;
    let mut request = ModelRequest::organ(vec![LabelRef::Value(organ)]);
    for &l in present.iter().filter(|&&l| l != organ) {
        let name = named(l).unwrap_or_else(|| format!("label-{l}"));
        let lower = name.to_ascii_lowercase();
        let vessel = ["vessel", "vein", "artery", "portal", "hepatic", "cava"]
            .iter()
            .any(|k| lower.contains(k));
        if vessel {
            request.points.push((name, vec![LabelRef::Value(l)]));
        } else {
            request.meshes.push((name, vec![LabelRef::Value(l)]));
        }
    }
    Ok(request)
}

/// Default cap on the points of a point structure (vessels).
pub const DEFAULT_MAX_POINTS: usize = 2_000;

/// A derived model, LPS millimetres.
#[derive(Debug, Clone)]
pub struct DerivedModel {
    /// The organ's closed surface.
    pub surface: TriSurface,
    /// Its validation report (watertight, volume in mm³, …).
    pub report: SurfaceReport,
    /// Mesh structures: name and closed surface.
    pub meshes: Vec<(String, TriSurface)>,
    /// Point structures: name and points.
    pub points: Vec<(String, Vec<Point3<f64>>)>,
    /// Labelmap dimensions.
    pub dims: [usize; 3],
    /// Milliseconds spent reading the labelmap, and deriving everything.
    pub read_ms: f64,
    /// Milliseconds spent extracting surfaces and points.
    pub derive_ms: f64,
}

/// Reads the labelmap at `path` and derives `request` from it. A label that is absent or
/// unknown, or an organ surface that does not come out closed, is an error naming the file
/// and the label.
pub fn derive_model(
    path: &Path,
    request: &ModelRequest,
) -> Result<DerivedModel, SegmentationError> {
    let t0 = Instant::now();
    let map = read_labelmap(path)?;
    let read_ms = t0.elapsed().as_secs_f64() * 1e3;
    derive_model_from(&map, path, request, read_ms)
}

/// [`derive_model`] of a labelmap file's bytes already in memory (read once, e.g. to hash
/// them as well); `path` chooses the reader and names the file in errors.
pub fn derive_model_from_bytes(
    path: &Path,
    bytes: &[u8],
    request: &ModelRequest,
) -> Result<DerivedModel, SegmentationError> {
    let t0 = Instant::now();
    let map = read_labelmap_bytes(path, bytes)?;
    let read_ms = t0.elapsed().as_secs_f64() * 1e3;
    derive_model_from(&map, path, request, read_ms)
}

/// [`derive_model`] of a labelmap already read from `path` (which names errors), `read_ms`
/// after reading it.
pub fn derive_model_from(
    map: &Labelmap,
    path: &Path,
    request: &ModelRequest,
    read_ms: f64,
) -> Result<DerivedModel, SegmentationError> {
    derive(map, path, request, read_ms).map_err(|e| naming(path, e))
}

/// `e`, naming `path` when it does not already (a missing label, a failed extraction).
fn naming(path: &Path, e: SegmentationError) -> SegmentationError {
    match e {
        SegmentationError::Labelmap(m)
        | SegmentationError::NoSuchLabel(m)
        | SegmentationError::Surface(m) => SegmentationError::data(path, m),
        other => other,
    }
}

fn derive(
    map: &Labelmap,
    path: &Path,
    request: &ModelRequest,
    read_ms: f64,
) -> Result<DerivedModel, SegmentationError> {
    let t1 = Instant::now();
    let organ = resolve_labels(map, &request.organ)?;
    let extracted = extract_surface(map, &organ, &request.organ_options)?;
    if !extracted.report.watertight {
        return Err(SegmentationError::data(
            path,
            format!(
                "the surface of labels {:?} is not closed ({} boundary, {} non-manifold edges)",
                request.organ, extracted.report.boundary_edges, extracted.report.non_manifold_edges
            ),
        ));
    }
    let mut meshes = Vec::new();
    for (name, labels) in &request.meshes {
        let values = resolve_labels(map, labels)?;
        let e = extract_surface(map, &values, &SurfaceOptions::small_structure())?;
        meshes.push((name.clone(), e.surface));
    }
    let mut points = Vec::new();
    for (name, labels) in &request.points {
        points.push((
            name.clone(),
            vessel_points(map, labels, request.max_points)?,
        ));
    }
    Ok(DerivedModel {
        surface: extracted.surface,
        report: extracted.report,
        meshes,
        points,
        dims: map.dims(),
        read_ms,
        derive_ms: t1.elapsed().as_secs_f64() * 1e3,
    })
}
