//! Benchmarks of `livereg_fem::geometry::InsideTest` on a 20 480-triangle sphere of radius 10 cm.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use livereg_fem::geometry::{shapes, Aabb, InsideTest};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

fn bench_inside_test(c: &mut Criterion) {
    let radius = 0.1;
    let (vertices, triangles) = shapes::icosphere(5, radius);
    assert_eq!(triangles.len(), 20_480);

    c.bench_function("build_sphere_20k", |b| {
        b.iter(|| InsideTest::new(black_box(&vertices), black_box(&triangles)))
    });

    let inside = InsideTest::new(&vertices, &triangles);
    // 1024 lines on a 32×32 lattice over the sphere's shadow, 64 points each.
    let lines: Vec<(f64, f64)> = (0..1024)
        .map(|k| {
            let (i, j) = (k % 32, k / 32);
            (
                -radius + (i as f64 + 0.5) * 2.0 * radius / 32.0,
                -radius + (j as f64 + 0.5) * 2.0 * radius / 32.0,
            )
        })
        .collect();
    let zs: Vec<f64> = (0..64)
        .map(|k| -radius + (k as f64 + 0.5) * 2.0 * radius / 64.0)
        .collect();
    let mut out = Vec::with_capacity(64);
    let mut k = 0;
    c.bench_function("classify_line_64_points", |b| {
        b.iter(|| {
            let (x, y) = lines[k % lines.len()];
            k += 1;
            inside.classify_line(black_box(x), black_box(y), black_box(&zs), &mut out);
            black_box(&out);
        })
    });

    // Points spread through the bounding box (inside, outside and near the surface).
    let points: Vec<Point3<f64>> = (0..4096)
        .map(|k| {
            let f = |s: u32| ((k as u32).wrapping_mul(s) % 1000) as f64 / 1000.0;
            Point3::new(
                (f(7919) * 2.4 - 1.2) * radius,
                (f(104_729) * 2.4 - 1.2) * radius,
                (f(1_299_709) * 2.4 - 1.2) * radius,
            )
        })
        .collect();
    let mut k = 0;
    c.bench_function("winding_number", |b| {
        b.iter(|| {
            let p = &points[k % points.len()];
            k += 1;
            black_box(inside.winding_number(black_box(p)))
        })
    });
    let mut k = 0;
    c.bench_function("contains", |b| {
        b.iter(|| {
            let p = &points[k % points.len()];
            k += 1;
            black_box(inside.contains(black_box(p)))
        })
    });
}

/// Work of an immersed-grid build, as the grid builder would issue it: cells of edge `h` over the
/// surface's box; each cut cell is refined `levels` times (children of a cut sub-cell are
/// tested against the parent's candidate triangles); the 2×2×2 Gauss points of cut leaves are
/// classified with one `classify_line` call per (x, y) Gauss line of the cell, and the centre
/// of every uncut cell or sub-cell with a one-point `classify_line`. Returns
/// (cut leaves, inside points) so that the work cannot be optimised away.
fn grid_workload(inside: &InsideTest, h: f64, levels: u32) -> (usize, usize) {
    let b = inside.bounds().expanded(0.5 * h);
    let n = (b.extents() / h).map(|e| e.ceil() as usize);
    let sub = 1usize << levels;
    let g = [-0.5 / 3f64.sqrt() + 0.5, 0.5 / 3f64.sqrt() + 0.5];
    (0..n.x * n.y * n.z)
        .into_par_iter()
        .map(|idx| {
            let (i, j, k) = (idx % n.x, (idx / n.x) % n.y, idx / (n.x * n.y));
            let min = b.min + Vector3::new(i as f64, j as f64, k as f64) * h;
            let cell = Aabb::new(min, min + Vector3::repeat(h));
            let mut cands = Vec::new();
            inside.triangles_overlapping(&cell, &mut cands);
            let mut out = Vec::new();
            if cands.is_empty() {
                let c = cell.center();
                inside.classify_line(c.x, c.y, &[c.z], &mut out);
                return (0, usize::from(out[0]));
            }
            // Recursive refinement; leaves are indexed on the sub × sub × sub lattice.
            let mut cut_leaf = vec![false; sub * sub * sub];
            let mut inside_count = 0;
            let mut stack = vec![(cell, cands, 0u32, [0usize; 3])];
            let mut child_cands = Vec::new();
            while let Some((bx, cands, level, at)) = stack.pop() {
                if level == levels {
                    cut_leaf[(at[2] * sub + at[1]) * sub + at[0]] = true;
                    continue;
                }
                for o in 0..8 {
                    let child = bx.octant(o);
                    inside.filter_overlapping(&cands, &child, &mut child_cands);
                    let span = sub >> (level + 1);
                    let at = [
                        at[0] + (o & 1) * span,
                        at[1] + ((o >> 1) & 1) * span,
                        at[2] + ((o >> 2) & 1) * span,
                    ];
                    if child_cands.is_empty() {
                        let c = child.center();
                        inside.classify_line(c.x, c.y, &[c.z], &mut out);
                        inside_count += usize::from(out[0]);
                    } else {
                        stack.push((child, child_cands.clone(), level + 1, at));
                    }
                }
            }
            // Gauss points of the cut leaves, one classify_line per (x, y) Gauss line.
            let hl = h / sub as f64;
            let mut zs = Vec::new();
            let mut leaves = 0;
            for li in 0..sub {
                for lj in 0..sub {
                    zs.clear();
                    for lk in 0..sub {
                        if cut_leaf[(lk * sub + lj) * sub + li] {
                            leaves += 1;
                            zs.extend(g.iter().map(|t| min.z + (lk as f64 + t) * hl));
                        }
                    }
                    if zs.is_empty() {
                        continue;
                    }
                    for gx in g {
                        for gy in g {
                            let x = min.x + (li as f64 + gx) * hl;
                            let y = min.y + (lj as f64 + gy) * hl;
                            inside.classify_line(x, y, &zs, &mut out);
                            inside_count += out.iter().filter(|&&o| o).count();
                        }
                    }
                }
            }
            (leaves, inside_count)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
}

fn bench_grid_workload(c: &mut Criterion) {
    // A 20 cm "organ": 20 480-triangle sphere of radius 10 cm, cells of 1 cm, 4 levels.
    let (vertices, triangles) = shapes::icosphere(5, 0.1);
    let inside = InsideTest::new(&vertices, &triangles);
    let (leaves, _) = grid_workload(&inside, 0.01, 4);
    eprintln!(
        "grid workload: {leaves} cut leaves, {} Gauss points",
        8 * leaves
    );
    let mut group = c.benchmark_group("grid_workload");
    group.sample_size(10);
    group.bench_function("sphere_20k_h1cm_L4", |b| {
        b.iter(|| {
            let inside = InsideTest::new(&vertices, &triangles);
            black_box(grid_workload(&inside, black_box(0.01), 4))
        })
    });
    group.finish();
}

criterion_group!(benches, bench_inside_test, bench_grid_workload);
criterion_main!(benches);
