//! Errors of the evaluation module: reading and writing JSON Lines files, and matching results
//! against truth.

use std::path::{Path, PathBuf};

/// Everything that can go wrong while reading or writing `results.jsonl` or a truth file, or
/// while evaluating results against truth.
///
/// File errors start with the path and, for a line, its 1-based number
/// (`truth.jsonl:3: missing field `structures``); evaluation errors name the frame and the
/// structure concerned.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The file could not be opened, created, read or written.
    #[error("{}: {error}", path.display())]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying I/O error (shown in the message rather than chained as a source).
        error: std::io::Error,
    },
    /// A line of a JSON Lines file is not a valid record.
    #[error("{}:{line}: {message}", path.display())]
    Parse {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong (serde's reason, without its position inside the line except as a
        /// column where that helps).
        message: String,
    },
    /// A record could not be turned into JSON.
    #[error("{}: cannot serialise a record: {message}", path.display())]
    Serialize {
        /// The file being written.
        path: PathBuf,
        /// serde's reason.
        message: String,
    },
    /// The same frame index appears on two lines of the results or of the truth.
    #[error("{what} frame {frame} appears more than once")]
    DuplicateFrame {
        /// `"result"` or `"truth"`.
        what: &'static str,
        /// The repeated frame index.
        frame: usize,
    },
    /// There are no results to evaluate.
    #[error("no result frames to evaluate")]
    NoResults,
    /// A result frame has no truth frame with the same index.
    #[error("result frame {frame} has no truth frame")]
    FrameWithoutTruth {
        /// The result's frame index.
        frame: usize,
    },
    /// A truth frame has no structures, so it has nothing to compare.
    #[error("truth frame {frame} has no structures")]
    EmptyTruthFrame {
        /// Frame index.
        frame: usize,
    },
    /// A structure of the truth is absent from the result of the same frame.
    #[error("frame {frame}: structure `{structure}` is in the truth but not in the result")]
    MissingStructure {
        /// Frame index.
        frame: usize,
        /// Structure name.
        structure: String,
    },
    /// A structure has a different number of points in the result and in the truth.
    #[error(
        "frame {frame}: structure `{structure}` has {result} points in the result but {truth} in the truth"
    )]
    PointCount {
        /// Frame index.
        frame: usize,
        /// Structure name.
        structure: String,
        /// Points in the result.
        result: usize,
        /// Points in the truth.
        truth: usize,
    },
    /// A structure of the truth has no points, so it has no error to measure.
    #[error("frame {frame}: structure `{structure}` has no points in the truth")]
    EmptyStructure {
        /// Frame index.
        frame: usize,
        /// Structure name.
        structure: String,
    },
}

impl EvalError {
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
}
