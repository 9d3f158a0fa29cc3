//! Test and benchmark helpers: linear-elasticity matrices on regular
//! hexahedral grids, random vectors, symmetric scaling.
//!
//! These functions are small and always compiled so that the unit tests, the
//! integration tests and the criterion benchmarks (`benches/linear_solvers.rs`)
//! share one generator. They are not meant for production assembly.

use super::SymmetricCsc;

/// Which nodes of the grid are fixed (by a diagonal penalty on their three
/// degrees of freedom).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fixation {
    /// The four corner nodes of the bottom face `z = 0` (enough to remove the
    /// six rigid-body modes; the hardest case for iterative solvers).
    BottomCorners,
    /// Every node of the bottom face `z = 0` (a clamped block).
    BottomFace,
}

/// Element stiffness matrix (24 × 24) of a trilinear hexahedron (hex8) that
/// is an axis-aligned cube of edge `h` (length unit), for isotropic linear
/// elasticity with Young's modulus `young` (stress unit) and Poisson ratio
/// `poisson`, integrated with 2 × 2 × 2 Gauss quadrature. Units of the
/// entries: stress × length (force per displacement).
///
/// Local node `a = ix + 2 iy + 4 iz` sits at `h (ix, iy, iz)`, `ix, iy, iz ∈
/// {0, 1}`; degree of freedom `3 a + c` is the displacement component `c`
/// (x, y, z) of node `a`.
pub fn hex8_stiffness(young: f64, poisson: f64, h: f64) -> [[f64; 24]; 24] {
    let lambda = young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson));
    let mu = young / (2.0 * (1.0 + poisson));
    // Voigt order: xx, yy, zz, xy, yz, zx (engineering shear strains).
    let mut d = [[0.0; 6]; 6];
    for (i, row) in d.iter_mut().enumerate().take(3) {
        for (j, v) in row.iter_mut().enumerate().take(3) {
            *v = lambda + if i == j { 2.0 * mu } else { 0.0 };
        }
    }
    for (i, row) in d.iter_mut().enumerate().skip(3) {
        row[i] = mu;
    }
    let g = 1.0 / 3f64.sqrt();
    let jac = h / 2.0; // dx/dξ for the cube
    let det_j = jac * jac * jac;
    let mut ke = [[0.0; 24]; 24];
    for &xi in &[-g, g] {
        for &eta in &[-g, g] {
            for &zeta in &[-g, g] {
                // Shape function gradients in physical coordinates.
                let mut grad = [[0.0; 3]; 8];
                for (a, ga) in grad.iter_mut().enumerate() {
                    let sx = if a & 1 == 1 { 1.0 } else { -1.0 };
                    let sy = if a & 2 == 2 { 1.0 } else { -1.0 };
                    let sz = if a & 4 == 4 { 1.0 } else { -1.0 };
                    let (fx, fy, fz) = (1.0 + sx * xi, 1.0 + sy * eta, 1.0 + sz * zeta);
                    ga[0] = sx * fy * fz / 8.0 / jac;
                    ga[1] = fx * sy * fz / 8.0 / jac;
                    ga[2] = fx * fy * sz / 8.0 / jac;
                }
                // Strain-displacement matrix B (6 × 24).
                let mut b = [[0.0; 24]; 6];
                for (a, ga) in grad.iter().enumerate() {
                    let c = 3 * a;
                    b[0][c] = ga[0];
                    b[1][c + 1] = ga[1];
                    b[2][c + 2] = ga[2];
                    b[3][c] = ga[1];
                    b[3][c + 1] = ga[0];
                    b[4][c + 1] = ga[2];
                    b[4][c + 2] = ga[1];
                    b[5][c] = ga[2];
                    b[5][c + 2] = ga[0];
                }
                // D B (6 × 24).
                let mut db = [[0.0; 24]; 6];
                for i in 0..6 {
                    for k in 0..24 {
                        db[i][k] = (0..6).map(|l| d[i][l] * b[l][k]).sum();
                    }
                }
                for (i, row) in ke.iter_mut().enumerate() {
                    for (j, v) in row.iter_mut().enumerate() {
                        *v += (0..6).map(|l| b[l][i] * db[l][j]).sum::<f64>() * det_j;
                    }
                }
            }
        }
    }
    ke
}

