//! ParaView `.pvd` collections: a time series of data files that ParaView opens as one
//! animated data set.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::super::error::MeshError;

/// A `.pvd` collection file listing data files by time step. Each [`PvdSeries::push`]
/// rewrites the collection (beside its final name, then renamed into place), so the file
/// on disk always lists every step written so far, also when the run stops early.
#[derive(Debug, Clone)]
pub struct PvdSeries {
    path: PathBuf,
    steps: Vec<(f64, String)>,
}

impl PvdSeries {
    /// A series that will be written to `path` (nothing is written until the first step).
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self {
            path: path.into(),
            steps: Vec::new(),
        }
    }

    /// The collection file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The steps listed so far: time and file name relative to the collection's directory.
    pub fn steps(&self) -> &[(f64, String)] {
        &self.steps
    }

    /// Adds `file` (relative to the collection's directory) at `time` (the series' time
    /// unit: livereg uses the frame index) and rewrites the collection.
    pub fn push(&mut self, time: f64, file: impl Into<String>) -> Result<(), MeshError> {
        self.steps.push((time, file.into()));
        self.write()
    }

    /// The collection's XML text.
    pub fn to_xml(&self) -> String {
        let mut s = String::from(
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" \
             byte_order=\"LittleEndian\">\n  <Collection>\n",
        );
        for (time, file) in &self.steps {
            let _ = writeln!(
                s,
                "    <DataSet timestep=\"{time}\" group=\"\" part=\"0\" file=\"{}\"/>",
                escape(file)
            );
        }
        s.push_str("  </Collection>\n</VTKFile>\n");
        s
    }

    fn write(&self) -> Result<(), MeshError> {
        let mut name = self.path.file_name().unwrap_or_default().to_os_string();
        name.push(".partial");
        let partial = self.path.with_file_name(name);
        std::fs::write(&partial, self.to_xml()).map_err(|e| MeshError::io(&partial, e))?;
        std::fs::rename(&partial, &self.path).map_err(|e| MeshError::io(&self.path, e))
    }
}

/// `s` with the five XML special characters escaped, for an attribute value.
fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}
