//! Jacobi-preconditioned conjugate gradient with deterministic parallel
//! kernels.
//!
//! Reproducibility: every reduction (dot product, norm) is computed as a sum of
//! per-block partial sums over fixed blocks of [`BLOCK`] entries, added in
//! block order; the matrix–vector product computes each output row serially.
//! The result is therefore bitwise identical for any number of rayon threads.

use rayon::prelude::*;

use super::{LinalgError, SymmetricCsc};

/// Block length (entries) of the deterministic reductions and the unit of
/// parallel work for vector operations.
const BLOCK: usize = 4096;
/// Rows per parallel task in the matrix–vector product.
const ROW_BLOCK: usize = 512;
/// Below this dimension all kernels run serially (parallel overhead dominates).
const PAR_MIN_N: usize = 8192;

/// The full (both triangles) compressed sparse row copy of a [`SymmetricCsc`],
/// which makes the product `K x` embarrassingly parallel over rows.
#[derive(Debug)]
pub(crate) struct FullOperator {
    n: usize,
    row_ptr: Vec<usize>,
    col_idx: Vec<u32>,
    /// For each full entry, the index of its value in the lower storage.
    src: Vec<usize>,
    values: Vec<f64>,
}

impl FullOperator {
    /// Builds the row structure of the full symmetric matrix (values are
    /// filled by [`FullOperator::gather`]).
    pub(crate) fn new(k: &SymmetricCsc) -> Result<Self, LinalgError> {
        let n = k.n;
        if n > u32::MAX as usize {
            return Err(LinalgError::InvalidPattern(format!(
                "dimension {n} too large for the conjugate-gradient operator"
            )));
        }
        let mut counts = vec![0usize; n + 1];
        for j in 0..n {
            for &i in &k.row_idx[k.col_ptr[j]..k.col_ptr[j + 1]] {
                counts[i + 1] += 1;
                if i != j {
                    counts[j + 1] += 1;
                }
            }
        }
        for i in 0..n {
            counts[i + 1] += counts[i];
        }
        let row_ptr = counts;
        let nnz = row_ptr[n];
        let mut next = row_ptr.clone();
        let mut col_idx = vec![0u32; nnz];
        let mut src = vec![0usize; nnz];
        // Column order j = 0..n makes each row's column indices sorted: row j
        // first receives (j, j') for j' < j from earlier columns, then the
        // diagonal and the entries (j, i), i > j, of column j in order.
        for j in 0..n {
            for p in k.col_ptr[j]..k.col_ptr[j + 1] {
                let i = k.row_idx[p];
                col_idx[next[i]] = j as u32;
                src[next[i]] = p;
                next[i] += 1;
                if i != j {
                    col_idx[next[j]] = i as u32;
                    src[next[j]] = p;
                    next[j] += 1;
                }
            }
        }
        Ok(Self {
            n,
            row_ptr,
            col_idx,
            src,
            values: vec![0.0; nnz],
        })
    }

    /// Copies the current values of `k` (same pattern) into the full storage.
    pub(crate) fn gather(&mut self, k: &SymmetricCsc) {
        let lower = &k.values;
        if self.n >= PAR_MIN_N {
            self.values
                .par_chunks_mut(BLOCK)
                .zip(self.src.par_chunks(BLOCK))
                .for_each(|(v, s)| {
                    for (v, &s) in v.iter_mut().zip(s) {
                        *v = lower[s];
                    }
                });
        } else {
            for (v, &s) in self.values.iter_mut().zip(&self.src) {
                *v = lower[s];
            }
        }
    }

    #[inline]
    fn row_dot(&self, i: usize, x: &[f64]) -> f64 {
        let range = self.row_ptr[i]..self.row_ptr[i + 1];
        let mut acc = 0.0;
        for (&c, &v) in self.col_idx[range.clone()].iter().zip(&self.values[range]) {
            acc += v * x[c as usize];
        }
        acc
    }

    /// `y = K x`.
    pub(crate) fn apply(&self, x: &[f64], y: &mut [f64]) {
        if self.n >= PAR_MIN_N {
            y.par_chunks_mut(ROW_BLOCK)
                .enumerate()
                .for_each(|(b, chunk)| {
                    let r0 = b * ROW_BLOCK;
                    for (k, yi) in chunk.iter_mut().enumerate() {
                        *yi = self.row_dot(r0 + k, x);
                    }
                });
        } else {
            for (i, yi) in y.iter_mut().enumerate() {
                *yi = self.row_dot(i, x);
            }
        }
    }

