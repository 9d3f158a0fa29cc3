//! The HTTP API against an in-process server on loopback: session creation (multipart and
//! inline JSON), frames, ownership, limits, the bad-input suite with a healthy session
//! streaming alongside, operations endpoints, and the OpenAPI document kept true.

use livereg::simulation::FromScene;
use std::net::SocketAddr;

use serde_json::{json, Value};

use crate::client::*;
use crate::server_support::*;

fn auth(token: &str) -> String {
    format!("Bearer {token}")
}

async fn post_json(addr: SocketAddr, path: &str, token: &str, body: &Value) -> HttpResponse {
    let a = auth(token);
    http(
        addr,
        "POST",
        path,
        &[("Authorization", &a), ("Content-Type", "application/json")],
        body.to_string().as_bytes(),
    )
    .await
    .unwrap()
}

fn assert_error(r: &HttpResponse, status: u16, code: &str) {
    let v = r.json();
    assert_eq!(
        r.status,
        status,
        "expected {status} {code}, got {} {}",
        r.status,
        String::from_utf8_lossy(&r.body)
    );
    assert_eq!(v["error"]["code"], code, "{v}");
    assert!(
        v["error"]["message"].as_str().is_some_and(|m| m.len() > 10),
        "{v}"
    );
}

fn frame_points(case: &std::path::Path, k: usize) -> Vec<[f64; 3]> {
    livereg::mesh::read_points(&case.join(format!("frames/f{k:03}.xyz")))
        .unwrap()
        .iter()
        .map(|p| [p.x, p.y, p.z])
        .collect()
}

/// A minimal JSON-schema check (type, required, properties, items, enum, $ref,
/// additionalProperties) of `v` against `schema` in `doc`.
fn check_schema(doc: &Value, schema: &Value, v: &Value, at: &str) -> Result<(), String> {
    if let Some(r) = schema["$ref"].as_str() {
        let name = r.rsplit('/').next().unwrap();
        return check_schema(doc, &doc["components"]["schemas"][name], v, at);
    }
    if let Some(t) = schema["type"].as_str() {
        let ok = match t {
            "object" => v.is_object(),
            "array" => v.is_array(),
            "string" => v.is_string(),
            "integer" => v.is_u64() || v.is_i64(),
            "number" => v.is_number(),
            "boolean" => v.is_boolean(),
            _ => true,
        };
        if !ok {
            return Err(format!("{at}: expected {t}, got {v}"));
        }
    }
    if let Some(e) = schema["enum"].as_array() {
        if !e.contains(v) {
            return Err(format!("{at}: {v} not in {e:?}"));
        }
    }
    if let Some(req) = schema["required"].as_array() {
        for k in req {
            let k = k.as_str().unwrap();
            if v.get(k).is_none() {
                return Err(format!("{at}: required `{k}` missing"));
            }
        }
    }
    if let (Some(props), Some(obj)) = (schema["properties"].as_object(), v.as_object()) {
        for (k, s) in props {
            if let Some(x) = obj.get(k) {
                check_schema(doc, s, x, &format!("{at}.{k}"))?;
            }
        }
        if let Some(extra) = schema.get("additionalProperties").filter(|a| a.is_object()) {
            for (k, x) in obj {
                if !props.contains_key(k) {
                    check_schema(doc, extra, x, &format!("{at}.{k}"))?;
                }
            }
        }
    } else if let (Some(extra), Some(obj)) = (
        schema.get("additionalProperties").filter(|a| a.is_object()),
        v.as_object(),
    ) {
        for (k, x) in obj {
            check_schema(doc, extra, x, &format!("{at}.{k}"))?;
        }
    }
    if let (Some(items), Some(arr)) = (schema.get("items"), v.as_array()) {
        // Check the first few items (results carry thousands of points).
        for (i, x) in arr.iter().enumerate().take(5) {
            check_schema(doc, items, x, &format!("{at}[{i}]"))?;
        }
    }
    Ok(())
}

