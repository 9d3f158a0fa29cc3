//! The OpenAPI 3.0 document of the HTTP API, served at `/v1/openapi.json`. A test
//! (`tests/server/server_http.rs`) checks that it lists exactly [`super::http::ROUTES`] and
//! that real responses match its schemas and status codes.

use serde_json::{json, Value};

fn error_response(description: &str) -> Value {
    json!({"description": description,
           "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}}})
}

fn json_response(description: &str, schema: &str) -> Value {
    json!({"description": description,
           "content": {"application/json": {"schema": {"$ref": format!("#/components/schemas/{schema}")}}}})
}

fn id_param() -> Value {
    json!({"name": "id", "in": "path", "required": true,
           "description": "Session id (32 lowercase hex digits).",
           "schema": {"type": "string"}})
}

/// The document: the API's info, its schemas ([`schemas`]) and its routes ([`paths`]).
pub(crate) fn document() -> Value {
    json!({
      "openapi": "3.0.3",
      "info": {
        "title": "livereg registration server",
        "version": "1.0.0",
        "description": "Registers a pre-operative liver model to intra-operative point clouds. Lengths are in the scene's units; results are in the cloud's (camera's) frame. Every /v1 route except this document needs `Authorization: Bearer <token>`. Errors are `{\"error\": {\"code\", \"message\"}}`. See docs/server.md."
      },
      "components": {
        "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}},
        "schemas": schemas()
      },
      "security": [{"bearer": []}],
      "paths": paths()
    })
}

/// The request and response bodies (`components.schemas`).
fn schemas() -> Value {
    json!({
      "Error": {
        "type": "object", "required": ["error"],
        "properties": {"error": {"type": "object", "required": ["code", "message"],
          "properties": {"code": {"type": "string"}, "message": {"type": "string"}}}}
      },
      "Health": {"type": "object", "required": ["status"], "properties": {"status": {"type": "string"}}},
      "Ready": {"type": "object", "required": ["status", "sessions"],
                "properties": {"status": {"type": "string"}, "sessions": {"type": "integer"}}},
      "Point": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
      "InlineMesh": {
        "type": "object", "required": ["vertices", "triangles"],
        "properties": {
          "vertices": {"type": "array", "items": {"$ref": "#/components/schemas/Point"}},
          "triangles": {"type": "array", "items": {"type": "array", "items": {"type": "integer"}, "minItems": 3, "maxItems": 3}}
        }
      },
      "CreateSession": {
        "type": "object", "required": ["scene"],
        "description": "Inline creation: `scene` is the scene file as a JSON object (or TOML text); the file names it uses are keys of `meshes` (OBJ), `points` (XYZ) or `files` (text).",
        "properties": {
          "scene": {"description": "The scene (JSON object) or TOML text."},
          "meshes": {"type": "object", "additionalProperties": {"$ref": "#/components/schemas/InlineMesh"}},
          "points": {"type": "object", "additionalProperties": {"type": "array", "items": {"$ref": "#/components/schemas/Point"}}},
          "files": {"type": "object", "additionalProperties": {"type": "string"}},
          "budget_ms": {"type": "number"},
          "rigid_only": {"type": "boolean"}
        }
      },
      "CreateSessionUpload": {
        "type": "object", "required": ["scene"],
        "description": "Files of a scene uploaded together: a `scene` part (scene.toml or scene.json) and one part per file it names, each with its filename.",
        "properties": {
          "scene": {"type": "string", "format": "binary"},
          "budget_ms": {"type": "number"},
          "rigid_only": {"type": "boolean"}
        },
        "additionalProperties": {"type": "string", "format": "binary"}
      },
      "SessionInfo": {
        "type": "object",
        "required": ["id", "units", "surface_vertices", "surface_triangles", "structures",
                     "frames_registered", "frames_failed", "frames_skipped", "frames_rejected",
                     "age_s", "warm", "stream"],
        "properties": {
          "id": {"type": "string"}, "units": {"type": "string", "enum": ["m", "cm", "mm"]},
          "surface_vertices": {"type": "integer"}, "surface_triangles": {"type": "integer"},
          "structures": {"type": "array", "items": {"type": "string"}},
          "frames_registered": {"type": "integer"}, "frames_failed": {"type": "integer"},
          "frames_skipped": {"type": "integer"}, "frames_rejected": {"type": "integer"},
          "age_s": {"type": "number"}, "warm": {"type": "boolean"},
          "stream": {"type": "string", "description": "Relative URL of the session's WebSocket."},
          "recording": {"type": ["string", "null"], "description": "File name of the session's MCAP recording in the server's recordings directory (never a server path); null when not recorded."},
          "recording_error": {"type": "string", "description": "Why the recording stopped while the session went on; absent while it records."},
          "memory_estimate_mb": {"type": "number", "description": "The session's estimated peak memory, MiB, counted against the server's memory budget (limits.max_memory_mb)."}
        }
      },
      "SessionList": {"type": "object", "required": ["sessions"],
        "properties": {"sessions": {"type": "array", "items": {"$ref": "#/components/schemas/SessionInfo"}}}},
      "Camera": {"type": "object", "required": ["position", "look_at"],
        "properties": {"position": {"$ref": "#/components/schemas/Point"},
                       "look_at": {"$ref": "#/components/schemas/Point"},
                       "up": {"$ref": "#/components/schemas/Point"}}},
      "Frame": {
        "type": "object", "required": ["points"],
        "properties": {
          "seq": {"type": "integer", "description": "Client frame number, echoed."},
          "source": {"type": "string"},
          "points": {"type": "array", "items": {"$ref": "#/components/schemas/Point"}},
          "camera": {"$ref": "#/components/schemas/Camera"}
        }
      },
      "Rigid": {"type": "object", "required": ["rotation", "translation"],
        "properties": {"rotation": {"type": "array", "items": {"$ref": "#/components/schemas/Point"}},
                       "translation": {"$ref": "#/components/schemas/Point"},
                         "uncertainty": {"type": "number", "description": "The pose's 1σ misplacement of the model surface (RMS over its vertices) from the fit's noise, scene units; a lower bound. Absent when the pose was given (rigid = none) or not determined."}}},
      "ContactForce": {"type": "object", "required": ["resultant_n", "magnitude_n", "centre"],
        "description": "The one concentrated load at the dent that explains the registered deformation (docs/contact-force.md).",
        "properties": {"resultant_n": {"$ref": "#/components/schemas/Point"},
                       "magnitude_n": {"type": "number"},
                       "centre": {"$ref": "#/components/schemas/Point"},
                       "expected_error_n": {"type": "number", "description": "The estimate's expected error, N: the length the error of resultant_n likely has (docs/contact-force.md#expected-error)."}}},
      "Diagnostics": {
        "type": "object", "required": ["icp_iterations", "newton_iterations", "surface_rms"],
        "properties": {
          "icp_iterations": {"type": "integer"}, "newton_iterations": {"type": "integer"},
          "surface_rms": {"type": "number"}, "rigid_iterations": {"type": "integer"},
          "cloud_points": {"type": "integer"}, "sources": {"type": "integer"},
          "timings_ms": {"type": "object", "additionalProperties": {"type": "number"}},
          "flags": {"type": "array", "items": {"type": "string"}},
          "error": {"type": "string", "description": "Why registration failed; positions are then the last good state's."},
          "warnings": {"type": "array", "items": {"type": "string"}}
        }
      },
      "Result": {
        "type": "object",
        "description": "A results.jsonl line of `livereg register` plus the deformed surface and transport fields.",
        "required": ["seq", "skipped", "server_ms", "queue_ms", "frame", "source", "wall_ms",
                     "converged", "rigid", "diagnostics", "structures", "surface"],
        "properties": {
          "seq": {"type": "integer"}, "skipped": {"type": "integer"},
          "server_ms": {"type": "number"}, "queue_ms": {"type": "number"},
          "frame": {"type": "integer"}, "source": {"type": "string"},
          "wall_ms": {"type": "number"}, "converged": {"type": "boolean"},
          "rigid": {"$ref": "#/components/schemas/Rigid"},
          "diagnostics": {"$ref": "#/components/schemas/Diagnostics"},
          "structures": {"type": "object", "additionalProperties": {"type": "array", "items": {"$ref": "#/components/schemas/Point"}}},
          "surface": {"type": "array", "items": {"$ref": "#/components/schemas/Point"}},
      "contact_force": {"description": "Absent when no force was estimated; null when the estimate cannot be trusted (a diagnostics flag says why: force_beyond_linear).", "anyOf": [{"$ref": "#/components/schemas/ContactForce"}, {"type": "null"}]}
        }
      }
    })
}

/// The routes, one entry per path of [`super::http::ROUTES`], with their responses.
fn paths() -> Value {
    let auth_errors = |mut v: serde_json::Map<String, Value>| {
        v.insert(
            "401".into(),
            error_response("Missing or wrong bearer token."),
        );
        Value::Object(v)
    };
    let session_errors = |mut v: serde_json::Map<String, Value>| {
        v.insert(
            "404".into(),
            error_response(
                "No such session for this token (another token's sessions are never revealed).",
            ),
        );
        auth_errors(v)
    };
    let m = |v: Value| v.as_object().cloned().unwrap_or_default();
    json!({
      "/healthz": {"get": {"summary": "Liveness.", "security": [],
        "responses": {"200": json_response("Alive.", "Health")}}},
      "/readyz": {"get": {"summary": "Readiness: 503 while shutting down.", "security": [],
        "responses": {"200": json_response("Ready.", "Ready"),
                      "503": error_response("Shutting down.")}}},
      "/metrics": {"get": {"summary": "Prometheus metrics (text exposition 0.0.4).", "security": [],
        "responses": {"200": {"description": "Metrics.", "content": {"text/plain": {"schema": {"type": "string"}}}}}}},
      "/v1/openapi.json": {"get": {"summary": "This document.", "security": [],
        "responses": {"200": {"description": "OpenAPI 3.0 document.", "content": {"application/json": {"schema": {"type": "object"}}}}}}},
      "/v1/sessions": {
        "post": {
          "summary": "Create a session from a scene (inline JSON, or the scene's files uploaded together).",
          "requestBody": {"required": true, "content": {
            "application/json": {"schema": {"$ref": "#/components/schemas/CreateSession"}},
            "multipart/form-data": {"schema": {"$ref": "#/components/schemas/CreateSessionUpload"}}}},
          "responses": auth_errors(m(json!({
            "201": json_response("Created.", "SessionInfo"),
            "400": error_response("Malformed request (JSON or multipart syntax)."),
            "413": error_response("Body, mesh, grid or work over a limit (payload_too_large, mesh_too_large, grid_too_large, work_too_large), or a model needing more memory than the server's whole budget (model_too_large)."),
            "415": error_response("Neither JSON nor multipart."),
            "422": error_response("The scene does not load (invalid_scene; the message names key and file)."),
            "429": error_response("Session limit of the token or the server reached (too_many_sessions), or the server's memory budget is held by open sessions (memory_budget): try another replica or later."),
            "503": error_response("Shutting down.")
          })))
        },
        "get": {"summary": "The caller's sessions.",
          "responses": auth_errors(m(json!({"200": json_response("Sessions.", "SessionList")})))}
      },
      "/v1/sessions/{id}": {
        "parameters": [id_param()],
        "get": {"summary": "Describe a session.",
          "responses": session_errors(m(json!({"200": json_response("The session.", "SessionInfo")})))},
        "delete": {"summary": "Close a session (frames in flight finish).",
          "responses": session_errors(m(json!({"200": json_response("Closed; final counters.", "SessionInfo")})))}
      },
      "/v1/sessions/{id}/reset": {
        "parameters": [id_param()],
        "post": {"summary": "Forget all frames: the next frame is registered cold from the rest shape.",
          "responses": session_errors(m(json!({"200": json_response("Reset.", "SessionInfo")})))}
      },
      "/v1/sessions/{id}/frames": {
        "parameters": [id_param()],
        "post": {
          "summary": "Register one frame and return its result. JSON, or the binary encoding (application/octet-stream, docs/server.md).",
          "description": "With `results=binary` the result comes in the binary result encoding (application/octet-stream; as the stream's binary messages, docs/server.md \"Binary result encoding\"). Errors stay JSON.",
          "parameters": [{"name": "results", "in": "query", "required": false,
            "description": "Encoding of the result: `json` (the default) or `binary` (f32 coordinates).",
            "schema": {"type": "string", "enum": ["json", "binary"], "default": "json"}}],
          "requestBody": {"required": true, "content": {
            "application/json": {"schema": {"$ref": "#/components/schemas/Frame"}},
            "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}},
          "responses": session_errors(m(json!({
            "200": {"description": "Registered (a registration failure is reported in diagnostics.error with the last good state).",
              "content": {
                "application/json": {"schema": {"$ref": "#/components/schemas/Result"}},
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}},
            "400": error_response("Malformed frame, unknown query parameter, or a `results` value other than json or binary."),
            "409": error_response("A newer frame of the session arrived first; this one was skipped (frame_superseded)."),
            "413": error_response("Body or points over a limit."),
            "422": error_response("Empty frame, non-finite coordinate or bad camera (invalid_frame)."),
            "429": error_response("Over the session's frame rate (rate_limited)."),
            "503": error_response("Shutting down.")
          })))
        }
      },
      "/v1/sessions/{id}/stream": {
        "parameters": [id_param()],
        "get": {
          "summary": "WebSocket: frames in (JSON text or binary), results out as they finish (`{\"type\":\"result\",...}` with `skipped`, or `{\"type\":\"error\",\"seq\",\"error\"}`).",
          "description": "With `results=binary` each result is a binary message instead: the header (magic `LVRR`, version 1, metadata length, surface vertex count, structure count and points per structure, u32 little-endian), the result's JSON without `surface` and `structures` (plus `structure_names`), then the surface vertices and each structure's points as little-endian f32 x, y, z (docs/server.md, \"Binary result encoding\"). Errors stay JSON text messages.",
          "parameters": [{"name": "results", "in": "query", "required": false,
            "description": "Encoding of the results: `json` (text messages, the default) or `binary` (binary messages, f32 coordinates).",
            "schema": {"type": "string", "enum": ["json", "binary"], "default": "json"}}],
          "responses": session_errors(m(json!({
            "101": {"description": "Switching to the WebSocket protocol."},
            "400": error_response("Unknown query parameter, or a `results` value other than json or binary."),
            "426": error_response("Not a WebSocket upgrade request."),
            "503": error_response("Shutting down.")
          })))
        }
      }
    })
}
