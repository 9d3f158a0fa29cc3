//! Frames in (JSON, the compact binary encoding, protobuf) and results out (JSON, protobuf).
//!
//! Binary frame encoding (WebSocket binary messages), all little-endian:
//!
//! | offset | size | field |
//! | --- | --- | --- |
//! | 0 | 4 | magic `LVRG` (bytes 0x4C 0x56 0x52 0x47) |
//! | 4 | 1 | version, 1 |
//! | 5 | 1 | flags: bit 0 = a camera follows the header; other bits 0 |
//! | 6 | 2 | reserved, 0 |
//! | 8 | 8 | `seq`, u64: the client's frame number, echoed in the result |
//! | 16 | 4 | `n`, u32: number of points |
//! | 20 | 36 | only with flag bit 0: camera as 9 × f32: position, look_at, up (up = 0 0 0: default) |
//! | 20 or 56 | 12 n | the points, n × (x, y, z) f32, scene units, cloud frame |
//!
//! The message length must be exactly the header plus the points.

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::error::ApiError;
use super::proto;
use crate::evaluation::ResultRecord;
use crate::geometry::Camera;
use crate::session::{Frame, FrameResult};

/// Magic bytes of a binary frame.
pub const BINARY_MAGIC: [u8; 4] = *b"LVRG";
/// Version of the binary frame encoding.
pub const BINARY_VERSION: u8 = 1;
/// Header length of a binary frame without a camera, bytes.
pub const BINARY_HEADER: usize = 20;
/// Length of the optional camera block, bytes.
pub const BINARY_CAMERA: usize = 36;

/// A camera in a JSON frame (scene units, cloud frame).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JsonCamera {
    /// Optical centre.
    pub position: [f64; 3],
    /// A point on the optical axis.
    pub look_at: [f64; 3],
    /// Up hint (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub up: Option<[f64; 3]>,
}

/// A frame as JSON: `{"seq": 3, "source": "pc03", "points": [[x, y, z], ...], "camera": {...}}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JsonFrame {
    /// Client frame number (echoed); default 0.
    #[serde(default)]
    pub seq: u64,
    /// Name carried into the result; default `frame-<seq>`.
    #[serde(default)]
    pub source: Option<String>,
    /// Points, scene units, cloud frame.
    pub points: Vec<[f64; 3]>,
    /// Camera pose, when known.
    #[serde(default)]
    pub camera: Option<JsonCamera>,
}

/// A decoded frame with the client's number.
#[derive(Debug, Clone)]
pub(crate) struct Incoming {
    /// Client frame number.
    pub seq: u64,
    /// The frame.
    pub frame: Frame,
}

fn camera(position: [f64; 3], look_at: [f64; 3], up: Option<[f64; 3]>) -> Result<Camera, ApiError> {
    let p = Point3::from(position);
    let l = Point3::from(look_at);
    let c = match up {
        None => Camera::looking_at(p, l),
        Some(u) => Camera::new(p, l, Vector3::from(u), crate::geometry::DEFAULT_FOV_DEG),
    };
    c.map_err(|e| ApiError::invalid_frame(format!("camera: {e}")))
}

fn source_or(seq: u64, source: Option<String>) -> String {
    match source {
        Some(s) if !s.is_empty() => s.chars().take(256).collect(),
        _ => format!("frame-{seq}"),
    }
}

/// Decodes a JSON frame; 400 naming line, column and field on malformed input.
pub(crate) fn decode_json_frame(bytes: &[u8]) -> Result<Incoming, ApiError> {
    let f: JsonFrame = serde_json::from_slice(bytes)
        .map_err(|e| ApiError::bad_request(format!("malformed JSON frame: {e}")))?;
    let cam = match f.camera {
        Some(c) => Some(camera(c.position, c.look_at, c.up)?),
        None => None,
    };
    Ok(Incoming {
        seq: f.seq,
        frame: Frame {
            source: source_or(f.seq, f.source),
            points: f.points.into_iter().map(Point3::from).collect(),
            camera: cam,
        },
    })
}

