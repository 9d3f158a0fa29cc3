//! Tests of the segmentation module against independent expectations: analytic spheres and
//! ellipsoids (distance, volume), hand-written NRRD and NIfTI files (every field's effect on
//! the affine worked out by hand), and the specific error of each malformed header.

use std::io::Write;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix4, Point3, Rotation3, Unit, Vector3};

use super::*;
use crate::geometry::closest_point_on_triangle;
use crate::mesh::{validate, TriSurface};

/// Unsigned distance from `p` to the nearest point of `surface` (brute force over all
/// triangles).
fn distance_to_surface(surface: &TriSurface, p: &Point3<f64>) -> f64 {
    (0..surface.triangles.len())
        .map(|t| {
            let (q, _) = closest_point_on_triangle(p, &surface.corners(t));
            (q - p).norm_squared()
        })
        .filter(|d2| d2.is_finite())
        .fold(f64::INFINITY, f64::min)
        .sqrt()
}

/// A fresh directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        let p = std::env::temp_dir().join(format!("livereg-seg-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        Self(p)
    }
    fn path(&self, f: &str) -> PathBuf {
        self.0.join(f)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Affine from index to physical: `translation + R · diag(spacing) · ijk`, with the first axis
/// flipped when `flip` (negative determinant).
fn affine(rotation: Rotation3<f64>, spacing: [f64; 3], flip: bool, t: [f64; 3]) -> Matrix4<f64> {
    let mut s = Vector3::from(spacing);
    if flip {
        s.x = -s.x;
    }
    let m = rotation.matrix() * nalgebra::Matrix3::from_diagonal(&s);
    let mut a = Matrix4::identity();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&m);
    a.fixed_view_mut::<3, 1>(0, 3).copy_from(&Vector3::from(t));
    a
}

/// Labelmap of the ellipsoid `Σ ((p − c)/r)² ≤ 1` (label 5) over a grid covering it.
fn ellipsoid(affine: Matrix4<f64>, centre: Point3<f64>, radii: [f64; 3]) -> Labelmap {
    let inv = affine.try_inverse().unwrap();
    // Grid: the index box of the ellipsoid's bounding box, plus 3 voxels.
    let mut lo = [f64::MAX; 3];
    let mut hi = [f64::MIN; 3];
    for corner in 0..8 {
        let p = Point3::new(
            centre.x + if corner & 1 == 0 { -radii[0] } else { radii[0] },
            centre.y + if corner & 2 == 0 { -radii[1] } else { radii[1] },
            centre.z + if corner & 4 == 0 { -radii[2] } else { radii[2] },
        );
        let q = inv.transform_point(&p);
        for a in 0..3 {
            lo[a] = lo[a].min(q[a]);
            hi[a] = hi[a].max(q[a]);
        }
    }
    let shift = lo.map(|l| l.floor() - 3.0);
    let dims = [0, 1, 2].map(|a| (hi[a] - shift[a]).ceil() as usize + 4);
    let mut a2 = affine;
    let t = affine.transform_point(&Point3::from(Vector3::from(shift)));
    a2.fixed_view_mut::<3, 1>(0, 3).copy_from(&t.coords);
    let mut labels = vec![0u16; dims[0] * dims[1] * dims[2]];
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let p = a2.transform_point(&Point3::new(i as f64, j as f64, k as f64)) - centre;
                let r =
                    (p.x / radii[0]).powi(2) + (p.y / radii[1]).powi(2) + (p.z / radii[2]).powi(2);
                if r <= 1.0 {
                    labels[i + dims[0] * (j + dims[1] * k)] = 5;
                }
            }
        }
    }
    Labelmap::new(dims, labels, a2).unwrap()
}

/// Points spread evenly over the sphere (Fibonacci lattice).
fn sphere_samples(c: Point3<f64>, r: f64, n: usize) -> Vec<Point3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let rho = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            c + r * Vector3::new(rho * phi.cos(), rho * phi.sin(), z)
        })
        .collect()
}

/// Points on the triangles: corners, edge midpoints and centroids.
fn surface_samples(s: &TriSurface) -> Vec<Point3<f64>> {
    let mut out = s.vertices.clone();
    for t in &s.triangles {
        let [a, b, c] = t.map(|i| s.vertices[i]);
        out.push(Point3::from((a.coords + b.coords + c.coords) / 3.0));
        out.push(Point3::from((a.coords + b.coords) / 2.0));
    }
    out
}

