//! The server's operations, shared by the HTTP, WebSocket and gRPC front ends: create,
//! describe, reset and close a session; submit a frame. Also the shared state.

use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use tokio::sync::{oneshot, watch, Notify, Semaphore};

use crate::recording::{Recorder, RecordingMeta, SceneFiles};

use super::auth::{Authenticator, Owner};
use super::codec::{decode_binary_frame, decode_json_frame, Incoming};
use super::config::ServerConfig;
use super::error::ApiError;
use super::limits::check_frame;
use super::metrics::Metrics;
use super::registry::{Registry, SessionInfo};
use super::slots::RegistrationSlots;
use super::upload::{prepare_session, SceneUpload};
use super::worker::{
    run_worker, Completed, Job, ModelInfo, Outcome, Reply, SessionHandle, WorkerGuardrails,
    WATCHDOG_FACTOR,
};

/// Frame messages up to this size (bytes) are decoded on the network thread that received
/// them (a few hundred µs at most); larger ones on the blocking pool.
pub(crate) const INLINE_DECODE_BYTES: usize = 64 * 1024;

/// Builds the session of `upload` in `dir` on the blocking pool (a panic while building is
/// an internal error, never a lost server): the loaded scene, the session, the upload and
/// the model's memory estimate (bytes).
async fn build_session(
    upload: SceneUpload,
    dir: std::path::PathBuf,
    limits: super::config::LimitsConfig,
) -> Result<
    (
        crate::scene::LoadedScene,
        crate::session::Session,
        SceneUpload,
        u64,
    ),
    ApiError,
> {
    tokio::task::spawn_blocking(move || {
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let (loaded, session) = prepare_session(&upload, &dir, &limits)?;
            let estimate = session.memory_estimate_bytes().map_err(|e| {
                ApiError::internal(format!("the model's memory cannot be estimated: {e}"))
            })?;
            Ok::<_, ApiError>((loaded, session, upload, estimate))
        }))
        .unwrap_or_else(|_| {
            Err(ApiError::internal(
                "building the model failed unexpectedly (please report this scene)",
            ))
        })
    })
    .await
    .map_err(|e| ApiError::internal(format!("session build task: {e}")))
    .and_then(|r| r)
}

/// What a session's clients are told about its model (`recorder`: where it records, if it
/// does; `estimate`: its memory, bytes).
fn model_info(
    loaded: &crate::scene::LoadedScene,
    session: &crate::session::Session,
    recorder: Option<&Recorder>,
    estimate: u64,
) -> ModelInfo {
    ModelInfo {
        recording: recorder.map(|r| r.path().to_path_buf()),
        units: loaded.scene.units.as_str().to_string(),
        length_scale: loaded.length_scale(),
        surface_vertices: session.model.surface.vertices.len(),
        surface_triangles: session.model.surface.triangles.len(),
        structures: session
            .model
            .structures
            .iter()
            .map(|s| s.name.clone())
            .collect(),
        meshes: Arc::new(crate::worker::ModelMeshes::of(&session.model)),
        memory_estimate_bytes: estimate,
    }
}

/// Opens the recording of session `id` (scene `loaded`, uploaded as `upload`) at `path`.
/// The recording's notes name the session and its owner (the token's name, never the token).
fn open_recording(
    path: &std::path::Path,
    loaded: &crate::scene::LoadedScene,
    upload: &SceneUpload,
    id: &str,
    owner: &Owner,
    fsync: std::time::Duration,
) -> Result<Recorder, String> {
    let files = SceneFiles::from_loaded(loaded).map_err(|e| e.to_string())?;
    let meta = RecordingMeta {
        command: "serve".into(),
        budget_ms: upload.budget_ms,
        rigid_only: upload.rigid_only,
        notes: [
            ("session".to_string(), id.to_string()),
            ("owner".to_string(), owner.name().to_string()),
        ]
        .into(),
    };
    let mut rec = Recorder::create(
        path,
        &files,
        &meta,
        loaded.length_scale(),
        loaded.scene.units.as_str(),
    )
    .map_err(|e| e.to_string())?;
    rec.set_fsync_interval(fsync);
    Ok(rec)
}