/// Lower-triangular pattern (values zero) of a 3-dof-per-node matrix on an
/// `m × m × m` node grid with 27-point node coupling (every node couples with
/// all nodes of the cells around it). Node `ix + m (iy + m iz)` owns degrees of
/// freedom `3 node + c`, `c = 0, 1, 2`.
///
/// # Panics
/// Panics if `m < 2`.
pub fn grid_pattern(m: usize) -> SymmetricCsc {
    assert!(m >= 2, "grid needs at least 2 nodes per side");
    let nodes = m * m * m;
    let n = 3 * nodes;
    let mut col_ptr = Vec::with_capacity(n + 1);
    let mut row_idx = Vec::with_capacity(n * 41);
    col_ptr.push(0);
    let mut neighbours = Vec::with_capacity(27);
    for iz in 0..m {
        for iy in 0..m {
            for ix in 0..m {
                let node = ix + m * (iy + m * iz);
                neighbours.clear();
                for jz in iz.saturating_sub(1)..=(iz + 1).min(m - 1) {
                    for jy in iy.saturating_sub(1)..=(iy + 1).min(m - 1) {
                        for jx in ix.saturating_sub(1)..=(ix + 1).min(m - 1) {
                            neighbours.push(jx + m * (jy + m * jz));
                        }
                    }
                }
                for c in 0..3 {
                    let j = 3 * node + c;
                    for &nb in &neighbours {
                        for c2 in 0..3 {
                            let i = 3 * nb + c2;
                            if i >= j {
                                row_idx.push(i);
                            }
                        }
                    }
                    col_ptr.push(row_idx.len());
                }
            }
        }
    }
    SymmetricCsc::from_pattern(n, col_ptr, row_idx).expect("grid pattern is valid by construction")
}

/// Linear-elasticity stiffness (E = 1, ν = 0.3, unit cubes) of an
/// `m × m × m` node grid with the four bottom corner nodes fixed by a penalty
/// of `1e8 ×` the largest element-diagonal entry. Symmetric positive definite,
/// dimension `3 m³`.
pub fn elasticity_grid_matrix(m: usize) -> SymmetricCsc {
    elasticity_grid_matrix_with(m, Fixation::BottomCorners, 1e8)
}

/// Like [`elasticity_grid_matrix`], with a choice of fixed nodes and penalty
/// factor (relative to the largest element-stiffness diagonal entry).
pub fn elasticity_grid_matrix_with(m: usize, fixation: Fixation, penalty: f64) -> SymmetricCsc {
    cut_cell_grid_matrix(m, fixation, penalty, 1.0)
}

/// Like [`elasticity_grid_matrix_with`], but the cells of the top layer
/// (`z` between `m − 2` and `m − 1`) and of the `x = 0` layer are "cut cells":
/// their stiffness is multiplied by `inside_fraction`, as for cells of which
/// only that fraction of the volume lies inside the organ. Small fractions
/// (e.g. `1e-6`) make the matrix badly conditioned in a way that diagonal
/// scaling only partly repairs (nodes shared by cut and full cells).
pub fn cut_cell_grid_matrix(
    m: usize,
    fixation: Fixation,
    penalty: f64,
    inside_fraction: f64,
) -> SymmetricCsc {
    let mut k = grid_pattern(m);
    let ke = hex8_stiffness(1.0, 0.3, 1.0);
    // Position of each (local dof i, local dof j) pair is computed per cell.
    let mut gdofs = [0usize; 24];
    for cz in 0..m - 1 {
        for cy in 0..m - 1 {
            for cx in 0..m - 1 {
                for a in 0..8 {
                    let node =
                        (cx + (a & 1)) + m * ((cy + ((a >> 1) & 1)) + m * (cz + ((a >> 2) & 1)));
                    for c in 0..3 {
                        gdofs[3 * a + c] = 3 * node + c;
                    }
                }
                let w = if cz == m - 2 || cx == 0 {
                    inside_fraction
                } else {
                    1.0
                };
                for i in 0..24 {
                    for j in 0..24 {
                        if gdofs[i] >= gdofs[j] {
                            let p = k
                                .position(gdofs[i], gdofs[j])
                                .expect("element entry in grid pattern");
                            k.values[p] += w * ke[i][j];
                        }
                    }
                }
            }
        }
    }
    let kmax = (0..24).map(|i| ke[i][i]).fold(0.0, f64::max);
    let fixed: Vec<usize> = match fixation {
        Fixation::BottomCorners => vec![0, m - 1, m * (m - 1), m * m - 1],
        Fixation::BottomFace => (0..m * m).collect(),
    };
    for node in fixed {
        for c in 0..3 {
            let d = 3 * node + c;
            let p = k.position(d, d).expect("diagonal present");
            k.values[p] += penalty * kmax;
        }
    }
    k
}

