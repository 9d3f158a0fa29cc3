//! The deployment as shipped starts: `livereg` is run with the exact argv of
//! `deploy/Dockerfile` (ENTRYPOINT + CMD, its ENV and the configuration it copies, and the
//! `docker run -e …` its header documents) and of `deploy/kubernetes/livereg.yaml` (the image's
//! ENTRYPOINT + the container's `args`, the ConfigMap's `config.toml`, the token Secret's file
//! mode, TLS files), and must log `listening` and answer. The files are parsed here (the
//! Dockerfile by its instructions, the manifest as YAML), never restated.
//!
//! The only changes from a real container: absolute paths under `/etc/livereg`, `/var/lib/…`
//! and `/usr/local/bin/livereg` are moved under a temporary root, and the listeners bind
//! `127.0.0.1:0` (`LIVEREG_BIND`, `LIVEREG_GRPC_BIND`: the ports a container publishes).

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{channel, Receiver};
use std::time::Duration;

use serde_json::Value;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The instructions of the Dockerfile's final stage that decide how the server starts.
#[derive(Debug, Default)]
struct Image {
    entrypoint: Vec<String>,
    cmd: Vec<String>,
    env: BTreeMap<String, String>,
    /// (source in the repository, destination in the image) of each `COPY` from the context.
    copies: Vec<(String, String)>,
    /// `-e NAME=VALUE` of the documented `docker run` line.
    docker_run_env: BTreeMap<String, String>,
    /// The build stage's dependency-layer `RUN` script (the one after `COPY crates`).
    stub_script: String,
}

/// Joins continuation lines (`\` at the end) into logical lines; keeps comments.
fn logical_lines(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    for line in text.lines() {
        if cur.is_empty() && line.trim_start().starts_with('#') {
            out.push(line.to_string());
            continue;
        }
        match line.strip_suffix('\\') {
            Some(head) => {
                cur.push_str(head);
                cur.push(' ');
            }
            None => {
                cur.push_str(line);
                out.push(std::mem::take(&mut cur));
            }
        }
    }
    out
}

fn parse_dockerfile() -> Image {
    let text = std::fs::read_to_string(Path::new(ROOT).join("deploy/Dockerfile")).unwrap();
    let mut image = Image::default();
    let mut stage = 0;
    let mut after_crates = false;
    for line in logical_lines(&text) {
        let t = line.trim();
        if let Some(cmd) = t.strip_prefix('#') {
            if let Some(run) = cmd.trim().strip_prefix("docker run") {
                let words: Vec<&str> = run.split_whitespace().collect();
                for w in words.windows(2).filter(|w| w[0] == "-e") {
                    let (k, v) = w[1].split_once('=').unwrap();
                    image.docker_run_env.insert(k.into(), v.into());
                }
            }
            continue;
        }
        let (instr, rest) = t.split_once(' ').unwrap_or((t, ""));
        match instr {
            "FROM" => stage += 1,
            "COPY" if stage == 1 && rest.trim() == "crates ./crates" => after_crates = true,
            "RUN" if stage == 1 && after_crates => {
                image.stub_script = rest.to_string();
                after_crates = false;
            }
            "COPY" if stage == 2 && !rest.starts_with("--from") => {
                let parts: Vec<&str> = rest.split_whitespace().collect();
                image.copies.push((parts[0].into(), parts[1].into()));
            }
            "ENV" if stage == 2 => {
                for kv in rest.split_whitespace() {
                    let (k, v) = kv.split_once('=').unwrap();
                    image.env.insert(k.into(), v.into());
                }
            }
            "ENTRYPOINT" if stage == 2 => image.entrypoint = serde_json::from_str(rest).unwrap(),
            "CMD" if stage == 2 => image.cmd = serde_json::from_str(rest).unwrap(),
            _ => {}
        }
    }
    assert_eq!(stage, 2, "a build stage and a runtime stage");
    assert!(
        !image.entrypoint.is_empty(),
        "ENTRYPOINT in the runtime stage"
    );
    image
}

