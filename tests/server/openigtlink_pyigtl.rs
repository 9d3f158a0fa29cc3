//! Cross-checks `livereg::openigtlink` against pyigtl 0.3.4, a Python OpenIGTLink implementation,
//! in both directions and over a real TCP connection. The Python side is
//! `tests/python/igtl_pyigtl.py`.
//!
//! Needs `python3` with pyigtl 0.3.4 (`python3 -m pip install pyigtl==0.3.4`, which brings numpy
//! and crcmod). Without them every test here FAILS with that instruction; none is skipped.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use nalgebra::{Isometry3, Matrix4, Point3, Vector3};
use serde_json::{json, Value};

use livereg::mesh::TriSurface;
use livereg::openigtlink::{
    conventions, crc64, decode_message, read_message, status_code, write_message, Content,
    HeaderVersion, IgtlError, Message, PointElement, PointMessage, PolyDataMessage, StatusMessage,
    Timestamp, TransformMessage,
};

const MAX_BODY: u64 = 1 << 20;
const INSTALL: &str = "python3 -m pip install pyigtl==0.3.4";

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/igtl_pyigtl.py")
}

/// Runs the Python script; panics (test failure) when python3 cannot be started.
fn run_python(args: &[&str]) -> Output {
    Command::new("python3")
        .arg(script())
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap_or_else(|e| {
            panic!("cannot run python3 ({e}); the pyigtl tests need python3 with pyigtl: {INSTALL}")
        })
}

