//! [`Labelmap`]: a 3-D grid of integer labels with its voxel-index → physical affine and the
//! names of its segments.
//!
//! **Physical coordinates are LPS, in millimetres**: x grows towards the patient's Left, y
//! towards Posterior, z towards Superior — the convention of DICOM, ITK and of 3D Slicer's files.
//! Readers convert into it: NIfTI's RAS+ world (x towards the patient's right, y anterior) is
//! turned into LPS by negating x and y; NRRD files declare their `space` and are converted the
//! same way.

use nalgebra::{Matrix3, Matrix4, Point3, Vector3};

use super::error::SegmentationError;

/// Largest labelmap accepted, in voxels (2³⁰ ≈ 1.07 G voxels, 2 GiB of `u16`): readers check
/// header sizes against it (and against the data actually present) before allocating.
pub const MAX_VOXELS: usize = 1 << 30;

/// A named segment of a labelmap (3D Slicer's `SegmentN_Name` / `SegmentN_LabelValue`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Segment {
    /// The segment's name, e.g. `"liver"`.
    pub name: String,
    /// The voxel value that marks it.
    pub label: u16,
}

/// A 3-D labelmap: `dims[0] × dims[1] × dims[2]` integer labels (0 = background by
/// convention), the first index varying fastest, and the 4×4 affine taking a voxel index
/// `(i, j, k, 1)` (voxel centres at integer indices) to physical LPS millimetres.
#[derive(Debug, Clone, PartialEq)]
pub struct Labelmap {
    dims: [usize; 3],
    labels: Vec<u16>,
    affine: Matrix4<f64>,
    segments: Vec<Segment>,
}

impl Labelmap {
    /// A labelmap from its sizes, labels (first index fastest) and index → LPS mm affine.
    ///
    /// Fails if `labels.len()` is not the product of `dims`, a size is zero, the labelmap is
    /// larger than [`MAX_VOXELS`], or the affine is not finite, affine (last row `0 0 0 1`) and
    /// invertible.
    pub fn new(
        dims: [usize; 3],
        labels: Vec<u16>,
        affine: Matrix4<f64>,
    ) -> Result<Self, SegmentationError> {
        let n = voxel_count(dims)
            .ok_or_else(|| SegmentationError::Labelmap(format!("sizes {dims:?} are too large")))?;
        if dims.contains(&0) {
            return Err(SegmentationError::Labelmap(format!(
                "sizes {dims:?} include a zero"
            )));
        }
        if n != labels.len() {
            return Err(SegmentationError::Labelmap(format!(
                "sizes {dims:?} make {n} voxels but {} labels were given",
                labels.len()
            )));
        }
        check_affine(&affine).map_err(SegmentationError::Labelmap)?;
        Ok(Self {
            dims,
            labels,
            affine,
            segments: Vec::new(),
        })
    }

    /// The same labelmap with these named segments (replacing any it had).
    pub fn with_segments(mut self, segments: Vec<Segment>) -> Self {
        self.segments = segments;
        self
    }

    /// Sizes along the three index axes.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// All labels, the first index varying fastest.
    pub fn labels(&self) -> &[u16] {
        &self.labels
    }

    /// The voxel index → physical LPS mm affine.
    pub fn affine(&self) -> &Matrix4<f64> {
        &self.affine
    }

    /// Named segments, as read from the file (empty when the file names none).
    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// The label value of the segment called `name` (exact match first, then ASCII
    /// case-insensitive).
    pub fn label_of(&self, name: &str) -> Option<u16> {
        self.segments
            .iter()
            .find(|s| s.name == name)
            .or_else(|| {
                self.segments
                    .iter()
                    .find(|s| s.name.eq_ignore_ascii_case(name))
            })
            .map(|s| s.label)
    }

    /// Linear position of voxel `(i, j, k)` in [`Self::labels`].
    pub fn linear_index(&self, [i, j, k]: [usize; 3]) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// The label at voxel `(i, j, k)`, `None` outside the grid.
    pub fn get(&self, ijk: [usize; 3]) -> Option<u16> {
        (ijk[0] < self.dims[0] && ijk[1] < self.dims[1] && ijk[2] < self.dims[2])
            .then(|| self.labels[self.linear_index(ijk)])
    }

    /// Physical LPS position (mm) of a continuous voxel index (voxel centres are integers).
    pub fn index_to_physical(&self, ijk: &Point3<f64>) -> Point3<f64> {
        self.affine.transform_point(ijk)
    }

    /// The linear part of the affine (columns: the physical steps of the three index axes).
    pub fn directions(&self) -> Matrix3<f64> {
        self.affine.fixed_view::<3, 3>(0, 0).into_owned()
    }

    /// Voxel spacing along the three index axes (norms of the affine's columns), mm.
    pub fn spacing(&self) -> Vector3<f64> {
        let d = self.directions();
        Vector3::new(d.column(0).norm(), d.column(1).norm(), d.column(2).norm())
    }

    /// Volume of one voxel, mm³.
    pub fn voxel_volume(&self) -> f64 {
        self.directions().determinant().abs()
    }

