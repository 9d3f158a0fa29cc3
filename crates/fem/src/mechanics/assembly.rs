//! Global assembly of internal forces and the tangent stiffness over the active cells, on a
//! sparsity pattern built once per grid.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::cell_kernel::{evaluate_cell, CellResponse, Need, VolumetricIntegration};
use super::material::{Material, MaterialError};
use crate::grid::WeightedCellGrid;
use crate::linalg::SymmetricCsc;

/// Number of stored (lower-triangle) entries of one cell's 24 × 24 tangent: 28 off-diagonal
/// 3 × 3 blocks and 8 diagonal blocks of 6.
pub(crate) const CELL_LOWER_ENTRIES: usize = 28 * 9 + 8 * 6;

/// Index, in a cell's scatter map, of entry `(i, k)` of node block `(a, b)` with `a ≥ b`
/// (and `i ≥ k` when `a == b`).
pub(crate) fn lower_slot(a: usize, b: usize, i: usize, k: usize) -> usize {
    debug_assert!(a > b || (a == b && i >= k));
    // Blocks in order (a, b) for a in 0..8, b in 0..=a; a diagonal block holds 6 entries.
    let before_row = a * a.saturating_sub(1) / 2 * 9 + a * 6; // all blocks of rows < a
    if b < a {
        before_row + b * 9 + 3 * i + k
    } else {
        before_row + a * 9 + i * (i + 1) / 2 + k
    }
}

/// Row and column, in the 24 × 24 cell tangent, of each stored entry in [`lower_slot`] order.
const LOWER_ROW_COL: [(u8, u8); CELL_LOWER_ENTRIES] = {
    let mut out = [(0u8, 0u8); CELL_LOWER_ENTRIES];
    let mut s = 0;
    let mut a = 0;
    while a < 8 {
        let mut b = 0;
        while b <= a {
            let mut i = 0;
            while i < 3 {
                let mut k = 0;
                while k < 3 {
                    if a > b || k <= i {
                        out[s] = ((3 * a + i) as u8, (3 * b + k) as u8);
                        s += 1;
                    }
                    k += 1;
                }
                i += 1;
            }
            b += 1;
        }
        a += 1;
    }
    out
};

/// The stored entries `(a, b, i, k)` of a cell tangent (blocks `a ≥ b`, and `i ≥ k` on the
/// diagonal blocks), in the order of [`lower_slot`].
pub(crate) fn lower_entries() -> impl Iterator<Item = (usize, usize, usize, usize)> {
    LOWER_ROW_COL.iter().map(|&(r, c)| {
        let (r, c) = (r as usize, c as usize);
        (r / 3, c / 3, r % 3, c % 3)
    })
}

/// A failed cell evaluation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellFailure {
    /// Active cell index.
    pub cell: usize,
    /// What the material reported.
    pub error: MaterialError,
}

/// Assembles the global internal force and tangent of a grid. The sparsity pattern (3 × 3
/// blocks between nodes sharing a cell, lower triangle) and each cell's scatter positions are
/// computed once; cells are evaluated in parallel into per-cell buffers and summed in a fixed
/// order, so results do not depend on the number of threads.
#[derive(Clone)]
pub struct Assembler {
    pattern: SymmetricCsc,
    scatter: Vec<[u32; CELL_LOWER_ENTRIES]>,
    buffers: Vec<CellResponse>,
}

