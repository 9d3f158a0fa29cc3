//! Wavefront OBJ: reading `v` and `f` lines, writing vertices and triangles.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use super::assemble::{fan, finish};
use super::error::MeshError;
use super::surface::TriSurface;
use super::text::{decode, quote, read_bytes, Lines};

/// Reads an OBJ file: `v x y z` vertices (extra values such as `w` or colours are ignored) and
/// `f` faces in the `v`, `v/vt`, `v//vn` and `v/vt/vn` forms with 1-based or negative (relative)
/// indices; polygons are fan-triangulated. All other statements (`vn`, `vt`, `o`, `g`, `s`,
/// `usemtl`, `mtllib`, `l`, ...) and `#` comments are ignored. Lengths are in the file's units.
pub fn read_obj(path: &Path) -> Result<TriSurface, MeshError> {
    parse(path, &decode(&read_bytes(path)?))
}

fn parse(path: &Path, text: &str) -> Result<TriSurface, MeshError> {
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    let mut poly = Vec::new();
    // Indices to vertices not defined yet (line, index as written), checked at the end.
    let mut forward = Vec::new();
    for line in Lines::new(path, text, Some('#')) {
        let mut tokens = line.tokens();
        match tokens.next() {
            Some("v") => vertices.push(tokens.point()?),
            Some("f") => {
                poly.clear();
                for corner in tokens {
                    let written = corner.split('/').next().unwrap_or_default();
                    let index: i64 = written.parse().map_err(|_| {
                        line.err(format!("invalid vertex index {} in face", quote(corner)))
                    })?;
                    let count = vertices.len();
                    let resolved = match index {
                        0 => {
                            return Err(
                                line.err("vertex index 0 is invalid (OBJ indices start at 1)")
                            )
                        }
                        i if i > 0 => (i - 1) as usize,
                        i => usize::try_from(count as i64 + i).map_err(|_| {
                            MeshError::IndexOutOfRange {
                                path: path.into(),
                                line: Some(line.no),
                                index,
                                count,
                            }
                        })?,
                    };
                    if resolved >= count {
                        forward.push((line.no, index, resolved));
                    }
                    poly.push(resolved);
                }
                fan(&poly, &mut triangles, |m| line.err(m))?;
            }
            _ => {}
        }
    }
    if let Some(&(line, index, _)) = forward.iter().find(|f| f.2 >= vertices.len()) {
        return Err(MeshError::IndexOutOfRange {
            path: path.into(),
            line: Some(line),
            index,
            count: vertices.len(),
        });
    }
    finish(path, vertices, triangles)
}

