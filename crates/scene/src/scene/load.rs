//! Reading a scene file: parse (TOML or JSON), validate, resolve paths, check referenced files.

use std::path::{Path, PathBuf};

use super::error::{
    json_key_at, line_column, missing_field, offset_of, one_line, toml_key_at,
    toml_value_with_span, Problem,
};
use super::types::{PointSource, Scene};
use super::validate::validate_scene;
use super::SceneError;
use crate::grid::derived_cell_size;

/// The syntax a scene is written in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SceneFormat {
    /// TOML (`.toml`, and any extension other than `.json`).
    Toml,
    /// JSON with the same structure (`.json`).
    Json,
}

impl SceneFormat {
    /// The format for a file name: `.json` (any case) is JSON, everything else TOML. The flag is
    /// true when the extension was neither `.toml` nor `.json` (TOML was guessed).
    pub fn from_path(path: &Path) -> (SceneFormat, bool) {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("json") => (SceneFormat::Json, false),
            Some("toml") => (SceneFormat::Toml, false),
            _ => (SceneFormat::Toml, true),
        }
    }

    /// `"TOML"` or `"JSON"`.
    pub fn name(self) -> &'static str {
        match self {
            SceneFormat::Toml => "TOML",
            SceneFormat::Json => "JSON",
        }
    }
}

/// A validated scene together with where it came from.
///
/// Every path inside [`LoadedScene::scene`] is absolute (resolved against [`LoadedScene::dir`])
/// and names an existing file. Lengths stay in scene units (see [`LoadedScene::length_scale`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedScene {
    /// The validated scene, with absolute paths.
    pub scene: Scene,
    /// The scene file (absolute).
    pub path: PathBuf,
    /// The directory relative paths in the scene are resolved against (absolute).
    pub dir: PathBuf,
}

impl LoadedScene {
    /// `p` if absolute, else `p` relative to the scene file's directory.
    pub fn resolve(&self, p: &Path) -> PathBuf {
        resolve_in(&self.dir, p)
    }

    /// Metres per scene unit (1, 0.01 or 0.001).
    ///
    /// Geometry (the surface, point files, boxes, probes, `cell_size`, the camera) is in scene
    /// units and is *not* rescaled on load; material constants (Pa, kg/m³), tractions (Pa),
    /// gravity (m/s²) and spring stiffnesses (N/m) are SI. A simulation must use one consistent
    /// system: either multiply lengths by this factor and work in SI (then divide displacements
    /// by it before writing results, which are in scene units), or convert the SI constants to
    /// scene units (Pa → N/unit²: × s², N/m → × s, with s = `length_scale()`).
    pub fn length_scale(&self) -> f64 {
        self.scene.units.to_metres()
    }
}

fn resolve_in(dir: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        dir.join(p)
    }
}

/// Read, parse, validate and resolve a scene file.
///
/// `.toml` is read as TOML and `.json` as JSON; any other extension is read as TOML and a parse
/// error then says so. Relative paths in the scene are resolved against the file's directory
/// and must name existing files. Errors always name the file; parse errors carry line:column and
/// the key path, validation errors the key and the offending value (all problems at once).
///
/// # Errors
///
/// [`SceneError::Read`] when the file cannot be read, [`SceneError::Parse`] when it is not a
/// scene (syntax, type, unknown or missing key), [`SceneError::Invalid`] when values are out of
/// range or referenced files are missing.
pub fn load_scene(path: &Path) -> Result<LoadedScene, SceneError> {
    let text = std::fs::read_to_string(path).map_err(|source| SceneError::Read {
        file: path.to_path_buf(),
        source,
    })?;
    let (format, guessed) = SceneFormat::from_path(path);
    load_scene_str_impl(&text, format, guessed, path)
}

