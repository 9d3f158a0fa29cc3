//! Helpers of the server tests: a small scene with a frame sequence, an in-process server on
//! loopback, the `livereg register` reference, and numeric comparison of results.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use livereg::mesh::primitives::icosphere;
use livereg::mesh::{write_obj, write_points};
use livereg::server::config::{LimitsConfig, TokenEntry};
use livereg::server::{RunningServer, ServerConfig};
use nalgebra::{Point3, Vector3};
use serde_json::Value;

/// Token of the first client.
pub const TOKEN_A: &str = "token-a-0123456789abcdef";
/// Token of the second client.
pub const TOKEN_B: &str = "token-b-fedcba9876543210";

/// A fresh directory under the system temp dir.
pub fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("livereg-server-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The scene of `tests/cli/register_cli.rs` (a clamped ellipsoid in mm, 3 targets, 20 mm cells)
/// with `n` frames bending it back and forth; coordinates are f32-exact so that JSON and
/// binary frames carry the same numbers. Frames are `frames/f000.xyz`…
pub fn small_case(tag: &str, n: usize) -> PathBuf {
    let d = temp_dir(tag);
    std::fs::create_dir_all(d.join("frames")).unwrap();
    let mut s = icosphere(Point3::origin(), 1.0, 2);
    for v in &mut s.vertices {
        *v = Point3::new(50.0 * v.x, 37.5 * v.y, 25.0 * v.z);
    }
    write_obj(&d.join("body.obj"), &s).unwrap();
    let targets = [
        Point3::new(-20.0, 0.0, 0.0),
        Point3::new(10.0, 5.0, 0.0),
        Point3::new(35.0, 0.0, -3.0),
    ];
    write_points(&d.join("targets.xyz"), &targets).unwrap();
    std::fs::write(
        d.join("scene.toml"),
        r#"units = "mm"
[model]
surface = "body.obj"
[[model.structures]]
name = "targets"
points = "targets.xyz"
[grid]
cell_size = 25.0
subdivisions = 2
[material]
law = "neo-hookean"
young_modulus = 4500.0
poisson_ratio = 0.45
[[boundary.fixed]]
box = [[-60.0, -60.0, -60.0], [-35.0, 60.0, 60.0]]
[registration]
rigid = "icp"
"#,
    )
    .unwrap();
    for k in 0..n {
        let a = 3.0 * (k as f64 * 0.3).sin();
        let pts: Vec<Point3<f64>> = s
            .vertices
            .iter()
            .map(|p| {
                let t = ((p.x + 35.0) / 85.0).max(0.0);
                let q = p + Vector3::new(0.5, 0.0, a * t * t);
                q.map(|c| f64::from(c as f32))
            })
            .collect();
        write_points(&d.join(format!("frames/f{k:03}.xyz")), &pts).unwrap();
    }
    d
}

/// The phantom scene (written to `dir`) and `n` tool-push frames in scene units.
pub fn phantom_case(dir: &Path, n: usize) -> Vec<Vec<[f64; 3]>> {
    livereg::phantom::write_phantom(dir).unwrap();
    let loaded = livereg::scene::load_scene(&dir.join("scene.toml")).unwrap();
    let scale = loaded.length_scale();
    let mut spec = livereg::synthetic::SequenceSpec::phantom_default(
        livereg::synthetic::ScenarioKind::ToolPush,
    );
    spec.frames = n;
    let seq = livereg::synthetic::generate_sequence(&loaded, &spec).unwrap();
    seq.frames
        .iter()
        .map(|f| {
            f.cloud
                .iter()
                .map(|p| [p.x / scale, p.y / scale, p.z / scale])
                .collect()
        })
        .collect()
}

/// Starts `cmd` (a `livereg serve` with `log_format = "json"`, possibly behind a wrapper) and
/// waits up to 60 s for its `listening` line: the child and the line's fields (`http_addr`,
/// `grpc_addr`, `tls`). Its later log lines are read and dropped, so that it never blocks on
/// a full pipe.
pub fn spawn_serve(mut cmd: std::process::Command) -> (std::process::Child, Value) {
    use std::io::BufRead;
    let mut child = cmd
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("the server starts");
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut sent = false;
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            if sent {
                continue;
            }
            if let Ok(v) = serde_json::from_str::<Value>(&line) {
                if v["fields"]["message"] == "listening" {
                    let _ = tx.send(v["fields"].clone());
                    sent = true;
                }
            }
        }
    });
    let fields = rx
        .recv_timeout(std::time::Duration::from_secs(60))
        .expect("livereg serve logs its address");
    (child, fields)
}

/// The `http_addr` of a `listening` line's fields.
pub fn http_addr_of(fields: &Value) -> std::net::SocketAddr {
    fields["http_addr"].as_str().unwrap().parse().unwrap()
}

/// A configuration for tests: loopback, free ports, two tokens, a private data directory.
pub fn test_config(tag: &str) -> ServerConfig {
    ServerConfig {
        bind: "127.0.0.1:0".parse().unwrap(),
        grpc_bind: Some("127.0.0.1:0".parse().unwrap()),
        tokens: vec![
            TokenEntry {
                name: "room-a".into(),
                token: TOKEN_A.into(),
            },
            TokenEntry {
                name: "room-b".into(),
                token: TOKEN_B.into(),
            },
        ],
        data_dir: temp_dir(&format!("data-{tag}")),
        worker_threads: 2,
        shutdown_grace_s: 20,
        limits: LimitsConfig {
            max_frames_per_second: 1000.0,
            // A served frame stops at the time budget, and where it stops depends on the
            // machine's speed; the tests compare served results with unbounded `livereg
            // register` runs and with replays. With the default 1 s, a cold phantom frame on
            // a loaded CI machine was once cut short and replayed 7 mm apart: a budget no
            // test frame reaches (the watchdog retires a session at 5× this).
            max_frame_ms: 120_000.0,
            ..Default::default()
        },
        ..Default::default()
    }
}