/// A container's file system under a temporary directory: image paths map into it.
struct Root {
    dir: PathBuf,
}

impl Root {
    fn new(tag: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("livereg-deploy-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self { dir }
    }

    /// `text` with every image path moved under the root (the binary to the one built here).
    fn map(&self, text: &str) -> String {
        let under = |p: &str| format!("{}{p}", self.dir.display());
        text.replace("/usr/local/bin/livereg", env!("CARGO_BIN_EXE_livereg"))
            .replace("/etc/livereg", &under("/etc/livereg"))
            .replace("/var/lib/livereg", &under("/var/lib/livereg"))
    }

    /// Writes `contents` at the image path `image_path` with Unix `mode`.
    fn put(&self, image_path: &str, contents: &[u8], mode: u32) {
        let p = PathBuf::from(self.map(image_path));
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(&p, contents).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&p, std::fs::Permissions::from_mode(mode)).unwrap();
        }
        #[cfg(not(unix))]
        let _ = mode;
    }
}

impl Drop for Root {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// A started server: the child, its log lines, and the `listening` line's fields.
struct Started {
    child: Child,
    lines: Receiver<String>,
    listening: Value,
}

impl Drop for Started {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Runs `argv` (image paths mapped) with exactly `env` (plus PATH and HOME) and waits for the
/// JSON `listening` line; panics with the server's output if it exits or stays silent.
fn start(root: &Root, argv: &[String], env: &BTreeMap<String, String>) -> Started {
    let argv: Vec<String> = argv.iter().map(|a| root.map(a)).collect();
    let mut cmd = Command::new(&argv[0]);
    cmd.args(&argv[1..])
        .env_clear()
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    for k in ["PATH", "HOME"] {
        if let Ok(v) = std::env::var(k) {
            cmd.env(k, v);
        }
    }
    for (k, v) in env {
        cmd.env(k, root.map(v));
    }
    cmd.env("LIVEREG_BIND", "127.0.0.1:0")
        .env("LIVEREG_GRPC_BIND", "127.0.0.1:0");
    let mut child = cmd.spawn().expect("livereg starts");
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut seen = Vec::new();
    loop {
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(line) => {
                if let Ok(v) = serde_json::from_str::<Value>(&line) {
                    if v["fields"]["message"] == "listening" {
                        return Started {
                            child,
                            lines: rx,
                            listening: v["fields"].clone(),
                        };
                    }
                }
                seen.push(line);
            }
            Err(_) => {
                let status = child.try_wait().ok().flatten();
                let _ = child.kill();
                panic!(
                    "`{}` did not start (exit: {status:?}); it said:\n{}",
                    argv.join(" "),
                    seen.join("\n")
                );
            }
        }
    }
}

/// One plain HTTP/1.1 request; the status code and body.
fn http_get(addr: SocketAddr, path: &str, authorization: Option<&str>) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let auth = authorization
        .map(|a| format!("Authorization: {a}\r\n"))
        .unwrap_or_default();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: livereg\r\n{auth}Connection: close\r\n\r\n"
    )
    .unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    let status = text[9..12].parse().unwrap();
    let body = text.split_once("\r\n\r\n").map_or("", |b| b.1).to_string();
    (status, body)
}