/// Like [`load_scene`] for a scene already in memory: `path` is where the scene notionally
/// lives (relative paths are resolved against its directory; errors name it); the file itself
/// is not read.
///
/// # Errors
///
/// As [`load_scene`] (a [`SceneError::Read`] only if `path` cannot be made absolute).
pub fn load_scene_str(
    text: &str,
    format: SceneFormat,
    path: &Path,
) -> Result<LoadedScene, SceneError> {
    load_scene_str_impl(text, format, false, path)
}

fn load_scene_str_impl(
    text: &str,
    format: SceneFormat,
    guessed: bool,
    path: &Path,
) -> Result<LoadedScene, SceneError> {
    let abs = std::path::absolute(path).map_err(|source| SceneError::Read {
        file: path.to_path_buf(),
        source,
    })?;
    let dir = abs.parent().map(Path::to_path_buf).unwrap_or_default();
    let mut scene = parse_impl(text, format, guessed, path)?;
    let mut problems = validate_scene(&scene);
    resolve_paths(&mut scene, &dir);
    check_files(&scene, &mut problems);
    if scene.model.segmentation.is_some() && problems.is_empty() {
        if let Err(message) = super::derived_model::derive_into(&mut scene, &dir) {
            problems.push(Problem {
                key: "model.segmentation".into(),
                message,
            });
        }
    }
    if scene.grid.cell_size_omitted() && problems.is_empty() {
        let derived = crate::mesh::read_surface(&scene.model.surface)
            .map_err(|e| e.to_string())
            .and_then(|s| {
                derived_cell_size(&s).ok_or_else(|| "the surface encloses no volume".to_string())
            });
        match derived {
            Ok(h) => scene.grid.cell_size = h,
            Err(e) => problems.push(Problem {
                key: "grid.cell_size".into(),
                message: format!("omitted, and it cannot be derived from the surface: {e}"),
            }),
        }
    }
    if !problems.is_empty() {
        return Err(SceneError::Invalid {
            file: path.to_path_buf(),
            problems,
        });
    }
    Ok(LoadedScene {
        scene,
        path: abs,
        dir,
    })
}

/// Parse scene text without validating values or touching the file system; paths stay as
/// written. `file` only names the scene in errors.
///
/// # Errors
///
/// [`SceneError::Parse`] on a syntax error, a wrong type, an unknown or a missing key.
pub fn parse_scene(text: &str, format: SceneFormat, file: &Path) -> Result<Scene, SceneError> {
    parse_impl(text, format, false, file)
}

fn parse_impl(
    text: &str,
    format: SceneFormat,
    guessed: bool,
    file: &Path,
) -> Result<Scene, SceneError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let note = if guessed {
        " (the file's extension is neither .toml nor .json, so it was read as TOML)"
    } else {
        ""
    };
    match format {
        SceneFormat::Toml => toml::from_str::<Scene>(text).map_err(|e| {
            let message = one_line(e.message());
            let syntax = toml::de::DeTable::parse(text).is_err();
            let (line, column, key) = match e.span() {
                Some(span) => {
                    let (l, c) = line_column(text, span.start);
                    let key = if syntax {
                        None
                    } else if let Some(field) = missing_field(&message) {
                        // toml puts a "missing field" error on the table that lacks it.
                        Some(match toml_value_with_span(text, span) {
                            Some(p) if !p.is_empty() => format!("{p}.{field}"),
                            _ => field.to_string(),
                        })
                    } else {
                        toml_key_at(text, span.start)
                    };
                    (Some(l), Some(c), key)
                }
                None => (None, None, missing_field(&message).map(str::to_string)),
            };
            let message = if syntax {
                // "duplicate key" does not say which: quote the text it points at.
                let quoted = e
                    .span()
                    .filter(|_| message.starts_with("duplicate"))
                    .and_then(|s| text.get(s))
                    .map(|k| format!(" `{k}`"))
                    .unwrap_or_default();
                format!("syntax error: {message}{quoted}{note}")
            } else {
                format!("{message}{note}")
            };
            SceneError::Parse {
                file: file.to_path_buf(),
                format,
                line,
                column,
                key,
                message,
            }
        }),
        SceneFormat::Json => serde_json::from_str::<Scene>(text).map_err(|e| {
            let message = one_line(&e.to_string_without_position());
            let (line, key) = if e.line() == 0 {
                (None, None)
            } else {
                let offset = offset_of(text, e.line(), e.column());
                let key = if e.is_syntax() || e.is_eof() {
                    None
                } else {
                    match missing_field(&message) {
                        Some(field) => {
                            // The position is at or just after the closing `}` of the object
                            // that lacks the field: scan up to that brace.
                            let upto = (offset + 1).min(text.len());
                            let brace = text.get(..upto).and_then(|t| t.rfind('}'));
                            let parent = json_key_at(text, brace.unwrap_or(offset), true);
                            Some(if parent.is_empty() {
                                field.to_string()
                            } else {
                                format!("{parent}.{field}")
                            })
                        }
                        None => Some(json_key_at(text, offset, false)),
                    }
                };
                (Some(line_column(text, offset)), key)
            };
            let message = if e.is_syntax() || e.is_eof() {
                format!("syntax error: {message}")
            } else {
                message
            };
            SceneError::Parse {
                file: file.to_path_buf(),
                format,
                line: line.map(|(l, _)| l),
                column: line.map(|(_, c)| c),
                key,
                message,
            }
        }),
    }
}

