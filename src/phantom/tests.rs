//! Tests of the liver phantom: shape, internal structures, ligament region, files.

use std::path::PathBuf;

use nalgebra::{Point3, Vector3};

use super::liver_surface::reference_boundary;
use super::*;
use crate::geometry::InsideTest;
use crate::mesh::{read_points, read_surface, validate};

/// A fresh temporary directory, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let dir =
            std::env::temp_dir().join(format!("livereg-phantom-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn inside_test(s: &TriSurface) -> InsideTest {
    InsideTest::new(&s.vertices, &s.triangles)
}

/// Point of the exact (smooth) liver surface in reference direction `n`.
fn on_surface(n: Vector3<f64>) -> Point3<f64> {
    liver_map(reference_boundary(n))
}

#[test]
fn surface_is_closed_outward_and_liver_sized() {
    let s = liver_phantom().surface;
    let r = validate(&s);
    assert!(r.watertight, "{r:?}");
    assert_eq!(r.components, 1);
    assert_eq!(r.degenerate_triangles, 0);
    assert_eq!(r.unreferenced_vertices, 0);
    assert!((4000..=8000).contains(&s.triangles.len()));
    let volume = s.signed_volume();
    assert!((0.0008..0.0020).contains(&volume), "volume {volume} m³");
    assert!((r.signed_volume - volume).abs() < 1e-9);
    let (lo, hi) = s.bounding_box().unwrap();
    let e = hi - lo;
    for (k, want) in [0.20, 0.15, 0.10].into_iter().enumerate() {
        assert!((e[k] / want - 1.0).abs() <= 0.15, "extent {k}: {} m", e[k]);
    }
    let centre = nalgebra::center(&lo, &hi);
    assert!(centre.coords.norm() < 0.015, "bbox centre {centre:?}");
}

#[test]
fn surface_is_locally_outward_everywhere() {
    // Just inside every triangle's centroid is inside, just outside is outside: no fold-overs
    // and no wrongly oriented triangles.
    let s = liver_phantom().surface;
    let inside = inside_test(&s);
    for t in 0..s.triangles.len() {
        let centroid = s.centroid(t);
        let n = s.scaled_normal(t).normalize();
        assert!(inside.contains(&(centroid - n * 2e-4)), "triangle {t}");
        assert!(!inside.contains(&(centroid + n * 2e-4)), "triangle {t}");
    }
}

#[test]
fn right_lobe_is_thick_and_left_lobe_thin() {
    let s = liver_phantom().surface;
    let (lo, hi) = s.bounding_box().unwrap();
    let at = |f: f64| max_thickness_at(&s, lo.x + f * (hi.x - lo.x));
    assert!(at(0.3) > 0.07, "right lobe {}", at(0.3));
    assert!(at(0.5) > 0.07, "middle {}", at(0.5));
    assert!(at(0.85) < 0.035, "left lobe at 85 %: {}", at(0.85));
    assert!(at(0.85) > 0.012, "left lobe at 85 % too thin: {}", at(0.85));
    assert!(at(0.95) < at(0.85));
}

/// Asserts that the midpoint of the chord `a`–`b` is outside `s` by at least `margin`.
fn assert_chord_outside(s: &TriSurface, a: Point3<f64>, b: Point3<f64>, margin: f64) {
    let inside = inside_test(s);
    let mid = nalgebra::center(&a, &b);
    assert!(!inside.contains(&mid), "{a:?}–{b:?}: midpoint inside");
    let d = distance_to_surface(s, &mid);
    assert!(d >= margin, "{a:?}–{b:?}: midpoint only {d} m outside");
}

#[test]
fn umbilical_notch_is_concave() {
    let s = liver_phantom().surface;
    // The front-most points on either side of the notch (mid-height): the chord crosses it.
    let front = |u: f64| on_surface(Vector3::new(u, 1.0, 0.0));
    assert_chord_outside(&s, front(0.04), front(0.44), 0.008);
    // Also slightly below mid-height (anterior-inferior edge).
    let low = |u: f64| on_surface(Vector3::new(u, 1.0, -0.3));
    assert_chord_outside(&s, low(0.08), low(0.40), 0.005);
}

#[test]
fn visceral_face_is_concave_and_diaphragmatic_face_convex() {
    let s = liver_phantom().surface;
    let inside = inside_test(&s);
    let bottom = |u: f64, v: f64| on_surface(Vector3::new(u, v, -1.0));
    let top = |u: f64, v: f64| on_surface(Vector3::new(u, v, 1.0));
    // Across the visceral face (under the right lobe), in both directions.
    assert_chord_outside(&s, bottom(-0.7, -0.05), bottom(0.05, -0.05), 0.003);
    assert_chord_outside(&s, bottom(-0.32, -0.6), bottom(-0.32, 0.5), 0.003);
    // Across the dome the chords run inside.
    for (a, b) in [
        (top(-0.7, 0.0), top(0.1, 0.0)),
        (top(-0.32, -0.6), top(-0.32, 0.5)),
    ] {
        let mid = nalgebra::center(&a, &b);
        assert!(inside.contains(&mid), "dome chord {a:?}–{b:?}");
        assert!(distance_to_surface(&s, &mid) > 0.005);
    }
}

#[test]
fn targets_are_well_inside_and_spread_over_both_lobes() {
    let p = liver_phantom();
    let inside = inside_test(&p.surface);
    assert!(p.targets.len() >= 15, "{} targets", p.targets.len());
    for (i, t) in p.targets.iter().enumerate() {
        assert!(inside.contains(t), "target {i} {t:?} outside");
        let d = distance_to_surface(&p.surface, t);
        assert!(d >= 0.008, "target {i} {t:?} only {d} m from the surface");
        for (j, q) in p.targets.iter().enumerate().take(i) {
            assert!((t - q).norm() >= 0.005, "targets {j} and {i} coincide");
        }
    }
    let left = p.targets.iter().filter(|t| t.x > 0.03).count();
    let right = p.targets.iter().filter(|t| t.x < -0.02).count();
    assert!(left >= 4 && right >= 6, "left {left}, right {right}");
    let b = crate::geometry::Aabb::from_points(&p.targets);
    let e = b.extents();
    assert!(e.x > 0.10 && e.y > 0.04 && e.z > 0.03, "spread {e:?}");
}

#[test]
fn tumour_is_small_closed_and_fully_inside_the_right_lobe() {
    let p = liver_phantom();
    let r = validate(&p.tumour);
    assert!(r.watertight && r.components == 1, "{r:?}");
    assert!(p.tumour.signed_volume() > 0.0);
    let (lo, hi) = p.tumour.bounding_box().unwrap();
    let e = hi - lo;
    assert!(e.iter().all(|&x| (0.015..=0.03).contains(&x)), "{e:?}");
    assert!(hi.x < -0.02, "not in the right lobe: {hi:?}");
    let liver = inside_test(&p.surface);
    for v in &p.tumour.vertices {
        assert!(liver.contains(v));
        assert!(distance_to_surface(&p.surface, v) >= 0.005, "{v:?}");
    }
    // No liver vertex inside the tumour (the two surfaces do not intersect).
    let tumour = inside_test(&p.tumour);
    assert!(p.surface.vertices.iter().all(|v| !tumour.contains(v)));
}

#[test]
fn ligament_box_holds_a_few_percent_of_the_posterior_superior_surface() {
    let p = liver_phantom();
    let share = area_in_box(&p.surface, &p.ligament) / p.surface.area();
    assert!((0.03..=0.08).contains(&share), "share {share}");
    let (lo, hi) = p.surface.bounding_box().unwrap();
    let c = p.ligament.center();
    let mid = nalgebra::center(&lo, &hi);
    assert!(c.y < mid.y - 0.03, "not posterior: {c:?}");
    assert!(c.z > mid.z + 0.01, "not superior: {c:?}");
    // Every surface point in the box is on the back or the top of the liver.
    let held: Vec<_> = p
        .surface
        .vertices
        .iter()
        .filter(|v| p.ligament.contains(v))
        .collect();
    assert!(held.len() > 50);
    assert!(held
        .iter()
        .all(|v| v.y < mid.y && v.z > lo.z + 0.4 * (hi.z - lo.z)));
}

#[test]
fn distance_to_surface_is_exact_on_simple_cases() {
    let cube =
        crate::mesh::primitives::box_surface(Point3::origin(), Point3::new(1.0, 1.0, 1.0), 2);
    let cases = [
        (Point3::new(0.5, 0.5, 0.5), 0.5),
        (Point3::new(0.2, 0.3, 0.6), 0.2),
        (Point3::new(0.5, 0.5, 3.0), 2.0),
        (Point3::new(2.0, 2.0, 0.5), 2f64.sqrt()),
        (Point3::new(2.0, 3.0, -2.0), (1.0f64 + 4.0 + 4.0).sqrt()),
        (Point3::new(1.0, 0.25, 0.5), 0.0),
    ];
    for (p, want) in cases {
        let d = distance_to_surface(&cube, &p);
        assert!((d - want).abs() < 1e-12, "{p:?}: {d} vs {want}");
    }
    let empty = TriSurface::default();
    assert_eq!(
        distance_to_surface(&empty, &Point3::origin()),
        f64::INFINITY
    );
}

#[test]
fn generation_is_deterministic() {
    assert_eq!(liver_phantom(), liver_phantom());
    let (a, b) = (TempDir::new("det-a"), TempDir::new("det-b"));
    write_phantom(&a.0).unwrap();
    write_phantom(&b.0).unwrap();
    for name in ["liver.obj", "targets.xyz", "tumour.obj", "scene.toml"] {
        let x = std::fs::read(a.0.join(name)).unwrap();
        let y = std::fs::read(b.0.join(name)).unwrap();
        assert!(!x.is_empty());
        assert!(x == y, "{name} differs between runs");
    }
}

fn assert_close(a: &[Point3<f64>], b: &[Point3<f64>], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    for (p, q) in a.iter().zip(b) {
        assert!((p - q).amax() <= 1e-7, "{what}: {p:?} vs {q:?}");
    }
}

#[test]
fn written_files_read_back_in_millimetres() {
    let p = liver_phantom();
    let dir = TempDir::new("files");
    let sub = dir.0.join("nested").join("out");
    write_phantom_files(&p, &sub).unwrap();

    let mut liver = read_surface(&sub.join("liver.obj")).unwrap();
    liver.scale(1e-3);
    assert_eq!(liver.triangles, p.surface.triangles);
    assert_close(&liver.vertices, &p.surface.vertices, "liver");
    let mut tumour = read_surface(&sub.join("tumour.obj")).unwrap();
    tumour.scale(1e-3);
    assert_eq!(tumour.triangles, p.tumour.triangles);
    assert_close(&tumour.vertices, &p.tumour.vertices, "tumour");
    let targets: Vec<_> = read_points(&sub.join("targets.xyz"))
        .unwrap()
        .into_iter()
        .map(|q| q * 1e-3)
        .collect();
    assert_close(&targets, &p.targets, "targets");

    // Small files: at most 4 decimals per coordinate.
    let text = std::fs::read_to_string(sub.join("liver.obj")).unwrap();
    assert!(text.len() < 200_000, "{} bytes", text.len());
    for line in text.lines().filter(|l| l.starts_with("v ")) {
        for tok in line.split_whitespace().skip(1) {
            let decimals = tok.split('.').nth(1).map_or(0, str::len);
            assert!(decimals <= 4, "{line}");
            assert_ne!(tok, "-0.0000", "{line}");
        }
    }
}

#[test]
fn scene_file_follows_the_contract() {
    let p = liver_phantom();
    let dir = TempDir::new("scene");
    write_phantom_files(&p, &dir.0).unwrap();
    let text = std::fs::read_to_string(dir.0.join("scene.toml")).unwrap();
    let v: toml::Value = toml::from_str(&text).unwrap();
    let get = |path: &str| -> &toml::Value {
        path.split('.').fold(&v, |t, k| {
            t.get(k).unwrap_or_else(|| panic!("missing {path}"))
        })
    };
    assert_eq!(get("units").as_str(), Some("mm"));
    assert_eq!(get("model.surface").as_str(), Some("liver.obj"));
    let st = get("model.structures").as_array().unwrap();
    assert_eq!(st.len(), 2);
    assert_eq!(st[0]["name"].as_str(), Some("vessels"));
    assert_eq!(st[0]["points"].as_str(), Some("targets.xyz"));
    assert_eq!(st[1]["name"].as_str(), Some("tumour"));
    assert_eq!(st[1]["mesh"].as_str(), Some("tumour.obj"));
    assert_eq!(get("grid.cell_size").as_float(), Some(22.5));
    assert_eq!(get("grid.subdivisions").as_integer(), Some(2));
    assert_eq!(get("grid.integration").as_str(), Some("weighted-cell"));
    assert_eq!(get("material.law").as_str(), Some("neo-hookean"));
    assert_eq!(get("material.young_modulus").as_float(), Some(4500.0));
    assert_eq!(get("material.poisson_ratio").as_float(), Some(0.45));
    assert_eq!(get("material.density").as_float(), Some(1060.0));
    assert_eq!(get("registration.rigid").as_str(), Some("icp"));
    let support = get("boundary.support").as_array().unwrap();
    assert_eq!(support.len(), 1);
    assert_eq!(support[0]["stiffness"].as_float(), Some(1.0e5));
    assert_eq!(support[0]["sliding"].as_bool(), Some(false));

    let num = |x: &toml::Value| x.as_float().unwrap();
    let point = |x: &toml::Value| {
        let a = x.as_array().unwrap();
        assert_eq!(a.len(), 3);
        Point3::new(num(&a[0]), num(&a[1]), num(&a[2]))
    };
    let fixed = get("boundary.fixed").as_array().unwrap();
    assert_eq!(fixed.len(), 1);
    let b = fixed[0]["box"].as_array().unwrap();
    assert_close(
        &[point(&b[0]) * 1e-3, point(&b[1]) * 1e-3],
        &[p.ligament.min, p.ligament.max],
        "ligament box",
    );
    let camera = get("registration.camera");
    let (pos, at) = (point(&camera["position"]), point(&camera["look_at"]));
    let distance = (pos - at).norm();
    assert!(
        (240.0..=260.0).contains(&distance),
        "camera {distance} mm away"
    );
    assert!(
        pos.y > 150.0 && pos.z > 100.0,
        "camera not anterior-superior: {pos:?}"
    );
    // The camera sees the liver from outside, the look-at point is near its front-top.
    let liver = inside_test(&p.surface);
    assert!(!liver.contains(&(pos * 1e-3)));
    assert!(distance_to_surface(&p.surface, &(at * 1e-3)) < 0.03);
}
