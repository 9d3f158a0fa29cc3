//! The OpenIGTLink transport of `livereg serve` (`igtl_bind`, default off): 3D Slicer's
//! OpenIGTLinkIF, PLUS, or an AR headset connects over TCP (port 18944 by convention), sends
//! its clouds as POLYDATA or POINT messages, and receives per registered frame a TRANSFORM
//! (`LiverToReference`), a POLYDATA (`DeformedLiver`), a POLYDATA per mesh structure (named
//! after the structure) and a POINT (`Targets`, one element per point of every point
//! structure), all in millimetres. Device names and metadata: docs/openigtlink.md.
//!
//! A connection gets one session per device name of the clouds it sends, built from the scene
//! configured for that device (`igtl_device_scenes`) or the default one (`igtl_scene`), and
//! closed when the connection ends. Frames go through the same admission, newest-frame-wins
//! mailbox, registration slots, metrics and recordings as WebSocket frames. A refused frame
//! or message gets a STATUS naming the problem and the stream goes on; a message whose
//! framing cannot be trusted (bad header, a body over `limits.max_body_bytes`, a short read)
//! gets a STATUS and the connection is closed. Replies use the header version the client
//! last used.
//!
//! OpenIGTLink has no authentication: sessions belong to the owner `openigtlink`, the
//! listener binds to loopback unless TLS is configured or `igtl_allow_remote = true`
//! ([`super::config::ServerConfig::validate`]).

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};

use super::audit::Peer;
use super::auth::Owner;
use super::codec::Incoming;
use super::connections::{ConnectionLimiter, ConnectionLimits};
use super::error::ApiError;
use super::service::AppState;
use super::stream_frames::{admit_frame, next_message, submit_frame, Next, OpenStream};
use super::upload::SceneUpload;
use super::worker::{Completed, SessionHandle, StreamEvent, StreamSink};
use crate::openigtlink::conventions::{
    DEFORMED_LIVER_DEVICE, LIVER_TO_REFERENCE_DEVICE, METADATA_FRAME, METADATA_SESSION,
    METADATA_UNITS, TARGETS_DEVICE, UNITS_MM,
};
use crate::openigtlink::{
    read_frame, status_code, Content, HeaderVersion, IgtlError, Message, Metadata, PointElement,
    PointMessage, PolyDataMessage, StatusMessage, Timestamp, TransformMessage,
};
use crate::recording::SceneFiles;
use crate::scene::load_scene;
use crate::session::Frame;

/// The owner of every OpenIGTLink session (the protocol carries no identity).
pub(crate) const IGTL_OWNER: &str = "openigtlink";

/// Results waiting to be written per connection.
const CONNECTION_BUFFER: usize = 16;

/// The scenes OpenIGTLink sessions are built from, read once at start.
#[derive(Debug, Default)]
pub(crate) struct IgtlScenes {
    default: Option<Arc<SceneUpload>>,
    by_device: HashMap<String, Arc<SceneUpload>>,
    /// Clients speak RAS (3D Slicer's world): x and y change sign both ways.
    ras: bool,
}

impl IgtlScenes {
    /// Reads `default` and every scene of `by_device` (device name → scene file) with the
    /// files they name; an unreadable scene is an error naming its key.
    pub(crate) fn load(
        default: Option<&Path>,
        by_device: &std::collections::BTreeMap<String, std::path::PathBuf>,
        coordinates: super::config::IgtlCoordinates,
    ) -> Result<Self, String> {
        let read = |key: &str, path: &Path| -> Result<Arc<SceneUpload>, String> {
            let loaded = load_scene(path).map_err(|e| format!("{key}: {e}"))?;
            let files = SceneFiles::from_loaded(&loaded).map_err(|e| format!("{key}: {e}"))?;
            // Sessions are built as uploads are, from one self-contained scene: its files by
            // plain names, wherever they were read from (beside the scene, elsewhere, or the
            // model derived from a labelmap, `model.segmentation`, once here).
            let (doc, named) = files
                .self_contained("")
                .map_err(|e| format!("{key}: {e}"))?;
            let named = named
                .into_iter()
                .map(|(name, bytes)| (name, bytes.to_vec()))
                .collect();
            Ok(Arc::new(SceneUpload {
                scene: serde_json::to_string(&doc).map_err(|e| format!("{key}: {e}"))?,
                format: Some(crate::scene::SceneFormat::Json),
                files: named,
                budget_ms: None,
                rigid_only: false,
            }))
        };
        Ok(Self {
            ras: coordinates == super::config::IgtlCoordinates::Ras,
            default: default.map(|p| read("igtl_scene", p)).transpose()?,
            by_device: by_device
                .iter()
                .map(|(d, p)| Ok((d.clone(), read(&format!("igtl_device_scenes.{d}"), p)?)))
                .collect::<Result<_, String>>()?,
        })
    }

