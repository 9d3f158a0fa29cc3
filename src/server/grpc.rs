//! gRPC (tonic) front end: the operations of the HTTP API on `proto/livereg/v1/registration.proto`,
//! including the bidirectional `Stream`. Every call needs `authorization: Bearer <token>`.
//!
//! Malformed protobuf is answered `INVALID_ARGUMENT` (tonic's own codec says `INTERNAL`; the
//! generated code uses [`Codec`], which wraps it).

use std::sync::atomic::AtomicU64;
use std::sync::Arc;
use std::time::Instant;

use tokio::sync::mpsc;
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
use super::upload::SceneUpload;
use super::worker::{Job, Reply, SessionHandle, StreamEvent, StreamSink};
use crate::scene::SceneFormat;

/// The protobuf codec of the generated code: tonic-prost's, with decode errors answered
/// `INVALID_ARGUMENT` naming the problem.
#[derive(Debug, Clone, Copy, Default)]
pub struct Codec<T, U>(std::marker::PhantomData<(T, U)>);

/// Decoder half of [`Codec`].
#[derive(Debug)]
pub struct CheckedDecoder<U>(tonic_prost::ProstDecoder<U>);

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
pub struct PlainEncoder<T>(tonic_prost::ProstEncoder<T>);

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
pub struct GrpcService {
    state: Arc<AppState>,
}

impl GrpcService {
    /// The service over the shared state.
    pub fn new(state: Arc<AppState>) -> Self {
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

async fn run_stream(
    state: Arc<AppState>,
    owner: Owner,
    peer: Peer,
    mut inbound: Streaming<proto::StreamRequest>,
    out: mpsc::Sender<Result<proto::StreamResponse, Status>>,
) {
    let _guard = state.stream_guard();
    let (ev_tx, mut ev_rx) = mpsc::channel::<StreamEvent>(8);
    let skipped = Arc::new(AtomicU64::new(0));
    let mut bound: Option<Arc<SessionHandle>> = None;
    let (bound_tx, mut bound_rx) = tokio::sync::watch::channel::<Option<Arc<SessionHandle>>>(None);
    let fwd_out = out.clone();
    let forward = tokio::spawn(async move {
        while let Some(ev) = ev_rx.recv().await {
            let msg = match ev {
                StreamEvent::Result(c) => {
                    let h = bound_rx.borrow_and_update().clone();
                    let Some(h) = h else { continue };
                    proto::StreamResponse {
                        kind: Some(proto::stream_response::Kind::Result(result_proto(&c, &h))),
                    }
                }
                StreamEvent::Error { seq, error } => error_response(seq, &error),
            };
            if fwd_out.send(Ok(msg)).await.is_err() {
                break;
            }
        }
    });
    let mut shutdown = state.shutdown.clone();
    let idle = std::time::Duration::from_secs_f64(state.config.limits.stream_idle_timeout_s);
    loop {
        let msg = tokio::select! {
            m = inbound.message() => Some(m),
            _ = shutdown.wait_for(|s| *s) => break,
            _ = tokio::time::sleep(idle) => None,
        };
        let Some(msg) = msg else {
            // Nothing received for the idle timeout: the stream ends with its reason.
            let _ = out
                .send(Err(Status::deadline_exceeded(format!(
                    "idle: no message on this stream for {} s (limits.stream_idle_timeout_s)",
                    state.config.limits.stream_idle_timeout_s
                ))))
                .await;
            break;
        };
        let received = Instant::now();
        let req = match msg {
            Ok(Some(r)) => r,
            Ok(None) => break,
            Err(status) => {
                // A malformed message or a broken transport ends the stream with its status.
                if status.code() != tonic::Code::Cancelled {
                    state.metrics.inc("livereg_errors_total", "bad_request", 1);
                    let _ = out.send(Err(status)).await;
                }
                break;
            }
        };
        let handle = match &bound {
            Some(h) if req.session_id.is_empty() || req.session_id == h.id => h.clone(),
            Some(h) => {
                let e = state.count(ApiError::bad_request(format!(
                    "this stream is bound to session `{}`; open another stream for `{}`",
                    h.id,
                    req.session_id.chars().take(64).collect::<String>()
                )));
                let _ = ev_tx
                    .send(StreamEvent::Error {
                        seq: req.frame.map(|f| f.seq).unwrap_or(0),
                        error: e,
                    })
                    .await;
                continue;
            }
            None => match state.session(&owner, &req.session_id) {
                Ok(h) => {
                    audit::event(
                        Action::OpenStream,
                        "ok",
                        peer,
                        Some(owner.name()),
                        Some(&h.id),
                        "grpc",
                    );
                    bound = Some(h.clone());
                    let _ = bound_tx.send(Some(h.clone()));
                    h
                }
                Err(e) => {
                    let _ = out.send(Err(state.count(e).to_status())).await;
                    break;
                }
            },
        };
        if state.registry.get(&owner, &handle.id).is_err() {
            let _ = out
                .send(Err(state
                    .count(ApiError::unknown_session(&handle.id))
                    .to_status()))
                .await;
            break;
        }
        let refused = match req.frame {
            None => Err((0, ApiError::bad_request("the message has no `frame`"))),
            Some(f) => match state.admit_rate(&handle) {
                Err(e) => Err((f.seq, e)),
                Ok(()) => match decode_proto_frame(f, state.config.limits.max_frame_points) {
                    Err(e) => {
                        state.reject(&handle, &e);
                        Err((0, e))
                    }
                    Ok(inc) => match state.admit_decoded(&handle, &inc) {
                        Ok(()) => Ok(inc),
                        Err(e) => Err((inc.seq, e)),
                    },
                },
            },
        };
        match refused {
            Ok(incoming) => handle.submit(
                Job {
                    incoming,
                    received,
                    reply: Reply::Stream(StreamSink {
                        tx: ev_tx.clone(),
                        skipped: skipped.clone(),
                    }),
                },
                &state.metrics,
            ),
            Err((seq, e)) => {
                let ev = StreamEvent::Error {
                    seq,
                    error: state.count(e),
                };
                if ev_tx.send(ev).await.is_err() {
                    break;
                }
            }
        }
    }
    drop(ev_tx);
    let _ = forward.await;
    if let Some(h) = &bound {
        audit::event(
            Action::CloseStream,
            "ok",
            peer,
            Some(owner.name()),
            Some(&h.id),
            "grpc",
        );
    }
}
