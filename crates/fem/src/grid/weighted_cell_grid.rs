//! The immersed grid: active cells of a regular grid around a surface, their nodes, and the
//! quadrature of cut cells (thesis ch. 4).

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::hex8::{gauss_points, CORNERS, GAUSS_2};
use super::quadrature::{CellQuadratures, IntegrationMode, QuadPoint};
use super::regular_grid::RegularGrid;
use crate::geometry::{triangle_overlaps_box, Aabb, InsideTest};
use crate::mesh::TriSurface;

/// Largest number of background cells a grid may have (a guard against a cell size that is far
/// too small for the surface, which would otherwise exhaust memory).
pub(crate) const MAX_BACKGROUND_CELLS: usize = 20_000_000;

/// How to build a [`WeightedCellGrid`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridOptions {
    /// Edge of a cubic cell, in the surface's units.
    pub cell_size: f64,
    /// Octree levels used on cut cells to compute inside volumes (0: cut cells count as full).
    pub subdivisions: u32,
    /// How cut cells are integrated.
    pub mode: IntegrationMode,
    /// Fictitious-domain weight α ∈ [0, 0.5) (default 1e-2, see docs/mechanics.md): the part
    /// of a cut cell outside the surface is integrated with weight α instead of 0, so that
    /// nodes of cells with a tiny inside volume keep a stiffness of at least α times a full
    /// cell's and the system stays non-singular.
    pub min_fraction: f64,
    /// Shift of the grid origin, in cells, each component in `[0, 1)`: moves where cells are cut.
    pub origin_offset: [f64; 3],
}

impl Default for GridOptions {
    fn default() -> Self {
        Self {
            cell_size: 0.01,
            subdivisions: 3,
            mode: IntegrationMode::WeightedCell,
            min_fraction: 1e-2,
            origin_offset: [0.0; 3],
        }
    }
}

/// Errors building a grid.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GridError {
    /// The surface has no triangles.
    #[error("the surface has no triangles")]
    EmptySurface,
    /// A non-finite vertex coordinate.
    #[error("surface vertex {0} has a non-finite coordinate")]
    NonFiniteVertex(usize),
    /// An option is out of range.
    #[error("invalid grid option {name} = {value}: {reason}")]
    InvalidOption {
        /// The option.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: &'static str,
    },
    /// The cell size makes too many cells.
    #[error("cell size {cell_size} makes {cells} background cells (limit {MAX_BACKGROUND_CELLS}); use a larger cell size")]
    TooManyCells {
        /// The requested cell size.
        cell_size: f64,
        /// Cells that it would make.
        cells: usize,
    },
    /// No cell has any volume inside the surface.
    #[error("no grid cell lies inside the surface (is it closed and is the cell size smaller than the object?)")]
    NoActiveCell,
}

/// An active cell: inside the surface or cut by it.
#[derive(Debug, Clone, PartialEq)]
pub struct ActiveCell {
    /// Cell coordinates `(i, j, k)` in the background grid.
    pub coords: [usize; 3],
    /// Its 8 nodes (indices into the grid's active nodes), in [`CORNERS`] order.
    pub nodes: [usize; 8],
    /// Whether the surface passes through the cell.
    pub cut: bool,
    /// Inside volume fraction of the whole cell, in `[0, 1]`.
    pub fraction: f64,
    /// Inside volume fraction of each first-level sub-cell (octant `I` holds Gauss point `I`):
    /// `v_tc` of thesis eq. 4.12 divided by the octant's volume.
    pub octant_fractions: [f64; 8],
}

/// Statistics of a grid build.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GridStats {
    /// Active cells.
    pub cells: usize,
    /// Active cells cut by the surface.
    pub cut_cells: usize,
    /// Active nodes.
    pub nodes: usize,
    /// Cut cells whose inside fraction is below 5% (the badly cut cells).
    pub tiny_cells: usize,
    /// Total inside volume integrated, length³.
    pub volume: f64,
    /// Integration points in all cells.
    pub quadrature_points: usize,
}

