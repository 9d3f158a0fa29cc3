//! Target registration error (TRE): the distance between each registered point and its true
//! position, per frame, per structure and in summary.
//!
//! Distances are in the units of the files (the scene's units, for example millimetres for the
//! bundled phantom's scenes); nothing is converted.

use std::collections::btree_map::Entry;
use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde::Serialize;

use super::error::EvalError;
use super::records::{ResultRecord, TruthRecord};

/// TRE of one structure in one frame, scene units.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StructureFrameTre {
    /// Mean distance over the structure's points.
    pub mean: f64,
    /// Largest distance.
    pub max: f64,
    /// Number of points.
    pub points: usize,
}

/// TRE of one frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameReport {
    /// Frame index.
    pub frame: usize,
    /// The result's `source` (input name).
    pub source: String,
    /// The result's `converged`.
    pub converged: bool,
    /// The result's `diagnostics.error`, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// `true` when the result did not converge or carries an error. The frame is evaluated
    /// all the same (its structures are then whatever the registration reported, typically the
    /// last good state).
    pub failed: bool,
    /// Per structure of the truth frame.
    pub structures: BTreeMap<String, StructureFrameTre>,
    /// Mean distance over all points of all structures of the frame (each point counts once,
    /// so larger structures weigh more), scene units.
    pub mean: f64,
    /// Largest distance over all points of the frame, scene units.
    pub max: f64,
    /// Number of points of the frame, all structures together.
    pub points: usize,
}

/// Statistics of a non-empty set of distances, scene units.
///
/// `median` and `p95` are percentiles by linear interpolation between closest ranks (see
/// [`percentile`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    /// Number of distances.
    pub count: usize,
    /// Arithmetic mean.
    pub mean: f64,
    /// 50th percentile.
    pub median: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Largest distance.
    pub max: f64,
}

impl Summary {
    /// Statistics of `values`, or `None` if it is empty.
    pub fn of(values: &[f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        let count = sorted.len();
        Some(Self {
            count,
            mean: sorted.iter().sum::<f64>() / count as f64,
            median: percentile(&sorted, 0.5),
            p95: percentile(&sorted, 0.95),
            max: sorted[count - 1],
        })
    }
}

/// The `p`-quantile (`p` in `[0, 1]`) of `sorted` (ascending, non-empty), by linear
/// interpolation between closest ranks (Hyndman & Fan type 7, NumPy's and R's default): with
/// `n` values `x[0] ≤ … ≤ x[n−1]`, `h = (n − 1)·p`, the result is
/// `x[⌊h⌋] + (h − ⌊h⌋)·(x[⌊h⌋+1] − x[⌊h⌋])`. So `p = 0` gives the minimum, `p = 1` the
/// maximum, and `p = 0.5` the usual median (the mean of the two middle values when `n` is even).
///
/// # Panics
/// If `sorted` is empty or `p` is outside `[0, 1]`.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    assert!(!sorted.is_empty(), "percentile of an empty set");
    assert!((0.0..=1.0).contains(&p), "percentile {p} outside [0, 1]");
    let h = (sorted.len() - 1) as f64 * p;
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// The evaluation of a results file against a truth file. Distances in scene units.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EvalReport {
    /// Per evaluated frame, by increasing frame index.
    pub frames: Vec<FrameReport>,
    /// Per structure, over all its points in all evaluated frames.
    pub structures: BTreeMap<String, Summary>,
    /// Over all points of all structures of all evaluated frames.
    pub overall: Summary,
    /// Truth frames with no result (not evaluated), increasing.
    pub missing_frames: Vec<usize>,
    /// Evaluated frames whose result did not converge or carries an error, increasing.
    pub failed_frames: Vec<usize>,
}

/// Euclidean distance between `a` and `b`, without overflow for large coordinates.
fn distance(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1]).hypot(a[2] - b[2])
}

/// Frames of `records` by index, refusing duplicates.
fn by_frame<'a, T>(
    records: &'a [T],
    frame: impl Fn(&T) -> usize,
    what: &'static str,
) -> Result<BTreeMap<usize, &'a T>, EvalError> {
    let mut map = BTreeMap::new();
    for r in records {
        match map.entry(frame(r)) {
            Entry::Vacant(v) => {
                v.insert(r);
            }
            Entry::Occupied(o) => {
                return Err(EvalError::DuplicateFrame {
                    what,
                    frame: *o.key(),
                })
            }
        }
    }
    Ok(map)
}

