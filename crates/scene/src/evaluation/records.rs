//! The line formats of `results.jsonl` (written by `livereg register`) and of truth files
//! (read by `livereg eval`), as in contracts.md ("`register` output"). Lengths are in the
//! scene's units.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::registration::RigidTransform;
use crate::session::FrameResult;

/// Rigid part of a frame's registration: `p_cloud = rotation · p_model + translation`
/// (model frame to camera/cloud frame), translation in scene units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RigidRecord {
    /// Row-major 3×3 rotation matrix.
    pub rotation: [[f64; 3]; 3],
    /// Translation, scene units.
    pub translation: [f64; 3],
    /// How uncertain the pose is: the 1σ misplacement of the model's surface (root mean
    /// square over its vertices) from the noise of the fit that found it, scene units; a
    /// lower bound (docs/pose.md#pose-uncertainty). Omitted when the pose was given
    /// (`rigid = "none"`) or not determined. This project's addition to the contract.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<f64>,
}

impl RigidRecord {
    /// The record of `t` (translation in metres) in scene units (`length_scale` metres per
    /// unit).
    pub fn from_transform(t: &RigidTransform, length_scale: f64) -> Self {
        let m = t.rotation.matrix();
        let v = t.translation / length_scale;
        RigidRecord {
            rotation: [
                [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
                [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
                [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
            ],
            translation: [v.x, v.y, v.z],
            uncertainty: None,
        }
    }
}

/// Per-frame diagnostics. The first three fields are the contract's; the others are this
/// project's additions and are omitted when empty.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticsRecord {
    /// Non-rigid ICP iterations of the frame.
    pub icp_iterations: usize,
    /// Newton iterations of the frame.
    pub newton_iterations: usize,
    /// RMS distance between the model's kept surface points and the cloud, scene units.
    pub surface_rms: f64,
    /// Rigid ICP iterations.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub rigid_iterations: usize,
    /// Cloud points received.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub cloud_points: usize,
    /// Model surface points paired with the cloud in the last ICP iteration.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub sources: usize,
    /// Milliseconds per stage (`rigid`, `non_rigid`, …).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub timings_ms: BTreeMap<String, f64>,
    /// Flags raised on this frame (`time_budget`, `icp_not_converged`, `failed`, …).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub flags: Vec<String>,
    /// Why the frame failed, when it did (the structures are then the last good state's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Warnings of the solver (for example a bisection limit reached), with their cause.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// The parts of `expected_error`, scene units: from the pose's uncertainty, from the
    /// deformation the cloud does not show, from the fit residual beyond the cloud's noise
    /// (`registration::error_estimate`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub expected_error_parts: Option<ErrorPartsRecord>,
}

/// The parts of a frame's expected error, scene units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ErrorPartsRecord {
    /// From the pose's uncertainty.
    pub pose: f64,
    /// From the deformation the cloud does not show.
    pub unseen: f64,
    /// From the fit residual beyond the cloud's noise.
    pub residual: f64,
    /// From the cloud's noise (absent in files written before it was estimated: 0).
    #[serde(default)]
    pub noise: f64,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// One line of `results.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResultRecord {
    /// Frame index from 0.
    pub frame: usize,
    /// Name of the frame's input (file name, or channel/sequence in a recording).
    pub source: String,
    /// Wall time of the frame's registration, ms.
    pub wall_ms: f64,
    /// Whether the registration converged.
    pub converged: bool,
    /// Rigid model→cloud transform.
    pub rigid: RigidRecord,
    /// Diagnostics.
    pub diagnostics: DiagnosticsRecord,
    /// For every structure of the scene, the deformed position of each point, in file
    /// order, in the cloud's frame, scene units.
    pub structures: BTreeMap<String, Vec<[f64; 3]>>,
    /// The contact force the registration estimated (contracts.md: the surface loads it
    /// needed): omitted (`None`) when none was estimated (rigid-only registration, no frame
    /// yet); `null` (`Some(None)`) when the frame's estimate cannot be trusted, with a flag
    /// saying why (`force_beyond_linear`, docs/contact-force.md).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "present_or_null"
    )]
    pub contact_force: Option<Option<ContactForceRecord>>,
    /// The registration's estimate of the mean error of this frame's structures, scene units
    /// (contracts.md; `null` before any frame succeeded): a bound on the true mean error in
    /// most frames (docs/error-estimate.md#expected-error).
    #[serde(default)]
    pub expected_error: Option<f64>,
}