/// Checks a real response against the document: the status is documented for the operation,
/// and a JSON body matches the documented schema.
fn check_documented(doc: &Value, method: &str, path: &str, r: &HttpResponse) {
    let op = &doc["paths"][path][method.to_ascii_lowercase()];
    assert!(op.is_object(), "{method} {path} is not documented");
    let resp = &op["responses"][r.status.to_string()];
    assert!(
        resp.is_object(),
        "{method} {path} answered {} which is not documented: {}",
        r.status,
        String::from_utf8_lossy(&r.body)
    );
    if let Some(schema) = resp["content"]["application/json"].get("schema") {
        let v: Value = serde_json::from_slice(&r.body).expect("JSON body");
        check_schema(doc, schema, &v, &format!("{method} {path} {}", r.status))
            .unwrap_or_else(|e| panic!("{e}"));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_frames_ownership_and_the_openapi_document() {
    let case = small_case("http", 4);
    let server = start(test_config("http")).await;
    let addr = server.http_addr;
    let doc = http(addr, "GET", "/v1/openapi.json", &[], b"")
        .await
        .unwrap();
    assert_eq!(doc.status, 200);
    let doc = doc.json();
    // Every route is documented and every documented path is a route.
    let mut documented: Vec<(String, String)> = Vec::new();
    for (path, item) in doc["paths"].as_object().unwrap() {
        for m in ["get", "post", "delete", "put", "patch"] {
            if item.get(m).is_some() {
                documented.push((m.to_ascii_uppercase(), path.clone()));
            }
        }
    }
    let mut routes: Vec<(String, String)> = livereg::server::http::ROUTES
        .iter()
        .map(|(m, p)| (m.to_string(), p.to_string()))
        .collect();
    documented.sort();
    routes.sort();
    assert_eq!(documented, routes, "OpenAPI paths differ from the router's");

    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    // Multipart creation.
    let (boundary, body) = scene.multipart();
    let ct = format!("multipart/form-data; boundary={boundary}");
    let a = auth(TOKEN_A);
    let r = http(
        addr,
        "POST",
        "/v1/sessions",
        &[("Authorization", &a), ("Content-Type", &ct)],
        &body,
    )
    .await
    .unwrap();
    check_documented(&doc, "POST", "/v1/sessions", &r);
    assert_eq!(r.status, 201);
    let info = r.json();
    let id = info["id"].as_str().unwrap().to_string();
    assert_eq!(id.len(), 32);
    assert_eq!(info["structures"], json!(["targets"]));
    assert_eq!(info["units"], "mm");

    // Inline creation: the same scene as a JSON object with inline arrays.
    let surf = livereg::mesh::read_surface(&case.join("body.obj")).unwrap();
    let inline = json!({
        "scene": {"units": "mm", "model": {"surface": "body.obj",
                    "structures": [{"name": "targets", "points": "targets.xyz"}]},
                  "grid": {"cell_size": 25.0, "subdivisions": 2},
                  "material": {"law": "neo-hookean", "young_modulus": 4500.0, "poisson_ratio": 0.45},
                  "boundary": {"fixed": [{"box": [[-60.0, -60.0, -60.0], [-35.0, 60.0, 60.0]]}]},
                  "registration": {"rigid": "icp"}},
        "meshes": {"body.obj": {
            "vertices": surf.vertices.iter().map(|v| [v.x, v.y, v.z]).collect::<Vec<_>>(),
            "triangles": surf.triangles.iter().map(|t| [t[0], t[1], t[2]]).collect::<Vec<_>>()}},
        "points": {"targets.xyz": [[-20.0, 0.0, 0.0], [10.0, 5.0, 0.0], [35.0, 0.0, -3.0]]}
    });
    let r = post_json(addr, "/v1/sessions", TOKEN_A, &inline).await;
    check_documented(&doc, "POST", "/v1/sessions", &r);
    assert_eq!(r.status, 201, "{}", String::from_utf8_lossy(&r.body));
    let id2 = r.json()["id"].as_str().unwrap().to_string();

    // A frame over HTTP on both: the same result (the scenes are the same).
    let pts = frame_points(&case, 0);
    let path = format!("/v1/sessions/{id}/frames");
    let r = post_json(
        addr,
        &path,
        TOKEN_A,
        &json!({"seq": 5, "source": "f000.xyz", "points": pts}),
    )
    .await;
    check_documented(&doc, "POST", "/v1/sessions/{id}/frames", &r);
    assert_eq!(r.status, 200);
    let res = r.json();
    assert_eq!(res["seq"], 5);
    assert_eq!(res["frame"], 0);
    assert_eq!(res["source"], "f000.xyz");
    assert_eq!(
        res["surface"].as_array().unwrap().len(),
        surf.vertices.len()
    );
    assert!(
        res["diagnostics"].get("error").is_none(),
        "{}",
        res["diagnostics"]
    );
    let r2 = post_json(
        addr,
        &format!("/v1/sessions/{id2}/frames"),
        TOKEN_A,
        &json!({"seq": 5, "source": "f000.xyz", "points": pts}),
    )
    .await;
    same(
        &res["structures"],
        &r2.json()["structures"],
        "inline vs multipart",
    )
    .unwrap();
    // The binary encoding over HTTP.
    let p32: Vec<[f32; 3]> = pts.iter().map(|p| p.map(|c| c as f32)).collect();
    let bin = livereg::server::codec::encode_binary_frame(6, &p32, None);
    let r = http(
        addr,
        "POST",
        &path,
        &[
            ("Authorization", &a),
            ("Content-Type", "application/octet-stream"),
        ],
        &bin,
    )
    .await
    .unwrap();
    check_documented(&doc, "POST", "/v1/sessions/{id}/frames", &r);
    assert_eq!(r.status, 200);
    assert_eq!(r.json()["frame"], 1);
    assert_eq!(r.json()["seq"], 6);

    // Describe, list, reset; ownership: token B sees nothing of A's.
    let r = http(
        addr,
        "GET",
        &format!("/v1/sessions/{id}"),
        &[("Authorization", &a)],
        b"",
    )
    .await
    .unwrap();
    check_documented(&doc, "GET", "/v1/sessions/{id}", &r);
    assert_eq!(r.json()["frames_registered"], 2);
    assert_eq!(r.json()["warm"], true);
    let r = http(addr, "GET", "/v1/sessions", &[("Authorization", &a)], b"")
        .await
        .unwrap();
    check_documented(&doc, "GET", "/v1/sessions", &r);
    assert_eq!(r.json()["sessions"].as_array().unwrap().len(), 2);
    let b = auth(TOKEN_B);
    let r = http(addr, "GET", "/v1/sessions", &[("Authorization", &b)], b"")
        .await
        .unwrap();
    assert_eq!(r.json()["sessions"], json!([]));
    for (m, p) in [
        ("GET", format!("/v1/sessions/{id}")),
        ("DELETE", format!("/v1/sessions/{id}")),
        ("POST", format!("/v1/sessions/{id}/reset")),
    ] {
        let r = http(addr, m, &p, &[("Authorization", &b)], b"")
            .await
            .unwrap();
        assert_error(&r, 404, "not_found");
    }
    let r = post_json(addr, &path, TOKEN_B, &json!({"points": pts})).await;
    assert_error(&r, 404, "not_found");
    let r = http(
        addr,
        "POST",
        &format!("/v1/sessions/{id}/reset"),
        &[("Authorization", &a)],
        b"",
    )
    .await
    .unwrap();
    check_documented(&doc, "POST", "/v1/sessions/{id}/reset", &r);
    assert_eq!(r.json()["warm"], false);

    // Operations endpoints.
    for p in ["/healthz", "/readyz", "/metrics"] {
        let r = http(addr, "GET", p, &[], b"").await.unwrap();
        check_documented(&doc, "GET", p, &r);
        assert_eq!(r.status, 200, "{p}");
    }
    let m = String::from_utf8(http(addr, "GET", "/metrics", &[], b"").await.unwrap().body).unwrap();
    assert!(
        m.contains("livereg_frames_total{outcome=\"registered\"} 3"),
        "{m}"
    );
    assert!(m.contains("livereg_sessions 2"), "{m}");
    assert!(
        m.contains("livereg_errors_total{code=\"not_found\"} 4"),
        "{m}"
    );
    assert!(m.contains("livereg_registration_seconds_count 3"), "{m}");

    // Unknown routes and methods answer the JSON error shape.
    let r = http(addr, "GET", "/v1/nothing", &[("Authorization", &a)], b"")
        .await
        .unwrap();
    assert_error(&r, 404, "not_found");
    let r = http(addr, "PUT", "/v1/sessions", &[("Authorization", &a)], b"")
        .await
        .unwrap();
    assert_error(&r, 405, "method_not_allowed");
    // A plain GET on the stream endpoint is not a WebSocket upgrade.
    let r = http(
        addr,
        "GET",
        &format!("/v1/sessions/{id}/stream"),
        &[("Authorization", &a)],
        b"",
    )
    .await
    .unwrap();
    check_documented(&doc, "GET", "/v1/sessions/{id}/stream", &r);
    assert_error(&r, 426, "websocket_required");

    // Close: 200 with final counters, then gone.
    let r = http(
        addr,
        "DELETE",
        &format!("/v1/sessions/{id}"),
        &[("Authorization", &a)],
        b"",
    )
    .await
    .unwrap();
    check_documented(&doc, "DELETE", "/v1/sessions/{id}", &r);
    assert_eq!(r.status, 200);
    let r = http(
        addr,
        "GET",
        &format!("/v1/sessions/{id}"),
        &[("Authorization", &a)],
        b"",
    )
    .await
    .unwrap();
    check_documented(&doc, "GET", "/v1/sessions/{id}", &r);
    assert_error(&r, 404, "not_found");
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_inputs_get_clear_errors_while_a_healthy_session_streams_on() {
    let n_healthy = 12;
    let case = small_case("bad", n_healthy);
    let reference_lines = {
        let c = case.clone();
        tokio::task::spawn_blocking(move || reference(&c))
    };
    let mut cfg = test_config("bad");
    cfg.limits.max_body_bytes = 256 * 1024;
    cfg.limits.max_frame_points = 5000;
    cfg.limits.max_sessions_per_token = 3;
    let server = start(cfg).await;
    let addr = server.http_addr;
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let healthy = http_create_session(addr, TOKEN_A, &scene).await.unwrap();
    let victim = http_create_session(addr, TOKEN_A, &scene).await.unwrap();
    // The healthy session streams all its frames while the bad inputs below are sent.
    let frames = read_frames(&case.join("frames")).unwrap();
    let h = healthy.clone();
    let healthy_task =
        tokio::spawn(async move { ws_lockstep(addr, &h, TOKEN_A, &frames, false).await });

    let a = auth(TOKEN_A);
    let vpath = format!("/v1/sessions/{victim}/frames");
    let json_h = [
        ("Authorization", a.as_str()),
        ("Content-Type", "application/json"),
    ];
    // Missing and wrong tokens, wrong scheme.
    let r = http(addr, "GET", "/v1/sessions", &[], b"").await.unwrap();
    assert_error(&r, 401, "unauthorized");
    assert!(r.headers.contains_key("www-authenticate"));
    let r = http(
        addr,
        "GET",
        "/v1/sessions",
        &[("Authorization", "Bearer nope-nope-nope-nope")],
        b"",
    )
    .await
    .unwrap();
    assert_error(&r, 401, "unauthorized");
    let r = http(
        addr,
        "GET",
        "/v1/sessions",
        &[("Authorization", "Basic dXNlcjpwYXNz")],
        b"",
    )
    .await
    .unwrap();
    assert_error(&r, 401, "unauthorized");
    let r = http(
        addr,
        "POST",
        &vpath,
        &[("Content-Type", "application/json")],
        b"{}",
    )
    .await
    .unwrap();
    assert_error(&r, 401, "unauthorized");
    // Malformed JSON, wrong types, unknown fields.
    for (body, needle) in [
        (&b"{\"points\": [[1, 2, 3]"[..], "EOF"),
        (b"{\"points\": [[1, 2]]}", "length 3"),
        (b"{\"points\": \"many\"}", "invalid type"),
        (b"{\"pts\": []}", "pts"),
        (b"{\"points\": [[NaN, 0, 0]]}", "expected value"),
    ] {
        let r = http(addr, "POST", &vpath, &json_h, body).await.unwrap();
        assert_error(&r, 400, "bad_request");
        let msg = r.json()["error"]["message"].as_str().unwrap().to_string();
        assert!(msg.contains(needle), "{msg} lacks {needle}");
    }
    // Non-finite coordinates (JSON cannot carry them: 1e999 overflows; binary can).
    let r = http(
        addr,
        "POST",
        &vpath,
        &json_h,
        b"{\"points\": [[1e999, 0, 0]]}",
    )
    .await
    .unwrap();
    assert!(r.status == 400 || r.status == 422, "{}", r.status);
    let bin_h = [
        ("Authorization", a.as_str()),
        ("Content-Type", "application/octet-stream"),
    ];
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let bin = livereg::server::codec::encode_binary_frame(
            3,
            &[[0.0, 0.0, 0.0], [1.0, bad, 0.0]],
            None,
        );
        let r = http(addr, "POST", &vpath, &bin_h, &bin).await.unwrap();
        assert_error(&r, 422, "invalid_frame");
        assert!(r.json()["error"]["message"]
            .as_str()
            .unwrap()
            .contains("point 1"));
    }
    // Truncated and garbage binary frames.
    let bin = livereg::server::codec::encode_binary_frame(3, &[[0.0, 0.0, 0.0]], None);
    let r = http(addr, "POST", &vpath, &bin_h, &bin[..bin.len() - 2])
        .await
        .unwrap();
    assert_error(&r, 400, "bad_request");
    let r = http(addr, "POST", &vpath, &bin_h, b"GARBAGE-GARBAGE-GARBAGE")
        .await
        .unwrap();
    assert_error(&r, 400, "bad_request");
    // Empty clouds.
    let r = http(addr, "POST", &vpath, &json_h, b"{\"points\": []}")
        .await
        .unwrap();
    assert_error(&r, 422, "invalid_frame");
    let r = http(
        addr,
        "POST",
        &vpath,
        &bin_h,
        &livereg::server::codec::encode_binary_frame(1, &[], None),
    )
    .await
    .unwrap();
    assert_error(&r, 422, "invalid_frame");
    // Too many points, oversized bodies.
    let many: Vec<[f32; 3]> = vec![[1.0, 2.0, 3.0]; 6000];
    let r = http(
        addr,
        "POST",
        &vpath,
        &bin_h,
        &livereg::server::codec::encode_binary_frame(1, &many, None),
    )
    .await
    .unwrap();
    assert_error(&r, 413, "too_many_points");
    let big = vec![b' '; 300 * 1024];
    let r = http(addr, "POST", &vpath, &json_h, &big).await.unwrap();
    assert_error(&r, 413, "payload_too_large");
    let r = http(addr, "POST", "/v1/sessions", &json_h, &big)
        .await
        .unwrap();
    assert_error(&r, 413, "payload_too_large");
    // Unknown sessions (well-formed and not), another token's session.
    for id in ["0123456789abcdef0123456789abcdef", "nope", "..%2F..%2Fetc"] {
        let r = http(
            addr,
            "POST",
            &format!("/v1/sessions/{id}/frames"),
            &json_h,
            b"{\"points\": [[0,0,0]]}",
        )
        .await
        .unwrap();
        assert_error(&r, 404, "not_found");
    }
    let b = auth(TOKEN_B);
    let r = http(
        addr,
        "POST",
        &vpath,
        &[("Authorization", &b), ("Content-Type", "application/json")],
        b"{\"points\": [[0,0,0]]}",
    )
    .await
    .unwrap();
    assert_error(&r, 404, "not_found");
    // Bad scenes: malformed, escaping the upload, missing files, unknown keys, huge grids.
    let body_obj = String::from_utf8(scene.files["body.obj"].clone()).unwrap();
    let targets_xyz = String::from_utf8(scene.files["targets.xyz"].clone()).unwrap();
    // The body shrunk 10⁴ times: a closed surface with no grid cell inside.
    let tiny_obj: String = body_obj
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(xyz) => {
                let c: Vec<f64> = xyz.split_whitespace().map(|t| t.parse().unwrap()).collect();
                format!("v {} {} {}\n", c[0] * 1e-4, c[1] * 1e-4, c[2] * 1e-4)
            }
            None => format!("{l}\n"),
        })
        .collect();
    for (body, status, code, needle) in [
        (json!({"scene": 3}), 400, "bad_request", "scene"),
        (
            json!({"scene": "units = \"mm\"\n[model]\nsurface = \"/etc/passwd\"\n[grid]\ncell_size = 1.0\n[material]\nyoung_modulus = 1.0\npoisson_ratio = 0.3\n"}),
            422,
            "invalid_scene",
            "model.surface",
        ),
        (
            json!({"scene": "[model]\nsurface = \"x.obj\"\n[grid]\ncell_size = 1.0\n[material]\nyoung_modulus = 1.0\npoisson_ratio = 0.3\n"}),
            422,
            "invalid_scene",
            "not uploaded",
        ),
        (json!({"scene": "[modle]\n"}), 422, "invalid_scene", "modle"),
        (
            json!({"scene": scene.scene.replace("cell_size = 25.0", "cell_size = 0.01"),
                "files": {"body.obj": String::from_utf8(scene.files["body.obj"].clone()).unwrap(),
                          "targets.xyz": String::from_utf8(scene.files["targets.xyz"].clone()).unwrap()}}),
            413,
            "grid_too_large",
            "cell_size",
        ),
        (
            json!({"scene": scene.scene.clone(),
                "files": {"body.obj": "v 0 0 0\nf 1 2 3\n", "targets.xyz": "0 0 0\n"}}),
            422,
            "invalid_scene",
            "model.surface",
        ),
        (
            json!({"scene": scene.scene.clone(), "files": {"../body.obj": "x"}}),
            422,
            "invalid_scene",
            "not allowed",
        ),
        // Every way a model build can fail names the upload's file, never a server path.
        (
            json!({"scene": scene.scene.clone(),
                "files": {"body.obj": body_obj.clone(), "targets.xyz": "nan 0 0\n"}}),
            422,
            "invalid_scene",
            "targets.xyz:1",
        ),
        (
            json!({"scene": scene.scene.clone(),
                "files": {"body.obj": body_obj.clone(), "targets.xyz": ""}}),
            422,
            "invalid_scene",
            "targets.xyz",
        ),
        (
            json!({"scene": scene.scene.replace("cell_size = 25.0", "cell_size = 1e300"),
                "files": {"body.obj": body_obj.clone(), "targets.xyz": targets_xyz.clone()}}),
            422,
            "invalid_scene",
            "cell",
        ),
        (
            json!({"scene": scene.scene.clone(),
                "files": {"body.obj": tiny_obj, "targets.xyz": targets_xyz.clone()}}),
            422,
            "invalid_scene",
            "cell",
        ),
    ] {
        let r = post_json(addr, "/v1/sessions", TOKEN_A, &body).await;
        assert_error(&r, status, code);
        let msg = r.json()["error"]["message"].as_str().unwrap().to_string();
        assert!(msg.contains(needle), "{msg} lacks {needle}");
        assert!(!msg.contains("/tmp/"), "server paths leak: {msg}");
        assert!(!msg.contains("sessions/"), "server paths leak: {msg}");
    }
    let r = http(
        addr,
        "POST",
        "/v1/sessions",
        &[("Authorization", &a), ("Content-Type", "text/plain")],
        b"x",
    )
    .await
    .unwrap();
    assert_error(&r, 415, "unsupported_media_type");
    let r = http(
        addr,
        "POST",
        "/v1/sessions",
        &[
            ("Authorization", &a),
            ("Content-Type", "multipart/form-data; boundary=zz"),
        ],
        b"--zz\r\nbroken",
    )
    .await
    .unwrap();
    assert_error(&r, 400, "bad_request");
    // Sessions per token: the third fits, the fourth is refused.
    let third = http_create_session(addr, TOKEN_A, &scene).await.unwrap();
    let r = post_json(
        addr,
        "/v1/sessions",
        TOKEN_A,
        &json!({"scene": scene.scene.clone(),
        "files": {"body.obj": String::from_utf8(scene.files["body.obj"].clone()).unwrap(),
                  "targets.xyz": String::from_utf8(scene.files["targets.xyz"].clone()).unwrap()}}),
    )
    .await;
    assert_error(&r, 429, "too_many_sessions");
    http_close_session(addr, TOKEN_A, &third).await.unwrap();

    // The healthy session saw none of it: every frame registered and equal to `register`.
    let (results, _) = healthy_task.await.unwrap().unwrap();
    let want = reference_lines.await.unwrap();
    assert_eq!(results.len(), n_healthy);
    for (got, want) in results.iter().zip(&want) {
        assert!(
            got["diagnostics"].get("error").is_none(),
            "{}",
            got["diagnostics"]
        );
        assert_matches_reference(got, want);
    }
    // The victim session is intact too: its counters show only rejections.
    let r = http(
        addr,
        "GET",
        &format!("/v1/sessions/{victim}"),
        &[("Authorization", &a)],
        b"",
    )
    .await
    .unwrap();
    let v = r.json();
    assert_eq!(v["frames_registered"], 0);
    assert!(v["frames_rejected"].as_u64().unwrap() >= 8, "{v}");
    let r = post_json(
        addr,
        &vpath,
        TOKEN_A,
        &json!({"points": read_frames(&case.join("frames")).unwrap()[0].1}),
    )
    .await;
    assert_eq!(r.status, 200);
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frame_rate_limit_and_loopback_dev_mode() {
    let case = small_case("rate", 1);
    let mut cfg = test_config("rate");
    cfg.limits.max_frames_per_second = 0.2;
    cfg.tokens.clear();
    cfg.insecure_loopback_dev = true;
    cfg.grpc_bind = None;
    let server = start(cfg).await;
    assert!(server.grpc_addr.is_none());
    let addr = server.http_addr;
    // Development mode: no token needed.
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let (boundary, body) = scene.multipart();
    let ct = format!("multipart/form-data; boundary={boundary}");
    let r = http(
        addr,
        "POST",
        "/v1/sessions",
        &[("Content-Type", &ct)],
        &body,
    )
    .await
    .unwrap();
    assert_eq!(r.status, 201);
    let id = r.json()["id"].as_str().unwrap().to_string();
    let path = format!("/v1/sessions/{id}/frames");
    let pts = frame_points(&case, 0);
    let body = json!({"points": pts}).to_string();
    let mut statuses = Vec::new();
    for _ in 0..3 {
        let r = http(
            addr,
            "POST",
            &path,
            &[("Content-Type", "application/json")],
            body.as_bytes(),
        )
        .await
        .unwrap();
        if r.status == 429 {
            assert_error(&r, 429, "rate_limited");
        }
        statuses.push(r.status);
    }
    // A bucket of one frame refilled every 5 s: the first passes, the next two do not.
    assert_eq!(statuses, [200, 429, 429]);
    server.shutdown().await.unwrap();
}

/// A session's memory estimate (`Session::memory_estimate_bytes`, itself checked against a
/// counting allocator in `tests/session_memory.rs`) is what the server's budget admits by:
/// with room for two phantom sessions the third is refused with 429 `memory_budget` (another
/// replica may take it), a closed session gives its share back, a budget smaller than one
/// session refuses with 413 `model_too_large`, and the metrics report both numbers. A refused
/// session leaves no recording and no upload behind.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_memory_budget_admits_sessions_by_their_estimates() {
    let dir = temp_dir("membudget-case");
    phantom_case(&dir, 1);
    let loaded = livereg::scene::load_scene(&dir.join("scene.toml")).unwrap();
    let estimate = livereg::session::Session::from_scene(&loaded)
        .unwrap()
        .memory_estimate_bytes()
        .unwrap();
    let mib = (1u64 << 20) as f64;
    assert!(
        estimate > 1 << 20,
        "a phantom session needs megabytes: {estimate} B"
    );
    // Room for 2.5 sessions, in whole MiB.
    let budget_mb = (2.5 * estimate as f64 / mib).floor() as u64;
    assert!((2 * estimate..3 * estimate).contains(&(budget_mb << 20)));
    let mut cfg = test_config("membudget");
    cfg.limits.max_memory_mb = budget_mb;
    let data_dir = cfg.data_dir.clone();
    let server = start(cfg).await;
    let addr = server.http_addr;
    let scene = SceneFiles::read(&dir.join("scene.toml")).unwrap();
    let first = http_create_session_info(addr, TOKEN_A, &scene)
        .await
        .unwrap();
    let mb = first["memory_estimate_mb"].as_f64().unwrap();
    assert!((mb - estimate as f64 / mib).abs() < 1e-9, "{first}");
    let second = http_create_session(addr, TOKEN_B, &scene).await.unwrap();

    let (boundary, body) = scene.multipart();
    let ct = format!("multipart/form-data; boundary={boundary}");
    let create = |addr: SocketAddr, token: &'static str| {
        let (ct, body) = (ct.clone(), body.clone());
        async move {
            let a = auth(token);
            http(
                addr,
                "POST",
                "/v1/sessions",
                &[("Content-Type", &ct), ("Authorization", &a)],
                &body,
            )
            .await
            .unwrap()
        }
    };
    let sessions_on_disk = || {
        std::fs::read_dir(data_dir.join("sessions"))
            .unwrap()
            .count()
    };
    let recordings = || {
        std::fs::read_dir(data_dir.join("recordings"))
            .unwrap()
            .count()
    };
    let (disk, recorded) = (sessions_on_disk(), recordings());
    let r = create(addr, TOKEN_A).await;
    assert_error(&r, 429, "memory_budget");
    let msg = r.json()["error"]["message"].as_str().unwrap().to_string();
    assert!(msg.contains(&format!("{budget_mb} MiB")), "{msg}");
    assert_eq!((sessions_on_disk(), recordings()), (disk, recorded));

    let metrics = http(addr, "GET", "/metrics", &[], b"").await.unwrap();
    let text = String::from_utf8_lossy(&metrics.body).to_string();
    let gauge = |name: &str| -> u64 {
        text.lines()
            .find_map(|l| l.strip_prefix(&format!("{name} ")))
            .unwrap_or_else(|| panic!("{name} missing from /metrics"))
            .parse()
            .unwrap()
    };
    assert_eq!(gauge("livereg_memory_budget_bytes"), budget_mb << 20);
    assert_eq!(gauge("livereg_memory_estimated_bytes"), 2 * estimate);

    // Closing a session gives its share back.
    http_close_session(addr, TOKEN_B, &second).await.unwrap();
    let r = create(addr, TOKEN_B).await;
    assert_eq!(r.status, 201, "{}", String::from_utf8_lossy(&r.body));
    server.shutdown().await.unwrap();

    // A budget smaller than one session: no server like this one can hold it.
    let mut cfg = test_config("membudget-small");
    cfg.limits.max_memory_mb = (estimate >> 20) / 2;
    let server = start(cfg).await;
    let r = create(server.http_addr, TOKEN_A).await;
    assert_error(&r, 413, "model_too_large");
    server.shutdown().await.unwrap();
}
