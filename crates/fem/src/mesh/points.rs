//! Point clouds (e.g. intra-operative surface samples): reading text or PLY, writing text.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use nalgebra::Point3;

use super::error::MeshError;
use super::extension;
use super::ply::read_ply_vertices;
use super::text::{decode, quote, read_bytes, Lines};

/// The point file formats [`read_points`] understands, by extension.
pub const POINT_EXTENSIONS: [&str; 6] = ["xyz", "txt", "csv", "ply", "vtk", "vtp"];

/// Reads a point cloud, dispatching on the extension (case-insensitive):
/// - `.xyz`, `.txt`, `.csv`: one point per line, three numbers separated by spaces, tabs or
///   commas (mixed allowed); blank lines and `#` comments are skipped; any other line is an
///   error naming the file, the line and its text;
/// - `.ply`: the x, y, z of the `vertex` element (faces, if any, are ignored);
/// - `.vtk`, `.vtp`: every point of the VTK data set (cells ignored).
///
/// Coordinates must be finite and are in the file's units. An empty cloud is an error.
pub fn read_points(path: &Path) -> Result<Vec<Point3<f64>>, MeshError> {
    let points = match extension(path).as_deref() {
        Some("xyz" | "txt" | "csv") => parse_text(path, &decode(&read_bytes(path)?))?,
        Some("ply") => read_ply_vertices(path)?,
        Some("vtk" | "vtp") => super::vtk::read_vtk_points(path)?,
        other => {
            return Err(MeshError::unsupported(
                path,
                format!(
                    "unknown point file extension {} (supported: {})",
                    quote(other.unwrap_or_default()),
                    POINT_EXTENSIONS.join(", ")
                ),
            ))
        }
    };
    if points.is_empty() {
        return Err(MeshError::empty(path, "points"));
    }
    Ok(points)
}

/// Whether `c` separates numbers in a point text file.
fn is_separator(c: char) -> bool {
    c.is_whitespace() || c == ','
}

fn parse_text(path: &Path, text: &str) -> Result<Vec<Point3<f64>>, MeshError> {
    Lines::new(path, text, Some('#'))
        .map(|line| {
            let found = line.tokens_split_by(is_separator).count();
            if found != 3 {
                return Err(line.err(format!(
                    "expected 3 numbers (x y z), found {found}: {}",
                    quote(line.text)
                )));
            }
            line.tokens_split_by(is_separator).point()
        })
        .collect()
}

/// Writes `points` as text, one `x y z` line per point, with Rust's shortest round-trip
/// formatting (reading the file back gives exactly the same values).
pub fn write_points(path: &Path, points: &[Point3<f64>]) -> Result<(), MeshError> {
    let io = |e| MeshError::io(path, e);
    let mut out = BufWriter::new(File::create(path).map_err(io)?);
    for p in points {
        writeln!(out, "{} {} {}", p.x, p.y, p.z).map_err(io)?;
    }
    out.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::fixtures::{assert_err, assert_robust, TempDir};

    #[test]
    fn text_round_trip_is_exact() {
        let dir = TempDir::new("pts-rt");
        let points = vec![
            Point3::new(0.1, -1.0 / 3.0, 2.5e-300),
            Point3::new(1e300, -0.0, 123456.789),
            Point3::new(f64::MIN_POSITIVE, f64::MAX, -f64::EPSILON),
        ];
        for name in ["a.xyz", "b.TXT", "c.csv"] {
            let path = dir.path(name);
            write_points(&path, &points).unwrap();
            let back = read_points(&path).unwrap();
            assert_eq!(back.len(), points.len());
            for (a, b) in points.iter().zip(&back) {
                assert!(a
                    .iter()
                    .zip(b.iter())
                    .all(|(x, y)| x.to_bits() == y.to_bits()));
            }
        }
    }

    #[test]
    fn corrupted_files_never_panic() {
        let data = "# points\n1.5 -2 3e-3\n4,5,6\n\n7\t8\t9\n0.1 0.2 0.3\n";
        assert_robust("xyz", data.as_bytes(), |p, d| parse_text(p, &decode(d)));
    }

    #[test]
    fn mixed_separators_comments_and_blank_lines() {
        let dir = TempDir::new("pts-mixed");
        let path = dir.write(
            "mixed.csv",
            "# x,y,z\n\n1,2,3\n4 5\t6\r\n  7 ,\t8,9  # trailing\n\t\n",
        );
        let pts = read_points(&path).unwrap();
        assert_eq!(
            pts,
            vec![
                Point3::new(1.0, 2.0, 3.0),
                Point3::new(4.0, 5.0, 6.0),
                Point3::new(7.0, 8.0, 9.0)
            ]
        );
    }

    #[test]
    fn ply_point_cloud_with_and_without_faces() {
        let dir = TempDir::new("pts-ply");
        let cloud = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                     property float z\nproperty uchar red\nend_header\n1 2 3 255\n4 5 6 0\n";
        let path = dir.write("cloud.ply", cloud);
        let pts = read_points(&path).unwrap();
        assert_eq!(
            pts,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]
        );
        let with_faces = cloud.replace(
            "end_header",
            "element face 1\nproperty list uchar int vertex_indices\nend_header",
        ) + "3 0 1 7\n";
        // The face refers to a missing vertex, but faces are ignored for point clouds.
        let path = dir.write("faces.PLY", with_faces);
        assert_eq!(read_points(&path).unwrap().len(), 2);
    }

    #[test]
    fn bad_input_names_file_line_and_text() {
        let dir = TempDir::new("pts-bad");
        let cases: &[(&str, &str, &[&str])] = &[
            ("two.xyz", "1 2 3\n4 5\n", &[":2:", "found 2: '4 5'"]),
            ("four.xyz", "1 2 3 4\n", &[":1:", "found 4: '1 2 3 4'"]),
            ("word.csv", "x,y,z\n", &[":1:", "'x'"]),
            ("nan.txt", "1 2 3\n\n1 nan 3\n", &[":3:", "'nan'", "finite"]),
            ("inf.txt", "1 2 -inf\n", &[":1:", "'-inf'"]),
            ("empty.xyz", "# nothing\n\n", &["no points"]),
            (
                "cloud.ply",
                "ply\nformat ascii 1.0\nend_header\n",
                &["no points"],
            ),
            ("points.las", "", &["'las'", "xyz, txt, csv, ply"]),
        ];
        for (name, text, parts) in cases {
            let path = dir.write(name, text);
            assert_err(read_points(&path), &path, parts);
        }
        let path = dir.write("garbage.xyz", [0xff, 0x00, 0x12, b'\n', 0x80]);
        assert_err(read_points(&path), &path, &[":1:"]);
        let missing = dir.path("missing.xyz");
        assert_err(read_points(&missing), &missing, &[]);
        let unwritable = dir.path("no/such/dir/out.xyz");
        assert_err(
            write_points(&unwritable, &[Point3::origin()]),
            &unwritable,
            &[],
        );
    }
}
