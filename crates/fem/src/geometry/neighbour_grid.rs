//! The `k` nearest neighbours of every point of a set, on a uniform grid of cubic cells.
//!
//! A k-d tree answers one query in `O(log n + k log k)` with a heap; when the neighbours of
//! *every* point are wanted (the change test's 32 nearest, a cloud's spacings) and the
//! points sample a surface at a roughly even density, a grid whose cell edge is about the
//! `k`-th neighbour's distance does it with a few hundred distance computations per point
//! and one partial selection: the cells around a point's own hold its neighbours.
//!
//! Exact: a query scans the block of cells within `r` cells of its own (`r` = 1, 2, …) and
//! stops when its `k`-th nearest candidate is no farther than the block's nearest face, which
//! no point outside the block can be nearer than. The cell edge only decides the speed.
//! Lengths in the points' units.

use nalgebra::Point3;

/// Largest number of cells the grid may have per point (plus [`MIN_CELLS`]): a set with far
/// outliers spans a box the grid would need millions of cells for; the caller then uses a
/// tree.
pub(crate) const MAX_CELLS_PER_POINT: usize = 8;

/// Cells allowed whatever the number of points.
pub(crate) const MIN_CELLS: usize = 4096;

/// A uniform grid over a borrowed point set (compressed: each cell's points are a range of
/// `order`).
#[derive(Debug, Clone)]
pub struct NeighbourGrid<'a> {
    origin: Point3<f64>,
    cell: f64,
    dims: [usize; 3],
    /// Start of each cell's range in `order` (length cells + 1).
    starts: Vec<u32>,
    /// Point indices, grouped by cell.
    order: Vec<u32>,
    points: &'a [Point3<f64>],
}

impl<'a> NeighbourGrid<'a> {
    /// Bins `points` (finite) into cubic cells of edge `cell` (> 0, finite). `None` when the
    /// set is empty or its box needs more than `MAX_CELLS_PER_POINT × n + MIN_CELLS` cells.
    pub fn new(points: &'a [Point3<f64>], cell: f64) -> Option<Self> {
        if points.is_empty()
            || points.len() > u32::MAX as usize
            || !(cell.is_finite() && cell > 0.0)
        {
            return None;
        }
        let mut lo = points[0];
        let mut hi = points[0];
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let limit = MAX_CELLS_PER_POINT * points.len() + MIN_CELLS;
        let mut dims = [0usize; 3];
        let mut total = 1usize;
        for a in 0..3 {
            let d = ((hi[a] - lo[a]) / cell).floor();
            if !d.is_finite() || d >= limit as f64 {
                return None;
            }
            dims[a] = d as usize + 1;
            total = total.checked_mul(dims[a])?;
            if total > limit {
                return None;
            }
        }
        let mut grid = Self {
            origin: lo,
            cell,
            dims,
            starts: vec![0; total + 1],
            order: vec![0; points.len()],
            points,
        };
        let cells: Vec<usize> = points.iter().map(|p| grid.flat(grid.cell_of(p))).collect();
        for &c in &cells {
            grid.starts[c + 1] += 1;
        }
        for c in 0..total {
            grid.starts[c + 1] += grid.starts[c];
        }
        let mut next = grid.starts.clone();
        for (i, &c) in cells.iter().enumerate() {
            grid.order[next[c] as usize] = i as u32;
            next[c] += 1;
        }
        Some(grid)
    }

    /// Integer cell coordinates of `p` (clamped to the grid).
    fn cell_of(&self, p: &Point3<f64>) -> [usize; 3] {
        let mut c = [0usize; 3];
        for a in 0..3 {
            let f = ((p[a] - self.origin[a]) / self.cell).floor();
            c[a] = if f > 0.0 {
                (f as usize).min(self.dims[a] - 1)
            } else {
                0
            };
        }
        c
    }

