//! The JSON object `livereg simulate` prints on stdout (contract: "`simulate` output").
//!
//! Field order is the contract's key order; the optional extras (`outcome`, `message`,
//! `bisections`) follow it. Lengths are in scene units, like the scene.

use serde::{Deserialize, Serialize};

use super::types::Vec3;

/// Size of the immersed-boundary grid that was simulated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
pub struct GridSummary {
    /// Number of grid nodes (each carries 3 degrees of freedom).
    pub nodes: usize,
    /// Number of active cells (entirely or partly inside the surface).
    pub cells: usize,
    /// Number of those cells cut by the surface.
    pub cut_cells: usize,
}

/// Displacement of one probe point.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
pub struct ProbeResult {
    /// Rest position, in scene units (as given in the scene / probe file).
    pub point: Vec3,
    /// Displacement `x − X`, in scene units.
    pub displacement: Vec3,
}

/// The result of `livereg simulate`, printed as one JSON object:
///
/// ```json
/// {"converged": true, "newton_iterations": 37, "load_steps": 10, "wall_ms": 84.2,
///  "grid": {"nodes": 1234, "cells": 900, "cut_cells": 310},
///  "probes": [{"point": [0.0, 0.0, 0.08], "displacement": [0.0, -0.0123, -0.0004]}],
///  "max_displacement": 0.0131, "outcome": "converged", "bisections": 0}
/// ```
///
/// Non-finite floats serialise as `null` (serde_json); keep them finite.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct SimulateReport {
    /// True when the full load was reached with every step converged.
    pub converged: bool,
    /// Total Newton iterations over all load steps (including failed, bisected attempts).
    pub newton_iterations: usize,
    /// Load steps completed (converged increments, counting bisected sub-steps).
    pub load_steps: usize,
    /// Wall-clock time of the simulation in milliseconds.
    pub wall_ms: f64,
    /// Grid size.
    pub grid: GridSummary,
    /// One entry per probe point, in the order of the scene's `[[probe]]` entries and points.
    pub probes: Vec<ProbeResult>,
    /// Largest nodal (or embedded-point) displacement norm, in scene units.
    pub max_displacement: f64,
    /// How it ended (see [`crate::mechanics::Outcome`]): `"converged"`, `"iteration-cap"`, `"diverged"` or
    /// `"inverted"`.
    pub outcome: String,
    /// A human-readable detail (why it failed, warnings); omitted when `None`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub message: Option<String>,
    /// Number of increment halvings that were needed.
    #[serde(default)]
    pub bisections: usize,
}

impl SimulateReport {
    /// The report as one line of compact JSON (what `livereg simulate` prints).
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("a SimulateReport always serialises")
    }
}