/// Encodes a frame in the binary encoding (f32 coordinates).
pub fn encode_binary_frame(seq: u64, points: &[[f32; 3]], cam: Option<[[f32; 3]; 3]>) -> Vec<u8> {
    let mut out = Vec::with_capacity(BINARY_HEADER + BINARY_CAMERA + 12 * points.len());
    out.extend_from_slice(&BINARY_MAGIC);
    out.push(BINARY_VERSION);
    out.push(u8::from(cam.is_some()));
    out.extend_from_slice(&[0, 0]);
    out.extend_from_slice(&seq.to_le_bytes());
    out.extend_from_slice(&(points.len() as u32).to_le_bytes());
    if let Some(c) = cam {
        for v in c.iter().flatten() {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    for v in points.iter().flatten() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// The `seq` of a binary frame read from its header alone (0 when the message is too short
/// or not a binary frame): refusals made before decoding still name the frame.
pub(crate) fn peek_binary_seq(bytes: &[u8]) -> u64 {
    match bytes.get(8..16) {
        Some(b) if bytes.starts_with(&BINARY_MAGIC) => {
            u64::from_le_bytes(b.try_into().unwrap_or([0; 8]))
        }
        _ => 0,
    }
}

/// Decodes a binary frame (see the module docs); 400 naming what is wrong, 413 when it holds
/// more than `max_points` points.
pub(crate) fn decode_binary_frame(bytes: &[u8], max_points: usize) -> Result<Incoming, ApiError> {
    if bytes.len() < BINARY_HEADER {
        return Err(ApiError::bad_request(format!(
            "binary frame of {} bytes is shorter than its {BINARY_HEADER}-byte header",
            bytes.len()
        )));
    }
    if bytes[0..4] != BINARY_MAGIC {
        return Err(ApiError::bad_request(
            "binary frame does not start with the magic `LVRG`",
        ));
    }
    if bytes[4] != BINARY_VERSION {
        return Err(ApiError::bad_request(format!(
            "binary frame version {} is not supported (this server reads version {BINARY_VERSION})",
            bytes[4]
        )));
    }
    let flags = bytes[5];
    if flags & !1 != 0 || bytes[6] != 0 || bytes[7] != 0 {
        return Err(ApiError::bad_request(
            "binary frame: unknown flags or non-zero reserved bytes",
        ));
    }
    let u64_at = |o: usize| u64::from_le_bytes(bytes[o..o + 8].try_into().unwrap_or([0; 8]));
    let seq = u64_at(8);
    let n = u32::from_le_bytes(bytes[16..20].try_into().unwrap_or([0; 4])) as usize;
    if n > max_points {
        return Err(ApiError::too_large(
            "too_many_points",
            format!("the frame has {n} points, more than the limit of {max_points} (limits.max_frame_points)"),
        ));
    }
    let cam_len = if flags & 1 == 1 { BINARY_CAMERA } else { 0 };
    let expected = BINARY_HEADER + cam_len + 12 * n;
    if bytes.len() != expected {
        return Err(ApiError::bad_request(format!(
            "binary frame of {} bytes, but its header announces {n} points{}: expected {expected} bytes",
            bytes.len(),
            if cam_len > 0 { " and a camera" } else { "" }
        )));
    }
    let f = |o: usize| {
        f64::from(f32::from_le_bytes(
            bytes[o..o + 4].try_into().unwrap_or([0; 4]),
        ))
    };
    let triple = |o: usize| [f(o), f(o + 4), f(o + 8)];
    let cam = if cam_len > 0 {
        let up = triple(BINARY_HEADER + 24);
        let up = (up != [0.0; 3]).then_some(up);
        Some(camera(
            triple(BINARY_HEADER),
            triple(BINARY_HEADER + 12),
            up,
        )?)
    } else {
        None
    };
    let start = BINARY_HEADER + cam_len;
    let points = (0..n)
        .map(|i| Point3::from(triple(start + 12 * i)))
        .collect();
    Ok(Incoming {
        seq,
        frame: Frame {
            source: format!("frame-{seq}"),
            points,
            camera: cam,
        },
    })
}

/// Decodes a protobuf frame (`points_f64` when non-empty, else `points`); 400 naming what is
/// wrong, 413 over `max_points`.
pub(crate) fn decode_proto_frame(f: proto::Frame, max_points: usize) -> Result<Incoming, ApiError> {
    let coords: Vec<f64> = if f.points_f64.is_empty() {
        f.points.iter().map(|&v| f64::from(v)).collect()
    } else {
        f.points_f64
    };
    if !coords.len().is_multiple_of(3) {
        return Err(ApiError::bad_request(format!(
            "frame.points has {} numbers, not a multiple of 3",
            coords.len()
        )));
    }
    if coords.len() / 3 > max_points {
        return Err(ApiError::too_large(
            "too_many_points",
            format!(
                "the frame has {} points, more than the limit of {max_points} (limits.max_frame_points)",
                coords.len() / 3
            ),
        ));
    }
    let cam = match f.camera {
        Some(c) => {
            let three = |v: &[f64], name: &str| -> Result<[f64; 3], ApiError> {
                <[f64; 3]>::try_from(v).map_err(|_| {
                    ApiError::bad_request(format!("camera.{name} needs 3 numbers, got {}", v.len()))
                })
            };
            let up = if c.up.is_empty() {
                None
            } else {
                Some(three(&c.up, "up")?)
            };
            Some(camera(
                three(&c.position, "position")?,
                three(&c.look_at, "look_at")?,
                up,
            )?)
        }
        None => None,
    };
    Ok(Incoming {
        seq: f.seq,
        frame: Frame {
            source: source_or(f.seq, Some(f.source)),
            points: coords
                .chunks_exact(3)
                .map(|c| Point3::new(c[0], c[1], c[2]))
                .collect(),
            camera: cam,
        },
    })
}

/// A frame's result as JSON: the `results.jsonl` line of `livereg register` (flattened), the
/// deformed surface vertices, and transport fields.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResultMessage {
    /// The client's frame number.
    pub seq: u64,
    /// Frames of this stream (or session, over HTTP) skipped since the previous result because
    /// a newer one arrived first.
    pub skipped: u64,
    /// Server time from receipt of the frame to the result being ready, ms.
    pub server_ms: f64,
    /// Part of `server_ms` spent waiting for a registration slot, ms.
    pub queue_ms: f64,
    /// The results.jsonl line (frame, source, wall_ms, converged, rigid, diagnostics,
    /// structures).
    #[serde(flatten)]
    pub record: ResultRecord,
    /// Deformed surface vertices, scene units, cloud frame, in the model's vertex order.
    pub surface: Vec<[f64; 3]>,
}

impl ResultMessage {
    /// The message for a session's result (`length_scale`: metres per scene unit).
    pub fn new(
        seq: u64,
        skipped: u64,
        server_ms: f64,
        queue_ms: f64,
        r: &FrameResult,
        length_scale: f64,
    ) -> Self {
        Self {
            seq,
            skipped,
            server_ms,
            queue_ms,
            record: ResultRecord::from_frame(r, length_scale),
            surface: r.surface.iter().map(|p| [p.x, p.y, p.z]).collect(),
        }
    }

    /// The protobuf form of the same result.
    pub fn to_proto(&self, error_cause: &str) -> proto::FrameResult {
        let rec = &self.record;
        let d = &rec.diagnostics;
        proto::FrameResult {
            seq: self.seq,
            frame: rec.frame as u64,
            source: rec.source.clone(),
            wall_ms: rec.wall_ms,
            converged: rec.converged,
            rotation: rec.rigid.rotation.iter().flatten().copied().collect(),
            translation: rec.rigid.translation.to_vec(),
            icp_iterations: d.icp_iterations as u32,
            newton_iterations: d.newton_iterations as u32,
            surface_rms: d.surface_rms,
            rigid_iterations: d.rigid_iterations as u32,
            cloud_points: d.cloud_points as u32,
            sources: d.sources as u32,
            timings_ms: d.timings_ms.clone().into_iter().collect(),
            flags: d.flags.clone(),
            error: d.error.clone().unwrap_or_default(),
            error_cause: error_cause.to_string(),
            warnings: d.warnings.clone(),
            structures: rec
                .structures
                .iter()
                .map(|(name, pts)| proto::Structure {
                    name: name.clone(),
                    points: pts.iter().flatten().copied().collect(),
                })
                .collect(),
            surface: self.surface.iter().flatten().copied().collect(),
            contact_force: rec
                .contact_force
                .as_ref()
                .and_then(Option::as_ref)
                .map(|c| proto::ContactForce {
                    resultant_n: c.resultant_n.to_vec(),
                    magnitude_n: c.magnitude_n,
                    centre: c.centre.to_vec(),
                    expected_error_n: c.expected_error_n.unwrap_or(0.0),
                }),
            pose_uncertainty: rec.rigid.uncertainty,
            expected_error: rec.expected_error,
            skipped: self.skipped,
            server_ms: self.server_ms,
            queue_ms: self.queue_ms,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_frames_round_trip_and_bad_ones_say_why() {
        let pts = [[1.0f32, 2.0, 3.0], [-4.5, 0.25, 1e-3]];
        let b = encode_binary_frame(7, &pts, None);
        assert_eq!(b.len(), BINARY_HEADER + 24);
        let f = decode_binary_frame(&b, 10).unwrap();
        assert_eq!(f.seq, 7);
        assert_eq!(
            f.frame.points[1],
            Point3::new(-4.5, 0.25, f64::from(1e-3f32))
        );
        let c = encode_binary_frame(1, &pts, Some([[0.0, 0.0, 5.0], [0.0; 3], [0.0; 3]]));
        assert!(decode_binary_frame(&c, 10).unwrap().frame.camera.is_some());
        let e = decode_binary_frame(&b[..b.len() - 1], 10).unwrap_err();
        assert!(e.message.contains("expected 44 bytes"), "{}", e.message);
        assert_eq!(decode_binary_frame(&b, 1).unwrap_err().status.as_u16(), 413);
        let mut bad = b.clone();
        bad[0] = b'X';
        assert!(decode_binary_frame(&bad, 10)
            .unwrap_err()
            .message
            .contains("magic"));
        assert!(decode_binary_frame(&[1, 2], 10).is_err());
        let mut huge = b.clone();
        huge[16..20].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(decode_binary_frame(&huge, usize::MAX).is_err());
    }

    #[test]
    fn json_frames_name_the_bad_field() {
        let e = decode_json_frame(br#"{"points": [[1, 2]]}"#).unwrap_err();
        assert_eq!(e.status.as_u16(), 400);
        assert!(e.message.contains("length 3"), "{}", e.message);
        let e = decode_json_frame(br#"{"pointz": []}"#).unwrap_err();
        assert!(e.message.contains("pointz"), "{}", e.message);
        let f = decode_json_frame(br#"{"seq": 4, "points": [[1, 2, 3]]}"#).unwrap();
        assert_eq!(f.frame.source, "frame-4");
        let e = decode_json_frame(
            br#"{"points": [[1, 2, 3]], "camera": {"position": [0,0,0], "look_at": [0,0,0]}}"#,
        )
        .unwrap_err();
        assert_eq!(e.code, "invalid_frame");
    }
}
