//! A Rust client of the livereg server: gRPC (tonic, the generated client) and WebSocket
//! (tokio-tungstenite), with a minimal HTTP/1.1 helper for the JSON API, over plain TCP or
//! TLS ([`Endpoint`]). Used by `examples/client/main.rs` and by the tests (`tests/server/`
//! include this file).
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use livereg::server::codec::{encode_binary_frame, ResultMessage};
use livereg::server::proto;
use livereg::server::proto::registration_client::RegistrationClient;
use livereg::server::result_codec::decode_binary_result;
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message;

/// Any error, as text.
pub type Res<T> = Result<T, String>;

/// TLS settings of a client: the CA certificates it trusts and the name the server's
/// certificate must carry.
#[derive(Clone)]
pub struct ClientTls {
    connector: tokio_rustls::TlsConnector,
    ca_pem: Vec<u8>,
    domain: String,
}

impl ClientTls {
    /// Trusts the PEM certificates of `ca_pem` (only them) and checks the name `domain`.
    pub fn new(ca_pem: &[u8], domain: &str) -> Res<Self> {
        use tokio_rustls::rustls;
        use tokio_rustls::rustls::pki_types::pem::PemObject;
        use tokio_rustls::rustls::pki_types::CertificateDer;
        let mut roots = rustls::RootCertStore::empty();
        for c in CertificateDer::pem_slice_iter(ca_pem) {
            roots
                .add(c.map_err(|e| format!("CA certificate: {e}"))?)
                .map_err(|e| format!("CA certificate: {e}"))?;
        }
        if roots.is_empty() {
            return Err("no PEM certificate in the CA file".into());
        }
        let provider = std::sync::Arc::new(rustls::crypto::ring::default_provider());
        let mut config = rustls::ClientConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()
            .map_err(|e| e.to_string())?
            .with_root_certificates(roots)
            .with_no_client_auth();
        config.alpn_protocols = vec![b"http/1.1".to_vec()];
        Ok(Self {
            connector: tokio_rustls::TlsConnector::from(std::sync::Arc::new(config)),
            ca_pem: ca_pem.to_vec(),
            domain: domain.to_string(),
        })
    }
}

/// Where a server listens: its address, and TLS when it speaks TLS.
#[derive(Clone)]
pub struct Endpoint {
    /// Socket address.
    pub addr: SocketAddr,
    /// `None`: plain TCP (`http://`, `ws://`).
    pub tls: Option<ClientTls>,
}

impl From<SocketAddr> for Endpoint {
    fn from(addr: SocketAddr) -> Self {
        Self { addr, tls: None }
    }
}

impl From<&Endpoint> for Endpoint {
    fn from(e: &Endpoint) -> Self {
        e.clone()
    }
}

/// A connection of the client, plain or TLS.
pub trait Io: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send {}
impl<T: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send> Io for T {}

impl Endpoint {
    /// A connected socket (no Nagle delay), through the TLS handshake when TLS is on.
    pub async fn connect(&self) -> Res<Box<dyn Io>> {
        let s = tokio::net::TcpStream::connect(self.addr)
            .await
            .map_err(|e| format!("connect {}: {e}", self.addr))?;
        let _ = s.set_nodelay(true);
        match &self.tls {
            None => Ok(Box::new(s)),
            Some(t) => {
                let name = tokio_rustls::rustls::pki_types::ServerName::try_from(t.domain.clone())
                    .map_err(|e| format!("TLS name {:?}: {e}", t.domain))?;
                let tls = t
                    .connector
                    .connect(name, s)
                    .await
                    .map_err(|e| format!("TLS handshake with {}: {e}", self.addr))?;
                Ok(Box::new(tls))
            }
        }
    }

    /// `http` or `https`, `ws` or `wss`: the scheme for `plain`.
    fn scheme(&self, plain: &str) -> String {
        match self.tls {
            Some(_) => format!("{plain}s"),
            None => plain.to_string(),
        }
    }
}
/// An HTTP response: status, headers (lower-case names) and body.
#[derive(Debug, Clone)]
pub struct HttpResponse {
    /// Status code.
    pub status: u16,
    /// Headers, names in lower case.
    pub headers: BTreeMap<String, String>,
    /// Body bytes.
    pub body: Vec<u8>,
}

impl HttpResponse {
    /// The body as JSON (Null when it is not JSON).
    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or(Value::Null)
    }
}

/// One HTTP/1.1 request (`Connection: close`) with raw `body` bytes.
pub async fn http(
    to: impl Into<Endpoint>,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> Res<HttpResponse> {
    let ep = to.into();
    let addr = ep.addr;
    let mut s = ep.connect().await?;
    let mut req = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: {}\r\n",
        body.len()
    );
    for (k, v) in headers {
        req.push_str(&format!("{k}: {v}\r\n"));
    }
    req.push_str("\r\n");
    let mut bytes = req.into_bytes();
    bytes.extend_from_slice(body);
    // The server may answer (413) before reading a large body: ignore a failed write then.
    let _ = s.write_all(&bytes).await;
    let mut out = Vec::new();
    if let Err(e) = s.read_to_end(&mut out).await {
        // A TLS peer that closes without close_notify after a complete response is fine.
        if out.is_empty() || e.kind() != std::io::ErrorKind::UnexpectedEof {
            return Err(format!("read: {e}"));
        }
    }
    parse_response(&out)
}

