//! [`Recording`]: a recording read back, complete or cut short by a kill.

use std::path::{Path, PathBuf};

use mcap::read::Options;
use mcap::MessageStream;
use serde::de::DeserializeOwned;

use super::messages::{FrameMessage, ResultMessage, SceneMessage, SessionMessage};
use super::scene_files::SceneFiles;
use super::RecordingError;
use super::{FORMAT_NAME, TOPIC_FRAMES, TOPIC_RESULTS, TOPIC_SCENE, TOPIC_SESSION};

/// A recording read into memory.
#[derive(Debug, Clone)]
pub struct Recording {
    /// The file.
    pub path: PathBuf,
    /// `/session`.
    pub session: SessionMessage,
    /// `/scene`.
    pub scene: SceneMessage,
    /// `/frames`, in order.
    pub frames: Vec<FrameMessage>,
    /// `/results`, in order (`results[k]` is the result of `frames[k]`).
    pub results: Vec<ResultMessage>,
    /// Whether the file ends with its summary and footer (the writer finished); `false` for
    /// a recording cut short (killed process).
    pub finished: bool,
    /// For an unfinished file: why reading stopped (a partial last record), if it did.
    pub truncated_tail: Option<String>,
}

impl Recording {
    /// Reads `path`. An unfinished file (no summary, a partly written last chunk) is read up
    /// to its last complete chunk; see [`Recording::finished`] and
    /// [`Recording::truncated_tail`].
    ///
    /// # Errors
    ///
    /// [`RecordingError::Io`] when the file cannot be read; [`RecordingError::Invalid`] when it
    /// is not an MCAP file, has no `/session` or `/scene` message (not a livereg recording),
    /// or a message does not decode — each naming the file.
    pub fn open(path: &Path) -> Result<Self, RecordingError> {
        let buf = std::fs::read(path).map_err(|e| RecordingError::Io {
            path: path.to_path_buf(),
            message: format!("cannot read the recording: {e}"),
        })?;
        Self::from_bytes(path, &buf)
    }

    /// Like [`Recording::open`] for bytes already in memory (`path` names them in errors).
    pub fn from_bytes(path: &Path, buf: &[u8]) -> Result<Self, RecordingError> {
        let invalid = |message: String| RecordingError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        if buf.len() < 8 || &buf[..8] != mcap::MAGIC {
            return Err(invalid(
                "not an MCAP file (it does not start with the MCAP magic bytes)".into(),
            ));
        }
        let finished = mcap::read::footer(buf).is_ok();
        let stream = MessageStream::new_with_options(buf, Options::IgnoreEndMagic.into())
            .map_err(|e| invalid(format!("not a readable MCAP file: {e}")))?;
        let mut session: Option<SessionMessage> = None;
        let mut scene: Option<SceneMessage> = None;
        let mut frames = Vec::new();
        let mut results = Vec::new();
        let mut truncated_tail = None;
        for (n, m) in stream.enumerate() {
            let m = match m {
                Ok(m) => m,
                Err(e) => {
                    if finished {
                        return Err(invalid(format!(
                            "corrupt MCAP data after {n} messages: {e}"
                        )));
                    }
                    truncated_tail = Some(e.to_string());
                    break;
                }
            };
            let topic = m.channel.topic.as_str();
            match topic {
                TOPIC_SESSION => session = Some(decode(topic, n, &m.data).map_err(invalid)?),
                TOPIC_SCENE => scene = Some(decode(topic, n, &m.data).map_err(invalid)?),
                TOPIC_FRAMES => frames.push(decode(topic, n, &m.data).map_err(invalid)?),
                TOPIC_RESULTS => results.push(decode(topic, n, &m.data).map_err(invalid)?),
                _ => {}
            }
        }
        let session: SessionMessage = session.ok_or_else(|| {
            invalid(format!(
                "no {TOPIC_SESSION} message: not a livereg recording (or cut before its first chunk)"
            ))
        })?;
        if session.format != FORMAT_NAME {
            return Err(invalid(format!(
                "{TOPIC_SESSION} says format `{}`, expected `{FORMAT_NAME}`",
                session.format
            )));
        }
        let scene = scene.ok_or_else(|| {
            invalid(format!(
                "no {TOPIC_SCENE} message: the recording does not hold its scene"
            ))
        })?;
        if results.len() > frames.len() {
            return Err(invalid(format!(
                "{} results for {} frames",
                results.len(),
                frames.len()
            )));
        }
        Ok(Self {
            path: path.to_path_buf(),
            session,
            scene,
            frames,
            results,
            finished,
            truncated_tail,
        })
    }

    /// Frames recorded together with their result (what replay re-runs).
    pub fn complete_frames(&self) -> usize {
        self.results.len()
    }

    /// The recorded scene with its files.
    pub fn scene_files(&self) -> Result<SceneFiles, RecordingError> {
        SceneFiles::from_message(&self.scene).map_err(|e| RecordingError::Invalid {
            path: self.path.clone(),
            message: format!("{TOPIC_SCENE}: {e}"),
        })
    }

    /// One line about the file's state: finished, or cut short with the frames recovered.
    pub fn describe(&self) -> String {
        if self.finished {
            format!(
                "{}: complete recording, {} frames, {} results",
                self.path.display(),
                self.frames.len(),
                self.results.len()
            )
        } else {
            format!(
                "{}: unfinished recording (no summary: the writer was stopped); recovered {} complete frames{}",
                self.path.display(),
                self.results.len(),
                match &self.truncated_tail {
                    Some(e) => format!(", partial tail ignored ({e})"),
                    None => String::new(),
                }
            )
        }
    }
}

fn decode<T: DeserializeOwned>(topic: &str, n: usize, data: &[u8]) -> Result<T, String> {
    serde_json::from_slice(data).map_err(|e| format!("{topic} message (#{n}) does not decode: {e}"))
}
