//! JSON Schemas (draft 2020-12) of the recording's channels, written into the MCAP schema
//! records (`encoding = "jsonschema"`) so generic tools (Foxglove, `mcap` readers) can decode
//! and describe the JSON messages.

use serde_json::{json, Value};

/// Schema name of [`super::TOPIC_SESSION`].
pub(crate) const SESSION_SCHEMA: &str = "livereg.Session";
/// Schema name of [`super::TOPIC_SCENE`].
pub(crate) const SCENE_SCHEMA: &str = "livereg.Scene";
/// Schema name of [`super::TOPIC_FRAMES`].
pub(crate) const FRAME_SCHEMA: &str = "livereg.Frame";
/// Schema name of [`super::TOPIC_RESULTS`].
pub(crate) const RESULT_SCHEMA: &str = "livereg.Result";

fn vec3() -> Value {
    json!({"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3})
}

fn flat_points(what: &str) -> Value {
    json!({
        "type": "array",
        "items": {"type": "number"},
        "description": format!("{what}: flat [x0, y0, z0, x1, ...], scene units, cloud frame")
    })
}

/// The JSON Schema of `/session`.
pub(crate) fn session() -> Value {
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": SESSION_SCHEMA,
        "description": "What made the recording (one message).",
        "type": "object",
        "required": ["format", "format_version", "livereg_version", "created_ns", "command", "units", "length_scale"],
        "properties": {
            "format": {"type": "string", "const": super::FORMAT_NAME},
            "format_version": {"type": "integer"},
            "livereg_version": {"type": "string"},
            "created_ns": {"type": "integer", "description": "ns since the Unix epoch"},
            "command": {"type": "string"},
            "units": {"type": "string", "enum": ["m", "cm", "mm"]},
            "length_scale": {"type": "number", "description": "metres per scene unit"},
            "budget_ms": {"type": "number"},
            "rigid_only": {"type": "boolean"},
            "notes": {"type": "object", "additionalProperties": {"type": "string"}}
        }
    })
}

/// The JSON Schema of `/scene`.
pub(crate) fn scene() -> Value {
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": SCENE_SCHEMA,
        "description": "The scene file and the bytes of every file it names (one message).",
        "type": "object",
        "required": ["name", "format", "text", "files"],
        "properties": {
            "name": {"type": "string"},
            "format": {"type": "string", "enum": ["toml", "json"]},
            "text": {"type": "string"},
            "files": {
                "type": "array",
                "items": {
                    "type": "object",
                    "required": ["key", "path", "name", "size", "data_base64"],
                    "properties": {
                        "key": {"type": "string", "description": "scene key naming the file"},
                        "path": {"type": "string"},
                        "name": {"type": "string"},
                        "size": {"type": "integer"},
                        "data_base64": {"type": "string", "contentEncoding": "base64"}
                    }
                }
            }
        }
    })
}

/// The JSON Schema of `/frames`.
pub(crate) fn frame() -> Value {
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": FRAME_SCHEMA,
        "description": "One intra-operative point cloud as received.",
        "type": "object",
        "required": ["frame", "source", "timestamp_ns", "points"],
        "properties": {
            "frame": {"type": "integer"},
            "source": {"type": "string"},
            "timestamp_ns": {"type": "integer", "description": "ns since the Unix epoch"},
            "points": flat_points("the cloud"),
            "camera": {
                "type": "object",
                "required": ["position", "look_at", "up", "fov_deg"],
                "properties": {"position": vec3(), "look_at": vec3(), "up": vec3(), "fov_deg": {"type": "number"}}
            },
            "input_error": {"type": "string", "description": "why the input could not be read"}
        }
    })
}

/// The JSON Schema of `/results`: the `results.jsonl` line (contracts.md) plus the surface.
pub(crate) fn result() -> Value {
    let matrix = json!({"type": "array", "items": vec3(), "minItems": 3, "maxItems": 3});
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": RESULT_SCHEMA,
        "description": "One frame's registration: the results.jsonl line plus the deformed surface.",
        "type": "object",
        "required": ["frame", "source", "wall_ms", "converged", "rigid", "diagnostics", "structures", "timestamp_ns", "surface"],
        "properties": {
            "frame": {"type": "integer"},
            "source": {"type": "string"},
            "wall_ms": {"type": "number"},
            "converged": {"type": "boolean"},
            "rigid": {
                "type": "object",
                "required": ["rotation", "translation"],
                "properties": {"rotation": matrix, "translation": vec3(), "uncertainty": {"type": "number"}}
            },
            "diagnostics": {
                "type": "object",
                "required": ["icp_iterations", "newton_iterations", "surface_rms"],
                "properties": {
                    "icp_iterations": {"type": "integer"},
                    "newton_iterations": {"type": "integer"},
                    "surface_rms": {"type": "number"},
                    "rigid_iterations": {"type": "integer"},
                    "cloud_points": {"type": "integer"},
                    "sources": {"type": "integer"},
                    "timings_ms": {"type": "object", "additionalProperties": {"type": "number"}},
                    "flags": {"type": "array", "items": {"type": "string"}},
                    "error": {"type": "string"},
                    "warnings": {"type": "array", "items": {"type": "string"}},
                    "expected_error_parts": {
                        "type": "object",
                        "required": ["pose", "unseen", "residual"],
                        "properties": {"pose": {"type": "number"}, "unseen": {"type": "number"}, "residual": {"type": "number"}, "noise": {"type": "number"}}
                    }
                }
            },
            "structures": {
                "type": "object",
                "additionalProperties": {"type": "array", "items": vec3()},
                "description": "deformed points of every structure, scene units, cloud frame"
            },
            "contact_force": {
                "type": ["object", "null"],
                "description": "surface loads the registration needed: resultant (N) and centre (scene units), cloud frame; absent when none was estimated, null when the estimate cannot be trusted (flag force_beyond_linear)",
                "required": ["resultant_n", "magnitude_n", "centre"],
                "properties": {"resultant_n": vec3(), "magnitude_n": {"type": "number"}, "centre": vec3(), "expected_error_n": {"type": "number"}}
            },
            "expected_error": {
                "type": ["number", "null"],
                "description": "the registration's estimate of the mean error of the structures, scene units (null before any frame succeeded)"
            },
            "timestamp_ns": {"type": "integer"},
            "warm": {"type": "boolean"},
            "factorizations": {"type": "integer"},
            "cloud_points_used": {"type": "integer"},
            "surface": flat_points("deformed surface vertices")
        }
    })
}
