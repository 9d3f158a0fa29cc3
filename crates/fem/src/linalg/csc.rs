//! Lower-triangular compressed sparse column storage of a symmetric matrix.

use super::LinalgError;

/// Symmetric sparse matrix stored as its lower triangle (`row ≥ col`) in
/// compressed sparse column (CSC) form.
///
/// Invariants (checked by [`SymmetricCsc::from_pattern`]):
/// * `col_ptr.len() == n + 1`, `col_ptr[0] == 0`, `col_ptr` non-decreasing and
///   `col_ptr[n] == row_idx.len() == values.len()`;
/// * the row indices of column `j` are `row_idx[col_ptr[j]..col_ptr[j + 1]]`,
///   strictly increasing, all in `j..n`;
/// * the diagonal entry is always present, i.e. the first row index of
///   column `j` is `j`.
///
/// The entry `values[p]` is `K[row_idx[p]][j]` (and by symmetry
/// `K[j][row_idx[p]]`). Units are those of the assembled operator (for the
/// finite-element stiffness: force per displacement).
#[derive(Clone, Debug, PartialEq)]
pub struct SymmetricCsc {
    /// Matrix dimension (number of degrees of freedom).
    pub n: usize,
    /// Column pointers, length `n + 1`.
    pub col_ptr: Vec<usize>,
    /// Row indices of the stored (lower-triangular) entries, sorted per column.
    pub row_idx: Vec<usize>,
    /// Values of the stored entries, aligned with `row_idx`.
    pub values: Vec<f64>,
}

impl SymmetricCsc {
    /// Creates a matrix with the given lower-triangular pattern and all values
    /// zero, after checking every invariant listed on [`SymmetricCsc`].
    ///
    /// Returns [`LinalgError::InvalidPattern`] with a message naming the first
    /// violation (wrong `col_ptr` length, out-of-bounds or upper-triangular row
    /// index, unsorted or duplicated row indices, missing diagonal).
    pub fn from_pattern(
        n: usize,
        col_ptr: Vec<usize>,
        row_idx: Vec<usize>,
    ) -> Result<Self, LinalgError> {
        validate_pattern(n, &col_ptr, &row_idx)?;
        let nnz = row_idx.len();
        Ok(Self {
            n,
            col_ptr,
            row_idx,
            values: vec![0.0; nnz],
        })
    }

    /// Builds a matrix from `(row, col, value)` triplets. Entries may be given
    /// in either triangle (they are mirrored into the lower one) and
    /// duplicates are summed, as in finite-element assembly. Diagonal entries
    /// are always created (zero if absent from `triplets`).
    ///
    /// Intended for tests, examples and small problems; assembly of large
    /// matrices should build the pattern once and fill `values` through
    /// [`SymmetricCsc::position`].
    pub fn from_triplets(n: usize, triplets: &[(usize, usize, f64)]) -> Result<Self, LinalgError> {
        let mut cols: Vec<Vec<(usize, f64)>> = (0..n).map(|j| vec![(j, 0.0)]).collect();
        for &(r, c, v) in triplets {
            if r >= n || c >= n {
                return Err(LinalgError::InvalidPattern(format!(
                    "triplet ({r}, {c}) out of bounds for dimension {n}"
                )));
            }
            let (i, j) = if r >= c { (r, c) } else { (c, r) };
            cols[j].push((i, v));
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        let mut values = Vec::new();
        col_ptr.push(0);
        for mut col in cols {
            col.sort_by_key(|&(i, _)| i);
            for (i, v) in col {
                if row_idx.len() > *col_ptr.last().unwrap_or(&0) && row_idx.last() == Some(&i) {
                    if let Some(last) = values.last_mut() {
                        *last += v;
                    }
                } else {
                    row_idx.push(i);
                    values.push(v);
                }
            }
            col_ptr.push(row_idx.len());
        }
        let mut m = Self::from_pattern(n, col_ptr, row_idx)?;
        m.values = values;
        Ok(m)
    }

    /// Number of stored (lower-triangular, diagonal included) entries.
    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }

    /// Index into `values` of the entry `(max(row, col), min(row, col))`, found
    /// by binary search in the column, or `None` if the entry is not part of
    /// the pattern (or out of bounds). Assembly code typically precomputes
    /// these positions once per pattern.
    pub fn position(&self, row: usize, col: usize) -> Option<usize> {
        let (i, j) = if row >= col { (row, col) } else { (col, row) };
        if i >= self.n {
            return None;
        }
        let start = self.col_ptr[j];
        let end = self.col_ptr[j + 1];
        self.row_idx[start..end]
            .binary_search(&i)
            .ok()
            .map(|k| start + k)
    }

    /// Computes `y = K x` using the symmetric lower storage (each strictly
    /// lower entry contributes twice). Serial, hence bitwise deterministic.
    ///
    /// # Panics
    /// Panics if `x.len() != n` or `y.len() != n`.
    pub fn mul_vec(&self, x: &[f64], y: &mut [f64]) {
        assert_eq!(x.len(), self.n, "mul_vec: x has wrong length");
        assert_eq!(y.len(), self.n, "mul_vec: y has wrong length");
        y.fill(0.0);
        for j in 0..self.n {
            let xj = x[j];
            let mut acc = 0.0;
            let range = self.col_ptr[j]..self.col_ptr[j + 1];
            for (&i, &v) in self.row_idx[range.clone()].iter().zip(&self.values[range]) {
                if i == j {
                    acc += v * xj;
                } else {
                    y[i] += v * xj;
                    acc += v * x[i];
                }
            }
            y[j] += acc;
        }
    }

