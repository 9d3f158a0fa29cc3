//! [`Model`]: what registration reads of a liver, in SI units (lengths in metres): the
//! surface, its embedding in the immersed grid, the static problem, the holds, and the
//! embedded structures whose positions a registration reports.
//!
//! Registration does not know where a model comes from: the scene layer above builds one from
//! a scene file, a test from a fixture.

use crate::grid::{Embedding, EmbeddingError, GridError};
use crate::mechanics::{NewtonSettings, StaticProblem};
use crate::mesh::{MeshError, TriSurface};

/// Default penalty factor κ of rigid holds: a held surface sample of area A (a fixed box's)
/// gets a spring of `κ E A / h` (N/m), a point held rigidly (the contact refit's held
/// vertices) `κ E h`; relative to the cell stiffness `~E h` this holds the region to about
/// 1/κ of the local deformation. A fixed point list is held through a layer instead
/// ([`DEFAULT_POINT_HOLD_FACTOR`]).
pub const DEFAULT_FIXED_PENALTY_FACTOR: f64 = 1e3;

/// Default factor β of a surface held as points (a ligament given as the vertices it covers):
/// a point standing for surface area A gets a spring of `β E A / h` (N/m), so the hold acts
/// through a layer of tissue `h / β` thick, half a cell. A clamped patch concentrates strain at
/// its edge over far less than a cell; the grid cannot resolve it and, held rigidly, turns too
/// little about the patch. The tetrahedral truths of `fixtures/liver_force` (four tuning
/// livers, both laws), solved forward on the grid under their own loads at the deepest frame,
/// are off by 3.4–11 mm held rigidly per cell, 80–90 % of it a rotation about the ligament of
/// 2.6–9.9° too little; held through this layer, by 0.3–1.4 mm, turning within 0.1–1.2°
/// (`cargo test --test numerics ligament_hold -- --nocapture` prints two of them). β = 1.5
/// turns the neo-Hookean presses 14–16 % too far. The layer thins with the cell, so the hold
/// tightens as the grid refines, but not as fast as the neo-Hookean truths (ν = 0.49) need: on
/// finer cells their deep press turns too far (random liver 2 at 5.75 mm: 22 %), already at
/// small depth, while the linear truths stay right. A layer of the confined modulus instead
/// suits both laws on 5.75 mm cells and holds the neo-Hookean presses far too stiffly on the
/// derived ones (docs/force-truths.md, grid refinement).
pub const DEFAULT_POINT_HOLD_FACTOR: f64 = 2.0;

/// Errors building a model; every message names the file or key at fault.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A mesh or point file could not be read.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// The grid could not be built.
    #[error("{file}: grid: {source}")]
    Grid {
        /// The surface file.
        file: std::path::PathBuf,
        /// Why.
        source: GridError,
    },
    /// A point (probe, fixed point, structure) could not be embedded.
    #[error("{what}: {source}")]
    Embedding {
        /// Which key or file the points came from.
        what: String,
        /// Why.
        source: EmbeddingError,
    },
    /// Any other invalid model content.
    #[error("{0}")]
    Invalid(String),
}

/// A named set of embedded points carried by the deformation (vessel bifurcations, tumour
/// vertices).
#[derive(Debug, Clone)]
pub struct EmbeddedStructure {
    /// Name from the scene.
    pub name: String,
    /// The points, embedded in the grid (rest positions in metres).
    pub embedding: Embedding,
    /// The mesh's triangles, when the structure is a mesh.
    pub triangles: Option<Vec<[usize; 3]>>,
}

/// Everything registration needs of one liver, in SI units (lengths in metres).
pub struct Model {
    /// Metres per scene unit (to convert results back).
    pub length_scale: f64,
    /// The pre-operative surface, metres.
    pub surface: TriSurface,
    /// Surface vertices embedded in the grid.
    pub surface_embedding: Embedding,
    /// The mechanical problem (grid, material, dead loads, fixed regions).
    pub problem: StaticProblem,
    /// Newton settings of the model's solves.
    pub newton: NewtonSettings,
    /// Probe points, embedded.
    pub probes: Embedding,
    /// Internal structures, embedded.
    pub structures: Vec<EmbeddedStructure>,
}

impl Model {
    /// Each structure's name and number of points, in order (what a workload's truth must
    /// match).
    pub fn structure_sizes(&self) -> Vec<(String, usize)> {
        self.structures
            .iter()
            .map(|s| (s.name.clone(), s.embedding.rest.len()))
            .collect()
    }

    /// The deformed surface (scene units) for grid displacements `u` (m).
    pub fn deformed_surface(&self, u: &[f64]) -> TriSurface {
        let pos = self.surface_embedding.positions(u);
        TriSurface::new(
            pos.iter().map(|p| p / self.length_scale).collect(),
            self.surface.triangles.clone(),
        )
    }
}
