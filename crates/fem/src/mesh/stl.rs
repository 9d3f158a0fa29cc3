//! STL, ASCII and binary: triangle soups welded into an indexed mesh.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::Point3;

use super::assemble::finish;
use super::error::MeshError;
use super::finite_points::is_finite_point;
use super::surface::TriSurface;
use super::text::{decode, quote, read_bytes, Lines, BOM};

/// Size of the binary header (80 bytes of text plus the triangle count).
const HEADER: usize = 84;
/// Size of one binary triangle record (normal, three corners, attribute word).
const RECORD: usize = 50;

/// Reads an ASCII or binary STL file and welds exactly equal corners into shared vertices, so the
/// result is an indexed mesh whose edges can be checked. The facet normals are ignored; the
/// corner order (counter-clockwise seen from outside) is kept. Lengths are in the file's units.
///
/// A file is binary when its size is exactly `84 + 50·n` for the triangle count `n` in its
/// header, even if it starts with `solid` as many exporters write; otherwise it is ASCII if it
/// starts with `solid` and contains no NUL byte.
pub fn read_stl(path: &Path) -> Result<TriSurface, MeshError> {
    parse(path, &read_bytes(path)?)
}

/// Parses the STL content `data` of `path`.
fn parse(path: &Path, data: &[u8]) -> Result<TriSurface, MeshError> {
    let declared = data
        .get(80..HEADER)
        .map(|b| u32::from_le_bytes(b.try_into().unwrap()) as u64);
    let expected = declared.map(|n| HEADER as u64 + RECORD as u64 * n);
    if expected == Some(data.len() as u64) {
        return parse_binary(path, data);
    }
    let text = data.strip_prefix(BOM).unwrap_or(data);
    let starts_solid = text.trim_ascii_start().starts_with(b"solid");
    if starts_solid && !data.contains(&0) {
        return parse_ascii(path, &decode(data));
    }
    Err(MeshError::malformed(
        path,
        match (declared, expected) {
            (Some(n), Some(size)) => format!(
                "not an ASCII STL, and as a binary STL its header declares {n} triangles \
                 ({size} bytes) but the file has {} bytes (truncated or not an STL file)",
                data.len()
            ),
            _ => format!(
                "not an STL file: only {} bytes and no 'solid' keyword",
                data.len()
            ),
        },
    ))
}

/// Merges corners with bit-identical coordinates (`-0.0` is treated as `0.0`).
#[derive(Default)]
struct Welder {
    index: HashMap<[u64; 3], usize>,
    vertices: Vec<Point3<f64>>,
}

impl Welder {
    fn vertex(&mut self, p: Point3<f64>) -> usize {
        let key = [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits());
        *self.index.entry(key).or_insert_with(|| {
            self.vertices.push(p);
            self.vertices.len() - 1
        })
    }
}

fn parse_binary(path: &Path, data: &[u8]) -> Result<TriSurface, MeshError> {
    let mut welder = Welder::default();
    let records = data[HEADER..].chunks_exact(RECORD);
    let mut triangles = Vec::with_capacity(records.len());
    for (t, record) in records.enumerate() {
        let mut tri = [0; 3];
        for (k, corner) in tri.iter_mut().enumerate() {
            let at = 12 * (k + 1);
            let c = |i: usize| {
                let b = &record[at + 4 * i..at + 4 * i + 4];
                f64::from(f32::from_le_bytes(b.try_into().unwrap()))
            };
            let p = Point3::new(c(0), c(1), c(2));
            if !is_finite_point(&p) {
                return Err(MeshError::malformed(
                    path,
                    format!(
                        "triangle {t} has a non-finite corner ({}, {}, {})",
                        p.x, p.y, p.z
                    ),
                ));
            }
            *corner = welder.vertex(p);
        }
        triangles.push(tri);
    }
    finish(path, welder.vertices, triangles)
}