/// A surface immersed in a regular grid of hexahedral cells: the active cells (inside or cut),
/// their nodes (the degrees of freedom) and the integration points of each cell.
#[derive(Debug, Clone)]
pub struct WeightedCellGrid {
    /// The background grid.
    pub grid: RegularGrid,
    /// Active cells, ordered by background cell index.
    pub cells: Vec<ActiveCell>,
    /// Background-grid coordinates of each active node, ordered by background node index.
    pub node_coords: Vec<[usize; 3]>,
    /// Map from background cell index to active cell index (`u32::MAX` when inactive).
    cell_lookup: Vec<u32>,
    /// Integration points of the active cells for `options.mode`.
    pub quadrature: CellQuadratures,
    /// The options the grid was built with.
    pub options: GridOptions,
}

impl WeightedCellGrid {
    /// Builds the grid for a closed (or nearly closed) surface. Lengths are in the surface's
    /// units. Cells with no inside volume are dropped; cut cells are subdivided
    /// `options.subdivisions` times to measure their inside volume with a generalised winding
    /// number test, so open surfaces still give a sensible inside.
    pub fn build(surface: &TriSurface, options: &GridOptions) -> Result<Self, GridError> {
        check_options(options)?;
        if surface.triangles.is_empty() {
            return Err(GridError::EmptySurface);
        }
        if let Some(i) = crate::mesh::first_non_finite_point(&surface.vertices) {
            return Err(GridError::NonFiniteVertex(i));
        }
        let grid = background_grid(surface, options)?;
        let inside = InsideTest::new(&surface.vertices, &surface.triangles);
        let cell_tris = cell_triangle_lists(&grid, surface);
        let uncut_inside = uncut_cells_inside(&grid, &inside);

        // Measure cut cells.
        let levels = options.subdivisions.max(1);
        let want_points = options.mode == IntegrationMode::FiniteCell && options.subdivisions > 0;
        let cut: Vec<(usize, CutMeasure)> = cell_tris
            .par_iter()
            .map(|(cell, tris)| {
                let c = grid.cell_coords(*cell);
                (
                    *cell,
                    measure_cut_cell(&grid, c, surface, tris, &inside, levels, want_points),
                )
            })
            .collect();

        let (mut cells, fc_points) = active_cells(&grid, &uncut_inside, cut);
        if cells.is_empty() {
            return Err(GridError::NoActiveCell);
        }
        let (node_coords, cell_lookup) = number_nodes(&grid, &mut cells);
        let quadrature = build_quadrature(&grid, &cells, &fc_points, options);
        Ok(Self {
            grid,
            cells,
            node_coords,
            cell_lookup,
            quadrature,
            options: *options,
        })
    }

    /// Number of active nodes (each carries 3 displacement degrees of freedom).
    pub fn node_count(&self) -> usize {
        self.node_coords.len()
    }

    /// Rest position of active node `n`.
    pub fn node_position(&self, n: usize) -> Point3<f64> {
        self.grid.node_position(self.node_coords[n])
    }

    /// Rest positions of all active nodes.
    pub fn node_positions(&self) -> Vec<Point3<f64>> {
        (0..self.node_count())
            .map(|n| self.node_position(n))
            .collect()
    }

    /// The active cell at background coordinates `c`, if any.
    pub fn active_cell_at(&self, c: [usize; 3]) -> Option<usize> {
        let v = self.cell_lookup[self.grid.cell_index(c)];
        (v != u32::MAX).then_some(v as usize)
    }

    /// Counts that describe the grid.
    pub fn stats(&self) -> GridStats {
        let h3 = self.grid.cell_size.powi(3);
        GridStats {
            cells: self.cells.len(),
            cut_cells: self.cells.iter().filter(|c| c.cut).count(),
            nodes: self.node_count(),
            tiny_cells: self
                .cells
                .iter()
                .filter(|c| c.cut && c.fraction < 0.05)
                .count(),
            volume: self.cells.iter().map(|c| c.fraction * h3).sum(),
            quadrature_points: self.quadrature.total_points(),
        }
    }
}

