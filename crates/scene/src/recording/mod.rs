//! Recordings of registration sessions: one MCAP file per session holding the scene
//! and pre-operative model, every input frame and every result, on JSON channels described by
//! JSON Schema so that generic MCAP tools decode them.
//!
//! Channels (all `message_encoding = "json"`, schema encoding `jsonschema`):
//! - [`TOPIC_SESSION`] (once): format version, build, command and its settings overrides;
//! - [`TOPIC_SCENE`] (once): the scene file's text and the bytes (base64) of every file it
//!   names, so a recording replays without the original files ([`SceneFiles`]);
//! - [`TOPIC_FRAMES`] (per frame): source, timestamp, points (flat `[x, y, z, …]`, scene units,
//!   cloud frame), the camera when given, or the reason the input could not be read;
//! - [`TOPIC_RESULTS`] (per frame): the `results.jsonl` line ([`ResultRecord`]) plus the
//!   deformed surface and a few more counters.
//!
//! Kill safety: [`Recorder`] writes chunks whole (buffered, no seeking back) and closes the
//! chunk and flushes the file after every result, so a process killed at any moment leaves a
//! file whose completed chunks hold every frame whose result had been recorded. [`Recording`]
//! reads such a file (no summary, a partial last chunk) and says how much it recovered.
//!
//! [`ResultRecord`]: crate::evaluation::ResultRecord

mod base64;
pub(crate) mod messages;
pub(crate) mod reader;
pub mod retention;
pub(crate) mod scene_files;
pub(crate) mod schema;
pub(crate) mod writer;

pub use messages::{
    CameraMessage, FrameMessage, ResultMessage, SceneFileEntry, SceneMessage, SessionMessage,
};
pub use reader::Recording;
pub use scene_files::SceneFiles;
pub use writer::{Recorder, RecorderStats, RecordingMeta, DEFAULT_FSYNC_INTERVAL};

use std::path::PathBuf;

/// Topic of the session metadata (one message).
pub const TOPIC_SESSION: &str = "/session";
/// Topic of the scene and its files (one message).
pub const TOPIC_SCENE: &str = "/scene";
/// Topic of the input frames (one message per frame).
pub const TOPIC_FRAMES: &str = "/frames";
/// Topic of the results (one message per frame).
pub const TOPIC_RESULTS: &str = "/results";

/// Name of the recording format in [`SessionMessage::format`].
pub const FORMAT_NAME: &str = "livereg-recording";
/// Version of the recording format in [`SessionMessage::format_version`].
pub const FORMAT_VERSION: u32 = 1;

/// What can go wrong writing or reading a recording. Every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// The file could not be created, read or written.
    #[error("{}: {message}", path.display())]
    Io {
        /// The recording.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// The file is not an MCAP recording livereg can use (bad magic, no scene, bad payload).
    #[error("{}: {message}", path.display())]
    Invalid {
        /// The recording.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A file the scene names could not be read, or the recorded scene could not be rebuilt.
    #[error("{0}")]
    Scene(String),
}

impl RecordingError {
    /// What went wrong, without the file's path (for people the path must not reach, such
    /// as a server's clients).
    pub fn detail(&self) -> &str {
        match self {
            RecordingError::Io { message, .. } | RecordingError::Invalid { message, .. } => message,
            RecordingError::Scene(m) => m,
        }
    }
}

/// Nanoseconds since the Unix epoch, now (0 if the clock is before 1970).
pub fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

#[cfg(test)]
mod tests;