/// Everything the front ends share.
#[derive(Debug)]
pub(crate) struct AppState {
    /// The configuration in force.
    pub config: ServerConfig,
    /// Token check.
    pub auth: Authenticator,
    /// Open sessions.
    pub registry: Registry,
    /// Metrics.
    pub metrics: Arc<Metrics>,
    /// Registration slots (`worker_threads`).
    pub slots: Arc<RegistrationSlots>,
    /// Session-creation slots (`max_concurrent_creates`).
    pub creates: Arc<Semaphore>,
    /// Becomes true when shutdown starts.
    pub shutdown: watch::Receiver<bool>,
    draining: AtomicBool,
    open_streams: LiveCount,
    live_workers: LiveCount,
}

/// A count of live things (streams, session workers) that shutdown can wait to reach zero.
#[derive(Debug, Default)]
struct LiveCount {
    n: AtomicI64,
    zero: Notify,
}

impl LiveCount {
    fn enter(&self) {
        self.n.fetch_add(1, Ordering::AcqRel);
    }

    fn leave(&self) {
        if self.n.fetch_sub(1, Ordering::AcqRel) == 1 {
            self.zero.notify_waiters();
        }
    }

    async fn reached_zero(&self) {
        loop {
            let n = self.zero.notified();
            if self.n.load(Ordering::Acquire) <= 0 {
                return;
            }
            n.await;
        }
    }
}

/// Counts an open stream while alive (shutdown waits for streams to finish their frames).
#[derive(Debug)]
pub(crate) struct StreamGuard(Arc<AppState>);

impl Drop for StreamGuard {
    fn drop(&mut self) {
        self.0.metrics.streams.fetch_sub(1, Ordering::Relaxed);
        self.0.open_streams.leave();
    }
}

/// Counts a session worker while it runs, including a closed session's worker that is still
/// finishing its frames and its recording (shutdown waits for it).
#[derive(Debug)]
struct WorkerGuard(Arc<AppState>);

impl Drop for WorkerGuard {
    fn drop(&mut self) {
        self.0.live_workers.leave();
    }
}

impl AppState {
    /// The state for a validated configuration.
    pub(crate) fn new(
        config: ServerConfig,
        auth: Authenticator,
        shutdown: watch::Receiver<bool>,
    ) -> Self {
        Self {
            registry: Registry::new(config.limits.clone()),
            metrics: Arc::new(Metrics::default()),
            slots: RegistrationSlots::new(config.worker_threads),
            creates: Arc::new(Semaphore::new(config.max_concurrent_creates)),
            auth,
            config,
            shutdown,
            draining: AtomicBool::new(false),
            open_streams: LiveCount::default(),
            live_workers: LiveCount::default(),
        }
    }

    /// Whether shutdown has started.
    pub(crate) fn is_draining(&self) -> bool {
        self.draining.load(Ordering::Acquire)
    }

    /// Marks the start of shutdown: new work is refused from now on.
    pub(crate) fn start_draining(&self) {
        self.draining.store(true, Ordering::Release);
    }

    /// Counts `e` in the metrics and returns it.
    pub(crate) fn count(&self, e: ApiError) -> ApiError {
        self.metrics.inc("livereg_errors_total", e.code, 1);
        e
    }

    /// A guard counting an open stream.
    pub(crate) fn stream_guard(self: &Arc<Self>) -> StreamGuard {
        self.metrics.streams.fetch_add(1, Ordering::Relaxed);
        self.open_streams.enter();
        StreamGuard(self.clone())
    }

    /// Waits until no stream is open.
    pub(crate) async fn streams_closed(&self) {
        self.open_streams.reached_zero().await;
    }

    /// Waits until every session worker has ended, those of sessions closed earlier included
    /// (a closed session's worker still finishes its pending frames and its recording).
    pub(crate) async fn workers_ended(&self) {
        self.live_workers.reached_zero().await;
    }

