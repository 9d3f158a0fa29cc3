//! Registration slots: at most `worker_threads` frames are registered at once, and a slot
//! that frees goes to the waiting session whose pending frame is the freshest.
//!
//! Under overload (more frames per second than the cores register) every waiting session
//! holds exactly one pending frame, its newest (newest-wins mailboxes), aged anywhere within
//! its client's frame period. A first-come queue hands the slot to a session whose frame is on
//! average half a period old (16 ms at 30 Hz) and up to a whole period at p95; the freshest
//! frame among several waiting sessions is a few milliseconds old. So freshest-first cuts
//! end-to-end latency by most of a frame period at the same throughput. Fairness: a session
//! that has waited more than twice its fair share since its last registration goes first
//! (oldest first), so no phase pattern between clients can starve one. Its fair share is the
//! interval at which each of the competing sessions would be served in turn: sessions
//! (waiting and registering) × mean registration time / slots.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::oneshot;

/// The starvation limit is never below this (a few sessions on fast frames).
pub(crate) const MIN_STARVATION_LIMIT: Duration = Duration::from_millis(50);

/// How many fair shares a session may wait before it is served ahead of fresher frames.
pub(crate) const STARVATION_SHARES: f64 = 2.0;

/// What the slots need to know of a session that waits for one: when its pending frame
/// arrived. The server's session handle implements it; the slots know nothing else of it.
pub(crate) trait PendingFrame: Send + Sync {
    /// When the frame waiting for registration was received (`None`: none waits).
    fn pending_received(&self) -> Option<Instant>;
}

/// What the choice looks at for one waiting session.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct WaitingSession {
    /// When the session was last registered (or started waiting, if never).
    pub since: Instant,
    /// When its pending frame was received (`None`: nothing pending).
    pub pending: Option<Instant>,
}

/// Index of the session to serve:
/// 1. a session that has waited more than 1.5 × `starvation` since `since`, whatever its
///    frame's age (the longest waiting first): a client that sends one frame and waits for
///    its result never sends a fresher one;
/// 2. else, among sessions that have waited more than `starvation` and whose pending frame is
///    at most `fresh_enough` old, the longest waiting: a starving streaming session with an
///    old frame is served at the first choice after its next frame arrives, instead of
///    registering a frame up to a whole client period old;
/// 3. else the session with the freshest pending frame (ties: longest waiting).
///
/// Sessions with nothing pending come last (they only need the slot to notice they are done).
pub(crate) fn choose(
    waiting: &[WaitingSession],
    now: Instant,
    starvation: Duration,
    fresh_enough: Duration,
) -> Option<usize> {
    let waited = |i: usize| now.saturating_duration_since(waiting[i].since);
    let abandoned = (0..waiting.len())
        .filter(|&i| waited(i) > starvation.mul_f64(1.5))
        .min_by_key(|&i| waiting[i].since);
    if abandoned.is_some() {
        return abandoned;
    }
    let starving = (0..waiting.len())
        .filter(|&i| {
            let w = &waiting[i];
            now.saturating_duration_since(w.since) > starvation
                && w.pending
                    .is_none_or(|p| now.saturating_duration_since(p) <= fresh_enough)
        })
        .min_by_key(|&i| waiting[i].since);
    if starving.is_some() {
        return starving;
    }
    let freshest = (0..waiting.len())
        .filter(|&i| waiting[i].pending.is_some())
        .max_by(|&a, &b| {
            waiting[a]
                .pending
                .cmp(&waiting[b].pending)
                .then(waiting[b].since.cmp(&waiting[a].since))
        });
    freshest.or_else(|| (0..waiting.len()).min_by_key(|&i| waiting[i].since))
}

struct Waiter {
    session: Arc<dyn PendingFrame>,
    since: Instant,
    wake: oneshot::Sender<()>,
}

struct Inner {
    free: usize,
    waiting: Vec<Waiter>,
    /// Mean time a slot is held, s (exponential average; `None` before the first release).
    mean_hold: Option<f64>,
}

/// The server's registration slots.
pub(crate) struct RegistrationSlots {
    inner: Mutex<Inner>,
    total: usize,
    min_starvation: Duration,
}

impl std::fmt::Debug for RegistrationSlots {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RegistrationSlots")
            .field("free", &self.free())
            .field("waiting", &self.waiting())
            .field("slots", &self.total)
            .field("min_starvation", &self.min_starvation)
            .finish()
    }
}

/// A held slot; dropping it hands the slot on.
pub(crate) struct SlotPermit {
    slots: Arc<RegistrationSlots>,
    granted: Instant,
}

impl Drop for SlotPermit {
    fn drop(&mut self) {
        self.slots.release(Some(self.granted.elapsed()));
    }
}