#[test]
fn the_image_starts_as_documented_with_docker_run() {
    let image = parse_dockerfile();
    // ENTRYPOINT is the binary alone, so that an orchestrator's arguments replace CMD.
    assert_eq!(image.entrypoint, ["/usr/local/bin/livereg"]);
    assert_eq!(image.cmd.first().map(String::as_str), Some("serve"));
    let root = Root::new("docker");
    for (src, dst) in &image.copies {
        let bytes = std::fs::read(Path::new(ROOT).join(src)).unwrap();
        let text = root.map(&String::from_utf8(bytes).unwrap());
        root.put(dst, text.as_bytes(), 0o644);
    }
    let mut env = image.env.clone();
    let secret = "s3cr3t-0123456789abcdef0123456789";
    for (k, v) in &image.docker_run_env {
        env.insert(k.clone(), v.replace("<secret>", secret));
    }
    assert!(
        env.contains_key("LIVEREG_TOKENS"),
        "the documented docker run gives tokens"
    );
    std::fs::create_dir_all(root.map("/var/lib/livereg")).unwrap();
    let argv: Vec<String> = image.entrypoint.iter().chain(&image.cmd).cloned().collect();
    let server = start(&root, &argv, &env);
    let addr: SocketAddr = server.listening["http_addr"]
        .as_str()
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(server.listening["tls"], false);
    let (status, body) = http_get(addr, "/healthz", None);
    assert_eq!(status, 200, "{body}");
    let (status, _) = http_get(addr, "/v1/sessions", Some(&format!("Bearer {secret}")));
    assert_eq!(status, 200, "the documented token is accepted");
    // A wrong token is refused and audited: one JSON line naming the peer and the outcome.
    let (status, _) = http_get(addr, "/v1/sessions", Some("bearer wrong-token-0123456789"));
    assert_eq!(status, 401);
    let audit = loop {
        let line = server
            .lines
            .recv_timeout(Duration::from_secs(10))
            .expect("an audit line for the refused token");
        let v: Value = serde_json::from_str(&line).unwrap_or(Value::Null);
        if v["target"] == "livereg::audit" {
            break v;
        }
    };
    let f = &audit["fields"];
    assert_eq!(f["action"], "authenticate", "{audit}");
    assert_eq!(f["outcome"], "unauthorized", "{audit}");
    assert!(
        f["peer"].as_str().unwrap().starts_with("127.0.0.1:"),
        "{audit}"
    );
    assert!(
        !audit.to_string().contains("wrong-token"),
        "the token is never logged"
    );
}

/// The dependency-cache layer stubs every `[[bench]]` target the manifest declares (cargo
/// refuses a manifest whose targets are missing): its script is run here with `cargo`
/// replaced by a recorder, and the stubs compared with the manifest read as TOML.
#[test]
fn the_dependency_layer_stubs_every_declared_target() {
    let image = parse_dockerfile();
    assert!(
        !image.stub_script.contains("|| true"),
        "a failing build must fail the layer"
    );
    let root = Root::new("stubs");
    let dir = root.dir.join("src");
    std::fs::create_dir_all(&dir).unwrap();
    for f in ["Cargo.toml", "Cargo.lock"] {
        std::fs::copy(Path::new(ROOT).join(f), dir.join(f)).unwrap();
    }
    let shim = root.dir.join("bin");
    std::fs::create_dir_all(&shim).unwrap();
    let log = root.dir.join("cargo-args");
    let cargo = shim.join("cargo");
    std::fs::write(
        &cargo,
        format!("#!/bin/sh\necho \"$@\" > {}\n", log.display()),
    )
    .unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&cargo, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    let out = Command::new("sh")
        .arg("-c")
        .arg(&image.stub_script)
        .current_dir(&dir)
        .env(
            "PATH",
            format!("{}:{}", shim.display(), std::env::var("PATH").unwrap()),
        )
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        std::fs::read_to_string(&log).unwrap().trim(),
        "build --release --bin livereg"
    );
    let manifest: toml::Value =
        toml::from_str(&std::fs::read_to_string(dir.join("Cargo.toml")).unwrap()).unwrap();
    let benches = manifest["bench"].as_array().unwrap();
    assert!(!benches.is_empty());
    for b in benches {
        let name = b["name"].as_str().unwrap();
        assert!(
            dir.join(format!("benches/{name}.rs")).is_file(),
            "bench `{name}` has no stub"
        );
    }
    assert!(dir.join("src/main.rs").is_file() && dir.join("src/lib.rs").is_file());
}

