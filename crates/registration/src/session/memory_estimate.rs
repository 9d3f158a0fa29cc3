//! How much memory a registration session will hold once it has registered frames, estimated
//! when it is created, before its first frame: a server admits a session only when its
//! estimate fits the memory budget left.
//!
//! The estimate is the peak live heap of a session over its first frames, summed over its
//! models (the fine one, and the coarse one of a coarse-to-fine start), as a linear function
//! of four sizes of each model:
//!
//! | size | bytes each | what holds it |
//! | --- | --- | --- |
//! | value of the tangent's direct factor `L` | 20 | the cold and warm solvers' f64 factors, a single-precision copy |
//! | active grid cell | 20 KiB | assembly slots, cell tangents and caches of its integration points |
//! | embedded point (surface vertex, structure point, probe) | 420 | embedding, k-d trees, correspondences |
//! | triangle (surface, structure meshes) | 600 | adjacency, surface samples of the rigid and data terms |
//! | the normals' averaging | its own count | samples and vertex–cluster entries (`NormalsAtScale::heap_bytes`, counted, not fitted) |
//! | the surface's topology for signed distances | its own count | triangles and the triangles around each vertex (`SurfaceTopology::heap_bytes`, counted, not fitted) |
//! | the rest compliance of the contact force | 8 per factor value, 16 per tangent entry | its own f64 factor and copy of the rest tangent (`RestCompliance`, counted, not fitted; non-rigid sessions) |
//! | the contact refit's solver | 8 per factor value, 16 per tangent entry | its own f64 factor and tangent (`registration.contact_refit`, counted like the rest compliance, not fitted; non-rigid sessions) |
//! | the linear law's kept stiffness | 16 per tangent entry, 8 per unknown | its matrix and product (`StaticProblem`, small-strain linear models only, counted, not fitted) |
//! | the linear law's refit columns | 24 per unknown per vertex, for twice the most surface vertices within the contact radius, at most 64 MiB | the held body's compliance columns (`HeldColumns`, small-strain linear models that refit, counted, not fitted) |
//! | the still window's registered points | 800 per point, at the `max_cloud_points` cap | the data term, trees and neighbour lists of a union of clouds (non-rigid sessions with `still_frames` > 1; measured: below) |
//!
//! The factor's size comes from the same symbolic analysis the solver makes (fill-reducing
//! ordering included), without allocating the factor: it grows faster than the grid (about
//! `n^{4/3}` for nested dissection), so no per-node rule could follow it. The four weights
//! were fitted by least squares to the peaks a counting allocator measured on three surfaces
//! (the phantom, the lobe, the tool-indentation liver; 11 grids from 435 to 7,794 unknowns)
//! and predicted a fourth surface (the cylinder, 768 to 4,968 unknowns) within 5 %;
//! `tests/session_memory.rs` checks all four against the allocator.
//!
//! The fit's sessions registered one cloud of a third of the surface's vertices per frame.
//! A still window registers the union of its clouds, up to `max_cloud_points` points: where
//! that test's frames gather, the peaks grow by 0.6–0.7 MiB for 854 more points on the
//! phantom and 0.2–0.5 MiB for 1,251 on the tool-indentation liver (without a term for them,
//! the coarse phantom's estimate is 0.79 of its peak). The window is counted at its cap,
//! [`BYTES_PER_WINDOW_POINT`] each (the phantom's, the larger).

use crate::linalg::{predicted_factor_len, SolverKind};
use crate::model::Model;
use crate::registration::linear_held_body::HELD_COLUMNS_BUDGET_BYTES;

/// Sizes of one model that drive a session's memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ModelSize {
    /// Unknowns (3 per grid node).
    pub dofs: usize,
    /// Stored entries of the tangent's lower triangle.
    pub tangent_entries: usize,
    /// Stored values of the tangent's direct factor `L` (0 when the conjugate gradient is
    /// used).
    pub factor_values: usize,
    /// Active grid cells.
    pub cells: usize,
    /// Integration points of all cells.
    pub quadrature_points: usize,
    /// Surface vertices plus structure and probe points (each embedded in the grid).
    pub embedded_points: usize,
    /// Surface and structure triangles.
    pub triangles: usize,
    /// Heap bytes of the normals' averaging (`NormalsAtScale::heap_bytes`; set by the
    /// session, which shares one between its stages).
    pub normal_bytes: usize,
    /// Bytes of the session's surface topology for signed distances
    /// ([`SurfaceTopology::heap_bytes`](crate::registration::SurfaceTopology::heap_bytes);
    /// counted by the session, 0 from [`ModelSize::of`]).
    pub topology_bytes: usize,
}

/// Bytes per value of the direct factor `L`.
pub(crate) const BYTES_PER_FACTOR_VALUE: f64 = 20.0;
/// Bytes per active grid cell.
pub(crate) const BYTES_PER_CELL: f64 = 20.0 * 1024.0;
/// Bytes per embedded point (surface vertex, structure point, probe).
pub(crate) const BYTES_PER_EMBEDDED_POINT: f64 = 420.0;
/// Bytes per surface or structure triangle.
pub(crate) const BYTES_PER_TRIANGLE: f64 = 600.0;
/// Bytes per value of the rest compliance's factor (one f64).
pub(crate) const BYTES_PER_REST_FACTOR_VALUE: f64 = 8.0;
/// Bytes per entry of the rest compliance's tangent (an f64 value and a row index).
pub(crate) const BYTES_PER_REST_TANGENT_ENTRY: f64 = 16.0;

