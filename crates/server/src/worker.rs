//! Per-session registration: a single-slot mailbox where the newest frame wins, and a worker
//! task that registers on the blocking thread pool when one of the server's registration
//! slots is free.
//!
//! Registration is CPU-bound (15–30 ms per warm frame on the phantom), so at most
//! `worker_threads` frames are registered at once ([`RegistrationSlots`]: a freed slot goes
//! to the session with the freshest pending frame, unless one starves). A session's worker
//! takes its pending frame only once it holds a slot: a frame that waited is replaced by any
//! newer one that arrived meanwhile, so what gets registered is never older than the client's
//! frame period, and queues cannot grow. Replaced frames are answered "skipped" and counted.

use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, oneshot, Notify};

use super::auth::Owner;
use super::codec::Incoming;
use super::error::ApiError;
use super::limits::RateLimiter;
use super::metrics::Metrics;
use super::slots::{PendingFrame, RegistrationSlots};
use crate::recording::{now_ns, Recorder};
use crate::session::{FrameResult, Session};

/// A registered frame with its timings.
#[derive(Debug, Clone)]
pub(crate) struct Completed {
    /// The client's frame number.
    pub seq: u64,
    /// The session's result.
    pub result: FrameResult,
    /// Receipt of the frame → result ready, ms.
    pub server_ms: f64,
    /// Wait for a registration slot, ms.
    pub queue_ms: f64,
    /// Frames skipped since the previous result delivered to this receiver.
    pub skipped: u64,
}

/// What happened to a submitted frame.
#[derive(Debug)]
pub(crate) enum Outcome {
    /// Registered (the result may still carry a registration `error`).
    Done(Box<Completed>),
    /// Replaced by a newer frame before registration.
    Skipped,
    /// Not registered (the session closed, or the worker failed).
    Failed(ApiError),
}

/// Events delivered to a stream (WebSocket or gRPC).
#[derive(Debug)]
pub(crate) enum StreamEvent {
    /// A registered frame.
    Result(Box<Completed>),
    /// An error about one frame (`seq`) or the stream; the stream goes on.
    Error {
        /// The frame concerned (0 when unknown).
        seq: u64,
        /// The error.
        error: ApiError,
    },
}

/// A stream's receiving end, as held by the frames it submitted.
#[derive(Debug, Clone)]
pub(crate) struct StreamSink {
    /// Where results go (bounded: a client that does not read loses results, counted as
    /// skipped, rather than making the server queue them).
    pub tx: mpsc::Sender<StreamEvent>,
    /// Frames of this stream skipped since its last result.
    pub skipped: Arc<AtomicU64>,
}

/// Where a frame's outcome goes.
#[derive(Debug)]
pub(crate) enum Reply {
    /// One request waiting for its answer (HTTP, gRPC unary).
    Once(oneshot::Sender<Outcome>),
    /// A stream.
    Stream(StreamSink),
}

/// A frame waiting in a session's mailbox.
#[derive(Debug)]
pub(crate) struct Job {
    /// The decoded frame.
    pub incoming: Incoming,
    /// When the server received it.
    pub received: Instant,
    /// Where the outcome goes.
    pub reply: Reply,
}

/// Facts about a session's model, fixed at creation.
#[derive(Debug, Clone)]
pub(crate) struct ModelInfo {
    /// Scene units (`m`, `cm`, `mm`).
    pub units: String,
    /// Metres per scene unit.
    pub length_scale: f64,
    /// Surface vertices.
    pub surface_vertices: usize,
    /// Surface triangles.
    pub surface_triangles: usize,
    /// Structure names in scene order.
    pub structures: Vec<String>,
    /// The surface's and the mesh structures' triangles (for transports that send meshes:
    /// OpenIGTLink POLYDATA).
    pub meshes: std::sync::Arc<ModelMeshes>,
    /// The session's recording (`None` when not recorded).
    pub recording: Option<std::path::PathBuf>,
    /// The session's estimated peak memory, bytes (`Session::memory_estimate_bytes`),
    /// counted against the server's memory budget while it is open.
    pub memory_estimate_bytes: u64,
}

