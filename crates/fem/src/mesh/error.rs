//! Errors of the mesh and point-cloud readers and writers.

use std::fmt;
use std::path::{Path, PathBuf};

/// Everything that can go wrong while reading or writing a mesh or point file.
///
/// Every message starts with the file path, followed by the 1-based line number for text formats
/// (`liver.obj:12: face index 40 out of range (the file has 38 vertices)`), and quotes the
/// offending token or value.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be opened, read or written.
    #[error("{}: {error}", path.display())]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying I/O error (shown in the message rather than chained as a source).
        error: std::io::Error,
    },
    /// A line of a text file (or of a text header) could not be understood.
    #[error("{}:{line}: {message}", path.display())]
    Parse {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong, quoting the offending text.
        message: String,
    },
    /// Binary data or the overall structure of the file is wrong (truncated, sizes disagree, ...),
    /// where no line number applies.
    #[error("{}: {message}", path.display())]
    Malformed {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The file was read successfully but holds nothing usable.
    #[error("{}: the file contains no {what}", path.display())]
    Empty {
        /// The file concerned.
        path: PathBuf,
        /// What is missing, e.g. `"triangles"` or `"points"`.
        what: &'static str,
    },
    /// A file format, format version or feature that this crate does not read.
    #[error("{}: {message}", path.display())]
    Unsupported {
        /// The file concerned.
        path: PathBuf,
        /// What is not supported, and what to do instead where possible.
        message: String,
    },
    /// A face refers to a vertex that does not exist.
    #[error(
        "{}{}: face index {index} out of range (the file has {count} vertices)",
        path.display(),
        LineSuffix(*line)
    )]
    IndexOutOfRange {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number, for text formats.
        line: Option<usize>,
        /// The index as written in the file (1-based or negative for OBJ, 0-based elsewhere).
        index: i64,
        /// Number of vertices in the file.
        count: usize,
    },
}

/// Formats an optional line number as `:12`, or nothing.
struct LineSuffix(Option<usize>);

impl fmt::Display for LineSuffix {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            Some(line) => write!(f, ":{line}"),
            None => Ok(()),
        }
    }
}

impl MeshError {
    /// An I/O error on `path`.
    pub fn io(path: &Path, error: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            error,
        }
    }

    /// A parse error at 1-based `line` of `path`.
    pub fn parse(path: &Path, line: usize, message: impl Into<String>) -> Self {
        Self::Parse {
            path: path.to_path_buf(),
            line,
            message: message.into(),
        }
    }

    /// A structural or binary-data error in `path`.
    pub fn malformed(path: &Path, message: impl Into<String>) -> Self {
        Self::Malformed {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    /// An unsupported format or feature in `path`.
    pub fn unsupported(path: &Path, message: impl Into<String>) -> Self {
        Self::Unsupported {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    /// The file `path` contains no `what`.
    pub fn empty(path: &Path, what: &'static str) -> Self {
        Self::Empty {
            path: path.to_path_buf(),
            what,
        }
    }

    /// The path of the file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            Self::Io { path, .. }
            | Self::Parse { path, .. }
            | Self::Malformed { path, .. }
            | Self::Empty { path, .. }
            | Self::Unsupported { path, .. }
            | Self::IndexOutOfRange { path, .. } => path,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_file_line_and_value() {
        let p = Path::new("dir/liver.obj");
        let e = MeshError::IndexOutOfRange {
            path: p.into(),
            line: Some(12),
            index: 40,
            count: 38,
        };
        assert_eq!(
            e.to_string(),
            "dir/liver.obj:12: face index 40 out of range (the file has 38 vertices)"
        );
        let e = MeshError::IndexOutOfRange {
            path: p.into(),
            line: None,
            index: -1,
            count: 3,
        };
        assert_eq!(
            e.to_string(),
            "dir/liver.obj: face index -1 out of range (the file has 3 vertices)"
        );
        assert_eq!(
            MeshError::parse(p, 3, "bad token 'x'").to_string(),
            "dir/liver.obj:3: bad token 'x'"
        );
        assert_eq!(
            MeshError::empty(p, "triangles").to_string(),
            "dir/liver.obj: the file contains no triangles"
        );
        let io = MeshError::io(p, std::io::Error::other("boom"));
        assert_eq!(io.to_string(), "dir/liver.obj: boom");
        assert_eq!(io.path(), p);
    }
}
