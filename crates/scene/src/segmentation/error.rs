//! The one error type of the segmentation module: every reader error names the file and the
//! header field (or data) that is wrong.

use std::path::{Path, PathBuf};

/// What went wrong reading a labelmap or turning one of its labels into a structure.
#[derive(Debug, thiserror::Error)]
pub enum SegmentationError {
    /// The file could not be opened or read.
    #[error("{}: cannot read the file: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A header field is missing, malformed or has a value this reader refuses.
    #[error("{}: header field '{field}': {message}", path.display())]
    Header {
        /// The file.
        path: PathBuf,
        /// The field (NRRD field name, NIfTI header member).
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// The voxel data do not match the header or are not labels (e.g. non-integer floats).
    #[error("{}: voxel data: {message}", path.display())]
    Data {
        /// The file.
        path: PathBuf,
        /// What is wrong with them.
        message: String,
    },
    /// A valid file using a feature this reader does not support.
    #[error("{}: unsupported: {message}", path.display())]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// The feature.
        message: String,
    },
    /// A labelmap built in memory is inconsistent (sizes, affine).
    #[error("invalid labelmap: {0}")]
    Labelmap(String),
    /// The requested label is absent (no voxel carries it, or no segment has that name).
    #[error("{0}")]
    NoSuchLabel(String),
    /// The extracted surface failed a check (never expected; reported rather than returned).
    #[error("surface extraction: {0}")]
    Surface(String),
}

impl SegmentationError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_owned(),
            source,
        }
    }

    pub(crate) fn header(path: &Path, field: &str, message: impl Into<String>) -> Self {
        Self::Header {
            path: path.to_owned(),
            field: field.to_owned(),
            message: message.into(),
        }
    }

    pub(crate) fn data(path: &Path, message: impl Into<String>) -> Self {
        Self::Data {
            path: path.to_owned(),
            message: message.into(),
        }
    }

    pub(crate) fn unsupported(path: &Path, message: impl Into<String>) -> Self {
        Self::Unsupported {
            path: path.to_owned(),
            message: message.into(),
        }
    }
}