/// serde_json's message without its " at line L column C" suffix (we add our own).
trait WithoutPosition {
    fn to_string_without_position(&self) -> String;
}

impl WithoutPosition for serde_json::Error {
    fn to_string_without_position(&self) -> String {
        let s = self.to_string();
        let suffix = format!(" at line {} column {}", self.line(), self.column());
        s.strip_suffix(&suffix).map(str::to_string).unwrap_or(s)
    }
}

/// Make every path in the scene absolute, relative to `dir`.
fn resolve_paths(scene: &mut Scene, dir: &Path) {
    let r = |p: &mut PathBuf| {
        if !p.as_os_str().is_empty() {
            *p = resolve_in(dir, p);
        }
    };
    r(&mut scene.model.surface);
    if let Some(p) = &mut scene.model.segmentation {
        r(p);
    }
    for s in &mut scene.model.structures {
        if let Some(p) = &mut s.points {
            r(p);
        }
        if let Some(p) = &mut s.mesh {
            r(p);
        }
    }
    for f in &mut scene.boundary.fixed {
        if let Some(PointSource::File(p)) = &mut f.points {
            r(p);
        }
    }
    for p in &mut scene.probe {
        if let PointSource::File(f) = &mut p.points {
            r(f);
        }
    }
}

/// Every referenced file must exist and be a file (paths already resolved).
fn check_files(scene: &Scene, problems: &mut Vec<Problem>) {
    let mut check = |key: String, p: &Path| {
        if p.as_os_str().is_empty() {
            return; // reported by validation
        }
        let message = match std::fs::metadata(p) {
            Ok(m) if m.is_file() => return,
            Ok(_) => format!("`{}` is not a file", p.display()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                format!("file not found: `{}`", p.display())
            }
            Err(e) => format!("cannot access `{}`: {e}", p.display()),
        };
        problems.push(Problem { key, message });
    };
    check("model.surface".into(), &scene.model.surface);
    if let Some(p) = &scene.model.segmentation {
        check("model.segmentation".into(), p);
    }
    for (i, s) in scene.model.structures.iter().enumerate() {
        if let Some(p) = &s.points {
            check(format!("model.structures[{i}].points"), p);
        }
        if let Some(p) = &s.mesh {
            check(format!("model.structures[{i}].mesh"), p);
        }
    }
    for (i, f) in scene.boundary.fixed.iter().enumerate() {
        if let Some(PointSource::File(p)) = &f.points {
            check(format!("boundary.fixed[{i}].points"), p);
        }
    }
    for (i, pr) in scene.probe.iter().enumerate() {
        if let PointSource::File(p) = &pr.points {
            check(format!("probe[{i}].points"), p);
        }
    }
}
