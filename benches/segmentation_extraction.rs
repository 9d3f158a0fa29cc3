//! Surface extraction from a CT-sized labelmap: 512 × 512 × 300 voxels of 0.7 × 0.7 × 1 mm
//! (LPS), the bundled phantom liver scaled to 1.5 L as label 1, its tumour as label 2 and two
//! vessel tubes inside the liver as label 3 (cavities in label 1).
//!
//! `cargo bench --bench segmentation_extraction` runs criterion on the liver extraction (crop →
//! marching cubes → Taubin → decimation to 20 000 triangles). With `--once` it times a single
//! extraction per stage and exits (for `/usr/bin/time -v`, see docs/segmentation.md):
//! `cargo bench --bench segmentation_extraction -- --once`.

use std::hint::black_box;
use std::time::Instant;

use criterion::Criterion;
use livereg::mesh::{read_obj, validate, TriSurface};
use livereg::segmentation::{extract_surface, voxelise_into, Labelmap, SurfaceOptions};
use nalgebra::{Matrix4, Point3, Vector3};

fn labelmap() -> Labelmap {
    let root = env!("CARGO_MANIFEST_DIR");
    let mut liver = read_obj(format!("{root}/fixtures/liver_phantom/liver.obj").as_ref()).unwrap();
    let tumour = read_obj(format!("{root}/fixtures/liver_phantom/tumour.obj").as_ref()).unwrap();
    let volume = validate(&liver).signed_volume;
    liver.scale((1.5e6 / volume).cbrt());
    let dims = [512, 512, 300];
    // Centre of the grid at the origin; L-P-S axes.
    let mut affine = Matrix4::from_diagonal(&nalgebra::Vector4::new(0.7, 0.7, 1.0, 1.0));
    affine[(0, 3)] = -0.7 * 255.5;
    affine[(1, 3)] = -0.7 * 255.5;
    affine[(2, 3)] = -149.5;
    let mut labels = vec![0u16; 512 * 512 * 300];
    voxelise_into(&liver, dims, &affine, &mut labels, 1).unwrap();
    voxelise_into(&tumour, dims, &affine, &mut labels, 2).unwrap();
    for (a, b) in [
        (
            Point3::new(-40.0, 0.0, -10.0),
            Point3::new(40.0, 10.0, 10.0),
        ),
        (
            Point3::new(-10.0, -30.0, 0.0),
            Point3::new(20.0, 30.0, -5.0),
        ),
    ] {
        voxelise_into(&tube(a, b, 5.0), dims, &affine, &mut labels, 3).unwrap();
    }
    Labelmap::new(dims, labels, affine).unwrap()
}

/// A closed 16-sided prism of radius `r` from `a` to `b`.
fn tube(a: Point3<f64>, b: Point3<f64>, r: f64) -> TriSurface {
    let axis = (b - a).normalize();
    let u = axis.cross(&Vector3::z()).normalize();
    let v = axis.cross(&u);
    let n = 16;
    let mut vertices = Vec::new();
    for end in [a, b] {
        for k in 0..n {
            let t = k as f64 * std::f64::consts::TAU / n as f64;
            vertices.push(end + r * (t.cos() * u + t.sin() * v));
        }
    }
    vertices.push(a);
    vertices.push(b);
    let (ca, cb) = (2 * n, 2 * n + 1);
    let mut triangles = Vec::new();
    for k in 0..n {
        let k1 = (k + 1) % n;
        triangles.push([k, k1, n + k1]);
        triangles.push([k, n + k1, n + k]);
        triangles.push([ca, k1, k]);
        triangles.push([cb, n + k, n + k1]);
    }
    let mut s = TriSurface::new(vertices, triangles);
    livereg::mesh::orient_outward(&mut s);
    s
}

fn main() {
    let t = Instant::now();
    let map = labelmap();
    eprintln!(
        "labelmap {:?} built in {:.2?}: liver {} voxels = {:.2} L",
        map.dims(),
        t.elapsed(),
        map.count(&[1]),
        map.count(&[1]) as f64 * map.voxel_volume() * 1e-6
    );
    let options = SurfaceOptions::default();
    eprintln!("before extraction: {}", memory());
    let t = Instant::now();
    let out = extract_surface(&map, &[1], &options).unwrap();
    let total = t.elapsed();
    eprintln!(
        "liver surface: {total:.3?} ({}), {} marching-cubes triangles → {}; {}",
        out.timings
            .iter()
            .map(|(n, d)| format!("{n} {:.0} ms", d.as_secs_f64() * 1e3))
            .collect::<Vec<_>>()
            .join(", "),
        out.marching_cubes_triangles,
        out.surface.triangles.len(),
        out.report
    );
    eprintln!("after extraction: {}", memory());
    if std::env::args().any(|a| a == "--once") {
        return;
    }
    let mut c = Criterion::default().configure_from_args().sample_size(10);
    c.bench_function("extract_liver_512x512x300", |b| {
        b.iter(|| extract_surface(black_box(&map), &[1], &options).unwrap())
    });
    c.final_summary();
}

/// Current and peak resident memory (Linux `/proc/self/status`).
fn memory() -> String {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .filter(|l| l.starts_with("VmRSS") || l.starts_with("VmHWM"))
        .map(|l| l.split_whitespace().collect::<Vec<_>>().join(" "))
        .collect::<Vec<_>>()
        .join(", ")
}