    /// Number of voxels whose label is one of `labels`.
    pub fn count(&self, labels: &[u16]) -> usize {
        let table = LabelSet::new(labels);
        self.labels.iter().filter(|&&l| table.contains(l)).count()
    }

    /// The distinct non-zero labels present, sorted.
    pub fn present_labels(&self) -> Vec<u16> {
        let mut seen = vec![false; 1 << 16];
        for &l in &self.labels {
            seen[l as usize] = true;
        }
        (1..=u16::MAX).filter(|&l| seen[l as usize]).collect()
    }

    /// Index bounding box `(min, max)` (inclusive) of the voxels whose label is one of
    /// `labels`; `None` if there is none.
    pub fn bounding_box(&self, labels: &[u16]) -> Option<([usize; 3], [usize; 3])> {
        let table = LabelSet::new(labels);
        let [nx, ny, _] = self.dims;
        let mut lo = [usize::MAX; 3];
        let mut hi = [0usize; 3];
        for (row, chunk) in self.labels.chunks_exact(nx).enumerate() {
            let (j, k) = (row % ny, row / ny);
            let first = chunk.iter().position(|&l| table.contains(l));
            let Some(first) = first else { continue };
            let last = chunk
                .iter()
                .rposition(|&l| table.contains(l))
                .unwrap_or(first);
            lo[0] = lo[0].min(first);
            hi[0] = hi[0].max(last);
            lo[1] = lo[1].min(j);
            hi[1] = hi[1].max(j);
            lo[2] = lo[2].min(k);
            hi[2] = hi[2].max(k);
        }
        (lo[0] != usize::MAX).then_some((lo, hi))
    }
}

/// Product of the sizes, `None` on overflow.
pub(crate) fn voxel_count(dims: [usize; 3]) -> Option<usize> {
    dims[0].checked_mul(dims[1])?.checked_mul(dims[2])
}

/// Checks that an index → physical matrix is finite, affine and invertible.
pub(crate) fn check_affine(a: &Matrix4<f64>) -> Result<(), String> {
    if a.iter().any(|v| !v.is_finite()) {
        return Err(format!("the affine has non-finite entries: {a}"));
    }
    if a.row(3) != nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0) {
        return Err(format!("the affine's last row is not (0 0 0 1): {a}"));
    }
    let d: Matrix3<f64> = a.fixed_view::<3, 3>(0, 0).into_owned();
    let scale = d.column(0).norm() * d.column(1).norm() * d.column(2).norm();
    if scale == 0.0 || d.determinant().abs() <= 1e-9 * scale {
        return Err(format!(
            "the affine's 3×3 part is singular (a zero or repeated axis direction): {a}"
        ));
    }
    Ok(())
}

/// Membership table for a set of labels.
pub(crate) struct LabelSet(Box<[bool]>);

impl LabelSet {
    pub(crate) fn new(labels: &[u16]) -> Self {
        let mut t = vec![false; 1 << 16].into_boxed_slice();
        for &l in labels {
            t[l as usize] = true;
        }
        Self(t)
    }

    #[inline]
    pub(crate) fn contains(&self, l: u16) -> bool {
        self.0[l as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_affine_are_checked() {
        let id = Matrix4::identity();
        assert!(Labelmap::new([2, 2, 2], vec![0; 8], id).is_ok());
        let e = Labelmap::new([2, 2, 2], vec![0; 7], id).unwrap_err();
        assert!(e.to_string().contains("8 voxels but 7 labels"), "{e}");
        let e = Labelmap::new([0, 2, 2], vec![], id).unwrap_err();
        assert!(e.to_string().contains("zero"), "{e}");
        let mut singular = id;
        singular[(2, 2)] = 0.0;
        let e = Labelmap::new([2, 2, 2], vec![0; 8], singular).unwrap_err();
        assert!(e.to_string().contains("singular"), "{e}");
    }

    #[test]
    fn bounding_box_and_counts() {
        let mut labels = vec![0u16; 4 * 5 * 6];
        let m = |i: usize, j: usize, k: usize| i + 4 * (j + 5 * k);
        labels[m(1, 2, 3)] = 7;
        labels[m(2, 4, 1)] = 7;
        labels[m(3, 0, 5)] = 9;
        let lm = Labelmap::new([4, 5, 6], labels, Matrix4::identity())
            .unwrap()
            .with_segments(vec![Segment {
                name: "Liver".into(),
                label: 7,
            }]);
        assert_eq!(lm.bounding_box(&[7]), Some(([1, 2, 1], [2, 4, 3])));
        assert_eq!(lm.bounding_box(&[7, 9]), Some(([1, 0, 1], [3, 4, 5])));
        assert_eq!(lm.bounding_box(&[5]), None);
        assert_eq!(lm.count(&[7, 9]), 3);
        assert_eq!(lm.present_labels(), vec![7, 9]);
        assert_eq!(lm.label_of("liver"), Some(7));
        assert_eq!(lm.get([3, 0, 5]), Some(9));
        assert_eq!(lm.get([4, 0, 0]), None);
    }
}
