//! gRPC (tonic) front end: the operations of the HTTP API on `proto/livereg/v1/registration.proto`,
//! including the bidirectional `Stream`. Every call needs `authorization: Bearer <token>`.
//!
//! Malformed protobuf is answered `INVALID_ARGUMENT` (tonic's own codec says `INTERNAL`; the
//! generated code uses [`Codec`], which wraps it).

use std::sync::atomic::AtomicU64;
use std::sync::Arc;
use std::time::Instant;

use tokio::sync::{mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tonic::codec::{BufferSettings, DecodeBuf, Decoder, EncodeBuf, Encoder};
use tonic::{Request, Response, Status, Streaming};

use super::audit::{self, Action, Peer};
use super::auth::Owner;
use super::codec::{decode_proto_frame, ResultMessage};
use super::error::ApiError;
use super::proto;
use super::registry::{requested_session_id, SessionInfo, SESSION_HEADER};
use super::service::AppState;
use super::stream_frames::{admit_frame, next_message, submit_frame, Next, OpenStream};
use super::upload::SceneUpload;
use super::worker::{SessionHandle, StreamEvent, StreamSink};
use crate::scene::SceneFormat;

/// The protobuf codec of the generated code: tonic-prost's, with decode errors answered
/// `INVALID_ARGUMENT` naming the problem.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Codec<T, U>(std::marker::PhantomData<(T, U)>);

/// Decoder half of [`Codec`].
#[derive(Debug)]
pub(crate) struct CheckedDecoder<U>(tonic_prost::ProstDecoder<U>);

impl<U: prost::Message + Default> Decoder for CheckedDecoder<U> {
    type Item = U;
    type Error = Status;

    fn decode(&mut self, buf: &mut DecodeBuf<'_>) -> Result<Option<U>, Status> {
        self.0.decode(buf).map_err(|s| {
            if s.code() == tonic::Code::Internal {
                Status::invalid_argument(format!(
                    "bad_request: malformed protobuf message: {}",
                    s.message()
                ))
            } else {
                s
            }
        })
    }

    fn buffer_settings(&self) -> BufferSettings {
        self.0.buffer_settings()
    }
}

/// Encoder half of [`Codec`].
#[derive(Debug)]
pub(crate) struct PlainEncoder<T>(tonic_prost::ProstEncoder<T>);

impl<T: prost::Message> Encoder for PlainEncoder<T> {
    type Item = T;
    type Error = Status;

    fn encode(&mut self, item: T, buf: &mut EncodeBuf<'_>) -> Result<(), Status> {
        self.0.encode(item, buf)
    }

    fn buffer_settings(&self) -> BufferSettings {
        self.0.buffer_settings()
    }
}

impl<T, U> tonic::codec::Codec for Codec<T, U>
where
    T: prost::Message + Send + 'static,
    U: prost::Message + Default + Send + 'static,
{
    type Encode = T;
    type Decode = U;
    type Encoder = PlainEncoder<T>;
    type Decoder = CheckedDecoder<U>;

    fn encoder(&mut self) -> Self::Encoder {
        PlainEncoder(tonic::codec::Codec::encoder(
            &mut tonic_prost::ProstCodec::<T, U>::default(),
        ))
    }

    fn decoder(&mut self) -> Self::Decoder {
        CheckedDecoder(tonic::codec::Codec::decoder(
            &mut tonic_prost::ProstCodec::<T, U>::default(),
        ))
    }
}

/// The gRPC service.
#[derive(Debug, Clone)]
pub(crate) struct GrpcService {
    state: Arc<AppState>,
}

impl GrpcService {
    /// The service over the shared state.
    pub(crate) fn new(state: Arc<AppState>) -> Self {
        Self { state }
    }

    fn owner<T>(&self, req: &Request<T>) -> Result<Owner, Status> {
        let header = req.metadata().get("authorization").map(|v| v.as_bytes());
        self.state.auth.authenticate(header).map_err(|e| {
            audit::event(
                Action::Authenticate,
                e.code,
                Peer(req.remote_addr()),
                None,
                None,
                &format!("grpc: {}", e.message),
            );
            self.state.count(e).to_status()
        })
    }

    fn err(&self, e: ApiError) -> Status {
        self.state.count(e).to_status()
    }

    /// `CreateSession` after authentication: the upload, then the session.
    async fn create_session_from(
        &self,
        owner: &Owner,
        r: proto::CreateSessionRequest,
        requested_id: Option<&str>,
    ) -> Result<SessionInfo, ApiError> {
        let format = match r.scene_format.to_ascii_lowercase().as_str() {
            "" | "toml" => SceneFormat::Toml,
            "json" => SceneFormat::Json,
            other => {
                return Err(ApiError::bad_request(format!(
                    "scene_format must be \"toml\" or \"json\", got {other:?}"
                )))
            }
        };
        let upload = SceneUpload {
            scene: r.scene,
            format: Some(format),
            files: r.files.into_iter().collect(),
            budget_ms: r.budget_ms,
            rigid_only: r.rigid_only,
        };
        self.state.create_session(owner, upload, requested_id).await
    }
}

fn info_proto(i: SessionInfo) -> proto::SessionInfo {
    proto::SessionInfo {
        id: i.id,
        units: i.units,
        surface_vertices: i.surface_vertices as u32,
        surface_triangles: i.surface_triangles as u32,
        structures: i.structures,
        frames_registered: i.frames_registered,
        frames_skipped: i.frames_skipped,
        frames_rejected: i.frames_rejected,
        age_s: i.age_s,
        warm: i.warm,
    }
}

fn result_proto(c: &super::worker::Completed, h: &SessionHandle) -> proto::FrameResult {
    let cause = c.result.error.as_ref().map(|e| e.cause()).unwrap_or("");
    ResultMessage::new(
        c.seq,
        c.skipped,
        c.server_ms,
        c.queue_ms,
        &c.result,
        h.info.length_scale,
    )
    .to_proto(cause)
}

#[tonic::async_trait]
impl proto::registration_server::Registration for GrpcService {
    async fn create_session(
        &self,
        req: Request<proto::CreateSessionRequest>,
    ) -> Result<Response<proto::SessionInfo>, Status> {
        let owner = self.owner(&req)?;
        let peer = Peer(req.remote_addr());
        let requested =
            requested_session_id(req.metadata().get(SESSION_HEADER).map(|v| v.as_bytes()))
                .map_err(|e| self.err(e))?;
        let r = self
            .create_session_from(&owner, req.into_inner(), requested.as_deref())
            .await;
        audit::event(
            Action::CreateSession,
            audit::outcome(&r),
            peer,
            Some(owner.name()),
            r.as_ref().ok().map(|i| i.id.as_str()),
            r.as_ref().err().map_or("grpc", |e| e.message.as_str()),
        );
        let info = r.map_err(|e| self.err(e))?;
        Ok(Response::new(info_proto(info)))
    }

    async fn get_session(
        &self,
        req: Request<proto::SessionRef>,
    ) -> Result<Response<proto::SessionInfo>, Status> {
        let owner = self.owner(&req)?;
        let h = self
            .state
            .session(&owner, &req.get_ref().id)
            .map_err(|e| self.err(e))?;
        Ok(Response::new(info_proto(SessionInfo::of(&h))))
    }

    async fn close_session(
        &self,
        req: Request<proto::SessionRef>,
    ) -> Result<Response<proto::CloseSessionResponse>, Status> {
        let owner = self.owner(&req)?;
        let id = &req.get_ref().id;
        let r = self.state.close_session(&owner, id);
        audit::event(
            Action::CloseSession,
            audit::outcome(&r),
            Peer(req.remote_addr()),
            Some(owner.name()),
            Some(id),
            "grpc",
        );
        let i = r.map_err(|e| self.err(e))?;
        Ok(Response::new(proto::CloseSessionResponse {
            id: i.id,
            frames_registered: i.frames_registered,
        }))
    }

    async fn register(
        &self,
        req: Request<proto::RegisterRequest>,
    ) -> Result<Response<proto::FrameResult>, Status> {
        let owner = self.owner(&req)?;
        let r = req.into_inner();
        let h = self
            .state
            .session(&owner, &r.session_id)
            .map_err(|e| self.err(e))?;
        let frame = r
            .frame
            .ok_or_else(|| self.err(ApiError::bad_request("the request has no `frame`")))?;
        self.state.admit_rate(&h).map_err(|e| self.err(e))?;
        let incoming = decode_proto_frame(frame, self.state.config.limits.max_frame_points)
            .map_err(|e| {
                self.state.reject(&h, &e);
                self.err(e)
            })?;
        let (_, done) = self
            .state
            .register_once(&owner, &r.session_id, incoming)
            .await
            .map_err(|e| self.err(e))?;
        Ok(Response::new(result_proto(&done, &h)))
    }

    type StreamStream = ReceiverStream<Result<proto::StreamResponse, Status>>;

    async fn stream(
        &self,
        req: Request<Streaming<proto::StreamRequest>>,
    ) -> Result<Response<Self::StreamStream>, Status> {
        let owner = self.owner(&req)?;
        if self.state.is_draining() {
            return Err(self.err(ApiError::shutting_down()));
        }
        let peer = Peer(req.remote_addr());
        let inbound = req.into_inner();
        let (out_tx, out_rx) = mpsc::channel(8);
        tokio::spawn(run_stream(self.state.clone(), owner, peer, inbound, out_tx));
        Ok(Response::new(ReceiverStream::new(out_rx)))
    }
}

fn error_response(seq: u64, e: &ApiError) -> proto::StreamResponse {
    proto::StreamResponse {
        kind: Some(proto::stream_response::Kind::Error(proto::StreamError {
            code: e.code.to_string(),
            message: e.message.clone(),
            seq,
        })),
    }
}

/// One gRPC stream: bound to the session its first message names, each frame through the
/// shared admission ([`admit_frame`]) to that session, results and refusals forwarded as they
/// come, until the client ends the stream, the session is gone, the stream stays idle or the
/// server shuts down.
async fn run_stream(
    state: Arc<AppState>,
    owner: Owner,
    peer: Peer,
    mut inbound: Streaming<proto::StreamRequest>,
    out: mpsc::Sender<Result<proto::StreamResponse, Status>>,
) {
    let stream = OpenStream::new(&state, peer, owner.name());
    let (ev_tx, ev_rx) = mpsc::channel::<StreamEvent>(8);
    let results = StreamSink {
        tx: ev_tx,
        skipped: Arc::new(AtomicU64::new(0)),
    };
    let (bound_tx, bound_rx) = watch::channel::<Option<Arc<SessionHandle>>>(None);
    let forward = tokio::spawn(forward_results(ev_rx, bound_rx, out.clone()));
    let reader = StreamReader {
        state: &state,
        owner: &owner,
        stream: &stream,
        results: &results,
        out: &out,
    };
    let bound = reader.read_frames(&mut inbound, &bound_tx).await;
    drop(results);
    let _ = forward.await;
    if let Some(h) = &bound {
        stream.close(Some(&h.id), "grpc");
    }
}

/// Sends each result (of the session `bound` names once the stream is bound) and each
/// refusal to the client, in order, until every sender is gone or the client left.
async fn forward_results(
    mut events: mpsc::Receiver<StreamEvent>,
    mut bound: watch::Receiver<Option<Arc<SessionHandle>>>,
    out: mpsc::Sender<Result<proto::StreamResponse, Status>>,
) {
    while let Some(ev) = events.recv().await {
        let msg = match ev {
            StreamEvent::Result(c) => {
                let h = bound.borrow_and_update().clone();
                let Some(h) = h else { continue };
                proto::StreamResponse {
                    kind: Some(proto::stream_response::Kind::Result(result_proto(&c, &h))),
                }
            }
            StreamEvent::Error { seq, error } => error_response(seq, &error),
        };
        if out.send(Ok(msg)).await.is_err() {
            break;
        }
    }
}

/// What a gRPC stream's reader works with.
struct StreamReader<'a> {
    state: &'a Arc<AppState>,
    owner: &'a Owner,
    stream: &'a OpenStream,
    results: &'a StreamSink,
    out: &'a mpsc::Sender<Result<proto::StreamResponse, Status>>,
}

