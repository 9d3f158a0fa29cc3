//! [`Recorder`]: writes one session into an MCAP file, kill-safe after every result.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mcap::records::MessageHeader;
use mcap::{WriteOptions, Writer};
use serde::Serialize;

use super::messages::{FrameMessage, ResultMessage, SessionMessage};
use super::scene_files::SceneFiles;
use super::{schema, RecordingError};
use super::{FORMAT_NAME, FORMAT_VERSION, TOPIC_FRAMES, TOPIC_RESULTS, TOPIC_SCENE, TOPIC_SESSION};
use crate::session::{Frame, FrameObserver, FrameResult};

/// Longest time a recorded result stays in the operating system's cache before the recorder
/// forces it to the disk, unless [`Recorder::set_fsync_interval`] says otherwise.
pub const DEFAULT_FSYNC_INTERVAL: Duration = Duration::from_secs(1);

/// What the recorder is told about the session besides the scene.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecordingMeta {
    /// What records (`register`, `demo`, `serve`, …).
    pub command: String,
    /// Per-frame time budget override, ms.
    pub budget_ms: Option<f64>,
    /// Whether only the rigid stage runs.
    pub rigid_only: bool,
    /// Free-form notes (client, session id, …).
    pub notes: BTreeMap<String, String>,
}

/// What a finished recording holds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RecorderStats {
    /// Frames recorded.
    pub frames: usize,
    /// Results recorded.
    pub results: usize,
    /// File size, bytes.
    pub bytes: u64,
    /// Time spent serialising and writing, ms (all frames and results).
    pub write_ms: f64,
}

/// Writes a session to an MCAP file: `/session` and `/scene` at creation, then a `/frames`
/// message per [`Recorder::record_frame`] and a `/results` message per
/// [`Recorder::record_result`].
///
/// Chunks are built in memory and written whole (no compression), and each
/// [`record_result`](Self::record_result) closes the chunk and flushes the file: a process
/// killed at any moment leaves a readable file holding every frame whose result was recorded
/// (its summary and index are written by [`finish`](Self::finish) only). A flushed chunk is in
/// the operating system's cache; it reaches the disk (`fsync`) at most
/// [`DEFAULT_FSYNC_INTERVAL`] (or [`Recorder::set_fsync_interval`]) after its result, and at
/// [`finish`](Self::finish), so that a power loss or a kernel crash loses at most that much.
/// Not thread-safe: one recorder per session.
pub struct Recorder {
    path: PathBuf,
    writer: Option<Writer<BufWriter<File>>>,
    /// The same open file as the writer's, for `fsync`.
    sync_handle: File,
    fsync_interval: Duration,
    last_sync: Instant,
    frames_channel: u16,
    results_channel: u16,
    length_scale: f64,
    frames: usize,
    results: usize,
    write_ms: f64,
}