impl Assembler {
    /// Builds the pattern and scatter maps for `grid`.
    pub fn new(grid: &WeightedCellGrid) -> Self {
        let n = grid.node_count();
        // Node adjacency (lower: neighbour ≥ node) per column node.
        let mut adj: Vec<Vec<usize>> = vec![Vec::new(); n];
        for cell in &grid.cells {
            for &a in &cell.nodes {
                for &b in &cell.nodes {
                    if a >= b {
                        adj[b].push(a);
                    }
                }
            }
        }
        for list in &mut adj {
            list.sort_unstable();
            list.dedup();
        }
        let mut col_ptr = Vec::with_capacity(3 * n + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0);
        for (node, list) in adj.iter().enumerate() {
            for k in 0..3 {
                for &other in list {
                    for i in 0..3 {
                        let row = 3 * other + i;
                        if row >= 3 * node + k {
                            row_idx.push(row);
                        }
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let pattern = SymmetricCsc::from_pattern(3 * n, col_ptr, row_idx)
            .expect("assembled pattern is valid");
        let scatter = grid
            .cells
            .iter()
            .map(|cell| {
                let mut map = [0u32; CELL_LOWER_ENTRIES];
                for (slot, (a, b, i, k)) in lower_entries().enumerate() {
                    let (r, c) = (3 * cell.nodes[a] + i, 3 * cell.nodes[b] + k);
                    map[slot] = pattern.position(r, c).expect("cell entry in pattern") as u32;
                }
                map
            })
            .collect();
        let buffers = vec![CellResponse::default(); grid.cells.len()];
        Self {
            pattern,
            scatter,
            buffers,
        }
    }

    /// The sparsity pattern (lower triangle, values zero).
    pub fn pattern(&self) -> &SymmetricCsc {
        &self.pattern
    }

    /// Position in the pattern's values of entry `(i, k)` of node block `(a, b)` of `cell`
    /// (`a ≥ b`; for `a == b`, `i ≥ k`).
    pub fn cell_slot(&self, cell: usize, a: usize, b: usize, i: usize, k: usize) -> usize {
        self.scatter[cell][lower_slot(a, b, i, k)] as usize
    }

    /// Evaluates all cells at displacements `u` (3 per node, m) and accumulates the strain
    /// energy (returned, J), internal forces into `force` (added, N) and the tangent into
    /// `tangent`'s values (added, N/m), depending on `need`. The first inverted cell is
    /// reported (by lowest index, whatever the thread count).
    #[allow(clippy::too_many_arguments)]
    pub fn assemble(
        &mut self,
        grid: &WeightedCellGrid,
        material: &Material,
        volumetric: VolumetricIntegration,
        u: &[f64],
        need: Need,
        force: Option<&mut [f64]>,
        tangent: Option<&mut SymmetricCsc>,
    ) -> Result<f64, CellFailure> {
        let h = grid.grid.cell_size;
        let q = &grid.quadrature;
        let failures: Vec<CellFailure> = self
            .buffers
            .par_iter_mut()
            .zip(grid.cells.par_iter())
            .enumerate()
            .filter_map(|(c, (buf, cell))| {
                let ul = cell
                    .nodes
                    .map(|n| Vector3::new(u[3 * n], u[3 * n + 1], u[3 * n + 2]));
                evaluate_cell(material, volumetric, h, &ul, q.cell(c), need, buf)
                    .err()
                    .map(|error| CellFailure { cell: c, error })
            })
            .collect();
        if let Some(first) = failures.into_iter().min_by_key(|f| f.cell) {
            return Err(first);
        }
        let mut energy = 0.0;
        for b in &self.buffers {
            energy += b.energy;
        }
        if let (true, Some(force)) = (need >= Need::Force, force) {
            for (buf, cell) in self.buffers.iter().zip(&grid.cells) {
                for (a, &n) in cell.nodes.iter().enumerate() {
                    for i in 0..3 {
                        force[3 * n + i] += buf.force[3 * a + i];
                    }
                }
            }
        }
        if let (true, Some(k)) = (need >= Need::Tangent, tangent) {
            let values = &mut k.values;
            for (buf, map) in self.buffers.iter().zip(&self.scatter) {
                for (pos, &(r, c)) in map.iter().zip(&LOWER_ROW_COL) {
                    values[*pos as usize] += buf.tangent[(r as usize, c as usize)];
                }
            }
        }
        Ok(energy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lower_slots_enumerate_every_entry_once_in_order() {
        let mut count = 0;
        for (s, (a, b, i, k)) in lower_entries().enumerate() {
            assert!(a > b || (a == b && k <= i));
            assert_eq!(lower_slot(a, b, i, k), s);
            count += 1;
        }
        assert_eq!(count, CELL_LOWER_ENTRIES);
    }
}