fn check_options(o: &GridOptions) -> Result<(), GridError> {
    let bad = |name, value, reason| {
        Err(GridError::InvalidOption {
            name,
            value,
            reason,
        })
    };
    if !(o.cell_size.is_finite() && o.cell_size > 0.0) {
        return bad("cell_size", o.cell_size, "must be a positive number");
    }
    if o.subdivisions > 6 {
        return bad(
            "subdivisions",
            o.subdivisions as f64,
            "at most 6 (8^L sub-cells per cut cell)",
        );
    }
    if !(0.0..0.5).contains(&o.min_fraction) {
        return bad("min_fraction", o.min_fraction, "must be in [0, 0.5)");
    }
    for v in o.origin_offset {
        if !(0.0..1.0).contains(&v) {
            return bad("origin_offset", v, "components must be in [0, 1)");
        }
    }
    Ok(())
}

/// For every background cell the surface passes through (exact triangle–box overlap), the
/// triangles that overlap it; sorted by cell index.
fn cell_triangle_lists(grid: &RegularGrid, surface: &TriSurface) -> Vec<(usize, Vec<usize>)> {
    let h = grid.cell_size;
    let mut pairs: Vec<(usize, usize)> = (0..surface.triangles.len())
        .into_par_iter()
        .flat_map_iter(|t| {
            let tri = surface.corners(t);
            let lo = tri[0].inf(&tri[1]).inf(&tri[2]);
            let hi = tri[0].sup(&tri[1]).sup(&tri[2]);
            let range = |d: usize| {
                let a = ((lo[d] - grid.origin[d]) / h).floor().max(0.0) as usize;
                let b = ((hi[d] - grid.origin[d]) / h).floor().max(0.0) as usize;
                (a.min(grid.dims[d] - 1), b.min(grid.dims[d] - 1))
            };
            let (rx, ry, rz) = (range(0), range(1), range(2));
            let mut out = Vec::new();
            for k in rz.0..=rz.1 {
                for j in ry.0..=ry.1 {
                    for i in rx.0..=rx.1 {
                        let c = [i, j, k];
                        let min = grid.cell_min(c);
                        let b = Aabb {
                            min,
                            max: min + Vector3::repeat(h),
                        };
                        if triangle_overlaps_box(&tri, &b) {
                            out.push((grid.cell_index(c), t));
                        }
                    }
                }
            }
            out.into_iter()
        })
        .collect();
    pairs.par_sort_unstable();
    let mut lists: Vec<(usize, Vec<usize>)> = Vec::new();
    for (c, t) in pairs {
        match lists.last_mut() {
            Some((last, v)) if *last == c => v.push(t),
            _ => lists.push((c, vec![t])),
        }
    }
    lists
}

/// Inside volume of a cut cell measured on its octree.
struct CutMeasure {
    /// Inside fraction of the cell.
    fraction: f64,
    /// Inside fraction of each octant.
    octants: [f64; 8],
    /// Finite-cell integration points (reference coordinates, weight as a fraction of the cell
    /// volume), when asked for.
    points: Vec<QuadPoint>,
}

/// A point whose inside/outside state decides a piece of volume.
struct Sample {
    p: Point3<f64>,
    /// Volume fraction of the cell it stands for.
    volume: f64,
    octant: usize,
    /// Size of the sub-cell it belongs to (for expanding uncut inside sub-cells into 8 Gauss
    /// points in finite-cell mode), as a fraction of the cell edge; 0 for a leaf Gauss point.
    expand: f64,
}