    /// `y = K x` and returns `xᵀ y` (deterministic blocked reduction).
    fn apply_dot(&self, x: &[f64], y: &mut [f64]) -> f64 {
        let partial = |b: usize, chunk: &mut [f64]| {
            let r0 = b * BLOCK;
            let mut s = 0.0;
            for (k, yi) in chunk.iter_mut().enumerate() {
                let v = self.row_dot(r0 + k, x);
                *yi = v;
                s += v * x[r0 + k];
            }
            s
        };
        if self.n >= PAR_MIN_N {
            let parts: Vec<f64> = y
                .par_chunks_mut(BLOCK)
                .enumerate()
                .with_max_len(1)
                .map(|(b, c)| partial(b, c))
                .collect();
            parts.iter().sum()
        } else {
            y.chunks_mut(BLOCK)
                .enumerate()
                .map(|(b, c)| partial(b, c))
                .sum()
        }
    }
}

/// Deterministic dot product (fixed blocking, serial sum of block partials).
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let f = |(x, y): (&[f64], &[f64])| x.iter().zip(y).map(|(p, q)| p * q).sum::<f64>();
    if a.len() >= PAR_MIN_N {
        let parts: Vec<f64> = a
            .par_chunks(BLOCK)
            .zip(b.par_chunks(BLOCK))
            .map(f)
            .collect();
        parts.iter().sum()
    } else {
        a.chunks(BLOCK).zip(b.chunks(BLOCK)).map(f).sum()
    }
}

/// Euclidean norm with the deterministic blocked reduction.
pub(crate) fn norm(a: &[f64]) -> f64 {
    dot(a, a).sqrt()
}

/// Settings and work vectors of the preconditioned conjugate gradient.
#[derive(Debug, Default)]
pub(crate) struct CgWork {
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
}

/// Outcome of a CG run (the caller turns it into stats or errors).
#[derive(Debug)]
pub(crate) struct CgOutcome {
    pub(crate) iterations: usize,
    pub(crate) relative_residual: f64,
    pub(crate) result: Result<(), LinalgError>,
}

/// One block of [`update_xrz`].
fn xrz_block(
    alpha: f64,
    x: &mut [f64],
    r: &mut [f64],
    z: &mut [f64],
    p: &[f64],
    q: &[f64],
    d: &[f64],
) -> (f64, f64) {
    let mut rr = 0.0;
    let mut rz = 0.0;
    for i in 0..x.len() {
        x[i] += alpha * p[i];
        let ri = r[i] - alpha * q[i];
        r[i] = ri;
        let zi = ri * d[i];
        z[i] = zi;
        rr += ri * ri;
        rz += ri * zi;
    }
    (rr, rz)
}

/// x ← x + αp, r ← r − αq, z ← D⁻¹ r; returns (rᵀr, rᵀz).
fn update_xrz(
    alpha: f64,
    x: &mut [f64],
    r: &mut [f64],
    z: &mut [f64],
    p: &[f64],
    q: &[f64],
    inv_diag: &[f64],
) -> (f64, f64) {
    let n = x.len();
    let block = |b: usize, x: &mut [f64], r: &mut [f64], z: &mut [f64]| {
        let range = b * BLOCK..(b * BLOCK + x.len()).min(n);
        xrz_block(
            alpha,
            x,
            r,
            z,
            &p[range.clone()],
            &q[range.clone()],
            &inv_diag[range],
        )
    };
    let parts: Vec<(f64, f64)> = if n >= PAR_MIN_N {
        x.par_chunks_mut(BLOCK)
            .zip(r.par_chunks_mut(BLOCK))
            .zip(z.par_chunks_mut(BLOCK))
            .enumerate()
            .map(|(b, ((x, r), z))| block(b, x, r, z))
            .collect()
    } else {
        x.chunks_mut(BLOCK)
            .zip(r.chunks_mut(BLOCK))
            .zip(z.chunks_mut(BLOCK))
            .enumerate()
            .map(|(b, ((x, r), z))| block(b, x, r, z))
            .collect()
    };
    parts
        .iter()
        .fold((0.0, 0.0), |(a, b), &(c, d)| (a + c, b + d))
}

