//! Tests of the inside/outside classification against exact winding numbers.

use std::f64::consts::PI;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::shapes::{self, Mesh};
use super::{triangle_overlaps_box, Aabb, InsideTest};
use crate::random::Rng;

/// Removes the triangles having all corners with `cut(p)` true (keeps the vertex array).
fn remove_faces(mesh: &Mesh, cut: impl Fn(&Point3<f64>) -> bool) -> Mesh {
    let (v, t) = mesh;
    let kept = t
        .iter()
        .copied()
        .filter(|f| !f.iter().all(|&i| cut(&v[i])))
        .collect();
    (v.clone(), kept)
}

fn translated(mesh: &Mesh, d: Vector3<f64>) -> Mesh {
    (mesh.0.iter().map(|p| p + d).collect(), mesh.1.clone())
}

fn union_soup(a: &Mesh, b: &Mesh) -> Mesh {
    let mut v = a.0.clone();
    let off = v.len();
    v.extend_from_slice(&b.0);
    let mut t = a.1.clone();
    t.extend(b.1.iter().map(|f| f.map(|i| i + off)));
    (v, t)
}

/// Distance from `p` to the closed triangle `t` (Ericson, "Real-Time Collision Detection",
/// closest point by Voronoi regions).
fn point_triangle_distance(p: &Point3<f64>, t: &[Point3<f64>; 3]) -> f64 {
    let [a, b, c] = *t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return (p - a).norm();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return (p - b).norm();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (p - (a + ab * v)).norm();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (p - c).norm();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (p - (a + ac * w)).norm();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + (c - b) * w)).norm();
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    (p - (a + ab * v + ac * w)).norm()
}

/// Outcome of comparing `classify_line` with the exact winding-number decision.
#[derive(Debug, Default)]
struct Comparison {
    checked: usize,
    skipped: usize,
    wrong: usize,
}

/// Compares `classify_line` on `lines` × `zs` with `winding_number_exact ≥ ½`.
///
/// Skipped: points on the surface (distance < 1e-12; there the winding number is a boundary
/// value and the solid-angle formula is not even continuous) and points whose exact winding
/// number is within `band` of ½ (genuinely ambiguous, next to a hole).
fn compare_lines(t: &InsideTest, lines: &[(f64, f64)], zs: &[f64], band: f64) -> Comparison {
    let tris: Vec<[Point3<f64>; 3]> = (0..t.num_triangles())
        .filter_map(|k| t.triangle(k))
        .collect();
    let results: Vec<Comparison> = lines
        .par_iter()
        .map(|&(x, y)| {
            let mut c = Comparison::default();
            let mut out = Vec::new();
            t.classify_line(x, y, zs, &mut out);
            assert_eq!(out.len(), zs.len());
            for (k, &z) in zs.iter().enumerate() {
                let p = Point3::new(x, y, z);
                let w = t.winding_number_exact(&p);
                let on_surface = tris
                    .iter()
                    .any(|tri| point_triangle_distance(&p, tri) < 1e-12);
                if (w - 0.5).abs() < band || on_surface {
                    c.skipped += 1;
                    continue;
                }
                c.checked += 1;
                if out[k] != (w >= 0.5) {
                    c.wrong += 1;
                    eprintln!("mismatch at {p:?}: line {} exact w = {w}", out[k]);
                }
            }
            c
        })
        .collect();
    results
        .into_iter()
        .fold(Comparison::default(), |a, b| Comparison {
            checked: a.checked + b.checked,
            skipped: a.skipped + b.skipped,
            wrong: a.wrong + b.wrong,
        })
}

fn random_lines(rng: &mut Rng, b: &Aabb, n: usize) -> Vec<(f64, f64)> {
    let b = b.expanded(0.1 * b.extents().max());
    (0..n)
        .map(|_| {
            (
                rng.uniform_in(b.min.x, b.max.x),
                rng.uniform_in(b.min.y, b.max.y),
            )
        })
        .collect()
}

fn random_zs(rng: &mut Rng, b: &Aabb, n: usize) -> Vec<f64> {
    let b = b.expanded(0.1 * b.extents().max());
    (0..n).map(|_| rng.uniform_in(b.min.z, b.max.z)).collect()
}

// ---------------------------------------------------------------------------------------------
// Winding numbers
// ---------------------------------------------------------------------------------------------

