//! Gmsh mesh files, format version 2.x ASCII (`.msh`): the surface triangles of a mesh.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::Point3;

use super::assemble::{bounded_capacity, finish};
use super::error::MeshError;
use super::surface::TriSurface;
use super::text::{decode, quote, read_bytes, Line, Lines};

/// Gmsh element type of the 3-node triangle.
const TRIANGLE: usize = 2;
/// Gmsh element type of the 4-node quadrangle (split into two triangles).
const QUADRANGLE: usize = 3;

/// Reads a Gmsh 2.x ASCII mesh: all nodes of `$Nodes` (tags may be non-contiguous; the vertices
/// are in file order) and the triangles (type 2) and quadrangles (type 3, split into two
/// triangles) of `$Elements`, in their node order; every other element type and section is
/// skipped. Nodes used only by skipped elements (e.g. tetrahedra) are kept as unreferenced
/// vertices. Lengths are in the file's units.
pub fn read_msh(path: &Path) -> Result<TriSurface, MeshError> {
    let bytes = read_bytes(path)?;
    parse(path, &decode(&bytes))
}

/// Gmsh numbers, like other counts, are non-negative integers.
type Tags = HashMap<usize, usize>;

fn parse(path: &Path, text: &str) -> Result<TriSurface, MeshError> {
    let mut lines = Lines::new(path, text, None);
    let mut has_format = false;
    let mut vertices = Vec::new();
    let mut tags = Tags::new();
    let mut triangles = Vec::new();
    while let Some(line) = lines.next() {
        let Some(section) = line.text.strip_prefix('$') else {
            return Err(line.err(format!(
                "expected a section such as '$Nodes', found {}",
                quote(line.text)
            )));
        };
        if !has_format && section != "MeshFormat" {
            return Err(if section == "NOD" {
                MeshError::unsupported(
                    path,
                    "Gmsh 1.0 files are not supported; export as version 2.2 ASCII",
                )
            } else {
                line.err("the file does not start with '$MeshFormat' (not a Gmsh file?)")
            });
        }
        match section {
            "MeshFormat" => {
                read_format(path, &mut lines)?;
                has_format = true;
            }
            "Nodes" => read_nodes(&mut lines, text.len(), &mut vertices, &mut tags)?,
            "Elements" => read_elements(&mut lines, &tags, &mut triangles)?,
            other => {
                while lines.expect(&format!("'$End{other}'"))?.text != format!("$End{other}") {}
            }
        }
    }
    if !has_format {
        return Err(MeshError::malformed(
            path,
            "no '$MeshFormat' section (empty or not a Gmsh file)",
        ));
    }
    finish(path, vertices, triangles)
}

/// Checks the `$MeshFormat` section: version 2.x, ASCII.
fn read_format(path: &Path, lines: &mut Lines<'_>) -> Result<(), MeshError> {
    let line = lines.expect("the mesh format line")?;
    let mut t = line.tokens();
    let version = t.expect("the format version")?;
    if !version
        .parse::<f64>()
        .is_ok_and(|v| (2.0..3.0).contains(&v))
    {
        return Err(MeshError::unsupported(
            path,
            format!(
                "Gmsh format version {} is not supported; export as version 2.2 ASCII \
                 (gmsh -format msh22)",
                quote(version)
            ),
        ));
    }
    if t.int("the file type")? != 0 {
        return Err(MeshError::unsupported(
            path,
            "binary Gmsh files are not supported; export as ASCII (file type 0)",
        ));
    }
    t.uint("the data size")?;
    t.end()?;
    end_section(lines, "MeshFormat")
}

/// Reads `$Nodes`: a count, then `tag x y z` lines.
fn read_nodes(
    lines: &mut Lines<'_>,
    text_len: usize,
    vertices: &mut Vec<Point3<f64>>,
    tags: &mut Tags,
) -> Result<(), MeshError> {
    let count = section_count(lines, "nodes")?;
    // A node line takes at least 8 bytes ("1 0 0 0\n").
    vertices.reserve(bounded_capacity(count, text_len, 8));
    for i in 0..count {
        let line = data_line(lines, "nodes", i, count)?;
        let mut t = line.tokens();
        let tag = t.uint("a node tag")?;
        let p = t.point()?;
        t.end()?;
        if tags.insert(tag, vertices.len()).is_some() {
            return Err(line.err(format!("node tag {tag} is defined twice")));
        }
        vertices.push(p);
    }
    end_section(lines, "Nodes")
}