/// Compares `results` with `truth`, matching frames by their `frame` index (the order of the
/// records does not matter).
///
/// Every result frame must have a truth frame; truth frames without a result are listed in
/// [`EvalReport::missing_frames`]. For each evaluated frame, every structure of the truth frame
/// must be in the result with the same number of points, point `i` of the result being
/// compared with point `i` of the truth; structures of the result that the truth does not have
/// are ignored. Frames whose result did not converge or carries `diagnostics.error` are
/// evaluated and listed in [`EvalReport::failed_frames`].
///
/// # Errors
/// [`EvalError::NoResults`] if `results` is empty; [`EvalError::DuplicateFrame`] if a frame
/// index repeats in either input; [`EvalError::FrameWithoutTruth`];
/// [`EvalError::EmptyTruthFrame`] for a truth frame without structures;
/// [`EvalError::MissingStructure`], [`EvalError::PointCount`], [`EvalError::EmptyStructure`].
pub fn evaluate(results: &[ResultRecord], truth: &[TruthRecord]) -> Result<EvalReport, EvalError> {
    if results.is_empty() {
        return Err(EvalError::NoResults);
    }
    let results = by_frame(results, |r| r.frame, "result")?;
    let truth = by_frame(truth, |t| t.frame, "truth")?;

    let mut frames = Vec::with_capacity(results.len());
    let mut per_structure: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut all = Vec::new();
    let mut failed_frames = Vec::new();
    for (&frame, result) in &results {
        let truth_frame = truth
            .get(&frame)
            .ok_or(EvalError::FrameWithoutTruth { frame })?;
        if truth_frame.structures.is_empty() {
            return Err(EvalError::EmptyTruthFrame { frame });
        }
        let mut structures = BTreeMap::new();
        let mut frame_distances = Vec::new();
        for (name, true_points) in &truth_frame.structures {
            if true_points.is_empty() {
                return Err(EvalError::EmptyStructure {
                    frame,
                    structure: name.clone(),
                });
            }
            let points =
                result
                    .structures
                    .get(name)
                    .ok_or_else(|| EvalError::MissingStructure {
                        frame,
                        structure: name.clone(),
                    })?;
            if points.len() != true_points.len() {
                return Err(EvalError::PointCount {
                    frame,
                    structure: name.clone(),
                    result: points.len(),
                    truth: true_points.len(),
                });
            }
            let d: Vec<f64> = points
                .iter()
                .zip(true_points)
                .map(|(p, t)| distance(p, t))
                .collect();
            structures.insert(
                name.clone(),
                StructureFrameTre {
                    mean: d.iter().sum::<f64>() / d.len() as f64,
                    max: d.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                    points: d.len(),
                },
            );
            per_structure
                .entry(name.clone())
                .or_default()
                .extend_from_slice(&d);
            frame_distances.extend_from_slice(&d);
        }
        let failed = !result.converged || result.diagnostics.error.is_some();
        if failed {
            failed_frames.push(frame);
        }
        all.extend_from_slice(&frame_distances);
        frames.push(FrameReport {
            frame,
            source: result.source.clone(),
            converged: result.converged,
            error: result.diagnostics.error.clone(),
            failed,
            structures,
            mean: frame_distances.iter().sum::<f64>() / frame_distances.len() as f64,
            max: frame_distances
                .iter()
                .copied()
                .fold(f64::NEG_INFINITY, f64::max),
            points: frame_distances.len(),
        });
    }
    let missing_frames = truth
        .keys()
        .copied()
        .filter(|f| !results.contains_key(f))
        .collect();
    Ok(EvalReport {
        frames,
        structures: per_structure
            .into_iter()
            .map(|(name, d)| (name, Summary::of(&d).expect("structures are non-empty")))
            .collect(),
        overall: Summary::of(&all).expect("at least one frame with points"),
        missing_frames,
        failed_frames,
    })
}

/// `v` with four significant digits (scientific notation for very small or large values).
fn sig(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return v.to_string();
    }
    let magnitude = v.abs().log10().floor() as i32;
    if !(-5..=6).contains(&magnitude) {
        return format!("{v:.3e}");
    }
    let decimals = (3 - magnitude).max(0) as usize;
    format!("{v:.decimals$}")
}

/// Frame indices as `2, 5, 7`, the first 20 only followed by `…` when there are more.
fn frame_list(frames: &[usize]) -> String {
    let mut s = frames
        .iter()
        .take(20)
        .map(usize::to_string)
        .collect::<Vec<_>>()
        .join(", ");
    if frames.len() > 20 {
        s.push_str(", …");
    }
    s
}

impl EvalReport {
    /// A human-readable summary: counts of evaluated, failed and missing frames, a table of
    /// count, mean, median, p95 and max per structure and over all, and the frame with the
    /// largest mean TRE. Values in scene units with four significant digits.
    pub fn to_table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "TRE in scene units over {} frame(s); {} failed (not converged or with an error){}",
            self.frames.len(),
            self.failed_frames.len(),
            if self.failed_frames.is_empty() {
                String::new()
            } else {
                format!(": {}", frame_list(&self.failed_frames))
            }
        );
        if !self.missing_frames.is_empty() {
            let _ = writeln!(
                s,
                "{} truth frame(s) without a result: {}",
                self.missing_frames.len(),
                frame_list(&self.missing_frames)
            );
        }
        let width = self
            .structures
            .keys()
            .map(|k| k.chars().count())
            .max()
            .unwrap_or(0)
            .max("structure".len());
        let _ = writeln!(
            s,
            "{:<width$}  {:>8}  {:>10}  {:>10}  {:>10}  {:>10}",
            "structure", "points", "mean", "median", "p95", "max"
        );
        let rows = self
            .structures
            .iter()
            .map(|(k, v)| (k.as_str(), v))
            .chain(std::iter::once(("all", &self.overall)));
        for (name, v) in rows {
            let _ = writeln!(
                s,
                "{:<width$}  {:>8}  {:>10}  {:>10}  {:>10}  {:>10}",
                name,
                v.count,
                sig(v.mean),
                sig(v.median),
                sig(v.p95),
                sig(v.max)
            );
        }
        if let Some(worst) = self.frames.iter().max_by(|a, b| a.mean.total_cmp(&b.mean)) {
            let _ = writeln!(
                s,
                "worst frame: {} ({}): mean {}, max {}",
                worst.frame,
                worst.source,
                sig(worst.mean),
                sig(worst.max)
            );
        }
        s
    }
}
