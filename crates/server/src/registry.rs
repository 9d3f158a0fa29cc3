//! Open sessions: unguessable ids, ownership (a session is visible only to the token that
//! created it; to every other token it does not exist), the per-token and global limits, and
//! the memory budget the open sessions' estimates share.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use serde::{Deserialize, Serialize};

use super::auth::Owner;
use super::config::LimitsConfig;
use super::error::ApiError;
use super::memory_budget::{memory_budget, mib};
use super::worker::SessionHandle;

/// A new session id: 128 random bits from the operating system, 32 lowercase hex digits.
pub(crate) fn new_session_id() -> Result<String, ApiError> {
    let mut b = [0u8; 16];
    getrandom::fill(&mut b)
        .map_err(|e| ApiError::internal(format!("no randomness for a session id: {e}")))?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

/// The header naming a session: the id a client asks for when it creates one, and the key a
/// scaled-out deployment's proxy routes every request of the session by (docs/server.md,
/// "Scaling out"). HTTP header and gRPC metadata alike.
pub const SESSION_HEADER: &str = "x-livereg-session";

/// The session id a create request asks for, from the raw value of its [`SESSION_HEADER`]
/// (HTTP header or gRPC metadata), if any; its shape is checked when it is reserved.
pub(crate) fn requested_session_id(value: Option<&[u8]>) -> Result<Option<String>, ApiError> {
    value
        .map(|v| {
            std::str::from_utf8(v)
                .map(|s| s.trim().to_string())
                .map_err(|_| ApiError::bad_request("X-Livereg-Session is not valid text"))
        })
        .transpose()
}

/// Whether `id` has the shape of a session id (so bad ids are answered without a lookup).
pub(crate) fn is_session_id(id: &str) -> bool {
    id.len() == 32
        && id
            .bytes()
            .all(|c| c.is_ascii_digit() || (b'a'..=b'f').contains(&c))
}

/// A session's public description (`GET /v1/sessions/{id}`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct SessionInfo {
    /// The id.
    pub id: String,
    /// Scene units.
    pub units: String,
    /// Surface vertices of the model.
    pub surface_vertices: usize,
    /// Surface triangles of the model.
    pub surface_triangles: usize,
    /// Structure names in scene order.
    pub structures: Vec<String>,
    /// Frames registered.
    pub frames_registered: u64,
    /// Registered frames whose result carries an error.
    pub frames_failed: u64,
    /// Frames skipped (a newer one arrived first).
    pub frames_skipped: u64,
    /// Frames refused before registration.
    pub frames_rejected: u64,
    /// Seconds since creation.
    pub age_s: f64,
    /// Whether the next frame starts warm.
    pub warm: bool,
    /// Relative URL of the WebSocket stream.
    pub stream: String,
    /// File name of the session's MCAP recording in the server's recordings directory
    /// (`<id>.mcap`; never the server's path), `null` when not recorded (`record = false`, or
    /// the file could not be created).
    #[serde(default)]
    pub recording: Option<String>,
    /// Why the recording stopped while the session went on (a full disk, an I/O error);
    /// absent while it records.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recording_error: Option<String>,
    /// The session's estimated peak memory, MiB, counted against the server's memory budget
    /// (docs/server.md, "Memory budget").
    #[serde(default)]
    pub memory_estimate_mb: f64,
}

impl SessionInfo {
    /// The description of `h` now.
    pub(crate) fn of(h: &SessionHandle) -> Self {
        use std::sync::atomic::Ordering::Relaxed;
        Self {
            id: h.id.clone(),
            units: h.info.units.clone(),
            surface_vertices: h.info.surface_vertices,
            surface_triangles: h.info.surface_triangles,
            structures: h.info.structures.clone(),
            frames_registered: h.counters.registered.load(Relaxed),
            frames_failed: h.counters.failed.load(Relaxed),
            frames_skipped: h.counters.skipped.load(Relaxed),
            frames_rejected: h.counters.rejected.load(Relaxed),
            age_s: h.created.elapsed().as_secs_f64(),
            warm: h.is_warm(),
            stream: format!("/v1/sessions/{}/stream", h.id),
            recording: h
                .info
                .recording
                .as_ref()
                .and_then(|p| p.file_name())
                .map(|n| n.to_string_lossy().into_owned()),
            recording_error: h.recording_failure(),
            memory_estimate_mb: mib(h.info.memory_estimate_bytes),
        }
    }
}