fn parse_response(raw: &[u8]) -> Res<HttpResponse> {
    let end = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .ok_or("no end of headers")?;
    let head = String::from_utf8_lossy(&raw[..end]);
    let mut lines = head.split("\r\n");
    let status_line = lines.next().ok_or("empty response")?;
    let status: u16 = status_line
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .ok_or(format!("bad status line {status_line:?}"))?;
    let headers: BTreeMap<String, String> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    let mut body = raw[end + 4..].to_vec();
    if headers
        .get("transfer-encoding")
        .is_some_and(|v| v.contains("chunked"))
    {
        let mut out = Vec::new();
        let mut rest = &body[..];
        while let Some(p) = rest.windows(2).position(|w| w == b"\r\n") {
            let n = usize::from_str_radix(String::from_utf8_lossy(&rest[..p]).trim(), 16)
                .map_err(|e| format!("chunk size: {e}"))?;
            if n == 0 {
                break;
            }
            out.extend_from_slice(&rest[p + 2..p + 2 + n]);
            rest = &rest[p + 2 + n + 2..];
        }
        body = out;
    }
    Ok(HttpResponse {
        status,
        headers,
        body,
    })
}

/// A scene and its files read from disk (the scene's directory holds the files it names).
#[derive(Debug, Clone)]
pub struct SceneFiles {
    /// Scene text.
    pub scene: String,
    /// "toml" or "json".
    pub format: String,
    /// File name → content.
    pub files: BTreeMap<String, Vec<u8>>,
}

impl SceneFiles {
    /// Reads `scene_path` and every other regular file of its directory whose name the scene
    /// text mentions.
    pub fn read(scene_path: &Path) -> Res<Self> {
        let scene = std::fs::read_to_string(scene_path)
            .map_err(|e| format!("{}: {e}", scene_path.display()))?;
        let dir = scene_path.parent().unwrap_or(Path::new("."));
        let mut files = BTreeMap::new();
        for e in std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))? {
            let p = e.map_err(|e| e.to_string())?.path();
            let Some(name) = p.file_name().and_then(|n| n.to_str()) else {
                continue;
            };
            if p.is_file() && p != scene_path && scene.contains(&format!("\"{name}\"")) {
                files.insert(
                    name.to_string(),
                    std::fs::read(&p).map_err(|e| e.to_string())?,
                );
            }
        }
        let format = if scene_path.extension().is_some_and(|e| e == "json") {
            "json"
        } else {
            "toml"
        };
        Ok(Self {
            scene,
            format: format.into(),
            files,
        })
    }

    /// A multipart/form-data body (boundary, bytes) uploading the scene and its files.
    pub fn multipart(&self) -> (String, Vec<u8>) {
        let boundary = "livereg-boundary-7d1f0c2e9b";
        let mut b = Vec::new();
        let mut part = |name: &str, file: &str, data: &[u8]| {
            b.extend_from_slice(
                format!(
                    "--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"; filename=\"{file}\"\r\nContent-Type: application/octet-stream\r\n\r\n"
                )
                .as_bytes(),
            );
            b.extend_from_slice(data);
            b.extend_from_slice(b"\r\n");
        };
        part(
            "scene",
            &format!("scene.{}", self.format),
            self.scene.as_bytes(),
        );
        for (n, d) in &self.files {
            part("file", n, d);
        }
        b.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
        (boundary.to_string(), b)
    }
}

/// Creates a session over HTTP (multipart upload); returns its id.
pub async fn http_create_session(
    addr: impl Into<Endpoint>,
    token: &str,
    scene: &SceneFiles,
) -> Res<String> {
    http_create_session_info(addr, token, scene).await?["id"]
        .as_str()
        .map(str::to_string)
        .ok_or("no id".into())
}

/// Creates a session over HTTP (multipart upload); returns the whole create response (the
/// session description: id, recording file name, model size, …).
pub async fn http_create_session_info(
    addr: impl Into<Endpoint>,
    token: &str,
    scene: &SceneFiles,
) -> Res<Value> {
    let (boundary, body) = scene.multipart();
    let ct = format!("multipart/form-data; boundary={boundary}");
    let auth = format!("Bearer {token}");
    let r = http(
        addr,
        "POST",
        "/v1/sessions",
        &[("Content-Type", &ct), ("Authorization", &auth)],
        &body,
    )
    .await?;
    if r.status != 201 {
        return Err(format!(
            "create session: {} {}",
            r.status,
            String::from_utf8_lossy(&r.body)
        ));
    }
    Ok(r.json())
}

/// Closes a session over HTTP.
pub async fn http_close_session(addr: impl Into<Endpoint>, token: &str, id: &str) -> Res<Value> {
    let auth = format!("Bearer {token}");
    let r = http(
        addr,
        "DELETE",
        &format!("/v1/sessions/{id}"),
        &[("Authorization", &auth)],
        b"",
    )
    .await?;
    if r.status != 200 {
        return Err(format!(
            "close: {} {}",
            r.status,
            String::from_utf8_lossy(&r.body)
        ));
    }
    Ok(r.json())
}

/// A WebSocket stream of one session.
pub struct WsClient {
    ws: WsStream,
    binary_results: bool,
}

/// What the server said on a stream.
#[derive(Debug, Clone)]
pub enum WsEvent {
    /// A result (the JSON object, `type` = `result`).
    Result(Value),
    /// A result sent in the binary result encoding (streams opened with binary results),
    /// decoded; coordinates are f32 widened to f64.
    BinaryResult(Box<ResultMessage>),
    /// A message the client could not decode (a corrupted binary result, text that is not
    /// JSON), with the reason.
    Undecodable(String),
    /// A refused frame: seq, code, message.
    Error(u64, String, String),
    /// The server closed the stream with this code.
    Closed(u16),
}