/// Reads `$Elements`: a count, then `number type tag-count tags... nodes...` lines; keeps
/// triangles and quadrangles.
fn read_elements(
    lines: &mut Lines<'_>,
    tags: &Tags,
    triangles: &mut Vec<[usize; 3]>,
) -> Result<(), MeshError> {
    let count = section_count(lines, "elements")?;
    for i in 0..count {
        let line = data_line(lines, "elements", i, count)?;
        let mut t = line.tokens();
        t.uint("an element number")?;
        let kind = t.uint("an element type")?;
        let tag_count = t.uint("the number of tags")?;
        let corners = match kind {
            TRIANGLE => 3,
            QUADRANGLE => 4,
            _ => continue,
        };
        for _ in 0..tag_count {
            t.int("an element tag")?;
        }
        let mut v = [0; 4];
        for slot in &mut v[..corners] {
            let tag = t.uint("a node tag")?;
            *slot = *tags
                .get(&tag)
                .ok_or_else(|| line.err(format!("node {tag} is not defined in '$Nodes'")))?;
        }
        t.end()?;
        triangles.push([v[0], v[1], v[2]]);
        if corners == 4 {
            triangles.push([v[0], v[2], v[3]]);
        }
    }
    end_section(lines, "Elements")
}

/// The count line at the start of a `$Nodes` or `$Elements` section.
fn section_count(lines: &mut Lines<'_>, what: &str) -> Result<usize, MeshError> {
    let line = lines.expect(&format!("the number of {what}"))?;
    let mut t = line.tokens();
    let count = t.uint(&format!("the number of {what}"))?;
    t.end()?;
    Ok(count)
}

/// Data line `i` of the `count` announced, which must not be a section marker.
fn data_line<'a>(
    lines: &mut Lines<'a>,
    what: &str,
    i: usize,
    count: usize,
) -> Result<Line<'a>, MeshError> {
    let line = lines.expect(&format!("line {} of the {count} {what}", i + 1))?;
    if line.text.starts_with('$') {
        return Err(line.err(format!(
            "the section ends after {i} of the {count} {what} it announces"
        )));
    }
    Ok(line)
}