/// Starts a server in-process on the current runtime.
pub async fn start(config: ServerConfig) -> RunningServer {
    livereg::server::start(config).await.expect("server starts")
}

/// `livereg register` on the case's frames: the results.jsonl lines.
pub fn reference(case: &Path) -> Vec<Value> {
    let out = case.join("reference");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_livereg"))
        .args([
            "register",
            case.join("scene.toml").to_str().unwrap(),
            "--frames",
            case.join("frames").to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .expect("livereg runs");
    assert!(
        o.status.success(),
        "register failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    std::fs::read_to_string(out.join("results.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// Two numbers equal up to 1e-6 (scene units: a nanometre in mm scenes) plus 1e-9 relative.
/// Registration is not bit-reproducible from run to run (parallel reductions in the library):
/// two `livereg register` runs on the same frames differ by ~1e-8 mm.
fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-6 + 1e-9 * a.abs().max(b.abs())
}

/// Numbers, strings and arrays of `a` and `b` equal (numbers as [`close`]).
pub fn same(a: &Value, b: &Value, at: &str) -> Result<(), String> {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            if close(x, y) {
                Ok(())
            } else {
                Err(format!("{at}: {x} != {y}"))
            }
        }
        (Value::Array(x), Value::Array(y)) => {
            if x.len() != y.len() {
                return Err(format!("{at}: lengths {} != {}", x.len(), y.len()));
            }
            x.iter()
                .zip(y)
                .enumerate()
                .try_for_each(|(i, (p, q))| same(p, q, &format!("{at}[{i}]")))
        }
        (Value::Object(x), Value::Object(y)) => {
            for (k, v) in x {
                let w = y.get(k).ok_or(format!("{at}.{k} missing"))?;
                same(v, w, &format!("{at}.{k}"))?;
            }
            Ok(())
        }
        _ if a == b => Ok(()),
        _ => Err(format!("{at}: {a} != {b}")),
    }
}

/// Checks a server result against the `register` line of the same frame: frame index,
/// convergence, rigid pose, iteration counts, surface RMS and every structure point (the
/// timings and the frame's source name are not compared).
pub fn assert_matches_reference(got: &Value, want: &Value) {
    let at = format!("frame {}", want["frame"]);
    for key in ["frame", "converged", "rigid", "structures"] {
        same(&want[key], &got[key], &format!("{at}.{key}")).unwrap();
    }
    for key in ["icp_iterations", "newton_iterations", "surface_rms"] {
        same(
            &want["diagnostics"][key],
            &got["diagnostics"][key],
            &format!("{at}.diagnostics.{key}"),
        )
        .unwrap();
    }
}

/// The stdlib-only Python client.
pub const PYTHON_CLIENT: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/clients/python/livereg_client.py"
);

/// Fails the test unless `python3` runs here: the Python client is a real third-party peer
/// of these tests, and `scripts/test` provides it (never a silent skip).
pub fn require_python() {
    let ok = std::process::Command::new("python3")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "python3 is needed for the Python client's checks (install Python 3.11)"
    );
}

/// Arguments of `python3` running the Python client's `roundtrip` on the case in `case`
/// (its `scene.toml` and `frames/`) against the server at `url` (`http://host:port` or
/// `https://…`), with room A's token (written to `case/token.txt`), writing the results to
/// `out`; `global` goes before the subcommand (e.g. `--ca-file`), `extra` after it.
pub fn python_roundtrip_args(
    url: &str,
    case: &std::path::Path,
    out: &std::path::Path,
    global: &[&str],
    extra: &[&str],
) -> Vec<String> {
    let token_file = case.join("token.txt");
    std::fs::write(&token_file, format!("room-a:{TOKEN_A}\n")).unwrap();
    let mut args: Vec<String> = vec![
        PYTHON_CLIENT.into(),
        "--url".into(),
        url.into(),
        "--token-file".into(),
        token_file.display().to_string(),
    ];
    args.extend(global.iter().map(|a| a.to_string()));
    args.extend([
        "roundtrip".into(),
        "--scene".into(),
        case.join("scene.toml").display().to_string(),
        "--frames".into(),
        case.join("frames").display().to_string(),
        "--out".into(),
        out.display().to_string(),
    ]);
    args.extend(extra.iter().map(|a| a.to_string()));
    args
}

/// Runs the Python client's `roundtrip` (arguments as [`python_roundtrip_args`]) against the
/// server at `url`, writing `case/out_name`: the results it wrote, or its error output.
pub async fn python_roundtrip(
    url: &str,
    case: &std::path::Path,
    out_name: &str,
    global: &[&str],
    extra: &[&str],
) -> Result<Vec<serde_json::Value>, String> {
    let out = case.join(out_name);
    let args = python_roundtrip_args(url, case, &out, global, extra);
    let o = tokio::task::spawn_blocking(move || {
        std::process::Command::new("python3")
            .args(&args)
            .output()
            .unwrap()
    })
    .await
    .unwrap();
    if !o.status.success() {
        return Err(String::from_utf8_lossy(&o.stderr).into_owned());
    }
    Ok(std::fs::read_to_string(&out)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect())
}

/// [`python_roundtrip`] that must succeed.
pub async fn python_roundtrip_results(
    url: &str,
    case: &std::path::Path,
    out_name: &str,
    extra: &[&str],
) -> Vec<serde_json::Value> {
    python_roundtrip(url, case, out_name, &[], extra)
        .await
        .unwrap_or_else(|e| panic!("python client {extra:?} failed: {e}"))
}
