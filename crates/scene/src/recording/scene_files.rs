//! The scene and its files as one self-contained value: recorded on `/scene`, rebuilt into a
//! directory on replay (optionally with changed keys).

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::base64;
use super::messages::{SceneFileEntry, SceneMessage};
use super::RecordingError;
use crate::scene::{load_scene, LoadedScene, SceneFormat};

/// A scene file's text and the bytes of every file it names.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneFiles {
    /// File name of the scene (`scene.toml`).
    pub name: String,
    /// Its syntax.
    pub format: SceneFormat,
    /// Its text, verbatim.
    pub text: String,
    /// The files it names: scene key, path read from, bytes.
    pub files: Vec<(String, PathBuf, Vec<u8>)>,
}

/// Files by the names a self-contained scene document gives them, with their bytes.
pub(crate) type NamedFiles<'a> = Vec<(String, &'a [u8])>;

impl SceneFiles {
    /// Reads the scene file of `loaded` and every file it names (surface, structures, point
    /// files of fixed regions and probes).
    pub fn from_loaded(loaded: &LoadedScene) -> Result<Self, RecordingError> {
        let read_err = |p: &Path, e: std::io::Error| {
            RecordingError::Scene(format!(
                "{}: cannot read for the recording: {e}",
                p.display()
            ))
        };
        let text = std::fs::read_to_string(&loaded.path).map_err(|e| read_err(&loaded.path, e))?;
        let (format, _) = SceneFormat::from_path(&loaded.path);
        let mut files = Vec::new();
        for (key, path) in scene_file_keys(loaded) {
            let bytes = std::fs::read(&path).map_err(|e| read_err(&path, e))?;
            files.push((key, path, bytes));
        }
        Ok(Self {
            name: file_name(&loaded.path),
            format,
            text,
            files,
        })
    }

    /// The `/scene` message.
    pub fn to_message(&self) -> SceneMessage {
        SceneMessage {
            name: self.name.clone(),
            format: match self.format {
                SceneFormat::Toml => "toml".into(),
                SceneFormat::Json => "json".into(),
            },
            text: self.text.clone(),
            files: self
                .files
                .iter()
                .map(|(key, path, bytes)| SceneFileEntry {
                    key: key.clone(),
                    path: path.display().to_string(),
                    name: file_name(path),
                    size: bytes.len() as u64,
                    data_base64: base64::encode(bytes),
                })
                .collect(),
        }
    }

    /// The scene of a `/scene` message.
    pub fn from_message(m: &SceneMessage) -> Result<Self, String> {
        let format = match m.format.as_str() {
            "toml" => SceneFormat::Toml,
            "json" => SceneFormat::Json,
            other => return Err(format!("unknown scene format `{other}`")),
        };
        let mut files = Vec::new();
        for f in &m.files {
            let bytes = base64::decode(&f.data_base64)
                .map_err(|e| format!("scene file `{}` ({}): {e}", f.name, f.key))?;
            if bytes.len() as u64 != f.size {
                return Err(format!(
                    "scene file `{}` ({}): {} bytes decoded, {} recorded",
                    f.name,
                    f.key,
                    bytes.len(),
                    f.size
                ));
            }
            files.push((f.key.clone(), PathBuf::from(&f.path), bytes));
        }
        Ok(Self {
            name: m.name.clone(),
            format,
            text: m.text.clone(),
            files,
        })
    }