/// The triangles of a session's model, indexing the positions of its results.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct ModelMeshes {
    /// The liver surface's triangles (`FrameResult::surface` positions).
    pub surface: Vec<[usize; 3]>,
    /// Per structure, in scene order: its triangles when it is a mesh.
    pub structures: Vec<Option<Vec<[usize; 3]>>>,
}

impl ModelMeshes {
    /// The triangles of `model`'s surface and mesh structures.
    pub(crate) fn of(model: &crate::simulation::SceneModel) -> Self {
        Self {
            surface: model.surface.triangles.clone(),
            structures: model
                .structures
                .iter()
                .map(|s| s.triangles.clone())
                .collect(),
        }
    }
}

/// Frame counters of a session.
#[derive(Debug, Default)]
pub(crate) struct Counters {
    /// Frames registered (with or without a registration error).
    pub registered: AtomicU64,
    /// Frames skipped because a newer one arrived first.
    pub skipped: AtomicU64,
    /// Frames refused before registration (bad input, rate).
    pub rejected: AtomicU64,
    /// Registered frames whose result carries an error.
    pub failed: AtomicU64,
}

#[derive(Debug, Default)]
struct Mailbox {
    pending: Option<Job>,
    closed: bool,
}

/// One open session: ownership, model facts, mailbox and counters. The [`Session`] itself
/// lives in the worker task.
#[derive(Debug)]
pub(crate) struct SessionHandle {
    /// 128-bit random id, hex.
    pub id: String,
    /// The token that created it.
    pub owner: Owner,
    /// Creation time.
    pub created: Instant,
    /// Model facts.
    pub info: ModelInfo,
    /// Frame counters.
    pub counters: Counters,
    /// Directory of the uploaded scene (removed when the worker ends).
    pub dir: std::path::PathBuf,
    last_used: Mutex<Instant>,
    mailbox: Mutex<Mailbox>,
    wake: Notify,
    ended: Notify,
    ended_flag: AtomicBool,
    rate: Mutex<RateLimiter>,
    warm: AtomicBool,
    reset_requested: AtomicBool,
    skipped_since_result: AtomicU64,
    recording_failure: Mutex<Option<String>>,
}

impl PendingFrame for SessionHandle {
    /// When the frame waiting in the mailbox was received (`None`: none waits).
    fn pending_received(&self) -> Option<Instant> {
        self.mailbox
            .lock()
            .ok()
            .and_then(|mb| mb.pending.as_ref().map(|j| j.received))
    }
}

impl SessionHandle {
    /// A handle for a new session.
    pub(crate) fn new(
        id: String,
        owner: Owner,
        info: ModelInfo,
        dir: std::path::PathBuf,
        max_fps: f64,
    ) -> Self {
        Self {
            id,
            owner,
            created: Instant::now(),
            info,
            counters: Counters::default(),
            dir,
            last_used: Mutex::new(Instant::now()),
            mailbox: Mutex::new(Mailbox::default()),
            wake: Notify::new(),
            ended: Notify::new(),
            ended_flag: AtomicBool::new(false),
            rate: Mutex::new(RateLimiter::new(max_fps)),
            warm: AtomicBool::new(false),
            reset_requested: AtomicBool::new(false),
            skipped_since_result: AtomicU64::new(0),
            recording_failure: Mutex::new(None),
        }
    }

    /// Why the session's recording stopped while the session went on (a full disk, an I/O
    /// error), or `None` while it records (or was never recorded).
    pub(crate) fn recording_failure(&self) -> Option<String> {
        self.recording_failure.lock().ok().and_then(|f| f.clone())
    }

    fn set_recording_failure(&self, why: String) {
        if let Ok(mut f) = self.recording_failure.lock() {
            *f = Some(why);
        }
    }