/// Symmetric Hausdorff distance (sampled both ways) between a mesh and the sphere.
fn hausdorff_to_sphere(s: &TriSurface, c: Point3<f64>, r: f64) -> f64 {
    let to_sphere = surface_samples(s)
        .iter()
        .map(|p| ((p - c).norm() - r).abs())
        .fold(0.0, f64::max);
    let to_mesh = sphere_samples(c, r, 400)
        .iter()
        .map(|p| distance_to_surface(s, p))
        .fold(0.0, f64::max);
    to_sphere.max(to_mesh)
}

fn assert_clean(s: &TriSurface) -> crate::mesh::SurfaceReport {
    let r = validate(s);
    assert!(r.watertight, "{r}");
    assert_eq!(r.degenerate_triangles, 0, "{r}");
    assert_eq!(r.unreferenced_vertices, 0, "{r}");
    assert_eq!(r.components, 1, "{r}");
    assert!(r.signed_volume > 0.0, "{r}");
    r
}

#[test]
fn spheres_at_several_voxel_sizes_and_affines() {
    let tilt = Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(1.0, 2.0, 3.0)), 0.5);
    let cases = [
        (
            "1 mm isotropic",
            affine(Rotation3::identity(), [1.0; 3], false, [0.0; 3]),
            12.0,
        ),
        (
            "0.7×0.7×1.5 mm",
            affine(
                Rotation3::identity(),
                [0.7, 0.7, 1.5],
                false,
                [-40.0, 12.0, 300.0],
            ),
            14.0,
        ),
        (
            "2 mm isotropic",
            affine(Rotation3::identity(), [2.0; 3], false, [5.0; 3]),
            20.0,
        ),
        (
            "rotated, anisotropic, det < 0",
            affine(tilt, [0.8, 1.1, 1.6], true, [10.0, -20.0, 30.0]),
            15.0,
        ),
    ];
    for (name, a, r) in cases {
        let c = Point3::new(3.3, -7.1, 2.9);
        let map = ellipsoid(a, c, [r; 3]);
        let options = SurfaceOptions {
            target_triangles: 4000,
            ..SurfaceOptions::default()
        };
        let out = extract_surface(&map, &[5], &options).unwrap();
        let report = assert_clean(&out.surface);
        assert!(out.surface.triangles.len() <= 4000, "{name}: {report}");
        let s = map.spacing();
        let diagonal = s.norm();
        let h = hausdorff_to_sphere(&out.surface, c, r);
        assert!(
            h <= diagonal,
            "{name}: Hausdorff {h:.3} mm > voxel diagonal {diagonal:.3}"
        );
        let exact = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
        let rel = (report.signed_volume - exact) / exact;
        assert!(
            rel.abs() < 0.04,
            "{name}: volume {:.1} vs {exact:.1} ({:+.1} %)",
            report.signed_volume,
            100.0 * rel
        );
        eprintln!("{name}: Hausdorff {h:.3} mm (diagonal {diagonal:.3}), volume {:+.2} %, {} triangles from {}", 100.0 * rel, report.triangles, out.marching_cubes_triangles);
    }
}

#[test]
fn ellipsoid_volume_and_orientation_under_a_flipping_affine() {
    let rot = Rotation3::from_euler_angles(0.3, -0.2, 0.9);
    let map = ellipsoid(
        affine(rot, [0.9, 0.6, 1.2], true, [1.0, 2.0, 3.0]),
        Point3::origin(),
        [20.0, 12.0, 9.0],
    );
    assert!(map.directions().determinant() < 0.0);
    let out = extract_surface(&map, &[5], &SurfaceOptions::default()).unwrap();
    let r = assert_clean(&out.surface);
    let exact = 4.0 / 3.0 * std::f64::consts::PI * 20.0 * 12.0 * 9.0;
    assert!(
        (r.signed_volume - exact).abs() / exact < 0.04,
        "{r} vs {exact}"
    );
    // Every vertex lies within a voxel diagonal of the ellipsoid (radial distance bound).
    let d = map.spacing().norm();
    for p in &out.surface.vertices {
        let q = Vector3::new(p.x / 20.0, p.y / 12.0, p.z / 9.0).norm();
        let radial = (p.coords.norm()) * (1.0 - 1.0 / q);
        assert!(radial.abs() <= d, "vertex {p} off by {radial}");
    }
}