    /// The scene for clouds from `device`: its own, else the default.
    fn for_device(&self, device: &str) -> Option<Arc<SceneUpload>> {
        self.by_device
            .get(device)
            .or(self.default.as_ref())
            .cloned()
    }
}

/// Accepts OpenIGTLink connections on `listener` (through TLS when `tls` is given) within
/// `limits` until `shutdown`; each is served by [`serve_connection`].
pub(crate) async fn serve(
    listener: TcpListener,
    state: Arc<AppState>,
    scenes: Arc<IgtlScenes>,
    tls: Option<tokio_rustls::TlsAcceptor>,
    limits: ConnectionLimits,
    mut shutdown: watch::Receiver<bool>,
) -> Result<(), String> {
    let limiter = ConnectionLimiter::new(limits);
    loop {
        let accepted = tokio::select! {
            r = listener.accept() => r,
            _ = shutdown.wait_for(|s| *s) => return Ok(()),
        };
        let (stream, addr) = match accepted {
            Ok(x) => x,
            Err(e) => {
                tracing::warn!(error = %e, "OpenIGTLink accept failed");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let permit = match limiter.admit(addr.ip()) {
            Ok(p) => p,
            Err(refusal) => {
                state
                    .metrics
                    .inc("livereg_connections_refused_total", refusal.label(), 1);
                drop(stream);
                continue;
            }
        };
        let _ = stream.set_nodelay(true);
        let (state, scenes, tls) = (state.clone(), scenes.clone(), tls.clone());
        let opening = limits.header_read_timeout;
        tokio::spawn(async move {
            let _permit = permit;
            match tls {
                None => serve_connection(stream, addr, state, scenes).await,
                Some(acceptor) => {
                    match tokio::time::timeout(opening, acceptor.accept(stream)).await {
                        Ok(Ok(s)) => serve_connection(s, addr, state, scenes).await,
                        Ok(Err(e)) => {
                            tracing::debug!(%addr, error = %e, "OpenIGTLink TLS handshake failed")
                        }
                        Err(_) => tracing::debug!(%addr, "OpenIGTLink TLS handshake timed out"),
                    }
                }
            }
        });
    }
}

/// One device's session on a connection, and where its results go.
struct DeviceSession {
    handle: Arc<SessionHandle>,
    results: StreamSink,
}

/// What the connection's writer sends: encoded messages.
type Outgoing = Vec<u8>;

/// Serves one OpenIGTLink connection until the client closes it, the stream breaks, it
/// stays idle for `limits.stream_idle_timeout_s`, or the server shuts down.
pub(crate) async fn serve_connection<S>(
    io: S,
    addr: SocketAddr,
    state: Arc<AppState>,
    scenes: Arc<IgtlScenes>,
) where
    S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let stream = OpenStream::new(&state, Peer(Some(addr)), IGTL_OWNER);
    let (reader, writer) = tokio::io::split(io);
    let (out_tx, out_rx) = mpsc::channel::<Outgoing>(CONNECTION_BUFFER);
    let write_task = tokio::spawn(write_messages(writer, out_rx));
    stream.audit_open(None, "openigtlink");
    let mut connection = Connection {
        state: &state,
        scenes: &scenes,
        stream: &stream,
        addr,
        owner: Owner(Arc::from(IGTL_OWNER)),
        out: out_tx,
        // The header version of the client's latest message (replies use it).
        version: Arc::new(AtomicU8::new(HeaderVersion::V1 as u8)),
        sessions: HashMap::new(),
        forwarders: Vec::new(),
        counter: 0,
    };
    connection.read_messages(reader).await;
    connection.end_sessions().await;
    drop(connection);
    let _ = write_task.await;
    stream.close(None, "openigtlink");
}

/// The connection's writer: each queued message, flushed, until every sender is gone.
async fn write_messages<W: AsyncWrite + Unpin>(mut writer: W, mut out: mpsc::Receiver<Outgoing>) {
    while let Some(bytes) = out.recv().await {
        if writer.write_all(&bytes).await.is_err() {
            return;
        }
        if writer.flush().await.is_err() {
            return;
        }
    }
    let _ = writer.shutdown().await;
}

/// One OpenIGTLink connection's state: a session per device, created on its first cloud.
struct Connection<'a> {
    state: &'a Arc<AppState>,
    scenes: &'a IgtlScenes,
    stream: &'a OpenStream,
    addr: SocketAddr,
    owner: Owner,
    out: mpsc::Sender<Outgoing>,
    version: Arc<AtomicU8>,
    sessions: HashMap<String, DeviceSession>,
    forwarders: Vec<tokio::task::JoinHandle<()>>,
    /// Clouds received, the sequence number of a cloud that carries none.
    counter: u64,
}

