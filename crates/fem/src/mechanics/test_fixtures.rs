//! Problems shared by the mechanics unit tests, and by the tests of crates built on this one
//! (feature `test-fixtures`).

use nalgebra::Point3;

use super::{LawKind, Material, PenaltySprings, StaticProblem, VolumetricIntegration};
use crate::grid::{Embedding, GridOptions, WeightedCellGrid};
use crate::mesh::primitives::box_surface;
use crate::mesh::TriSurface;

/// A box from (3, −4, 1) mm to (103, `top_y`, 61) mm (`top_y` in m), offset from the grid
/// lines so cells are cut on every side, on 2 cm weighted cells; neo-Hookean, E = 4500 Pa,
/// ν = 0.45, no loads or springs. Returns the surface too.
pub fn cut_box(top_y: f64) -> (TriSurface, StaticProblem) {
    let s = box_surface(
        Point3::new(0.003, -0.004, 0.001),
        Point3::new(0.103, top_y, 0.061),
        4,
    );
    let grid = WeightedCellGrid::build(
        &s,
        &GridOptions {
            cell_size: 0.02,
            ..Default::default()
        },
    )
    .unwrap();
    let material = Material::from_young_poisson(LawKind::NeoHookean, 4500.0, 0.45).unwrap();
    (
        s,
        StaticProblem::new(grid, material, VolumetricIntegration::Reduced),
    )
}

/// [`cut_box`] with its end face (the surface vertices within 1 mm of x = 3 mm) held fixed by
/// springs of `stiffness` (N/m each).
pub fn cut_box_held_at_end(top_y: f64, stiffness: f64) -> (TriSurface, StaticProblem) {
    let (s, mut problem) = cut_box(top_y);
    let end: Vec<Point3<f64>> = s.vertices.iter().filter(|v| v.x < 0.004).copied().collect();
    let embedding = Embedding::new(&problem.grid, &end).unwrap();
    problem.springs = vec![PenaltySprings::fixed(embedding, vec![stiffness; end.len()])];
    (s, problem)
}
