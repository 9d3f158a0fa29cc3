//! Uniform 2D bucket grid over axis-aligned rectangles, for point-location queries.

/// Uniform grid over the (x, y) plane whose cells list the rectangles overlapping them
/// (compressed row storage).
///
/// Query `candidates(x, y)` returns every rectangle that contains `(x, y)` (closed rectangles),
/// plus others sharing its cell. Insertion and query use the same monotone cell mapping, so a
/// point on a rectangle's border always finds it.
#[derive(Clone, Debug, Default)]
pub(crate) struct BucketGrid {
    origin: [f64; 2],
    upper: [f64; 2],
    inv_cell: [f64; 2],
    dims: [usize; 2],
    offsets: Vec<u32>,
    items: Vec<u32>,
}

/// Largest number of cells per axis.
const MAX_DIM: usize = 4096;

impl BucketGrid {
    /// Builds the grid over `rects` given as `[x_min, y_min, x_max, y_max]` (finite, in length
    /// units), aiming at about `cells_per_rect` cells per rectangle in total.
    pub(crate) fn build(rects: &[[f64; 4]], cells_per_rect: f64) -> Self {
        if rects.is_empty() {
            return BucketGrid::default();
        }
        let mut origin = [f64::INFINITY; 2];
        let mut upper = [f64::NEG_INFINITY; 2];
        for r in rects {
            for a in 0..2 {
                origin[a] = origin[a].min(r[a]);
                upper[a] = upper[a].max(r[a + 2]);
            }
        }
        let size = [upper[0] - origin[0], upper[1] - origin[1]];
        let target = (rects.len() as f64 * cells_per_rect).max(1.0);
        let dims = if size[0] > 0.0 && size[1] > 0.0 {
            let cell = (size[0] * size[1] / target).sqrt();
            [
                ((size[0] / cell).ceil() as usize).clamp(1, MAX_DIM),
                ((size[1] / cell).ceil() as usize).clamp(1, MAX_DIM),
            ]
        } else if size[0] > 0.0 {
            [(target as usize).clamp(1, MAX_DIM), 1]
        } else if size[1] > 0.0 {
            [1, (target as usize).clamp(1, MAX_DIM)]
        } else {
            [1, 1]
        };
        let inv_cell = [
            if size[0] > 0.0 {
                dims[0] as f64 / size[0]
            } else {
                0.0
            },
            if size[1] > 0.0 {
                dims[1] as f64 / size[1]
            } else {
                0.0
            },
        ];
        let mut grid = BucketGrid {
            origin,
            upper,
            inv_cell,
            dims,
            offsets: vec![0; dims[0] * dims[1] + 1],
            items: Vec::new(),
        };
        // Counting pass, then filling pass.
        for r in rects {
            let ([i0, j0], [i1, j1]) = grid.cell_range(r);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    grid.offsets[j * dims[0] + i + 1] += 1;
                }
            }
        }
        for k in 1..grid.offsets.len() {
            grid.offsets[k] += grid.offsets[k - 1];
        }
        let mut fill = grid.offsets.clone();
        grid.items = vec![0; *grid.offsets.last().unwrap_or(&0) as usize];
        for (idx, r) in rects.iter().enumerate() {
            let ([i0, j0], [i1, j1]) = grid.cell_range(r);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    let c = j * dims[0] + i;
                    grid.items[fill[c] as usize] = idx as u32;
                    fill[c] += 1;
                }
            }
        }
        grid
    }

    /// Monotone mapping of a coordinate to a cell index along `axis`, clamped to the grid.
    #[inline]
    fn index(&self, v: f64, axis: usize) -> usize {
        let t = ((v - self.origin[axis]) * self.inv_cell[axis]).floor();
        if t <= 0.0 {
            0
        } else {
            (t as usize).min(self.dims[axis] - 1)
        }
    }

    fn cell_range(&self, r: &[f64; 4]) -> ([usize; 2], [usize; 2]) {
        (
            [self.index(r[0], 0), self.index(r[1], 1)],
            [self.index(r[2], 0), self.index(r[3], 1)],
        )
    }

    /// Rectangles listed in the cell containing `(x, y)`; empty outside the grid's extent
    /// (and for NaN coordinates).
    #[inline]
    pub(crate) fn candidates(&self, x: f64, y: f64) -> &[u32] {
        if self.offsets.is_empty()
            || !(x >= self.origin[0] && x <= self.upper[0])
            || !(y >= self.origin[1] && y <= self.upper[1])
        {
            return &[];
        }
        let c = self.index(y, 1) * self.dims[0] + self.index(x, 0);
        &self.items[self.offsets[c] as usize..self.offsets[c + 1] as usize]
    }

    /// Number of cells along x and y.
    #[cfg(test)]
    fn dims(&self) -> [usize; 2] {
        self.dims
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_containing_rectangle_is_found() {
        let mut s = 0x1234_5678u64;
        let mut r = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let rects: Vec<[f64; 4]> = (0..500)
            .map(|_| {
                let (x, y) = (r() * 3.0 - 1.0, r() * 2.0);
                [x, y, x + r() * 0.3, y + r() * 0.1]
            })
            .collect();
        let grid = BucketGrid::build(&rects, 1.0);
        assert!(grid.dims()[0] > 1 && grid.dims()[1] > 1);
        // Random points and points exactly on rectangle corners.
        let mut queries: Vec<(f64, f64)> =
            (0..2000).map(|_| (r() * 3.5 - 1.2, r() * 2.3)).collect();
        for q in &rects {
            queries.push((q[0], q[1]));
            queries.push((q[2], q[3]));
        }
        for (x, y) in queries {
            let c = grid.candidates(x, y);
            for (i, q) in rects.iter().enumerate() {
                if q[0] <= x && x <= q[2] && q[1] <= y && y <= q[3] {
                    assert!(c.contains(&(i as u32)), "rect {i} missing at ({x}, {y})");
                }
            }
        }
        assert!(grid.candidates(f64::NAN, 0.5).is_empty());
        assert!(BucketGrid::build(&[], 1.0).candidates(0.0, 0.0).is_empty());
    }
}