impl Connection<'_> {
    /// Reads messages until the client closes, the stream cannot be trusted, it stays idle
    /// or the server shuts down; each cloud goes to its device's session.
    async fn read_messages<R: AsyncRead + Unpin>(&mut self, mut reader: R) {
        let limits = self.state.config.limits.clone();
        let idle = Duration::from_secs_f64(limits.stream_idle_timeout_s);
        let max_body = limits.max_body_bytes as u64;
        let mut shutdown = self.state.shutdown.clone();
        loop {
            let read = match next_message(read_decoded(&mut reader, max_body), &mut shutdown, idle)
                .await
            {
                Next::Message(r) => r,
                Next::ShuttingDown => break,
                Next::Idle => {
                    let s = status(
                        status_code::TIME_OUT,
                        "idle",
                        format!("nothing received for {} s", limits.stream_idle_timeout_s),
                    );
                    self.send("", s, 0).await;
                    break;
                }
            };
            let received = Instant::now();
            let msg = match read {
                Ok(None) => break,
                Ok(Some(m)) => m,
                Err(e) => {
                    if self.refuse_unreadable(e).await {
                        continue;
                    }
                    break;
                }
            };
            self.version
                .store(m_version(&msg.version), Ordering::Relaxed);
            let Some(points) = self.cloud_of(&msg.message).await else {
                continue;
            };
            self.take_cloud(msg.message, points, received).await;
        }
    }

    /// Answers a message that could not be read with a STATUS; whether the stream is still
    /// in step (true: read on; false: the connection closes).
    async fn refuse_unreadable(&self, e: IgtlError) -> bool {
        self.state
            .metrics
            .inc("livereg_igtl_messages_total", "refused", 1);
        let device = match &e {
            IgtlError::UnsupportedMessageType { device_name, .. } => device_name.clone(),
            _ => String::new(),
        };
        self.send(&device, e.to_status(), 0).await;
        if e.keeps_stream_in_sync() {
            return true;
        }
        tracing::info!(addr = %self.addr, error = %e, "OpenIGTLink connection closed: the stream cannot be trusted");
        false
    }

    /// The cloud a message carries (POLYDATA, POINT), in the client's millimetres; `None`
    /// for an acknowledgement (STATUS, not answered) or a TRANSFORM (answered with a STATUS).
    async fn cloud_of(&self, message: &Message) -> Option<Vec<Point3<f64>>> {
        match &message.content {
            Content::PolyData(p) => Some(p.to_point_cloud()),
            Content::Point(p) => Some(p.positions()),
            // Acknowledgements a client may send; nothing to answer.
            Content::Status(_) => None,
            Content::Transform(_) => {
                self.state
                    .metrics
                    .inc("livereg_igtl_messages_total", "refused", 1);
                let s = status(
                    status_code::UNKNOWN_INSTRUCTION,
                    "unexpected",
                    "livereg takes clouds as POLYDATA or POINT; a TRANSFORM is not an input",
                );
                self.send(&message.device_name, s, message.message_id).await;
                None
            }
        }
    }

    /// One cloud of `message`'s device: its sequence number (the `livereg.frame` metadata,
    /// else the message id, else the connection's count), the device's session, and the
    /// shared admission ([`admit_frame`]) and submission; a refusal is answered with a STATUS.
    async fn take_cloud(&mut self, message: Message, points: Vec<Point3<f64>>, received: Instant) {
        let state = self.state;
        state.metrics.inc("livereg_igtl_messages_total", "cloud", 1);
        self.counter += 1;
        let device = message.device_name.clone();
        let seq = message
            .metadata
            .get(METADATA_FRAME)
            .and_then(|v| v.trim().parse::<u64>().ok())
            .unwrap_or(if message.message_id != 0 {
                u64::from(message.message_id)
            } else {
                self.counter
            });
        if !self.has_session(&device, message.message_id).await {
            return;
        }
        let ds = &self.sessions[&device];
        let scale_to_scene = 1e-3 / ds.handle.info.length_scale;
        let ras = self.scenes.ras;
        let frame = async {
            Ok(Incoming {
                seq,
                frame: Frame {
                    source: format!("igtl-{device}-{seq}"),
                    points: points
                        .iter()
                        .map(|p| flip(p, ras) * scale_to_scene)
                        .collect(),
                    camera: None,
                },
            })
        };
        match admit_frame(state, &ds.handle, seq, frame).await {
            Ok(incoming) => submit_frame(state, &ds.handle, incoming, received, &ds.results),
            Err((_, e)) => {
                let e = state.count(e);
                self.send(&device, api_status(&e), seq as u32).await;
            }
        }
    }

    /// Whether `device` has a session: the one it has (unless it was retired meanwhile, by
    /// the idle timeout or the watchdog), or a new one with its result forwarder (audited);
    /// when none can be made, the cause is answered with a STATUS of message `id`.
    async fn has_session(&mut self, device: &str, id: u32) -> bool {
        if let Some(ds) = self.sessions.get(device) {
            if self.state.registry.get(&self.owner, &ds.handle.id).is_ok() {
                return true;
            }
            self.sessions.remove(device);
        }
        match open_session(self.state, &self.owner, self.scenes, device).await {
            Ok(h) => {
                self.stream
                    .audit_open(Some(&h.id), &format!("openigtlink device {device:?}"));
                let (tx, rx) = mpsc::channel::<StreamEvent>(CONNECTION_BUFFER);
                self.forwarders.push(tokio::spawn(forward_results(
                    rx,
                    h.clone(),
                    device.to_string(),
                    self.out.clone(),
                    self.version.clone(),
                    self.scenes.ras,
                )));
                let results = StreamSink {
                    tx,
                    skipped: Arc::new(AtomicU64::new(0)),
                };
                self.sessions
                    .insert(device.to_string(), DeviceSession { handle: h, results });
                true
            }
            Err(e) => {
                let e = self.state.count(e);
                self.send(device, api_status(&e), id).await;
                false
            }
        }
    }

    /// Frames in flight finish and are sent; then the device sessions close.
    async fn end_sessions(&mut self) {
        let ended: Vec<Arc<SessionHandle>> =
            self.sessions.values().map(|d| d.handle.clone()).collect();
        self.sessions.clear();
        for f in self.forwarders.drain(..) {
            let _ = f.await;
        }
        for h in ended {
            if let Ok(h) = self.state.registry.remove(&self.owner, &h.id) {
                self.state.retire(&h, "client");
            }
        }
    }

    /// Queues a STATUS for the writer (see [`send`]).
    async fn send(&self, device: &str, s: StatusMessage, id: u32) {
        send(&self.out, &self.version, device, s, id).await;
    }
}

