//! A directory of frame files, as `livereg register --frames DIR` and the benches read it:
//! every point file (by extension) is a frame, in lexical order of name; the other files are
//! named, not read.

use std::path::{Path, PathBuf};

/// The frame files of a directory: its point files (every extension of
/// [`crate::mesh::POINT_EXTENSIONS`]: `.xyz .txt .csv .ply .vtk .vtp`, any case) in lexical
/// order of name, and the other files it holds, which are not frames.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameFiles {
    /// The point files, in lexical order of name: one frame each.
    pub frames: Vec<PathBuf>,
    /// Files of the directory that are not point files (by extension), in lexical order.
    pub skipped: Vec<PathBuf>,
}

impl FrameFiles {
    /// A one-line note naming the skipped files (at most five by name), or `None` when every
    /// file of the directory is a frame.
    pub fn skipped_note(&self, dir: &Path) -> Option<String> {
        if self.skipped.is_empty() {
            return None;
        }
        let names: Vec<String> = self
            .skipped
            .iter()
            .take(5)
            .map(|p| {
                p.file_name()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned()
            })
            .collect();
        let more = self.skipped.len().saturating_sub(names.len());
        let more = if more > 0 {
            format!(" and {more} more")
        } else {
            String::new()
        };
        Some(format!(
            "{}: skipped {} file(s) that are not point files ({}): {}{more}",
            dir.display(),
            self.skipped.len(),
            point_extension_list(),
            names.join(", ")
        ))
    }
}

/// The point file extensions as `.xyz .txt …`, for messages.
fn point_extension_list() -> String {
    crate::mesh::POINT_EXTENSIONS
        .iter()
        .map(|e| format!(".{e}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The frame files of `dir` ([`FrameFiles`]); an error names the directory when it cannot be
/// read or holds no point file (listing what it holds instead).
pub fn frame_files(dir: &Path) -> Result<FrameFiles, String> {
    let entries = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: cannot read the frame directory: {e}", dir.display()))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    let (frames, skipped): (Vec<PathBuf>, Vec<PathBuf>) =
        files.into_iter().partition(|p| is_point_file(p));
    let found = FrameFiles { frames, skipped };
    if found.frames.is_empty() {
        let held = found
            .skipped_note(dir)
            .map(|n| format!("; {n}"))
            .unwrap_or_else(|| "; the directory holds no files".to_string());
        return Err(format!(
            "{}: no point files ({}) in the frame directory{held}",
            dir.display(),
            point_extension_list()
        ));
    }
    Ok(found)
}

/// Whether `path` has a point file extension (any case).
fn is_point_file(path: &Path) -> bool {
    crate::mesh::extension(path)
        .is_some_and(|e| crate::mesh::POINT_EXTENSIONS.contains(&e.as_str()))
}
