//! The thesis's cylinder experiments (§4.6, fig. 4.6 and 4.8): neo-Hookean, E = 5000 Pa,
//! ν = 0.3, radius 5 cm. Bending: length 60 cm, base held, 30 Pa downward (−y) dead traction on
//! the free end face. Stretching: length 5 cm, both end faces displaced along their normals
//! until the cylinder is three times as long.

use nalgebra::{Point3, Vector3};

use crate::geometry::Aabb;
use crate::grid::{Embedding, GridOptions, IntegrationMode, WeightedCellGrid};
use crate::mechanics::loads::traction_forces;
use crate::mechanics::{
    LawKind, Material, NewtonSettings, NewtonSolver, PenaltySprings, SolveReport, StaticProblem,
    VolumetricIntegration,
};
use crate::mesh::primitives::cylinder_surface;
use crate::mesh::TriSurface;

/// Cylinder radius, m.
pub const RADIUS: f64 = 0.05;
/// Young's modulus, Pa.
pub const YOUNG: f64 = 5000.0;
/// Poisson's ratio.
pub const POISSON: f64 = 0.3;
/// Penalty factor κ of the held faces (spring density κ E / h per unit area).
pub const HOLD_PENALTY: f64 = 1e3;

/// A solved scenario: the solver's report and the displacements (m) of the scenario's sample
/// points.
#[derive(Debug, Clone)]
pub struct ScenarioResult {
    /// The Newton report.
    pub report: SolveReport,
    /// Sample points (rest positions, m).
    pub samples: Vec<Point3<f64>>,
    /// Their displacements, m.
    pub displacements: Vec<Vector3<f64>>,
    /// Grid size: active nodes.
    pub nodes: usize,
}

impl ScenarioResult {
    /// Relative L2 difference `‖d − d_ref‖ / ‖d_ref‖` of the sample displacements.
    pub fn relative_difference(&self, reference: &[Vector3<f64>]) -> f64 {
        let num: f64 = self
            .displacements
            .iter()
            .zip(reference)
            .map(|(a, b)| (a - b).norm_squared())
            .sum();
        let den: f64 = reference.iter().map(|b| b.norm_squared()).sum();
        (num / den).sqrt()
    }
}

fn face_box(z: f64) -> Aabb {
    Aabb {
        min: Point3::new(-1.0, -1.0, z - 1e-4),
        max: Point3::new(1.0, 1.0, z + 1e-4),
    }
}

fn base_problem(
    surface: &TriSurface,
    cell_size: f64,
    levels: u32,
    mode: IntegrationMode,
) -> StaticProblem {
    let opts = GridOptions {
        cell_size,
        subdivisions: levels,
        mode,
        ..GridOptions::default()
    };
    let grid = WeightedCellGrid::build(surface, &opts).expect("cylinder grid");
    let m =
        Material::from_young_poisson(LawKind::NeoHookean, YOUNG, POISSON).expect("valid material");
    StaticProblem::new(grid, m, VolumetricIntegration::Reduced)
}

fn held_face(p: &StaticProblem, surface: &TriSurface, z: f64) -> PenaltySprings {
    let density = HOLD_PENALTY * YOUNG / p.cell_size();
    PenaltySprings::fixed_surface_region(&p.grid, surface, &face_box(z), density)
        .expect("face embeds")
        .expect("face holds samples")
}

fn finish(
    mut p: StaticProblem,
    settings: NewtonSettings,
    samples: Vec<Point3<f64>>,
) -> ScenarioResult {
    let u0 = vec![0.0; p.dofs()];
    let report = NewtonSolver::new(settings).solve(&mut p, &[], &u0);
    let displacements = Embedding::new(&p.grid, &samples)
        .expect("samples embed")
        .interpolate(&report.u);
    ScenarioResult {
        report,
        samples,
        displacements,
        nodes: p.grid.node_count(),
    }
}

/// Cylinder bending (thesis fig. 4.6).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CylinderBending {
    /// Cell edge, m.
    pub cell_size: f64,
    /// Subdivision levels of cut cells.
    pub levels: u32,
    /// Integration of cut cells.
    pub mode: IntegrationMode,
}

impl CylinderBending {
    /// Length, m.
    pub const LENGTH: f64 = 0.6;
    /// End-face traction, Pa (downwards, −y).
    pub const TRACTION: f64 = 30.0;

    /// The sample points: on the axis and at 0.8 R towards +x and +y, at 12 heights.
    pub fn samples() -> Vec<Point3<f64>> {
        let mut v = Vec::new();
        for i in 1..=12 {
            let z = Self::LENGTH * i as f64 / 12.0 - 1e-3;
            v.push(Point3::new(0.0, 0.0, z));
            v.push(Point3::new(0.0, 0.8 * RADIUS, z));
            v.push(Point3::new(0.8 * RADIUS, 0.0, z));
        }
        v
    }

    /// The surface (48 segments around, 36 rings along).
    pub fn surface() -> TriSurface {
        cylinder_surface(RADIUS, 0.0, Self::LENGTH, 48, 36)
    }

    /// Solves it with 10 load steps.
    pub fn solve(&self) -> ScenarioResult {
        let s = Self::surface();
        let mut p = base_problem(&s, self.cell_size, self.levels, self.mode);
        p.springs = vec![held_face(&p, &s, 0.0)];
        let mut f = vec![0.0; p.dofs()];
        traction_forces(
            &p.grid,
            &s,
            &face_box(Self::LENGTH),
            Vector3::new(0.0, -Self::TRACTION, 0.0),
            &mut f,
        )
        .expect("end face embeds");
        p.external = f;
        let settings = NewtonSettings {
            load_steps: 10,
            max_iterations: 25,
            ..NewtonSettings::default()
        };
        finish(p, settings, Self::samples())
    }
}

/// Cylinder stretching (thesis fig. 4.8).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CylinderStretching {
    /// Cell edge, m.
    pub cell_size: f64,
    /// Subdivision levels of cut cells.
    pub levels: u32,
    /// Integration of cut cells.
    pub mode: IntegrationMode,
}

impl CylinderStretching {
    /// Rest length, m.
    pub const LENGTH: f64 = 0.05;

    /// Sample points on the axis near both end faces.
    pub fn samples() -> Vec<Point3<f64>> {
        vec![
            Point3::new(0.0, 0.0, Self::LENGTH - 1e-3),
            Point3::new(0.0, 0.0, 1e-3),
        ]
    }

    /// Solves it with 10 load steps: each end face pulled outwards by one length.
    pub fn solve(&self) -> ScenarioResult {
        let s = cylinder_surface(RADIUS, 0.0, Self::LENGTH, 48, 8);
        let mut p = base_problem(&s, self.cell_size, self.levels, self.mode);
        let mut bottom = held_face(&p, &s, 0.0);
        bottom.target = vec![Vector3::new(0.0, 0.0, -Self::LENGTH); bottom.embedding.len()];
        bottom.follows_load = true;
        let mut top = held_face(&p, &s, Self::LENGTH);
        top.target = vec![Vector3::new(0.0, 0.0, Self::LENGTH); top.embedding.len()];
        top.follows_load = true;
        p.springs = vec![bottom, top];
        finish(
            p,
            NewtonSettings {
                load_steps: 10,
                ..NewtonSettings::default()
            },
            Self::samples(),
        )
    }
}
