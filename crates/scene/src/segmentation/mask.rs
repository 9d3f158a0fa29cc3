//! [`Mask`]: the voxels of one label (or a set of labels) cropped to their bounding box plus a
//! background margin, with the voxel clean-ups done before meshing: keeping the largest
//! component, filling enclosed cavities.
//!
//! Connectivities match the marching-cubes table of [`super::isosurface`]: inside voxels are
//! connected through faces (6-connectivity), background voxels through faces and edges
//! (18-connectivity). So one kept component gives one outer surface, and after cavity filling
//! there is no inner shell.

use super::labelmap::{LabelSet, Labelmap};

/// Background margin around the bounding box, in voxels (≥ 1 closes the surface).
pub(crate) const PADDING: usize = 2;

/// A binary crop of a labelmap: `data[i + dims[0] * (j + dims[1] * k)]` is 1 inside, 0
/// outside; mask voxel `(i, j, k)` is labelmap voxel `(i, j, k) + origin` (which may lie
/// outside the labelmap in the margin).
#[derive(Debug, Clone)]
pub(crate) struct Mask {
    /// Sizes.
    pub dims: [usize; 3],
    /// Labelmap index of mask voxel (0, 0, 0).
    pub origin: [i64; 3],
    /// 1 inside, 0 outside.
    pub data: Vec<u8>,
}

impl Mask {
    /// The voxels of `labelmap` whose label is in `labels`, cropped to their bounding box with
    /// [`PADDING`] voxels of background around it; `None` if there is none.
    pub(crate) fn from_labels(labelmap: &Labelmap, labels: &[u16]) -> Option<Self> {
        let (lo, hi) = labelmap.bounding_box(labels)?;
        let set = LabelSet::new(labels);
        let dims = [0, 1, 2].map(|a| hi[a] - lo[a] + 1 + 2 * PADDING);
        let mut data = vec![0u8; dims[0] * dims[1] * dims[2]];
        let src = labelmap.labels();
        let [sx, sy, _] = labelmap.dims();
        for k in lo[2]..=hi[2] {
            for j in lo[1]..=hi[1] {
                let row = &src[lo[0] + sx * (j + sy * k)..=hi[0] + sx * (j + sy * k)];
                let m =
                    PADDING + dims[0] * ((j - lo[1] + PADDING) + dims[1] * (k - lo[2] + PADDING));
                for (dst, &l) in data[m..m + row.len()].iter_mut().zip(row) {
                    *dst = set.contains(l) as u8;
                }
            }
        }
        Some(Self {
            dims,
            origin: [0, 1, 2].map(|a| lo[a] as i64 - PADDING as i64),
            data,
        })
    }

    /// Number of inside voxels.
    pub(crate) fn count(&self) -> usize {
        self.data.iter().filter(|&&v| v != 0).count()
    }

    /// Keeps only the largest 6-connected component of inside voxels; returns the number of
    /// voxels removed.
    pub(crate) fn keep_largest_component(&mut self) -> usize {
        let n = self.data.len();
        let steps = self.steps6();
        let mut queue: Vec<u32> = Vec::new();
        let (mut best, mut best_seed, mut total) = (0usize, usize::MAX, 0usize);
        // Pass 1: measure each component, marking visited voxels 2.
        for seed in 0..n {
            if self.data[seed] != 1 {
                continue;
            }
            let size = flood(&mut self.data, seed, 1, 2, &steps, &mut queue);
            total += size;
            if size > best {
                (best, best_seed) = (size, seed);
            }
        }
        if best_seed == usize::MAX {
            return 0;
        }
        // Pass 2: mark the largest 3, then keep only it.
        flood(&mut self.data, best_seed, 2, 3, &steps, &mut queue);
        for v in &mut self.data {
            *v = (*v == 3) as u8;
        }
        total - best
    }

    /// Fills background regions not 18-connected to the margin (cavities); returns the number
    /// of voxels filled.
    pub(crate) fn fill_cavities(&mut self) -> usize {
        let steps = self.steps18();
        let mut queue = Vec::new();
        // The margin is background and connected: one flood from voxel 0 reaches all of it.
        flood(&mut self.data, 0, 0, 2, &steps, &mut queue);
        let mut filled = 0;
        for v in &mut self.data {
            *v = match *v {
                2 => 0,
                0 => {
                    filled += 1;
                    1
                }
                x => x,
            };
        }
        filled
    }

    fn steps6(&self) -> Vec<isize> {
        let (sx, sy) = (1isize, self.dims[0] as isize);
        let sz = sy * self.dims[1] as isize;
        vec![sx, -sx, sy, -sy, sz, -sz]
    }

    fn steps18(&self) -> Vec<isize> {
        let (sx, sy) = (1isize, self.dims[0] as isize);
        let sz = sy * self.dims[1] as isize;
        let mut s = Vec::new();
        for dz in -1..=1isize {
            for dy in -1..=1isize {
                for dx in -1..=1isize {
                    let nonzero = (dx != 0) as u8 + (dy != 0) as u8 + (dz != 0) as u8;
                    if nonzero == 1 || nonzero == 2 {
                        s.push(dx * sx + dy * sy + dz * sz);
                    }
                }
            }
        }
        s
    }
}

/// Flood fill from `seed` over voxels equal to `from`, setting them to `to`; returns the count.
///
/// Steps are linear offsets. Inside voxels lie at least [`PADDING`] voxels from the border, so
/// their steps never wrap; a background step from the border may wrap to the opposite border
/// of the next row or slice, which is margin too (connected background either way). Steps
/// leaving `0..len` are skipped.
fn flood(
    data: &mut [u8],
    seed: usize,
    from: u8,
    to: u8,
    steps: &[isize],
    queue: &mut Vec<u32>,
) -> usize {
    queue.clear();
    data[seed] = to;
    queue.push(seed as u32);
    let mut head = 0;
    let n = data.len() as isize;
    while head < queue.len() {
        let v = queue[head] as isize;
        head += 1;
        for &s in steps {
            let w = v + s;
            if w < 0 || w >= n {
                continue;
            }
            let w = w as usize;
            if data[w] == from {
                data[w] = to;
                queue.push(w as u32);
            }
        }
    }
    queue.len()
}