fn end_section(lines: &mut Lines<'_>, name: &str) -> Result<(), MeshError> {
    let end = format!("$End{name}");
    let line = lines.expect(&quote(&end))?;
    if line.text == end {
        Ok(())
    } else {
        Err(line.err(format!("expected '{end}', found {}", quote(line.text))))
    }
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

    /// Node tag of vertex `i`: non-contiguous, not sorted.
    fn tag(i: usize) -> usize {
        1000 - 7 * i
    }

    /// Writes `s` as Gmsh 2.2 ASCII with non-contiguous node tags, extra sections, an extra
    /// unreferenced node, and point, line and tetrahedron elements mixed with the triangles.
    fn write_msh(s: &TriSurface) -> String {
        let mut out = String::from(
            "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$PhysicalNames\n1\n2 1 \"liver\"\n$EndPhysicalNames\n",
        );
        writeln!(out, "$Nodes\n{}", s.vertices.len() + 1).unwrap();
        for (i, p) in s.vertices.iter().enumerate() {
            writeln!(out, "{} {} {} {}", tag(i), p.x, p.y, p.z).unwrap();
        }
        out.push_str("5 0.5 0.5 0.5\n$EndNodes\n");
        writeln!(out, "$Elements\n{}", s.triangles.len() + 3).unwrap();
        writeln!(out, "1 15 2 0 1 {}", tag(0)).unwrap();
        writeln!(out, "2 1 2 0 1 {} {}", tag(0), tag(1)).unwrap();
        for (e, t) in s.triangles.iter().enumerate() {
            // Alternate the number of tags (2, 0, 3).
            let tags = ["2 1 5", "0", "3 1 5 9"][e % 3];
            writeln!(
                out,
                "{} 2 {tags} {} {} {}",
                e + 3,
                tag(t[0]),
                tag(t[1]),
                tag(t[2])
            )
            .unwrap();
        }
        writeln!(out, "99 4 2 0 1 {} {} {} 5", tag(0), tag(1), tag(2)).unwrap();
        out + "$EndElements\n$Comments\nanything $Nodes\n$EndComments\n"
    }

    #[test]
    fn round_trip_with_sparse_tags_and_mixed_elements() {
        let dir = TempDir::new("msh-rt");
        for (name, mesh) in reference_meshes() {
            let path = dir.write(&format!("{name}.msh"), write_msh(&mesh));
            let mut back = read_msh(&path).unwrap();
            let report = validate(&back);
            assert_eq!(report.unreferenced_vertices, 1, "the extra node is kept");
            assert_eq!(back.vertices.pop(), Some(Point3::new(0.5, 0.5, 0.5)));
            assert_eq!(back, mesh, "{name}");
            assert!(validate(&back).watertight);
        }
        assert_eq!(
            read_msh(&dir.path("cube.msh")).unwrap().signed_volume(),
            1.0
        );
    }

    #[test]
    fn corrupted_files_never_panic() {
        let data = write_msh(&octahedron());
        assert_robust("msh", data.as_bytes(), |p, d| parse(p, &decode(d)));
    }

    #[test]
    fn quadrangles_are_split() {
        let dir = TempDir::new("msh-quads");
        let mut text = String::from("$MeshFormat\n2.1 0 8\n$EndMeshFormat\n$Nodes\n8\n");
        for (i, p) in cube().vertices.iter().enumerate() {
            writeln!(text, "{} {} {} {}", i + 1, p.x, p.y, p.z).unwrap();
        }
        text.push_str("$EndNodes\n$Elements\n6\n");
        for (e, q) in CUBE_QUADS.iter().enumerate() {
            let [a, b, c, d] = q.map(|i| i + 1);
            writeln!(text, "{} 3 2 0 {e} {a} {b} {c} {d}", e + 1).unwrap();
        }
        text.push_str("$EndElements\n");
        let back = read_msh(&dir.write("quads.msh", text)).unwrap();
        assert_same_surface(&back, &cube());
        assert_eq!(back.signed_volume(), 1.0);
    }

    #[test]
    fn bad_input_names_file_and_line() {
        let dir = TempDir::new("msh-bad");
        let head = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n";
        let nodes = "$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n$EndNodes\n";
        let elems = |e: &str| format!("{head}{nodes}$Elements\n1\n{e}\n$EndElements\n");
        // Lines: 1-3 format, 4-9 nodes (node lines 6-8), 10-11 elements header, 12 the element.
        let cases: Vec<(&str, String, &[&str])> = vec![
            (
                "v4.msh",
                "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n".into(),
                &["'4.1'", "2.2"],
            ),
            (
                "binary.msh",
                "$MeshFormat\n2.2 1 8\n$EndMeshFormat\n".into(),
                &["binary", "ASCII"],
            ),
            ("v1.msh", "$NOD\n3\n".into(), &["Gmsh 1.0"]),
            ("noformat.msh", nodes.into(), &[":1:", "$MeshFormat"]),
            ("text.msh", "hello\n".into(), &[":1:", "'hello'"]),
            ("void.msh", String::new(), &["no '$MeshFormat'"]),
            (
                "unterminated.msh",
                "$MeshFormat\n2.2 0 8\n".into(),
                &["end of file", "$EndMeshFormat"],
            ),
            (
                "range.msh",
                elems("1 2 2 0 1 1 2 4"),
                &[":12:", "node 4 is not defined"],
            ),
            ("negative.msh", elems("1 2 2 0 1 1 -2 3"), &[":12:", "'-2'"]),
            (
                "short.msh",
                elems("1 2 2 0 1 1 2"),
                &[":12:", "end of line"],
            ),
            (
                "long.msh",
                elems("1 2 2 0 1 1 2 3 4"),
                &[":12:", "extra value '4'"],
            ),
            (
                "notags.msh",
                elems("1 2 3 0 1 1 2 3"),
                &[":12:", "end of line"],
            ),
            (
                "nan.msh",
                format!("{head}$Nodes\n1\n1 0 nan 0\n$EndNodes\n"),
                &[":6:", "'nan'"],
            ),
            (
                "dup.msh",
                format!("{head}$Nodes\n2\n1 0 0 0\n1 1 0 0\n$EndNodes\n"),
                &[":7:", "node tag 1 is defined twice"],
            ),
            (
                "fewer.msh",
                format!("{head}$Nodes\n3\n1 0 0 0\n$EndNodes\n"),
                &[":7:", "after 1 of the 3 nodes"],
            ),
            (
                "huge.msh",
                format!("{head}$Nodes\n18446744073709551615\n1 0 0 0\n"),
                &["end of file", "line 2 of the 18446744073709551615 nodes"],
            ),
            (
                "trunc.msh",
                format!("{head}$Nodes\n3\n1 0 0 0\n2 1"),
                &[":7:", "y coordinate"],
            ),
            (
                "count.msh",
                format!("{head}$Nodes\nmany\n"),
                &[":5:", "'many'"],
            ),
            (
                "noend.msh",
                format!("{head}{nodes}$Elements\n0\n$EndNodes\n"),
                &[":12:", "expected '$EndElements'"],
            ),
            ("empty.msh", elems("1 15 2 0 1 1"), &["no triangles"]),
        ];
        for (name, text, parts) in &cases {
            let path = dir.write(name, text);
            assert_err(read_msh(&path), &path, parts);
        }
        let path = dir.write("bytes.msh", [b'$', 0xff, 0x00, b'\n', 0x80]);
        assert_err(read_msh(&path), &path, &[":1:"]);
    }
}