#[test]
fn winding_number_of_closed_icosphere() {
    let r = 1.0;
    let (v, tris) = shapes::icosphere(4, r);
    let t = InsideTest::new(&v, &tris);
    assert!(t.is_closed());
    let mut rng = Rng::new(7);
    let mut max_err: f64 = 0.0;
    let mut n_far = 0;
    for _ in 0..3000 {
        let p = Point3::new(
            rng.uniform_in(-2.0, 2.0),
            rng.uniform_in(-2.0, 2.0),
            rng.uniform_in(-2.0, 2.0),
        );
        let exact = t.winding_number_exact(&p);
        let fast = t.winding_number(&p);
        let dist = (p.coords.norm() - r).abs();
        // The polyhedron lies within 1e-3 R of the sphere (5120 triangles).
        if dist > 0.01 * r {
            n_far += 1;
            let expected = if p.coords.norm() < r { 1.0 } else { 0.0 };
            assert!((exact - expected).abs() < 1e-9, "exact {exact} at {p:?}");
            assert!(
                (fast - exact).abs() <= 0.02,
                "fast {fast} exact {exact} at {p:?}"
            );
            assert_eq!(fast >= 0.5, exact >= 0.5);
            assert_eq!(t.contains(&p), exact >= 0.5);
            max_err = max_err.max((fast - exact).abs());
        }
    }
    assert!(n_far > 2900);
    eprintln!("closed icosphere: max |fast − exact| = {max_err:.2e}");
    // Points very close to the surface (0.2 % of R): fast and exact still agree on the decision.
    for k in 0..500 {
        let dir = Vector3::new(
            rng.uniform_in(-1.0, 1.0),
            rng.uniform_in(-1.0, 1.0),
            rng.uniform_in(-1.0, 1.0),
        )
        .normalize();
        let s = if k % 2 == 0 { 0.995 } else { 1.005 };
        let p = Point3::from(dir * s * r);
        let exact = t.winding_number_exact(&p);
        assert_eq!(t.contains(&p), exact >= 0.5, "at {p:?}");
        assert!((t.winding_number(&p) - exact).abs() <= 0.02);
    }
}