    /// Marks the session used now (idle timeout).
    pub(crate) fn touch(&self) {
        if let Ok(mut t) = self.last_used.lock() {
            *t = Instant::now();
        }
    }

    /// Seconds since the last request.
    pub(crate) fn idle_s(&self) -> f64 {
        self.last_used
            .lock()
            .map(|t| t.elapsed().as_secs_f64())
            .unwrap_or(0.0)
    }

    /// Whether the next frame starts from a registered state.
    pub(crate) fn is_warm(&self) -> bool {
        self.warm.load(Ordering::Relaxed)
    }

    /// Takes a frame-rate token; 429 when the session is over its rate.
    pub(crate) fn admit(&self, max_fps: f64) -> Result<(), ApiError> {
        let ok = self
            .rate
            .lock()
            .map(|mut r| r.try_acquire(Instant::now()))
            .unwrap_or(false);
        if ok {
            Ok(())
        } else {
            self.counters.rejected.fetch_add(1, Ordering::Relaxed);
            Err(super::limits::rate_limited(max_fps))
        }
    }

    /// Puts `job` in the mailbox; a frame still waiting there is skipped (newest wins).
    pub(crate) fn submit(&self, job: Job, metrics: &Metrics) {
        self.touch();
        let previous = {
            let Ok(mut mb) = self.mailbox.lock() else {
                fail(job.reply, ApiError::internal("session mailbox poisoned"));
                return;
            };
            if mb.closed {
                drop(mb);
                fail(
                    job.reply,
                    ApiError::not_found(format!("session `{}` is closed", self.id)),
                );
                return;
            }
            mb.pending.replace(job)
        };
        if let Some(old) = previous {
            self.counters.skipped.fetch_add(1, Ordering::Relaxed);
            metrics.inc("livereg_frames_total", "skipped", 1);
            match old.reply {
                Reply::Once(tx) => {
                    self.skipped_since_result.fetch_add(1, Ordering::Relaxed);
                    let _ = tx.send(Outcome::Skipped);
                }
                Reply::Stream(sink) => {
                    sink.skipped.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        self.wake.notify_one();
    }

    /// Asks the worker to forget every frame before the next one (back to the rest shape).
    pub(crate) fn request_reset(&self) {
        self.reset_requested.store(true, Ordering::Relaxed);
        self.warm.store(false, Ordering::Relaxed);
    }

    /// Closes the mailbox: frames already submitted are still registered, new ones refused;
    /// the worker ends after them.
    pub(crate) fn close(&self) {
        if let Ok(mut mb) = self.mailbox.lock() {
            mb.closed = true;
        }
        self.wake.notify_one();
    }

    /// Whether the worker has ended.
    pub(crate) fn has_ended(&self) -> bool {
        self.ended_flag.load(Ordering::Acquire)
    }

    /// Waits until the worker has ended (after [`SessionHandle::close`]).
    pub(crate) async fn wait_ended(&self) {
        loop {
            let notified = self.ended.notified();
            if self.has_ended() {
                return;
            }
            notified.await;
        }
    }

    fn take(&self) -> Option<Job> {
        self.mailbox
            .lock()
            .ok()
            .and_then(|mut mb| mb.pending.take())
    }

    /// `Some(true)` when a frame waits, `Some(false)` when closed and empty, `None` when idle.
    fn state(&self) -> Option<bool> {
        let mb = self.mailbox.lock().ok()?;
        if mb.pending.is_some() {
            Some(true)
        } else if mb.closed {
            Some(false)
        } else {
            None
        }
    }
}

fn fail(reply: Reply, error: ApiError) {
    match reply {
        Reply::Once(tx) => {
            let _ = tx.send(Outcome::Failed(error));
        }
        Reply::Stream(sink) => {
            let _ = sink.tx.try_send(StreamEvent::Error { seq: 0, error });
        }
    }
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The worker of one session: waits for frames, takes a registration slot, registers the
/// newest frame on the blocking pool and delivers the outcome; ends when the session is
/// closed and its mailbox empty (or if registration panicked, which closes the session).
///
/// With a `recorder`, each registered frame and its result are recorded on the blocking
/// thread right after registration, before the result is delivered (the recorder flushes
/// after every result, so a killed server leaves every frame whose result a client saw); the
/// recording is finished when the worker ends. A recording failure is logged and counted
/// (`livereg_recording_errors_total`) and ends the recording, never the session.
///
/// A frame still registering after `guard.watchdog` retires the session: its waiting frames
/// are refused, `guard.on_failure` takes it out of the registry, and the registration
/// thread, which cannot be stopped, keeps its slot until it returns.
pub(crate) async fn run_worker(
    handle: Arc<SessionHandle>,
    session: Session,
    recorder: Option<Recorder>,
    slots: Arc<RegistrationSlots>,
    metrics: Arc<Metrics>,
    guard: WorkerGuardrails,
) {
    let mut recorder = recorder;
    serve_frames(&handle, session, &mut recorder, slots, &metrics, &guard).await;
    if let Some(rec) = recorder.take() {
        let id = handle.id.clone();
        let finished = tokio::task::spawn_blocking(move || rec.finish()).await;
        match finished {
            Ok(Ok(stats)) => tracing::info!(
                session = %id,
                frames = stats.frames,
                bytes = stats.bytes,
                write_ms = stats.write_ms,
                "recording finished"
            ),
            Ok(Err(e)) => {
                metrics.inc("livereg_recording_errors_total", "finish", 1);
                tracing::error!(session = %id, error = %e, "recording could not be finished");
            }
            Err(e) => {
                metrics.inc("livereg_recording_errors_total", "finish", 1);
                tracing::error!(session = %id, error = %e, "recording finish task failed");
            }
        }
    }
    finish(&handle);
}

/// Records `frame` (received at `received_ns`) and its `result`; on failure (a full disk, an
/// I/O error) the recorder is dropped (its file keeps every frame recorded before), the
/// failure logged and counted, and the session's description says so
/// ([`SessionHandle::recording_failure`]); the session goes on unrecorded.
fn record(
    recorder: &mut Option<Recorder>,
    frame: &crate::session::Frame,
    received_ns: u64,
    result: &FrameResult,
    handle: &SessionHandle,
    metrics: &Metrics,
) {
    let Some(rec) = recorder.as_mut() else {
        return;
    };
    let r = rec
        .record_frame(frame, received_ns)
        .and_then(|()| rec.record_result(result));
    if let Err(e) = r {
        metrics.inc("livereg_recording_errors_total", "write", 1);
        tracing::error!(session = %handle.id, error = %e, "recording failed; the session goes on unrecorded");
        let frames = handle.counters.registered.load(Ordering::Relaxed);
        // Without the server's path: the description goes to the client.
        handle.set_recording_failure(format!(
            "the recording stopped after {frames} registered frames ({}); the session goes on unrecorded",
            e.detail()
        ));
        *recorder = None;
    }
}

async fn serve_frames(
    handle: &Arc<SessionHandle>,
    session: Session,
    recorder: &mut Option<Recorder>,
    slots: Arc<RegistrationSlots>,
    metrics: &Arc<Metrics>,
    guard: &WorkerGuardrails,
) {
    let mut session = Some(session);
    let mut last_registered = Instant::now();
    loop {
        // Wait for a frame (or the end).
        loop {
            let notified = handle.wake.notified();
            match handle.state() {
                Some(true) => break,
                Some(false) => return,
                None => notified.await,
            }
        }
        let permit = slots.acquire(handle, last_registered).await;
        // The newest frame, taken only now that a slot is ours.
        let Some(job) = handle.take() else {
            continue;
        };
        let Some(mut s) = session.take() else {
            return;
        };
        let queue_ms = ms_since(job.received);
        let received_ns =
            now_ns().saturating_sub(job.received.elapsed().as_nanos().min(u64::MAX as u128) as u64);
        if handle.reset_requested.swap(false, Ordering::Relaxed) {
            s.reset();
        }
        let frame = job.incoming.frame;
        let mut rec = recorder.take();
        let (h, m) = (handle.clone(), metrics.clone());
        let mut task = tokio::task::spawn_blocking(move || {
            let r = std::panic::catch_unwind(AssertUnwindSafe(|| s.register(&frame)));
            if let Ok(result) = &r {
                // Before the result is delivered: on disk once the client sees it.
                record(&mut rec, &frame, received_ns, result, &h, &m);
            }
            (s, rec, r)
        });
        let joined = match tokio::time::timeout(guard.watchdog, &mut task).await {
            Ok(joined) => joined,
            Err(_) => {
                // The thread cannot be stopped: it keeps its slot until it returns.
                tokio::spawn(async move {
                    let _ = task.await;
                    drop(permit);
                });
                return fail_session(handle, job.reply, metrics, guard, Failure::Overran);
            }
        };
        drop(permit);
        last_registered = Instant::now();
        let (s, result) = match joined {
            Ok((s, rec, Ok(r))) => {
                *recorder = rec;
                (s, r)
            }
            Ok((_, rec, Err(_))) => {
                *recorder = rec;
                return fail_session(handle, job.reply, metrics, guard, Failure::Panicked);
            }
            Err(_) => return fail_session(handle, job.reply, metrics, guard, Failure::Panicked),
        };
        handle.warm.store(s.is_warm(), Ordering::Relaxed);
        session = Some(s);
        handle.counters.registered.fetch_add(1, Ordering::Relaxed);
        metrics.registration.observe(result.wall_ms / 1e3);
        metrics.queue_wait.observe(queue_ms / 1e3);
        match &result.error {
            Some(e) => {
                handle.counters.failed.fetch_add(1, Ordering::Relaxed);
                metrics.inc("livereg_frames_total", "failed", 1);
                metrics.inc("livereg_frame_failures_total", e.cause(), 1);
            }
            None => metrics.inc("livereg_frames_total", "registered", 1),
        }
        let server_ms = ms_since(job.received);
        metrics.latency.observe(server_ms / 1e3);
        let mut done = Completed {
            seq: job.incoming.seq,
            result,
            server_ms,
            queue_ms,
            skipped: 0,
        };
        match job.reply {
            Reply::Once(tx) => {
                done.skipped = handle.skipped_since_result.swap(0, Ordering::Relaxed);
                let _ = tx.send(Outcome::Done(Box::new(done)));
            }
            Reply::Stream(sink) => {
                done.skipped = sink.skipped.swap(0, Ordering::Relaxed);
                let n = done.skipped;
                if sink
                    .tx
                    .try_send(StreamEvent::Result(Box::new(done)))
                    .is_err()
                {
                    // The client is not reading (or left): count the result as skipped.
                    sink.skipped.fetch_add(n + 1, Ordering::Relaxed);
                }
            }
        }
    }
}

/// How many times `limits.max_frame_ms` a frame may run before its session is retired.
pub(crate) const WATCHDOG_FACTOR: f64 = 5.0;

/// What a session's worker does when a frame goes wrong beyond the frame itself.
#[derive(Clone)]
pub(crate) struct WorkerGuardrails {
    /// Longest a frame may register before the session is retired.
    pub watchdog: Duration,
    /// Called once when the session fails (takes it out of the registry at once).
    pub on_failure: Arc<dyn Fn(&SessionHandle) + Send + Sync>,
}

impl std::fmt::Debug for WorkerGuardrails {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WorkerGuardrails")
            .field("watchdog", &self.watchdog)
            .finish_non_exhaustive()
    }
}

/// Why a session failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Failure {
    /// Registration panicked.
    Panicked,
    /// A frame ran past the watchdog.
    Overran,
}

/// Registration panicked or overran the watchdog: the session is closed and leaves the
/// registry at once, this frame and any waiting one refused.
fn fail_session(
    handle: &SessionHandle,
    reply: Reply,
    metrics: &Metrics,
    guard: &WorkerGuardrails,
    why: Failure,
) {
    let (cause, message) = match why {
        Failure::Panicked => {
            tracing::error!(session = %handle.id, "registration panicked; the session is closed");
            (
                "panic",
                "registration failed unexpectedly; the session was closed (please report this frame)"
                    .to_string(),
            )
        }
        Failure::Overran => {
            tracing::error!(session = %handle.id, watchdog_ms = guard.watchdog.as_secs_f64() * 1e3, "a frame overran the watchdog; the session is closed");
            (
                "watchdog",
                format!(
                    "the frame was still registering after {:.0} ms ({WATCHDOG_FACTOR} × limits.max_frame_ms); the session was closed",
                    guard.watchdog.as_secs_f64() * 1e3
                ),
            )
        }
    };
    metrics.inc("livereg_frame_failures_total", cause, 1);
    metrics.inc("livereg_sessions_closed_total", "failed", 1);
    handle.close();
    (guard.on_failure)(handle);
    fail(reply, ApiError::internal(message));
    // Refuse whatever else is waiting.
    while let Some(j) = handle.take() {
        fail(j.reply, ApiError::internal("the session was closed"));
    }
}

fn finish(handle: &SessionHandle) {
    let _ = std::fs::remove_dir_all(&handle.dir);
    handle.ended_flag.store(true, Ordering::Release);
    handle.ended.notify_waiters();
    tracing::info!(session = %handle.id, owner = handle.owner.name(), "session ended");
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session::Frame;

    fn handle() -> SessionHandle {
        let info = ModelInfo {
            units: "m".into(),
            length_scale: 1.0,
            surface_vertices: 0,
            surface_triangles: 0,
            structures: Vec::new(),
            meshes: Default::default(),
            recording: None,
            memory_estimate_bytes: 0,
        };
        SessionHandle::new(
            "s".into(),
            Owner("s".into()),
            info,
            std::env::temp_dir(),
            100.0,
        )
    }

    fn job(seq: u64, received: Instant) -> (Job, oneshot::Receiver<Outcome>) {
        let (tx, rx) = oneshot::channel();
        let job = Job {
            incoming: Incoming {
                seq,
                frame: Frame {
                    source: format!("f{seq}"),
                    points: Vec::new(),
                    camera: None,
                },
            },
            received,
            reply: Reply::Once(tx),
        };
        (job, rx)
    }

    /// What the registration slots read of a session: the arrival of the one frame its
    /// mailbox holds. A newer frame replaces the waiting one (which is answered `Skipped`
    /// and counted), and once the worker takes it nothing is pending.
    #[test]
    fn the_pending_frame_is_the_newest_until_the_worker_takes_it() {
        let (h, metrics) = (handle(), Metrics::default());
        assert_eq!(h.pending_received(), None);
        let t0 = Instant::now();
        let t1 = t0 + Duration::from_millis(20);
        let (first, mut first_reply) = job(1, t0);
        h.submit(first, &metrics);
        assert_eq!(h.pending_received(), Some(t0));
        let (second, _second_reply) = job(2, t1);
        h.submit(second, &metrics);
        assert_eq!(h.pending_received(), Some(t1));
        assert!(matches!(first_reply.try_recv(), Ok(Outcome::Skipped)));
        assert_eq!(h.counters.skipped.load(Ordering::Relaxed), 1);
        let taken = h.take().expect("a frame waits");
        assert_eq!(taken.incoming.seq, 2);
        assert_eq!(h.pending_received(), None);
    }
}
