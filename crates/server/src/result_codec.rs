//! The compact binary *result* encoding of the WebSocket stream (opt-in with
//! `GET /v1/sessions/{id}/stream?results=binary`): the same result as the JSON message, with
//! the big arrays (deformed surface vertices, structure points) as little-endian f32 instead of
//! JSON numbers — about 4× smaller than the JSON text and nearly free to encode and decode.
//!
//! Layout, all little-endian:
//!
//! | offset | size | field |
//! | --- | --- | --- |
//! | 0 | 4 | magic `LVRR` (bytes 0x4C 0x56 0x52 0x52) |
//! | 4 | 1 | version, 1 |
//! | 5 | 1 | flags, 0 |
//! | 6 | 2 | reserved, 0 |
//! | 8 | 4 | `m`, u32: length of the metadata, bytes (a multiple of 4) |
//! | 12 | 4 | `v`, u32: number of surface vertices |
//! | 16 | 4 | `s`, u32: number of structures |
//! | 20 | 4 s | `c_0 … c_{s-1}`, u32 each: points of each structure, in the order of `structure_names` |
//! | 20 + 4 s | m | metadata: a UTF-8 JSON object, padded with spaces to a multiple of 4 bytes |
//! | 20 + 4 s + m | 12 v | surface vertices, v × (x, y, z) f32 |
//! | then | 12 c_i | each structure's points in turn, c_i × (x, y, z) f32 |
//!
//! The message length must be exactly `20 + 4 s + m + 12 (v + Σ c_i)`; the arrays start at
//! 4-byte aligned offsets (typed-array views need no copy). The metadata is the JSON result
//! message without `surface` and `structures`: `type` (`"result"`), `seq`, `skipped`,
//! `server_ms`, `queue_ms`, `frame`, `source`, `wall_ms`, `converged`, `rigid`, `diagnostics`,
//! `contact_force` (when estimated), plus `structure_names` (the structures' names, in the order of their arrays: the JSON
//! result's key order). Coordinates are in scene units, in the cloud frame, in the same order as
//! the JSON result's arrays. Decoders ignore metadata keys they do not know.
//!
//! Why f32: 7 significant digits are 10 nm on a 100 mm organ in mm scenes (0.01 µm in metres),
//! far below the registration's accuracy (≈ 1 mm) and any display's resolution, and half the
//! bytes of f64. Clients that need the last bits use JSON results or gRPC (f64).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::codec::ResultMessage;
use super::error::ApiError;
use crate::evaluation::{
    present_or_null, ContactForceRecord, DiagnosticsRecord, ResultRecord, RigidRecord,
};

/// How results are sent: `?results=json|binary` on the stream URL, or on a frame's POST.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) enum ResultFormat {
    /// JSON: `{"type": "result", ...}` text messages on a stream, a JSON body for a POST
    /// (the default).
    #[default]
    Json,
    /// The binary encoding of this module: binary messages, or an `application/octet-stream`
    /// body.
    Binary,
}

impl ResultFormat {
    /// Reads the URL's query string: empty, or `results=json` / `results=binary`; any
    /// other parameter or value is a 400 naming it.
    pub(crate) fn from_query(query: Option<&str>) -> Result<Self, ApiError> {
        let mut format = Self::Json;
        for pair in query.unwrap_or("").split('&').filter(|p| !p.is_empty()) {
            match pair.split_once('=').unwrap_or((pair, "")) {
                ("results", "json") => format = Self::Json,
                ("results", "binary") => format = Self::Binary,
                ("results", other) => {
                    return Err(ApiError::bad_request(format!(
                        "query parameter results={other:?}: expected `json` or `binary`"
                    )))
                }
                (name, _) => {
                    return Err(ApiError::bad_request(format!(
                        "unknown query parameter {name:?} (expected only `results=json|binary`)"
                    )))
                }
            }
        }
        Ok(format)
    }
}

/// Magic bytes of a binary result.
pub const RESULT_MAGIC: [u8; 4] = *b"LVRR";
/// Version of the binary result encoding.
pub const RESULT_VERSION: u8 = 1;
/// Length of the fixed part of the header (before the per-structure counts), bytes.
pub const RESULT_HEADER: usize = 20;

/// Why a binary result could not be decoded (a truncated, corrupted or inconsistent message).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("binary result: {0}")]
pub struct ResultDecodeError(pub String);

fn bad(message: impl Into<String>) -> ResultDecodeError {
    ResultDecodeError(message.into())
}