/// Releases a slot that was handed to a waiter whose `acquire` was dropped before taking it.
struct PendingWake {
    rx: Option<oneshot::Receiver<()>>,
    slots: Arc<RegistrationSlots>,
}

impl Drop for PendingWake {
    fn drop(&mut self) {
        if let Some(mut rx) = self.rx.take() {
            rx.close();
            if rx.try_recv().is_ok() {
                self.slots.release(None);
            }
        }
    }
}

impl RegistrationSlots {
    /// `n` slots (at least 1), starvation limit at least [`MIN_STARVATION_LIMIT`].
    pub(crate) fn new(n: usize) -> Arc<Self> {
        Self::with_min_starvation(n, MIN_STARVATION_LIMIT)
    }

    /// `n` slots with a given floor of the starvation limit.
    pub(crate) fn with_min_starvation(n: usize, min_starvation: Duration) -> Arc<Self> {
        Arc::new(Self {
            inner: Mutex::new(Inner {
                free: n.max(1),
                waiting: Vec::new(),
                mean_hold: None,
            }),
            total: n.max(1),
            min_starvation,
        })
    }

    /// The starvation limit now: [`STARVATION_SHARES`] fair shares, at least the floor.
    fn starvation(&self, inner: &Inner) -> Duration {
        let busy = self.total.saturating_sub(inner.free);
        let share = inner.mean_hold.unwrap_or(0.0) * (inner.waiting.len() + busy) as f64
            / self.total as f64;
        Duration::from_secs_f64(STARVATION_SHARES * share).max(self.min_starvation)
    }