/// The contact force a frame's registration implies: the concentrated load at the dent that
/// explains the registered deformation (N, cloud frame) and where it acts (scene units, cloud
/// frame); see docs/contact-force.md.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ContactForceRecord {
    /// Resultant force, N, cloud frame.
    pub resultant_n: [f64; 3],
    /// Its magnitude, N.
    pub magnitude_n: f64,
    /// Where the load acts: the centre of the loaded surface patch in the registered state,
    /// scene units, cloud frame.
    pub centre: [f64; 3],
    /// The estimate's expected error, N: the length the error of `resultant_n` likely has
    /// (docs/contact-force.md#expected-error); absent in results written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub expected_error_n: Option<f64>,
}

impl ContactForceRecord {
    /// The record of a session's estimate (resultant N, centre in scene units, cloud frame).
    pub fn from_estimate(c: &crate::registration::ContactForce) -> Self {
        Self {
            resultant_n: [c.resultant.x, c.resultant.y, c.resultant.z],
            magnitude_n: c.resultant.norm(),
            centre: [c.centre.x, c.centre.y, c.centre.z],
            expected_error_n: Some(c.expected_error),
        }
    }
}

/// Serde helper for a field that tells an absent key from `null`: a key that is present
/// deserialises to `Some` of its value, `null` included (`Some(None)`); an absent key stays at
/// the field's default (`None`). Use with `#[serde(default, deserialize_with = ...)]`.
pub fn present_or_null<'de, D, T>(d: D) -> Result<Option<Option<T>>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de>,
{
    Option::<T>::deserialize(d).map(Some)
}

/// One line of a truth file: `frame` and `structures` are required, the rest is ignored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthRecord {
    /// Frame index from 0.
    pub frame: usize,
    /// For every structure, the true position of each point, scene units.
    pub structures: BTreeMap<String, Vec<[f64; 3]>>,
}

impl ResultRecord {
    /// The line of `results.jsonl` for a session's frame result; `length_scale` is metres per
    /// scene unit (the rigid translation is converted to scene units).
    pub fn from_frame(r: &FrameResult, length_scale: f64) -> Self {
        let timings_ms: BTreeMap<String, f64> = r
            .times
            .named()
            .iter()
            .map(|&(name, v)| (name.to_string(), v))
            .collect();
        ResultRecord {
            frame: r.frame,
            source: r.source.clone(),
            wall_ms: r.wall_ms,
            converged: r.converged,
            rigid: RigidRecord {
                uncertainty: r.pose_uncertainty,
                ..RigidRecord::from_transform(&r.model_to_cloud, length_scale)
            },
            diagnostics: DiagnosticsRecord {
                icp_iterations: r.icp_iterations,
                newton_iterations: r.newton_iterations,
                surface_rms: r.surface_rms,
                rigid_iterations: r.rigid_iterations,
                cloud_points: r.cloud_points.0,
                sources: r.sources,
                timings_ms,
                flags: crate::session::flag_texts(&r.flags),
                error: r.error.as_ref().map(|e| e.to_string()),
                warnings: r.warnings.clone(),
                expected_error_parts: r.expected_error.map(|e| ErrorPartsRecord {
                    pose: e.pose,
                    unseen: e.unseen,
                    residual: e.residual,
                    noise: e.noise,
                }),
            },
            structures: r
                .structures
                .iter()
                .map(|(name, pts)| (name.clone(), pts.iter().map(|p| [p.x, p.y, p.z]).collect()))
                .collect(),
            contact_force: match &r.contact_force {
                Some(force) => Some(Some(ContactForceRecord::from_estimate(force))),
                None if r
                    .flags
                    .contains(&crate::session::FrameFlag::ForceBeyondLinear) =>
                {
                    Some(None)
                }
                None => None,
            },
            expected_error: r.expected_error.map(|e| e.expected),
        }
    }
}