    /// Returns the diagonal `K[j][j]` for `j = 0..n` (the diagonal is always
    /// the first stored entry of each column).
    pub fn diagonal(&self) -> Vec<f64> {
        (0..self.n).map(|j| self.values[self.col_ptr[j]]).collect()
    }

    /// Sets every stored value to zero, keeping the pattern (start of a new
    /// assembly).
    pub fn zero_values(&mut self) {
        self.values.fill(0.0);
    }

    /// A cheap 64-bit fingerprint (hash) of `n`, `col_ptr` and `row_idx`.
    ///
    /// Two matrices with the same pattern always have the same id; solvers use
    /// it (together with `n` and the number of entries) to decide whether a
    /// symbolic analysis can be reused. Values do not enter the hash. Cost:
    /// one pass over the index arrays.
    pub fn pattern_id(&self) -> u64 {
        let mut h = Fingerprint::new();
        h.write(self.n as u64);
        h.write(self.col_ptr.len() as u64);
        for &c in &self.col_ptr {
            h.write(c as u64);
        }
        h.write(self.row_idx.len() as u64);
        for &r in &self.row_idx {
            h.write(r as u64);
        }
        h.finish()
    }

    /// Dense copy of the full symmetric matrix (row-major, `n × n`). Only for
    /// small matrices (tests, debugging).
    pub fn to_dense(&self) -> Vec<Vec<f64>> {
        let mut d = vec![vec![0.0; self.n]; self.n];
        for (j, w) in self.col_ptr.windows(2).enumerate() {
            for p in w[0]..w[1] {
                let i = self.row_idx[p];
                d[i][j] = self.values[p];
                d[j][i] = self.values[p];
            }
        }
        d
    }

    /// Checks the pattern invariants of this matrix (see
    /// [`SymmetricCsc::from_pattern`]) and that `values` has one entry per
    /// stored index. Useful when the struct was built field by field.
    pub fn validate(&self) -> Result<(), LinalgError> {
        validate_pattern(self.n, &self.col_ptr, &self.row_idx)?;
        if self.values.len() != self.row_idx.len() {
            return Err(LinalgError::InvalidPattern(format!(
                "values has length {} but row_idx has length {}",
                self.values.len(),
                self.row_idx.len()
            )));
        }
        Ok(())
    }
}

fn validate_pattern(n: usize, col_ptr: &[usize], row_idx: &[usize]) -> Result<(), LinalgError> {
    let err = |m: String| Err(LinalgError::InvalidPattern(m));
    if col_ptr.len() != n + 1 {
        return err(format!(
            "col_ptr has length {} but n + 1 = {}",
            col_ptr.len(),
            n + 1
        ));
    }
    if col_ptr[0] != 0 {
        return err(format!("col_ptr[0] = {} (must be 0)", col_ptr[0]));
    }
    if col_ptr[n] != row_idx.len() {
        return err(format!(
            "col_ptr[n] = {} but row_idx has length {}",
            col_ptr[n],
            row_idx.len()
        ));
    }
    for j in 0..n {
        let (start, end) = (col_ptr[j], col_ptr[j + 1]);
        if end < start {
            return err(format!("col_ptr decreases at column {j} ({start} > {end})"));
        }
        if end > row_idx.len() {
            return err(format!("col_ptr[{}] = {end} exceeds row_idx length", j + 1));
        }
        let rows = &row_idx[start..end];
        match rows.first() {
            None => return err(format!("column {j} is empty (diagonal entry missing)")),
            Some(&r) if r < j => {
                return err(format!(
                    "column {j} has row index {r} above the diagonal (only the lower triangle may be stored)"
                ))
            }
            Some(&r) if r != j => {
                return err(format!("column {j} is missing its diagonal entry (first row index is {r})"))
            }
            _ => {}
        }
        for w in rows.windows(2) {
            if w[1] <= w[0] {
                return err(format!(
                    "row indices of column {j} are not strictly increasing ({} then {})",
                    w[0], w[1]
                ));
            }
        }
        if let Some(&last) = rows.last() {
            if last >= n {
                return err(format!(
                    "row index {last} in column {j} is out of bounds for dimension {n}"
                ));
            }
        }
    }
    Ok(())
}

/// Small, fast, deterministic 64-bit hash (multiply–xorshift mixing of each
/// word, splitmix64 finaliser).
struct Fingerprint(u64);

impl Fingerprint {
    fn new() -> Self {
        Self(0x243F_6A88_85A3_08D3)
    }

    #[inline]
    fn write(&mut self, v: u64) {
        let mut z = v ^ self.0.rotate_left(23);
        z = z.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        z ^= z >> 29;
        self.0 = z.wrapping_add(self.0.wrapping_mul(0xBF58_476D_1CE4_E5B9));
    }

    fn finish(self) -> u64 {
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}