/// Reads one message; a body over [`super::service::INLINE_DECODE_BYTES`] is decoded on the
/// blocking pool, so that big clouds never stall the network threads.
async fn read_decoded<R: AsyncRead + Unpin>(
    reader: &mut R,
    max_body: u64,
) -> Result<Option<crate::openigtlink::ReceivedMessage>, IgtlError> {
    let Some(frame) = read_frame(reader, max_body).await? else {
        return Ok(None);
    };
    if frame.body.len() <= super::service::INLINE_DECODE_BYTES {
        return frame.decode().map(Some);
    }
    tokio::task::spawn_blocking(move || frame.decode())
        .await
        .map_err(|e| IgtlError::Io(std::io::Error::other(format!("decoding task: {e}"))))?
        .map(Some)
}

/// The header version as stored in the connection's atomic.
fn m_version(v: &HeaderVersion) -> u8 {
    v.as_u16() as u8
}

/// Creates the session for clouds of `device`.
async fn open_session(
    state: &Arc<AppState>,
    owner: &Owner,
    scenes: &IgtlScenes,
    device: &str,
) -> Result<Arc<SessionHandle>, ApiError> {
    let upload = scenes.for_device(device).ok_or_else(|| {
        ApiError::not_found(format!(
            "no scene is configured for device {device:?} (igtl_scene, igtl_device_scenes)"
        ))
    })?;
    let info = state.create_session(owner, (*upload).clone(), None).await?;
    state.session(owner, &info.id)
}