/// Runs the script and requires success, reporting its output otherwise.
fn python_ok(args: &[&str]) -> String {
    let output = run_python(args);
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    assert!(
        output.status.success(),
        "python3 {} {:?} failed ({}); is pyigtl 0.3.4 installed? ({INSTALL})\nstdout:\n{stdout}\nstderr:\n{}",
        script().display(),
        args,
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    stdout
}

/// A scratch directory removed on drop.
struct Scratch(PathBuf);

impl Scratch {
    fn new(tag: &str) -> Self {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let dir = std::env::temp_dir().join(format!(
            "livereg-igtl-{tag}-{}-{}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn path(&self, name: &str) -> String {
        self.0.join(name).to_string_lossy().into_owned()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn f64s(value: &Value) -> Vec<f64> {
    value
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect()
}

fn cells(value: &Value) -> Vec<Vec<u32>> {
    value
        .as_array()
        .unwrap()
        .iter()
        .map(|cell| {
            cell.as_array()
                .unwrap()
                .iter()
                .map(|i| i.as_u64().unwrap() as u32)
                .collect()
        })
        .collect()
}

fn metadata_json(message: &Message) -> Value {
    Value::Object(
        message
            .metadata
            .iter()
            .map(|(k, v)| (k.to_owned(), Value::String(v.to_owned())))
            .collect(),
    )
}

/// Compares a message decoded by livereg with what pyigtl says it encoded.
fn check_against_expected(name: &str, version: HeaderVersion, message: &Message, expected: &Value) {
    assert_eq!(
        message.content.type_name(),
        expected["type"],
        "{name}: type"
    );
    assert_eq!(
        message.device_name, expected["device_name"],
        "{name}: device name"
    );
    assert_eq!(
        u64::from(version.as_u16()),
        expected["header_version"],
        "{name}: header version"
    );
    assert_eq!(
        u64::from(message.message_id),
        expected["message_id"],
        "{name}: message id"
    );
    assert_eq!(
        metadata_json(message),
        expected["metadata"],
        "{name}: metadata"
    );
    let timestamp = expected["timestamp"].as_f64().unwrap();
    assert!(
        (message.timestamp.as_secs_f64() - timestamp).abs() < 1e-6,
        "{name}: timestamp {} against {timestamp}",
        message.timestamp.as_secs_f64()
    );
    let content = &expected["content"];
    match &message.content {
        Content::Transform(t) => {
            for (row, values) in content["matrix"].as_array().unwrap().iter().enumerate() {
                for (column, value) in f64s(values).into_iter().enumerate() {
                    assert_eq!(
                        t.matrix[(row, column)],
                        value,
                        "{name}: matrix ({row}, {column})"
                    );
                }
            }
        }
        Content::Point(p) => {
            let points = content["points"].as_array().unwrap();
            assert_eq!(p.points.len(), points.len(), "{name}: point count");
            for (got, want) in p.points.iter().zip(points) {
                assert_eq!(got.name, want["name"], "{name}: point name");
                assert_eq!(got.group, want["group"], "{name}: point group");
                assert_eq!(got.owner, want["owner"], "{name}: point owner");
                let rgba: Vec<u8> = want["rgba"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|c| c.as_u64().unwrap() as u8)
                    .collect();
                assert_eq!(got.rgba.to_vec(), rgba, "{name}: rgba");
                assert_eq!(
                    got.position.coords.as_slice(),
                    f64s(&want["position"]).as_slice(),
                    "{name}: position"
                );
                assert_eq!(
                    got.diameter,
                    want["diameter"].as_f64().unwrap(),
                    "{name}: diameter"
                );
            }
        }
        Content::PolyData(p) => {
            let points: Vec<Vec<f64>> = content["points"]
                .as_array()
                .unwrap()
                .iter()
                .map(f64s)
                .collect();
            let got: Vec<Vec<f64>> = p
                .points
                .iter()
                .map(|q| q.coords.as_slice().to_vec())
                .collect();
            assert_eq!(got, points, "{name}: points");
            assert_eq!(p.vertices, cells(&content["vertices"]), "{name}: vertices");
            assert_eq!(p.lines, cells(&content["lines"]), "{name}: lines");
            assert_eq!(p.polygons, cells(&content["polygons"]), "{name}: polygons");
            assert_eq!(
                p.triangle_strips,
                cells(&content["triangle_strips"]),
                "{name}: strips"
            );
            assert!(p.attributes.is_empty(), "{name}: attributes");
        }
        Content::Status(s) => {
            assert_eq!(u64::from(s.code), content["code"], "{name}: code");
            assert_eq!(
                s.subcode,
                content["subcode"].as_i64().unwrap(),
                "{name}: subcode"
            );
            assert_eq!(s.error_name, content["error_name"], "{name}: error name");
            assert_eq!(s.message, content["message"], "{name}: message");
        }
    }
}

#[test]
fn crc64_matches_pyigtl() {
    let pyigtl_crc = python_ok(&["check"]);
    assert_eq!(pyigtl_crc.trim(), format!("{:016x}", crc64(b"123456789")));
    assert_eq!(pyigtl_crc.trim(), "6c40df5f0b497347");
}

#[test]
fn livereg_decodes_what_pyigtl_encodes() {
    let scratch = Scratch::new("from-pyigtl");
    python_ok(&["encode", &scratch.path("")]);
    let expected: Value =
        serde_json::from_str(&std::fs::read_to_string(scratch.path("expected.json")).unwrap())
            .unwrap();
    let expected = expected.as_object().unwrap();
    let names = [
        "transform_v1",
        "transform_v2",
        "point_v1",
        "point_v2",
        "polydata_surface",
        "polydata_cloud",
        "status_v1",
        "status_v2",
    ];
    for name in names {
        let bytes = std::fs::read(scratch.path(&format!("{name}.bin"))).unwrap();
        let (received, used) = decode_message(&bytes, MAX_BODY)
            .unwrap_or_else(|e| panic!("{name}: livereg cannot decode pyigtl's message: {e}"));
        assert_eq!(used, bytes.len(), "{name}: bytes used");
        check_against_expected(name, received.version, &received.message, &expected[name]);
    }
    // Every file written was checked (no silent omission).
    assert_eq!(expected.len(), names.len() + 1);

    // The surface converts to a TriSurface: 4 triangles and the quad fanned into 2.
    let bytes = std::fs::read(scratch.path("polydata_surface.bin")).unwrap();
    let Content::PolyData(polydata) = decode_message(&bytes, MAX_BODY).unwrap().0.message.content
    else {
        panic!("polydata_surface is not POLYDATA");
    };
    let surface = polydata.to_tri_surface().unwrap();
    assert_eq!(
        surface.triangles,
        vec![
            [0, 2, 1],
            [0, 1, 3],
            [0, 3, 2],
            [1, 2, 3],
            [0, 1, 3],
            [0, 3, 4]
        ]
    );
    let bytes = std::fs::read(scratch.path("polydata_cloud.bin")).unwrap();
    let Content::PolyData(cloud) = decode_message(&bytes, MAX_BODY).unwrap().0.message.content
    else {
        panic!("polydata_cloud is not POLYDATA");
    };
    assert_eq!(cloud.to_point_cloud()[1], Point3::new(-4.0, 5.5, 600.0));

    // pyigtl 0.3.4 writes VERTICES little-endian (numpy's native order), against the spec:
    // livereg refuses it with a specific error instead of reading garbage indices.
    let bytes = std::fs::read(scratch.path("polydata_vertices_pyigtl_byte_order.bin")).unwrap();
    match decode_message(&bytes, MAX_BODY) {
        Err(IgtlError::InvalidField { field, value, .. }) => {
            assert_eq!(field, "POLYDATA cell size");
            assert_eq!(
                value, 0x0100_0000,
                "a count of 1 read big-endian from little-endian bytes"
            );
        }
        other => panic!("pyigtl's little-endian vertices: {other:?}"),
    }
}

/// A message with a fixed timestamp.
fn stamped(device: &str, content: impl Into<Content>, seconds: u32) -> Message {
    let mut message = Message::new(device, content);
    message.timestamp = Timestamp {
        seconds,
        fraction: 1 << 30, // .25 s
    };
    message
}

fn expected_json(message: &Message, version: HeaderVersion, content: Value) -> Value {
    json!({
        "type": message.content.type_name(),
        "device_name": message.device_name,
        "timestamp": message.timestamp.as_secs_f64(),
        "header_version": version.as_u16(),
        "message_id": if version == HeaderVersion::V2 { message.message_id } else { 0 },
        "metadata": metadata_json(message),
        "content": content,
    })
}

fn matrix_json(matrix: &Matrix4<f64>) -> Value {
    json!((0..4)
        .map(|r| (0..4).map(|c| matrix[(r, c)]).collect::<Vec<_>>())
        .collect::<Vec<_>>())
}

fn cells_json(cells: &[Vec<u32>]) -> Value {
    json!(cells)
}

fn polydata_json(p: &PolyDataMessage) -> Value {
    json!({
        "points": p.points.iter().map(|q| vec![q.x, q.y, q.z]).collect::<Vec<_>>(),
        "vertices": cells_json(&p.vertices),
        "lines": cells_json(&p.lines),
        "polygons": cells_json(&p.polygons),
        "triangle_strips": cells_json(&p.triangle_strips),
    })
}

#[test]
fn pyigtl_decodes_what_livereg_encodes() {
    let scratch = Scratch::new("to-pyigtl");
    // Values exact in float32, so that both sides compare exactly.
    let pose = Isometry3::new(
        Vector3::new(12.5, -40.0, 310.25),
        Vector3::new(0.3, -0.2, 1.1),
    )
    .to_homogeneous()
    .map(|v| f64::from(v as f32));
    let transform = TransformMessage::from_matrix(pose);
    let mut point_a = PointElement::new("Tumour centre", Point3::new(1.5, -2.25, 300.0));
    point_a.group = "Target".to_owned();
    point_a.rgba = [200, 10, 20, 255];
    point_a.diameter = 12.5;
    point_a.owner = "CT".to_owned();
    let points = PointMessage {
        points: vec![
            point_a,
            PointElement::new("Portal vein", Point3::new(-8.0, 0.5, 280.0)),
        ],
    };
    let surface = TriSurface::new(
        vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(10.0, 0.0, 0.0),
            Point3::new(0.0, 10.0, 0.0),
            Point3::new(0.0, 0.0, 10.5),
        ],
        vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    );
    let mut mesh = PolyDataMessage::from_tri_surface(&surface).unwrap();
    mesh.lines = vec![vec![0, 1, 2, 3]];
    mesh.triangle_strips = vec![vec![0, 1, 2, 3]];
    let cloud = PolyDataMessage::from_point_cloud(
        &[Point3::new(1.25, 2.5, 3.75), Point3::new(-4.0, 5.5, 600.0)],
        true,
    )
    .unwrap();
    let status = StatusMessage {
        code: status_code::UNKNOWN_INSTRUCTION,
        subcode: -7,
        error_name: "Unsupported".to_owned(),
        message: "IMAGE is not supported".to_owned(),
    };

    let mut cases: Vec<(&str, Message, HeaderVersion, Value)> = Vec::new();
    let m = stamped(
        conventions::LIVER_TO_REFERENCE_DEVICE,
        transform,
        1_700_000_000,
    );
    cases.push((
        "transform_v1",
        m.clone(),
        HeaderVersion::V1,
        json!({ "matrix": matrix_json(&pose) }),
    ));
    let mut m = m;
    m.message_id = 4242;
    m.metadata
        .insert(conventions::METADATA_UNITS, conventions::UNITS_MM);
    m.metadata.insert(conventions::METADATA_FRAME, "17");
    m.metadata.insert("comment", "Leber über Zwerchfell"); // UTF-8 value (encoding 106)
    cases.push((
        "transform_v2",
        m,
        HeaderVersion::V2,
        json!({ "matrix": matrix_json(&pose) }),
    ));
    let point_content = json!({ "points": points.points.iter().map(|p| json!({
        "name": p.name, "group": p.group, "rgba": p.rgba, "owner": p.owner,
        "position": [p.position.x, p.position.y, p.position.z], "diameter": p.diameter,
    })).collect::<Vec<_>>() });
    let mut m = stamped(conventions::TARGETS_DEVICE, points, 1_700_000_100);
    m.metadata
        .insert(conventions::METADATA_UNITS, conventions::UNITS_MM);
    cases.push(("point_v2", m, HeaderVersion::V2, point_content));
    let mesh_content = polydata_json(&mesh);
    let mut m = stamped(conventions::DEFORMED_LIVER_DEVICE, mesh, 1_700_000_200);
    m.metadata.insert(conventions::METADATA_SESSION, "s-0123");
    cases.push(("polydata_v2", m, HeaderVersion::V2, mesh_content));
    let cloud_content = polydata_json(&cloud);
    cases.push((
        "polydata_v1",
        stamped(conventions::INTRAOP_CLOUD_DEVICE, cloud, 1_700_000_300),
        HeaderVersion::V1,
        cloud_content,
    ));
    let status_content = json!({
        "code": status.code, "subcode": status.subcode,
        "error_name": status.error_name, "message": status.message,
    });
    let m = stamped("IntraopCloud", status, 1_700_000_400);
    cases.push((
        "status_v1",
        m.clone(),
        HeaderVersion::V1,
        status_content.clone(),
    ));
    let mut m = m;
    m.message_id = 1;
    cases.push(("status_v2", m, HeaderVersion::V2, status_content));

    for (name, message, version, content) in cases {
        let file = scratch.path(&format!("{name}.bin"));
        let expected = scratch.path(&format!("{name}.json"));
        std::fs::write(&file, message.encode(version).unwrap()).unwrap();
        std::fs::write(
            &expected,
            expected_json(&message, version, content).to_string(),
        )
        .unwrap();
        let out = python_ok(&["decode", &file, &expected]);
        assert_eq!(out.trim(), "ok", "{name}");
    }

    // The comparison can fail: a wrong expectation makes the script exit with an error.
    let message = stamped("Check", StatusMessage::ok("fine"), 1_700_000_500);
    let file = scratch.path("negative.bin");
    let expected = scratch.path("negative.json");
    std::fs::write(&file, message.encode(HeaderVersion::V2).unwrap()).unwrap();
    let wrong = json!({ "code": 1, "subcode": 0, "error_name": "OK", "message": "not fine" });
    std::fs::write(
        &expected,
        expected_json(&message, HeaderVersion::V2, wrong).to_string(),
    )
    .unwrap();
    let output = run_python(&["decode", &file, &expected]);
    assert!(!output.status.success(), "a wrong expectation must fail");
    assert!(String::from_utf8_lossy(&output.stderr).contains("not fine"));
}

/// A real TCP exchange: livereg listens, pyigtl's OpenIGTLinkClient connects and sends a POINT
/// message (header version 2, metadata); livereg decodes it and answers with a STATUS (which
/// pyigtl skips: it has no STATUS class) and a TRANSFORM that pyigtl receives.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn socket_exchange_with_pyigtl_client() {
    python_ok(&["check"]); // fails at once, with the install line, when pyigtl is missing
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port().to_string();
    let mut python = tokio::task::spawn_blocking(move || run_python(&["client", &port]));

    let (mut stream, _) = tokio::select! {
        accepted = tokio::time::timeout(Duration::from_secs(30), listener.accept()) => accepted
            .unwrap_or_else(|_| panic!("pyigtl client did not connect within 30 s ({INSTALL})"))
            .unwrap(),
        finished = &mut python => {
            let output = finished.unwrap();
            panic!(
                "pyigtl client exited before connecting ({}):\n{}",
                output.status,
                String::from_utf8_lossy(&output.stderr)
            );
        }
    };
    let received =
        tokio::time::timeout(Duration::from_secs(30), read_message(&mut stream, MAX_BODY))
            .await
            .expect("no message from pyigtl within 30 s")
            .expect("livereg cannot decode pyigtl's POINT message")
            .expect("pyigtl closed the connection without sending");
    assert_eq!(received.version, HeaderVersion::V2);
    let message = received.message;
    assert_eq!(message.device_name, "IntraopCloud");
    assert_eq!(message.metadata.get("livereg.frame"), Some("3"));
    assert_eq!(message.metadata.get("units"), Some("mm"));
    assert!((message.timestamp.as_secs_f64() - 1_700_000_500.0).abs() < 1e-6);
    let Content::Point(points) = &message.content else {
        panic!("expected POINT, got {}", message.content.type_name());
    };
    assert_eq!(
        points.positions(),
        vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-4.5, 5.25, 600.0)]
    );
    assert_eq!(points.points[1].name, "B");

    let mut status = stamped(
        "IntraopCloud",
        StatusMessage::ok("frame 3 registered"),
        1_700_000_600,
    );
    status.message_id = 3;
    write_message(&mut stream, &status, HeaderVersion::V2)
        .await
        .unwrap();
    let pose = Matrix4::new(
        0.0, -1.0, 0.0, 10.5, //
        1.0, 0.0, 0.0, -20.25, //
        0.0, 0.0, 1.0, 300.125, //
        0.0, 0.0, 0.0, 1.0,
    );
    let mut reply = stamped(
        conventions::LIVER_TO_REFERENCE_DEVICE,
        TransformMessage::from_matrix(pose),
        1_700_000_601,
    );
    reply.message_id = 3;
    reply.metadata.insert(conventions::METADATA_FRAME, "3");
    write_message(&mut stream, &reply, HeaderVersion::V2)
        .await
        .unwrap();

    let output = tokio::time::timeout(Duration::from_secs(60), python)
        .await
        .expect("pyigtl client did not finish within 60 s")
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "pyigtl client failed ({}; {INSTALL})\nstdout:\n{stdout}\nstderr:\n{}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    let got: Value = serde_json::from_str(stdout.trim().lines().last().unwrap_or(""))
        .unwrap_or_else(|e| panic!("pyigtl client printed no JSON ({e}):\n{stdout}"));
    assert_eq!(got["type"], "TRANSFORM");
    assert_eq!(got["device_name"], "LiverToReference");
    assert_eq!(got["header_version"], 2);
    assert_eq!(got["message_id"], 3);
    assert_eq!(got["metadata"], json!({ "livereg.frame": "3" }));
    assert!((got["timestamp"].as_f64().unwrap() - 1_700_000_601.25).abs() < 1e-6);
    assert_eq!(got["matrix"], matrix_json(&pose));
}
