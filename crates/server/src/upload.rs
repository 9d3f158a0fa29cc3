//! A scene uploaded by a client, with the files it names, turned into a [`LoadedScene`] and a
//! [`Session`]: inline JSON arrays or uploaded files, written to a private directory under the
//! data directory, with every path of the scene confined to that directory.

use crate::simulation::FromScene;
use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::{Component, Path};

use serde::{Deserialize, Serialize};

use super::config::LimitsConfig;
use super::error::ApiError;
use super::limits::{check_scene_size, check_scene_work};
use crate::scene::{load_scene, parse_scene, LoadedScene, SceneFormat};
use crate::session::Session;

/// A scene and its files, however they arrived.
#[derive(Debug, Clone, Default)]
pub(crate) struct SceneUpload {
    /// The scene file's text.
    pub scene: String,
    /// Its syntax.
    pub format: Option<SceneFormat>,
    /// File name → content.
    pub files: BTreeMap<String, Vec<u8>>,
    /// Per-frame time budget override, ms.
    pub budget_ms: Option<f64>,
    /// Rigid stage only.
    pub rigid_only: bool,
}

/// An inline triangle mesh (written as OBJ).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct InlineMesh {
    /// Vertex positions, scene units.
    pub vertices: Vec<[f64; 3]>,
    /// Triangles as 0-based vertex indices, outward (right-hand) orientation.
    pub triangles: Vec<[u32; 3]>,
}

/// `POST /v1/sessions` with `Content-Type: application/json`.
///
/// `scene` is the scene as a JSON object (or a TOML string); the names its paths use
/// (`model.surface`, structure `points`/`mesh`, fixed `points`) are keys of `meshes`,
/// `points` or `files`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CreateSessionJson {
    /// The scene: a JSON object with the scene file's structure, or TOML text.
    pub scene: serde_json::Value,
    /// Inline meshes by file name (must end in `.obj`).
    #[serde(default)]
    pub meshes: BTreeMap<String, InlineMesh>,
    /// Inline point sets by file name (must end in `.xyz`).
    #[serde(default)]
    pub points: BTreeMap<String, Vec<[f64; 3]>>,
    /// Other files as text (OBJ, OFF, PLY ASCII, point files …) by file name.
    #[serde(default)]
    pub files: BTreeMap<String, String>,
    /// Per-frame time budget, ms (overrides the scene's).
    #[serde(default)]
    pub budget_ms: Option<f64>,
    /// Rigid registration only.
    #[serde(default)]
    pub rigid_only: bool,
}

/// Checks an uploaded file name: 1–128 characters of `A-Z a-z 0-9 . _ -`, not starting with a
/// dot (no directories, no traversal).
pub(crate) fn check_file_name(name: &str) -> Result<(), ApiError> {
    let ok = !name.is_empty()
        && name.len() <= 128
        && !name.starts_with('.')
        && name
            .bytes()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, b'.' | b'_' | b'-'));
    if ok {
        Ok(())
    } else {
        Err(ApiError::invalid_scene(format!(
            "file name {:?} is not allowed: use 1-128 characters of A-Z a-z 0-9 . _ - without directories",
            name.chars().take(140).collect::<String>()
        )))
    }
}

fn ends_with(name: &str, exts: &[&str]) -> bool {
    let lower = name.to_ascii_lowercase();
    exts.iter().any(|e| lower.ends_with(e))
}