/// Grid coordinates `[ix, iy, iz]` of the nodes of an `m × m × m` grid in
/// the node numbering of [`grid_pattern`] / [`elasticity_grid_matrix`]
/// (node `ix + m (iy + m iz)`), e.g. for
/// [`SparseSolver::with_node_coordinates`](super::SparseSolver::with_node_coordinates).
pub fn grid_node_coordinates(m: usize) -> Vec<[usize; 3]> {
    let mut coords = Vec::with_capacity(m * m * m);
    for iz in 0..m {
        for iy in 0..m {
            for ix in 0..m {
                coords.push([ix, iy, iz]);
            }
        }
    }
    coords
}

/// Linear-elasticity stiffness (E = 1, ν = 0.3, unit cubes) of an arbitrary
/// set of grid cells, with the node coordinates.
///
/// A grid node `[i, j, k]` (`i, j, k < extent`) is *inside* if
/// `inside([i, j, k])`; a cell is active if its 8 corner nodes are inside;
/// the active nodes are the corners of active cells, numbered in `z, y, x`
/// lexicographic order (x fastest, as in [`grid_pattern`]) with 3 dofs each.
/// Two nodes are coupled iff they share an active cell. The nodes of the
/// lowest occupied `z` layer are fixed by a penalty of `1e8 ×` the largest
/// element-diagonal entry (every connected component must touch that layer
/// for the matrix to be positive definite).
///
/// Returns the matrix and `coords[node] = [i, j, k]`.
///
/// # Panics
/// Panics if no cell is active.
pub fn node_set_elasticity_matrix(
    extent: usize,
    inside: impl Fn([usize; 3]) -> bool,
) -> (SymmetricCsc, Vec<[usize; 3]>) {
    let e = extent;
    let idx = |i: usize, j: usize, k: usize| i + e * (j + e * k);
    let corner =
        |c: [usize; 3], a: usize| [c[0] + (a & 1), c[1] + ((a >> 1) & 1), c[2] + ((a >> 2) & 1)];
    let mut cell_active = vec![false; e * e * e];
    let mut node_used = vec![false; e * e * e];
    let mut cells = Vec::new();
    for k in 0..e.saturating_sub(1) {
        for j in 0..e - 1 {
            for i in 0..e - 1 {
                if (0..8).all(|a| inside(corner([i, j, k], a))) {
                    cell_active[idx(i, j, k)] = true;
                    cells.push([i, j, k]);
                    for a in 0..8 {
                        let [x, y, z] = corner([i, j, k], a);
                        node_used[idx(x, y, z)] = true;
                    }
                }
            }
        }
    }
    assert!(!cells.is_empty(), "no active cell");
    let mut node_id = vec![usize::MAX; e * e * e];
    let mut coords = Vec::new();
    for k in 0..e {
        for j in 0..e {
            for i in 0..e {
                if node_used[idx(i, j, k)] {
                    node_id[idx(i, j, k)] = coords.len();
                    coords.push([i, j, k]);
                }
            }
        }
    }
    // Pattern: for each node, the nodes of the active cells around it.
    let n = 3 * coords.len();
    let mut col_ptr = Vec::with_capacity(n + 1);
    let mut row_idx = Vec::new();
    col_ptr.push(0);
    let mut neighbours = Vec::with_capacity(27);
    for &[i, j, k] in &coords {
        let node = node_id[idx(i, j, k)];
        neighbours.clear();
        for a in 0..8 {
            let (dx, dy, dz) = (a & 1, (a >> 1) & 1, (a >> 2) & 1);
            if i < dx || j < dy || k < dz {
                continue;
            }
            let c = [i - dx, j - dy, k - dz];
            if c[0] + 1 >= e
                || c[1] + 1 >= e
                || c[2] + 1 >= e
                || !cell_active[idx(c[0], c[1], c[2])]
            {
                continue;
            }
            for b in 0..8 {
                let [x, y, z] = corner(c, b);
                neighbours.push(node_id[idx(x, y, z)]);
            }
        }
        neighbours.sort_unstable();
        neighbours.dedup();
        for c in 0..3 {
            let col = 3 * node + c;
            for &nb in &neighbours {
                for c2 in 0..3 {
                    if 3 * nb + c2 >= col {
                        row_idx.push(3 * nb + c2);
                    }
                }
            }
            col_ptr.push(row_idx.len());
        }
    }
    let mut k = SymmetricCsc::from_pattern(n, col_ptr, row_idx)
        .expect("node-set pattern is valid by construction");
    let ke = hex8_stiffness(1.0, 0.3, 1.0);
    let mut gdofs = [0usize; 24];
    for &c in &cells {
        for a in 0..8 {
            let [x, y, z] = corner(c, a);
            for d in 0..3 {
                gdofs[3 * a + d] = 3 * node_id[idx(x, y, z)] + d;
            }
        }
        for i in 0..24 {
            for j in 0..24 {
                if gdofs[i] >= gdofs[j] {
                    let p = k
                        .position(gdofs[i], gdofs[j])
                        .expect("element entry in pattern");
                    k.values[p] += ke[i][j];
                }
            }
        }
    }
    let kmax = (0..24).map(|i| ke[i][i]).fold(0.0, f64::max);
    let zmin = coords.iter().map(|c| c[2]).min().unwrap_or(0);
    for (node, c) in coords.iter().enumerate() {
        if c[2] == zmin {
            for d in 0..3 {
                let p = k
                    .position(3 * node + d, 3 * node + d)
                    .expect("diagonal present");
                k.values[p] += 1e8 * kmax;
            }
        }
    }
    (k, coords)
}