/// Bytes per point of a still window's union of clouds, beyond what the fitted weights hold
/// (module doc).
pub(crate) const BYTES_PER_WINDOW_POINT: f64 = 800.0;

/// What a still window of up to `max_cloud_points` points adds to a session's peak, bytes
/// (module doc); 0 when frames are registered alone (`still_frames` ≤ 1).
pub fn still_window_bytes(still_frames: usize, max_cloud_points: usize) -> u64 {
    if still_frames <= 1 {
        return 0;
    }
    (BYTES_PER_WINDOW_POINT * max_cloud_points as f64).ceil() as u64
}

impl ModelSize {
    /// Estimated peak live heap of a session's registration with this model, bytes (see the
    /// module's table).
    pub fn estimated_bytes(&self) -> u64 {
        let surface = BYTES_PER_EMBEDDED_POINT * self.embedded_points as f64
            + BYTES_PER_TRIANGLE * self.triangles as f64
            + self.normal_bytes as f64
            + self.topology_bytes as f64;
        self.estimated_grid_bytes() + surface.ceil() as u64
    }

    /// The grid's part of [`ModelSize::estimated_bytes`] (factor and cells), bytes: what the
    /// coarse model of a coarse-to-fine start adds to a session (the per-point and
    /// per-triangle weights stand mostly for the frames' correspondences and search trees,
    /// which the fine model holds once).
    pub fn estimated_grid_bytes(&self) -> u64 {
        let bytes =
            BYTES_PER_FACTOR_VALUE * self.factor_values as f64 + BYTES_PER_CELL * self.cells as f64;
        bytes.ceil() as u64
    }

    /// What the contact force's rest compliance (`RestCompliance`) of this model holds, bytes:
    /// a factor like the tangent's and a copy of the tangent.
    pub fn rest_compliance_bytes(&self) -> u64 {
        (BYTES_PER_REST_FACTOR_VALUE * self.factor_values as f64
            + BYTES_PER_REST_TANGENT_ENTRY * self.tangent_entries as f64)
            .ceil() as u64
    }

    /// What the contact refit's own Newton solver of this model holds, bytes: an f64 factor
    /// like the tangent's and its own tangent.
    pub fn contact_refit_bytes(&self) -> u64 {
        self.rest_compliance_bytes()
    }

    /// What a small-strain linear model's kept stiffness holds (its cells' matrix and one
    /// product vector), bytes; nothing for the other laws, which evaluate their cells anew.
    pub fn linear_stiffness_bytes(&self, linear: bool) -> u64 {
        if linear {
            (BYTES_PER_REST_TANGENT_ENTRY * self.tangent_entries as f64 + 8.0 * self.dofs as f64)
                .ceil() as u64
        } else {
            0
        }
    }

    /// What a small-strain linear model's contact refit keeps of its compliance columns
    /// (`HeldColumns`), bytes: three f64 columns of all unknowns for each vertex, for twice
    /// `region_vertices` (the most surface vertices one contact region holds; a sequence's
    /// region moves, and the columns of vertices it left are kept), at most the columns'
    /// memory cap. The other laws keep none: give them 0 vertices.
    pub fn held_columns_bytes(&self, region_vertices: usize) -> u64 {
        let bytes = 2 * region_vertices * 3 * self.dofs * std::mem::size_of::<f64>();
        bytes.min(HELD_COLUMNS_BUDGET_BYTES) as u64
    }

    /// The sizes of `model`, whose linear solver is `kind`. Runs the symbolic analysis of the
    /// tangent's pattern (milliseconds for the grids a session uses).
    pub fn of(model: &Model, kind: SolverKind) -> Result<Self, String> {
        let grid = &model.problem.grid;
        let pattern = model.problem.assembler().pattern();
        let factor_values = predicted_factor_len(pattern, Some(&grid.node_coords), kind)
            .map_err(|e| format!("symbolic analysis of the tangent: {e}"))?;
        let structure_points: usize = model
            .structures
            .iter()
            .map(|s| s.embedding.points.len())
            .sum();
        let structure_triangles: usize = model
            .structures
            .iter()
            .filter_map(|s| s.triangles.as_ref().map(Vec::len))
            .sum();
        Ok(Self {
            dofs: model.problem.dofs(),
            tangent_entries: pattern.row_idx.len(),
            factor_values,
            cells: grid.cells.len(),
            quadrature_points: grid.quadrature.points.len(),
            embedded_points: model.surface.vertices.len()
                + structure_points
                + model.probes.points.len(),
            triangles: model.surface.triangles.len() + structure_triangles,
            normal_bytes: 0,
            topology_bytes: 0,
        })
    }
}