impl CreateSessionJson {
    /// The upload this request describes (inline meshes and points rendered as OBJ and XYZ).
    pub(crate) fn into_upload(self) -> Result<SceneUpload, ApiError> {
        let (scene, format) = match self.scene {
            serde_json::Value::String(toml) => (toml, SceneFormat::Toml),
            v @ serde_json::Value::Object(_) => (v.to_string(), SceneFormat::Json),
            _ => {
                return Err(ApiError::bad_request(
                    "`scene` must be a JSON object (the scene) or a string (TOML text)",
                ))
            }
        };
        let mut files = BTreeMap::new();
        for (name, m) in self.meshes {
            check_file_name(&name)?;
            if !ends_with(&name, &[".obj"]) {
                return Err(ApiError::invalid_scene(format!(
                    "inline mesh `{name}`: inline meshes are stored as OBJ, so the name must end in .obj"
                )));
            }
            let mut text = String::new();
            for v in &m.vertices {
                let _ = writeln!(text, "v {} {} {}", v[0], v[1], v[2]);
            }
            for (i, t) in m.triangles.iter().enumerate() {
                if let Some(bad) = t.iter().find(|&&k| k as usize >= m.vertices.len()) {
                    return Err(ApiError::invalid_scene(format!(
                        "inline mesh `{name}`: triangle {i} uses vertex {bad}, but there are {} vertices",
                        m.vertices.len()
                    )));
                }
                let _ = writeln!(text, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
            }
            files.insert(name, text.into_bytes());
        }
        for (name, pts) in self.points {
            check_file_name(&name)?;
            if !ends_with(&name, &[".xyz"]) {
                return Err(ApiError::invalid_scene(format!(
                    "inline points `{name}`: inline point sets are stored as XYZ text, so the name must end in .xyz"
                )));
            }
            let mut text = String::new();
            for p in &pts {
                let _ = writeln!(text, "{} {} {}", p[0], p[1], p[2]);
            }
            files.insert(name, text.into_bytes());
        }
        for (name, text) in self.files {
            check_file_name(&name)?;
            if files.insert(name.clone(), text.into_bytes()).is_some() {
                return Err(ApiError::invalid_scene(format!(
                    "file `{name}` is given twice"
                )));
            }
        }
        Ok(SceneUpload {
            scene,
            format: Some(format),
            files,
            budget_ms: self.budget_ms,
            rigid_only: self.rigid_only,
        })
    }
}

/// Every file path a scene names, with its key.
fn plain_name(p: &Path) -> Option<&str> {
    let mut comps = p.components();
    match (comps.next(), comps.next()) {
        (Some(Component::Normal(n)), None) => n.to_str(),
        _ => None,
    }
}

/// Writes the upload into `dir` (created) after checking names, confinement and sizes, and
/// loads the scene from there. Errors name the key, file and limit concerned; paths in
/// messages are shown relative to the upload.
pub(crate) fn materialize(
    upload: &SceneUpload,
    dir: &Path,
    limits: &LimitsConfig,
) -> Result<LoadedScene, ApiError> {
    let format = upload.format.unwrap_or(SceneFormat::Toml);
    let scene_name = match format {
        SceneFormat::Toml => "scene.toml",
        SceneFormat::Json => "scene.json",
    };
    let hide = |m: String| hide_server_paths(&m, dir);
    let scene = parse_scene(&upload.scene, format, Path::new(scene_name))
        .map_err(|e| ApiError::invalid_scene(e.to_string()))?;
    check_scene_work(limits, &scene)?;
    if scene.model.segmentation.is_some() {
        return Err(ApiError::invalid_scene(
            "model.segmentation is not accepted in uploaded scenes (a labelmap can inflate to \
             gigabytes): derive the model with `livereg model` and upload its surface and \
             structure files",
        ));
    }
    for name in upload.files.keys() {
        check_file_name(name)?;
        if name == scene_name {
            return Err(ApiError::invalid_scene(format!(
                "`{name}` is reserved for the scene itself"
            )));
        }
    }
    for (key, p) in scene.file_keys() {
        let name = plain_name(&p).ok_or_else(|| {
            ApiError::invalid_scene(format!(
                "{key} = {:?}: uploaded scenes may only name files uploaded with them (a plain file name, no directories)",
                p.display().to_string()
            ))
        })?;
        if !upload.files.contains_key(name) {
            return Err(ApiError::invalid_scene(format!(
                "{key} names `{name}`, which was not uploaded (uploaded: {})",
                if upload.files.is_empty() {
                    "nothing".to_string()
                } else {
                    upload.files.keys().cloned().collect::<Vec<_>>().join(", ")
                }
            )));
        }
    }
    std::fs::create_dir_all(dir)
        .map_err(|e| ApiError::internal(format!("cannot create the session directory: {e}")))?;
    for (name, bytes) in &upload.files {
        std::fs::write(dir.join(name), bytes)
            .map_err(|e| ApiError::internal(format!("cannot store `{name}`: {e}")))?;
    }
    let scene_path = dir.join(scene_name);
    std::fs::write(&scene_path, &upload.scene)
        .map_err(|e| ApiError::internal(format!("cannot store the scene: {e}")))?;
    // Mesh sizes and the grid before anything expensive.
    let mut meshes = vec![("model.surface", scene.model.surface.clone())];
    meshes.extend(
        scene
            .model
            .structures
            .iter()
            .filter_map(|s| s.mesh.clone().map(|m| ("structure mesh", m))),
    );
    for (i, (key, rel)) in meshes.iter().enumerate() {
        let path = dir.join(rel);
        let surface = crate::mesh::read_surface(&path)
            .map_err(|e| ApiError::invalid_scene(hide(format!("{key}: {e}"))))?;
        let bbox = (i == 0 && !surface.vertices.is_empty()).then(|| {
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            for v in &surface.vertices {
                for (k, c) in v.coords.iter().enumerate() {
                    lo[k] = lo[k].min(*c);
                    hi[k] = hi[k].max(*c);
                }
            }
            (lo, hi)
        });
        check_scene_size(
            limits,
            &rel.display().to_string(),
            surface.triangles.len(),
            scene.grid.subdivisions,
            bbox,
            scene.grid.cell_size,
        )?;
    }
    load_scene(&scene_path).map_err(|e| ApiError::invalid_scene(hide(e.to_string())))
}

/// `message` with the session directory `dir` (as given and canonicalised) removed from
/// every path, so that a file shows as the name it was uploaded under: the client learns
/// which of its files is wrong, never where the server keeps it.
pub(crate) fn hide_server_paths(message: &str, dir: &Path) -> String {
    let mut forms = vec![dir.to_path_buf()];
    if let Ok(c) = dir.canonicalize() {
        forms.push(c);
    }
    if let Ok(abs) = std::path::absolute(dir) {
        forms.push(abs);
    }
    // Longest first: an absolute form contains the relative one.
    forms.sort_by_key(|f| std::cmp::Reverse(f.as_os_str().len()));
    let mut out = message.to_string();
    for f in forms {
        let shown = f.display().to_string();
        if shown.is_empty() {
            continue;
        }
        out = out
            .replace(&format!("{shown}/"), "")
            .replace(&shown, "the upload");
    }
    out
}

/// The uploaded scene loaded from `dir` and its session built ([`materialize`] then
/// [`build_session`]); every error's message names the upload's files, never a server path.
pub(crate) fn prepare_session(
    upload: &SceneUpload,
    dir: &Path,
    limits: &LimitsConfig,
) -> Result<(LoadedScene, Session), ApiError> {
    let hide = |mut e: ApiError| {
        e.message = hide_server_paths(&e.message, dir);
        e
    };
    let loaded = materialize(upload, dir, limits).map_err(hide)?;
    let session = build_session(&loaded, upload, limits).map_err(hide)?;
    Ok((loaded, session))
}

/// A session for a loaded scene with the upload's overrides (budget, rigid only); its time
/// budget is at most `limits.max_frame_ms` whatever the scene or the upload asks. Its errors
/// may name the files where the scene was loaded from: [`prepare_session`] hides them.
pub(crate) fn build_session(
    loaded: &LoadedScene,
    upload: &SceneUpload,
    limits: &LimitsConfig,
) -> Result<Session, ApiError> {
    let mut session = Session::from_scene(loaded)
        .map_err(|e| ApiError::invalid_scene(format!("the model cannot be built: {e}")))?;
    if let Some(b) = upload.budget_ms {
        if !(b.is_finite() && b > 0.0) {
            return Err(ApiError::invalid_scene(format!(
                "budget_ms must be > 0, got {b}"
            )));
        }
        session.settings.time_budget_ms = Some(b);
    }
    let budget = &mut session.settings.time_budget_ms;
    *budget = Some(budget.map_or(limits.max_frame_ms, |b| b.min(limits.max_frame_ms)));
    session.settings.non_rigid = !upload.rigid_only;
    Ok(session)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_paths_are_confined_to_the_upload() {
        for bad in [
            "",
            "../x.obj",
            "a/b.obj",
            ".hidden",
            "x y.obj",
            "/etc/passwd",
        ] {
            assert!(check_file_name(bad).is_err(), "{bad}");
        }
        check_file_name("liver-01_v2.obj").unwrap();
        let dir = std::env::temp_dir().join(format!("livereg-upload-{}", std::process::id()));
        let scene = "[model]\nsurface = \"/etc/passwd\"\n[grid]\ncell_size = 1.0\n[material]\nyoung_modulus = 1000.0\npoisson_ratio = 0.3\n";
        let up = SceneUpload {
            scene: scene.into(),
            ..Default::default()
        };
        let e = materialize(&up, &dir, &LimitsConfig::default()).unwrap_err();
        assert!(e.message.contains("model.surface"), "{}", e.message);
        let up = SceneUpload {
            scene: scene.replace("/etc/passwd", "liver.obj"),
            ..Default::default()
        };
        let e = materialize(&up, &dir, &LimitsConfig::default()).unwrap_err();
        assert!(e.message.contains("not uploaded"), "{}", e.message);
        assert!(!dir.exists());
    }
}