/// p ← z + βp.
fn update_p(beta: f64, p: &mut [f64], z: &[f64]) {
    let f = |(p, z): (&mut [f64], &[f64])| {
        for (pi, zi) in p.iter_mut().zip(z) {
            *pi = zi + beta * *pi;
        }
    };
    if p.len() >= PAR_MIN_N {
        p.par_chunks_mut(BLOCK).zip(z.par_chunks(BLOCK)).for_each(f);
    } else {
        p.chunks_mut(BLOCK).zip(z.chunks(BLOCK)).for_each(f);
    }
}

/// z ← D⁻¹ r; returns rᵀz.
fn precondition(r: &[f64], inv_diag: &[f64], z: &mut [f64]) -> f64 {
    for ((zi, ri), di) in z.iter_mut().zip(r).zip(inv_diag) {
        *zi = ri * di;
    }
    dot(r, z)
}

/// r ← b − K x; returns ‖r‖.
fn true_residual(op: &FullOperator, b: &[f64], x: &[f64], r: &mut [f64]) -> f64 {
    op.apply(x, r);
    for (ri, bi) in r.iter_mut().zip(b) {
        *ri = bi - *ri;
    }
    norm(r)
}

/// Preconditioned conjugate gradient (thesis fig. 4.10) with the Jacobi
/// preconditioner `M = diag(K)`, starting from `x = 0`.
///
/// Stops when the recursively updated residual satisfies `‖r‖ ≤ rel_tol ‖b‖`
/// and the true residual `b − Kx` confirms it (otherwise CG restarts from the
/// true residual), or after `max_iter` iterations. A curvature `pᵀKp ≤ 0`
/// reports [`LinalgError::NotPositiveDefinite`]. `x` always holds a finite
/// vector on return (the last finite iterate, or zero).
pub(crate) fn pcg(
    op: &FullOperator,
    inv_diag: &[f64],
    b: &[f64],
    x: &mut [f64],
    rel_tol: f64,
    max_iter: usize,
    work: &mut CgWork,
) -> CgOutcome {
    let n = b.len();
    x.fill(0.0);
    let bnorm = norm(b);
    if bnorm == 0.0 {
        return CgOutcome {
            iterations: 0,
            relative_residual: 0.0,
            result: Ok(()),
        };
    }
    for v in [&mut work.r, &mut work.z, &mut work.p, &mut work.q] {
        v.clear();
        v.resize(n, 0.0);
    }
    let CgWork { r, z, p, q } = work;
    r.copy_from_slice(b);
    let mut rz = precondition(r, inv_diag, z);
    p.copy_from_slice(z);
    let mut rel = 1.0;
    let mut it = 0;
    while it < max_iter {
        it += 1;
        let pq = op.apply_dot(p, q);
        if !pq.is_finite() {
            x.fill(0.0);
            return CgOutcome {
                iterations: it,
                relative_residual: f64::INFINITY,
                result: Err(LinalgError::NonFinite),
            };
        }
        if pq <= 0.0 {
            let rel = true_residual(op, b, x, r) / bnorm;
            return CgOutcome {
                iterations: it,
                relative_residual: rel,
                result: Err(LinalgError::NotPositiveDefinite),
            };
        }
        let alpha = rz / pq;
        let (rr, rz_new) = update_xrz(alpha, x, r, z, p, q, inv_diag);
        if !(rr.is_finite() && rz_new.is_finite()) {
            x.fill(0.0);
            return CgOutcome {
                iterations: it,
                relative_residual: f64::INFINITY,
                result: Err(LinalgError::NonFinite),
            };
        }
        rel = rr.sqrt() / bnorm;
        if rel <= rel_tol {
            // Confirm with the true residual (guards against drift of the
            // recursively updated residual); restart from it if needed.
            rel = true_residual(op, b, x, r) / bnorm;
            if rel <= rel_tol {
                return CgOutcome {
                    iterations: it,
                    relative_residual: rel,
                    result: Ok(()),
                };
            }
            rz = precondition(r, inv_diag, z);
            p.copy_from_slice(z);
            continue;
        }
        let beta = rz_new / rz;
        rz = rz_new;
        update_p(beta, p, z);
    }
    if it > 0 {
        rel = true_residual(op, b, x, r) / bnorm;
    }
    if rel <= rel_tol {
        return CgOutcome {
            iterations: it,
            relative_residual: rel,
            result: Ok(()),
        };
    }
    CgOutcome {
        iterations: it,
        relative_residual: rel,
        result: Err(LinalgError::NotConverged {
            iterations: it,
            relative_residual: rel,
        }),
    }
}
