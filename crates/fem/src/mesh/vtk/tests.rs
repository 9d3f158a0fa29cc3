//! Tests of the VTK reader and writer: round trips, hand-written files in both formats, and
//! bad input.

use nalgebra::Point3;

use super::super::fixtures::{assert_err, assert_robust, cube, TempDir};
use super::read::parse_vtk;
use super::*;

fn write_cube(dir: &TempDir, name: &str) -> std::path::PathBuf {
    let c = cube();
    let path = dir.path(name);
    write_vtk(
        &path,
        &VtkPolyData {
            points: &c.vertices,
            triangles: &c.triangles,
            arrays: &[],
        },
    )
    .unwrap();
    path
}

#[test]
fn both_formats_round_trip_exactly() {
    let dir = TempDir::new("vtk-roundtrip");
    let mut c = cube();
    // Coordinates that 32-bit floats would not keep.
    c.vertices[3].x = 0.1;
    c.vertices[5].z = 1.0 / 3.0;
    for name in ["cube.vtp", "cube.vtk", "CUBE.VTP"] {
        let path = dir.path(name);
        let arrays = [PointArray {
            name: "index".into(),
            components: 1,
            values: (0..8).map(f64::from).collect(),
        }];
        write_vtk(
            &path,
            &VtkPolyData {
                points: &c.vertices,
                triangles: &c.triangles,
                arrays: &arrays,
            },
        )
        .unwrap();
        let back = read_vtk(&path).unwrap();
        assert_eq!(back, c, "{name}");
        assert_eq!(read_vtk_points(&path).unwrap(), c.vertices, "{name}");
        assert!(!dir.path(&format!("{name}.partial")).exists());
    }
}

#[test]
fn a_point_set_is_written_as_vertices_and_read_back_as_points() {
    let dir = TempDir::new("vtk-points");
    let pts = vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-4.5, 0.25, 7.0)];
    for name in ["targets.vtp", "targets.vtk"] {
        let path = dir.path(name);
        let data = VtkPolyData {
            points: &pts,
            triangles: &[],
            arrays: &[],
        };
        write_vtk(&path, &data).unwrap();
        assert_eq!(read_vtk_points(&path).unwrap(), pts);
        assert_err(read_vtk(&path), &path, &["no triangles"]);
    }
}

