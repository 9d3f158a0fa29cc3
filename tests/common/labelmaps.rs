//! Labelmaps for the segmentation tests: a voxel grid laid over a surface, and labelmap files
//! written from labels by the independent writers nibabel and pynrrd
//! (`tests/python/write_labelmaps.py`: `sform.nii.gz`, `qform.nii`, `liver.seg.nrrd`,
//! `ras.nrrd`).

use std::path::Path;
use std::process::Command;

use livereg::mesh::TriSurface;
use nalgebra::{Matrix3, Matrix4, Point3, Rotation3, Vector3};

/// What the Python writers need.
pub const PIP: &str = "python3 -m pip install nibabel==5.4.2 pynrrd==1.1.3 numpy";

/// Index → LPS affine with voxel edges `spacing` (mm; a negative one mirrors) turned by
/// `rotation`, its grid covering `surface` with 3 voxels to spare: the grid's sizes and the
/// affine.
pub fn grid_for(
    surface: &TriSurface,
    spacing: Vector3<f64>,
    rotation: Rotation3<f64>,
) -> ([usize; 3], Matrix4<f64>) {
    let mut a = Matrix4::identity();
    a.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(rotation.matrix() * Matrix3::from_diagonal(&spacing)));
    let inv = a.try_inverse().expect("an invertible affine");
    let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
    for p in &surface.vertices {
        let q = inv.transform_point(p);
        for k in 0..3 {
            lo[k] = lo[k].min(q[k]);
            hi[k] = hi[k].max(q[k]);
        }
    }
    let start = lo.map(|l| l.floor() - 3.0);
    let dims = [0, 1, 2].map(|k| (hi[k] - start[k]).ceil() as usize + 4);
    let t = a.transform_point(&Point3::new(start[0], start[1], start[2]));
    a.fixed_view_mut::<3, 1>(0, 3).copy_from(&t.coords);
    (dims, a)
}

/// Writes `labels` (first index fastest) and the affine into `dir` (created) and runs the
/// Python writers there; fails the test, naming the install line, when they cannot run.
pub fn write_with_python(dir: &Path, labels: &[u16], dims: [usize; 3], affine: &Matrix4<f64>) {
    std::fs::create_dir_all(dir).unwrap();
    let bytes: Vec<u8> = labels.iter().flat_map(|l| l.to_le_bytes()).collect();
    std::fs::write(dir.join("labels.u16"), bytes).unwrap();
    let rows: Vec<Vec<f64>> = (0..4)
        .map(|r| (0..4).map(|c| affine[(r, c)]).collect())
        .collect();
    let meta = serde_json::json!({ "dims": dims, "affine_lps": rows });
    std::fs::write(dir.join("meta.json"), meta.to_string()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/write_labelmaps.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(dir)
        .output()
        .unwrap_or_else(|e| panic!("python3 does not run ({e}); install it and: {PIP}"));
    assert!(
        out.status.success(),
        "the Python writers failed (are they installed? {PIP}):\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
