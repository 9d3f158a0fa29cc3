//! Test fixtures shared by the reader tests: reference meshes, temporary directories and
//! comparisons of surfaces up to vertex numbering.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::Point3;

use super::error::MeshError;
use super::surface::TriSurface;

/// The unit cube `[0, 1]³`: 8 vertices, 12 outward triangles, volume exactly 1.
pub(crate) fn cube() -> TriSurface {
    let vertices = [
        [0., 0., 0.],
        [1., 0., 0.],
        [1., 1., 0.],
        [0., 1., 0.],
        [0., 0., 1.],
        [1., 0., 1.],
        [1., 1., 1.],
        [0., 1., 1.],
    ]
    .map(Point3::from)
    .to_vec();
    let triangles = vec![
        [0, 2, 1],
        [0, 3, 2],
        [4, 5, 6],
        [4, 6, 7],
        [0, 1, 5],
        [0, 5, 4],
        [3, 7, 6],
        [3, 6, 2],
        [0, 4, 7],
        [0, 7, 3],
        [1, 2, 6],
        [1, 6, 5],
    ];
    TriSurface::new(vertices, triangles)
}

/// The faces of [`cube`] as outward quadrangles whose fan triangulation gives its triangles.
pub(crate) const CUBE_QUADS: [[usize; 4]; 6] = [
    [0, 3, 2, 1],
    [4, 5, 6, 7],
    [0, 1, 5, 4],
    [3, 7, 6, 2],
    [0, 4, 7, 3],
    [1, 2, 6, 5],
];

/// The octahedron with vertices `±eᵢ` scaled by 1.5 and shifted by (0.25, -0.5, 2), outward
/// triangles, volume `4/3 · 1.5³`.
pub(crate) fn octahedron() -> TriSurface {
    let r = 1.5;
    let c = Point3::new(0.25, -0.5, 2.0);
    let vertices = [
        [r, 0., 0.],
        [-r, 0., 0.],
        [0., r, 0.],
        [0., -r, 0.],
        [0., 0., r],
        [0., 0., -r],
    ]
    .map(|v| c + nalgebra::Vector3::from(v))
    .to_vec();
    let triangles = vec![
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    TriSurface::new(vertices, triangles)
}

/// Both reference meshes with a short name.
pub(crate) fn reference_meshes() -> [(&'static str, TriSurface); 2] {
    [("cube", cube()), ("octahedron", octahedron())]
}

/// A fresh directory under the system temporary directory, removed on drop.
pub(crate) struct TempDir(PathBuf);

impl TempDir {
    /// Creates a directory whose name contains `tag`, the process id and a counter.
    pub(crate) fn new(tag: &str) -> Self {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let dir =
            std::env::temp_dir().join(format!("livereg-mesh-{}-{n}-{tag}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    /// Path of file `name` inside the directory.
    pub(crate) fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    /// Writes `data` to file `name` and returns its path.
    pub(crate) fn write(&self, name: &str, data: impl AsRef<[u8]>) -> PathBuf {
        let path = self.path(name);
        std::fs::write(&path, data).unwrap();
        path
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn key(p: &Point3<f64>) -> [u64; 3] {
    [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]
}

/// Triangles as coordinate triples, each rotated to start at its smallest corner (so the
/// orientation is kept), sorted.
fn oriented_triangles(s: &TriSurface) -> Vec<[[u64; 3]; 3]> {
    let mut tris: Vec<_> = s
        .triangles
        .iter()
        .map(|t| {
            let mut k = t.map(|i| key(&s.vertices[i]));
            let first = (0..3).min_by_key(|&i| k[i]).unwrap();
            k.rotate_left(first);
            k
        })
        .collect();
    tris.sort_unstable();
    tris
}

/// Asserts that `a` and `b` have the same vertex positions (exactly, as a set), the same number
/// of triangles and the same oriented triangles, whatever the vertex numbering.
pub(crate) fn assert_same_surface(a: &TriSurface, b: &TriSurface) {
    let mut va: Vec<_> = a.vertices.iter().map(key).collect();
    let mut vb: Vec<_> = b.vertices.iter().map(key).collect();
    va.sort_unstable();
    vb.sort_unstable();
    assert_eq!(va, vb, "vertex sets differ");
    assert_eq!(
        a.triangles.len(),
        b.triangles.len(),
        "triangle counts differ"
    );
    assert_eq!(
        oriented_triangles(a),
        oriented_triangles(b),
        "oriented triangles differ"
    );
}

/// Asserts that the message of `result`'s error contains the file name of `path` and every one
/// of `parts`, and returns the message.
#[track_caller]
pub(crate) fn assert_err<T: std::fmt::Debug>(
    result: Result<T, MeshError>,
    path: &Path,
    parts: &[&str],
) -> String {
    let msg = result.expect_err("expected an error").to_string();
    let name = path.file_name().unwrap().to_string_lossy();
    assert!(msg.contains(&*name), "message {msg:?} does not name {name}");
    for part in parts {
        assert!(
            msg.contains(part),
            "message {msg:?} does not contain {part:?}"
        );
    }
    msg
}

/// Feeds the parser `parse` (path, content) prefixes of the valid file content `good` and copies
/// of it with a few bytes overwritten (deterministic pseudo-random positions and values); it must
/// return, with a value or an error naming the file, and never panic.
pub(crate) fn assert_robust<T>(
    ext: &str,
    good: &[u8],
    parse: impl Fn(&Path, &[u8]) -> Result<T, MeshError>,
) {
    let path = PathBuf::from(format!("fuzz.{ext}"));
    let check = |data: &[u8]| {
        if let Err(e) = parse(&path, data) {
            assert!(e.to_string().starts_with("fuzz."), "{e}");
        }
    };
    for len in 0..good.len() {
        check(&good[..len]);
    }
    const BYTES: &[u8] = b"\n \t-+.0123456789eE/#$\x00\xff\x80";
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for _ in 0..2000 {
        let mut bad = good.to_vec();
        for _ in 0..1 + next() % 3 {
            let at = (next() % good.len() as u64) as usize;
            let r = next();
            bad[at] = if r % 2 == 0 {
                BYTES[(r / 2 % BYTES.len() as u64) as usize]
            } else {
                (r >> 8) as u8
            };
        }
        check(&bad);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_meshes_are_closed_and_outward() {
        assert_eq!(cube().signed_volume(), 1.0);
        let v = octahedron().signed_volume();
        assert!((v - 4.0 / 3.0 * 1.5f64.powi(3)).abs() < 1e-12, "{v}");
    }

    #[test]
    fn comparison_detects_flipped_triangle() {
        let a = cube();
        let mut b = cube();
        b.triangles[3].swap(1, 2);
        let r = std::panic::catch_unwind(|| assert_same_surface(&a, &b));
        assert!(r.is_err());
        let mut c = cube();
        c.vertices.reverse();
        for t in &mut c.triangles {
            *t = t.map(|i| 7 - i);
        }
        assert_same_surface(&a, &c);
    }
}