impl WsClient {
    /// Opens `ws://addr/v1/sessions/{id}/stream` (`wss://` with TLS) with the token (JSON
    /// results).
    pub async fn connect(addr: impl Into<Endpoint>, id: &str, token: &str) -> Res<Self> {
        Self::connect_with(addr, id, token, false).await
    }

    /// Opens the stream, asking for binary results (`?results=binary`) when `binary_results`.
    pub async fn connect_with(
        addr: impl Into<Endpoint>,
        id: &str,
        token: &str,
        binary_results: bool,
    ) -> Res<Self> {
        let query = if binary_results {
            "?results=binary"
        } else {
            ""
        };
        let ep = addr.into();
        let mut req = format!(
            "{}://{}/v1/sessions/{id}/stream{query}",
            ep.scheme("ws"),
            ep.addr
        )
        .into_client_request()
        .map_err(|e| e.to_string())?;
        req.headers_mut().insert(
            "authorization",
            format!("Bearer {token}").parse().map_err(|_| "bad token")?,
        );
        // The routing key of a scaled-out deployment (ignored by a single server).
        req.headers_mut()
            .insert(SESSION_HEADER, id.parse().map_err(|_| "bad session id")?);
        let io = ep.connect().await?;
        let (ws, _) = tokio_tungstenite::client_async(req, io)
            .await
            .map_err(|e| format!("websocket connect: {e}"))?;
        Ok(Self { ws, binary_results })
    }

    /// Sends a frame as JSON.
    pub async fn send_json(&mut self, seq: u64, source: &str, points: &[[f64; 3]]) -> Res<()> {
        let msg = serde_json::json!({"seq": seq, "source": source, "points": points});
        self.ws
            .send(Message::Text(msg.to_string().into()))
            .await
            .map_err(|e| e.to_string())
    }

    /// Sends a frame in the binary encoding (f32).
    pub async fn send_binary(&mut self, seq: u64, points: &[[f32; 3]]) -> Res<()> {
        self.ws
            .send(Message::Binary(
                encode_binary_frame(seq, points, None).into(),
            ))
            .await
            .map_err(|e| e.to_string())
    }

    /// Sends raw text or bytes (tests of bad input).
    pub async fn send_raw(&mut self, m: Message) -> Res<()> {
        self.ws.send(m).await.map_err(|e| e.to_string())
    }

    /// The next event (None when the connection ended without a close frame).
    pub async fn next(&mut self) -> Option<WsEvent> {
        loop {
            match self.ws.next().await? {
                Ok(Message::Text(t)) => {
                    let v: Value = match serde_json::from_str(&t) {
                        Ok(v) => v,
                        Err(e) => return Some(WsEvent::Undecodable(format!("text message: {e}"))),
                    };
                    return Some(match v["type"].as_str() {
                        Some("result") => WsEvent::Result(v),
                        _ => WsEvent::Error(
                            v["seq"].as_u64().unwrap_or(0),
                            v["error"]["code"].as_str().unwrap_or("").to_string(),
                            v["error"]["message"].as_str().unwrap_or("").to_string(),
                        ),
                    });
                }
                Ok(Message::Binary(b)) if self.binary_results => {
                    return Some(match decode_binary_result(&b) {
                        Ok(r) => WsEvent::BinaryResult(Box::new(r)),
                        Err(e) => WsEvent::Undecodable(e.to_string()),
                    });
                }
                Ok(Message::Close(f)) => {
                    return Some(WsEvent::Closed(
                        f.map(|f| u16::from(f.code)).unwrap_or(1005),
                    ))
                }
                Ok(_) => continue,
                Err(_) => return None,
            }
        }
    }

    /// Closes the stream.
    pub async fn close(mut self) {
        let _ = self.ws.close(None).await;
    }

    /// Splits into a sender and a receiver.
    pub fn split(self) -> (WsSink, WsSource) {
        self.ws.split()
    }
}

/// The WebSocket connection type of the client.
pub type WsStream = tokio_tungstenite::WebSocketStream<Box<dyn Io>>;
/// Sending half of a split [`WsClient`].
pub type WsSink = futures_util::stream::SplitSink<WsStream, Message>;
/// Receiving half of a split [`WsClient`].
pub type WsSource = futures_util::stream::SplitStream<WsStream>;

/// A gRPC client with its token.
#[derive(Clone)]
pub struct GrpcClient {
    /// The generated client.
    pub inner: RegistrationClient<tonic::transport::Channel>,
    token: String,
}

impl GrpcClient {
    /// Connects to `http://addr`.
    pub async fn connect(addr: SocketAddr, token: &str) -> Res<Self> {
        let inner = RegistrationClient::connect(format!("http://{addr}"))
            .await
            .map_err(|e| format!("grpc connect: {e}"))?
            .max_decoding_message_size(usize::MAX);
        Ok(Self {
            inner,
            token: token.to_string(),
        })
    }

    /// Connects to `https://addr` through TLS, trusting the CA certificates of `ca_pem` and
    /// checking that the server's certificate names `domain` (e.g. `localhost`).
    pub async fn connect_tls(
        addr: SocketAddr,
        token: &str,
        ca_pem: &[u8],
        domain: &str,
    ) -> Res<Self> {
        let tls = ClientTls::new(ca_pem, domain)?;
        Self::connect_endpoint(
            &Endpoint {
                addr,
                tls: Some(tls),
            },
            token,
        )
        .await
    }

