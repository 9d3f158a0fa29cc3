//! `model.segmentation`: the model's surface (and `mesh_label` / `points_label` structures)
//! derived from a labelmap when the scene loads, through [`crate::segmentation::derive_model_from_bytes`]
//! (the labelmap is read once, for its hash and, on a cache miss, its voxels).
//!
//! The derived files are kept in `<scene dir>/.livereg-derived/<labelmap>-<key>/` (or under
//! the system's temporary directory when the scene's directory cannot be written), `key`
//! being a hash of the labelmap's bytes, the labels asked for and this build's version: a
//! scene loads from its labelmap once, and again only when something changed. After
//! derivation the loaded scene names those files as if written by hand (`model.surface`,
//! `structures[i].mesh` / `.points`) and the derivation keys are cleared, so everything
//! downstream (grid, recordings, replays, calibration) sees an ordinary scene.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use livereg_fem::random::fnv1a;

use super::types::Scene;
use crate::mesh::{write_obj, write_points};
use crate::segmentation::{
    derive_model_from_bytes, ModelRequest, SurfaceOptions, DEFAULT_MAX_POINTS,
};

/// Where derived models are kept inside a scene's directory.
pub(crate) const DERIVED_DIR: &str = ".livereg-derived";

/// Derives the model of `scene` (paths resolved against `dir`) from its
/// `model.segmentation` and rewrites the scene to name the derived files; the error is a
/// one-line message for the `model.segmentation` key.
pub(crate) fn derive_into(scene: &mut Scene, dir: &Path) -> Result<(), String> {
    let Some(labelmap) = scene.model.segmentation.clone() else {
        return Ok(());
    };
    let organ = scene
        .model
        .label
        .as_ref()
        .map(|l| l.refs())
        .unwrap_or_default();
    let mut request = ModelRequest {
        organ,
        meshes: Vec::new(),
        points: Vec::new(),
        organ_options: SurfaceOptions {
            target_triangles: scene.model.target_triangles.unwrap_or(20_000),
            ..SurfaceOptions::default()
        },
        max_points: DEFAULT_MAX_POINTS,
    };
    for s in &scene.model.structures {
        if let Some(l) = &s.mesh_label {
            request.meshes.push((s.name.clone(), l.refs()));
        }
        if let Some(l) = &s.points_label {
            request.points.push((s.name.clone(), l.refs()));
        }
    }
    let bytes = std::fs::read(&labelmap).map_err(|e| format!("{}: {e}", labelmap.display()))?;
    // FNV-1a of the labelmap then the request: a cache key, not a security measure.
    let key = fnv1a(
        bytes
            .iter()
            .copied()
            .chain(format!("{request:?} {}", env!("CARGO_PKG_VERSION")).into_bytes()),
    );
    let name = labelmap
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let leaf = format!("{name}-{key:016x}");
    let source = LabelmapFile {
        path: &labelmap,
        bytes: &bytes,
    };
    let out = match cached_or_derived(&dir.join(DERIVED_DIR).join(&leaf), &source, &request) {
        Ok(p) => p,
        // A read-only scene directory: the system's temporary directory instead.
        Err(_) => cached_or_derived(
            &std::env::temp_dir().join("livereg-derived").join(&leaf),
            &source,
            &request,
        )?,
    };
    drop(bytes);
    scene.model.surface = out.join("liver.obj");
    let (mut m, mut p) = (0, 0);
    for s in &mut scene.model.structures {
        if s.mesh_label.take().is_some() {
            s.mesh = Some(out.join(format!("mesh{m}.obj")));
            m += 1;
        }
        if s.points_label.take().is_some() {
            s.points = Some(out.join(format!("points{p}.xyz")));
            p += 1;
        }
    }
    scene.model.segmentation = None;
    scene.model.label = None;
    scene.model.target_triangles = None;
    Ok(())
}

/// A labelmap file read once: its path (for the reader's choice and for errors) and bytes.
struct LabelmapFile<'a> {
    path: &'a Path,
    bytes: &'a [u8],
}

/// The directory `target` holding the derived files: as found (a complete earlier
/// derivation), or derived now, written beside it and renamed into place.
fn cached_or_derived(
    target: &Path,
    source: &LabelmapFile,
    request: &ModelRequest,
) -> Result<PathBuf, String> {
    if target.join("complete").is_file() {
        return Ok(target.to_path_buf());
    }
    let labelmap = source.path;
    let model =
        derive_model_from_bytes(labelmap, source.bytes, request).map_err(|e| e.to_string())?;
    let parent = target.parent().unwrap_or(target);
    std::fs::create_dir_all(parent).map_err(|e| format!("{}: {e}", parent.display()))?;
    let partial = parent.join(format!(
        ".partial-{}-{}",
        std::process::id(),
        target
            .file_name()
            .map(|n| n.to_string_lossy())
            .unwrap_or_default()
    ));
    let _ = std::fs::remove_dir_all(&partial);
    std::fs::create_dir_all(&partial).map_err(|e| format!("{}: {e}", partial.display()))?;
    let write = || -> Result<(), String> {
        write_obj(&partial.join("liver.obj"), &model.surface).map_err(|e| e.to_string())?;
        for (k, (_, mesh)) in model.meshes.iter().enumerate() {
            write_obj(&partial.join(format!("mesh{k}.obj")), mesh).map_err(|e| e.to_string())?;
        }
        for (k, (_, pts)) in model.points.iter().enumerate() {
            write_points(&partial.join(format!("points{k}.xyz")), pts)
                .map_err(|e| e.to_string())?;
        }
        let mut note = String::new();
        let _ = writeln!(
            note,
            "derived from {} ({} triangles, {:.1} mL)",
            labelmap.display(),
            model.surface.triangles.len(),
            model.report.signed_volume * 1e-3
        );
        std::fs::write(partial.join("complete"), note).map_err(|e| e.to_string())
    };
    if let Err(e) = write() {
        let _ = std::fs::remove_dir_all(&partial);
        return Err(e);
    }
    if std::fs::rename(&partial, target).is_err() {
        // Another process finished the same derivation first: use theirs.
        let _ = std::fs::remove_dir_all(&partial);
        if !target.join("complete").is_file() {
            return Err(format!(
                "{}: cannot store the derived model",
                target.display()
            ));
        }
    }
    Ok(target.to_path_buf())
}