/// Sends each result of a device's session as TRANSFORM, POLYDATA and POINT messages, and
/// each refusal as a STATUS, until the session's senders are gone.
async fn forward_results(
    mut rx: mpsc::Receiver<StreamEvent>,
    handle: Arc<SessionHandle>,
    device: String,
    out: mpsc::Sender<Outgoing>,
    version: Arc<AtomicU8>,
    ras: bool,
) {
    while let Some(ev) = rx.recv().await {
        let v = current_version(&version);
        let encoded = match ev {
            StreamEvent::Result(c) => result_messages(&c, &handle, ras)
                .into_iter()
                .map(|mut m| {
                    // Header version 1 carries no metadata.
                    if v == HeaderVersion::V1 {
                        m.metadata = Metadata::new();
                    }
                    m.encode(v)
                })
                .collect::<Result<Vec<_>, _>>()
                .map(|parts| parts.concat()),
            StreamEvent::Error { seq, error } => {
                status_message(&device, api_status(&error), seq as u32).encode(v)
            }
        };
        match encoded {
            Ok(bytes) => {
                if out.send(bytes).await.is_err() {
                    return;
                }
            }
            Err(e) => {
                tracing::warn!(session = %handle.id, error = %e, "cannot encode an OpenIGTLink result")
            }
        }
    }
}

fn current_version(v: &AtomicU8) -> HeaderVersion {
    HeaderVersion::from_u16(u16::from(v.load(Ordering::Relaxed))).unwrap_or(HeaderVersion::V1)
}