    /// Connects to an [`Endpoint`]: `http://addr`, or `https://addr` with its TLS settings.
    pub async fn connect_endpoint(ep: &Endpoint, token: &str) -> Res<Self> {
        use tonic::transport::{Certificate, Channel, ClientTlsConfig};
        let mut channel = Channel::from_shared(format!("{}://{}", ep.scheme("http"), ep.addr))
            .map_err(|e| format!("grpc address: {e}"))?;
        if let Some(t) = &ep.tls {
            let tls = ClientTlsConfig::new()
                .ca_certificate(Certificate::from_pem(&t.ca_pem))
                .domain_name(t.domain.clone());
            channel = channel
                .tls_config(tls)
                .map_err(|e| format!("grpc tls: {e}"))?;
        }
        let channel = channel
            .connect()
            .await
            .map_err(|e| format!("grpc connect: {e}"))?;
        Ok(Self {
            inner: RegistrationClient::new(channel).max_decoding_message_size(usize::MAX),
            token: token.to_string(),
        })
    }

    /// A request carrying the token.
    pub fn req<T>(&self, m: T) -> tonic::Request<T> {
        let mut r = tonic::Request::new(m);
        if let Ok(v) = format!("Bearer {}", self.token).parse() {
            r.metadata_mut().insert("authorization", v);
        }
        r
    }

    /// A request carrying the token and the session's routing key (`x-livereg-session`).
    pub fn req_for<T>(&self, session: &str, m: T) -> tonic::Request<T> {
        let mut r = self.req(m);
        if let Ok(v) = session.parse() {
            r.metadata_mut().insert(SESSION_HEADER, v);
        }
        r
    }

    /// The create request for `scene` and its files.
    fn create_request(scene: &SceneFiles) -> proto::CreateSessionRequest {
        proto::CreateSessionRequest {
            scene: scene.scene.clone(),
            scene_format: scene.format.clone(),
            files: scene.files.clone().into_iter().collect(),
            budget_ms: None,
            rigid_only: false,
        }
    }

    /// Creates a session with the id `id` chosen by the client (the routing key).
    pub async fn create_session_with_id(
        &mut self,
        scene: &SceneFiles,
        id: &str,
    ) -> Result<proto::SessionInfo, tonic::Status> {
        let req = self.req_for(id, Self::create_request(scene));
        Ok(self.inner.create_session(req).await?.into_inner())
    }

    /// Creates a session from a scene and its files (the server draws its id).
    pub async fn create_session(
        &mut self,
        scene: &SceneFiles,
    ) -> Result<proto::SessionInfo, tonic::Status> {
        let req = self.req(Self::create_request(scene));
        Ok(self.inner.create_session(req).await?.into_inner())
    }

    /// Registers one frame of `session` (full precision), with the session's routing key.
    pub async fn register(
        &mut self,
        session: &str,
        seq: u64,
        source: &str,
        points: &[[f64; 3]],
    ) -> Result<proto::FrameResult, tonic::Status> {
        let req = self.req_for(
            session,
            proto::RegisterRequest {
                session_id: session.to_string(),
                frame: Some(frame_f64(seq, source, points)),
            },
        );
        Ok(self.inner.register(req).await?.into_inner())
    }

    /// Closes a session.
    pub async fn close_session(
        &mut self,
        id: &str,
    ) -> Result<proto::CloseSessionResponse, tonic::Status> {
        let req = self.req(proto::SessionRef { id: id.to_string() });
        Ok(self.inner.close_session(req).await?.into_inner())
    }
}

/// A protobuf frame with f64 coordinates.
pub fn frame_f64(seq: u64, source: &str, points: &[[f64; 3]]) -> proto::Frame {
    proto::Frame {
        seq,
        source: source.to_string(),
        points: Vec::new(),
        camera: None,
        points_f64: points.iter().flatten().copied().collect(),
    }
}

/// The JSON results.jsonl-shaped record of a gRPC result (for comparison with `register`).
pub fn proto_to_record(r: &proto::FrameResult) -> Value {
    let rot: Vec<Vec<f64>> = r.rotation.chunks(3).map(|c| c.to_vec()).collect();
    let structures: serde_json::Map<String, Value> = r
        .structures
        .iter()
        .map(|s| {
            let pts: Vec<Vec<f64>> = s.points.chunks(3).map(|c| c.to_vec()).collect();
            (s.name.clone(), serde_json::json!(pts))
        })
        .collect();
    let mut rigid = serde_json::json!({"rotation": rot, "translation": r.translation});
    if let Some(u) = r.pose_uncertainty {
        rigid["uncertainty"] = u.into();
    }
    serde_json::json!({
        "frame": r.frame, "source": r.source, "converged": r.converged,
        "rigid": rigid,
        "diagnostics": {"icp_iterations": r.icp_iterations, "newton_iterations": r.newton_iterations,
                        "surface_rms": r.surface_rms},
        "structures": structures,
        "error": r.error,
    })
}

/// Reads the point files of a directory in lexical order: (file name, points).
pub fn read_frames(dir: &Path) -> Res<Vec<(String, Vec<[f64; 3]>)>> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "xyz" || e == "txt"))
        .collect();
    files.sort();
    files
        .iter()
        .map(|p| {
            let pts = livereg::mesh::read_points(p).map_err(|e| e.to_string())?;
            Ok((
                p.file_name()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned(),
                pts.iter().map(|q| [q.x, q.y, q.z]).collect(),
            ))
        })
        .collect()
}

