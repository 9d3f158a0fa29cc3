//! The JSON payloads of a recording's channels (see [`super::schema`] for their JSON Schemas).
//! Lengths are in the scene's units; times in nanoseconds since the Unix epoch.

use std::collections::BTreeMap;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::evaluation::ResultRecord;
use crate::geometry::Camera;
use crate::session::{Frame, FrameResult};

/// `/session`: what made the recording (one message, first in the file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionMessage {
    /// Always [`super::FORMAT_NAME`].
    pub format: String,
    /// [`super::FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// Version of the livereg build that recorded (`CARGO_PKG_VERSION`).
    pub livereg_version: String,
    /// When the recording was created, ns since the Unix epoch.
    pub created_ns: u64,
    /// What recorded it (`register`, `demo`, `serve`, …).
    pub command: String,
    /// The scene's units (`m`, `cm`, `mm`): every length in the recording is in them.
    pub units: String,
    /// Metres per scene unit.
    pub length_scale: f64,
    /// Per-frame time budget override, ms (results then depend on timing).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget_ms: Option<f64>,
    /// Whether only the rigid stage ran.
    #[serde(default)]
    pub rigid_only: bool,
    /// Free-form notes (client, session id, …).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub notes: BTreeMap<String, String>,
}

/// `/scene`: the scene file and every file it names (one message).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneMessage {
    /// File name of the scene (`scene.toml`).
    pub name: String,
    /// Its syntax: `toml` or `json`.
    pub format: String,
    /// The scene file's text, verbatim.
    pub text: String,
    /// The files the scene names (surface, structures, point files), in scene order.
    pub files: Vec<SceneFileEntry>,
}

/// One file a scene names, with its bytes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneFileEntry {
    /// The scene key that names it (`model.surface`, `model.structures[1].mesh`,
    /// `boundary.fixed[0].points`, `probe[2].points`).
    pub key: String,
    /// Where it was read from when recording (absolute).
    pub path: String,
    /// Its file name.
    pub name: String,
    /// Size, bytes.
    pub size: u64,
    /// The bytes, standard base64.
    pub data_base64: String,
}

/// A camera pose in a frame message (scene units, the cloud's frame).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraMessage {
    /// Optical centre.
    pub position: [f64; 3],
    /// A point on the optical axis.
    pub look_at: [f64; 3],
    /// Up hint.
    pub up: [f64; 3],
    /// Full field-of-view angle, degrees.
    pub fov_deg: f64,
}

impl CameraMessage {
    /// The message of `c`.
    pub fn from_camera(c: &Camera) -> Self {
        Self {
            position: c.position.into(),
            look_at: c.look_at.into(),
            up: c.up.into(),
            fov_deg: c.fov_deg,
        }
    }

    /// The camera (not validated: the session rejects an invalid one as a frame error).
    pub fn to_camera(&self) -> Camera {
        Camera {
            position: Point3::from(self.position),
            look_at: Point3::from(self.look_at),
            up: Vector3::from(self.up),
            fov_deg: self.fov_deg,
        }
    }
}

/// `/frames`: one input frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameMessage {
    /// Index of the frame in the recording, from 0.
    pub frame: usize,
    /// The frame's source (file name, client's name).
    pub source: String,
    /// When it was received, ns since the Unix epoch (also the message's log time).
    pub timestamp_ns: u64,
    /// The points, flat `[x0, y0, z0, x1, …]`, scene units, cloud frame.
    pub points: Vec<f64>,
    /// The camera's pose, when the frame brought one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraMessage>,
    /// Why the input could not be read (then `points` is empty and the frame was rejected).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input_error: Option<String>,
}

impl FrameMessage {
    /// The message of `frame`, received at `timestamp_ns`, as frame `index`.
    pub fn from_frame(index: usize, frame: &Frame, timestamp_ns: u64) -> Self {
        Self {
            frame: index,
            source: frame.source.clone(),
            timestamp_ns,
            points: frame.points.iter().flat_map(|p| [p.x, p.y, p.z]).collect(),
            camera: frame.camera.as_ref().map(CameraMessage::from_camera),
            input_error: None,
        }
    }

    /// The session frame (`None` for a frame whose input could not be read).
    pub fn to_frame(&self) -> Option<Frame> {
        if self.input_error.is_some() {
            return None;
        }
        Some(Frame {
            source: self.source.clone(),
            points: self
                .points
                .chunks_exact(3)
                .map(|c| Point3::new(c[0], c[1], c[2]))
                .collect(),
            camera: self.camera.as_ref().map(CameraMessage::to_camera),
        })
    }
}

/// `/results`: one frame's result: the `results.jsonl` line plus the deformed surface.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResultMessage {
    /// The `results.jsonl` line (contracts.md), fields inlined.
    #[serde(flatten)]
    pub record: ResultRecord,
    /// When the result was known, ns since the Unix epoch (also the message's log time).
    pub timestamp_ns: u64,
    /// Whether the frame started from the previous frame's state.
    pub warm: bool,
    /// Tangent factorisations of the frame.
    pub factorizations: usize,
    /// Cloud points used after thinning.
    pub cloud_points_used: usize,
    /// Deformed surface vertices, flat `[x0, y0, z0, …]`, scene units, cloud frame, in the
    /// order of the scene's surface file.
    pub surface: Vec<f64>,
}

impl ResultMessage {
    /// The message of `r` (`length_scale`: metres per scene unit), known at `timestamp_ns`.
    pub fn from_result(r: &FrameResult, length_scale: f64, timestamp_ns: u64) -> Self {
        Self {
            record: ResultRecord::from_frame(r, length_scale),
            timestamp_ns,
            warm: r.warm,
            factorizations: r.factorizations,
            cloud_points_used: r.cloud_points.1,
            surface: r.surface.iter().flat_map(|p| [p.x, p.y, p.z]).collect(),
        }
    }
}