#[test]
fn unsmoothed_undecimated_surface_is_the_voxel_boundary() {
    // Two separate blocks and a cavity in the bigger one: the options decide what remains.
    let dims = [20, 12, 12];
    let mut labels = vec![0u16; 20 * 12 * 12];
    let idx = |i: usize, j: usize, k: usize| i + 20 * (j + 12 * k);
    for k in 2..10 {
        for j in 2..10 {
            for i in 2..10 {
                labels[idx(i, j, k)] = 1;
            }
        }
    }
    labels[idx(5, 5, 5)] = 0; // cavity
    labels[idx(15, 5, 5)] = 1; // island
    let map = Labelmap::new(dims, labels, Matrix4::identity()).unwrap();
    let raw = SurfaceOptions {
        smooth: false,
        target_triangles: 0,
        keep_largest_component: false,
        fill_cavities: false,
        ..SurfaceOptions::default()
    };
    let out = extract_surface(&map, &[1], &raw).unwrap();
    let r = validate(&out.surface);
    assert!(r.watertight, "{r}");
    assert_eq!(r.components, 3, "block, cavity shell, island: {r}");
    let clean = extract_surface(
        &map,
        &[1],
        &SurfaceOptions {
            keep_largest_component: true,
            fill_cavities: true,
            ..raw.clone()
        },
    )
    .unwrap();
    assert_eq!((clean.removed_voxels, clean.filled_voxels), (1, 1));
    let r = validate(&clean.surface);
    assert_eq!(r.components, 1, "{r}");
    // An 8³ block meshed at the 0.5 level with chamfered edges and corners: 512 minus the
    // edge prisms (12 × 8 × 1/8 … ) — bounded by the block and its 7³ core.
    assert!(r.signed_volume < 512.0 && r.signed_volume > 343.0, "{r}");
}

#[test]
fn missing_labels_and_names_are_reported() {
    let map =
        ellipsoid(Matrix4::identity(), Point3::new(5.0, 5.0, 5.0), [3.0; 3]).with_segments(vec![
            Segment {
                name: "liver".into(),
                label: 5,
            },
        ]);
    let e = extract_surface(&map, &[9], &SurfaceOptions::default()).unwrap_err();
    assert!(
        e.to_string().contains("[9]") && e.to_string().contains("[5]"),
        "{e}"
    );
    let e = organ_surface(
        &map,
        &[LabelRef::from("tumour")],
        &SurfaceOptions::default(),
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("'tumour'") && e.to_string().contains("'liver' = 5"),
        "{e}"
    );
    let s = organ_surface(&map, &[LabelRef::from("Liver")], &SurfaceOptions::default()).unwrap();
    assert!(validate(&s).watertight);
    assert_eq!(LabelRef::from("7"), LabelRef::Value(7));
}

#[test]
fn tumour_mesh_keeps_every_lesion() {
    let mut map = ellipsoid(Matrix4::identity(), Point3::new(8.0, 8.0, 8.0), [4.0; 3]);
    let dims = map.dims();
    let mut labels = map.labels().to_vec();
    // A second lesion far from the first.
    for k in 1..4 {
        for j in 1..4 {
            for i in dims[0] - 4..dims[0] - 1 {
                labels[i + dims[0] * (j + dims[1] * k)] = 5;
            }
        }
    }
    map = Labelmap::new(dims, labels, *map.affine()).unwrap();
    let t = tumour_mesh(&map, &[LabelRef::Value(5)]).unwrap();
    let r = validate(&t);
    assert!(r.watertight && r.components == 2, "{r}");
}

#[test]
fn vessel_points_are_voxel_centres_evenly_subsampled() {
    let a = affine(
        Rotation3::identity(),
        [0.5, 0.5, 2.0],
        false,
        [10.0, 20.0, 30.0],
    );
    let mut labels = vec![0u16; 10 * 10 * 10];
    for i in 0..10 {
        labels[i + 10 * (3 + 10 * 4)] = 3; // a line of 10 voxels along x at j = 3, k = 4
    }
    let map = Labelmap::new([10, 10, 10], labels, a).unwrap();
    let all = vessel_points(&map, &[LabelRef::Value(3)], 100).unwrap();
    assert_eq!(all.len(), 10);
    assert_eq!(all[0], Point3::new(10.0, 21.5, 38.0));
    let some = vessel_points(&map, &[LabelRef::Value(3)], 4).unwrap();
    assert_eq!(some.len(), 4);
    let xs: Vec<f64> = some.iter().map(|p| p.x).collect();
    assert_eq!(xs, vec![11.0, 12.0, 13.5, 14.5], "every 2.5th voxel");
    assert!(vessel_points(&map, &[LabelRef::Value(4)], 4).is_err());
}