/// Percentile (nearest rank on sorted data), 0 when empty.
pub fn pct(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let k = ((p * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    sorted[k]
}

/// The JSON object of a decoded binary result: the shape of a JSON result message (`type`,
/// the results.jsonl fields, `surface`, `seq`, …), coordinates at f32 precision.
pub fn binary_result_to_json(r: &ResultMessage) -> Value {
    let mut v = serde_json::to_value(r).unwrap_or(Value::Null);
    v["type"] = "result".into();
    v
}

/// Streams `frames` over one WebSocket in lock step (send, wait for the result): the results
/// in order, and per frame (end-to-end ms, registration wall ms). Frames in the binary
/// encoding when `binary`; JSON results.
pub async fn ws_lockstep(
    addr: impl Into<Endpoint>,
    id: &str,
    token: &str,
    frames: &[(String, Vec<[f64; 3]>)],
    binary: bool,
) -> Res<(Vec<Value>, Vec<(f64, f64)>)> {
    ws_lockstep_with(addr, id, token, frames, binary, false).await
}

/// [`ws_lockstep`] with the choice of result encoding: `binary_results` opens the stream with
/// `?results=binary`; the decoded results are returned as JSON objects of the JSON shape
/// ([`binary_result_to_json`]). The end-to-end time ends once the result is decoded (into a
/// `serde_json::Value` for JSON results, a [`ResultMessage`] for binary ones).
pub async fn ws_lockstep_with(
    addr: impl Into<Endpoint>,
    id: &str,
    token: &str,
    frames: &[(String, Vec<[f64; 3]>)],
    binary: bool,
    binary_results: bool,
) -> Res<(Vec<Value>, Vec<(f64, f64)>)> {
    let mut ws = WsClient::connect_with(addr, id, token, binary_results).await?;
    let mut results = Vec::new();
    let mut times = Vec::new();
    for (k, (name, pts)) in frames.iter().enumerate() {
        let t = Instant::now();
        if binary {
            let p32: Vec<[f32; 3]> = pts
                .iter()
                .map(|p| [p[0] as f32, p[1] as f32, p[2] as f32])
                .collect();
            ws.send_binary(k as u64, &p32).await?;
        } else {
            ws.send_json(k as u64, name, pts).await?;
        }
        match ws.next().await {
            Some(WsEvent::Result(v)) => {
                let e2e = t.elapsed().as_secs_f64() * 1e3;
                times.push((e2e, v["wall_ms"].as_f64().unwrap_or(0.0)));
                results.push(v);
            }
            Some(WsEvent::BinaryResult(r)) => {
                let e2e = t.elapsed().as_secs_f64() * 1e3;
                times.push((e2e, r.record.wall_ms));
                results.push(binary_result_to_json(&r));
            }
            other => return Err(format!("frame {k}: expected a result, got {other:?}")),
        }
    }
    ws.close().await;
    Ok((results, times))
}

/// Settings of a load run.
#[derive(Debug, Clone)]
pub struct LoadSpec {
    /// Concurrent sessions.
    pub sessions: usize,
    /// Frames per second each session sends.
    pub hz: f64,
    /// Streaming time per session.
    pub duration: Duration,
    /// Send frames in the binary encoding.
    pub binary: bool,
    /// Ask for results in the binary result encoding (`?results=binary`).
    pub binary_results: bool,
    /// When each session sends within the frame period, once every session is warmed up.
    pub phases: Phases,
}

/// Phases of the sessions' frame clocks in a load run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Phases {
    /// Session `i` of `n` sends at `i / n` of the period: independent clients (operating
    /// rooms) spread their frames over the period, on average evenly.
    #[default]
    Spread,
    /// Every session sends at the same instants: the worst case, a burst of `n` frames
    /// each period.
    Together,
}

/// What a load run measured.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct LoadReport {
    /// Sessions.
    pub sessions: usize,
    /// Frames sent (after warm-up).
    pub sent: u64,
    /// Results received.
    pub results: u64,
    /// Frames the server skipped (newest wins), as reported in results.
    pub skipped: u64,
    /// Error messages received, and results whose registration failed.
    pub errors: u64,
    /// End-to-end latency percentiles (client send → result received), ms.
    pub e2e_p50_ms: f64,
    /// See `e2e_p50_ms`.
    pub e2e_p95_ms: f64,
    /// See `e2e_p50_ms`.
    pub e2e_p99_ms: f64,
    /// Largest end-to-end latency, ms.
    pub e2e_max_ms: f64,
    /// Registration wall time percentiles of the same frames, ms.
    pub wall_p50_ms: f64,
    /// See `wall_p50_ms`.
    pub wall_p95_ms: f64,
    /// Server-side wait for a registration slot of the same frames (`queue_ms`), ms: with
    /// `wall` and `server`, where the end-to-end time goes.
    pub queue_p50_ms: f64,
    /// See `queue_p50_ms`.
    pub queue_p95_ms: f64,
    /// Server time from receipt of a frame to its result (`server_ms`), ms; end-to-end minus
    /// this is the transport and the client.
    pub server_p50_ms: f64,
    /// See `server_p50_ms`.
    pub server_p95_ms: f64,
    /// Cold first frame (warm-up, not counted above): median over sessions, ms.
    pub warmup_p50_ms: f64,
    /// First error messages, for the record.
    pub error_samples: Vec<String>,
}