fn measure_cut_cell(
    grid: &RegularGrid,
    c: [usize; 3],
    surface: &TriSurface,
    tris: &[usize],
    inside: &InsideTest,
    levels: u32,
    want_points: bool,
) -> CutMeasure {
    let h = grid.cell_size;
    let cmin = grid.cell_min(c);
    let mut samples = Vec::new();
    // Octants of the cell: octant I contains corner I.
    for (o, corner) in CORNERS.iter().enumerate() {
        let omin = cmin
            + Vector3::new(
                if corner[0] > 0.0 { 0.5 * h } else { 0.0 },
                if corner[1] > 0.0 { 0.5 * h } else { 0.0 },
                if corner[2] > 0.0 { 0.5 * h } else { 0.0 },
            );
        subdivide(surface, tris, omin, 0.5 * h, 1, levels, o, h, &mut samples);
    }
    // Classify samples line by line (points sharing x and y).
    let mut order: Vec<usize> = (0..samples.len()).collect();
    order.sort_unstable_by(|&a, &b| {
        let (pa, pb) = (&samples[a].p, &samples[b].p);
        (pa.x.to_bits(), pa.y.to_bits()).cmp(&(pb.x.to_bits(), pb.y.to_bits()))
    });
    let mut flags = vec![false; samples.len()];
    let mut out = Vec::new();
    let mut start = 0;
    while start < order.len() {
        let p0 = samples[order[start]].p;
        let mut end = start + 1;
        while end < order.len() {
            let p = samples[order[end]].p;
            if p.x.to_bits() != p0.x.to_bits() || p.y.to_bits() != p0.y.to_bits() {
                break;
            }
            end += 1;
        }
        let zs: Vec<f64> = order[start..end].iter().map(|&i| samples[i].p.z).collect();
        out.clear();
        inside.classify_line(p0.x, p0.y, &zs, &mut out);
        for (slot, &i) in order[start..end].iter().enumerate() {
            flags[i] = out[slot];
        }
        start = end;
    }
    let mut octants = [0.0; 8];
    let mut points = Vec::new();
    let center = grid.cell_center(c);
    for (s, &f) in samples.iter().zip(&flags) {
        if !f {
            continue;
        }
        octants[s.octant] += s.volume * 8.0;
        if want_points {
            let xi = (s.p - center) * (2.0 / h);
            if s.expand > 0.0 {
                // An uncut inside sub-cell: its own 2×2×2 Gauss points.
                for g in gauss_points() {
                    points.push(QuadPoint {
                        xi: xi + g * s.expand,
                        weight: s.volume / 8.0,
                    });
                }
            } else {
                points.push(QuadPoint {
                    xi,
                    weight: s.volume,
                });
            }
        }
    }
    let fraction = octants.iter().sum::<f64>() / 8.0;
    CutMeasure {
        fraction,
        octants,
        points,
    }
}

/// Recursive octree split of a sub-cell with minimum corner `min` and edge `size` at `level`.
#[allow(clippy::too_many_arguments)]
fn subdivide(
    surface: &TriSurface,
    tris: &[usize],
    min: Point3<f64>,
    size: f64,
    level: u32,
    levels: u32,
    octant: usize,
    h: f64,
    samples: &mut Vec<Sample>,
) {
    let b = Aabb {
        min,
        max: min + Vector3::repeat(size),
    };
    let hits: Vec<usize> = tris
        .iter()
        .copied()
        .filter(|&t| triangle_overlaps_box(&surface.corners(t), &b))
        .collect();
    let volume = (size / h).powi(3);
    let center = min + Vector3::repeat(0.5 * size);
    if hits.is_empty() {
        samples.push(Sample {
            p: center,
            volume,
            octant,
            expand: size / h,
        });
        return;
    }
    if level >= levels {
        for g in gauss_points() {
            samples.push(Sample {
                p: center + g * (0.5 * size),
                volume: volume / 8.0,
                octant,
                expand: 0.0,
            });
        }
        return;
    }
    let half = 0.5 * size;
    for corner in CORNERS {
        let cmin = min
            + Vector3::new(
                if corner[0] > 0.0 { half } else { 0.0 },
                if corner[1] > 0.0 { half } else { 0.0 },
                if corner[2] > 0.0 { half } else { 0.0 },
            );
        subdivide(
            surface,
            &hits,
            cmin,
            half,
            level + 1,
            levels,
            octant,
            h,
            samples,
        );
    }
}

