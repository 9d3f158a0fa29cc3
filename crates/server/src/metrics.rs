//! Prometheus metrics in the text exposition format (version 0.0.4), written by hand: a few
//! counters with labels, gauges and histograms, no dependency.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};
use std::sync::Mutex;

/// Bucket upper bounds of the latency histograms, seconds.
pub(crate) const LATENCY_BUCKETS: &[f64] = &[
    0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0,
];

/// A histogram with fixed buckets (seconds).
#[derive(Debug)]
pub(crate) struct Histogram {
    bounds: &'static [f64],
    counts: Vec<AtomicU64>,
    sum_micros: AtomicU64,
    count: AtomicU64,
}

impl Histogram {
    /// An empty histogram with upper bounds `bounds` (seconds, increasing).
    pub(crate) fn new(bounds: &'static [f64]) -> Self {
        Self {
            bounds,
            counts: bounds.iter().map(|_| AtomicU64::new(0)).collect(),
            sum_micros: AtomicU64::new(0),
            count: AtomicU64::new(0),
        }
    }

    /// Records one observation, seconds (non-finite or negative values count as 0).
    pub(crate) fn observe(&self, seconds: f64) {
        let s = if seconds.is_finite() && seconds > 0.0 {
            seconds
        } else {
            0.0
        };
        for (b, c) in self.bounds.iter().zip(&self.counts) {
            if s <= *b {
                c.fetch_add(1, Ordering::Relaxed);
            }
        }
        self.sum_micros
            .fetch_add((s * 1e6) as u64, Ordering::Relaxed);
        self.count.fetch_add(1, Ordering::Relaxed);
    }

    /// Observations so far.
    pub(crate) fn count(&self) -> u64 {
        self.count.load(Ordering::Relaxed)
    }

    fn write(&self, out: &mut String, name: &str, help: &str) {
        let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} histogram");
        for (b, c) in self.bounds.iter().zip(&self.counts) {
            let _ = writeln!(
                out,
                "{name}_bucket{{le=\"{b}\"}} {}",
                c.load(Ordering::Relaxed)
            );
        }
        let n = self.count();
        let _ = writeln!(out, "{name}_bucket{{le=\"+Inf\"}} {n}");
        let _ = writeln!(
            out,
            "{name}_sum {}",
            self.sum_micros.load(Ordering::Relaxed) as f64 / 1e6
        );
        let _ = writeln!(out, "{name}_count {n}");
    }
}

/// Counter families: name, help, label name.
const COUNTERS: &[(&str, &str, &str)] = &[
    (
        "livereg_frames_total",
        "Frames by outcome: registered, failed (registered with an error), skipped (a newer frame won), rejected (refused before registration).",
        "outcome",
    ),
    (
        "livereg_frame_failures_total",
        "Failed or rejected frames by cause.",
        "cause",
    ),
    (
        "livereg_errors_total",
        "Errors answered to clients, by code.",
        "code",
    ),
    (
        "livereg_recording_errors_total",
        "Session recording failures by stage (create, write, finish); the session goes on, unrecorded from there.",
        "stage",
    ),
    (
        "livereg_connections_refused_total",
        "HTTP/WebSocket connections closed at once because too many were open, by limit (server, address).",
        "limit",
    ),
    (
        "livereg_recordings_removed_total",
        "Finished recordings removed by the retention policy, by reason (age, size).",
        "reason",
    ),
    (
        "livereg_igtl_messages_total",
        "OpenIGTLink messages received, by kind (cloud, refused).",
        "kind",
    ),
    (
        "livereg_sessions_closed_total",
        "Sessions closed, by reason (client, idle, shutdown, failed).",
        "reason",
    ),
];