/// Runs `spec.sessions` sessions at once over WebSocket, each created over HTTP from `scene`,
/// warmed up with one frame (the cold first frame, reported apart), then streaming `frames`
/// cyclically at `spec.hz` for `spec.duration`; collects end-to-end latencies.
pub async fn load_test(
    addr: impl Into<Endpoint>,
    token: &str,
    scene: &SceneFiles,
    frames: &[(String, Vec<[f64; 3]>)],
    spec: &LoadSpec,
) -> Res<LoadReport> {
    let addr: Endpoint = addr.into();
    let mut ids = Vec::new();
    for _ in 0..spec.sessions {
        ids.push(http_create_session(&addr, token, scene).await?);
    }
    let frames = std::sync::Arc::new(frames.to_vec());
    // Every session starts streaming at a common instant after all warm-ups (plus its phase).
    let warmed = std::sync::Arc::new(tokio::sync::Barrier::new(ids.len()));
    let start = std::sync::Arc::new(std::sync::Mutex::new(None::<tokio::time::Instant>));
    let mut tasks = Vec::new();
    for (i, id) in ids.clone().into_iter().enumerate() {
        let token = token.to_string();
        let frames = frames.clone();
        let spec = spec.clone();
        let addr = addr.clone();
        let period = Duration::from_secs_f64(1.0 / spec.hz);
        let phase = match spec.phases {
            Phases::Spread => period.mul_f64(i as f64 / ids.len() as f64),
            Phases::Together => Duration::ZERO,
        };
        let clock = StreamClock {
            warmed: warmed.clone(),
            start: start.clone(),
            phase,
        };
        tasks.push(tokio::spawn(async move {
            one_session(&addr, &id, &token, &frames, &spec, clock).await
        }));
    }
    let mut rep = LoadReport {
        sessions: spec.sessions,
        ..Default::default()
    };
    let mut e2e = Vec::new();
    let mut wall = Vec::new();
    let mut queue = Vec::new();
    let mut server = Vec::new();
    let mut warm = Vec::new();
    for t in tasks {
        let s = t.await.map_err(|e| e.to_string())??;
        rep.sent += s.sent;
        rep.results += s.e2e.len() as u64;
        rep.skipped += s.skipped;
        rep.errors += s.errors.len() as u64;
        rep.error_samples.extend(s.errors.into_iter().take(3));
        e2e.extend(s.e2e);
        wall.extend(s.wall);
        queue.extend(s.queue);
        server.extend(s.server);
        warm.push(s.warmup_ms);
    }
    for id in &ids {
        http_close_session(&addr, token, id).await?;
    }
    let sort = |v: &mut Vec<f64>| v.sort_by(f64::total_cmp);
    sort(&mut e2e);
    sort(&mut wall);
    sort(&mut queue);
    sort(&mut server);
    sort(&mut warm);
    rep.e2e_p50_ms = pct(&e2e, 0.5);
    rep.e2e_p95_ms = pct(&e2e, 0.95);
    rep.e2e_p99_ms = pct(&e2e, 0.99);
    rep.e2e_max_ms = e2e.last().copied().unwrap_or(0.0);
    rep.wall_p50_ms = pct(&wall, 0.5);
    rep.wall_p95_ms = pct(&wall, 0.95);
    rep.queue_p50_ms = pct(&queue, 0.5);
    rep.queue_p95_ms = pct(&queue, 0.95);
    rep.server_p50_ms = pct(&server, 0.5);
    rep.server_p95_ms = pct(&server, 0.95);
    rep.warmup_p50_ms = pct(&warm, 0.5);
    Ok(rep)
}

struct SessionRun {
    sent: u64,
    skipped: u64,
    errors: Vec<String>,
    e2e: Vec<f64>,
    wall: Vec<f64>,
    queue: Vec<f64>,
    server: Vec<f64>,
    warmup_ms: f64,
}

fn f32_points(p: &[[f64; 3]]) -> Vec<[f32; 3]> {
    p.iter()
        .map(|q| [q[0] as f32, q[1] as f32, q[2] as f32])
        .collect()
}

/// When a load session starts streaming: after every session's warm-up (`warmed`), at the
/// common `start` (set by the first session past the barrier) plus its `phase`.
struct StreamClock {
    warmed: std::sync::Arc<tokio::sync::Barrier>,
    start: std::sync::Arc<std::sync::Mutex<Option<tokio::time::Instant>>>,
    phase: Duration,
}

