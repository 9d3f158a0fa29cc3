//! OFF (Object File Format, as written by Geomview, CGAL and MeshLab).

use std::path::Path;

use super::assemble::{bounded_capacity, fan, finish};
use super::error::MeshError;
use super::surface::TriSurface;
use super::text::{decode, quote, read_bytes, Lines};

/// Reads an ASCII OFF file: the `OFF` header (also `COFF`, `NOFF`, `STOFF`, ..., optionally
/// followed by the counts on the same line), the vertex, face and edge counts, `x y z` vertex
/// lines (extra values such as colours or normals ignored) and `n i1 … in` faces
/// (fan-triangulated, trailing colour values ignored). `#` starts a comment. Lengths are in the
/// file's units.
pub fn read_off(path: &Path) -> Result<TriSurface, MeshError> {
    let bytes = read_bytes(path)?;
    parse(path, &decode(&bytes))
}

fn parse(path: &Path, text: &str) -> Result<TriSurface, MeshError> {
    let mut lines = Lines::new(path, text, Some('#'));
    let header = lines.expect("the 'OFF' header")?;
    let mut tokens = header.tokens();
    let keyword = tokens.next().unwrap_or_default();
    let prefix = keyword.strip_suffix("OFF").ok_or_else(|| {
        header.err(format!(
            "not an OFF file: expected the 'OFF' header, found {}",
            quote(keyword)
        ))
    })?;
    if prefix.contains(['4', 'n']) {
        return Err(MeshError::unsupported(
            path,
            format!("{} files (not 3-D) are not supported", quote(keyword)),
        ));
    }
    if !prefix.chars().all(|c| "STCN".contains(c)) {
        return Err(header.err(format!("unknown OFF header {}", quote(keyword))));
    }
    let mut t = match header.tokens().nth(1) {
        Some("BINARY") => {
            return Err(MeshError::unsupported(
                path,
                "binary OFF files are not supported",
            ));
        }
        Some(_) => tokens, // the counts follow the keyword on the same line
        None => lines.expect("the vertex and face counts")?.tokens(),
    };
    let vertex_count = t.uint("the vertex count")?;
    let face_count = t.uint("the face count")?;
    t.next(); // the edge count, unused
    t.end()?;

    // A vertex line takes at least 6 bytes ("0 0 0\n"), a face line at least 8.
    let mut vertices = Vec::with_capacity(bounded_capacity(vertex_count, text.len(), 6));
    for i in 0..vertex_count {
        let line = lines.expect(&format!("vertex {i} of {vertex_count}"))?;
        vertices.push(line.tokens().point()?);
    }
    let mut triangles = Vec::with_capacity(bounded_capacity(face_count, text.len(), 8));
    let mut poly = Vec::new();
    for i in 0..face_count {
        let line = lines.expect(&format!("face {i} of {face_count}"))?;
        let mut t = line.tokens();
        let n = t.uint("the number of face vertices")?;
        poly.clear();
        for _ in 0..n {
            let index = t.int("a vertex index")?;
            match usize::try_from(index) {
                Ok(v) if v < vertex_count => poly.push(v),
                _ => {
                    return Err(MeshError::IndexOutOfRange {
                        path: path.into(),
                        line: Some(line.no),
                        index,
                        count: vertex_count,
                    })
                }
            }
        }
        fan(&poly, &mut triangles, |m| line.err(m))?;
    }
    finish(path, vertices, triangles)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::fixtures::{
        assert_err, assert_robust, assert_same_surface, cube, octahedron, reference_meshes,
        TempDir, CUBE_QUADS,
    };
    use crate::mesh::validate::validate;
    use std::fmt::Write as _;

    /// Writes `s` as OFF, with the counts on the header line or on their own line.
    fn write_off(s: &TriSurface, counts_on_header: bool) -> String {
        let (nv, nf) = (s.vertices.len(), s.triangles.len());
        let mut out = if counts_on_header {
            format!("OFF {nv} {nf} 0\n")
        } else {
            format!("OFF\n# a comment\n\n{nv} {nf} {}\n", nv + nf - 2)
        };
        for p in &s.vertices {
            writeln!(out, "{} {} {}", p.x, p.y, p.z).unwrap();
        }
        for [a, b, c] in &s.triangles {
            writeln!(out, "3 {a} {b} {c}").unwrap();
        }
        out
    }

    #[test]
    fn round_trip_reference_meshes() {
        let dir = TempDir::new("off-rt");
        for (name, mesh) in reference_meshes() {
            for counts_on_header in [false, true] {
                let path = dir.write(
                    &format!("{name}-{counts_on_header}.off"),
                    write_off(&mesh, counts_on_header),
                );
                let back = read_off(&path).unwrap();
                assert_eq!(back, mesh, "{name}");
                assert!(validate(&back).watertight);
            }
        }
        assert_eq!(
            read_off(&dir.path("cube-true.off"))
                .unwrap()
                .signed_volume(),
            1.0
        );
    }

    #[test]
    fn corrupted_files_never_panic() {
        let data = write_off(&octahedron(), false);
        assert_robust("off", data.as_bytes(), |p, d| parse(p, &decode(d)));
    }

    #[test]
    fn colour_variant_with_quads_and_trailing_colours() {
        let dir = TempDir::new("off-coff");
        let mut text = String::from("COFF # coloured\n8 6 12\n");
        for p in &cube().vertices {
            writeln!(text, "{} {} {} 255 128 0 255", p.x, p.y, p.z).unwrap();
        }
        for [a, b, c, d] in CUBE_QUADS {
            writeln!(text, "4 {a} {b} {c} {d} 0.5 0.5 0.5 1 # colour").unwrap();
        }
        let back = read_off(&dir.write("coloured.off", text)).unwrap();
        assert_same_surface(&back, &cube());
        assert_eq!(back.signed_volume(), 1.0);
    }

    #[test]
    fn bad_input_names_file_and_line() {
        let dir = TempDir::new("off-bad");
        let v = "0 0 0\n1 0 0\n0 1 0\n";
        let ok = |face: &str| format!("OFF\n3 1 0\n{v}{face}\n");
        let cases: Vec<(&str, String, &[&str])> = vec![
            (
                "header.off",
                ok("3 0 1 2").replace("OFF", "PLY"),
                &[":1:", "'PLY'"],
            ),
            (
                "prefix.off",
                ok("3 0 1 2").replace("OFF", "XOFF"),
                &[":1:", "'XOFF'"],
            ),
            (
                "4d.off",
                ok("3 0 1 2").replace("OFF", "4OFF"),
                &["'4OFF'", "not supported"],
            ),
            ("binary.off", "OFF BINARY\n".into(), &["binary OFF"]),
            ("counts.off", "OFF\nthree 1 0\n".into(), &[":2:", "'three'"]),
            ("nocounts.off", "OFF\n".into(), &["end of file", "counts"]),
            (
                "trunc.off",
                "OFF\n3 1 0\n0 0 0\n1 0 0\n".into(),
                &["end of file", "vertex 2 of 3"],
            ),
            (
                "noface.off",
                format!("OFF\n3 1 0\n{v}"),
                &["end of file", "face 0 of 1"],
            ),
            (
                "range.off",
                ok("3 0 1 3"),
                &[":6:", "face index 3 out of range (the file has 3 vertices)"],
            ),
            ("negative.off", ok("3 0 -1 2"), &[":6:", "face index -1"]),
            (
                "nan.off",
                "OFF\n3 1 0\n0 0 0\n1 NaN 0\n0 1 0\n3 0 1 2\n".into(),
                &[":4:", "'NaN'"],
            ),
            ("short.off", ok("3 0 1"), &[":6:", "end of line"]),
            ("two.off", ok("2 0 1"), &[":6:", "at least 3"]),
            ("garbage.off", ok("3 0 \u{1}x 2"), &[":6:", "vertex index"]),
            ("empty.off", "OFF\n0 0 0\n".into(), &["no triangles"]),
            ("void.off", String::new(), &["end of file", "'OFF' header"]),
        ];
        for (name, text, parts) in &cases {
            let path = dir.write(name, text);
            assert_err(read_off(&path), &path, parts);
        }
        let path = dir.write(
            "bytes.off",
            [b'O', b'F', b'F', b'\n', 0xff, 0xfe, 0x00, b'\n'],
        );
        assert_err(read_off(&path), &path, &[":2:"]);
    }
}