    /// Waits for a slot for `session`, last registered at `since`.
    pub(crate) async fn acquire<S: PendingFrame + 'static>(
        self: &Arc<Self>,
        session: &Arc<S>,
        since: Instant,
    ) -> SlotPermit {
        let rx = {
            let mut inner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
            if inner.free > 0 {
                inner.free -= 1;
                return SlotPermit {
                    slots: self.clone(),
                    granted: Instant::now(),
                };
            }
            let (tx, rx) = oneshot::channel();
            inner.waiting.push(Waiter {
                session: session.clone(),
                since,
                wake: tx,
            });
            rx
        };
        let mut pending = PendingWake {
            rx: Some(rx),
            slots: self.clone(),
        };
        let rx = pending.rx.as_mut().expect("set above");
        // The sender lives in `waiting` until a slot is handed over; it is only dropped
        // unsent when the slots themselves are dropped, which outlive every worker.
        let _ = rx.await;
        pending.rx = None;
        SlotPermit {
            slots: self.clone(),
            granted: Instant::now(),
        }
    }

    /// Hands a freed slot (held for `held`, when it was used) to the waiter [`choose`]
    /// picks, or keeps it free.
    fn release(&self, held: Option<Duration>) {
        let mut inner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(h) = held {
            let h = h.as_secs_f64();
            inner.mean_hold = Some(inner.mean_hold.map_or(h, |m| 0.9 * m + 0.1 * h));
        }
        // The slot being handed on still counts as busy in the fair share. A starving
        // session's frame must be at most one mean registration old to jump the queue.
        let starvation = self.starvation(&inner);
        let fresh_enough = inner
            .mean_hold
            .map_or(Duration::MAX, Duration::from_secs_f64);
        loop {
            let now = Instant::now();
            let view: Vec<WaitingSession> = inner
                .waiting
                .iter()
                .map(|w| WaitingSession {
                    since: w.since,
                    pending: w.session.pending_received(),
                })
                .collect();
            let Some(i) = choose(&view, now, starvation, fresh_enough) else {
                inner.free += 1;
                return;
            };
            let w = inner.waiting.swap_remove(i);
            if w.wake.send(()).is_ok() {
                return;
            }
            // That waiter is gone: try the next.
        }
    }

    /// Slots free now.
    pub(crate) fn free(&self) -> usize {
        self.inner.lock().map(|i| i.free).unwrap_or_default()
    }

    /// Sessions waiting for a slot.
    pub(crate) fn waiting(&self) -> usize {
        self.inner
            .lock()
            .map(|i| i.waiting.len())
            .unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A session as the slots see it: a name and the arrival of its pending frame.
    struct Waiting {
        id: String,
        pending: Mutex<Option<Instant>>,
    }

    fn session(name: &str) -> Arc<Waiting> {
        Arc::new(Waiting {
            id: name.into(),
            pending: Mutex::new(None),
        })
    }

    impl PendingFrame for Waiting {
        fn pending_received(&self) -> Option<Instant> {
            *self.pending.lock().unwrap()
        }
    }

    fn frame_now(h: &Waiting) {
        *h.pending.lock().unwrap() = Some(Instant::now());
    }

    /// With the one slot held, two sessions wait with frames received 20 ms apart: the slot
    /// goes to the newer frame's session, then to the other; a waiter dropped after being
    /// chosen hands its slot on.
    #[tokio::test]
    async fn a_freed_slot_goes_to_the_freshest_pending_frame() {
        let slots = RegistrationSlots::new(1);
        let (a, b, c) = (session("a"), session("b"), session("c"));
        let start = Instant::now();
        let held = slots.acquire(&c, start).await;
        frame_now(&a);
        tokio::time::sleep(Duration::from_millis(20)).await;
        frame_now(&b);
        let order = Arc::new(Mutex::new(Vec::new()));
        let task = |h: Arc<Waiting>| {
            let (slots, order) = (slots.clone(), order.clone());
            tokio::spawn(async move {
                let p = slots.acquire(&h, start).await;
                order.lock().unwrap().push(h.id.clone());
                tokio::time::sleep(Duration::from_millis(5)).await;
                drop(p);
            })
        };
        let (ta, tb) = (task(a.clone()), task(b.clone()));
        while slots.waiting() < 2 {
            tokio::task::yield_now().await;
        }
        drop(held);
        ta.await.unwrap();
        tb.await.unwrap();
        assert_eq!(
            *order.lock().unwrap(),
            vec!["b".to_string(), "a".to_string()]
        );
        assert_eq!(slots.free(), 1);

        // A waiter whose task is aborted after being handed the slot passes it on.
        let held = slots.acquire(&c, Instant::now()).await;
        let lost = {
            let slots = slots.clone();
            let a = a.clone();
            tokio::spawn(async move {
                let _p = slots.acquire(&a, Instant::now()).await;
                std::future::pending::<()>().await;
            })
        };
        while slots.waiting() < 1 {
            tokio::task::yield_now().await;
        }
        drop(held);
        lost.abort();
        let _ = lost.await;
        let again = tokio::time::timeout(Duration::from_secs(5), slots.acquire(&b, Instant::now()))
            .await
            .expect("the slot was not lost");
        drop(again);
        assert_eq!(slots.free(), 1);
    }

    #[test]
    fn the_freshest_frame_wins_unless_someone_starves() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let now = at(200);
        let limit = Duration::from_millis(120);
        let fresh = Duration::from_secs(1);
        // Last registered at 150, 120 and 100 ms; frames received at 170, 195 and 180 ms.
        let w = [
            WaitingSession {
                since: at(150),
                pending: Some(at(170)),
            },
            WaitingSession {
                since: at(120),
                pending: Some(at(195)),
            },
            WaitingSession {
                since: at(100),
                pending: Some(at(180)),
            },
        ];
        assert_eq!(choose(&w, now, limit, fresh), Some(1), "freshest frame");
        // Equal frames: the one waiting longest.
        let tie = [
            WaitingSession {
                since: at(150),
                pending: Some(at(190)),
            },
            WaitingSession {
                since: at(110),
                pending: Some(at(190)),
            },
        ];
        assert_eq!(choose(&tie, now, limit, fresh), Some(1));
        // One session last served 130 ms ago (> limit) with an old frame: it goes first,
        // and of two starving ones the longer-waiting.
        let mut s = w;
        s[0].since = at(70);
        assert_eq!(choose(&s, now, limit, fresh), Some(0));
        s[2].since = at(60);
        assert_eq!(choose(&s, now, limit, fresh), Some(2));
        // Only frames at most 25 ms old may jump the queue: `s[2]`'s (20 ms) may, `s[0]`'s
        // (30 ms) may not; with neither fresh enough, the freshest frame wins again.
        let gate = Duration::from_millis(25);
        assert_eq!(choose(&s, now, limit, gate), Some(2));
        s[2].pending = Some(at(160));
        assert_eq!(choose(&s, now, limit, gate), Some(1));
        // A request/response client (one frame, waiting for its result) never gets a fresher
        // frame: past 1.5 × the limit it is served whatever its frame's age.
        let mut r = w;
        r[0] = WaitingSession {
            since: at(30),
            pending: Some(at(30)),
        };
        // Waited 170 ms (starving, frame too old to jump the queue): the freshest wins.
        assert_eq!(choose(&r, now, limit, gate), Some(1));
        // Waited 200 ms > 1.5 × 120: served.
        r[0].since = t0;
        assert_eq!(choose(&r, now, limit, gate), Some(0));
        // Nothing pending anywhere: the longest waiting (it only needs to see it is done).
        let idle = [
            WaitingSession {
                since: at(150),
                pending: None,
            },
            WaitingSession {
                since: at(140),
                pending: None,
            },
        ];
        assert_eq!(choose(&idle, now, limit, fresh), Some(1));
        assert_eq!(choose(&[], now, limit, fresh), None);
    }
}