/// Integration points of every active cell for the chosen mode (weights in length³).
fn build_quadrature(
    grid: &RegularGrid,
    cells: &[ActiveCell],
    fc_points: &[Vec<QuadPoint>],
    options: &GridOptions,
) -> CellQuadratures {
    let v = grid.cell_size.powi(3);
    let gauss = gauss_points();
    let alpha = options.min_fraction;
    let mut q = CellQuadratures {
        offsets: vec![0],
        points: Vec::new(),
    };
    for (cell, fc) in cells.iter().zip(fc_points) {
        let full =
            !cell.cut || options.mode == IntegrationMode::FullCell || options.subdivisions == 0;
        match (full, options.mode) {
            (true, _) => q.points.extend(gauss.iter().map(|xi| QuadPoint {
                xi: *xi,
                weight: v / 8.0,
            })),
            (false, IntegrationMode::FiniteCell) => {
                q.points.extend(fc.iter().map(|p| QuadPoint {
                    xi: p.xi,
                    weight: p.weight * v,
                }));
                if alpha > 0.0 {
                    // The fictitious (outside) part of each octant at weight α.
                    q.points
                        .extend(
                            gauss
                                .iter()
                                .zip(cell.octant_fractions)
                                .map(|(xi, f)| QuadPoint {
                                    xi: *xi,
                                    weight: alpha * (1.0 - f) * v / 8.0,
                                }),
                        );
                }
            }
            (false, _) => q.points.extend(gauss.iter().zip(cell.octant_fractions).map(
                |(xi, f)| QuadPoint {
                    xi: *xi,
                    weight: (f + alpha * (1.0 - f)) * v / 8.0,
                },
            )),
        }
        q.offsets.push(q.points.len());
    }
    debug_assert!(gauss.iter().all(|g| g.abs().max() == GAUSS_2));
    q
}

/// The background grid over `surface`'s bounding box: its origin the box's low corner moved
/// by `options.origin_offset` cells, cells of `options.cell_size` (the surface's units).
/// Errors when it would have more than [`MAX_BACKGROUND_CELLS`] cells.
fn background_grid(surface: &TriSurface, options: &GridOptions) -> Result<RegularGrid, GridError> {
    let (lo, hi) = surface.bounding_box().ok_or(GridError::EmptySurface)?;
    let h = options.cell_size;
    let origin = lo - Vector3::from(options.origin_offset) * h;
    let mut dims = [0usize; 3];
    let mut total = 1usize;
    for d in 0..3 {
        let n = ((hi[d] - origin[d]) / h - 1e-9).ceil().max(1.0);
        if n > MAX_BACKGROUND_CELLS as f64 {
            return Err(GridError::TooManyCells {
                cell_size: h,
                cells: usize::MAX,
            });
        }
        dims[d] = n as usize;
        total = total.saturating_mul(dims[d]);
    }
    if total > MAX_BACKGROUND_CELLS {
        return Err(GridError::TooManyCells {
            cell_size: h,
            cells: total,
        });
    }
    Ok(RegularGrid {
        origin,
        cell_size: h,
        dims,
    })
}

/// Whether each background cell's centre lies inside the surface, classified column by
/// column (in parallel); what decides an uncut cell.
fn uncut_cells_inside(grid: &RegularGrid, inside: &InsideTest) -> Vec<bool> {
    let dims = grid.dims;
    let h = grid.cell_size;
    let mut uncut_inside = vec![false; grid.cell_count()];
    let columns: Vec<Vec<bool>> = (0..dims[0] * dims[1])
        .into_par_iter()
        .map(|col| {
            let (i, j) = (col % dims[0], col / dims[0]);
            let c = grid.cell_center([i, j, 0]);
            let zs: Vec<f64> = (0..dims[2]).map(|k| c.z + k as f64 * h).collect();
            let mut out = Vec::with_capacity(zs.len());
            inside.classify_line(c.x, c.y, &zs, &mut out);
            out
        })
        .collect();
    for (col, flags) in columns.iter().enumerate() {
        for (k, &f) in flags.iter().enumerate() {
            uncut_inside[grid.cell_index([col % dims[0], col / dims[0], k])] = f;
        }
    }
    uncut_inside
}

