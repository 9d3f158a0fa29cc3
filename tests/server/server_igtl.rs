//! The OpenIGTLink transport end to end, against a real client: pyigtl (PyPI, installed by
//! `scripts/test`) streams 50 frames of a scene to `livereg serve`'s OpenIGTLink port and gets
//! back TRANSFORM, POLYDATA and POINT per frame, whose targets equal `livereg register`'s on
//! the same frames. Then hostile input — a malformed header, a wrong CRC, a content that
//! disagrees with its size, an unknown message type, a 1 GB body claim — each gets a STATUS
//! or a closed connection, and the server keeps serving. The test fails, not skips, without
//! python3 or pyigtl.

use std::path::Path;
use std::time::{Duration, Instant};

use livereg::mesh::{read_obj, read_points};
use livereg::openigtlink::{
    crc64, read_message, status_code, Content, HeaderVersion, Message, Metadata, PointElement,
    PointMessage, ReceivedMessage,
};
use nalgebra::Point3;
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use crate::server_support::*;

const FRAMES: usize = 50;

fn frames_of(case: &Path) -> Vec<Vec<Point3<f64>>> {
    let mut files: Vec<_> = std::fs::read_dir(case.join("frames"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    files.iter().map(|f| read_points(f).unwrap()).collect()
}

/// Reads messages until one from `device` (skipping others), within 60 s.
async fn next_from(s: &mut TcpStream, device: &str) -> ReceivedMessage {
    tokio::time::timeout(Duration::from_secs(60), async {
        loop {
            let m = read_message(s, 1 << 26)
                .await
                .expect("a well-formed message")
                .expect("the connection stays open");
            if m.message.device_name == device {
                return m;
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no message from {device} within 60 s"))
}

/// A STATUS, or the end of the connection (`None`), within 30 s.
async fn status_or_close(s: &mut TcpStream) -> Option<(u16, String)> {
    let m = tokio::time::timeout(Duration::from_secs(30), read_message(s, 1 << 26))
        .await
        .expect("an answer within 30 s");
    match m {
        Ok(Some(ReceivedMessage {
            message:
                Message {
                    content: Content::Status(st),
                    ..
                },
            ..
        })) => Some((st.code, st.error_name)),
        Ok(Some(other)) => panic!(
            "expected a STATUS, got {}",
            other.message.content.type_name()
        ),
        Ok(None) | Err(_) => None,
    }
}

/// Whether the server closed `s` (end of stream) within 10 s.
async fn closed(s: &mut TcpStream) -> bool {
    let mut b = [0u8; 1];
    matches!(
        tokio::time::timeout(Duration::from_secs(10), s.read(&mut b)).await,
        Ok(Ok(0)) | Ok(Err(_))
    )
}

fn cloud_message(points: &[Point3<f64>], frame: usize) -> Message {
    let mut m = Message::new(
        "IntraopCloud",
        PointMessage {
            points: points
                .iter()
                .enumerate()
                .map(|(i, p)| PointElement::new(format!("p{i}"), *p))
                .collect(),
        },
    );
    let mut md = Metadata::new();
    md.insert("livereg.frame", frame.to_string());
    m.metadata = md;
    m
}

/// A raw message: `header` fields as given (no checks), `body` after it.
fn raw(
    version: u16,
    type_name: &str,
    device: &str,
    body: &[u8],
    body_size: u64,
    crc: u64,
) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&version.to_be_bytes());
    let mut t = [0u8; 12];
    t[..type_name.len()].copy_from_slice(type_name.as_bytes());
    out.extend_from_slice(&t);
    let mut d = [0u8; 20];
    d[..device.len()].copy_from_slice(device.as_bytes());
    out.extend_from_slice(&d);
    out.extend_from_slice(&0u64.to_be_bytes());
    out.extend_from_slice(&body_size.to_be_bytes());
    out.extend_from_slice(&crc.to_be_bytes());
    out.extend_from_slice(body);
    out
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pyigtl_streams_frames_and_the_server_survives_hostile_messages() {
    let case = small_case("igtl", FRAMES);
    let reference = reference(&case);
    assert_eq!(reference.len(), FRAMES);
    let mut config = test_config("igtl");
    config.igtl_bind = Some("127.0.0.1:0".parse().unwrap());
    config.igtl_scene = Some(case.join("scene.toml"));
    config.limits.max_body_bytes = 4 << 20;
    // register's frame, for comparison; the RAS default is checked at the end.
    config.igtl_coordinates = livereg::server::config::IgtlCoordinates::Lps;
    let ras_config = livereg::server::ServerConfig {
        igtl_coordinates: livereg::server::config::IgtlCoordinates::Ras,
        data_dir: config.data_dir.join("ras"),
        ..config.clone()
    };
    let server = start(config).await;
    let port = server.igtl_addr.expect("OpenIGTLink listens").port();
    let frames = frames_of(&case);
    let body = read_obj(&case.join("body.obj")).unwrap();

    // pyigtl streams the 50 frames (POINT and POLYDATA alternately, header version 2).
    let frames_json = case.join("igtl_frames.json");
    let json: Vec<Vec<[f64; 3]>> = frames
        .iter()
        .map(|f| f.iter().map(|p| [p.x, p.y, p.z]).collect())
        .collect();
    std::fs::write(&frames_json, serde_json::to_string(&json).unwrap()).unwrap();
    let out = case.join("igtl_out.json");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/igtl_stream.py");
    let (f, o) = (frames_json.clone(), out.clone());
    let run = tokio::task::spawn_blocking(move || {
        std::process::Command::new("python3")
            .arg(&script)
            .arg(port.to_string())
            .arg(&f)
            .arg(&o)
            .output()
            .expect("python3 runs")
    })
    .await
    .unwrap();
    assert!(
        run.status.success(),
        "the pyigtl client failed (python3 -m pip install pyigtl==0.3.4): {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let got: Vec<Value> = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(got.len(), FRAMES);
    let tris: Vec<Vec<u64>> = body
        .triangles
        .iter()
        .map(|t| t.iter().map(|&i| i as u64).collect())
        .collect();
    let mut overhead = Vec::new();
    for (k, (g, want)) in got.iter().zip(&reference).enumerate() {
        assert_eq!(g["units"], "mm");
        assert_eq!(
            g["header_version"], 2,
            "replies use the client's header version"
        );
        assert_eq!(g["liver_points"], body.vertices.len(), "frame {k}");
        assert_eq!(g["liver_polygons"], serde_json::json!(tris), "frame {k}");
        assert_eq!(
            g["target_names"],
            serde_json::json!(["targets-0", "targets-1", "targets-2"])
        );
        let want_targets = want["structures"]["targets"].as_array().unwrap();
        let targets = g["targets"].as_array().unwrap();
        assert_eq!(targets.len(), want_targets.len());
        for (a, b) in targets.iter().zip(want_targets) {
            for c in 0..3 {
                let (x, y) = (a[c].as_f64().unwrap(), b[c].as_f64().unwrap());
                // float32 on the wire: 1e-4 mm at these 50 mm coordinates.
                assert!(
                    (x - y).abs() < 1e-4,
                    "frame {k}: target {a} vs register's {b}"
                );
            }
        }
        // The TRANSFORM: register's rigid pose (rotation, translation in mm).
        let m = &g["transform"];
        for r in 0..3 {
            for c in 0..3 {
                let (x, y) = (
                    m[r][c].as_f64().unwrap(),
                    want["rigid"]["rotation"][r][c].as_f64().unwrap(),
                );
                assert!((x - y).abs() < 1e-5, "frame {k}: rotation");
            }
            let (x, y) = (
                m[r][3].as_f64().unwrap(),
                want["rigid"]["translation"][r].as_f64().unwrap(),
            );
            assert!((x - y).abs() < 1e-4, "frame {k}: translation {x} vs {y}");
        }
        overhead.push(g["round_trip_ms"].as_f64().unwrap() - g["server_ms"].as_f64().unwrap());
    }
    eprintln!(
        "pyigtl round trip minus server time: p50 {:.2} ms (pyigtl polls its queue every 10 ms)",
        percentile(&mut overhead, 0.5)
    );

    // A Rust client on the codec: the transport's own overhead, and the hostile messages.
    let addr = server.igtl_addr.unwrap();
    let mut s = TcpStream::connect(addr).await.unwrap();
    let mut over = Vec::new();
    for (k, f) in frames.iter().enumerate().take(20) {
        let t0 = Instant::now();
        s.write_all(&cloud_message(f, k).encode(HeaderVersion::V2).unwrap())
            .await
            .unwrap();
        let targets = next_from(&mut s, "Targets").await;
        let rt = t0.elapsed().as_secs_f64() * 1e3;
        let server_ms: f64 = targets
            .message
            .metadata
            .get("livereg.server_ms")
            .unwrap()
            .parse()
            .unwrap();
        assert_eq!(
            targets.message.metadata.get("livereg.frame"),
            Some(k.to_string().as_str())
        );
        // The pose's uncertainty: register's `rigid.uncertainty` (the scene is in mm).
        let want_u = reference[k]["rigid"]["uncertainty"].as_f64();
        let got_u: Option<f64> = targets
            .message
            .metadata
            .get("livereg.pose_uncertainty_mm")
            .map(|s| s.parse().unwrap());
        match (got_u, want_u) {
            (Some(a), Some(b)) => assert!((a - b).abs() < 1e-5, "frame {k}: {a} vs {b}"),
            (a, b) => panic!("frame {k}: pose uncertainty {a:?}, register's {b:?}"),
        }
        over.push(rt - server_ms);
    }
    eprintln!(
        "OpenIGTLink round trip minus server time (Rust client, loopback): p50 {:.3} ms, p95 {:.3} ms",
        percentile(&mut over, 0.5),
        percentile(&mut over, 0.95)
    );

    // Wrong CRC: a STATUS (CHECKSUM_ERROR), and the stream goes on.
    let mut bytes = cloud_message(&frames[0], 100)
        .encode(HeaderVersion::V2)
        .unwrap();
    bytes[50] ^= 0xff;
    s.write_all(&bytes).await.unwrap();
    assert_eq!(
        status_or_close(&mut s).await.map(|x| x.0),
        Some(status_code::CHECKSUM_ERROR)
    );
    // An unknown message type with a correct CRC: a STATUS, and the stream goes on.
    let body = b"hello";
    s.write_all(&raw(1, "FOOBAR", "Dev", body, 5, crc64(body)))
        .await
        .unwrap();
    assert_eq!(
        status_or_close(&mut s).await.map(|x| x.0),
        Some(status_code::UNKNOWN_INSTRUCTION)
    );
    // A POINT whose content is not a whole number of 136-byte elements: a STATUS.
    let odd = vec![0u8; 137];
    s.write_all(&raw(1, "POINT", "IntraopCloud", &odd, 137, crc64(&odd)))
        .await
        .unwrap();
    assert!(
        status_or_close(&mut s).await.is_some(),
        "a STATUS for a malformed POINT body"
    );
    // The same connection still registers.
    s.write_all(
        &cloud_message(&frames[1], 101)
            .encode(HeaderVersion::V2)
            .unwrap(),
    )
    .await
    .unwrap();
    let t = next_from(&mut s, "Targets").await;
    assert_eq!(t.message.metadata.get("livereg.frame"), Some("101"));

    // A malformed header (unknown version): a STATUS, then the connection closes.
    let mut bad = TcpStream::connect(addr).await.unwrap();
    bad.write_all(&raw(0x7777, "POINT", "X", &[], 0, 0))
        .await
        .unwrap();
    assert_eq!(
        status_or_close(&mut bad).await.map(|x| x.0),
        Some(status_code::UNKNOWN_VERSION)
    );
    assert!(closed(&mut bad).await);
    // A 1 GB body claim: refused before any allocation, STATUS, closed.
    let mut huge = TcpStream::connect(addr).await.unwrap();
    huge.write_all(&raw(1, "POINT", "X", &[], 1 << 30, 0))
        .await
        .unwrap();
    assert_eq!(
        status_or_close(&mut huge).await.map(|x| x.0),
        Some(status_code::RESOURCE_ERROR)
    );
    assert!(closed(&mut huge).await);
    // A body shorter than its header says, then the client goes away: the server ends that
    // connection and keeps serving.
    let mut short = TcpStream::connect(addr).await.unwrap();
    short
        .write_all(&raw(1, "POINT", "X", &[0u8; 40], 136, 0))
        .await
        .unwrap();
    drop(short);
    // Garbage bytes: the first 58 make a header that cannot be decoded.
    let mut garbage = TcpStream::connect(addr).await.unwrap();
    garbage.write_all(&[0xA5u8; 200]).await.unwrap();
    let _ = status_or_close(&mut garbage).await;
    assert!(closed(&mut garbage).await);

    // A cloud over 64 KiB (decoded off the network threads) registers too.
    let big: Vec<Point3<f64>> = (0..4).flat_map(|_| frames[3].iter().copied()).collect();
    let bytes = cloud_message(&big, 103).encode(HeaderVersion::V2).unwrap();
    assert!(bytes.len() > 64 * 1024, "{} bytes", bytes.len());
    s.write_all(&bytes).await.unwrap();
    let t = next_from(&mut s, "Targets").await;
    assert_eq!(t.message.metadata.get("livereg.frame"), Some("103"));

    // Still serving: the first connection registers another frame.
    let mut v1 = cloud_message(&frames[2], 102);
    v1.metadata = Metadata::new();
    s.write_all(&v1.encode(HeaderVersion::V1).unwrap())
        .await
        .unwrap();
    let t = next_from(&mut s, "Targets").await;
    assert_eq!(
        t.version,
        HeaderVersion::V1,
        "replies follow the client's latest version"
    );
    let refused = server.counter("livereg_igtl_messages_total", "refused");
    assert!(refused >= 5, "refusals counted: {refused}");
    drop(s);
    server.shutdown().await.unwrap();

    // The default: clients speak RAS (3D Slicer's world). The same frame sent in RAS gives
    // register's targets in RAS, and the model-to-reference transform conjugated to RAS.
    let server = start(ras_config).await;
    let mut s = TcpStream::connect(server.igtl_addr.unwrap()).await.unwrap();
    let ras: Vec<Point3<f64>> = frames[0]
        .iter()
        .map(|p| Point3::new(-p.x, -p.y, p.z))
        .collect();
    s.write_all(&cloud_message(&ras, 0).encode(HeaderVersion::V2).unwrap())
        .await
        .unwrap();
    let transform = next_from(&mut s, "LiverToReference").await;
    let targets = next_from(&mut s, "Targets").await;
    let Content::Point(points) = &targets.message.content else {
        panic!("Targets is a POINT message")
    };
    let want = reference[0]["structures"]["targets"].as_array().unwrap();
    for (p, w) in points.points.iter().zip(want) {
        let w = [
            w[0].as_f64().unwrap(),
            w[1].as_f64().unwrap(),
            w[2].as_f64().unwrap(),
        ];
        let d = (p.position - Point3::new(-w[0], -w[1], w[2])).norm();
        assert!(
            d < 1e-4,
            "RAS target {} vs register's {w:?} in RAS",
            p.position
        );
    }
    let Content::Transform(t) = &transform.message.content else {
        panic!("LiverToReference is a TRANSFORM")
    };
    let flip = [-1.0, -1.0, 1.0];
    for r in 0..3 {
        for c in 0..3 {
            let want =
                flip[r] * flip[c] * reference[0]["rigid"]["rotation"][r][c].as_f64().unwrap();
            assert!(
                (t.matrix[(r, c)] - want).abs() < 1e-5,
                "RAS rotation ({r},{c})"
            );
        }
        let want = flip[r] * reference[0]["rigid"]["translation"][r].as_f64().unwrap();
        assert!(
            (t.matrix[(r, 3)] - want).abs() < 1e-4,
            "RAS translation {r}"
        );
    }
    drop(s);
    server.shutdown().await.unwrap();
}