    fn flat(&self, c: [usize; 3]) -> usize {
        (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
    }

    /// The `k` points nearest to point `i` of the set (itself included), nearest first, ties
    /// by index, with their distances; all points when there are fewer than `k`. `scratch`
    /// is reused between calls (its contents do not matter).
    pub fn k_nearest_of(
        &self,
        i: usize,
        k: usize,
        scratch: &mut Vec<(f64, u32)>,
    ) -> Vec<(usize, f64)> {
        let q = self.points[i];
        let k = k.min(self.points.len());
        if k == 0 {
            return Vec::new();
        }
        let home = self.cell_of(&q);
        let mut r = 1usize;
        loop {
            scratch.clear();
            let mut clearance = f64::INFINITY;
            let mut covers_all = true;
            let mut range = [(0usize, 0usize); 3];
            for a in 0..3 {
                let first = home[a].saturating_sub(r);
                let last = (home[a] + r).min(self.dims[a] - 1);
                range[a] = (first, last);
                // Distance from q to the block's faces on this axis; none where the block
                // reaches the grid's end (no point lies beyond it).
                if first > 0 {
                    let face = self.origin[a] + first as f64 * self.cell;
                    clearance = clearance.min(q[a] - face);
                    covers_all = false;
                }
                if last + 1 < self.dims[a] {
                    let face = self.origin[a] + (last + 1) as f64 * self.cell;
                    clearance = clearance.min(face - q[a]);
                    covers_all = false;
                }
            }
            for z in range[2].0..=range[2].1 {
                for y in range[1].0..=range[1].1 {
                    let row = (z * self.dims[1] + y) * self.dims[0];
                    let from = self.starts[row + range[0].0] as usize;
                    let to = self.starts[row + range[0].1 + 1] as usize;
                    for &j in &self.order[from..to] {
                        let d2 = (self.points[j as usize] - q).norm_squared();
                        scratch.push((d2, j));
                    }
                }
            }
            // The whole grid holds every point, and k <= n: `covers_all` always ends the loop.
            if scratch.len() >= k || covers_all {
                let k = k.min(scratch.len());
                let by_distance =
                    |a: &(f64, u32), b: &(f64, u32)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
                // Also with exactly k candidates: the k-th must be the farthest.
                if k > 0 {
                    scratch.select_nth_unstable_by(k - 1, by_distance);
                }
                let kth = scratch.get(k.wrapping_sub(1)).map_or(0.0, |c| c.0);
                if covers_all || kth.sqrt() <= clearance {
                    let nearest = &mut scratch[..k];
                    nearest.sort_unstable_by(by_distance);
                    return nearest
                        .iter()
                        .map(|&(d2, j)| (j as usize, d2.sqrt()))
                        .collect();
                }
            }
            r += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    /// The `k` nearest by brute force: every distance, sorted (ties by index).
    fn brute_force(points: &[Point3<f64>], i: usize, k: usize) -> Vec<(usize, f64)> {
        let mut all: Vec<(f64, usize)> = points
            .iter()
            .enumerate()
            .map(|(j, p)| ((p - points[i]).norm_squared(), j))
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        all.truncate(k);
        all.into_iter().map(|(d2, j)| (j, d2.sqrt())).collect()
    }

    fn check(points: &[Point3<f64>], cell: f64, k: usize) {
        let grid = NeighbourGrid::new(points, cell).expect("grid");
        let mut scratch = Vec::new();
        for i in 0..points.len() {
            assert_eq!(
                grid.k_nearest_of(i, k, &mut scratch),
                brute_force(points, i, k),
                "point {i}, cell {cell}, k {k}"
            );
        }
    }

    /// A curved patch (a camera's view of an organ), noisy, with a denser spot and a few
    /// points off it: the lists equal brute force's at cell edges far below, near and far
    /// above the neighbours' distance, so the edge decides only the speed.
    #[test]
    fn lists_equal_brute_force_whatever_the_cell() {
        let mut rng = Rng::new(7);
        let mut points: Vec<Point3<f64>> = (0..600)
            .map(|_| {
                let (x, y) = (rng.uniform() * 0.1, rng.uniform() * 0.08);
                let z = 0.02 * (30.0 * x).sin() * (20.0 * y).cos() + 0.002 * (rng.uniform() - 0.5);
                Point3::new(x, y, z)
            })
            .collect();
        points.extend((0..150).map(|_| {
            Point3::new(
                0.05 + 0.005 * rng.uniform(),
                0.04 + 0.005 * rng.uniform(),
                0.0,
            )
        }));
        points.push(points[17]); // a duplicate: a tie broken by index
                                 // The 32nd neighbour lies about 1 cm away: cells of 4 mm make the search widen.
        for cell in [0.004, 0.01, 0.05, 1.0] {
            for k in [1, 9, 32] {
                check(&points, cell, k);
            }
        }
        // Two points far off the patch: a larger box, the same lists.
        points.push(Point3::new(0.3, -0.1, 0.05));
        points.push(Point3::new(0.25, 0.2, -0.05));
        for cell in [0.02, 0.05] {
            check(&points, cell, 32);
        }
    }

    #[test]
    fn small_sets_return_every_point_and_bad_grids_are_refused() {
        let points = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 2.0, 0.0),
        ];
        check(&points, 0.1, 5);
        let grid = NeighbourGrid::new(&points, 0.1).unwrap();
        assert!(grid.k_nearest_of(0, 0, &mut Vec::new()).is_empty());
        assert!(NeighbourGrid::new(&[], 0.1).is_none());
        assert!(NeighbourGrid::new(&points, 0.0).is_none());
        assert!(NeighbourGrid::new(&points, f64::NAN).is_none());
        // 1e9 cells for 3 points: refused (a tree serves such a set).
        assert!(NeighbourGrid::new(&points, 1e-3).is_none());
    }
}