/// The manifest's resources by kind.
fn manifest() -> Vec<serde_norway::Value> {
    let text =
        std::fs::read_to_string(Path::new(ROOT).join("deploy/kubernetes/livereg.yaml")).unwrap();
    serde_norway::Deserializer::from_str(&text)
        .map(|d| serde::Deserialize::deserialize(d).unwrap())
        .collect()
}

fn of_kind<'a>(docs: &'a [serde_norway::Value], kind: &str) -> Vec<&'a serde_norway::Value> {
    docs.iter()
        .filter(|d| d["kind"].as_str() == Some(kind))
        .collect()
}

fn strings(v: &serde_norway::Value) -> Vec<String> {
    v.as_sequence()
        .map(|s| s.iter().map(|x| x.as_str().unwrap().to_string()).collect())
        .unwrap_or_default()
}

#[test]
fn the_kubernetes_pods_start_with_their_args_config_and_secrets() {
    let image = parse_dockerfile();
    let docs = manifest();
    let config = of_kind(&docs, "ConfigMap")[0]["data"]["config.toml"]
        .as_str()
        .unwrap()
        .to_string();
    let sets = of_kind(&docs, "StatefulSet");
    assert_eq!(sets.len(), 1, "one StatefulSet");
    let pod = &sets[0]["spec"]["template"]["spec"];
    let container = &pod["containers"][0];
    // Kubernetes: `command` replaces ENTRYPOINT, `args` replaces CMD.
    let command = match strings(&container["command"]) {
        c if c.is_empty() => image.entrypoint.clone(),
        c => c,
    };
    let args = match strings(&container["args"]) {
        a if a.is_empty() => image.cmd.clone(),
        a => a,
    };
    let argv: Vec<String> = command.into_iter().chain(args).collect();
    let mut env = image.env.clone();
    if let Some(list) = container["env"].as_sequence() {
        for e in list {
            env.insert(
                e["name"].as_str().unwrap().into(),
                e["value"].as_str().unwrap_or_default().into(),
            );
        }
    }
    // Volumes as mounted: the ConfigMap's file, the Secrets with their file modes.
    let root = Root::new("k8s");
    let volumes = pod["volumes"].as_sequence().unwrap();
    let mode_of = |name: &str| {
        volumes
            .iter()
            .find(|v| v["name"].as_str() == Some(name))
            .and_then(|v| v["secret"]["defaultMode"].as_u64())
            .unwrap_or(0o644) as u32
    };
    let tls = Path::new(ROOT).join("fixtures/tls");
    for m in container["volumeMounts"].as_sequence().unwrap() {
        let name = m["name"].as_str().unwrap();
        let at = m["mountPath"].as_str().unwrap();
        match name {
            "config" => root.put(at, root.map(&config).as_bytes(), 0o644),
            "tokens" => root.put(
                &format!("{at}/tokens.txt"),
                b"# operating rooms\nroom-1:0123456789abcdef0123456789abcdef\n",
                mode_of(name),
            ),
            "tls" => {
                let cert = std::fs::read(tls.join("server.pem")).unwrap();
                let key = std::fs::read(tls.join("server.key")).unwrap();
                root.put(&format!("{at}/tls.crt"), &cert, mode_of(name));
                root.put(&format!("{at}/tls.key"), &key, mode_of(name));
            }
            _ => std::fs::create_dir_all(root.map(at)).unwrap(),
        }
    }
    let server = start(&root, &argv, &env);
    assert_eq!(server.listening["tls"], true, "TLS on in the cluster");
    assert!(server.listening["grpc_addr"].as_str().is_some());
    // The probes' port answers TLS: a plain-text request gets no HTTP answer.
    let addr: SocketAddr = server.listening["http_addr"]
        .as_str()
        .unwrap()
        .parse()
        .unwrap();
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(15))).unwrap();
    s.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        .unwrap();
    let mut buf = Vec::new();
    let _ = s.read_to_end(&mut buf);
    assert!(
        !buf.starts_with(b"HTTP/1.1 200"),
        "plain HTTP answered on a TLS port"
    );
}