/// The active cells in background order, with each cut cell's finite-cell points: a cut
/// cell (`cut`, in background order) with inside volume, or an uncut cell whose centre is
/// inside. Node numbers are filled in by [`number_nodes`].
fn active_cells(
    grid: &RegularGrid,
    uncut_inside: &[bool],
    cut: Vec<(usize, CutMeasure)>,
) -> (Vec<ActiveCell>, Vec<Vec<QuadPoint>>) {
    let mut cut_iter = cut.into_iter().peekable();
    let mut cells = Vec::new();
    let mut fc_points: Vec<Vec<QuadPoint>> = Vec::new();
    for (index, &inside_centre) in uncut_inside.iter().enumerate() {
        let coords = grid.cell_coords(index);
        if cut_iter.peek().map(|(c, _)| *c) == Some(index) {
            let (_, m) = cut_iter.next().expect("peeked");
            if m.fraction <= 1e-12 {
                continue;
            }
            let full = m.fraction >= 1.0 - 1e-12;
            cells.push(ActiveCell {
                coords,
                nodes: [0; 8],
                cut: !full,
                fraction: m.fraction.min(1.0),
                octant_fractions: m.octants.map(|v| v.min(1.0)),
            });
            fc_points.push(m.points);
        } else if inside_centre {
            cells.push(ActiveCell {
                coords,
                nodes: [0; 8],
                cut: false,
                fraction: 1.0,
                octant_fractions: [1.0; 8],
            });
            fc_points.push(Vec::new());
        }
    }
    (cells, fc_points)
}

