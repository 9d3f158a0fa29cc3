//! JSON Lines files: one JSON object per line (`results.jsonl`, truth files).
//!
//! Reading skips blank lines and reports the first bad line by file and 1-based line number,
//! with serde's reason. Writing puts one record per line and flushes after each, so a process
//! killed between two frames leaves only complete lines.
//!
//! JSON has no NaN or infinity: `serde_json` writes a non-finite `f64` as `null`, and such a
//! line then fails to read back (`invalid type: null, expected f64 …`, with a hint). Writers
//! of results should therefore only hand finite coordinates to [`JsonlWriter::write`].

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::Serialize;

use super::error::EvalError;
use super::records::{ResultRecord, TruthRecord};

/// Reads a `results.jsonl` file (contracts.md, "`register` output").
///
/// # Errors
/// [`EvalError::Io`] if the file cannot be opened or read, [`EvalError::Parse`] (with the line
/// number) for the first line that is not a valid result record.
pub fn read_results(path: impl AsRef<Path>) -> Result<Vec<ResultRecord>, EvalError> {
    read_jsonl(path.as_ref())
}

/// Reads a truth file: one object per line with `frame` and `structures` (other fields are
/// ignored, so a `results.jsonl` is also a valid truth file).
///
/// # Errors
/// As [`read_results`].
pub fn read_truth(path: impl AsRef<Path>) -> Result<Vec<TruthRecord>, EvalError> {
    read_jsonl(path.as_ref())
}

/// Reads a JSON Lines file of `T`, in file order, skipping blank (whitespace-only) lines.
///
/// # Errors
/// [`EvalError::Io`] if the file cannot be opened, [`EvalError::Parse`] naming the 1-based
/// line for a line that cannot be read or is not a valid `T`.
pub fn read_jsonl<T: DeserializeOwned>(path: &Path) -> Result<Vec<T>, EvalError> {
    let file = File::open(path).map_err(|e| EvalError::io(path, e))?;
    let mut records = Vec::new();
    for (i, line) in BufReader::new(file).lines().enumerate() {
        let number = i + 1;
        let line = line.map_err(|e| EvalError::parse(path, number, format!("cannot read: {e}")))?;
        if line.trim().is_empty() {
            continue;
        }
        let record = serde_json::from_str(&line)
            .map_err(|e| EvalError::parse(path, number, describe(&e)))?;
        records.push(record);
    }
    Ok(records)
}

/// serde's reason for `e`, with the position inside the line given as a column only (the line
/// number of a single-line parse is always 1), and a hint for `null` numbers.
fn describe(e: &serde_json::Error) -> String {
    let full = e.to_string();
    let suffix = format!(" at line {} column {}", e.line(), e.column());
    let reason = full.strip_suffix(&suffix).unwrap_or(&full);
    if reason.starts_with("missing field") || e.line() == 0 {
        reason.to_string()
    } else if reason.starts_with("invalid type: null") {
        format!(
            "{reason} at column {} (JSON has no NaN or infinity; a writer puts null in their \
             place, so this value was probably not finite)",
            e.column()
        )
    } else {
        format!("{reason} at column {}", e.column())
    }
}

/// Writes records as JSON Lines, one per call, flushing after each.
#[derive(Debug)]
pub struct JsonlWriter {
    path: PathBuf,
    out: BufWriter<File>,
}

impl JsonlWriter {
    /// Creates (or truncates) the file at `path`.
    ///
    /// # Errors
    /// [`EvalError::Io`] if the file cannot be created.
    pub fn create(path: impl AsRef<Path>) -> Result<Self, EvalError> {
        let path = path.as_ref().to_path_buf();
        let file = File::create(&path).map_err(|e| EvalError::io(&path, e))?;
        Ok(Self {
            path,
            out: BufWriter::new(file),
        })
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes `record` as one line and flushes it to the file. The record is serialised in
    /// full before anything is written, so a serialisation error writes nothing.
    ///
    /// # Errors
    /// [`EvalError::Serialize`] if `record` cannot be serialised, [`EvalError::Io`] if writing
    /// fails.
    pub fn write(&mut self, record: &impl Serialize) -> Result<(), EvalError> {
        let mut line = serde_json::to_vec(record).map_err(|e| EvalError::Serialize {
            path: self.path.clone(),
            message: e.to_string(),
        })?;
        line.push(b'\n');
        self.out
            .write_all(&line)
            .and_then(|()| self.out.flush())
            .map_err(|e| EvalError::io(&self.path, e))
    }
}