#[test]
fn decimation_keeps_a_closed_manifold_and_reaches_the_target() {
    let map = ellipsoid(
        Matrix4::identity(),
        Point3::new(0.0, 0.0, 0.0),
        [25.0, 15.0, 10.0],
    );
    for target in [10_000, 1000, 200, 50] {
        let opts = SurfaceOptions {
            target_triangles: target,
            ..SurfaceOptions::default()
        };
        let out = extract_surface(&map, &[5], &opts).unwrap();
        let r = assert_clean(&out.surface);
        assert!(r.triangles <= target, "{target}: {r}");
        assert!(
            r.triangles + 4 >= target.min(out.marching_cubes_triangles) * 9 / 10,
            "{target}: only {r}"
        );
    }
}

// ---------------------------------------------------------------- NRRD

/// A 4×3×2 labelmap, values 0..24 mod 7, first index fastest.
fn small_values() -> Vec<u16> {
    (0..24u16).map(|v| v % 7).collect()
}

fn write(path: &Path, bytes: &[u8]) {
    std::fs::write(path, bytes).unwrap();
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

fn nrrd_file(header_fields: &str, data: &[u8]) -> Vec<u8> {
    let mut out = format!("NRRD0004\n# test\n{}\n\n", header_fields.trim_end()).into_bytes();
    out.extend_from_slice(data);
    out
}

const GEOMETRY: &str = "space directions: (0,0.5,0) (-2,0,0) (0,0,3)\nspace origin: (10,-20,30)\n";

#[test]
fn nrrd_raw_gzip_endians_and_spaces() {
    let dir = TempDir::new("nrrd");
    let v = small_values();
    let le: Vec<u8> = v.iter().flat_map(|x| (*x as i16).to_le_bytes()).collect();
    let be: Vec<u8> = v.iter().flat_map(|x| (*x as i16).to_be_bytes()).collect();
    let u8s: Vec<u8> = v.iter().map(|&x| x as u8).collect();
    // Expected LPS affine for the LPS header.
    #[rustfmt::skip]
    let lps = Matrix4::new(
        0.0, -2.0, 0.0, 10.0,
        0.5,  0.0, 0.0, -20.0,
        0.0,  0.0, 3.0, 30.0,
        0.0,  0.0, 0.0, 1.0,
    );
    // The same numbers read as RAS: x and y negated.
    #[rustfmt::skip]
    let from_ras = Matrix4::new(
        0.0,  2.0, 0.0, -10.0,
        -0.5, 0.0, 0.0, 20.0,
        0.0,  0.0, 3.0, 30.0,
        0.0,  0.0, 0.0, 1.0,
    );
    let cases: Vec<(&str, String, Vec<u8>, Matrix4<f64>)> = vec![
        ("raw-le", format!("type: short\nencoding: raw\nendian: little\nspace: left-posterior-superior\n{GEOMETRY}"), le.clone(), lps),
        ("raw-be", format!("type: int16\nencoding: raw\nendian: big\nspace: LPS\n{GEOMETRY}"), be.clone(), lps),
        ("gz-le", format!("type: short\nencoding: gzip\nendian: little\nspace: right-anterior-superior\n{GEOMETRY}"), gzip(&le), from_ras),
        ("gz-be", format!("type: signed short\nencoding: gz\nendian: big\nspace: RAS\n{GEOMETRY}"), gzip(&be), from_ras),
        ("uchar-no-endian", format!("type: uchar\nencoding: raw\nspace: left-posterior-superior\nkinds: domain domain domain\n{GEOMETRY}"), u8s.clone(), lps),
        ("ascii", format!("type: uint8\nencoding: ascii\nspace: LPS\n{GEOMETRY}"), v.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(" ").into_bytes(), lps),
    ];
    for (name, fields, data, expected) in cases {
        let p = dir.path(&format!("{name}.nrrd"));
        write(
            &p,
            &nrrd_file(&format!("dimension: 3\nsizes: 4 3 2\n{fields}"), &data),
        );
        let map = read_labelmap(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(map.dims(), [4, 3, 2], "{name}");
        assert_eq!(map.labels(), &v[..], "{name}");
        assert!(
            (map.affine() - expected).abs().max() < 1e-12,
            "{name}: {}",
            map.affine()
        );
    }
}

#[test]
fn nrrd_spacings_without_space_and_byte_skip() {
    let dir = TempDir::new("nrrd-spacings");
    let v = small_values();
    let p = dir.path("s.nrrd");
    let mut data = vec![0xAAu8; 5];
    data.extend(v.iter().map(|&x| x as u8));
    write(&p, &nrrd_file("type: uchar\ndimension: 3\nsizes: 4 3 2\nspacings: 0.5 0.25 4\nencoding: raw\nbyte skip: 5", &data));
    let map = read_nrrd(&p).unwrap();
    assert_eq!(map.labels(), &v[..]);
    assert_eq!(
        *map.affine(),
        Matrix4::from_diagonal(&nalgebra::Vector4::new(0.5, 0.25, 4.0, 1.0))
    );
    let q = dir.path("end.nrrd");
    write(
        &q,
        &nrrd_file(
            "type: uchar\ndimension: 3\nsizes: 4 3 2\nencoding: raw\nbyte skip: -1",
            &data,
        ),
    );
    assert_eq!(read_nrrd(&q).unwrap().labels(), &v[..]);
}

#[test]
fn seg_nrrd_segments_and_layers() {
    let dir = TempDir::new("seg");
    let v = small_values();
    let segs = "Segment0_Name:=liver\nSegment0_LabelValue:=1\nSegment0_Layer:=0\nSegment1_Name:=tumour\nSegment1_LabelValue:=2\nSegment1_Layer:=1\n";
    // Two layers: layer 0 = v, layer 1 = v reversed; the list axis first (interleaved).
    let mut data = Vec::new();
    for (i, &x) in v.iter().enumerate() {
        data.push(x as u8);
        data.push(v[23 - i] as u8);
    }
    let p = dir.path("two.seg.nrrd");
    write(&p, &nrrd_file(&format!("type: uchar\ndimension: 4\nsizes: 2 4 3 2\nkinds: list domain domain domain\nencoding: gzip\nspace: LPS\nspace directions: none (1,0,0) (0,1,0) (0,0,1)\nspace origin: (0,0,0)\n{segs}"), &gzip(&data)));
    let layers = read_nrrd_layers(&p).unwrap();
    assert_eq!(layers.len(), 2);
    assert_eq!(layers[0].labels(), &v[..]);
    assert_eq!(layers[1].labels()[0], v[23]);
    assert_eq!(layers[0].label_of("liver"), Some(1));
    assert_eq!(layers[0].label_of("tumour"), None);
    assert_eq!(layers[1].label_of("tumour"), Some(2));
    let e = read_labelmap(&p).unwrap_err().to_string();
    assert!(
        e.contains("2 layers") && e.contains("read_nrrd_layers"),
        "{e}"
    );
    // A single layer in 4-D form reads as a labelmap, with its segments.
    let one = dir.path("one.seg.nrrd");
    write(&one, &nrrd_file("type: uchar\ndimension: 4\nsizes: 1 4 3 2\nkinds: list domain domain domain\nencoding: raw\nspace: LPS\nspace directions: none (1,0,0) (0,1,0) (0,0,1)\nSegment0_Name:=liver\nSegment0_LabelValue:=3\n", &v.iter().map(|&x| x as u8).collect::<Vec<_>>()));
    let map = read_labelmap(&one).unwrap();
    assert_eq!(
        map.segments(),
        &[Segment {
            name: "liver".into(),
            label: 3
        }]
    );
}

#[test]
fn malformed_nrrd_headers_give_the_specific_error() {
    let dir = TempDir::new("nrrd-bad");
    let ok = "type: uchar\ndimension: 3\nsizes: 4 3 2\nencoding: raw\nspace: LPS\nspace directions: (1,0,0) (0,1,0) (0,0,1)";
    let data = vec![1u8; 24];
    let cases: Vec<(&str, Vec<u8>, &[&str])> = vec![
        ("magic", b"NRRD0009\ntype: uchar\n\n".to_vec(), &["header field 'magic'", "NRRD0009"]),
        ("no-type", nrrd_file(&ok.replace("type: uchar\n", ""), &data), &["'type'", "missing"]),
        ("bad-type", nrrd_file(&ok.replace("uchar", "block"), &data), &["'type'", "'block'"]),
        ("dimension", nrrd_file(&ok.replace("dimension: 3", "dimension: 2").replace("sizes: 4 3 2", "sizes: 4 3"), &data), &["'dimension'", "2"]),
        ("sizes", nrrd_file(&ok.replace("sizes: 4 3 2", "sizes: 4 x 2"), &data), &["'sizes'", "'4 x 2'"]),
        ("short", nrrd_file(ok, &data[..20]), &["voxel data", "need 24"]),
        ("short-gz", nrrd_file(&ok.replace("raw", "gzip"), &gzip(&data[..20])), &["voxel data", "20 bytes", "need 24"]),
        ("huge", nrrd_file(&ok.replace("sizes: 4 3 2", "sizes: 100000 100000 100000"), &data), &["'sizes'", "voxels accepted"]),
        ("encoding", nrrd_file(&ok.replace("raw", "bzip2"), &data), &["unsupported", "bzip2"]),
        ("endian", nrrd_file(&ok.replace("uchar", "short"), &data), &["'endian'", "missing"]),
        ("space", nrrd_file(&ok.replace("space: LPS", "space: scanner-xyz"), &data), &["unsupported", "scanner-xyz"]),
        ("directions", nrrd_file(&ok.replace("(0,1,0) (0,0,1)", "(0,1) (0,0,1)"), &data), &["'space directions'", "(0,1)"]),
        ("singular", nrrd_file(&ok.replace("(0,1,0) (0,0,1)", "(1,0,0) (0,0,1)"), &data), &["'space directions'", "singular"]),
        ("origin", nrrd_file(&format!("{ok}\nspace origin: (1,2)"), &data), &["'space origin'", "(1,2)"]),
        ("detached", nrrd_file(&format!("{ok}\ndata file: x.raw"), &[]), &["unsupported", "detached", "x.raw"]),
        ("no-blank-line", format!("NRRD0004\n{ok}\n").into_bytes(), &["'header'", "blank line"]),
        ("not-a-label", nrrd_file(&ok.replace("uchar", "float").replace("raw", "raw\nendian: little"), &[0.5f32; 24].iter().flat_map(|f| f.to_le_bytes()).collect::<Vec<_>>()), &["voxel data", "0.5", "not an integer"]),
        ("segment", nrrd_file(&format!("{ok}\nSegment0_Name:=liver\nSegment0_LabelValue:=-3"), &data), &["'Segment0_LabelValue'", "'-3'"]),
        ("layer", nrrd_file(&format!("{ok}\nSegment0_Name:=liver\nSegment0_Layer:=2"), &data), &["'Segment0_Layer'", "1 layer"]),
        ("line-skip", nrrd_file(&format!("{ok}\nline skip: 1000000000000"), &data), &["'line skip'", "ends after 1 lines"]),
        ("list-last", nrrd_file("type: uchar\ndimension: 4\nsizes: 4 3 2 1\nencoding: raw\nspace: LPS\nspace directions: (1,0,0) (0,1,0) (0,0,1) none", &data), &["unsupported", "not the first"]),
    ];
    for (name, bytes, needles) in cases {
        let p = dir.path(&format!("{name}.nrrd"));
        write(&p, &bytes);
        let e = read_nrrd(&p).expect_err(name).to_string();
        assert!(
            e.contains(&*p.to_string_lossy()),
            "{name}: the error names the file: {e}"
        );
        for n in needles {
            assert!(e.contains(n), "{name}: '{n}' missing from: {e}");
        }
    }
}

// ---------------------------------------------------------------- NIfTI

/// A NIfTI-1 single file (header, 4 zero extension bytes, data) written field by field.
struct Nifti1 {
    dims: [i16; 3],
    datatype: i16,
    bitpix: i16,
    pixdim: [f32; 4],
    qform_code: i16,
    sform_code: i16,
    quatern: [f32; 6],
    srow: [[f32; 4]; 3],
    scl: [f32; 2],
    xyzt_units: u8,
    big_endian: bool,
    data: Vec<u8>,
}

impl Nifti1 {
    fn new(dims: [i16; 3], data_u8: Vec<u8>) -> Self {
        Self {
            dims,
            datatype: 2,
            bitpix: 8,
            pixdim: [1.0; 4],
            qform_code: 0,
            sform_code: 0,
            quatern: [0.0; 6],
            srow: [[0.0; 4]; 3],
            scl: [0.0, 0.0],
            xyzt_units: 2,
            big_endian: false,
            data: data_u8,
        }
    }

    fn bytes(&self) -> Vec<u8> {
        let mut h = vec![0u8; 352];
        let be = self.big_endian;
        let put = |h: &mut Vec<u8>, at: usize, b: &[u8]| h[at..at + b.len()].copy_from_slice(b);
        macro_rules! w {
            ($at:expr, $v:expr) => {{
                let v = $v;
                if be {
                    put(&mut h, $at, &v.to_be_bytes())
                } else {
                    put(&mut h, $at, &v.to_le_bytes())
                }
            }};
        }
        w!(0, 348i32);
        w!(40, 3i16);
        for a in 0..3 {
            w!(42 + 2 * a, self.dims[a]);
        }
        for a in 3..7 {
            w!(42 + 2 * a, 1i16);
        }
        w!(70, self.datatype);
        w!(72, self.bitpix);
        for a in 0..4 {
            w!(76 + 4 * a, self.pixdim[a]);
        }
        w!(108, 352f32);
        w!(112, self.scl[0]);
        w!(116, self.scl[1]);
        h[123] = self.xyzt_units;
        w!(252, self.qform_code);
        w!(254, self.sform_code);
        for (n, q) in self.quatern.iter().enumerate() {
            w!(256 + 4 * n, *q);
        }
        for r in 0..3 {
            for c in 0..4 {
                w!(280 + 16 * r + 4 * c, self.srow[r][c]);
            }
        }
        put(&mut h, 344, b"n+1\0");
        h.extend_from_slice(&self.data);
        h
    }
}

#[test]
fn nifti_sform_qform_pixdim_and_scaling() {
    let dir = TempDir::new("nifti");
    let v = small_values();
    let u8s: Vec<u8> = v.iter().map(|&x| x as u8).collect();

    // sform: RAS srows; LPS negates the first two rows.
    let mut f = Nifti1::new([4, 3, 2], u8s.clone());
    f.sform_code = 1;
    f.qform_code = 1; // ignored: the sform wins
    f.quatern = [0.0, 0.0, 1.0, 5.0, 5.0, 5.0];
    f.srow = [
        [0.0, 0.7, 0.0, -50.0],
        [-0.7, 0.0, 0.0, 60.0],
        [0.0, 0.0, 1.5, -70.0],
    ];
    let p = dir.path("sform.nii");
    write(&p, &f.bytes());
    let (map, how) = read_nifti_with_transform(&p).unwrap();
    assert_eq!(how, NiftiTransform::Sform);
    assert_eq!(map.labels(), &v[..]);
    #[rustfmt::skip]
    let expected = Matrix4::new(
        0.0, -0.7, 0.0, 50.0,
        0.7,  0.0, 0.0, -60.0,
        0.0,  0.0, 1.5, -70.0,
        0.0,  0.0, 0.0, 1.0,
    );
    assert!(
        (map.affine() - expected).abs().max() < 1e-6,
        "{}",
        map.affine()
    );

    // qform: 90° about z (b = c = 0, d = sin 45°), pixdim (2, 3, 4), qfac = −1, big-endian,
    // 16-bit data, gzip.
    let mut f = Nifti1::new(
        [4, 3, 2],
        v.iter().flat_map(|&x| (x as i16).to_be_bytes()).collect(),
    );
    f.big_endian = true;
    f.datatype = 4;
    f.bitpix = 16;
    f.qform_code = 1;
    f.pixdim = [-1.0, 2.0, 3.0, 4.0];
    let d = std::f32::consts::FRAC_1_SQRT_2;
    f.quatern = [0.0, 0.0, d, 1.0, 2.0, 3.0];
    let p = dir.path("qform.nii.gz");
    write(&p, &gzip(&f.bytes()));
    let (map, how) = read_nifti_with_transform(&p).unwrap();
    assert_eq!(how, NiftiTransform::Qform);
    assert_eq!(map.labels(), &v[..]);
    // R = [[0,-1,0],[1,0,0],[0,0,1]]; R·diag(2, 3, −4) = [[0,-3,0],[2,0,0],[0,0,-4]] in RAS.
    #[rustfmt::skip]
    let expected = Matrix4::new(
        0.0,  3.0, 0.0, -1.0,
        -2.0, 0.0, 0.0, -2.0,
        0.0,  0.0, -4.0, 3.0,
        0.0,  0.0, 0.0, 1.0,
    );
    assert!(
        (map.affine() - expected).abs().max() < 1e-5,
        "{}",
        map.affine()
    );

    // Neither: pixdim only (in metres: × 1000), with scl_slope/inter on floats.
    let mut f = Nifti1::new(
        [4, 3, 2],
        v.iter()
            .flat_map(|&x| ((x as f32 - 1.0) / 2.0).to_le_bytes())
            .collect(),
    );
    f.datatype = 16;
    f.bitpix = 32;
    f.pixdim = [1.0, 0.001, 0.002, 0.003];
    f.xyzt_units = 1;
    f.scl = [2.0, 1.0];
    let p = dir.path("pixdim.nii");
    write(&p, &f.bytes());
    let (map, how) = read_nifti_with_transform(&p).unwrap();
    assert_eq!(how, NiftiTransform::Pixdim);
    assert_eq!(map.labels(), &v[..]);
    let expected = Matrix4::from_diagonal(&nalgebra::Vector4::new(-1.0, -2.0, 3.0, 1.0));
    assert!(
        (map.affine() - expected).abs().max() < 1e-6,
        "{}",
        map.affine()
    );
}

#[test]
fn malformed_nifti_gives_the_specific_error() {
    let dir = TempDir::new("nifti-bad");
    let u8s = vec![1u8; 24];
    let good = Nifti1::new([4, 3, 2], u8s.clone());
    let mut cases: Vec<(&str, Vec<u8>, &[&str])> = Vec::new();
    let mut f = good.bytes();
    f.truncate(352 + 10);
    cases.push(("short.nii", f, &["voxel data", "needs 376"]));
    let mut gz = good.bytes();
    gz.truncate(352 + 10);
    cases.push(("short.nii.gz", gzip(&gz), &["voxel data", "after 10 bytes"]));
    let mut f = good.bytes();
    f[..4].copy_from_slice(&540i32.to_le_bytes());
    cases.push(("v2.nii", f, &["unsupported", "NIfTI-2"]));
    cases.push(("tiny.nii", vec![0u8; 100], &["'sizeof_hdr'", "shorter"]));
    let mut f = good.bytes();
    f[40..42].copy_from_slice(&4i16.to_le_bytes());
    f[48..50].copy_from_slice(&2i16.to_le_bytes());
    cases.push(("4d.nii", f, &["unsupported", "dim[4] = 2"]));
    let mut t = Nifti1::new(
        [4, 3, 2],
        [0.5f32; 24].iter().flat_map(|x| x.to_le_bytes()).collect(),
    );
    t.datatype = 16;
    t.bitpix = 32;
    cases.push((
        "prob.nii",
        t.bytes(),
        &["voxel data", "0.5", "not an integer"],
    ));
    let mut t = Nifti1::new([4, 3, 2], u8s.clone());
    t.datatype = 128;
    cases.push(("rgb.nii", t.bytes(), &["unsupported", "Rgb24"]));
    let mut t = Nifti1::new([4, 3, 2], u8s.clone());
    t.pixdim = [1.0, 1.0, 0.0, 1.0];
    cases.push(("pixdim.nii", t.bytes(), &["'pixdim[2]'", "0"]));
    let mut t = Nifti1::new([4, 3, 2], u8s.clone());
    t.qform_code = 1;
    t.quatern = [0.9, 0.9, 0.0, 0.0, 0.0, 0.0];
    cases.push((
        "quat.nii",
        t.bytes(),
        &["'quatern_b/c/d'", "unit quaternion"],
    ));
    let mut t = Nifti1::new([30000, 30000, 30000], u8s.clone());
    t.pixdim = [1.0; 4];
    cases.push(("huge.nii", t.bytes(), &["'dim'", "voxels accepted"]));
    let mut f = good.bytes();
    f[344..348].copy_from_slice(b"ni1\0");
    cases.push(("pair.nii", f, &["unsupported", ".img"]));
    for (name, bytes, needles) in cases {
        let p = dir.path(name);
        write(&p, &bytes);
        let e = read_labelmap(&p).expect_err(name).to_string();
        assert!(e.contains(&*p.to_string_lossy()), "{name}: {e}");
        for n in needles {
            assert!(e.contains(n), "{name}: '{n}' missing from: {e}");
        }
    }
    let e = read_labelmap(Path::new("x.mha")).unwrap_err().to_string();
    assert!(e.contains("unknown labelmap extension"), "{e}");
}

#[test]
fn a_label_filling_the_whole_image_still_closes() {
    // Every voxel labelled: the crop's margin lies outside the image and counts as background.
    let map = Labelmap::new([6, 5, 4], vec![2; 120], Matrix4::identity()).unwrap();
    let raw = SurfaceOptions {
        smooth: false,
        target_triangles: 0,
        ..SurfaceOptions::default()
    };
    let out = extract_surface(&map, &[2], &raw).unwrap();
    let r = assert_clean(&out.surface);
    // The 0.5-level box of 6×5×4 voxel centres is 5×4×3 plus half a voxel all round, minus
    // the chamfers at its 12 edges (prisms of cross-section 1/8) and 8 corners.
    assert!(
        r.signed_volume > 5.0 * 4.0 * 3.0 && r.signed_volume < 6.0 * 5.0 * 4.0,
        "{r}"
    );
    let (lo, hi) = out.surface.bounding_box().unwrap();
    assert_eq!(
        (lo, hi),
        (Point3::new(-0.5, -0.5, -0.5), Point3::new(5.5, 4.5, 3.5))
    );
}