#[test]
fn legacy_ascii_polygons_strips_and_ras_space() {
    let dir = TempDir::new("vtk-legacy");
    // A unit square as one quad, and the same square as a strip 0 1 3 2 (two triangles).
    let body = "ASCII\nDATASET POLYDATA\nPOINTS 4 float\n0 0 0 1 0 0 1 1 0 0 1 0\n";
    let quad = dir.write(
        "quad.vtk",
        format!("# vtk DataFile Version 4.2\nquad SPACE=LPS\n{body}POLYGONS 1 5\n4 0 1 2 3\n"),
    );
    let s = read_vtk(&quad).unwrap();
    assert_eq!(s.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    let strip = dir.write(
        "strip.vtk",
        format!("# vtk DataFile Version 3.0\nstrip\n{body}TRIANGLE_STRIPS 1 5\n4 0 1 3 2\n"),
    );
    let s = read_vtk(&strip).unwrap();
    // Both triangles of the strip face +z, as the quad's do.
    assert_eq!(s.triangles, vec![[0, 1, 3], [3, 1, 2]]);
    for t in 0..2 {
        assert!(s.scaled_normal(t).z > 0.0);
    }
    let ras = dir.write(
        "ras.vtk",
        format!("# vtk DataFile Version 4.2\nmodel SPACE=RAS\n{body}POLYGONS 1 5\n4 0 1 2 3\n"),
    );
    let s = read_vtk(&ras).unwrap();
    assert_eq!(s.vertices[2], Point3::new(-1.0, -1.0, 0.0));
}

#[test]
fn unstructured_grid_surface_cells_are_read_and_volume_cells_refused() {
    let dir = TempDir::new("vtk-grid");
    let head = "# vtk DataFile Version 4.2\ngrid\nASCII\nDATASET UNSTRUCTURED_GRID\n\
                POINTS 4 double\n0 0 0 1 0 0 0 1 0 0 0 1\n";
    let tris = dir.write(
        "tris.vtk",
        format!("{head}CELLS 2 8\n3 0 2 1\n3 0 1 3\nCELL_TYPES 2\n5\n5\n"),
    );
    assert_eq!(
        read_vtk(&tris).unwrap().triangles,
        vec![[0, 2, 1], [0, 1, 3]]
    );
    let tet = dir.write(
        "tet.vtk",
        format!("{head}CELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10\n"),
    );
    assert_err(read_vtk(&tet), &tet, &["cell 0", "Tetra", "boundary"]);
}

#[test]
fn xml_with_offsets_and_ascii_arrays_is_read() {
    let dir = TempDir::new("vtk-xml");
    let path = dir.write(
        "tet.vtp",
        r#"<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian">
<PolyData><Piece NumberOfPoints="4" NumberOfVerts="0" NumberOfLines="0" NumberOfStrips="0" NumberOfPolys="4">
<Points><DataArray type="Float32" NumberOfComponents="3" format="ascii">0 0 0 1 0 0 0 1 0 0 0 1</DataArray></Points>
<Polys>
<DataArray type="Int32" Name="connectivity" format="ascii">0 2 1 0 1 3 0 3 2 1 2 3</DataArray>
<DataArray type="Int32" Name="offsets" format="ascii">3 6 9 12</DataArray>
</Polys>
</Piece></PolyData></VTKFile>
"#,
    );
    let s = read_vtk(&path).unwrap();
    assert_eq!(s.triangles.len(), 4);
    assert!((s.signed_volume() - 1.0 / 6.0).abs() < 1e-12);
}

#[test]
fn bad_files_are_named_errors() {
    let dir = TempDir::new("vtk-bad");
    let body = "# vtk DataFile Version 4.2\nbad\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n\
                0 0 0 1 0 0 0 1 0\n";
    let out_of_range = dir.write("range.vtk", format!("{body}POLYGONS 1 4\n3 0 1 7\n"));
    assert_err(
        read_vtk(&out_of_range),
        &out_of_range,
        &["cell 0", "point 7", "3 points"],
    );
    let nan = dir.write(
        "nan.vtk",
        "# vtk DataFile Version 4.2\nbad\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n\
         0 0 0 nan 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 2\n",
    );
    assert!(read_vtk(&nan).is_err());
    let garbage = dir.write("garbage.vtp", "<VTKFile type=\"PolyData\"");
    assert_err(read_vtk(&garbage), &garbage, &["XML error"]);
    let image = dir.write(
        "image.vtk",
        "# vtk DataFile Version 4.2\nimg\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 2 1 1\n\
         ORIGIN 0 0 0\nSPACING 1 1 1\nPOINT_DATA 2\nSCALARS s float 1\nLOOKUP_TABLE default\n0 1\n",
    );
    assert_err(read_vtk(&image), &image, &["no polygons"]);
    let missing = dir.path("missing.vtp");
    assert_err(read_vtk(&missing), &missing, &[]);
}

/// A file that ends inside an element nested in a `<DataArray>` (VTK's `<InformationKey>`
/// notes) is a named error, not an endless read: the reader runs on a thread and must answer
/// within 10 s.
#[test]
fn a_file_cut_inside_a_nested_element_is_an_error_not_a_hang() {
    let dir = TempDir::new("vtk-cut");
    let path = dir.write(
        "cut.vtp",
        r#"<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian">
<PolyData><Piece NumberOfPoints="4" NumberOfPolys="1">
<Points><DataArray type="Float32" NumberOfComponents="3" format="ascii"><InformationKey name="L2_NORM_RANGE">"#,
    );
    let (tx, rx) = std::sync::mpsc::channel();
    let reading = path.clone();
    std::thread::spawn(move || {
        let _ = tx.send(read_vtk(&reading).map(|s| s.triangles.len()));
    });
    let read = rx
        .recv_timeout(std::time::Duration::from_secs(10))
        .expect("the reader answers instead of reading forever");
    assert_err(read, &path, &[]);
}

#[test]
fn corrupted_files_never_panic() {
    let dir = TempDir::new("vtk-fuzz");
    for name in ["c.vtk", "c.vtp"] {
        let good = std::fs::read(write_cube(&dir, name)).unwrap();
        let ext = name.rsplit('.').next().unwrap();
        assert_robust(ext, &good, parse_vtk);
    }
}

#[test]
fn writer_refuses_bad_data() {
    let dir = TempDir::new("vtk-write-bad");
    let c = cube();
    let path = dir.path("bad.vtp");
    let bad_tri = [[0, 1, 8]];
    let e = write_vtk(
        &path,
        &VtkPolyData {
            points: &c.vertices,
            triangles: &bad_tri,
            arrays: &[],
        },
    );
    assert_err(e, &path, &["triangle 0"]);
    let short = [PointArray {
        name: "e".into(),
        components: 1,
        values: vec![0.0; 3],
    }];
    let e = write_vtk(
        &path,
        &VtkPolyData {
            points: &c.vertices,
            triangles: &c.triangles,
            arrays: &short,
        },
    );
    assert_err(e, &path, &["\"e\"", "3 values for 8 points"]);
    let obj = dir.path("bad.obj");
    assert_err(
        write_vtk(
            &obj,
            &VtkPolyData {
                points: &c.vertices,
                triangles: &c.triangles,
                arrays: &[],
            },
        ),
        &obj,
        &["use .vtp or .vtk"],
    );
    assert!(!path.exists());
}

#[test]
fn pvd_lists_every_step_and_escapes_names() {
    let dir = TempDir::new("vtk-pvd");
    let mut series = PvdSeries::new(dir.path("liver.pvd"));
    series.push(0.0, "liver_000000.vtp").unwrap();
    series.push(1.0, "a&b\"<.vtp").unwrap();
    let text = std::fs::read_to_string(dir.path("liver.pvd")).unwrap();
    assert!(
        text.contains(r#"timestep="0" group="" part="0" file="liver_000000.vtp""#),
        "{text}"
    );
    assert!(text.contains(r#"file="a&amp;b&quot;&lt;.vtp""#), "{text}");
    assert_eq!(text.matches("<DataSet ").count(), 2);
    assert_eq!(series.steps().len(), 2);
}

/// A `.vtp` whose points array is appended raw data with `header` (little-endian words of
/// `word` bytes) before `data`.
fn appended_vtp(
    header_type: &str,
    compressor: &str,
    header: &[u64],
    word: usize,
    data: &[u8],
) -> Vec<u8> {
    let mut out = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"1.0\" \
         byte_order=\"LittleEndian\" header_type=\"{header_type}\"{compressor}>\n<PolyData>\
         <Piece NumberOfPoints=\"3\" NumberOfPolys=\"1\"><Points><DataArray type=\"Float64\" \
         NumberOfComponents=\"3\" format=\"appended\" offset=\"0\"/></Points><Polys>\
         <DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">0 1 2</DataArray>\
         <DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">3</DataArray></Polys>\
         </Piece></PolyData>\n<AppendedData encoding=\"raw\">\n_"
    )
    .into_bytes();
    for h in header {
        out.extend_from_slice(&h.to_le_bytes()[..word]);
    }
    out.extend_from_slice(data);
    out.extend_from_slice(b"\n</AppendedData>\n</VTKFile>\n");
    out
}

#[test]
fn appended_raw_and_zlib_data_are_read_and_false_sizes_refused() {
    let dir = TempDir::new("vtk-appended");
    let coords: Vec<u8> = [0.0f64, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let plain = dir.write("plain.vtp", appended_vtp("UInt64", "", &[72], 8, &coords));
    let s = read_vtk(&plain).unwrap();
    assert_eq!(s.vertices[1], Point3::new(1.0, 0.0, 0.0));
    assert_eq!(s.triangles, vec![[0, 1, 2]]);
    // zlib in two blocks of 64 and 8 bytes.
    let z = |b: &[u8]| {
        let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        std::io::Write::write_all(&mut e, b).unwrap();
        e.finish().unwrap()
    };
    let (b0, b1) = (z(&coords[..64]), z(&coords[64..]));
    let zlib = " compressor=\"vtkZLibDataCompressor\"";
    let header = [2, 64, 8, b0.len() as u64, b1.len() as u64];
    let data = [b0.clone(), b1.clone()].concat();
    let packed = dir.write("zlib.vtp", appended_vtp("UInt32", zlib, &header, 4, &data));
    assert_eq!(read_vtk(&packed).unwrap(), s);
    // Headers that claim more than the file holds are refused before any allocation.
    for (name, file) in [
        (
            "huge.vtp",
            appended_vtp("UInt64", "", &[1 << 40], 8, &coords),
        ),
        ("short.vtp", appended_vtp("UInt64", "", &[80], 8, &coords)),
        (
            "blocks.vtp",
            appended_vtp("UInt32", zlib, &[u32::MAX as u64, 64, 8], 4, &data),
        ),
        (
            "inflate.vtp",
            appended_vtp("UInt32", zlib, &[2, 1 << 30, 8, 10, 10], 4, &data),
        ),
        (
            "lying.vtp",
            appended_vtp(
                "UInt32",
                zlib,
                &[2, 64, 16, b0.len() as u64, b1.len() as u64],
                4,
                &data,
            ),
        ),
    ] {
        let path = dir.write(name, file);
        assert_err(read_vtk(&path), &path, &["DataArray"]);
    }
}
