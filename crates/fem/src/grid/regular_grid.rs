//! The regular background grid of cubic cells that the surface is immersed in (thesis §4.3).

use nalgebra::{Point3, Vector3};

/// A regular grid of `dims[0] × dims[1] × dims[2]` cubic cells of edge `cell_size`, whose first
/// corner is `origin`. Lengths are in the units of the geometry it was built from (metres inside
/// the mechanics).
#[derive(Debug, Clone, PartialEq)]
pub struct RegularGrid {
    /// Corner of cell (0, 0, 0) with the smallest coordinates.
    pub origin: Point3<f64>,
    /// Edge length of every (cubic) cell.
    pub cell_size: f64,
    /// Number of cells along x, y and z.
    pub dims: [usize; 3],
}

impl RegularGrid {
    /// Number of cells (active or not).
    pub fn cell_count(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Number of grid nodes (active or not): `(nx+1)(ny+1)(nz+1)`.
    pub fn node_count(&self) -> usize {
        (self.dims[0] + 1) * (self.dims[1] + 1) * (self.dims[2] + 1)
    }

    /// Linear index of cell `(i, j, k)` (x fastest).
    pub fn cell_index(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    /// Cell coordinates `(i, j, k)` of a linear cell index.
    pub fn cell_coords(&self, index: usize) -> [usize; 3] {
        let nx = self.dims[0];
        let ny = self.dims[1];
        [index % nx, (index / nx) % ny, index / (nx * ny)]
    }

    /// Linear index of grid node `(i, j, k)` (x fastest).
    pub fn node_index(&self, n: [usize; 3]) -> usize {
        let (nx, ny) = (self.dims[0] + 1, self.dims[1] + 1);
        n[0] + nx * (n[1] + ny * n[2])
    }

    /// Rest position of grid node `(i, j, k)`.
    pub fn node_position(&self, n: [usize; 3]) -> Point3<f64> {
        self.origin + Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64) * self.cell_size
    }

    /// The 8 corner nodes of cell `c`, in the order of [`crate::grid::hex8::CORNERS`]
    /// (corner `a` sits at reference coordinates `CORNERS[a]`).
    pub fn cell_node_coords(&self, c: [usize; 3]) -> [[usize; 3]; 8] {
        let mut out = [[0; 3]; 8];
        for (a, corner) in crate::grid::hex8::CORNERS.iter().enumerate() {
            out[a] = [
                c[0] + usize::from(corner[0] > 0.0),
                c[1] + usize::from(corner[1] > 0.0),
                c[2] + usize::from(corner[2] > 0.0),
            ];
        }
        out
    }

    /// Minimum corner of cell `c`.
    pub fn cell_min(&self, c: [usize; 3]) -> Point3<f64> {
        self.node_position(c)
    }

    /// Centre of cell `c`.
    pub fn cell_center(&self, c: [usize; 3]) -> Point3<f64> {
        self.cell_min(c) + Vector3::repeat(0.5 * self.cell_size)
    }

    /// Physical position of reference coordinates `xi ∈ [-1, 1]³` in cell `c` (thesis eq. 4.3).
    pub fn to_physical(&self, c: [usize; 3], xi: &Vector3<f64>) -> Point3<f64> {
        self.cell_center(c) + xi * (0.5 * self.cell_size)
    }

    /// Reference coordinates of `p` in cell `c` (thesis eq. 4.4); outside `[-1, 1]³` when `p`
    /// lies outside the cell.
    pub fn to_reference(&self, c: [usize; 3], p: &Point3<f64>) -> Vector3<f64> {
        (p - self.cell_center(c)) * (2.0 / self.cell_size)
    }

    /// Cell coordinates containing `p` as real numbers (not clamped): `(p - origin) / h`.
    pub fn fractional_cell(&self, p: &Point3<f64>) -> Vector3<f64> {
        (p - self.origin) / self.cell_size
    }

    /// The cell containing `p`, or `None` when `p` is outside the grid (or not finite).
    pub fn locate(&self, p: &Point3<f64>) -> Option<[usize; 3]> {
        let f = self.fractional_cell(p);
        let mut c = [0usize; 3];
        for d in 0..3 {
            if !f[d].is_finite() || f[d] < 0.0 || f[d] > self.dims[d] as f64 {
                return None;
            }
            c[d] = (f[d].floor() as usize).min(self.dims[d] - 1);
        }
        Some(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> RegularGrid {
        RegularGrid {
            origin: Point3::new(-1.0, 0.5, 2.0),
            cell_size: 0.25,
            dims: [3, 4, 5],
        }
    }

    #[test]
    fn index_round_trip() {
        let g = grid();
        for idx in 0..g.cell_count() {
            assert_eq!(g.cell_index(g.cell_coords(idx)), idx);
        }
    }

    #[test]
    fn reference_mapping_round_trip_and_corners() {
        let g = grid();
        let c = [1, 2, 3];
        let p = Point3::new(-0.6, 1.1, 2.8);
        let xi = g.to_reference(c, &p);
        assert!((g.to_physical(c, &xi) - p).norm() < 1e-14);
        let nodes = g.cell_node_coords(c);
        for (a, corner) in crate::grid::hex8::CORNERS.iter().enumerate() {
            let x = g.to_physical(c, &Vector3::from(*corner));
            assert!((x - g.node_position(nodes[a])).norm() < 1e-14);
        }
    }

    #[test]
    fn locate_inside_boundary_and_outside() {
        let g = grid();
        assert_eq!(g.locate(&Point3::new(-1.0, 0.5, 2.0)), Some([0, 0, 0]));
        assert_eq!(g.locate(&Point3::new(-0.25, 1.5, 3.25)), Some([2, 3, 4]));
        assert_eq!(g.locate(&Point3::new(-1.01, 0.6, 2.1)), None);
        assert_eq!(g.locate(&Point3::new(f64::NAN, 0.6, 2.1)), None);
    }
}