    /// The scene as one self-contained document: the derivation keys of a model derived from
    /// a labelmap removed (the derived files stand for it), and every file key naming
    /// `<prefix>NN-<file name>` (NN its index; characters other than `A-Z a-z 0-9 . _ -` in
    /// the file name become `_`), with those names → bytes.
    pub fn self_contained(&self, prefix: &str) -> Result<(Value, NamedFiles<'_>), RecordingError> {
        let mut doc: Value = match self.format {
            SceneFormat::Toml => {
                let t: toml::Table = toml::from_str(&self.text).map_err(|e| {
                    RecordingError::Scene(format!("recorded scene `{}`: {e}", self.name))
                })?;
                serde_json::to_value(t).map_err(|e| RecordingError::Scene(e.to_string()))?
            }
            SceneFormat::Json => serde_json::from_str(&self.text).map_err(|e| {
                RecordingError::Scene(format!("recorded scene `{}`: {e}", self.name))
            })?,
        };
        // A scene whose model was derived from a labelmap is recorded with the derived files
        // under the ordinary keys: the derivation keys go (replay uses the recorded model).
        strip_derivation_keys(&mut doc);
        let mut files = Vec::with_capacity(self.files.len());
        for (i, (key, path, bytes)) in self.files.iter().enumerate() {
            let plain: String = file_name(path)
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                        c
                    } else {
                        '_'
                    }
                })
                .collect();
            let rel = format!("{prefix}{i:02}-{plain}");
            set_key(&mut doc, key, Value::String(rel.clone()), true)
                .map_err(|e| RecordingError::Scene(format!("recorded scene: {e}")))?;
            files.push((rel, bytes.as_slice()));
        }
        Ok((doc, files))
    }

    /// Writes the scene into `dir` (created) as `scene.json` with its files under `files/`,
    /// after setting each `key=value` of `overrides` (dotted keys as in the scene reference,
    /// `[i]` for array entries; the value is read as a TOML value, or else taken as a string),
    /// and loads it.
    pub fn materialize(
        &self,
        dir: &Path,
        overrides: &[String],
    ) -> Result<LoadedScene, RecordingError> {
        let io = |p: &Path, e: std::io::Error| {
            RecordingError::Scene(format!(
                "{}: cannot write the recorded scene: {e}",
                p.display()
            ))
        };
        let files_dir = dir.join("files");
        std::fs::create_dir_all(&files_dir).map_err(|e| io(&files_dir, e))?;
        let (mut doc, files) = self.self_contained("files/")?;
        for (rel, bytes) in files {
            let target = dir.join(&rel);
            std::fs::write(&target, bytes).map_err(|e| io(&target, e))?;
        }
        for o in overrides {
            let (key, value) = o
                .split_once('=')
                .ok_or_else(|| RecordingError::Scene(format!("--set `{o}`: expected KEY=VALUE")))?;
            let value = parse_value(value.trim());
            set_key(&mut doc, key.trim(), value, true)
                .map_err(|e| RecordingError::Scene(format!("--set `{o}`: {e}")))?;
        }
        let scene_path = dir.join("scene.json");
        let text =
            serde_json::to_string_pretty(&doc).map_err(|e| RecordingError::Scene(e.to_string()))?;
        std::fs::write(&scene_path, text).map_err(|e| io(&scene_path, e))?;
        load_scene(&scene_path).map_err(|e| RecordingError::Scene(format!("recorded scene: {e}")))
    }
}

/// Every file a loaded scene names, with the key naming it (paths absolute):
/// [`crate::scene::Scene::file_keys`].
pub(crate) fn scene_file_keys(loaded: &LoadedScene) -> Vec<(String, PathBuf)> {
    loaded.scene.file_keys()
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "file".into())
}

/// Removes `model.segmentation`, `model.label`, `model.target_triangles` and the
/// structures' `mesh_label` / `points_label` from a scene document.
fn strip_derivation_keys(doc: &mut Value) {
    let Some(model) = doc.get_mut("model").and_then(Value::as_object_mut) else {
        return;
    };
    for k in ["segmentation", "label", "target_triangles"] {
        model.remove(k);
    }
    if let Some(structures) = model.get_mut("structures").and_then(Value::as_array_mut) {
        for s in structures.iter_mut().filter_map(Value::as_object_mut) {
            s.remove("mesh_label");
            s.remove("points_label");
        }
    }
}

/// A `--set` value: a TOML value (`0.5`, `true`, `"icp"`, `[1, 2, 3]`), else the text itself.
fn parse_value(text: &str) -> Value {
    toml::from_str::<toml::Table>(&format!("v = {text}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .and_then(|v| serde_json::to_value(v).ok())
        .unwrap_or_else(|| Value::String(text.to_string()))
}

/// Sets `doc` at the dotted `key` (`a.b[2].c`) to `value`; with `create`, missing tables
/// are created (array entries must exist).
fn set_key(doc: &mut Value, key: &str, value: Value, create: bool) -> Result<(), String> {
    let mut parts: Vec<(String, Option<usize>)> = Vec::new();
    for part in key.split('.') {
        let (name, index) = match part.split_once('[') {
            Some((n, rest)) => {
                let i = rest
                    .strip_suffix(']')
                    .and_then(|r| r.parse::<usize>().ok())
                    .ok_or_else(|| format!("bad index in key `{key}`"))?;
                (n, Some(i))
            }
            None => (part, None),
        };
        if name.is_empty() {
            return Err(format!("empty part in key `{key}`"));
        }
        parts.push((name.to_string(), index));
    }
    let mut cur = doc;
    let last = parts.len() - 1;
    for (k, (name, index)) in parts.into_iter().enumerate() {
        let obj = cur
            .as_object_mut()
            .ok_or_else(|| format!("`{key}`: `{name}` is inside a value that is not a table"))?;
        if k == last && index.is_none() {
            obj.insert(name, value);
            return Ok(());
        }
        if !obj.contains_key(&name) {
            if !create || index.is_some() {
                return Err(format!("`{key}`: no `{name}` in the scene"));
            }
            obj.insert(name.clone(), Value::Object(Default::default()));
        }
        let mut next = obj.get_mut(&name).expect("inserted above");
        if let Some(i) = index {
            let arr = next
                .as_array_mut()
                .ok_or_else(|| format!("`{key}`: `{name}` is not an array"))?;
            let len = arr.len();
            next = arr
                .get_mut(i)
                .ok_or_else(|| format!("`{key}`: `{name}` has {len} entries"))?;
            if k == last {
                *next = value;
                return Ok(());
            }
        }
        cur = next;
    }
    Ok(())
}