/// Inside test of a ball of radius `radius` centred at node `[c, c, c]`
/// (`(i − c)² + (j − c)² + (k − c)² ≤ radius²`), for
/// [`node_set_elasticity_matrix`] with `extent ≥ 2c + 1`.
pub fn ball(c: usize, radius: f64) -> impl Fn([usize; 3]) -> bool {
    move |p: [usize; 3]| {
        p.iter()
            .map(|&x| (x as f64 - c as f64).powi(2))
            .sum::<f64>()
            <= radius * radius
    }
}

/// Deterministic pseudo-random vector with entries uniform in `[-1, 1)`
/// (splitmix64 generator seeded by `seed`).
pub fn random_vector(n: usize, seed: u64) -> Vec<f64> {
    let mut state = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    (0..n)
        .map(|_| {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        })
        .collect()
}

/// Symmetric diagonal scaling `K ← S K S` with `S = diag(scale)` (models the
/// badly conditioned rows/columns of cut cells with a tiny inside volume).
///
/// # Panics
/// Panics if `scale.len() != k.n`.
pub fn scale_symmetric(k: &mut SymmetricCsc, scale: &[f64]) {
    assert_eq!(scale.len(), k.n);
    for j in 0..k.n {
        for p in k.col_ptr[j]..k.col_ptr[j + 1] {
            k.values[p] *= scale[k.row_idx[p]] * scale[j];
        }
    }
}

/// `k0` with the 3 dofs of each of `nodes` scaled by `factor` ([`scale_symmetric`]), and the
/// scale vector `S` used (1 elsewhere).
pub fn with_scaled_nodes(
    k0: &SymmetricCsc,
    nodes: &[usize],
    factor: f64,
) -> (SymmetricCsc, Vec<f64>) {
    let mut scale = vec![1.0; k0.n];
    for &node in nodes {
        for c in 0..3 {
            scale[3 * node + c] = factor;
        }
    }
    let mut k = k0.clone();
    scale_symmetric(&mut k, &scale);
    (k, scale)
}

/// Relative residual `‖b − K x‖₂ / ‖b‖₂` (0 if `b = 0` and `Kx = 0`).
pub fn relative_residual(k: &SymmetricCsc, x: &[f64], b: &[f64]) -> f64 {
    let mut y = vec![0.0; k.n];
    k.mul_vec(x, &mut y);
    let rn: f64 = y
        .iter()
        .zip(b)
        .map(|(yi, bi)| (bi - yi) * (bi - yi))
        .sum::<f64>()
        .sqrt();
    let bn: f64 = b.iter().map(|v| v * v).sum::<f64>().sqrt();
    if bn == 0.0 {
        rn
    } else {
        rn / bn
    }
}