/// The metadata as written (borrowing the message).
#[derive(Serialize)]
struct MetaOut<'a> {
    #[serde(rename = "type")]
    kind: &'static str,
    seq: u64,
    skipped: u64,
    server_ms: f64,
    queue_ms: f64,
    frame: usize,
    source: &'a str,
    wall_ms: f64,
    converged: bool,
    rigid: &'a RigidRecord,
    diagnostics: &'a DiagnosticsRecord,
    #[serde(skip_serializing_if = "Option::is_none")]
    contact_force: Option<&'a Option<ContactForceRecord>>,
    expected_error: Option<f64>,
    structure_names: Vec<&'a str>,
}

/// The metadata as read.
#[derive(Deserialize)]
struct MetaIn {
    #[serde(rename = "type")]
    kind: String,
    seq: u64,
    skipped: u64,
    server_ms: f64,
    queue_ms: f64,
    frame: usize,
    source: String,
    wall_ms: f64,
    converged: bool,
    rigid: RigidRecord,
    diagnostics: DiagnosticsRecord,
    #[serde(default, deserialize_with = "present_or_null")]
    contact_force: Option<Option<ContactForceRecord>>,
    #[serde(default)]
    expected_error: Option<f64>,
    structure_names: Vec<String>,
}

fn push_points(out: &mut Vec<u8>, points: &[[f64; 3]]) {
    for v in points.iter().flatten() {
        out.extend_from_slice(&(*v as f32).to_le_bytes());
    }
}

/// Encodes a result in the binary result encoding (see the module docs); coordinates are
/// rounded to f32. Fails only when the metadata cannot be written as JSON, or when an array
/// holds more than `u32::MAX` points.
pub fn encode_binary_result(msg: &ResultMessage) -> Result<Vec<u8>, ResultDecodeError> {
    // Exhaustive on purpose: a new field of the record must be added to the metadata too.
    let ResultRecord {
        frame,
        source,
        wall_ms,
        converged,
        rigid,
        diagnostics,
        structures,
        contact_force,
        expected_error,
    } = &msg.record;
    let meta = MetaOut {
        kind: "result",
        seq: msg.seq,
        skipped: msg.skipped,
        server_ms: msg.server_ms,
        queue_ms: msg.queue_ms,
        frame: *frame,
        source,
        wall_ms: *wall_ms,
        converged: *converged,
        rigid,
        diagnostics,
        contact_force: contact_force.as_ref(),
        expected_error: *expected_error,
        structure_names: structures.keys().map(String::as_str).collect(),
    };
    let mut json = serde_json::to_vec(&meta).map_err(|e| bad(format!("metadata: {e}")))?;
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let count = |n: usize, what: &str| {
        u32::try_from(n).map_err(|_| bad(format!("{what}: {n} is more than u32::MAX")))
    };
    let total_points = msg.surface.len() + structures.values().map(Vec::len).sum::<usize>();
    let mut out =
        Vec::with_capacity(RESULT_HEADER + 4 * structures.len() + json.len() + 12 * total_points);
    out.extend_from_slice(&RESULT_MAGIC);
    out.extend_from_slice(&[RESULT_VERSION, 0, 0, 0]);
    out.extend_from_slice(&count(json.len(), "metadata length")?.to_le_bytes());
    out.extend_from_slice(&count(msg.surface.len(), "surface vertices")?.to_le_bytes());
    out.extend_from_slice(&count(structures.len(), "structures")?.to_le_bytes());
    for (name, pts) in structures {
        out.extend_from_slice(&count(pts.len(), name)?.to_le_bytes());
    }
    out.extend_from_slice(&json);
    push_points(&mut out, &msg.surface);
    for pts in structures.values() {
        push_points(&mut out, pts);
    }
    Ok(out)
}

fn u32_at(bytes: &[u8], o: usize) -> Option<u32> {
    Some(u32::from_le_bytes(bytes.get(o..o + 4)?.try_into().ok()?))
}

fn read_points(bytes: &[u8], start: usize, n: usize) -> Vec<[f64; 3]> {
    bytes[start..start + 12 * n]
        .chunks_exact(12)
        .map(|c| {
            let f = |i: usize| f64::from(f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]));
            [f(0), f(4), f(8)]
        })
        .collect()
}