    /// Creates a session for `owner` from `upload`, with the client's `requested_id` (the
    /// `X-Livereg-Session` routing key) or a new random id: limits, scene checks, model build
    /// on the blocking pool, then its worker.
    pub(crate) async fn create_session(
        self: &Arc<Self>,
        owner: &Owner,
        upload: SceneUpload,
        requested_id: Option<&str>,
    ) -> Result<SessionInfo, ApiError> {
        if self.is_draining() {
            return Err(ApiError::shutting_down());
        }
        let mut reservation = self.registry.reserve(owner, requested_id)?;
        let id = reservation.id.clone();
        let dir = self.config.data_dir.join("sessions").join(&id);
        let _permit = self
            .creates
            .acquire()
            .await
            .map_err(|_| ApiError::shutting_down())?;
        let limits = self.config.limits.clone();
        let t = Instant::now();
        let d = dir.clone();
        let record_to = self
            .config
            .record
            .then(|| self.config.recordings_path().join(format!("{id}.mcap")));
        let (rec_owner, fsync) = (
            owner.clone(),
            std::time::Duration::from_millis(self.config.recordings_fsync_ms),
        );
        let (sid, metrics) = (id.clone(), self.metrics.clone());
        let built = build_session(upload, d, limits).await;
        // The memory budget is claimed before anything lasting (a recording) is made.
        let (loaded, session, upload, estimate) =
            match built.and_then(|b| reservation.claim_memory(b.3).map(|_| b)) {
                Ok(x) => x,
                Err(e) => {
                    let _ = std::fs::remove_dir_all(&dir);
                    return Err(e);
                }
            };
        let opened = tokio::task::spawn_blocking(move || {
            let recorder = record_to.and_then(|path| {
                open_recording(&path, &loaded, &upload, &sid, &rec_owner, fsync)
                    .inspect_err(|e| {
                        metrics.inc("livereg_recording_errors_total", "create", 1);
                        tracing::error!(session = %sid, error = %e, "cannot record the session; it is served unrecorded");
                    })
                    .ok()
            });
            let info = model_info(&loaded, &session, recorder.as_ref(), estimate);
            (session, recorder, info)
        })
        .await;
        let (session, recorder, info) = match opened {
            Ok(x) => x,
            Err(e) => {
                let _ = std::fs::remove_dir_all(&dir);
                return Err(ApiError::internal(format!("session start task: {e}")));
            }
        };
        self.metrics
            .session_build
            .observe(t.elapsed().as_secs_f64());
        let handle = Arc::new(SessionHandle::new(
            id,
            owner.clone(),
            info,
            dir,
            self.config.limits.max_frames_per_second,
        ));
        self.spawn_worker(&handle, session, recorder);
        reservation.commit(handle.clone());
        self.metrics.sessions.fetch_add(1, Ordering::Relaxed);
        self.metrics
            .sessions_created
            .fetch_add(1, Ordering::Relaxed);
        tracing::info!(session = %handle.id, owner = owner.name(), build_ms = t.elapsed().as_secs_f64() * 1e3, "session created");
        Ok(SessionInfo::of(&handle))
    }

    /// Starts the worker that registers `handle`'s frames with `session` (and records them
    /// to `recorder`), under the watchdog; a worker that fails removes its session.
    fn spawn_worker(
        self: &Arc<Self>,
        handle: &Arc<SessionHandle>,
        session: crate::session::Session,
        recorder: Option<Recorder>,
    ) {
        self.live_workers.enter();
        let guard = WorkerGuard(self.clone());
        let state = Arc::downgrade(self);
        let guard_rails = WorkerGuardrails {
            watchdog: std::time::Duration::from_secs_f64(
                WATCHDOG_FACTOR * self.config.limits.max_frame_ms / 1e3,
            ),
            // (the worker has closed the session and counted it as failed)
            on_failure: Arc::new(move |h: &SessionHandle| {
                if let Some(st) = state.upgrade() {
                    if st.registry.remove(&h.owner, &h.id).is_ok() {
                        st.forget(h, "failed");
                    }
                }
            }),
        };
        let worker = run_worker(
            handle.clone(),
            session,
            recorder,
            self.slots.clone(),
            self.metrics.clone(),
            guard_rails,
        );
        tokio::spawn(async move {
            let _guard = guard;
            worker.await
        });
    }

    /// The session `id` of `owner` (404 otherwise).
    pub(crate) fn session(&self, owner: &Owner, id: &str) -> Result<Arc<SessionHandle>, ApiError> {
        let h = self.registry.get(owner, id)?;
        h.touch();
        Ok(h)
    }

    /// Closes a session: removed at once, its pending frames still finish.
    pub(crate) fn close_session(&self, owner: &Owner, id: &str) -> Result<SessionInfo, ApiError> {
        let h = self.registry.remove(owner, id)?;
        self.retire(&h, "client");
        Ok(SessionInfo::of(&h))
    }