/// The messages of one result, millimetres: TRANSFORM `LiverToReference` (model → cloud),
/// POLYDATA `DeformedLiver`, a POLYDATA per mesh structure, POINT `Targets` (every point of
/// the point structures, named `<structure>-<k>`, grouped by structure), and a STATUS when
/// the frame failed (the positions are then the last good state's).
pub(crate) fn result_messages(c: &Completed, handle: &SessionHandle, ras: bool) -> Vec<Message> {
    let r = &c.result;
    let to_mm = handle.info.length_scale * 1e3;
    let mm = |ps: &[Point3<f64>]| -> Vec<Point3<f64>> {
        ps.iter().map(|p| flip(&(p * to_mm), ras)).collect()
    };
    let meta = |m: &mut Message| {
        m.message_id = c.seq as u32;
        m.timestamp = Timestamp::now();
        let mut md = Metadata::new();
        md.insert(METADATA_SESSION, handle.id.clone());
        md.insert(METADATA_FRAME, c.seq.to_string());
        md.insert(METADATA_UNITS, UNITS_MM);
        md.insert("livereg.converged", r.converged.to_string());
        md.insert("livereg.server_ms", format!("{:.3}", c.server_ms));
        if let Some(u) = r.pose_uncertainty {
            md.insert("livereg.pose_uncertainty_mm", format!("{:.6}", u * to_mm));
        }
        if let Some(e) = &r.expected_error {
            md.insert(
                "livereg.expected_error_mm",
                format!("{:.6}", e.expected * to_mm),
            );
        }
        if !r.flags.is_empty() {
            md.insert(
                "livereg.flags",
                crate::session::flag_texts(&r.flags).join(","),
            );
        }
        m.metadata = md;
    };
    let mut out = Vec::new();
    let t = &r.model_to_cloud;
    // In RAS, both the model's and the reference's coordinates: F T F, F = diag(−1, −1, 1).
    let f = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(-1.0, -1.0, 1.0));
    let (rotation, translation) = if ras {
        (
            nalgebra::Rotation3::from_matrix_unchecked(f * t.rotation.matrix() * f),
            f * t.translation * 1e3,
        )
    } else {
        (t.rotation, t.translation * 1e3)
    };
    let iso = Isometry3::from_parts(
        Translation3::from(translation),
        UnitQuaternion::from_rotation_matrix(&rotation),
    );
    out.push(Message::new(
        LIVER_TO_REFERENCE_DEVICE,
        TransformMessage::from_isometry(&iso),
    ));
    let meshes = &handle.info.meshes;
    if let Ok(p) = PolyDataMessage::from_triangles(mm(&r.surface), &meshes.surface) {
        out.push(Message::new(DEFORMED_LIVER_DEVICE, p));
    }
    let mut targets = Vec::new();
    for (k, (name, points)) in r.structures.iter().enumerate() {
        match meshes.structures.get(k).and_then(|t| t.as_ref()) {
            Some(tris) => {
                if let Ok(p) = PolyDataMessage::from_triangles(mm(points), tris) {
                    out.push(Message::new(device_name(name), p));
                }
            }
            None => {
                for (i, p) in mm(points).into_iter().enumerate() {
                    let mut e = PointElement::new(truncate(&format!("{name}-{i}"), 63), p);
                    e.group = truncate(name, 31);
                    targets.push(e);
                }
            }
        }
    }
    if !targets.is_empty() {
        out.push(Message::new(
            TARGETS_DEVICE,
            PointMessage { points: targets },
        ));
    }
    if let Some(e) = &r.error {
        out.push(Message::new(
            DEFORMED_LIVER_DEVICE,
            status(
                status_code::UNKNOWN_ERROR,
                "frame_failed",
                format!("{e}; the last good state is sent"),
            ),
        ));
    }
    for m in &mut out {
        meta(m);
    }
    out
}

/// `p` turned between LPS and RAS (x and y change sign) when `ras`.
fn flip(p: &Point3<f64>, ras: bool) -> Point3<f64> {
    if ras {
        Point3::new(-p.x, -p.y, p.z)
    } else {
        *p
    }
}

/// A device name for structure `name`: printable ASCII, at most 20 bytes.
fn device_name(name: &str) -> String {
    let ascii: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_graphic() || c == ' ' {
                c
            } else {
                '_'
            }
        })
        .collect();
    let t = truncate(ascii.trim(), 20);
    if t.is_empty() {
        "Structure".into()
    } else {
        t
    }
}

/// `s` cut to at most `max` bytes at a character boundary.
fn truncate(s: &str, max: usize) -> String {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    s[..end].to_string()
}

/// A STATUS with `code`, error name (at most 20 bytes) and message.
fn status(code: u16, name: &str, message: impl Into<String>) -> StatusMessage {
    StatusMessage {
        code,
        subcode: 0,
        error_name: truncate(name, 20),
        message: message.into(),
    }
}

/// The STATUS answering an API error: its stable code as the error name.
fn api_status(e: &ApiError) -> StatusMessage {
    let code = match e.code {
        "rate_limited" | "too_many_sessions" | "server_busy" | "memory_budget" => status_code::BUSY,
        "shutting_down" => status_code::SHUT_DOWN,
        "not_found" | "unknown_session" => status_code::NOT_FOUND,
        "payload_too_large" | "frame_too_large" | "work_too_large" | "model_too_large"
        | "too_many_points" | "mesh_too_large" | "grid_too_large" => status_code::OVERFLOW,
        "invalid_frame" | "bad_request" | "invalid_scene" => status_code::CONFIG_ERROR,
        _ => status_code::UNKNOWN_ERROR,
    };
    status(code, e.code, e.message.clone())
}