#[derive(Debug, Default)]
struct Inner {
    sessions: HashMap<String, Arc<SessionHandle>>,
    /// Sessions being created, per owner (they count against the limits).
    reserved: HashMap<Owner, usize>,
    /// Ids of the sessions being created.
    reserved_ids: std::collections::HashSet<String>,
    /// Estimated memory claimed by sessions being created, bytes.
    reserved_memory: u64,
}

impl Inner {
    /// Estimated memory of the open sessions and of those being created, bytes.
    fn memory_in_use(&self) -> u64 {
        self.reserved_memory
            + self
                .sessions
                .values()
                .map(|h| h.info.memory_estimate_bytes)
                .sum::<u64>()
    }
}

/// The open sessions.
#[derive(Debug)]
pub(crate) struct Registry {
    inner: Mutex<Inner>,
    limits: LimitsConfig,
    /// Bytes of estimated session memory the open sessions may hold together.
    memory_budget: u64,
}

/// A place and an id reserved for a session being created; released on drop unless
/// committed.
#[derive(Debug)]
pub(crate) struct Reservation<'a> {
    registry: &'a Registry,
    owner: Owner,
    /// The new session's id.
    pub id: String,
    /// Estimated memory claimed for the new session, bytes ([`Reservation::claim_memory`]).
    memory: u64,
    done: bool,
}

impl Drop for Reservation<'_> {
    fn drop(&mut self) {
        if !self.done {
            self.registry.release(&self.owner, &self.id, self.memory);
        }
    }
}

impl Reservation<'_> {
    /// Claims `bytes` of the server's memory budget for the new session (its estimate,
    /// `Session::memory_estimate_bytes`). 413 `model_too_large` when it exceeds the whole
    /// budget (no server configured like this one can hold it); 429 `memory_budget` when the
    /// open sessions leave too little (another replica, or later, may). Claiming again
    /// replaces the earlier claim.
    pub(crate) fn claim_memory(&mut self, bytes: u64) -> Result<(), ApiError> {
        let budget = self.registry.memory_budget;
        let mut g = self.registry.lock()?;
        g.reserved_memory -= self.memory;
        self.memory = 0;
        if bytes > budget {
            return Err(ApiError::too_large(
                "model_too_large",
                format!(
                    "the scene's model needs about {:.0} MiB, more than this server's whole memory budget of {:.0} MiB (limits.max_memory_mb); use a larger grid.cell_size",
                    mib(bytes),
                    mib(budget)
                ),
            ));
        }
        let in_use = g.memory_in_use();
        if in_use.saturating_add(bytes) > budget {
            return Err(ApiError::too_many(
                "memory_budget",
                format!(
                    "the scene's model needs about {:.0} MiB and the open sessions hold {:.0} MiB of this server's {:.0} MiB memory budget (limits.max_memory_mb); try another replica or later",
                    mib(bytes),
                    mib(in_use),
                    mib(budget)
                ),
            ));
        }
        g.reserved_memory += bytes;
        self.memory = bytes;
        Ok(())
    }

    /// Registers the created session (its id must be [`Reservation::id`]) in place of the
    /// reservation.
    pub(crate) fn commit(mut self, handle: Arc<SessionHandle>) {
        debug_assert_eq!(handle.id, self.id);
        self.done = true;
        if let Ok(mut g) = self.registry.inner.lock() {
            if let Some(n) = g.reserved.get_mut(&self.owner) {
                *n = n.saturating_sub(1);
            }
            g.reserved_ids.remove(&self.id);
            g.reserved_memory -= self.memory;
            g.sessions.insert(handle.id.clone(), handle);
        }
    }
}

impl Registry {
    /// An empty registry enforcing `limits`, with the memory budget they give
    /// ([`memory_budget`], logged with where it came from).
    pub(crate) fn new(limits: LimitsConfig) -> Self {
        let (memory_budget, source) = memory_budget(limits.max_memory_mb);
        tracing::info!(
            memory_budget_mb = mib(memory_budget).round(),
            source = ?source,
            "session memory budget"
        );
        Self::with_memory_budget(limits, memory_budget)
    }

    /// An empty registry enforcing `limits` with a memory budget of `bytes`.
    pub(crate) fn with_memory_budget(limits: LimitsConfig, bytes: u64) -> Self {
        Self {
            inner: Mutex::new(Inner::default()),
            limits,
            memory_budget: bytes,
        }
    }

    /// The memory budget of the open sessions' estimates, bytes (`u64::MAX`: none known).
    pub(crate) fn memory_budget(&self) -> u64 {
        self.memory_budget
    }