    /// Closes a session already removed from the registry, counting why.
    pub(crate) fn retire(&self, h: &SessionHandle, reason: &str) {
        h.close();
        self.metrics.inc("livereg_sessions_closed_total", reason, 1);
        self.forget(h, reason);
    }

    /// Accounts for a session that left the registry: the open-session gauge, and an audit
    /// event when the server (not the client, whose request is audited) retired it.
    fn forget(&self, h: &SessionHandle, reason: &str) {
        self.metrics.sessions.fetch_sub(1, Ordering::Relaxed);
        if reason != "client" {
            super::audit::event(
                super::audit::Action::RetireSession,
                "ok",
                super::audit::Peer(None),
                Some(h.owner.name()),
                Some(&h.id),
                reason,
            );
        }
    }

    /// Admits one more frame of `h` before it is decoded: not draining, within the session's
    /// frame rate (token bucket). A flood of frames costs a counter each, never a decode.
    /// Refusals are counted.
    pub(crate) fn admit_rate(&self, h: &SessionHandle) -> Result<(), ApiError> {
        if self.is_draining() {
            return Err(ApiError::shutting_down());
        }
        // (the session counts its own rate refusals)
        h.admit(self.config.limits.max_frames_per_second)
            .inspect_err(|e| self.count_rejection(e))
    }

    /// Checks a decoded frame for `h` (not empty, finite, within `max_frame_points`):
    /// refusals are counted.
    pub(crate) fn admit_decoded(
        &self,
        h: &SessionHandle,
        incoming: &Incoming,
    ) -> Result<(), ApiError> {
        if self.is_draining() {
            return Err(ApiError::shutting_down());
        }
        check_frame(&incoming.frame, &self.config.limits).inspect_err(|e| self.reject(h, e))
    }

    /// Decodes a frame message (binary encoding or JSON) of `h`: on the blocking pool when it
    /// is large (over [`INLINE_DECODE_BYTES`]), so that big clouds never stall the network
    /// threads. Decoding failures are counted as rejections of `h`.
    pub(crate) async fn decode(
        &self,
        h: &SessionHandle,
        bytes: axum::body::Bytes,
        binary: bool,
    ) -> Result<Incoming, ApiError> {
        let max_points = self.config.limits.max_frame_points;
        let large = bytes.len() > INLINE_DECODE_BYTES;
        let run = move || {
            if binary {
                decode_binary_frame(&bytes, max_points)
            } else {
                decode_json_frame(&bytes)
            }
        };
        let decoded = if large {
            tokio::task::spawn_blocking(run)
                .await
                .unwrap_or_else(|e| Err(ApiError::internal(format!("frame decoding task: {e}"))))
        } else {
            run()
        };
        decoded.inspect_err(|e| self.reject(h, e))
    }

    /// Counts a frame of `h` refused before registration (session counter and metrics).
    pub(crate) fn reject(&self, h: &SessionHandle, e: &ApiError) {
        h.counters.rejected.fetch_add(1, Ordering::Relaxed);
        self.count_rejection(e);
    }

    fn count_rejection(&self, e: &ApiError) {
        self.metrics.inc("livereg_frames_total", "rejected", 1);
        self.metrics.inc("livereg_frame_failures_total", e.code, 1);
    }

    /// Submits one frame and waits for its outcome (HTTP and gRPC unary): 409 when a newer
    /// frame replaced it.
    pub(crate) async fn register_once(
        &self,
        owner: &Owner,
        id: &str,
        incoming: Incoming,
    ) -> Result<(Arc<SessionHandle>, Completed), ApiError> {
        let received = Instant::now();
        let h = self.session(owner, id)?;
        self.admit_decoded(&h, &incoming)?;
        let (tx, rx) = oneshot::channel();
        h.submit(
            Job {
                incoming,
                received,
                reply: Reply::Once(tx),
            },
            &self.metrics,
        );
        match rx.await {
            Ok(Outcome::Done(c)) => Ok((h, *c)),
            Ok(Outcome::Skipped) => Err(ApiError::superseded()),
            Ok(Outcome::Failed(e)) => Err(e),
            Err(_) => Err(ApiError::internal("the session's worker ended")),
        }
    }
}