async fn one_session(
    addr: &Endpoint,
    id: &str,
    token: &str,
    frames: &[(String, Vec<[f64; 3]>)],
    spec: &LoadSpec,
    clock: StreamClock,
) -> Res<SessionRun> {
    // Warm-up: the cold first frame.
    let t = Instant::now();
    let warm = async {
        let mut ws = WsClient::connect_with(addr, id, token, spec.binary_results).await?;
        ws.send_json(0, &frames[0].0, &frames[0].1).await?;
        match ws.next().await {
            Some(WsEvent::Result(_) | WsEvent::BinaryResult(_)) => Ok(ws),
            other => Err(format!("warm-up: {other:?}")),
        }
    }
    .await;
    let warmup_ms = t.elapsed().as_secs_f64() * 1e3;
    // Every session passes the barrier, a failed one too, so that none waits forever.
    clock.warmed.wait().await;
    let ws = warm?;
    let start = {
        let mut s = clock.start.lock().map_err(|_| "clock lock")?;
        *s.get_or_insert_with(|| tokio::time::Instant::now() + Duration::from_millis(20))
    };
    let (mut tx, mut rx) = ws.split();
    let sent_at = std::sync::Arc::new(std::sync::Mutex::new(BTreeMap::<u64, Instant>::new()));
    let sa = sent_at.clone();
    let period = Duration::from_secs_f64(1.0 / spec.hz);
    let n = (spec.duration.as_secs_f64() * spec.hz).round() as u64;
    let binary = spec.binary;
    let frames_owned = frames.to_vec();
    let sender = tokio::spawn(async move {
        let mut tick = tokio::time::interval_at(start + clock.phase, period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut sent = 0u64;
        for k in 1..=n {
            tick.tick().await;
            let (name, pts) = &frames_owned[k as usize % frames_owned.len()];
            let msg = if binary {
                Message::Binary(encode_binary_frame(k, &f32_points(pts), None).into())
            } else {
                Message::Text(
                    serde_json::json!({"seq": k, "source": name, "points": pts})
                        .to_string()
                        .into(),
                )
            };
            if let Ok(mut m) = sa.lock() {
                m.insert(k, Instant::now());
            }
            if tx.send(msg).await.is_err() {
                break;
            }
            sent += 1;
        }
        (tx, sent)
    });
    let mut run = SessionRun {
        sent: 0,
        skipped: 0,
        errors: Vec::new(),
        e2e: Vec::new(),
        wall: Vec::new(),
        queue: Vec::new(),
        server: Vec::new(),
        warmup_ms,
    };
    let deadline = Instant::now() + spec.duration + Duration::from_secs(30);
    let mut last_seq = 0;
    while last_seq < n && Instant::now() < deadline {
        let msg = tokio::time::timeout(Duration::from_secs(30), rx.next()).await;
        let now = Instant::now();
        // (seq, wall ms, skipped, registration error, queue ms, server ms) of a result; text
        // that is not a result.
        let result = match msg {
            Ok(Some(Ok(Message::Text(t)))) => {
                let v: Value = serde_json::from_str(&t).map_err(|e| e.to_string())?;
                if v["type"] == "result" {
                    (
                        v["seq"].as_u64().unwrap_or(0),
                        v["wall_ms"].as_f64().unwrap_or(0.0),
                        v["skipped"].as_u64().unwrap_or(0),
                        v["diagnostics"]["error"].as_str().map(str::to_string),
                        v["queue_ms"].as_f64().unwrap_or(0.0),
                        v["server_ms"].as_f64().unwrap_or(0.0),
                    )
                } else {
                    run.errors.push(t.to_string());
                    continue;
                }
            }
            Ok(Some(Ok(Message::Binary(b)))) if spec.binary_results => {
                let r = decode_binary_result(&b).map_err(|e| e.to_string())?;
                (
                    r.seq,
                    r.record.wall_ms,
                    r.skipped,
                    r.record.diagnostics.error,
                    r.queue_ms,
                    r.server_ms,
                )
            }
            Ok(Some(Ok(_))) => continue,
            _ => break,
        };
        let (seq, wall_ms, skipped, error, queue_ms, server_ms) = result;
        let sent = sent_at.lock().ok().and_then(|m| m.get(&seq).copied());
        if let Some(s) = sent {
            run.e2e.push((now - s).as_secs_f64() * 1e3);
        }
        run.wall.push(wall_ms);
        run.queue.push(queue_ms);
        run.server.push(server_ms);
        run.skipped += skipped;
        if let Some(e) = error {
            run.errors.push(format!("frame {seq}: {e}"));
        }
        last_seq = seq;
        // The last frame was sent and an answer for a frame after all earlier ones arrived:
        // once the sender is done, stop when the newest frame is answered.
        if sender.is_finished() && last_seq == n {
            break;
        }
    }
    let (mut tx, sent) = sender.await.map_err(|e| e.to_string())?;
    run.sent = sent;
    let _ = tx.send(Message::Close(None)).await;
    Ok(run)
}

/// The header naming a session (the server's: the id a create asks for, and the key a
/// scaled-out deployment's proxy routes every request of the session by).
pub use livereg::server::SESSION_HEADER;

/// A session id chosen by the client: 128 random bits, 32 lowercase hex digits.
pub fn new_client_session_id() -> String {
    let mut b = [0u8; 16];
    getrandom::fill(&mut b).expect("randomness");
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// Creates a session over HTTP with the id `id` (multipart upload, `X-Livereg-Session`): the
/// raw response (201, or the refusal).
pub async fn http_create_session_with_id(
    addr: impl Into<Endpoint>,
    token: &str,
    scene: &SceneFiles,
    id: &str,
) -> Res<HttpResponse> {
    let (boundary, body) = scene.multipart();
    let ct = format!("multipart/form-data; boundary={boundary}");
    let auth = format!("Bearer {token}");
    http(
        addr,
        "POST",
        "/v1/sessions",
        &[
            ("Content-Type", &ct),
            ("Authorization", &auth),
            (SESSION_HEADER, id),
        ],
        &body,
    )
    .await
}

/// Whether a refusal means "this backend no longer has, or will not keep, the session":
/// follow it by re-creating the session where its id now routes.
fn means_moved(code: &str) -> bool {
    matches!(code, "shutting_down" | "not_found")
}

/// A session that follows its id across backends behind a routing proxy (a drained or lost
/// server): it holds its scene, sends its id on every request, and when a backend says the
/// session is gone or moving (`shutting_down`, `not_found`, a closed stream, a refused or
/// broken connection, gRPC UNAVAILABLE) re-creates it with the same id wherever the proxy now
/// routes the id, then sends the unanswered frame again. Every frame is answered once.
pub struct MovingSession {
    /// Where the proxy listens.
    pub ep: Endpoint,
    /// Bearer token.
    pub token: String,
    /// The scene the session is (re)created from.
    pub scene: SceneFiles,
    /// The client-chosen id (the routing key).
    pub id: String,
    /// Re-creations so far (the registration restarts cold after each).
    pub moves: usize,
    /// Longest a re-creation may keep failing before the client gives up.
    pub give_up: Duration,
    /// Wait between one frame's result and the next frame (a camera's period; zero: as fast
    /// as results come).
    pub pace: Duration,
}

/// Whether a gRPC status means the session's backend went away (drained, restarted) rather
/// than a refusal: unavailable, not found, unknown or cancelled, or the proxy's own gateway
/// error page (502/503/504) in place of a gRPC response, which tonic reports as an internal
/// protocol error.
pub fn grpc_means_moved(st: &tonic::Status) -> bool {
    match st.code() {
        tonic::Code::Unavailable
        | tonic::Code::NotFound
        | tonic::Code::Unknown
        | tonic::Code::Cancelled => true,
        tonic::Code::Internal => ["status: 502", "status: 503", "status: 504"]
            .iter()
            .any(|s| st.message().contains(s)),
        _ => false,
    }
}

impl MovingSession {
    /// Creates the session over HTTP with a new client-chosen id.
    pub async fn create(ep: impl Into<Endpoint>, token: &str, scene: &SceneFiles) -> Res<Self> {
        let mut s = Self {
            ep: ep.into(),
            token: token.to_string(),
            scene: scene.clone(),
            id: new_client_session_id(),
            moves: 0,
            give_up: Duration::from_secs(60),
            pace: Duration::ZERO,
        };
        s.establish().await?;
        Ok(s)
    }

    /// (Re)creates the session where its id routes: true when a new session was made, false
    /// when it was still open there (409 `session_exists`).
    async fn establish(&mut self) -> Res<bool> {
        let t = Instant::now();
        loop {
            match http_create_session_with_id(&self.ep, &self.token, &self.scene, &self.id).await {
                Ok(r) if r.status == 201 => return Ok(true),
                Ok(r) if r.json()["error"]["code"] == "session_exists" => return Ok(false),
                Ok(r) => {
                    let code = r.json()["error"]["code"].as_str().unwrap_or("").to_string();
                    if !(means_moved(&code) || matches!(r.status, 502..=504)) {
                        return Err(format!(
                            "create {}: {} {}",
                            self.id,
                            r.status,
                            String::from_utf8_lossy(&r.body)
                        ));
                    }
                }
                Err(_) => {} // refused or broken connection: try again
            }
            if t.elapsed() > self.give_up {
                return Err(format!("session {}: no backend took it in time", self.id));
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }

    /// Follows the session after a loss: re-creates it (counted in `moves` when new).
    pub async fn follow(&mut self) -> Res<()> {
        if self.establish().await? {
            self.moves += 1;
        }
        Ok(())
    }

    /// Registers every frame in lock step over WebSocket (binary frames), following the
    /// session across backends; the results in order.
    pub async fn stream_ws(&mut self, frames: &[(String, Vec<[f64; 3]>)]) -> Res<Vec<Value>> {
        let mut results = Vec::with_capacity(frames.len());
        let mut ws: Option<WsClient> = None;
        let mut k = 0;
        let mut attempts = 0;
        while k < frames.len() {
            let (name, pts) = &frames[k];
            if ws.is_none() {
                match WsClient::connect(&self.ep, &self.id, &self.token).await {
                    Ok(c) => ws = Some(c),
                    Err(_) => {
                        attempts += 1;
                        if attempts > 200 {
                            return Err(format!("frame {k}: no stream after {attempts} tries"));
                        }
                        self.follow().await?;
                        continue;
                    }
                }
            }
            let c = ws.as_mut().expect("connected above");
            let answer = match c.send_json(k as u64, name, pts).await {
                Ok(()) => c.next().await,
                Err(_) => None,
            };
            match answer {
                Some(WsEvent::Result(v)) if v["seq"] == k as u64 => {
                    results.push(v);
                    k += 1;
                    attempts = 0;
                    if !self.pace.is_zero() {
                        tokio::time::sleep(self.pace).await;
                    }
                }
                Some(WsEvent::Error(_, code, msg)) if !means_moved(&code) => {
                    return Err(format!("frame {k}: {code}: {msg}"));
                }
                other => {
                    // Closed, moved or gone: this frame was not answered; follow the session.
                    attempts += 1;
                    if attempts > 200 {
                        return Err(format!("frame {k}: still unanswered: {other:?}"));
                    }
                    ws = None;
                    self.follow().await?;
                }
            }
        }
        if let Some(c) = ws {
            c.close().await;
        }
        Ok(results)
    }

    /// Registers every frame over gRPC (unary calls through `g`, a channel to the proxy),
    /// following the session across backends; the results in order.
    pub async fn register_grpc(
        &mut self,
        g: &mut GrpcClient,
        frames: &[(String, Vec<[f64; 3]>)],
    ) -> Res<Vec<proto::FrameResult>> {
        let mut out = Vec::with_capacity(frames.len());
        for (k, (name, pts)) in frames.iter().enumerate() {
            let mut attempts = 0;
            loop {
                match g.register(&self.id, k as u64, name, pts).await {
                    Ok(r) => {
                        out.push(r);
                        if !self.pace.is_zero() {
                            tokio::time::sleep(self.pace).await;
                        }
                        break;
                    }
                    Err(st) if grpc_means_moved(&st) => {
                        attempts += 1;
                        if attempts > 200 {
                            return Err(format!("frame {k}: {st}"));
                        }
                        self.follow().await?;
                    }
                    Err(st) => return Err(format!("frame {k}: {st}")),
                }
            }
        }
        Ok(out)
    }
}