    /// Estimated memory of the open sessions and of those being created, bytes.
    pub(crate) fn memory_in_use(&self) -> u64 {
        self.inner.lock().map(|g| g.memory_in_use()).unwrap_or(0)
    }

    fn lock(&self) -> Result<std::sync::MutexGuard<'_, Inner>, ApiError> {
        self.inner
            .lock()
            .map_err(|_| ApiError::internal("session registry poisoned"))
    }

    fn release(&self, owner: &Owner, id: &str, memory: u64) {
        if let Ok(mut g) = self.inner.lock() {
            g.reserved_memory -= memory;
            if let Some(n) = g.reserved.get_mut(owner) {
                *n = n.saturating_sub(1);
            }
            g.reserved_ids.remove(id);
        }
    }

    /// Reserves a place for a new session of `owner`, with the id `requested` by the client
    /// (32 lowercase hex digits; the routing key of a scaled-out deployment, docs/server.md)
    /// or a new random one. 400 for a malformed id, 409 `session_exists` when the id is
    /// taken, 429 when the token or the server is at its session limit.
    pub(crate) fn reserve(
        &self,
        owner: &Owner,
        requested: Option<&str>,
    ) -> Result<Reservation<'_>, ApiError> {
        let id = match requested {
            Some(r) if is_session_id(r) => r.to_string(),
            Some(r) => {
                return Err(ApiError::bad_request(format!(
                    "X-Livereg-Session {:?} is not a session id: use 32 lowercase hex digits (128 random bits)",
                    r.chars().take(64).collect::<String>()
                )))
            }
            None => new_session_id()?,
        };
        let mut g = self.lock()?;
        if g.sessions.contains_key(&id) || g.reserved_ids.contains(&id) {
            return Err(ApiError::new(
                axum::http::StatusCode::CONFLICT,
                "session_exists",
                format!("a session `{id}` is already open on this server: close it first, or choose another id"),
            ));
        }
        let mine = g.sessions.values().filter(|h| &h.owner == owner).count()
            + g.reserved.get(owner).copied().unwrap_or(0);
        if mine >= self.limits.max_sessions_per_token {
            return Err(ApiError::too_many(
                "too_many_sessions",
                format!(
                    "this token already has {mine} open sessions, the limit (limits.max_sessions_per_token = {}); close one first",
                    self.limits.max_sessions_per_token
                ),
            ));
        }
        let all = g.sessions.len() + g.reserved.values().sum::<usize>();
        if all >= self.limits.max_sessions {
            return Err(ApiError::too_many(
                "too_many_sessions",
                format!(
                    "the server has {all} open sessions, its limit (limits.max_sessions); try another replica or later"
                ),
            ));
        }
        *g.reserved.entry(owner.clone()).or_insert(0) += 1;
        g.reserved_ids.insert(id.clone());
        Ok(Reservation {
            registry: self,
            owner: owner.clone(),
            id,
            memory: 0,
            done: false,
        })
    }

    /// The session `id` of `owner`; 404 when it does not exist *or belongs to another token*
    /// (the same answer, so ids of other tokens cannot be probed).
    pub(crate) fn get(&self, owner: &Owner, id: &str) -> Result<Arc<SessionHandle>, ApiError> {
        if !is_session_id(id) {
            return Err(ApiError::unknown_session(id));
        }
        let g = self.lock()?;
        match g.sessions.get(id) {
            Some(h) if &h.owner == owner => Ok(h.clone()),
            _ => Err(ApiError::unknown_session(id)),
        }
    }

    /// Removes the session `id` of `owner` (404 as [`Registry::get`]) and returns it.
    pub(crate) fn remove(&self, owner: &Owner, id: &str) -> Result<Arc<SessionHandle>, ApiError> {
        let h = self.get(owner, id)?;
        self.lock()?.sessions.remove(id);
        Ok(h)
    }

    /// The sessions of `owner`.
    pub(crate) fn list(&self, owner: &Owner) -> Vec<Arc<SessionHandle>> {
        self.inner
            .lock()
            .map(|g| {
                g.sessions
                    .values()
                    .filter(|h| &h.owner == owner)
                    .cloned()
                    .collect()
            })
            .unwrap_or_default()
    }

    /// Removes and returns every session (shutdown).
    pub(crate) fn drain(&self) -> Vec<Arc<SessionHandle>> {
        self.inner
            .lock()
            .map(|mut g| g.sessions.drain().map(|(_, h)| h).collect())
            .unwrap_or_default()
    }

    /// Removes and returns the sessions idle for more than `seconds`.
    pub(crate) fn take_idle(&self, seconds: f64) -> Vec<Arc<SessionHandle>> {
        let Ok(mut g) = self.inner.lock() else {
            return Vec::new();
        };
        let idle: Vec<String> = g
            .sessions
            .values()
            .filter(|h| h.idle_s() > seconds)
            .map(|h| h.id.clone())
            .collect();
        idle.iter().filter_map(|id| g.sessions.remove(id)).collect()
    }

    /// The recordings of the open sessions (files that retention must not remove).
    pub(crate) fn recording_paths(&self) -> std::collections::HashSet<std::path::PathBuf> {
        self.inner
            .lock()
            .map(|i| {
                i.sessions
                    .values()
                    .filter_map(|h| h.info.recording.clone())
                    .collect()
            })
            .unwrap_or_default()
    }

    /// Number of open sessions.
    pub(crate) fn len(&self) -> usize {
        self.inner.lock().map(|g| g.sessions.len()).unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_128_bit_hex_and_distinct() {
        let a = new_session_id().unwrap();
        let b = new_session_id().unwrap();
        assert!(is_session_id(&a) && is_session_id(&b));
        assert_ne!(a, b);
        assert!(!is_session_id("../etc"));
        assert!(!is_session_id(&a.to_uppercase()));
    }

    #[test]
    fn reservations_count_against_the_token_limit() {
        let r = Registry::new(LimitsConfig {
            max_sessions_per_token: 1,
            max_sessions: 2,
            ..Default::default()
        });
        let a = Owner("a".into());
        let b = Owner("b".into());
        let ra = r.reserve(&a, None).unwrap();
        assert_eq!(r.reserve(&a, None).unwrap_err().code, "too_many_sessions");
        let rb = r.reserve(&b, None).unwrap();
        assert!(r.reserve(&Owner("c".into()), None).is_err());
        drop(ra);
        drop(rb);
        assert!(r.reserve(&a, None).is_ok());
    }

    /// A client-chosen id (the routing key) is used as given, refused while taken (being
    /// created or open, whoever owns it), free again when its reservation is dropped, and
    /// refused when malformed.
    #[test]
    fn requested_ids_are_unique_and_well_formed() {
        let r = Registry::new(LimitsConfig::default());
        let (a, b) = (Owner("a".into()), Owner("b".into()));
        let id = new_session_id().unwrap();
        let ra = r.reserve(&a, Some(&id)).unwrap();
        assert_eq!(ra.id, id);
        assert_eq!(r.reserve(&b, Some(&id)).unwrap_err().code, "session_exists");
        assert_eq!(r.reserve(&a, Some(&id)).unwrap_err().code, "session_exists");
        drop(ra);
        assert_eq!(r.reserve(&b, Some(&id)).unwrap().id, id);
        for bad in ["", "ABCDEF0123456789abcdef0123456789", "../x", "0123"] {
            assert_eq!(
                r.reserve(&a, Some(bad)).unwrap_err().code,
                "bad_request",
                "{bad}"
            );
        }
        let fresh = r.reserve(&a, None).unwrap();
        assert!(is_session_id(&fresh.id) && fresh.id != id);
    }

    /// Claims in flight count against the budget like open sessions; a reservation dropped
    /// without commit (a failed build) gives its claim back, a re-claim replaces the earlier
    /// one, and an estimate above the whole budget is refused as such.
    #[test]
    fn memory_claims_share_the_budget() {
        let r = Registry::with_memory_budget(LimitsConfig::default(), 100);
        let a = Owner("a".into());
        let mut first = r.reserve(&a, None).unwrap();
        first.claim_memory(60).unwrap();
        let mut second = r.reserve(&a, None).unwrap();
        assert_eq!(second.claim_memory(50).unwrap_err().code, "memory_budget");
        assert_eq!(r.memory_in_use(), 60);
        second.claim_memory(40).unwrap();
        assert_eq!(r.memory_in_use(), 100);
        first.claim_memory(10).unwrap();
        assert_eq!(r.memory_in_use(), 50);
        drop(first);
        assert_eq!(r.memory_in_use(), 40);
        let mut third = r.reserve(&a, None).unwrap();
        let e = third.claim_memory(101).unwrap_err();
        assert_eq!((e.code, e.status.as_u16()), ("model_too_large", 413));
        third.claim_memory(60).unwrap();
        drop(second);
        drop(third);
        assert_eq!(r.memory_in_use(), 0);
    }
}
