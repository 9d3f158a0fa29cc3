//! Simple closed triangle surfaces with known volumes, for tests and benchmarks.
//!
//! Every function returns `(vertices, triangles)` with shared (welded) vertices and outward
//! right-hand orientation, in the same length units as its size arguments.

use std::collections::HashMap;

use nalgebra::Point3;

/// Vertices and triangles of a surface.
pub type Mesh = (Vec<Point3<f64>>, Vec<[usize; 3]>);

/// Icosphere of radius `radius` centred at the origin: an icosahedron whose faces are split
/// `subdivisions` times into 4, with all vertices projected onto the sphere
/// (`20 · 4^subdivisions` triangles; 5 subdivisions give 20 480).
pub fn icosphere(subdivisions: u32, radius: f64) -> Mesh {
    let s = crate::mesh::primitives::icosphere(Point3::origin(), radius, subdivisions as usize);
    (s.vertices, s.triangles)
}

/// Torus around the z axis through the origin: tube centre radius `major`, tube radius
/// `minor`, `n_major × n_minor` quads split into two triangles each
/// (volume of the smooth torus: 2π² · major · minor²).
pub fn torus(major: f64, minor: f64, n_major: usize, n_minor: usize) -> Mesh {
    let tau = std::f64::consts::TAU;
    let mut vertices = Vec::with_capacity(n_major * n_minor);
    for i in 0..n_major {
        let u = tau * i as f64 / n_major as f64;
        for j in 0..n_minor {
            let v = tau * j as f64 / n_minor as f64;
            let rho = major + minor * v.cos();
            vertices.push(Point3::new(rho * u.cos(), rho * u.sin(), minor * v.sin()));
        }
    }
    let id = |i: usize, j: usize| (i % n_major) * n_minor + (j % n_minor);
    let mut triangles = Vec::with_capacity(2 * n_major * n_minor);
    for i in 0..n_major {
        for j in 0..n_minor {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    (vertices, triangles)
}

/// Boundary surface of a union of axis-aligned voxels of edge `size`: voxel `[i, j, k]` is the
/// cube `[i, i+1] × [j, j+1] × [k, k+1]` scaled by `size`. Every exposed voxel face becomes two
/// triangles split along the diagonal from its lowest to its highest corner, so vertices lie on
/// the lattice and horizontal faces are split along lines `x − y = const`.
///
/// Voxel sets whose voxels touch only along an edge or at a corner give a non-manifold (but
/// still closed) surface.
pub fn voxel_surface(voxels: &[[i32; 3]], size: f64) -> Mesh {
    let occupied: std::collections::HashSet<[i32; 3]> = voxels.iter().copied().collect();
    let mut index: HashMap<[i32; 3], usize> = HashMap::new();
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    let mut vid = |c: [i32; 3], vertices: &mut Vec<Point3<f64>>| {
        *index.entry(c).or_insert_with(|| {
            vertices.push(Point3::new(
                c[0] as f64 * size,
                c[1] as f64 * size,
                c[2] as f64 * size,
            ));
            vertices.len() - 1
        })
    };
    let mut sorted: Vec<[i32; 3]> = occupied.iter().copied().collect();
    sorted.sort_unstable();
    for v in sorted {
        for axis in 0..3 {
            for dir in [-1i32, 1] {
                let mut nb = v;
                nb[axis] += dir;
                if occupied.contains(&nb) {
                    continue;
                }
                // Face on the plane coordinate v[axis] (+1 if dir > 0), spanned by axes u, w.
                let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
                let mut base = v;
                if dir > 0 {
                    base[axis] += 1;
                }
                let corner = |du: i32, dw: i32| {
                    let mut c = base;
                    c[u] += du;
                    c[w] += dw;
                    c
                };
                let c00 = vid(corner(0, 0), &mut vertices);
                let c10 = vid(corner(1, 0), &mut vertices);
                let c11 = vid(corner(1, 1), &mut vertices);
                let c01 = vid(corner(0, 1), &mut vertices);
                // (u, w, axis) is right-handed, so (c00, c10, c11) has normal +axis.
                if dir > 0 {
                    triangles.push([c00, c10, c11]);
                    triangles.push([c00, c11, c01]);
                } else {
                    triangles.push([c00, c11, c10]);
                    triangles.push([c00, c01, c11]);
                }
            }
        }
    }
    (vertices, triangles)
}

/// Signed enclosed volume of a surface by the divergence theorem (positive for outward
/// orientation), in length units³.
pub fn signed_volume(vertices: &[Point3<f64>], triangles: &[[usize; 3]]) -> f64 {
    triangles
        .iter()
        .map(|&[a, b, c]| {
            vertices[a]
                .coords
                .dot(&vertices[b].coords.cross(&vertices[c].coords))
                / 6.0
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn volumes_and_orientation() {
        let (v, t) = icosphere(3, 2.0);
        assert_eq!(t.len(), 1280);
        let vol = signed_volume(&v, &t);
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 8.0;
        assert!(vol > 0.95 * exact && vol < exact, "{vol} vs {exact}");

        let (v, t) = torus(1.0, 0.25, 96, 48);
        let vol = signed_volume(&v, &t);
        let exact = 2.0 * std::f64::consts::PI.powi(2) * 1.0 * 0.0625;
        assert!((vol / exact - 1.0).abs() < 0.01, "{vol} vs {exact}");

        let l = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]];
        let (v, t) = voxel_surface(&l, 0.5);
        assert!((signed_volume(&v, &t) - 4.0 * 0.125).abs() < 1e-12);
    }
}