impl Recorder {
    /// Creates (or truncates) `path` and records the session metadata and the scene with its
    /// files; both are on disk when this returns.
    pub fn create(
        path: &Path,
        scene: &SceneFiles,
        meta: &RecordingMeta,
        length_scale: f64,
        units: &str,
    ) -> Result<Self, RecordingError> {
        let io = |e: &dyn std::fmt::Display| RecordingError::Io {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| io(&format!("cannot create: {e}")))?;
        }
        let file = File::create(path).map_err(|e| io(&format!("cannot create: {e}")))?;
        let sync_handle = file
            .try_clone()
            .map_err(|e| io(&format!("cannot open: {e}")))?;
        let options = WriteOptions::new()
            .compression(None)
            .profile("")
            .library(format!(
                "livereg {} (mcap-rs 0.26)",
                env!("CARGO_PKG_VERSION")
            ))
            // Whole chunks: built in memory, written at once, never patched afterwards.
            .disable_seeking(true)
            .chunk_size(Some(16 << 20));
        let mut writer = options
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| io(&e))?;
        let mut channel = |topic: &str, name: &str, schema: serde_json::Value| {
            let data = serde_json::to_vec_pretty(&schema).expect("schemas serialise");
            let sid = writer.add_schema(name, "jsonschema", &data)?;
            writer.add_channel(sid, topic, "json", &BTreeMap::new())
        };
        let session_ch = channel(TOPIC_SESSION, schema::SESSION_SCHEMA, schema::session())
            .map_err(|e| io(&e))?;
        let scene_ch =
            channel(TOPIC_SCENE, schema::SCENE_SCHEMA, schema::scene()).map_err(|e| io(&e))?;
        let frames_channel =
            channel(TOPIC_FRAMES, schema::FRAME_SCHEMA, schema::frame()).map_err(|e| io(&e))?;
        let results_channel =
            channel(TOPIC_RESULTS, schema::RESULT_SCHEMA, schema::result()).map_err(|e| io(&e))?;
        let now = super::now_ns();
        let session = SessionMessage {
            format: FORMAT_NAME.into(),
            format_version: FORMAT_VERSION,
            livereg_version: env!("CARGO_PKG_VERSION").into(),
            created_ns: now,
            command: meta.command.clone(),
            units: units.into(),
            length_scale,
            budget_ms: meta.budget_ms,
            rigid_only: meta.rigid_only,
            notes: meta.notes.clone(),
        };
        let mut rec = Self {
            path: path.to_path_buf(),
            writer: Some(writer),
            sync_handle,
            fsync_interval: DEFAULT_FSYNC_INTERVAL,
            last_sync: Instant::now(),
            frames_channel,
            results_channel,
            length_scale,
            frames: 0,
            results: 0,
            write_ms: 0.0,
        };
        rec.write(session_ch, 0, now, &session)?;
        rec.write(scene_ch, 0, now, &scene.to_message())?;
        rec.flush()?;
        rec.sync()?;
        // The new file's directory entry too, so that the recording itself survives a crash.
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
        }
        Ok(rec)
    }

    /// Sets how long a recorded result may stay in the operating system's cache before it is
    /// forced to the disk (`fsync`); zero syncs after every result.
    pub fn set_fsync_interval(&mut self, interval: Duration) {
        self.fsync_interval = interval;
    }

    /// The recording's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Records an input frame received at `timestamp_ns` (ns since the Unix epoch, e.g.
    /// [`super::now_ns`]). It reaches the disk with the next result.
    pub fn record_frame(&mut self, frame: &Frame, timestamp_ns: u64) -> Result<(), RecordingError> {
        let t = Instant::now();
        let m = FrameMessage::from_frame(self.frames, frame, timestamp_ns);
        self.write(self.frames_channel, self.frames as u32, timestamp_ns, &m)?;
        self.frames += 1;
        self.write_ms += t.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }

    /// Records an input that could not be read (`error` says why), received at
    /// `timestamp_ns`; replay rejects it the same way.
    pub fn record_unreadable_frame(
        &mut self,
        source: &str,
        error: &str,
        timestamp_ns: u64,
    ) -> Result<(), RecordingError> {
        let m = FrameMessage {
            frame: self.frames,
            source: source.into(),
            timestamp_ns,
            points: Vec::new(),
            camera: None,
            input_error: Some(error.into()),
        };
        self.write(self.frames_channel, self.frames as u32, timestamp_ns, &m)?;
        self.frames += 1;
        Ok(())
    }

    /// Records the result of the last recorded frame, then closes the chunk and flushes the
    /// file: from here on the frame and its result survive a kill.
    pub fn record_result(&mut self, result: &FrameResult) -> Result<(), RecordingError> {
        let t = Instant::now();
        let now = super::now_ns();
        let m = ResultMessage::from_result(result, self.length_scale, now);
        self.write(self.results_channel, self.results as u32, now, &m)?;
        self.results += 1;
        self.flush()?;
        if self.last_sync.elapsed() >= self.fsync_interval {
            self.sync()?;
        }
        self.write_ms += t.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }

    /// Writes the summary and index (the file is then a complete, indexed MCAP) and closes it.
    pub fn finish(mut self) -> Result<RecorderStats, RecordingError> {
        let mut writer = self.writer.take().expect("writer present until finish");
        writer.finish().map_err(|e| self.err(&e))?;
        let mut inner = writer.into_inner();
        std::io::Write::flush(&mut inner).map_err(|e| self.err(&e))?;
        drop(inner);
        self.sync_handle.sync_all().map_err(|e| self.err(&e))?;
        let bytes = std::fs::metadata(&self.path).map(|m| m.len()).unwrap_or(0);
        Ok(RecorderStats {
            frames: self.frames,
            results: self.results,
            bytes,
            write_ms: self.write_ms,
        })
    }

    fn err(&self, e: &dyn std::fmt::Display) -> RecordingError {
        RecordingError::Io {
            path: self.path.clone(),
            message: format!("writing the recording: {e}"),
        }
    }

    fn write(
        &mut self,
        channel: u16,
        sequence: u32,
        time_ns: u64,
        payload: &impl Serialize,
    ) -> Result<(), RecordingError> {
        let data = serde_json::to_vec(payload).map_err(|e| self.err(&e))?;
        let header = MessageHeader {
            channel_id: channel,
            sequence,
            log_time: time_ns,
            publish_time: time_ns,
        };
        let w = self.writer.as_mut().expect("writer present until finish");
        let r = w.write_to_known_channel(&header, &data);
        r.map_err(|e| self.err(&e))
    }

    /// Forces what was written to the disk (`fsync` of the data).
    fn sync(&mut self) -> Result<(), RecordingError> {
        self.sync_handle.sync_data().map_err(|e| self.err(&e))?;
        self.last_sync = Instant::now();
        Ok(())
    }

    /// Closes the current chunk and flushes it to the file.
    fn flush(&mut self) -> Result<(), RecordingError> {
        let w = self.writer.as_mut().expect("writer present until finish");
        let r = w.flush();
        r.map_err(|e| self.err(&e))
    }
}

impl Drop for Recorder {
    /// A recorder dropped without [`Recorder::finish`] (an error path) still finishes the file.
    fn drop(&mut self) {
        if let Some(mut w) = self.writer.take() {
            let _ = w.finish();
        }
    }
}

/// A recorder records every frame a session registers, and its result (an unreadable frame
/// as its reason).
impl FrameObserver for Recorder {
    fn frame_done(
        &mut self,
        _index: usize,
        frame: Option<&Frame>,
        received_ns: u64,
        result: &FrameResult,
    ) -> Result<(), String> {
        match frame {
            Some(f) => self.record_frame(f, received_ns),
            None => {
                let why = result.error.as_ref().map(|e| e.to_string());
                self.record_unreadable_frame(&result.source, &why.unwrap_or_default(), received_ns)
            }
        }
        .and_then(|()| self.record_result(result))
        .map_err(|e| e.to_string())
    }
}