/// Numbers the nodes of the active `cells` in background node order and writes them into
/// each cell: the active nodes' background coordinates and the background → active cell map
/// (`u32::MAX` for an inactive cell).
fn number_nodes(grid: &RegularGrid, cells: &mut [ActiveCell]) -> (Vec<[usize; 3]>, Vec<u32>) {
    let dims = grid.dims;
    let mut node_lookup = vec![u32::MAX; grid.node_count()];
    for cell in cells.iter() {
        for n in grid.cell_node_coords(cell.coords) {
            node_lookup[grid.node_index(n)] = 0;
        }
    }
    let mut node_coords = Vec::new();
    for k in 0..=dims[2] {
        for j in 0..=dims[1] {
            for i in 0..=dims[0] {
                let idx = grid.node_index([i, j, k]);
                if node_lookup[idx] == 0 {
                    node_lookup[idx] = node_coords.len() as u32;
                    node_coords.push([i, j, k]);
                }
            }
        }
    }
    let mut cell_lookup = vec![u32::MAX; grid.cell_count()];
    for (a, cell) in cells.iter_mut().enumerate() {
        cell_lookup[grid.cell_index(cell.coords)] = a as u32;
        let ns = grid.cell_node_coords(cell.coords);
        for (slot, n) in cell.nodes.iter_mut().zip(ns) {
            *slot = node_lookup[grid.node_index(n)] as usize;
        }
    }
    (node_coords, cell_lookup)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::{box_surface, icosphere};

    fn sphere() -> TriSurface {
        icosphere(Point3::new(0.0011, -0.0007, 0.0003), 0.05, 5)
    }

    #[test]
    fn inside_volume_of_a_sphere_converges_with_levels() {
        let s = sphere();
        let exact = s.signed_volume();
        let mut last = f64::INFINITY;
        for levels in 1..=4 {
            let g = WeightedCellGrid::build(
                &s,
                &GridOptions {
                    cell_size: 0.02,
                    subdivisions: levels,
                    ..Default::default()
                },
            )
            .unwrap();
            let err = (g.stats().volume - exact).abs() / exact;
            assert!(
                err < last * 1.05 || err < 2e-3,
                "level {levels}: error {err} after {last}"
            );
            last = err;
        }
        assert!(last < 5e-3, "level 4 volume error {last}");
    }

    #[test]
    fn weighted_and_finite_cell_integrate_the_same_inside_volume() {
        let s = sphere();
        let base = GridOptions {
            cell_size: 0.02,
            subdivisions: 3,
            min_fraction: 0.0,
            ..Default::default()
        };
        let wc = WeightedCellGrid::build(&s, &base).unwrap();
        let fc = WeightedCellGrid::build(
            &s,
            &GridOptions {
                mode: IntegrationMode::FiniteCell,
                ..base
            },
        )
        .unwrap();
        assert_eq!(wc.cells.len(), fc.cells.len());
        for c in 0..wc.cells.len() {
            let (a, b) = (wc.quadrature.cell_volume(c), fc.quadrature.cell_volume(c));
            assert!((a - b).abs() < 1e-15, "cell {c}: {a} vs {b}");
            assert!((a - wc.cells[c].fraction * 0.02f64.powi(3)).abs() < 1e-15);
        }
        assert!(fc.quadrature.total_points() > 4 * wc.quadrature.total_points());
    }

    #[test]
    fn octant_fractions_follow_a_plane_cut() {
        // A box whose top face z = 0.0125 cuts the cells of the second layer through the
        // middle of their lower octants' upper half: octants below hold 1/2, those above 0.
        let s = box_surface(
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.04, 0.04, 0.0125),
            4,
        );
        let g = WeightedCellGrid::build(
            &s,
            &GridOptions {
                cell_size: 0.01,
                subdivisions: 3,
                ..Default::default()
            },
        )
        .unwrap();
        let cut: Vec<&ActiveCell> = g.cells.iter().filter(|c| c.cut).collect();
        assert_eq!(cut.len(), 16);
        for c in cut {
            assert!((c.fraction - 0.25).abs() < 1e-12);
            for (i, f) in c.octant_fractions.iter().enumerate() {
                let expected = if CORNERS[i][2] < 0.0 { 0.5 } else { 0.0 };
                assert!((f - expected).abs() < 1e-12, "octant {i}: {f}");
            }
        }
    }

    #[test]
    fn every_cut_cell_keeps_a_floor_of_stiffness_weight() {
        let s = sphere();
        let g = WeightedCellGrid::build(
            &s,
            &GridOptions {
                cell_size: 0.02,
                subdivisions: 4,
                min_fraction: 1e-4,
                origin_offset: [0.31, 0.77, 0.05],
                ..Default::default()
            },
        )
        .unwrap();
        let v8 = 0.02f64.powi(3) / 8.0;
        assert!(
            g.stats().tiny_cells > 0,
            "this offset should make badly cut cells"
        );
        for c in 0..g.cells.len() {
            for q in g.quadrature.cell(c) {
                assert!(q.weight >= 1e-4 * v8 * (1.0 - 1e-12));
            }
        }
    }

    #[test]
    fn bad_options_and_surfaces_are_errors() {
        let s = sphere();
        let bad = |o: GridOptions| WeightedCellGrid::build(&s, &o).unwrap_err();
        assert!(matches!(
            bad(GridOptions {
                cell_size: -1.0,
                ..Default::default()
            }),
            GridError::InvalidOption {
                name: "cell_size",
                ..
            }
        ));
        assert!(matches!(
            bad(GridOptions {
                cell_size: f64::NAN,
                ..Default::default()
            }),
            GridError::InvalidOption { .. }
        ));
        assert!(matches!(
            bad(GridOptions {
                subdivisions: 9,
                ..Default::default()
            }),
            GridError::InvalidOption {
                name: "subdivisions",
                ..
            }
        ));
        assert!(matches!(
            bad(GridOptions {
                cell_size: 1e-5,
                ..Default::default()
            }),
            GridError::TooManyCells { .. }
        ));
        assert_eq!(
            WeightedCellGrid::build(&TriSurface::default(), &GridOptions::default()).unwrap_err(),
            GridError::EmptySurface
        );
        let mut nan = sphere();
        nan.vertices[3].x = f64::NAN;
        assert_eq!(
            WeightedCellGrid::build(&nan, &GridOptions::default()).unwrap_err(),
            GridError::NonFiniteVertex(3)
        );
    }

    #[test]
    fn an_open_surface_still_gives_a_sensible_inside() {
        let mut s = sphere();
        let closed = WeightedCellGrid::build(
            &s,
            &GridOptions {
                cell_size: 0.02,
                subdivisions: 2,
                ..Default::default()
            },
        )
        .unwrap();
        // Punch a hole: drop the triangles of a small cap.
        s.triangles.retain(|t| s.vertices[t[0]].z < 0.045);
        let open = WeightedCellGrid::build(
            &s,
            &GridOptions {
                cell_size: 0.02,
                subdivisions: 2,
                ..Default::default()
            },
        )
        .unwrap();
        let (a, b) = (closed.stats().volume, open.stats().volume);
        assert!((a - b).abs() / a < 0.02, "closed {a} vs open {b}");
    }
}