/// Decodes a binary result (see the module docs) into the message a JSON result gives, with
/// the coordinates widened from f32. Truncated, corrupted or inconsistent input is an error
/// saying what is wrong; never a panic.
pub fn decode_binary_result(bytes: &[u8]) -> Result<ResultMessage, ResultDecodeError> {
    if bytes.len() < RESULT_HEADER {
        return Err(bad(format!(
            "{} bytes is shorter than the {RESULT_HEADER}-byte header",
            bytes.len()
        )));
    }
    if bytes[0..4] != RESULT_MAGIC {
        return Err(bad("does not start with the magic `LVRR`"));
    }
    if bytes[4] != RESULT_VERSION {
        return Err(bad(format!(
            "version {} is not supported (this decoder reads version {RESULT_VERSION})",
            bytes[4]
        )));
    }
    if bytes[5..8] != [0, 0, 0] {
        return Err(bad("unknown flags or non-zero reserved bytes"));
    }
    let field = |o: usize| u32_at(bytes, o).map(|v| v as usize).unwrap_or(0);
    let (m, v, s) = (field(8), field(12), field(16));
    // Lengths in u128: no announced count can overflow the arithmetic.
    let counts_end = RESULT_HEADER as u128 + 4 * s as u128;
    if counts_end > bytes.len() as u128 {
        return Err(bad(format!(
            "{} bytes cannot hold the counts of the {s} structures its header announces",
            bytes.len()
        )));
    }
    let counts_end = counts_end as usize;
    let counts: Vec<usize> = (0..s).map(|i| field(RESULT_HEADER + 4 * i)).collect();
    let points: u128 = v as u128 + counts.iter().map(|&c| c as u128).sum::<u128>();
    let expected = counts_end as u128 + m as u128 + 12 * points;
    if expected != bytes.len() as u128 {
        return Err(bad(format!(
            "{} bytes, but its header announces {m} bytes of metadata, {v} surface vertices and \
             {s} structures of {counts:?} points: expected {expected} bytes",
            bytes.len()
        )));
    }
    let meta_bytes = &bytes[counts_end..counts_end + m];
    let meta: MetaIn = serde_json::from_slice(meta_bytes)
        .map_err(|e| bad(format!("malformed metadata JSON: {e}")))?;
    if meta.kind != "result" {
        return Err(bad(format!(
            "metadata type {:?}, expected \"result\"",
            meta.kind
        )));
    }
    if meta.structure_names.len() != s {
        return Err(bad(format!(
            "the metadata names {} structures, the header counts {s}",
            meta.structure_names.len()
        )));
    }
    let mut at = counts_end + m;
    let surface = read_points(bytes, at, v);
    at += 12 * v;
    let mut structures = BTreeMap::new();
    for (name, &c) in meta.structure_names.into_iter().zip(&counts) {
        let pts = read_points(bytes, at, c);
        at += 12 * c;
        if structures.insert(name.clone(), pts).is_some() {
            return Err(bad(format!("structure {name:?} appears twice")));
        }
    }
    Ok(ResultMessage {
        seq: meta.seq,
        skipped: meta.skipped,
        server_ms: meta.server_ms,
        queue_ms: meta.queue_ms,
        record: ResultRecord {
            frame: meta.frame,
            source: meta.source,
            wall_ms: meta.wall_ms,
            converged: meta.converged,
            rigid: meta.rigid,
            diagnostics: meta.diagnostics,
            structures,
            contact_force: meta.contact_force,
            expected_error: meta.expected_error,
        },
        surface,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A message with every field set to something other than its default, and coordinates
    /// that are not f32-exact.
    fn message() -> ResultMessage {
        let mut structures = BTreeMap::new();
        structures.insert(
            "vessels".to_string(),
            vec![[0.1, -2.2, 3.3], [4.4, 5.5, -6.6]],
        );
        structures.insert("nodes".to_string(), vec![[1.0 / 3.0, 2.0 / 3.0, 1e-3]]);
        structures.insert("empty".to_string(), vec![]);
        ResultMessage {
            seq: 41,
            skipped: 2,
            server_ms: 21.5,
            queue_ms: 0.25,
            record: ResultRecord {
                frame: 7,
                source: "pc07.xyz".into(),
                wall_ms: 19.75,
                converged: false,
                rigid: RigidRecord {
                    rotation: [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
                    translation: [1.5, -2.0, 0.125],
                    uncertainty: Some(1.75),
                },
                diagnostics: DiagnosticsRecord {
                    icp_iterations: 3,
                    newton_iterations: 11,
                    surface_rms: 0.4,
                    rigid_iterations: 5,
                    cloud_points: 1234,
                    sources: 321,
                    timings_ms: [("newton".to_string(), 12.5)].into_iter().collect(),
                    flags: vec!["failed".into()],
                    error: Some("no-match: too few pairs".into()),
                    warnings: vec!["bisection limit".into()],
                    expected_error_parts: None,
                },
                structures,
                contact_force: Some(Some(ContactForceRecord {
                    resultant_n: [0.25, -3.5, 1.0],
                    magnitude_n: 3.648,
                    centre: [-12.5, 40.25, 8.0],
                    expected_error_n: Some(1.25),
                })),
                expected_error: Some(2.625),
            },
            surface: (0..50)
                .map(|i| {
                    let t = f64::from(i) * 0.37;
                    [t.sin() * 80.0, t.cos() * 61.3, -t / 7.0]
                })
                .collect(),
        }
    }

    fn round_f32(p: &[[f64; 3]]) -> Vec<[f64; 3]> {
        p.iter().map(|q| q.map(|c| f64::from(c as f32))).collect()
    }

    #[test]
    fn binary_results_round_trip_to_f32_precision() {
        let msg = message();
        let b = encode_binary_result(&msg).unwrap();
        let points = 50 + 2 + 1;
        let m = u32_at(&b, 8).unwrap() as usize;
        assert_eq!(m % 4, 0, "metadata padded to 4 bytes");
        assert_eq!(b.len(), RESULT_HEADER + 4 * 3 + m + 12 * points);
        // About a quarter of the JSON message for the same result.
        let json = serde_json::to_vec(&msg).unwrap();
        assert!(b.len() < json.len(), "{} >= {}", b.len(), json.len());
        let got = decode_binary_result(&b).unwrap();
        // Everything but the coordinates is exact; coordinates are the f32 nearest to them.
        let mut want = msg.clone();
        want.surface = round_f32(&msg.surface);
        for pts in want.record.structures.values_mut() {
            *pts = round_f32(pts);
        }
        assert_eq!(got, want);
        assert_ne!(got.surface, msg.surface, "the coordinates were rounded");
        for (g, w) in got.surface.iter().zip(&msg.surface) {
            for k in 0..3 {
                assert!((g[k] - w[k]).abs() <= w[k].abs() * f64::from(f32::EPSILON));
            }
        }
    }

    #[test]
    fn truncated_or_corrupted_binary_results_are_errors() {
        let b = encode_binary_result(&message()).unwrap();
        // Every truncation is refused (never a panic).
        for n in 0..b.len() {
            assert!(decode_binary_result(&b[..n]).is_err(), "truncated to {n}");
        }
        let e = decode_binary_result(&b[..b.len() - 1]).unwrap_err();
        assert!(e.to_string().contains("expected"), "{e}");
        let mut longer = b.clone();
        longer.extend_from_slice(&[0; 12]);
        assert!(decode_binary_result(&longer).is_err());
        let edit = |o: usize, bytes: &[u8]| {
            let mut c = b.clone();
            c[o..o + bytes.len()].copy_from_slice(bytes);
            decode_binary_result(&c).unwrap_err().to_string()
        };
        assert!(edit(0, b"LVRG").contains("magic"));
        assert!(edit(4, &[2]).contains("version 2"));
        assert!(edit(5, &[1]).contains("flags"));
        // Announced counts that do not match the length, including ones that would overflow.
        assert!(edit(12, &51u32.to_le_bytes()).contains("expected"));
        assert!(edit(12, &u32::MAX.to_le_bytes()).contains("expected"));
        assert!(edit(16, &u32::MAX.to_le_bytes()).contains("counts"));
        assert!(edit(8, &0u32.to_le_bytes()).contains("expected"));
        let m = u32_at(&b, 8).unwrap() as usize;
        let meta_start = RESULT_HEADER + 12;
        // Corrupted metadata.
        let mut c = b.clone();
        c[meta_start] = b'[';
        assert!(decode_binary_result(&c)
            .unwrap_err()
            .to_string()
            .contains("metadata"));
        let meta: String = String::from_utf8(b[meta_start..meta_start + m].to_vec()).unwrap();
        let swapped = meta.replace("\"result\"", "\"errorr\"");
        assert!(edit(meta_start, swapped.as_bytes()).contains("type"));
        let fewer = meta.replacen("\"empty\",", "", 1);
        assert_ne!(fewer, meta);
        let mut c = b[..meta_start].to_vec();
        let mut j = fewer.into_bytes();
        j.resize(m, b' ');
        c.extend_from_slice(&j);
        c.extend_from_slice(&b[meta_start + m..]);
        assert!(decode_binary_result(&c)
            .unwrap_err()
            .to_string()
            .contains("names 2 structures"));
    }
}