/// Writes `surface` as OBJ (`v` and 1-based `f` lines). Coordinates use Rust's shortest
/// round-trip formatting, so reading the file back gives exactly the same values.
pub fn write_obj(path: &Path, surface: &TriSurface) -> Result<(), MeshError> {
    let io = |e| MeshError::io(path, e);
    let mut out = BufWriter::new(File::create(path).map_err(io)?);
    writeln!(
        out,
        "# {} vertices, {} triangles",
        surface.vertices.len(),
        surface.triangles.len()
    )
    .map_err(io)?;
    for v in &surface.vertices {
        writeln!(out, "v {} {} {}", v.x, v.y, v.z).map_err(io)?;
    }
    for [a, b, c] in &surface.triangles {
        writeln!(out, "f {} {} {}", a + 1, b + 1, c + 1).map_err(io)?;
    }
    out.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::fixtures::{
        assert_err, assert_robust, assert_same_surface, cube, octahedron, reference_meshes, TempDir,
    };
    use crate::mesh::validate::validate;
    use nalgebra::Point3;

    #[test]
    fn round_trip_reference_meshes() {
        let dir = TempDir::new("obj-rt");
        for (name, mesh) in reference_meshes() {
            let path = dir.path(&format!("{name}.obj"));
            write_obj(&path, &mesh).unwrap();
            let back = read_obj(&path).unwrap();
            assert_eq!(back, mesh, "{name}: exact round trip");
            assert!(validate(&back).watertight, "{name}");
        }
        assert_eq!(
            read_obj(&dir.path("cube.obj")).unwrap().signed_volume(),
            1.0
        );
    }

    #[test]
    fn round_trip_is_exact_for_awkward_values() {
        let dir = TempDir::new("obj-f64");
        let vals = [0.1, 1.0 / 3.0, -2.5e-300, 1.0e300, -0.0, 123456.789];
        let vertices = vals
            .iter()
            .map(|&x| Point3::new(x, -x * 7.0, x / 3.0))
            .collect();
        let mesh = TriSurface::new(vertices, vec![[0, 1, 2], [3, 4, 5]]);
        let path = dir.path("vals.obj");
        write_obj(&path, &mesh).unwrap();
        let back = read_obj(&path).unwrap();
        for (a, b) in mesh.vertices.iter().zip(&back.vertices) {
            for k in 0..3 {
                assert_eq!(a[k].to_bits(), b[k].to_bits());
            }
        }
    }

    #[test]
    fn face_forms_negative_indices_quads_and_ignored_statements() {
        let dir = TempDir::new("obj-forms");
        let text = "\
mtllib cube.mtl
o cube
# bottom ring
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vn 0 0 -1
v 0 0 1 1.0
v 1 0 1
v 1 1 1
v 0 1 1
g sides
usemtl skin
s off
f 1/1/1 3/1/1 2/1/1
f 1//1 4//1 3//1
f -4/1 -3/1 -2/1 -1/1
f 1 2 6 5
f 4 8 7 3
f 1 5 8 4
f 2 3 7 6
";
        let path = dir.write("forms.obj", text);
        let mesh = read_obj(&path).unwrap();
        assert_eq!(mesh.triangles.len(), 12);
        assert_same_surface(&mesh, &cube());
        assert_eq!(mesh.signed_volume(), 1.0);
        assert!(validate(&mesh).watertight);
    }

    #[test]
    fn corrupted_files_never_panic() {
        let dir = TempDir::new("obj-fuzz");
        let good = dir.path("good.obj");
        write_obj(&good, &octahedron()).unwrap();
        let mut data = std::fs::read(&good).unwrap();
        data.extend(b"vt 0 1\nf 1/1/1 -1//2 3/4\nf -6 -5 -4 -3\n");
        assert_robust("obj", &data, |p, d| parse(p, &decode(d)));
    }

    #[test]
    fn byte_order_mark_is_ignored() {
        let dir = TempDir::new("obj-bom");
        let path = dir.write("bom.obj", "\u{feff}v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
        assert_eq!(read_obj(&path).unwrap().vertices.len(), 3);
    }

    #[test]
    fn forward_references_are_resolved_at_the_end() {
        let dir = TempDir::new("obj-fwd");
        let path = dir.write("fwd.obj", "f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n");
        assert_eq!(read_obj(&path).unwrap().triangles, vec![[0, 1, 2]]);
    }

    #[test]
    fn bad_input_is_reported_with_file_and_line() {
        let dir = TempDir::new("obj-bad");
        let cases: &[(&str, &str, &[&str])] = &[
            (
                "range.obj",
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 40\n",
                &[
                    ":4:",
                    "face index 40 out of range (the file has 3 vertices)",
                ],
            ),
            (
                "neg.obj",
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n",
                &[":4:", "face index -4"],
            ),
            (
                "zero.obj",
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",
                &[":4:", "index 0"],
            ),
            (
                "nan.obj",
                "v 0 0 0\nv 1 NaN 0\n",
                &[":2:", "'NaN'", "not a finite"],
            ),
            ("inf.obj", "v 0 0 0\nv 1 0 inf\n", &[":2:", "'inf'"]),
            (
                "trunc.obj",
                "v 0 0 0\nv 1 0 0\nv 0 1\n",
                &[":3:", "z coordinate", "end of line"],
            ),
            (
                "two.obj",
                "v 0 0 0\nv 1 0 0\nf 1 2\n",
                &[":3:", "at least 3"],
            ),
            ("garbage.obj", "v 0 0 0\nf a/b c d\n", &[":2:", "'a/b'"]),
            ("empty.obj", "# nothing\nv 1 2 3\n", &["no triangles"]),
        ];
        for (name, text, parts) in cases {
            let path = dir.write(name, text);
            assert_err(read_obj(&path), &path, parts);
        }
        let path = dir.write(
            "bytes.obj",
            [0xff, 0xfe, b'v', 0, 0x80, b'\n', b'f', b' ', 0x90],
        );
        assert_err(read_obj(&path), &path, &[":"]);
        let missing = dir.path("missing.obj");
        assert_err(read_obj(&missing), &missing, &[]);
    }
}