fn parse_ascii(path: &Path, text: &str) -> Result<TriSurface, MeshError> {
    let mut welder = Welder::default();
    let mut triangles = Vec::new();
    // The open facet: its first line, and the corners read so far.
    let mut facet: Option<(usize, Vec<usize>)> = None;
    for line in Lines::new(path, text, None) {
        let mut tokens = line.tokens();
        match tokens.next().unwrap_or_default() {
            "solid" | "endsolid" | "outer" | "endloop" => {}
            "facet" => {
                if let Some((start, _)) = facet {
                    return Err(line.err(format!(
                        "'facet' before the 'endfacet' of the facet at line {start}"
                    )));
                }
                facet = Some((line.no, Vec::with_capacity(3)));
            }
            "vertex" => {
                let Some((_, corners)) = facet.as_mut() else {
                    return Err(line.err("'vertex' outside a facet"));
                };
                let p = tokens.point()?;
                tokens.end()?;
                corners.push(welder.vertex(p));
            }
            "endfacet" => {
                let Some((_, corners)) = facet.take() else {
                    return Err(line.err("'endfacet' without 'facet'"));
                };
                let tri: [usize; 3] = corners.try_into().map_err(|c: Vec<_>| {
                    line.err(format!("facet has {} vertices, expected 3", c.len()))
                })?;
                triangles.push(tri);
            }
            other => return Err(line.err(format!("unexpected keyword {}", quote(other)))),
        }
    }
    if let Some((start, _)) = facet {
        return Err(MeshError::malformed(
            path,
            format!("file ends inside the facet that starts at line {start} (truncated file?)"),
        ));
    }
    finish(path, welder.vertices, triangles)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::fixtures::{
        assert_err, assert_robust, assert_same_surface, cube, octahedron, reference_meshes, TempDir,
    };
    use crate::mesh::validate::validate;
    use std::fmt::Write as _;

    fn ascii(s: &TriSurface) -> String {
        let mut out = String::from("solid test\n");
        for t in 0..s.triangles.len() {
            let n = s.scaled_normal(t).normalize();
            writeln!(
                out,
                "  facet normal {} {} {}\n    outer loop",
                n.x, n.y, n.z
            )
            .unwrap();
            for p in s.corners(t) {
                writeln!(out, "      vertex {} {} {}", p.x, p.y, p.z).unwrap();
            }
            out.push_str("    endloop\n  endfacet\n");
        }
        out + "endsolid test\n"
    }

    fn binary(s: &TriSurface, header: &[u8]) -> Vec<u8> {
        let mut out = header.to_vec();
        out.resize(80, b' ');
        out.extend((s.triangles.len() as u32).to_le_bytes());
        for t in 0..s.triangles.len() {
            let n = s.scaled_normal(t).normalize();
            let mut floats = vec![n.x, n.y, n.z];
            floats.extend(s.corners(t).iter().flat_map(|p| [p.x, p.y, p.z]));
            for f in floats {
                out.extend((f as f32).to_le_bytes());
            }
            out.extend([0, 0]);
        }
        out
    }

    #[test]
    fn round_trip_ascii_and_binary() {
        let dir = TempDir::new("stl-rt");
        for (name, mesh) in reference_meshes() {
            for (kind, data) in [
                ("ascii", ascii(&mesh).into_bytes()),
                (
                    "bom-ascii",
                    format!("\u{feff}{}", ascii(&mesh)).into_bytes(),
                ),
                ("binary", binary(&mesh, b"binary")),
                (
                    "solid-binary",
                    binary(&mesh, b"solid exported by a binary writer"),
                ),
            ] {
                let path = dir.write(&format!("{name}-{kind}.stl"), data);
                let back = read_stl(&path).unwrap();
                assert_same_surface(&back, &mesh);
                let report = validate(&back);
                assert!(report.watertight, "{name} {kind}: {report}");
            }
        }
        let back = read_stl(&dir.path("cube-solid-binary.stl")).unwrap();
        assert_eq!(back.signed_volume(), 1.0);
        assert_eq!(back.vertices.len(), 8);
    }

    #[test]
    fn corrupted_files_never_panic() {
        assert_robust("stl", ascii(&octahedron()).as_bytes(), parse);
        assert_robust("stl", &binary(&octahedron(), b"solid x"), parse);
    }

    #[test]
    fn welding_treats_negative_zero_as_zero() {
        let dir = TempDir::new("stl-weld");
        let mut mesh = cube();
        mesh.vertices.push(Point3::new(-0.0, 0.0, -0.0));
        mesh.triangles[0][0] = 8;
        let back = read_stl(&dir.write("negzero.stl", ascii(&mesh))).unwrap();
        assert_eq!(back.vertices.len(), 8);
        assert!(validate(&back).watertight);
    }

    #[test]
    fn bad_input_names_file_and_line() {
        let dir = TempDir::new("stl-bad");
        let good = ascii(&cube());
        let lines: Vec<&str> = good.lines().collect();
        let truncated_ascii = lines[..6].join("\n");
        let nan = good.replacen("vertex 0 0 0", "vertex 0 nan 0", 1);
        let bad_kw = good.replacen("outer loop", "outer lop\nbogus", 1);
        let four = good.replacen("endloop", "vertex 1 1 1\nendloop", 1);
        let cases: Vec<(&str, Vec<u8>, &[&str])> = vec![
            (
                "trunc-ascii.stl",
                truncated_ascii.into(),
                &["facet that starts at line 2"],
            ),
            ("nan-ascii.stl", nan.into(), &[":4:", "'nan'"]),
            ("keyword.stl", bad_kw.into(), &[":4:", "'bogus'"]),
            ("four.stl", four.into(), &[":9:", "4 vertices"]),
            ("garbage.stl", b"\x01\x02garbage".to_vec(), &["not an STL"]),
            ("empty.stl", vec![], &["not an STL"]),
            (
                "solid-empty.stl",
                b"solid x\nendsolid x\n".to_vec(),
                &["no triangles"],
            ),
        ];
        for (name, data, parts) in &cases {
            let path = dir.write(name, data);
            assert_err(read_stl(&path), &path, parts);
        }
        // Binary: truncated (also when the header says "solid"), huge count, NaN corner.
        let full = binary(&cube(), b"solid but binary");
        for (name, data, parts) in [
            (
                "trunc-bin.stl",
                full[..full.len() - 7].to_vec(),
                &["12 triangles", "684 bytes", "677"][..],
            ),
            (
                "huge.stl",
                [&full[..80], &u32::MAX.to_le_bytes()[..], &full[84..]].concat(),
                &["4294967295"],
            ),
        ] {
            let path = dir.write(name, data);
            assert_err(read_stl(&path), &path, parts);
        }
        let mut nan = binary(&cube(), b"bin");
        nan[84 + 50 * 3 + 16..84 + 50 * 3 + 20].copy_from_slice(&f32::NAN.to_le_bytes());
        let path = dir.write("nan-bin.stl", nan);
        assert_err(read_stl(&path), &path, &["triangle 3", "NaN"]);
    }
}