/// Every metric of the server.
#[derive(Debug)]
pub(crate) struct Metrics {
    counters: Mutex<BTreeMap<(&'static str, String), u64>>,
    /// Open sessions.
    pub sessions: AtomicI64,
    /// Sessions created since start.
    pub sessions_created: AtomicU64,
    /// Open WebSocket and gRPC streams.
    pub streams: AtomicI64,
    /// Registration wall time per frame, seconds.
    pub registration: Histogram,
    /// From receipt of a frame to its result being ready, seconds.
    pub latency: Histogram,
    /// Wait for a registration slot, seconds.
    pub queue_wait: Histogram,
    /// Session creation (scene load and model build), seconds.
    pub session_build: Histogram,
}

impl Default for Metrics {
    fn default() -> Self {
        Self {
            counters: Mutex::new(BTreeMap::new()),
            sessions: AtomicI64::new(0),
            sessions_created: AtomicU64::new(0),
            streams: AtomicI64::new(0),
            registration: Histogram::new(LATENCY_BUCKETS),
            latency: Histogram::new(LATENCY_BUCKETS),
            queue_wait: Histogram::new(LATENCY_BUCKETS),
            session_build: Histogram::new(LATENCY_BUCKETS),
        }
    }
}

fn escape(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

impl Metrics {
    /// Adds `n` to the counter `family` (one of the families above) with label value `label`.
    pub(crate) fn inc(&self, family: &'static str, label: &str, n: u64) {
        debug_assert!(COUNTERS.iter().any(|(f, _, _)| *f == family));
        if let Ok(mut c) = self.counters.lock() {
            *c.entry((family, label.to_string())).or_insert(0) += n;
        }
    }

    /// The value of a counter (0 when never incremented).
    pub(crate) fn counter(&self, family: &'static str, label: &str) -> u64 {
        self.counters
            .lock()
            .map(|c| c.get(&(family, label.to_string())).copied().unwrap_or(0))
            .unwrap_or(0)
    }

    /// The text exposition of every metric.
    pub(crate) fn render(&self) -> String {
        let mut out = String::new();
        let counters = self.counters.lock().map(|c| c.clone()).unwrap_or_default();
        for (family, help, label) in COUNTERS {
            let _ = writeln!(out, "# HELP {family} {help}\n# TYPE {family} counter");
            for ((f, value), n) in &counters {
                if f == family {
                    let _ = writeln!(out, "{family}{{{label}=\"{}\"}} {n}", escape(value));
                }
            }
        }
        let _ = writeln!(
            out,
            "# HELP livereg_sessions Open sessions.\n# TYPE livereg_sessions gauge\nlivereg_sessions {}",
            self.sessions.load(Ordering::Relaxed)
        );
        let _ = writeln!(
            out,
            "# HELP livereg_sessions_created_total Sessions created.\n# TYPE livereg_sessions_created_total counter\nlivereg_sessions_created_total {}",
            self.sessions_created.load(Ordering::Relaxed)
        );
        let _ = writeln!(
            out,
            "# HELP livereg_streams Open WebSocket and gRPC frame streams.\n# TYPE livereg_streams gauge\nlivereg_streams {}",
            self.streams.load(Ordering::Relaxed)
        );
        self.registration.write(
            &mut out,
            "livereg_registration_seconds",
            "Registration wall time per frame.",
        );
        self.latency.write(
            &mut out,
            "livereg_frame_latency_seconds",
            "From receipt of a frame to its result being ready (queue wait + registration + encoding).",
        );
        self.queue_wait.write(
            &mut out,
            "livereg_queue_wait_seconds",
            "Wait of a frame for a registration slot.",
        );
        self.session_build.write(
            &mut out,
            "livereg_session_build_seconds",
            "Session creation: scene load and model build.",
        );
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exposition_has_counters_and_cumulative_buckets() {
        let m = Metrics::default();
        m.inc("livereg_frames_total", "registered", 2);
        m.inc("livereg_frame_failures_total", "non-finite", 1);
        m.registration.observe(0.003);
        m.registration.observe(0.7);
        let t = m.render();
        assert!(t.contains("livereg_frames_total{outcome=\"registered\"} 2"));
        assert!(t.contains("livereg_frame_failures_total{cause=\"non-finite\"} 1"));
        assert!(t.contains("livereg_registration_seconds_bucket{le=\"0.005\"} 1"));
        assert!(t.contains("livereg_registration_seconds_bucket{le=\"1\"} 2"));
        assert!(t.contains("livereg_registration_seconds_count 2"));
    }
}