#[test]
fn winding_number_of_open_sphere() {
    let sphere = shapes::icosphere(4, 1.0);
    let (v, tris) = remove_faces(&sphere, |p| p.z > 0.5);
    let t = InsideTest::new(&v, &tris);
    assert!(!t.is_closed());
    let c = Point3::origin();
    let exact = t.winding_number_exact(&c);
    let fast = t.winding_number(&c);
    // Cap z > 0.5 of the unit sphere spans the solid angle 2π (1 − 0.5) = π, i.e. a quarter
    // of 4π: the centre sees the rest, winding ≈ 0.75.
    assert!(exact > 0.0 && exact < 1.0);
    assert!((exact - 0.75).abs() < 0.02, "exact {exact}");
    assert!((fast - exact).abs() < 0.02, "fast {fast} exact {exact}");
    // A sample of points: fast vs exact.
    let mut rng = Rng::new(99);
    for _ in 0..500 {
        let p = Point3::new(
            rng.uniform_in(-1.5, 1.5),
            rng.uniform_in(-1.5, 1.5),
            rng.uniform_in(-1.5, 1.5),
        );
        if ((p.coords.norm()) - 1.0).abs() < 0.01 {
            continue;
        }
        let (f, e) = (t.winding_number(&p), t.winding_number_exact(&p));
        assert!((f - e).abs() <= 0.02, "fast {f} exact {e} at {p:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// classify_line against the exact winding number
// ---------------------------------------------------------------------------------------------

fn check_random_lines(mesh: &Mesh, seed: u64, n_lines: usize, n_z: usize) -> Comparison {
    let t = InsideTest::new(&mesh.0, &mesh.1);
    let b = t.bounds();
    let mut rng = Rng::new(seed);
    let lines = random_lines(&mut rng, &b, n_lines);
    let zs = random_zs(&mut rng, &b, n_z);
    let c = compare_lines(&t, &lines, &zs, 0.0);
    assert!(t.is_closed());
    assert_eq!(t.fallback_lines(), 0);
    c
}

#[test]
fn classify_line_sphere() {
    let c = check_random_lines(&shapes::icosphere(3, 0.1), 1, 3000, 12);
    assert_eq!(c.wrong, 0, "{c:?}");
    assert!(c.checked > 35_000, "{c:?}");
}

#[test]
fn classify_line_torus() {
    // Lying torus and a tilted copy (lines then cross up to four sheets at steep angles).
    let mesh = shapes::torus(1.0, 0.3, 48, 24);
    let c = check_random_lines(&mesh, 2, 2500, 12);
    assert_eq!(c.wrong, 0, "{c:?}");
    assert!(c.checked > 29_000, "{c:?}");
    let rot = nalgebra::Rotation3::from_euler_angles(1.1, 0.3, 0.0);
    let tilted = (mesh.0.iter().map(|p| rot * p).collect(), mesh.1.clone());
    let c = check_random_lines(&tilted, 3, 2500, 12);
    assert_eq!(c.wrong, 0, "{c:?}");
}

/// L-shaped slab of voxels: [0,1]² minus [0.5,1]², thickness 0.5, voxel 0.25.
fn l_shape() -> Mesh {
    let mut voxels = Vec::new();
    for i in 0..4 {
        for j in 0..4 {
            if i >= 2 && j >= 2 {
                continue;
            }
            for k in 0..2 {
                voxels.push([i, j, k]);
            }
        }
    }
    shapes::voxel_surface(&voxels, 0.25)
}

/// Lines through every point of the lattice with step `step` over `[lo, hi]²`: through
/// vertices, along edges and through face diagonals of lattice-aligned meshes.
fn lattice_lines(lo: f64, hi: f64, step: f64) -> Vec<(f64, f64)> {
    let n = ((hi - lo) / step).round() as usize;
    let mut lines = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            lines.push((lo + i as f64 * step, lo + j as f64 * step));
        }
    }
    lines
}

#[test]
fn classify_line_l_shape_random_and_degenerate_lines() {
    let mesh = l_shape();
    let c = check_random_lines(&mesh, 4, 3000, 12);
    assert_eq!(c.wrong, 0, "{c:?}");
    let t = InsideTest::new(&mesh.0, &mesh.1);
    // Lattice step 1/16: lines through vertices (multiples of 1/4), along edges, through the
    // diagonals of the faces' triangle pairs (x − y ≡ 0 mod 1/4), and on vertical faces.
    let lines = lattice_lines(-0.25, 1.25, 1.0 / 16.0);
    let zs: Vec<f64> = (0..=24).map(|k| -0.25 + k as f64 / 24.0).collect();
    let c = compare_lines(&t, &lines, &zs, 0.0);
    assert_eq!(c.wrong, 0, "{c:?}");
    assert!(c.checked > 14_000, "{c:?}");
    assert_eq!(t.fallback_lines(), 0);
}

#[test]
fn classify_line_cube_through_vertices_and_edges() {
    // Unit cube with corner at the origin, as 12 triangles and as 4×4×4 voxel faces.
    let coarse = shapes::voxel_surface(&[[0, 0, 0]], 1.0);
    let mut voxels = Vec::new();
    for i in 0..4 {
        for j in 0..4 {
            for k in 0..4 {
                voxels.push([i, j, k]);
            }
        }
    }
    let fine = shapes::voxel_surface(&voxels, 0.25);
    let zs: Vec<f64> = (0..=30).map(|k| -0.25 + k as f64 / 20.0).collect();
    for mesh in [&coarse, &fine] {
        let t = InsideTest::new(&mesh.0, &mesh.1);
        let lines = lattice_lines(-0.125, 1.125, 0.125);
        let c = compare_lines(&t, &lines, &zs, 0.0);
        assert_eq!(c.wrong, 0, "{c:?}");
        assert!(c.checked > 2_000, "{c:?}");
        assert_eq!(t.fallback_lines(), 0);

        // Interior lines through top/bottom face vertices and diagonals: exact expectations.
        let mut out = Vec::new();
        for (x, y) in [
            (0.5, 0.5),
            (0.25, 0.75),
            (0.125, 0.125),
            (0.3, 0.3),
            (0.5, 0.1),
        ] {
            t.classify_line(x, y, &zs, &mut out);
            for (k, &z) in zs.iter().enumerate() {
                if z != 0.0 && z != 1.0 {
                    assert_eq!(out[k], z > 0.0 && z < 1.0, "({x}, {y}, {z})");
                }
            }
        }

        // Lines lying in the surface (x = y = 0 runs along a cube edge, (0.5, 0) along a
        // face): points with z outside [0, 1] are outside; points on the surface are
        // classified as if the line were moved by (+ε, +ε²).
        for (x, y) in [
            (0.0, 0.0),
            (1.0, 1.0),
            (1.0, 0.0),
            (0.0, 1.0),
            (0.5, 0.0),
            (0.0, 0.5),
        ] {
            let mut shifted = Vec::new();
            t.classify_line(x, y, &zs, &mut out);
            t.classify_line(x + 1e-9, y + 1e-12, &zs, &mut shifted);
            assert_eq!(out, shifted, "line ({x}, {y})");
            for (k, &z) in zs.iter().enumerate() {
                if !(0.0..=1.0).contains(&z) {
                    assert!(!out[k]);
                }
            }
        }
        assert_eq!(t.fallback_lines(), 0);
    }
}

#[test]
fn classify_line_overlapping_and_unwelded_and_flipped() {
    // Two overlapping spheres given as one self-intersecting soup: winding 2 in the lens.
    let a = shapes::icosphere(3, 1.0);
    let b = translated(&a, Vector3::new(0.7, 0.2, 0.1));
    let both = union_soup(&a, &b);
    let c = check_random_lines(&both, 5, 1500, 12);
    assert_eq!(c.wrong, 0, "{c:?}");

    // Unwelded: every triangle with its own three vertices.
    let (v, t) = shapes::torus(1.0, 0.4, 32, 16);
    let soup_v: Vec<Point3<f64>> = t.iter().flat_map(|f| f.map(|i| v[i])).collect();
    let soup_t: Vec<[usize; 3]> = (0..t.len())
        .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
        .collect();
    let c = check_random_lines(&(soup_v, soup_t), 6, 1500, 12);
    assert_eq!(c.wrong, 0, "{c:?}");

    // One flipped triangle: not closed any more (its edges are unmatched twice); outside the
    // close neighbourhood of the flipped triangle the decision is unchanged.
    let (v, mut t) = shapes::icosphere(3, 1.0);
    t[17].swap(1, 2);
    let inside = InsideTest::new(&v, &t);
    assert!(!inside.is_closed());
    let mut rng = Rng::new(8);
    let lines = random_lines(&mut rng, &inside.bounds(), 1500);
    let zs = random_zs(&mut rng, &inside.bounds(), 12);
    let c = compare_lines(&inside, &lines, &zs, 0.02);
    assert_eq!(c.wrong, 0, "{c:?}");
}

#[test]
fn classify_line_many_crossings() {
    // 24 disjoint spheres stacked along z: lines cross up to 48 sheets (beyond the inline
    // crossing buffer).
    let ball = shapes::icosphere(2, 0.4);
    let mut mesh = ball.clone();
    for k in 1..24 {
        mesh = union_soup(&mesh, &translated(&ball, Vector3::new(0.0, 0.0, k as f64)));
    }
    let t = InsideTest::new(&mesh.0, &mesh.1);
    let mut crossings = Vec::new();
    t.line_crossings(0.01, 0.02, &mut crossings);
    assert_eq!(crossings.len(), 48);
    assert!(crossings.windows(2).all(|w| w[0].0 <= w[1].0));
    assert_eq!(crossings.iter().map(|c| c.1).sum::<i32>(), 0);
    let mut rng = Rng::new(31);
    let lines: Vec<(f64, f64)> = (0..300)
        .map(|_| (rng.uniform_in(-0.45, 0.45), rng.uniform_in(-0.45, 0.45)))
        .collect();
    let zs: Vec<f64> = (0..100).map(|_| rng.uniform_in(-0.5, 23.5)).collect();
    let c = compare_lines(&t, &lines, &zs, 0.0);
    assert_eq!(c.wrong, 0, "{c:?}");
    assert!(c.checked > 29_000);
    assert_eq!(t.fallback_lines(), 0);
}

#[test]
fn classify_line_sphere_with_holes_matches_winding_decision() {
    let sphere = shapes::icosphere(3, 1.0);
    // A large hole on top (lines pass through it) and a small hole on the side.
    let open_top = remove_faces(&sphere, |p| p.z > 0.6);
    let open_side = remove_faces(&sphere, |p| p.x > 0.93);
    for (seed, mesh) in [(11, open_top), (12, open_side)] {
        let t = InsideTest::new(&mesh.0, &mesh.1);
        assert!(!t.is_closed());
        let mut rng = Rng::new(seed);
        let lines = random_lines(&mut rng, &t.bounds(), 1500);
        let zs = random_zs(&mut rng, &t.bounds(), 12);
        let c = compare_lines(&t, &lines, &zs, 0.02);
        assert_eq!(c.wrong, 0, "{c:?}");
        assert!(c.checked > 15_000, "{c:?}");
        assert!(t.fallback_lines() > 0);
        eprintln!(
            "open sphere: {c:?}, fallback lines {} points {}",
            t.fallback_lines(),
            t.fallback_points()
        );
    }
}

#[test]
fn classify_line_is_consistent_across_threads() {
    let (v, t) = shapes::torus(0.1, 0.03, 64, 32);
    let inside = InsideTest::new(&v, &t);
    let zs: Vec<f64> = (0..64).map(|k| -0.05 + k as f64 * 0.1 / 63.0).collect();
    let lines: Vec<(f64, f64)> = (0..4096)
        .map(|k| {
            (
                -0.14 + 0.28 * (k % 64) as f64 / 63.0,
                -0.14 + 0.28 * (k / 64) as f64 / 63.0,
            )
        })
        .collect();
    let par: Vec<Vec<bool>> = lines
        .par_iter()
        .map(|&(x, y)| {
            let mut out = Vec::new();
            inside.classify_line(x, y, &zs, &mut out);
            out
        })
        .collect();
    let mut out = Vec::new();
    for (k, &(x, y)) in lines.iter().enumerate() {
        inside.classify_line(x, y, &zs, &mut out);
        assert_eq!(out, par[k]);
    }
    // Unsorted z and repeated z give the same per-point answers.
    let mut rev: Vec<f64> = zs.iter().rev().copied().collect();
    rev.push(zs[10]);
    inside.classify_line(0.1, 0.0, &rev, &mut out);
    let mut fwd = Vec::new();
    inside.classify_line(0.1, 0.0, &zs, &mut fwd);
    for k in 0..zs.len() {
        assert_eq!(out[zs.len() - 1 - k], fwd[k]);
    }
    assert_eq!(out[zs.len()], fwd[10]);
    assert!(fwd.iter().any(|&b| b));
}

// ---------------------------------------------------------------------------------------------
// Volumes from lattice classification
// ---------------------------------------------------------------------------------------------

/// Inside count × cell volume over a lattice of `n³` cell centres covering `b`.
fn lattice_volume(t: &InsideTest, b: &Aabb, n: usize) -> f64 {
    let h = b.extents() / n as f64;
    let zs: Vec<f64> = (0..n).map(|k| b.min.z + (k as f64 + 0.5) * h.z).collect();
    let count: usize = (0..n * n)
        .into_par_iter()
        .map(|ij| {
            let (i, j) = (ij % n, ij / n);
            let x = b.min.x + (i as f64 + 0.5) * h.x;
            let y = b.min.y + (j as f64 + 0.5) * h.y;
            let mut out = Vec::with_capacity(n);
            t.classify_line(x, y, &zs, &mut out);
            out.iter().filter(|&&o| o).count()
        })
        .sum();
    count as f64 * h.product()
}

#[test]
fn lattice_volume_of_sphere_and_torus() {
    let r = 0.1;
    let (v, tris) = shapes::icosphere(5, r);
    let t = InsideTest::new(&v, &tris);
    let b = Aabb::new(Point3::new(-r, -r, -r), Point3::new(r, r, r)).expanded(0.013 * r);
    let vol = lattice_volume(&t, &b, 160);
    let exact = 4.0 / 3.0 * PI * r.powi(3);
    let mesh_vol = shapes::signed_volume(&v, &tris);
    eprintln!(
        "sphere: lattice {vol:.6e}, mesh {mesh_vol:.6e}, exact {exact:.6e}, rel {:.2e}",
        vol / exact - 1.0
    );
    assert!((vol / exact - 1.0).abs() < 0.01);
    assert!((vol / mesh_vol - 1.0).abs() < 0.005);

    let (major, minor) = (0.08, 0.025);
    let (v, tris) = shapes::torus(major, minor, 160, 64);
    let t = InsideTest::new(&v, &tris);
    let e = major + minor;
    let b = Aabb::new(Point3::new(-e, -e, -minor), Point3::new(e, e, minor)).expanded(0.003);
    let vol = lattice_volume(&t, &b, 200);
    let exact = 2.0 * PI * PI * major * minor * minor;
    eprintln!(
        "torus: lattice {vol:.6e}, exact {exact:.6e}, rel {:.2e}",
        vol / exact - 1.0
    );
    assert!((vol / exact - 1.0).abs() < 0.01);
    assert_eq!(t.fallback_lines(), 0);
}

// ---------------------------------------------------------------------------------------------
// Box overlap queries
// ---------------------------------------------------------------------------------------------

#[test]
fn triangles_overlapping_matches_brute_force() {
    let (v, tris) = shapes::icosphere(4, 1.0);
    let t = InsideTest::new(&v, &tris);
    let mut rng = Rng::new(21);
    let mut out = Vec::new();
    let mut filtered = Vec::new();
    let mut total = 0;
    for _ in 0..300 {
        let c = Point3::new(
            rng.uniform_in(-1.2, 1.2),
            rng.uniform_in(-1.2, 1.2),
            rng.uniform_in(-1.2, 1.2),
        );
        let h = Vector3::repeat(rng.uniform_in(0.01, 0.3));
        let b = Aabb::new(c - h, c + h);
        t.triangles_overlapping(&b, &mut out);
        let want: Vec<usize> = (0..tris.len())
            .filter(|&k| triangle_overlaps_box(&tris[k].map(|i| v[i]), &b))
            .collect();
        assert_eq!(out, want);
        total += out.len();
        let mut bbox = Vec::new();
        t.triangles_bbox_overlapping(&b, &mut bbox);
        let want_bbox: Vec<usize> = (0..tris.len())
            .filter(|&k| Aabb::from_points(&tris[k].map(|i| v[i])).intersects(&b))
            .collect();
        assert_eq!(bbox, want_bbox);
        // Recursive refinement through the candidate filter gives the same sets.
        for o in 0..8 {
            let child = b.octant(o);
            t.filter_overlapping(&out, &child, &mut filtered);
            let mut direct = Vec::new();
            t.triangles_overlapping(&child, &mut direct);
            assert_eq!(filtered, direct);
        }
    }
    assert!(total > 1000);
}

#[test]
fn far_field_expansion_orders_converge() {
    use super::bvh::Bvh;
    use super::winding::{ExpansionOrder, FastWinding};
    // One node holding a curved patch (the cap z > 0.7 of a unit sphere, radius ≈ 0.7):
    // the relative error of an order-k expansion decays like d^-(k+1).
    let (v, tris) = shapes::icosphere(2, 1.0);
    let corners: Vec<[Point3<f64>; 3]> = tris
        .iter()
        .map(|t| t.map(|i| v[i]))
        .filter(|c| c.iter().all(|p| p.z > 0.7))
        .collect();
    let boxes: Vec<Aabb> = corners.iter().map(Aabb::from_points).collect();
    let bvh = Bvh::build(&boxes, 1000);
    let fw = FastWinding::new(&bvh, &corners);
    let rel = |q: Point3<f64>, order| {
        let e = super::winding_number_brute(&corners, &q);
        ((fw.eval(&bvh, &q, 1.01, order) - e) / e).abs()
    };
    let near = Point3::new(3.0, 5.0, 7.0);
    let far = Point3::new(30.0, 50.0, 70.0);
    for (order, k) in [
        (ExpansionOrder::Dipole, 1),
        (ExpansionOrder::FirstOrder, 2),
        (ExpansionOrder::SecondOrder, 3),
    ] {
        let ratio = rel(near, order) / rel(far, order);
        let expected = 10f64.powi(k);
        assert!(
            ratio > 0.3 * expected && ratio < 3.0 * expected,
            "{order:?}: error ratio {ratio} for 10× distance"
        );
    }
    assert!(rel(far, ExpansionOrder::SecondOrder) < 1e-6);
}
