//! The cell size a scene gets when `grid.cell_size` is omitted, and an organ's own length
//! scale for tolerances that must not shrink with the cells: derived from the enclosed volume
//! of its surface, so that one default serves livers of any size and any file unit.
//!
//! Rule: `h = V^(1/3) / CELLS_PER_CUBE_ROOT`, with `V` the volume the surface encloses (scene
//! units³). A liver of 1.1–1.2 L gets 11.5–11.8 mm cells (about 1,500 active nodes): on the
//! tool-indentation class (`livereg bench --indentation`) they give 1.32 / 0.82 mm mean node
//! error at 23 ms warm p50 / 35 ms p95, where 8 mm cells with 4 levels give 7–9 % less error
//! at 89 / 115 ms, beyond a warm frame's 30 ms p50 and 60 ms p95; see
//! docs/indentation.md#the-classs-sweep.

use crate::mesh::TriSurface;

/// Cells across the cube root of the enclosed volume.
pub const CELLS_PER_CUBE_ROOT: f64 = 9.0;

/// The derived cell size of `surface` (its units): the cube root of the volume it encloses over
/// [`CELLS_PER_CUBE_ROOT`]; `None` when it encloses no volume.
pub fn derived_cell_size(surface: &TriSurface) -> Option<f64> {
    let v = surface.signed_volume().abs();
    (v.is_finite() && v > 0.0).then(|| v.cbrt() / CELLS_PER_CUBE_ROOT)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::icosphere;
    use nalgebra::Point3;

    /// A sphere of radius r encloses (4/3)πr³ (less the polyhedral deficit): the cell size is
    /// its cube root over 9, and it scales with the unit.
    #[test]
    fn cell_size_is_the_cube_root_of_the_volume_over_nine() {
        let s = icosphere(Point3::origin(), 60.0, 4);
        let v = 4.0 / 3.0 * std::f64::consts::PI * 60f64.powi(3);
        let h = derived_cell_size(&s).unwrap();
        assert!((h - v.cbrt() / 9.0).abs() < 0.01 * h, "{h}");
        let mut metres = s.clone();
        metres.scale(1e-3);
        assert!((derived_cell_size(&metres).unwrap() - h * 1e-3).abs() < 1e-12);
        let flat = TriSurface::new(vec![Point3::origin(); 3], vec![[0, 1, 2]]);
        assert_eq!(derived_cell_size(&flat), None);
    }
}