fn status_message(device: &str, s: StatusMessage, id: u32) -> Message {
    let mut m = Message::new(device, s);
    m.message_id = id;
    m.timestamp = Timestamp::now();
    m
}

/// Queues a STATUS for the writer.
async fn send(
    out: &mpsc::Sender<Outgoing>,
    version: &AtomicU8,
    device: &str,
    s: StatusMessage,
    id: u32,
) {
    if let Ok(bytes) = status_message(device, s, id).encode(current_version(version)) {
        let _ = out.send(bytes).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{IgtlCoordinates, LimitsConfig};

    /// A 40³ NRRD of 1.5 mm voxels: label 1 a ball of radius 24 mm, label 2 a ball of 5 mm
    /// inside it (written byte by byte from the NRRD specification).
    fn write_labelmap(path: &Path) {
        let n = 40usize;
        let mut bytes = format!(
            "NRRD0004\ntype: uint8\ndimension: 3\nspace: left-posterior-superior\nsizes: {n} {n} {n}\n\
             space directions: (1.5,0,0) (0,1.5,0) (0,0,1.5)\nkinds: domain domain domain\n\
             encoding: raw\nspace origin: (-30,-30,-30)\n\n"
        )
        .into_bytes();
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let p = [i, j, k].map(|c| c as f64 * 1.5 - 30.0);
                    let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                    let t = ((p[0] - 8.0).powi(2) + p[1] * p[1] + p[2] * p[2]).sqrt();
                    bytes.push(if t <= 5.0 {
                        2
                    } else if r <= 24.0 {
                        1
                    } else {
                        0
                    });
                }
            }
        }
        std::fs::write(path, bytes).unwrap();
    }

    #[test]
    fn a_configured_scene_may_derive_its_model_from_a_labelmap() {
        let dir = std::env::temp_dir().join(format!("livereg-igtl-seg-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let sub = dir.join("segmentations");
        std::fs::create_dir_all(&sub).unwrap();
        // The labelmap is not beside the scene: an operator's files sit where they are.
        write_labelmap(&sub.join("patient seg.nrrd"));
        let scene = dir.join("scene.toml");
        std::fs::write(
            &scene,
            "units = \"mm\"\n[model]\nsegmentation = \"segmentations/patient seg.nrrd\"\n\
             label = 1\ntarget_triangles = 2000\n[[model.structures]]\nname = \"tumour\"\n\
             mesh_label = 2\n[grid]\ncell_size = 12.0\nsubdivisions = 1\n\
             [material]\nlaw = \"linear\"\nyoung_modulus = 4500.0\npoisson_ratio = 0.45\n\
             [[boundary.fixed]]\nbox = [[-40.0, -40.0, -40.0], [-16.0, 40.0, 40.0]]\n",
        )
        .unwrap();
        let scenes =
            IgtlScenes::load(Some(&scene), &Default::default(), IgtlCoordinates::Lps).unwrap();
        let upload = scenes.for_device("AnyDevice").unwrap();
        assert!(!upload.scene.contains("segmentation"), "{}", upload.scene);
        // The session's scene, built as the server builds it, holds the derived model.
        let built = super::super::upload::materialize(
            &upload,
            &dir.join("session"),
            &LimitsConfig::default(),
        )
        .unwrap();
        let direct = load_scene(&scene).unwrap();
        let read = |s: &crate::scene::LoadedScene| {
            crate::mesh::read_surface(&s.scene.model.surface).unwrap()
        };
        assert_eq!(read(&built).vertices, read(&direct).vertices);
        assert_eq!(read(&built).triangles, read(&direct).triangles);
        let tumour = |s: &crate::scene::LoadedScene| {
            let m = s.scene.model.structures[0].mesh.clone().unwrap();
            crate::mesh::read_surface(&m).unwrap().vertices.len()
        };
        assert!(tumour(&built) > 0);
        assert_eq!(tumour(&built), tumour(&direct));
        std::fs::remove_dir_all(&dir).ok();
    }
}