/// What to do with a stream after a request.
enum Then<T> {
    /// Go on with this.
    Go(T),
    /// Wait for the next request.
    Next,
    /// End the stream.
    End,
}

impl StreamReader<'_> {
    /// Reads requests until the stream ends; returns the session it was bound to, if any.
    async fn read_frames(
        &self,
        inbound: &mut Streaming<proto::StreamRequest>,
        bound_tx: &watch::Sender<Option<Arc<SessionHandle>>>,
    ) -> Option<Arc<SessionHandle>> {
        let state = self.state;
        let mut shutdown = state.shutdown.clone();
        let idle = std::time::Duration::from_secs_f64(state.config.limits.stream_idle_timeout_s);
        let mut bound: Option<Arc<SessionHandle>> = None;
        loop {
            let msg = match next_message(inbound.message(), &mut shutdown, idle).await {
                Next::Message(m) => m,
                Next::ShuttingDown => break,
                Next::Idle => {
                    // Nothing received for the idle timeout: the stream ends with its reason.
                    let _ = self
                        .out
                        .send(Err(Status::deadline_exceeded(format!(
                            "idle: no message on this stream for {} s (limits.stream_idle_timeout_s)",
                            state.config.limits.stream_idle_timeout_s
                        ))))
                        .await;
                    break;
                }
            };
            let received = Instant::now();
            let req = match msg {
                Ok(Some(r)) => r,
                Ok(None) => break,
                Err(status) => {
                    // A malformed message or a broken transport ends the stream with its status.
                    if status.code() != tonic::Code::Cancelled {
                        state.metrics.inc("livereg_errors_total", "bad_request", 1);
                        let _ = self.out.send(Err(status)).await;
                    }
                    break;
                }
            };
            let handle = match self.session_of(&req, &mut bound, bound_tx).await {
                Then::Go(h) => h,
                Then::Next => continue,
                Then::End => break,
            };
            if state.registry.get(self.owner, &handle.id).is_err() {
                let e = state.count(ApiError::unknown_session(&handle.id));
                let _ = self.out.send(Err(e.to_status())).await;
                break;
            }
            let admitted = match req.frame {
                None => Err((0, ApiError::bad_request("the message has no `frame`"))),
                Some(f) => {
                    let seq = f.seq;
                    let max_points = state.config.limits.max_frame_points;
                    let decode = async {
                        decode_proto_frame(f, max_points).inspect_err(|e| state.reject(&handle, e))
                    };
                    admit_frame(state, &handle, seq, decode).await
                }
            };
            match admitted {
                Ok(frame) => submit_frame(state, &handle, frame, received, self.results),
                Err((seq, e)) => {
                    let ev = StreamEvent::Error {
                        seq,
                        error: state.count(e),
                    };
                    if self.results.tx.send(ev).await.is_err() {
                        break;
                    }
                }
            }
        }
        bound
    }

    /// The session `req` is for: the stream's `bound` one (a request naming another is
    /// refused on the stream), or, on the first request, the one it names, bound from then
    /// on (audited, and told to the forwarder through `bound_tx`); a session that cannot be
    /// had ends the stream with its status.
    async fn session_of(
        &self,
        req: &proto::StreamRequest,
        bound: &mut Option<Arc<SessionHandle>>,
        bound_tx: &watch::Sender<Option<Arc<SessionHandle>>>,
    ) -> Then<Arc<SessionHandle>> {
        match bound {
            Some(h) if req.session_id.is_empty() || req.session_id == h.id => Then::Go(h.clone()),
            Some(h) => {
                let e = self.state.count(ApiError::bad_request(format!(
                    "this stream is bound to session `{}`; open another stream for `{}`",
                    h.id,
                    req.session_id.chars().take(64).collect::<String>()
                )));
                let _ = self
                    .results
                    .tx
                    .send(StreamEvent::Error {
                        seq: req.frame.as_ref().map(|f| f.seq).unwrap_or(0),
                        error: e,
                    })
                    .await;
                Then::Next
            }
            None => match self.state.session(self.owner, &req.session_id) {
                Ok(h) => {
                    self.stream.audit_open(Some(&h.id), "grpc");
                    *bound = Some(h.clone());
                    let _ = bound_tx.send(Some(h.clone()));
                    Then::Go(h)
                }
                Err(e) => {
                    let _ = self.out.send(Err(self.state.count(e).to_status())).await;
                    Then::End
                }
            },
        }
    }
}
